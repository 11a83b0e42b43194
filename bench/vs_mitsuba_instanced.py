#!/usr/bin/env python3
"""Simulated grains against Mitsuba 3's explicit instancing, at equal error.

The heap of examples/make_grain_heap.py (a UsdGeomPointInstancer with
GranularInstancedAggregateAPI: round and rock prototypes, quartz grains, a ground card, a
camera, a 0.53° sun written at zero irradiance (`--sun 0`: lit by the sky) and a sky) is exported to Mitsuba 3 (scalar_rgb) as what our renderer
sees (core/granular_prims.h, core/instanced_grains.h, usd_reader.read_instanced_grains):

  - one `shapegroup` per prototype: its mesh as authored (outward, flat-shaded), a
    `dielectric` of the grain's IOR, inside a `homogeneous` medium of albedo 0 and
    σ_t = absorption / (prototype bounding radius at scale 1 × the instancer's scale), the
    schema's unit (schemas/README.md: absorption per the prototype's radius at scale 1);
  - one `instance` per grain: instancer-to-world · translate(position) · rotate(orientation)
    · scale(scale), USD's instance transform;
  - the ground as a Lambert (`diffuse`) mesh of its displayColor, the sky as `constant`, the
    sun as our renderer has it (light.cpp: radiance = intensity over a cone of the light's
    angle) — a one-sided emitting `disk` 10^4 units away subtending that angle, so that
    refracted paths can reach it as they can ours;
  - the camera's matrix times diag(−1, 1, −1) (Mitsuba looks down +Z with +X left), its
    horizontal field of view after the aperture is fitted inside the image (camera.cpp),
    a `box` filter; integrator `volpathmis` with our 4096 scattering events (+1 for
    Mitsuba's camera vertex) and no Russian roulette, as bench/validate_mitsuba.py
    validated it (`--mitsuba-rr-depth 5` gives Mitsuba's default roulette instead);
  - the whole scene 100 times larger on Mitsuba's side (--mitsuba-scale; σ_t divided by
    it: the same image). Mitsuba offsets every ray leaving a surface by RayEpsilon (1 +
    max |p|) along the normal: 0.9–1.9% of the 10^4 heap's grains (0.75–1 cm) at metre
    scale, which biased its heap by −0.26% (4 standard errors), −2.1% at scale 0.1; at
    scale 100 they are 0.1–0.7% of a grain. Scaling cannot bring them below
    RayEpsilon |p| / r, up to 3% at the edge of the 10^6 heap. Every ray that enters a
    grain starts that far inside it, so absorbing grains absorb less: Mitsuba renders
    quartz grains brighter than they are, the more the more they absorb and the farther
    from the origin (bench/README.md; --reference shows it).

Agreement (--check N, default 10^4 grains): K independent renders per side, fixed seeds.
Over the heap's pixels (our primId of the instancer) the mean per channel, and per 8x8 block
of pixels, with standard errors from the K renders; z = (ours − Mitsuba) / sqrt(se_o² +
se_m²). --reference adds the judge: granular-reference (bench/reference_double.cpp, double
precision, offsets 1e-9 grain radii) on the same scene (the export's ours.json), and the
same with Mitsuba's offset rule at Mitsuba's scale (--offset-rule 8.94e-5 --offset-scale
S); the sun is then off on every side (--no-sun: the reference takes delta suns only, and
this one gives 2e-4 of the sky's irradiance). --translate X,Y,Z moves the whole scene
(camera, heap, ground) on every side: ours renders in render space and must not change.
Both are layers over the heap's stage (variant_stage), which every side reads.

Speed (--grains): each side in fresh processes, one thread each. Mitsuba: one process per
heap, which builds its scene dictionary from the exported arrays, loads it (`load_dict`,
its BVHs), reports both times and the peak RSS after the load, then renders the spp ladder.
Ours: one `granular render --technique ept|hybrid --threads 1` process per ladder step; its
"render" figure is the time, its "read and built" line the set-up, /usr/bin/time the peak
RSS. relMSE over the heap's pixels and channels, (x − ref)² / (ref² + 0.01) (as
bench/instanced_hybrid.py), against our EPT at --ref-spp (all threads); the time to a target
relMSE is interpolated on log–log axes between the ladder steps around it.

Usage (from the repository root; Mitsuba in a separate, git-ignored venv):
    /usr/bin/python3 -m venv .venv-mitsuba && .venv-mitsuba/bin/pip install mitsuba numpy
    .venv/bin/python bench/vs_mitsuba_instanced.py [--check 10000] [--grains 100000,1000000]
        [--size 80x60] [--renders 16] [--check-spp 32] [--ref-spp 1024] [--targets 0.02,0.01]
        [--reference] [--translate X,Y,Z] [--no-sun] [--out out/bench/vs_mitsuba_instanced]
Prints markdown tables (progress to stderr).
"""
import argparse
import json
import math
import os
import re
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from instanced_hybrid import crossing  # noqa: E402  (one interpolation for both benches)

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SUN_DISTANCE = 1.0e4  # far enough that the heap sees the disk within 3e-3° of its direction


