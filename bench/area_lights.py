#!/usr/bin/env python3
"""Area lights against their surface integral: a grey floor (albedo 0.5) seen from straight
above, lit by one area light close beside the view, rendered by `granular-render` (EPT:
light sampling, BSDF rays that meet the light, MIS) and compared with the floor's radiance
integrated over the light's surface by the midpoint rule here (rho / pi * integral of
L cos(theta_floor) cos(theta_light) / d^2 dA, times the shaping factor where the light has
one).

Prints a markdown table: light | reference | render | bias % +- s.e. (from the variance
AOV) | relative s.e. per sample (the noise of one sample, s.e. * sqrt(spp * pixels) /
mean) | render time. The s.e. per sample measures how well each light is sampled.

The "mesh" lights are UsdLuxMeshLightAPI's (core's LightType::Mesh): the rect's quad and a
valley of two tilted panels; "emissive_quad" is the quad as an emissive surface, which only
BSDF rays find (what a stage could do before mesh lights). A table (--mesh-sizes 1) prices a
mesh light's triangles: a ball as icospheres of 80 to 20480 triangles against the sphere light.
A last table (with --grain-spp) lights the sugar cube by a softbox, as a mesh light and as an
emissive surface. Another (--many 1) times the floor under 4 to 1024 small sphere lights.

The "ies" lights carry an IES profile (UsdLuxShapingAPI's inputs:shaping:ies:*): the
reference evaluates the profile here (linear in the vertical and the horizontal angle, in
the light's frame) and normalises it by its own quadrature. A second table times reading a
profile (parsing and the mean normalisation divides by) for three sizes of file.

A third table (--grain-spp N > 0) prices a profile in a scene of grains: the sugar cube
example with its sun and sky off, lit by a sphere light 8 cm above it with a 60° cone,
rendered by `granular render` with that cone alone and with the downlight's profile
(normalised) as well, best of three.

Usage: .venv/bin/python bench/area_lights.py [--spp 1024] [--width 32] [--build build]
       [--out out/bench/area_lights]
       [--lights sphere,rect,disk,cylinder,spot,ies,ies_scaled,ies_asym,mesh_quad,mesh_valley,emissive_quad]
       [--grain-spp 16] [--mesh-sizes 1] [--many 1]
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# Each light: its JSON, and its emitting surface as (points, normals, areas) for the
# reference. All of them lie outside the camera's view of the floor, [-0.2, 0.2]^2.
M = 400  # quadrature cells per side of a light's parameter domain


def grid():
    """The cells' midpoints in [0, 1]^2, M x M."""
    u = (np.arange(M) + 0.5) / M
    return np.meshgrid(u, u, indexing="ij")


def sphere_surface(c, r):
    a, b = grid()
    z = 1 - 2 * a  # uniform in z and phi: equal areas
    phi = 2 * np.pi * b
    s = np.sqrt(1 - z * z)
    n = np.stack([s * np.cos(phi), s * np.sin(phi), z], -1).reshape(-1, 3)
    return np.array(c) + r * n, n, np.full(len(n), 4 * np.pi * r * r / M ** 2)


def disk_surface(c, r):  # facing down (-y)
    a, b = grid()
    rho, phi = r * a, 2 * np.pi * b  # rings of width r / M, their midpoints
    rho0, rho1 = rho - 0.5 * r / M, rho + 0.5 * r / M
    p = np.stack([c[0] + rho * np.cos(phi), np.full_like(rho, c[1]), c[2] + rho * np.sin(phi)], -1).reshape(-1, 3)
    area = (0.5 * (rho1 ** 2 - rho0 ** 2) * 2 * np.pi / M).reshape(-1)
    return p, np.tile([0.0, -1.0, 0.0], (len(p), 1)), area


def rect_surface(c, w, h):  # in the XZ plane, facing down
    a, b = grid()
    p = np.stack([c[0] + (a - 0.5) * w, np.full_like(a, c[1]), c[2] + (b - 0.5) * h], -1).reshape(-1, 3)
    return p, np.tile([0.0, -1.0, 0.0], (len(p), 1)), np.full(len(p), w * h / M ** 2)


