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

Usage: .venv/bin/python bench/area_lights.py [--spp 1024] [--width 32] [--build build]
       [--out out/bench/area_lights] [--lights sphere,rect,disk,cylinder,spot]
"""
import argparse
import json
import os
import subprocess
import sys

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


def at(c):
    """A light at c whose local -Z (its emitting side) faces straight down."""
    return {"transform": {"translate": list(c), "rotate": [-90, 1, 0, 0]}}


SPOT = {"shaping_cone_angle": 20, "shaping_cone_softness": 0.5, "shaping_focus": 8, "shaping_focus_tint": 0.25}
LIGHTS = {
    "sphere": ({"type": "sphere", "position": [0, 0.3, 0.4], "radius": 0.1}, lambda: sphere_surface((0, 0.3, 0.4), 0.1)),
    "rect": ({"type": "rect", "width": 0.4, "height": 0.2, **at((0.0, 0.5, 0.45))},
             lambda: rect_surface((0.0, 0.5, 0.45), 0.4, 0.2)),
    "disk": ({"type": "disk", "radius": 0.3, **at((0.1, 1.0, 0.0))}, lambda: disk_surface((0.1, 1.0, 0.0), 0.3)),
    "cylinder": ({"type": "cylinder", "position": [0, 0.5, 0.5], "radius": 0.05, "length": 1},
                 lambda: cylinder_surface((0, 0.5, 0.5), 0.05, 1.0)),
    "spot": ({"type": "disk", "radius": 0.3, **at((0.1, 1.0, 0.0)), **SPOT}, lambda: disk_surface((0.1, 1.0, 0.0), 0.3)),
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
            if "shaping_cone_angle" in light:
                f = f * shaping(-w[:, 1] / d, cos_l, light)  # the axis: straight down
            total += 0.5 / np.pi * f.sum()
    return total / n ** 2


def scene(name, width, spp):
    light, _ = LIGHTS[name]
    return {
        "render": {"width": width, "height": width, "spp": spp, "technique": "ept"},
        "camera": {"look_at": {"eye": [0, 2, 0], "target": [0, 0, 0], "up": [0, 0, -1]},
                   "focal_length": 50, "horizontal_aperture": 10, "vertical_aperture": 10},
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-5, -0.1, -5], "hi": [5, 0, 5]}}}],
        "lights": [dict(light, name=name)],
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "area_lights"))
    ap.add_argument("--lights", default=",".join(LIGHTS))
    a = ap.parse_args()
    sys.path[:0] = [os.path.join(a.build, "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    os.makedirs(a.out, exist_ok=True)
    print("| light | reference | render | bias % ± s.e. | s.e. per sample | render s |")
    print("|---|---|---|---|---|---|")
    for name in a.lights.split(","):
        path = os.path.join(a.out, name + ".json")
        with open(path, "w") as f:
            json.dump(scene(name, a.width, a.spp), f)
        exr, stats = os.path.join(a.out, name + ".exr"), os.path.join(a.out, name + ".stats.json")
        subprocess.run([os.path.join(a.build, "core", "granular-render"), path, "-o", exr, "--quiet",
                        "--stats-json", stats], check=True)
        img = core.read_exr(exr)
        px = np.asarray(img.pixels)
        ch = list(img.channels)
        mean = px[..., ch.index("R")].mean()
        se = np.sqrt(px[..., ch.index("variance.R")].sum()) / px[..., 0].size
        ref = reference(name)
        per_sample = se * np.sqrt(a.spp * px[..., 0].size) / mean
        with open(stats) as f:
            t = json.load(f)["render_s"]
        print(f"| {name} | {ref:.5f} | {mean:.5f} | {100 * (mean / ref - 1):+.2f} ± {100 * se / ref:.2f} "
              f"| {per_sample:.2f} | {t:.2f} |", flush=True)


if __name__ == "__main__":
    main()