def log(*a):
    print(*a, file=sys.stderr, flush=True)


# ---- export (the project's interpreter: pxr, granular_core) ---------------------------------

def write_ply(path, points, indices):
    """Binary PLY of a triangle mesh (float32 vertices, int32 faces)."""
    points = np.asarray(points, dtype="<f4").reshape(-1, 3)
    faces = np.asarray(indices, dtype="<i4").reshape(-1, 3)
    with open(path, "wb") as f:
        f.write((f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\n"
                 "property float x\nproperty float y\nproperty float z\n"
                 f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n").encode())
        rec = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        rec["n"], rec["v"] = 3, faces
        f.write(points.tobytes())
        f.write(rec.tobytes())


def build_dir():
    return os.environ.get("GRANULAR_BUILD_DIR", os.path.join(ROOT, "build"))


def export(stage_path, width, height, out):
    """Writes out/scene.json, out/grains.npz and the PLYs: the stage as our renderer reads it;
    and out/ours.json, the same scene as our JSON scene (granular-render; granular-reference
    when the stage has no sun: it takes delta suns only)."""
    sys.path[:0] = [os.path.join(build_dir(), "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    from pxr import Gf, Usd, UsdGeom
    from granular import usd_reader

    scene = usd_reader.read_stage(stage_path, width=width, height=height)
    desc = scene.desc
    os.makedirs(out, exist_ok=True)
    cam = desc.camera
    ours = {"render": {"width": width, "height": height, "technique": "ept", "max_depth": desc.settings.max_depth,
                       "rr_depth": desc.settings.rr_depth, "physical_sun": desc.settings.physical_sun,
                       "sun_regularization": 0, "motion_blur": False},
            "camera": {"transform": np.asarray(cam.camera_to_world).ravel().tolist(),
                       "focal_length": cam.focal_length, "horizontal_aperture": cam.horizontal_aperture,
                       "vertical_aperture": cam.vertical_aperture, "clipping_range": [cam.clip_near, cam.clip_far]},
            "materials": {}, "meshes": [], "lights": []}
    # camera.cpp: the aperture fitted inside the image, extended along the longer axis.
    h_ap, v_ap = cam.horizontal_aperture, cam.vertical_aperture
    if width / height > h_ap / v_ap:
        h_ap = v_ap * width / height
    if cam.lens_radius > 0 or cam.horizontal_aperture_offset or cam.vertical_aperture_offset:
        raise SystemExit("the export handles a centred pinhole camera only")
    exp = {"width": width, "height": height, "max_depth": desc.settings.max_depth,
           "camera": {"to_world": np.asarray(cam.camera_to_world).tolist(),
                      "fov_x_deg": math.degrees(2.0 * math.atan(0.5 * h_ap / cam.focal_length)),
                      "near": cam.clip_near, "far": cam.clip_far},
           "lights": [], "meshes": [], "prototypes": []}
    for light in desc.lights:
        radiance = [c * light.intensity * 2.0 ** light.exposure for c in light.color]
        if light.type == core.LightType.Dome:
            if light.texture_file:
                raise SystemExit(f"{light.name}: a textured dome is not exported")
            exp["lights"].append({"type": "constant", "radiance": radiance})
            ours["lights"].append({"name": f"dome{len(ours['lights'])}", "type": "dome", "color": radiance,
                                   "intensity": 1.0})
        elif light.type == core.LightType.Distant:
            xf = np.asarray(light.xf)
            d = xf[:3, 2] / np.linalg.norm(xf[:3, 2])  # towards the sun (light.cpp: +Z of its frame)
            half = math.radians(0.5 * light.angle)
            if light.normalize:  # light.cpp normalizationArea: irradiance = intensity
                radiance = [c / (math.pi * math.sin(half) ** 2) for c in radiance]
            exp["lights"].append({"type": "sun", "direction": d.tolist(), "half_angle": half, "radiance": radiance})
            ours["lights"].append({"name": f"sun{len(ours['lights'])}", "type": "distant",
                                   "transform": xf.ravel().tolist(), "angle": light.angle, "color": list(light.color), "intensity": light.intensity,
                                   "exposure": light.exposure, "normalize": light.normalize})
        else:
            raise SystemExit(f"{light.name}: light type {light.type} is not exported")
    for i, m in enumerate(desc.meshes):
        mat = desc.materials[m.material]
        if mat.type != core.MaterialType.Lambert or mat.albedo_texture.enabled:
            raise SystemExit(f"{m.name}: only untextured Lambert meshes are exported")
        pts = np.asarray(m.mesh.points, dtype=np.float64)
        xf = np.asarray(m.xf)
        pts = pts @ xf[:3, :3].T + xf[:3, 3]
        ply = f"mesh{i}.ply"
        write_ply(os.path.join(out, ply), pts, np.asarray(m.mesh.indices))
        exp["meshes"].append({"name": m.name, "ply": ply, "albedo": list(mat.albedo)})
        ours["materials"][f"mesh{i}"] = {"type": "lambert", "albedo": list(mat.albedo)}
        ours["meshes"].append({"name": f"mesh{i}", "material": f"mesh{i}",
                               "shape": {"mesh": {"points": pts.tolist(),
                                                  "face_vertex_indices": np.asarray(m.mesh.indices).tolist()}}})

    # The instancer, read as usd_reader.read_instanced_grains hands it to core.
    stage = Usd.Stage.Open(stage_path)
    tc = usd_reader.stage_time(stage)
    xfc = UsdGeom.XformCache(tc)
    instancers = [p for p in stage.Traverse() if p.IsA(UsdGeom.PointInstancer)]
    if len(instancers) != 1:
        raise SystemExit(f"expected one PointInstancer, found {len(instancers)}")
    pi = UsdGeom.PointInstancer(instancers[0])
    inst_xf = np.array(xfc.GetLocalToWorldTransform(pi.GetPrim()), dtype=np.float64).T  # column vectors
    world_scale = abs(np.linalg.det(inst_xf[:3, :3])) ** (1.0 / 3.0)
    materials = {mt.name: mt for mt in desc.materials}
    protos = []
    for k, t in enumerate(pi.GetPrototypesRel().GetForwardedTargets()):
        prim = stage.GetPrimAtPath(t)
        if not Gf.IsClose(xfc.GetLocalTransformation(prim)[0], Gf.Matrix4d(1), 1e-12):
            raise SystemExit(f"{t}: prototype root transforms are not exported")
        mesh = UsdGeom.Mesh(prim)
        tri = core.mesh_from_usd(str(t), np.asarray(mesh.GetPointsAttr().Get(tc), np.float32),
                                 np.asarray(mesh.GetFaceVertexCountsAttr().Get(tc), np.int64),
                                 np.asarray(mesh.GetFaceVertexIndicesAttr().Get(tc), np.int64),
                                 np.zeros(0, np.int64), mesh.GetOrientationAttr().Get(tc))
        if tri.signed_volume() < 0:  # grain.cpp: prototypes are made outward
            tri.flip()
        # The prototype's bounding radius at scale 1 (grain.cpp fitRadius): one grain of scale 1.
        one = core.instanced_grains_desc("r", [tri], np.zeros((1, 3), np.float32), np.ones(1, np.float32),
                                         np.zeros(1, np.int64))
        fit_radius = core.build_grain_density(one).stats["mean_radius"]
        mat = materials[str(t)]
        if mat.type != core.MaterialType.Dielectric or mat.roughness > 0:
            raise SystemExit(f"{t}: only smooth dielectric grains are exported")
        ply = f"proto{k}.ply"
        write_ply(os.path.join(out, ply), np.asarray(tri.points), np.asarray(tri.indices))
        exp["prototypes"].append({"path": str(t), "ply": ply, "ior": mat.ior, "fit_radius": fit_radius,
                                  "sigma_t": [a / (fit_radius * world_scale) for a in mat.absorption]})
        ours["materials"][f"grain{k}"] = {"type": "dielectric", "ior": mat.ior, "absorption": list(mat.absorption)}
        protos.append({"name": f"grain{k}", "material": f"grain{k}",
                       "shape": {"mesh": {"points": np.asarray(tri.points, np.float64).tolist(),
                                          "face_vertex_indices": np.asarray(tri.indices).tolist()}}})
    pos = np.asarray(pi.GetPositionsAttr().Get(tc), np.float64)
    q = np.asarray(pi.GetOrientationsAttr().Get(tc), np.float64)[:, [3, 0, 1, 2]]  # (w, x, y, z)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scales = np.asarray(pi.GetScalesAttr().Get(tc), np.float64)
    if np.any(np.abs(scales - scales.max(1, keepdims=True)) > 1e-3 * scales.max(1, keepdims=True)):
        raise SystemExit("non-uniform scales are not exported")
    mask = pi.ComputeMaskAtTime(tc)
    if mask and not all(mask):
        raise SystemExit("invisibleIds/inactiveIds are not exported")
    np.savez(os.path.join(out, "grains.npz"), positions=pos, orientations=q, scales=scales.max(1),
             protos=np.asarray(pi.GetProtoIndicesAttr().Get(tc), np.int32), instancer=inst_xf)
    exp["grains"] = int(len(pos))
    with open(os.path.join(out, "scene.json"), "w") as f:
        json.dump(exp, f, indent=1)
    ours["instanced_grains"] = [{"name": "heap", "transform": inst_xf.ravel().tolist(), "prototypes": protos,
                                 "positions": pos.tolist(), "orientations": q.tolist(),
                                 "scales": scales.max(1).tolist(),
                                 "proto_indices": np.asarray(pi.GetProtoIndicesAttr().Get(tc), int).tolist()}]
    with open(os.path.join(out, "ours.json"), "w") as f:
        json.dump(ours, f)
    return exp


# ---- the Mitsuba side (run by the Mitsuba interpreter: --mitsuba-child) ---------------------

def grain_matrices(g):
    """instancer · T(p) · R(q) · S(s), (N, 4, 4)."""
    w, x, y, z = (g["orientations"][:, i] for i in range(4))
    r = np.empty((len(w), 3, 3))
    r[:, 0, 0] = 1 - 2 * (y * y + z * z); r[:, 0, 1] = 2 * (x * y - w * z); r[:, 0, 2] = 2 * (x * z + w * y)
    r[:, 1, 0] = 2 * (x * y + w * z); r[:, 1, 1] = 1 - 2 * (x * x + z * z); r[:, 1, 2] = 2 * (y * z - w * x)
    r[:, 2, 0] = 2 * (x * z - w * y); r[:, 2, 1] = 2 * (y * z + w * x); r[:, 2, 2] = 1 - 2 * (x * x + y * y)
    m = np.zeros((len(w), 4, 4))
    m[:, :3, :3] = r * g["scales"][:, None, None]
    m[:, :3, 3] = g["positions"]
    m[:, 3, 3] = 1
    return np.einsum("ij,njk->nik", g["instancer"], m)


def mitsuba_dict(mi, exp, base, spp, rr_depth, scale=1.0):
    """The export as a Mitsuba scene dictionary; `scale` enlarges the whole scene (lengths
    times scale, σ_t over it: the same image), which shrinks Mitsuba's ray offsets,
    RayEpsilon (1 + max |p|), against the grains."""
    def rgb(v):
        return {"type": "rgb", "value": [float(c) for c in v]}

    cam = exp["camera"]
    S = np.diag([scale, scale, scale, 1.0])
    to_world = np.asarray(cam["to_world"], np.float64) @ np.diag([-1.0, 1.0, -1.0, 1.0])
    to_world[:3, 3] *= scale
    scene = {
        "type": "scene",
        "integrator": {"type": "volpathmis", "max_depth": exp["max_depth"] + 1, "rr_depth": rr_depth},
        "sensor": {"type": "perspective", "fov": cam["fov_x_deg"], "fov_axis": "x", "near_clip": cam["near"] * scale,
                   "far_clip": cam["far"] * scale, "to_world": mi.ScalarTransform4f(to_world.tolist()),
                   "film": {"type": "hdrfilm", "width": exp["width"], "height": exp["height"],
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
    }
    for i, l in enumerate(exp["lights"]):
        if l["type"] == "constant":
            scene[f"light{i}"] = {"type": "constant", "radiance": rgb(l["radiance"])}
        else:
            d = np.asarray(l["direction"])
            c = d * SUN_DISTANCE * scale
            up = [0.0, 0.0, 1.0] if abs(d[2]) < 0.9 else [1.0, 0.0, 0.0]
            xf = mi.ScalarTransform4f().look_at(origin=c.tolist(), target=[0.0, 0.0, 0.0], up=up) @ \
                mi.ScalarTransform4f().scale([SUN_DISTANCE * scale * math.tan(l["half_angle"])] * 3)
            scene[f"light{i}"] = {"type": "disk", "to_world": xf, "emitter": {"type": "area", "radiance": rgb(l["radiance"])},
                                  "bsdf": {"type": "null"}}
    for i, m in enumerate(exp["meshes"]):
        scene[f"mesh{i}"] = {"type": "ply", "filename": os.path.join(base, m["ply"]), "face_normals": True,
                             "to_world": mi.ScalarTransform4f(S.tolist()),
                             "bsdf": {"type": "diffuse", "reflectance": rgb(m["albedo"])}}
    for k, p in enumerate(exp["prototypes"]):
        shape = {"type": "ply", "filename": os.path.join(base, p["ply"]), "face_normals": True,
                 "bsdf": {"type": "dielectric", "int_ior": p["ior"], "ext_ior": 1.0}}
        s = max(p["sigma_t"])
        if s > 0:
            shape["interior"] = {"type": "homogeneous", "scale": s / scale, "sigma_t": rgb([x / s for x in p["sigma_t"]]),
                                 "albedo": rgb([0.0, 0.0, 0.0])}
        scene[f"proto{k}"] = {"type": "shapegroup", "grain": shape}
    g = dict(np.load(os.path.join(base, "grains.npz")))
    mats = np.einsum("ij,njk->nik", S, grain_matrices(g))
    refs = [{"type": "ref", "id": f"proto{k}"} for k in range(len(exp["prototypes"]))]
    for i, (m, k) in enumerate(zip(mats, g["protos"])):
        scene[f"g{i}"] = {"type": "instance", "shapegroup": refs[k], "to_world": mi.ScalarTransform4f(m.tolist())}
    return scene


def mitsuba_child(job_path):
    """Runs a job (JSON: base, renders [[spp, seed]...], rr_depth, prefix; optionally ref and
    mask .npy, stop_below, max_step_s): loads the export, times the dictionary and the load,
    renders each step, stopping once a step's relMSE against ref is below stop_below or a
    step took max_step_s. Prints one JSON line."""
    import resource
    import drjit as dr
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    dr.set_thread_count(1)
    job = json.load(open(job_path))
    base = job["base"]
    exp = json.load(open(os.path.join(base, "scene.json")))
    t0 = time.monotonic()
    d = mitsuba_dict(mi, exp, base, 1, job["rr_depth"], job.get("scale", 1.0))
    t1 = time.monotonic()
    scene = mi.load_dict(d)
    del d
    t2 = time.monotonic()
    peak_load = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    ref = np.load(job["ref"]) if job.get("ref") else None
    heap = np.load(job["mask"]) if job.get("mask") else None
    renders = []
    for spp, seed in job["renders"]:
        t = time.monotonic()
        img = np.array(mi.render(scene, seed=seed, spp=spp), dtype=np.float32)[..., :3]
        step = {"spp": spp, "seed": seed, "render_s": time.monotonic() - t,
                "file": f"{job['prefix']}_{spp}_{seed}.npy"}
        np.save(step["file"], img)
        renders.append(step)
        if ref is not None:
            step["relmse"] = rel_mse(img.astype(np.float64), ref, heap)
            print(json.dumps(step), file=sys.stderr, flush=True)
            if step["relmse"] < job["stop_below"] or step["render_s"] > job["max_step_s"]:
                break
    print(json.dumps({"dict_s": t1 - t0, "load_s": t2 - t1, "peak_after_load_mib": peak_load,
                      "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "renders": renders}))


# ---- driving both sides ---------------------------------------------------------------------

def timed(cmd):
    """Runs cmd under /usr/bin/time -v: (stdout + stderr, wall s, peak RSS MiB)."""
    t = time.monotonic()
    r = subprocess.run(["/usr/bin/time", "-v"] + cmd, capture_output=True, text=True)
    wall = time.monotonic() - t
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stdout}\n{r.stderr}")
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    return r.stdout + r.stderr, wall, int(m.group(1)) / 1024 if m else float("nan")


def run_mitsuba(args, base, job):
    job = dict(job, base=base, rr_depth=args.mitsuba_rr_depth, scale=args.mitsuba_scale)
    path = job["prefix"] + "_job.json"
    with open(path, "w") as f:
        json.dump(job, f)
    out, wall, peak = timed([args.mitsuba_python, os.path.abspath(__file__), "--mitsuba-child", path])
    res = json.loads([s for s in out.splitlines() if s.startswith('{"dict_s"')][-1])
    res["process_peak_mib"], res["wall_s"] = peak, wall
    return res


def render_ours(args, stage, out, size, spp, technique, seed, threads=1):
    w, h = size
    text, wall, peak = timed([args.granular, "render", stage, "-o", out, "--width", str(w), "--height", str(h),
                              "--spp", str(spp), "--technique", technique, "--seed", str(seed),
                              "--threads", str(threads)])
    render = float(re.search(r"render ([\d.]+) s", text).group(1))
    built = re.search(r"built in ([\d.]+) s", text)
    return {"render_s": render, "setup_s": float(built.group(1)) if built else float("nan"), "wall_s": wall,
            "peak_mib": peak}


def load_ours(path):
    import granular_core as core
    im = core.read_exr(path)
    px = np.asarray(im.pixels, dtype=np.float64)
    ch = list(im.channels)
    return px[..., [ch.index(c) for c in "RGB"]], px[..., ch.index("primId")] if "primId" in ch else None


def rel_mse(img, ref, heap):
    return float((((img - ref) ** 2) / (ref ** 2 + 0.01))[heap].mean())


def heap_stage(args, n):
    stage = os.path.join(args.out, f"heap_{n}.usdc")
    if not os.path.exists(stage):
        subprocess.run([args.python, os.path.join(ROOT, "examples", "make_grain_heap.py"), stage, "--grains", str(n),
                        "--frames", "1", "--sun", "0"], check=True, capture_output=True)
    return stage


def variant_stage(args, n):
    """The heap, or a layer over it that moves the whole of /World by --translate and turns
    the sun off (--no-sun, --reference): both renderers read the same variant."""
    stage = heap_stage(args, n)
    if not args.translate and not args.no_sun:
        return stage
    t = [float(v) for v in (args.translate or "0,0,0").split(",")]
    name = f"heap_{n}_t{'_'.join(f'{v:g}' for v in t)}{'_nosun' if args.no_sun else ''}"
    path = os.path.join(args.out, name + ".usda")
    ops = (f"        double3 xformOp:translate = ({t[0]!r}, {t[1]!r}, {t[2]!r})\n"
           f"        uniform token[] xformOpOrder = [\"xformOp:translate\"]\n") if any(t) else ""
    sun = '        over "Sun" (active = false)\n        {\n        }\n' if args.no_sun else ""
    with open(path, "w") as f:
        f.write(f'#usda 1.0\n(\n    defaultPrim = "World"\n    subLayers = [@./{os.path.basename(stage)}@]\n)\n\n'
                f'over "World"\n{{\n{ops}{sun}}}\n')
    return path


REFERENCE_EPS = 8.94e-5  # Mitsuba 3's RayEpsilon in single precision (granular-reference --offset-rule)


def render_reference(args, base, spp, seed, offsets):
    """granular-reference on the export's ours.json; offsets: Mitsuba's rule at its scale."""
    out = os.path.join(base, f"ref_{'mitsuba_offsets' if offsets else 'exact'}_{spp}_{seed}.exr")
    cmd = [args.reference_bin, "render", os.path.join(base, "ours.json"), out, "--spp", str(spp), "--seed", str(seed),
           "--threads", str(args.threads), "--stats-json", out + ".stats.json"]
    if offsets:
        cmd += ["--offset-rule", str(REFERENCE_EPS), "--offset-scale", str(args.mitsuba_scale)]
    subprocess.run(cmd, check=True, capture_output=True)
    stats = json.load(open(out + ".stats.json"))
    if stats["inconsistent"]:
        raise SystemExit(f"{out}: {stats['inconsistent']} rays crossed a grain against their inside/outside state")
    return load_ours(out)[0]


def compare(ours, theirs, heap):
    """Per channel and over RGB: heap means of two sets of K renders, their standard errors,
    the relative difference ours / theirs − 1 and its z-score."""
    K = len(ours)
    rows = []
    for name, sel in (("R", [0]), ("G", [1]), ("B", [2]), ("RGB", [0, 1, 2])):
        a = ours[..., sel][:, heap].mean(axis=(1, 2))
        b = theirs[..., sel][:, heap].mean(axis=(1, 2))
        A, B = a.mean(), b.mean()
        sa, sb = a.std(ddof=1) / math.sqrt(K), b.std(ddof=1) / math.sqrt(len(theirs))
        rows.append((name, A, sa, B, sb, (A - B) / B, math.sqrt(sa ** 2 + (A / B) ** 2 * sb ** 2) / B,
                     (A - B) / math.hypot(sa, sb)))
    return rows


def agreement(args, n, size):
    """K renders per side at --check-spp: heap means per channel and 8x8 blocks, z-scores;
    with --reference also granular-reference's, exact and with Mitsuba's ray offsets."""
    stage = variant_stage(args, n)
    base = os.path.join(args.out, "mi_" + os.path.splitext(os.path.basename(stage))[0][len("heap_"):])
    exp = export(stage, size[0], size[1], base)
    K, spp = args.renders, args.check_spp
    log(f"agreement at {exp['grains']} grains ({os.path.basename(stage)}): {K} renders x {spp} spp per side")
    ours, prim = [], None
    for k in range(1, K + 1):
        path = os.path.join(base, f"ours_check_{k}.exr")
        render_ours(args, stage, path, size, spp, "ept", k, threads=args.threads)
        img, prim = load_ours(path)
        ours.append(img)
    ours = np.stack(ours)
    heap = prim == 1
    out = {"grains": exp["grains"], "stage": os.path.basename(stage), "heap_pixels": int(heap.sum()), "pairs": []}
    theirs = None
    if not args.reference_only:
        out["mitsuba"] = run_mitsuba(args, base, {"renders": [[spp, k] for k in range(1, K + 1)],
                                                  "prefix": os.path.join(base, "mi_check")})
        theirs = np.stack([np.load(os.path.join(base, f"mi_check_{spp}_{k}.npy"))
                           for k in range(1, K + 1)]).astype(np.float64)
        out["pairs"].append(("ours EPT", "Mitsuba", compare(ours, theirs, heap)))
    if args.reference:
        log(f"  granular-reference, exact and with Mitsuba's offsets at scale {args.mitsuba_scale:g}")
        exact = np.stack([render_reference(args, base, spp, k, False) for k in range(1, K + 1)])
        offs = np.stack([render_reference(args, base, spp, k, True) for k in range(1, K + 1)])
        out["pairs"].append(("ours EPT", "reference", compare(ours, exact, heap)))
        if theirs is not None:
            out["pairs"].append(("Mitsuba", "reference", compare(theirs, exact, heap)))
        out["pairs"].append(("reference with Mitsuba's offsets", "reference", compare(offs, exact, heap)))
        if theirs is not None:
            out["pairs"].append(("Mitsuba", "reference with Mitsuba's offsets", compare(theirs, offs, heap)))
    # 8x8 blocks holding at least 32 heap pixels: each channel's heap mean, ours against Mitsuba.
    z = []
    if theirs is None:
        out["z"] = np.asarray(z)
        return out
    H, W = heap.shape
    for y in range(0, H - 7, 8):
        for x in range(0, W - 7, 8):
            m = heap[y:y + 8, x:x + 8]
            if m.sum() < 32:
                continue
            for c in range(3):
                a = ours[:, y:y + 8, x:x + 8, c][:, m].mean(1)
                b = theirs[:, y:y + 8, x:x + 8, c][:, m].mean(1)
                z.append((a.mean() - b.mean()) / math.hypot(a.std(ddof=1) / math.sqrt(K), b.std(ddof=1) / math.sqrt(K)))
    out["z"] = np.asarray(z)
    return out


def speed(args, n, size, targets):
    stage = heap_stage(args, n)
    base = os.path.join(args.out, f"mi_{n}")
    exp = export(stage, size[0], size[1], base)
    log(f"speed at {exp['grains']} grains")
    ref_path = os.path.join(base, f"ref_ept_{args.ref_spp}.exr")
    if not os.path.exists(ref_path):
        log(f"  reference: our EPT at {args.ref_spp} spp")
        render_ours(args, stage, ref_path, size, args.ref_spp, "ept", 1000, threads=args.threads)
    ref, prim = load_ours(ref_path)
    heap = prim == 1
    floor = min(targets)
    ladders, setup = {}, {}
    for technique in ("ept", "hybrid"):
        ladders[technique] = []
        for spp in args.spp:
            out = os.path.join(base, f"ours_{technique}_{spp}.exr")
            r = render_ours(args, stage, out, size, spp, technique, 1)
            setup.setdefault(technique, r)
            img, _ = load_ours(out)
            e = rel_mse(img, ref, heap)
            ladders[technique].append((r["render_s"], e))
            log(f"  ours {technique} {spp} spp: {r['render_s']:.2f} s, relMSE {e:.4g}, heap mean "
                f"{100 * (img[heap].mean() / ref[heap].mean() - 1):+.2f}%")
            if e < 0.8 * floor:
                break
    # Mitsuba: one process, the ladder after one load, stopped once below the targets.
    np.save(os.path.join(base, "ref.npy"), ref)
    np.save(os.path.join(base, "heap.npy"), heap)
    mres = run_mitsuba(args, base, {"renders": [[spp, 1] for spp in args.spp], "prefix": os.path.join(base, "mi"),
                                    "ref": os.path.join(base, "ref.npy"), "mask": os.path.join(base, "heap.npy"),
                                    "stop_below": 0.8 * floor, "max_step_s": args.max_mitsuba_s})
    ladders["mitsuba"] = []
    for s in mres["renders"]:
        img = np.load(s["file"]).astype(np.float64)
        e = rel_mse(img, ref, heap)
        ladders["mitsuba"].append((s["render_s"], e))
        log(f"  Mitsuba {s['spp']} spp: {s['render_s']:.2f} s, relMSE {e:.4g}, heap mean "
            f"{100 * (img[heap].mean() / ref[heap].mean() - 1):+.2f}%")
    log(f"  Mitsuba dictionary {mres['dict_s']:.2f} s, load {mres['load_s']:.2f} s, peak after load "
        f"{mres['peak_after_load_mib']:.0f} MiB, process peak {mres['process_peak_mib']:.0f} MiB")
    return {"grains": exp["grains"], "ladders": ladders, "setup": setup, "mitsuba": mres}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--mitsuba-child", metavar="JOB.json", help=argparse.SUPPRESS)
    ap.add_argument("--check", type=int, default=10000, help="grains of the agreement check (0: none)")
    ap.add_argument("--grains", default="100000,1000000", help="heaps of the speed comparison ('': none)")
    ap.add_argument("--size", default="80x60")
    ap.add_argument("--renders", type=int, default=16, help="independent renders per side of the check")
    ap.add_argument("--check-spp", type=int, default=32)
    ap.add_argument("--ref-spp", type=int, default=1024, help="samples of our EPT reference")
    ap.add_argument("--spp", default="1,2,4,8,16,32,64,128", help="the ladder")
    ap.add_argument("--targets", default="0.02,0.01")
    ap.add_argument("--threads", type=int, default=2, help="threads of the check's and the reference's renders")
    ap.add_argument("--max-mitsuba-s", type=float, default=120.0, help="stop Mitsuba's ladder after a step this long")
    ap.add_argument("--mitsuba-rr-depth", type=int, default=1 << 30,
                    help="Mitsuba's Russian roulette start (default: none, as validate_mitsuba.py)")
    ap.add_argument("--mitsuba-scale", type=float, default=100.0,
                    help="render Mitsuba's scene this many times larger (same image; smaller ray offsets)")
    ap.add_argument("--translate", default="", metavar="X,Y,Z",
                    help="move the whole scene (a layer over the heap's stage): Mitsuba's offsets grow with |p|")
    ap.add_argument("--no-sun", action="store_true", help="the sun off on every side (a layer over the stage)")
    ap.add_argument("--reference-only", action="store_true",
                    help="the check without Mitsuba: ours against granular-reference (implies --reference)")
    ap.add_argument("--reference", action="store_true",
                    help="the check also renders granular-reference, exact and with Mitsuba's ray offsets (implies "
                         "--no-sun: the reference takes delta suns only)")
    ap.add_argument("--mitsuba-python", default=os.path.join(ROOT, ".venv-mitsuba", "bin", "python"))
    ap.add_argument("--granular", default=os.path.join(os.path.dirname(sys.executable), "granular"))
    ap.add_argument("--reference-bin", default=os.path.join(build_dir(), "bench", "granular-reference"),
                    help="granular-reference (default: GRANULAR_BUILD_DIR or build/, bench/)")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "vs_mitsuba_instanced"))
    args = ap.parse_args()
    if args.mitsuba_child:
        mitsuba_child(args.mitsuba_child)
        return
    args.python = sys.executable
    args.spp = [int(s) for s in args.spp.split(",")]
    if not os.path.exists(args.mitsuba_python):
        raise SystemExit(f"no Mitsuba interpreter at {args.mitsuba_python} (see the usage above)")
    args.reference = args.reference or args.reference_only
    if args.reference:
        args.no_sun = True
        if not os.path.exists(args.reference_bin):
            raise SystemExit(f"no granular-reference at {args.reference_bin} (cmake --build build --target "
                             "granular-reference)")
    os.makedirs(args.out, exist_ok=True)
    size = tuple(int(v) for v in args.size.split("x"))
    targets = [float(t) for t in args.targets.split(",")]

    if args.check:
        a = agreement(args, args.check, size)
        z = a["z"]
        print(f"### Agreement at {a['grains']} grains ({a['stage']}, {size[0]}x{size[1]}, {a['heap_pixels']} heap "
              f"pixels, {args.renders} renders x {args.check_spp} spp per side, Mitsuba at scale "
              f"{args.mitsuba_scale:g})\n")
        print("| A | B | channel | A (mean ± se) | B (mean ± se) | A / B − 1 ± se | difference / se |")
        print("|---|---|---|---|---|---|---|")
        for na, nb, rows in a["pairs"]:
            for name, A, sa, B, sb, rel, se, zz in rows:
                print(f"| {na} | {nb} | {name} | {A:.5f} ± {sa:.5f} | {B:.5f} ± {sb:.5f} | {100 * rel:+.2f}% ± "
                      f"{100 * se:.2f}% | {zz:+.2f} |")
        if z.size:
            print(f"\n8x8 blocks (≥ 32 heap pixels), ours against Mitsuba, per channel: {z.size} z-scores, mean "
                  f"{z.mean():+.3f}, std {z.std():.3f}, |z|>2 {100 * (np.abs(z) > 2).mean():.1f}%, |z|>3 "
                  f"{100 * (np.abs(z) > 3).mean():.1f}%, max |z| {np.abs(z).max():.2f}\n")
    rows = []
    for n in [int(float(g)) for g in args.grains.split(",") if g]:
        rows.append(speed(args, n, size, targets))
    if rows:
        rr = "no Russian roulette" if args.mitsuba_rr_depth >= 1 << 30 else f"rr_depth {args.mitsuba_rr_depth}"
        print(f"### Equal error ({size[0]}x{size[1]}, one thread each, relMSE over the heap's pixels against our "
              f"EPT at {args.ref_spp} spp; Mitsuba 3 scalar_rgb volpathmis, {rr})\n")
        print("| grains | Mitsuba dict + load (s) | Mitsuba peak RSS (MiB) | ours set-up EPT / hybrid (s) | "
              "ours peak RSS EPT / hybrid (MiB) | target | Mitsuba (s) | ours EPT (s) | ours hybrid (s) | "
              "EPT speed-up | hybrid speed-up |")
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        fmt = lambda x: "not reached" if x is None else f"{x:.2f}"
        for r in rows:
            m, s = r["mitsuba"], r["setup"]
            for t in targets:
                tm, te, th = (crossing(r["ladders"][k], t) for k in ("mitsuba", "ept", "hybrid"))
                print(f"| {r['grains']:.3g} | {m['dict_s']:.1f} + {m['load_s']:.1f} | {m['process_peak_mib']:.0f} | "
                      f"{s['ept']['setup_s']:.2f} / {s['hybrid']['setup_s']:.2f} | {s['ept']['peak_mib']:.0f} / "
                      f"{s['hybrid']['peak_mib']:.0f} | {t} | {fmt(tm)} | {fmt(te)} | {fmt(th)} | "
                      f"{f'{tm / te:.1f}x' if tm and te else '-'} | {f'{tm / th:.1f}x' if tm and th else '-'} |")
        print("\nLadders (render s, relMSE):")
        for r in rows:
            for k, lad in r["ladders"].items():
                print(f"- {r['grains']:.3g} {k}: " + ", ".join(f"({t:.2f}, {e:.3g})" for t, e in lad))


if __name__ == "__main__":
    main()