def cylinder_surface(c, r, length):  # along X
    a, b = grid()
    phi = 2 * np.pi * b
    n = np.stack([np.zeros_like(phi), np.cos(phi), np.sin(phi)], -1).reshape(-1, 3)
    p = np.stack([c[0] + (a - 0.5) * length, c[1] + r * np.cos(phi), c[2] + r * np.sin(phi)], -1).reshape(-1, 3)
    return p, n, np.full(len(p), 2 * np.pi * r * length / M ** 2)


def valley_surface(c, w, depth):
    """Two panels meeting along z at c (their fold, lowest), each w wide in x and w in z,
    rising to depth above the fold at x = c_x +- w, facing down (and away from the fold)."""
    a, b = grid()
    slope = depth / w
    norm = np.sqrt(1 + slope * slope)
    parts = []
    for side in (-1, 1):
        x = side * w * a
        p = np.stack([c[0] + x, c[1] + slope * np.abs(x), c[2] + (b - 0.5) * w], -1).reshape(-1, 3)
        n = np.tile([side * slope / norm, -1 / norm, 0.0], (len(p), 1))
        parts.append((p, n, np.full(len(p), w * w * norm / M ** 2)))
    return tuple(np.concatenate(x) for x in zip(*parts))


def mesh_shape(points, faces):
    return {"mesh": {"points": [list(map(float, p)) for p in points], "face_vertex_counts": [len(f) for f in faces],
                     "face_vertex_indices": [i for f in faces for i in f]}}


# The rect's quad (0.4 x 0.2, facing down) and a valley of two 0.2 x 0.2 panels, as meshes.
QUAD = mesh_shape([(-0.2, 0.5, 0.35), (0.2, 0.5, 0.35), (0.2, 0.5, 0.55), (-0.2, 0.5, 0.55)], [(0, 1, 2, 3)])
VALLEY = mesh_shape([(-0.2, 0.6, 0.35), (0, 0.5, 0.35), (0.2, 0.6, 0.35), (-0.2, 0.6, 0.55), (0, 0.5, 0.55),
                     (0.2, 0.6, 0.55)], [(0, 1, 4, 3), (1, 2, 5, 4)])


def at(c):
    """A light at c whose local -Z (its emitting side) faces straight down."""
    return {"transform": {"translate": list(c), "rotate": [-90, 1, 0, 0]}}


SPOT = {"shaping_cone_angle": 20, "shaping_cone_softness": 0.5, "shaping_focus": 8, "shaping_focus_tint": 0.25}
# Profiles: a downlight (axial, 2.5° steps to 90°, I = 1000 cos^8 θ + 200 on a ring at 30°)
# and one without symmetry (5° steps over the sphere and the circle).
DOWN_V = np.arange(0, 90.01, 2.5)
# Candela to 3 decimals, as the files hold them (ies_text writes them in full).
DOWN_ROWS = [np.round(1000 * np.cos(np.radians(DOWN_V)) ** 8 + 200 * np.exp(-((DOWN_V - 30) / 6) ** 2), 3)]
ASYM_V, ASYM_H = np.arange(0, 180.01, 5), np.arange(0, 360.01, 15)
ASYM_ROWS = [np.round(300 * (1.2 + np.cos(np.radians(h)) * np.cos(np.radians(ASYM_V))) * np.exp(-np.radians(ASYM_V))
                      + 20, 3) for h in ASYM_H]


def ies_text(vertical, horizontal, rows):
    numbers = lambda v: " ".join(f"{x:.10g}" for x in v)
    return (f"IESNA:LM-63-2002\n[TEST] bench profile\nTILT=NONE\n1 -1 1 {len(vertical)} {len(horizontal)} 1 2 0 0 0\n"
            f"1 1 10\n{numbers(vertical)}\n{numbers(horizontal)}\n" + "\n".join(numbers(r) for r in rows) + "\n")


PROFILES = {"down": (DOWN_V, np.array([0.0]), DOWN_ROWS), "asym": (ASYM_V, ASYM_H, ASYM_ROWS)}


def ies_eval(profile, theta, phi):
    """Candela at (theta, phi) degrees, written out here: linear in theta per row (0 past the
    last vertical angle), then linear in phi between rows (one row: axial)."""
    v, h, rows = PROFILES[profile]
    per_row = [np.where(theta <= v[-1], np.interp(theta, v, r), 0.0) for r in rows]
    if len(h) == 1:
        return per_row[0]
    phi = np.mod(phi, 360.0)
    j = np.clip(np.searchsorted(h, phi, side="right"), 1, len(h) - 1)
    t = (phi - h[j - 1]) / (h[j] - h[j - 1])
    stacked = np.stack(per_row)
    idx = np.arange(len(phi))
    return stacked[j - 1, idx] * (1 - t) + stacked[j, idx] * t


def ies_mean(profile):
    """∫ I dω over 4π, or 2π for a profile over the lower hemisphere alone (core/ies.h)."""
    v, _, _ = PROFILES[profile]
    th, ph = np.meshgrid(np.radians(np.arange(0.025, v[-1], 0.05)), np.radians(np.arange(0.25, 360, 0.5)),
                         indexing="ij")
    I = ies_eval(profile, np.degrees(th).ravel(), np.degrees(ph).ravel()).reshape(th.shape)
    total = (I * np.sin(th)).sum() * np.radians(0.05) * np.radians(0.5)
    return total / (2 * np.pi if v[-1] <= 90 else 4 * np.pi)


IES = {"down": {"shaping_ies_file": "down.ies"},
       "scaled": {"shaping_ies_file": "down.ies", "shaping_ies_angle_scale": 1.5, "shaping_ies_normalize": True},
       "asym": {"shaping_ies_file": "asym.ies", "shaping_cone_angle": 180}}
LIGHTS = {
    "sphere": ({"type": "sphere", "position": [0, 0.3, 0.4], "radius": 0.1}, lambda: sphere_surface((0, 0.3, 0.4), 0.1)),
    "rect": ({"type": "rect", "width": 0.4, "height": 0.2, **at((0.0, 0.5, 0.45))},
             lambda: rect_surface((0.0, 0.5, 0.45), 0.4, 0.2)),
    "disk": ({"type": "disk", "radius": 0.3, **at((0.1, 1.0, 0.0))}, lambda: disk_surface((0.1, 1.0, 0.0), 0.3)),
    "cylinder": ({"type": "cylinder", "position": [0, 0.5, 0.5], "radius": 0.05, "length": 1},
                 lambda: cylinder_surface((0, 0.5, 0.5), 0.05, 1.0)),
    "spot": ({"type": "disk", "radius": 0.3, **at((0.1, 1.0, 0.0)), **SPOT}, lambda: disk_surface((0.1, 1.0, 0.0), 0.3)),
    "ies": ({"type": "disk", "radius": 0.05, "intensity": 0.01, **at((0.05, 0.4, 0.0)), **IES["down"]},
            lambda: disk_surface((0.05, 0.4, 0.0), 0.05)),
    "ies_scaled": ({"type": "disk", "radius": 0.05, "intensity": 0.5, **at((0.05, 0.4, 0.0)), **IES["scaled"]},
                   lambda: disk_surface((0.05, 0.4, 0.0), 0.05)),
    "ies_asym": ({"type": "disk", "radius": 0.05, "intensity": 0.01, **at((0.05, 0.4, 0.0)), **IES["asym"]},
                 lambda: disk_surface((0.05, 0.4, 0.0), 0.05)),
    # Mesh lights (UsdLuxMeshLightAPI), and the quad as an emissive surface instead, which only
    # BSDF rays find.
    "mesh_quad": ({"type": "mesh", "shape": QUAD}, lambda: rect_surface((0.0, 0.5, 0.45), 0.4, 0.2)),
    "mesh_valley": ({"type": "mesh", "shape": VALLEY}, lambda: valley_surface((0.0, 0.5, 0.45), 0.2, 0.1)),
    "emissive_quad": ({"emissive_mesh": QUAD}, lambda: rect_surface((0.0, 0.5, 0.45), 0.4, 0.2)),
}


def shaping(w_axis_cos, cos_l, s):
    """UsdLuxShapingAPI's factor as core/scene_desc.h (LightShaping) states it."""
    theta = np.arccos(np.clip(w_axis_cos, -1, 1))
    cone = np.radians(s["shaping_cone_angle"])
    smooth = cone * (1 - s["shaping_cone_softness"])
    x = np.clip((cone - theta) / (cone - smooth), 0, 1)
    f = np.where(theta > cone, 0.0, np.where(theta > smooth, x * x * (3 - 2 * x), 1.0))
    tint = s["shaping_focus_tint"]
    return f * (tint + (1 - tint) * np.abs(cos_l) ** s["shaping_focus"])


def reference(name, n=48):
    light, surface = LIGHTS[name]
    q, nq, dA = surface()
    u = -0.2 + 0.4 * (np.arange(n) + 0.5) / n
    total = 0.0
    for x in u:
        for z in u:
            w = np.array([x, 0.0, z]) - q  # from the light to the floor point
            d = np.linalg.norm(w, axis=1)
            cos_l = np.einsum("ij,ij->i", nq, w) / d
            cos_p = q[:, 1] / d
            f = np.where((cos_l > 0) & (cos_p > 0), cos_l * cos_p / d ** 2 * dA, 0.0)
            if "shaping_cone_angle" in light and "shaping_ies_file" not in light:
                f = f * shaping(-w[:, 1] / d, cos_l, light)  # the axis: straight down
            if "shaping_ies_file" in light:
                # The light's frame (at()): local -Z down, +X along x, +Y along -z.
                theta = np.degrees(np.arccos(np.clip(-w[:, 1] / d, -1, 1)))
                phi = np.degrees(np.arctan2(-w[:, 2], w[:, 0]))
                scale = light.get("shaping_ies_angle_scale", 0)
                profile = light["shaping_ies_file"][:-4]
                candela = ies_eval(profile, theta / scale if scale > 0 else theta, phi)
                if light.get("shaping_ies_normalize"):
                    candela = candela / ies_mean(profile)
                f = f * candela * light.get("intensity", 1.0)
            total += 0.5 / np.pi * f.sum()
    return total / n ** 2


def scene(name, width, spp):
    light, _ = LIGHTS[name]
    s = {
        "render": {"width": width, "height": width, "spp": spp, "technique": "ept"},
        "camera": {"look_at": {"eye": [0, 2, 0], "target": [0, 0, 0], "up": [0, 0, -1]},
                   "focal_length": 50, "horizontal_aperture": 10, "vertical_aperture": 10},
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-5, -0.1, -5], "hi": [5, 0, 5]}}}],
        "lights": [dict(light, name=name)],
    }
    if "emissive_mesh" in light:  # a surface of emission 1 (black otherwise), no light
        s["materials"] = {"glow": {"type": "lambert", "albedo": [0, 0, 0], "emission": 1}}
        s["meshes"].append({"name": name, "shape": light["emissive_mesh"], "material": "glow"})
        s["lights"] = []
    return s


def render_json(a, sc, stem):
    """granular-render of scene sc (written to OUT/stem.json): (mean R, its s.e., the s.e. of
    one sample relative to the mean, render s)."""
    import granular_core as core
    path = os.path.join(a.out, stem + ".json")
    with open(path, "w") as f:
        json.dump(sc, f)
    exr, stats = os.path.join(a.out, stem + ".exr"), os.path.join(a.out, stem + ".stats.json")
    subprocess.run([os.path.join(a.build, "core", "granular-render"), path, "-o", exr, "--quiet",
                    "--stats-json", stats], check=True)
    img = core.read_exr(exr)
    px, ch = np.asarray(img.pixels), list(img.channels)
    mean = px[..., ch.index("R")].mean()
    se = np.sqrt(px[..., ch.index("variance.R")].sum()) / px[..., 0].size
    with open(stats) as f:
        t = json.load(f)["render_s"]
    return mean, se, se * np.sqrt(a.spp * px[..., 0].size) / mean, t


def render_usd_best_of_3(a, path, stem, channel):
    """`granular render` of the stage at path, 160 px wide, --grain-spp samples, three times:
    (best render s, mean of the channel, its s.e., the s.e. of one sample relative to the mean)."""
    import re
    import granular_core as core
    times = []
    for k in range(3):
        exr = os.path.join(a.out, f"{stem}_{k}.exr")
        r = subprocess.run([sys.executable, "-m", "granular.cli", "render", path, "-o", exr, "--width", "160",
                            "--spp", str(a.grain_spp), "--threads", "2"], capture_output=True, text=True, check=True,
                           env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path[:2])))
        times.append(float(re.search(r"\(render ([0-9.]+) s", r.stderr).group(1)))
    img = core.read_exr(exr)
    px = np.asarray(img.pixels)
    ch = list(img.channels)
    v, var = px[..., ch.index(channel)], px[..., ch.index("variance." + channel)]
    se = np.sqrt(var.sum()) / v.size
    return min(times), v.mean(), se, se * np.sqrt(a.grain_spp * v.size) / v.mean()


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "area_lights"))
    ap.add_argument("--lights", default=",".join(LIGHTS))
    ap.add_argument("--grain-spp", type=int, default=16, help="0: no grain scene table")
    ap.add_argument("--mesh-sizes", type=int, default=1, help="0: no table of mesh lights by triangle count")
    ap.add_argument("--many", type=int, default=1, help="0: no table of render time against the number of lights")
    a = ap.parse_args()
    sys.path[:0] = [os.path.join(a.build, "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    os.makedirs(a.out, exist_ok=True)
    print("| light | reference | render | bias % ± s.e. | s.e. per sample | render s |")
    print("|---|---|---|---|---|---|")
    for profile, (v, h, rows) in PROFILES.items():
        with open(os.path.join(a.out, profile + ".ies"), "w") as f:
            f.write(ies_text(v, h, rows))
    for name in a.lights.split(","):
        mean, se, per_sample, t = render_json(a, scene(name, a.width, a.spp), name)
        ref = reference(name)
        print(f"| {name} | {ref:.5f} | {mean:.5f} | {100 * (mean / ref - 1):+.2f} ± {100 * se / ref:.2f} "
              f"| {per_sample:.2f} | {t:.2f} |", flush=True)
    # Reading a profile: a fresh file each time (core reads one again only when it changes).
    print("\n| profile | angles (vertical × horizontal) | read and normalised, ms (best of 5) |")
    print("|---|---|---|")
    sizes = {"downlight": (DOWN_V, [0.0], DOWN_ROWS), "without symmetry": (ASYM_V, ASYM_H, ASYM_ROWS),
             "0.5° × 2.5° over the sphere": (np.arange(0, 180.01, 0.5), np.arange(0, 360.01, 2.5), None)}
    for label, (v, h, rows) in sizes.items():
        if rows is None:
            rows = [100 + 50 * np.sin(np.radians(v) * 3 + np.radians(x)) for x in h]
        best = float("inf")
        for k in range(5):
            path = os.path.join(a.out, f"load_{k}_{len(v)}x{len(h)}.ies")
            with open(path, "w") as f:
                f.write(ies_text(v, h, rows))
            t0 = time.perf_counter()
            core.read_ies_file(path)
            best = min(best, time.perf_counter() - t0)
        print(f"| {label} | {len(v)} × {len(h)} | {1000 * best:.1f} |", flush=True)
    if a.mesh_sizes:
        mesh_size_table(a)
    if a.many:
        many_lights_table(a)
    if a.grain_spp > 0:
        grain_table(a)
        spot_pick_table(a)
        softbox_table(a)


def unlit_sugarcube(path):
    """A new stage at path over examples/sugarcube.usda with its sun and sky off."""
    from pxr import Usd
    stage = Usd.Stage.CreateNew(path)
    stage.GetRootLayer().subLayerPaths.append(os.path.join(ROOT, "examples", "sugarcube.usda"))
    for prim in ("/World/Sun", "/World/Sky"):
        stage.OverridePrim(prim).SetActive(False)
    return stage


def softbox_table(a):
    """The sugar cube example with its sun and sky off, under a 4 cm square softbox 8 cm above
    it facing down: a mesh light (MeshLightAPI) against the same quad as an emissive
    UsdPreviewSurface of the same radiance, which only BSDF rays find; best of three."""
    from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade
    print("\n| sugar cube, 4 cm softbox | render s (best of 3) | mean G ± s.e. | s.e. per sample |")
    print("|---|---|---|---|")
    for label, as_light in (("mesh light (MeshLightAPI)", True), ("emissive surface", False)):
        path = os.path.join(a.out, f"softbox_{'light' if as_light else 'emissive'}.usda")
        stage = unlit_sugarcube(path)
        box = UsdGeom.Mesh.Define(stage, "/World/Softbox")
        box.CreatePointsAttr([(-0.02, 0.08, -0.02), (0.02, 0.08, -0.02), (0.02, 0.08, 0.02), (-0.02, 0.08, 0.02)])
        box.CreateFaceVertexCountsAttr([4])
        box.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        if as_light:
            UsdLux.MeshLightAPI.Apply(box.GetPrim())
            UsdLux.LightAPI(box.GetPrim()).CreateIntensityAttr(200.0)
        else:
            material = UsdShade.Material.Define(stage, "/World/Looks/Softbox")
            shader = UsdShade.Shader.Define(stage, "/World/Looks/Softbox/Surface")
            shader.CreateIdAttr("UsdPreviewSurface")
            shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.0))
            shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(200.0))
            material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
            UsdShade.MaterialBindingAPI.Apply(box.GetPrim()).Bind(material)
        stage.Save()
        t, mean, se, per_sample = render_usd_best_of_3(a, path, "softbox", "G")
        print(f"| {label} | {t:.2f} | {mean:.5f} ± {se:.5f} | {per_sample:.2f} |", flush=True)


def many_lights_table(a):
    """The floor lit by n small sphere lights (radius 0.02, or a third of their spacing) on a
    ring 0.6 from the view's centre, 0.3 above the floor, of equal total power: the render time as n grows (every ray asks the area
    lights: one by one, or through their BVH from Scene::kAreaLightBvhMin on)."""
    print("\n| sphere lights | mean | s.e. per sample | render s |")
    print("|---|---|---|---|")
    for n in (4, 16, 64, 256, 1024):
        r = min(0.02, 0.3 * np.pi * 0.6 / n)  # apart: a third of the spacing at most
        sc = scene("sphere", a.width, a.spp)
        sc["lights"] = [{"name": f"bulb{k}", "type": "sphere", "radius": r, "intensity": 64.0 / n * (0.02 / r) ** 2,
                         "position": [0.6 * np.cos(2 * np.pi * k / n), 0.3, 0.6 * np.sin(2 * np.pi * k / n)]}
                        for k in range(n)]
        mean, _, per_sample, t = render_json(a, sc, f"many_{n}")
        print(f"| {n} | {mean:.5f} | {per_sample:.2f} | {t:.2f} |", flush=True)


def mesh_size_table(a):
    """A ball of radius 0.1 as an icosphere mesh light of 80 to 20480 triangles, where the
    sphere light is: what its triangles cost (their BVH, picking one by area) against the
    sphere light, at the same samples."""
    print("\n| ball light | triangles | mean | s.e. per sample | render s |")
    print("|---|---|---|---|---|")
    rows = [("sphere light", None)] + [("icosphere mesh light", k) for k in (1, 3, 5)]
    for label, sub in rows:
        light = LIGHTS["sphere"][0] if sub is None else {
            "type": "mesh", "transform": {"translate": [0, 0.3, 0.4]},
            "shape": {"icosphere": {"radius": 0.1, "subdivisions": sub}}}
        sc = scene("sphere", a.width, a.spp)
        sc["lights"] = [dict(light, name="ball")]
        mean, _, per_sample, t = render_json(a, sc, f"ball_{sub}")
        tris = "—" if sub is None else str(20 * 4 ** sub)
        print(f"| {label} | {tris} | {mean:.5f} | {per_sample:.2f} | {t:.2f} |", flush=True)


def spot_pick_table(a):
    """examples/sugarcube_spot.usda with its sky at 0.4 (ten times the example's fill): how
    often light sampling picks the spot, and the noise per sample over the image and over
    the cube's lit top (the spot's beam)."""
    import re
    from pxr import Usd, UsdLux
    path = os.path.join(a.out, "sugarcube_spot_sky.usda")
    stage = Usd.Stage.CreateNew(path)
    stage.GetRootLayer().subLayerPaths.append(os.path.join(ROOT, "examples", "sugarcube_spot.usda"))
    UsdLux.DomeLight(stage.OverridePrim("/World/Sky")).CreateIntensityAttr(0.4)
    stage.Save()
    exr = os.path.join(a.out, "sugarcube_spot_sky.exr")
    r = subprocess.run([sys.executable, "-m", "granular.cli", "render", path, "-o", exr, "--width", "160",
                        "--spp", str(a.grain_spp), "--threads", "2"], capture_output=True, text=True, check=True,
                       env=dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path[:2])))
    picks = re.search(r"light sampling picks: (.*)", r.stderr).group(1)
    import granular_core as core
    img = core.read_exr(exr)
    px = np.asarray(img.pixels)
    ch = list(img.channels)
    lum, var = px[..., ch.index("G")], px[..., ch.index("variance.G")]

    def per_sample(region):
        m, v = lum[region], var[region]
        return np.sqrt(v.sum()) / m.size * np.sqrt(a.grain_spp * m.size) / m.mean()
    h, w = lum.shape
    top = (slice(int(0.36 * h), int(0.42 * h)), slice(int(0.42 * w), int(0.58 * w)))  # the cube's top face
    se = np.sqrt(var.sum()) / lum.size
    print("\n| sugar cube spot, sky 0.4 | light sampling picks | mean G ± s.e. | s.e. per sample, image "
          "| the cube's top |")
    print("|---|---|---|---|---|")
    print(f"| {a.grain_spp} spp, 160 px | {picks} | {lum.mean():.5f} ± {se:.5f} | "
          f"{per_sample((slice(None), slice(None))):.2f} | {per_sample(top):.2f} |", flush=True)


def grain_table(a):
    """The sugar cube under a shaped sphere light, without and with the downlight's profile."""
    from pxr import Gf, Sdf, UsdGeom, UsdLux
    print("\n| sugar cube, sphere light | render s (best of 3) | mean | s.e. per sample |")
    print("|---|---|---|---|")
    for label, profile in (("60° cone", None), ("60° cone and the downlight's profile", "down.ies")):
        path = os.path.join(a.out, f"sugarcube_{'ies' if profile else 'cone'}.usda")
        stage = unlit_sugarcube(path)
        bulb = UsdLux.SphereLight.Define(stage, "/World/Bulb")
        bulb.CreateRadiusAttr(0.005)
        bulb.CreateIntensityAttr(2000.0)
        UsdGeom.Xformable(bulb).AddTranslateOp().Set(Gf.Vec3d(0.01, 0.09, 0.0))
        UsdGeom.Xformable(bulb).AddRotateXOp().Set(-90.0)  # its -Z down
        shaping = UsdLux.ShapingAPI.Apply(bulb.GetPrim())
        shaping.CreateShapingConeAngleAttr(60.0)
        if profile:
            shaping.CreateShapingIesFileAttr(Sdf.AssetPath(os.path.join(a.out, profile)))
            shaping.CreateShapingIesNormalizeAttr(True)
        stage.Save()
        t, mean, _, per_sample = render_usd_best_of_3(a, path, "sugarcube", "R")
        print(f"| {label} | {t:.2f} | {mean:.4f} | {per_sample:.2f} |", flush=True)


if __name__ == "__main__":
    main()
