#!/usr/bin/env python3
"""Independent validation of our EPT and VPT against Mitsuba 3 (scalar_rgb).

Needs the `mitsuba` and `numpy` packages from PyPI, e.g. in a virtual environment that is
not part of the repository:

    /usr/bin/python3 -m venv .venv && .venv/bin/pip install mitsuba numpy
    .venv/bin/python bench/validate_mitsuba.py [--build build] [--renders 32] [--spp 32]

Cases (bench/scenes/validate_<case>.json):
  ept  validate_ept.json: ~500 explicit grains (two prototypes, two absorbing
       dielectrics) over a Lambert floor, a constant dome and a delta sun. Ours:
       `granular-render --technique ept`. Mitsuba: the grains exported by
       `granular-validate export` (prototype PLYs in their unit bounding spheres, one
       instance of a shapegroup per grain with its 4x4 matrix), `dielectric` BSDF with
       the same IOR, interior `homogeneous` medium of albedo 0 and σ_t = absorption / R
       (our absorption is per grain radius), integrator `volpathmis` (spectral MIS;
       `--integrator volpath` samples one hero channel, whose weights through the
       strongly chromatic grains make the red channel's per-pixel estimates skewed at
       this sample count: same mean, but per-pixel z-scores biased towards "ours
       brighter", see bench/README.md).
  ept_clear    the same with clear grains (absorption exactly 0) of IOR 2.4 and 1.33:
       long total-internal-reflection paths.
  ept_dof  validate_ept_dof.json: the ept scene through a thin lens focused in front of
       the grains; Mitsuba's `thinlens` sensor (aperture_radius, focus_distance).
  texture  validate_texture.json: a Lambert floor whose albedo is an sRGB PNG (a 16 x 16
       pattern of colour ramps, mirrored beyond its edges: st from -0.5 to 1.5) seen at
       an angle, texels 1 to 4 pixels wide, no grains. Mitsuba: `bitmap` (bilinear, the
       same wrap mode, sRGB decoded) on the exported quad's per-vertex uv.
  texture_flat  its control: the same floor with a constant albedo.
  ept_furnace  those clear grains alone under a white dome: every pixel is 1 in
       expectation (and, without Russian roulette, in every sample up to rounding).
  vpt  validate_vpt.json: the homogeneous medium our TT estimation derives for a ball of
       absorbing rock grains, bounded by the ball as an index-matched interface. Ours:
       `granular-validate vpt` (camera paths start in the media mode). Mitsuba: the
       boundary PLY with a `null` BSDF and an interior `homogeneous` medium with the
       exported σ_t and albedo per channel and a `tabphase` phase function.

Phase functions: ours is piecewise constant in μ = cos θ over B equal bins; Mitsuba's
tabphase is piecewise linear between values on a regular grid of μ in [-1, 1] (checked
here: its μ is ours, the cosine between the directions of travel in and out). We give it
a grid M = 32 times finer than our bins, with the bin's value at interior nodes and the
mean of the two neighbouring bins at each bin edge: the linear ramp then moves mass only
within ±1/M of a bin width around each edge and preserves every bin pair's total mass
exactly, so the two functions differ by a redistribution over 3% of each bin. Our
medium's phase differs per channel (absorption changes the exit distribution); tabphase
has one table for all channels, so Mitsuba renders the medium once per channel, each
time with that channel's table, and channel c of the image comes from render c.

Statistics: both renderers make K independent images (fixed seeds 1..K). For each side
the image mean (over pixels) of each render gives the mean of the image means and its
standard error; the table prints the relative difference of the two and its standard
error (delta method). Per pixel and channel, z = (ours − Mitsuba) / sqrt(se_ours² +
se_mitsuba²) with the standard errors from the K renders; the table summarises z
(mean, standard deviation, fractions beyond 2 and 3, largest |z|). Agreement within noise
means: relative difference within a few standard errors, z with mean ~0 and standard
deviation ~1 (slightly above 1 from the estimated variances: Student t with ~2(K−1) degrees
of freedom) and about 4.6% / 0.27% beyond 2 / 3.
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def mitsuba():
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    return mi


def rgb(v):
    return {"type": "rgb", "value": [float(x) for x in v]}


def tabphase_values(density, refine=32):
    """Node values of a piecewise-linear table reproducing a piecewise-constant one."""
    d = np.asarray(density, dtype=np.float64)
    bins = len(d)
    vals = []
    for j in range(bins * refine + 1):
        k, r = divmod(j, refine)
        if r == 0:  # a bin edge
            left = d[k - 1] if k > 0 else d[0]
            right = d[k] if k < bins else d[-1]
            vals.append(0.5 * (left + right))
        else:
            vals.append(d[k])
    return vals


def check_tabphase_convention(mi):
    """tabphase's first value must belong to back scattering (our μ = −1): a table that
    is zero except at μ = +1 must peak where the direction of travel does not change."""
    tab = mi.load_dict({"type": "tabphase", "values": "0, 0, 0, 1"})
    mei = mi.MediumInteraction3f()
    mei.wi = mi.Vector3f(0, 0, 1)  # Mitsuba: towards where the light came from
    mei.sh_frame = mi.Frame3f(mei.wi)
    ctx = mi.PhaseFunctionContext(None)
    forward = tab.eval_pdf(ctx, mei, mi.Vector3f(0, 0, -1))[1]  # travel continues along -z
    backward = tab.eval_pdf(ctx, mei, mi.Vector3f(0, 0, 1))[1]
    if not (forward > 0.4 and backward == 0):
        raise SystemExit(f"unexpected tabphase convention: forward {forward}, backward {backward}")


def medium_dict(sigma_t, albedo, phase=None):
    s = float(max(sigma_t))
    m = {"type": "homogeneous", "scale": s, "sigma_t": rgb([x / s for x in sigma_t]), "albedo": rgb(albedo)}
    if phase is not None:
        m["phase"] = {"type": "tabphase", "values": ", ".join(f"{v:.9g}" for v in phase)}
    return m


def mitsuba_scene(mi, exp, base, spp, case, integrator, phase_channel=0):
    cam = exp["camera"]
    to_world = np.array(cam["to_world"], dtype=np.float64).reshape(4, 4)
    # Ours looks down local -Z with +X right; Mitsuba's looks down +Z with +X left.
    to_world = to_world @ np.diag([-1.0, 1.0, -1.0, 1.0])
    lens = {"aperture_radius": cam["lens_radius"], "focus_distance": cam["focus_distance"]} if cam.get("lens_radius") else {}
    scene = {
        "type": "scene",
        # Our paths end at max_depth scattering events (Mitsuba counts the camera vertex
        # too: +1). No Russian roulette on Mitsuba's side: its q = min(throughput·η², 0.95)
        # kills 5% per bounce even in clear grains, and the 1/q weights of the rare
        # survivors of hundreds of total internal reflections give heavy-tailed pixels.
        "integrator": {"type": integrator, "max_depth": exp["max_depth"] + 1, "rr_depth": 1 << 30},
        "sensor": {
            "type": "perspective" if not cam.get("lens_radius") else "thinlens",
            "fov": cam["fov_x_deg"], "fov_axis": "x",
            "near_clip": cam["near"], "far_clip": cam["far"],
            "to_world": mi.ScalarTransform4f(to_world.tolist()),
            "film": {"type": "hdrfilm", "width": exp["width"], "height": exp["height"],
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent", "sample_count": spp},
            **lens,
        },
    }
    for i, l in enumerate(exp["lights"]):
        if l["type"] == "dome":
            scene[f"light{i}"] = {"type": "constant", "radiance": rgb(l["radiance"])}
        else:
            scene[f"light{i}"] = {"type": "directional", "direction": l["direction"], "irradiance": rgb(l["irradiance"])}
    mats = exp["materials"]

    def lambert(k):
        m = mats[k]
        if m["type"] != "lambert":
            raise SystemExit(f"mesh material {m['name']} is not lambert")
        if "albedo_texture" in m:
            t = m["albedo_texture"]
            return {"type": "diffuse", "reflectance": {"type": "bitmap", "filename": t["file"], "filter_type": "bilinear",
                                                       "wrap_mode": t["wrap"], "raw": t["raw"]}}
        return {"type": "diffuse", "reflectance": rgb(m["albedo"])}

    for i, m in enumerate(exp["meshes"]):
        scene[f"mesh{i}"] = {"type": "ply", "filename": os.path.join(base, m["ply"]), "face_normals": True,
                             "bsdf": lambert(m["material"])}
    for a, agg in enumerate(exp["aggregates"]):
        if case.startswith("vpt"):
            med = agg["medium"]
            scene[f"boundary{a}"] = {
                "type": "ply", "filename": os.path.join(base, agg["boundary_ply"]), "face_normals": True,
                "bsdf": {"type": "null"},
                "interior": medium_dict(med["sigma_t"], med["albedo"], tabphase_values(med["phase"][phase_channel]))}
            continue
        R = agg["grain_radius"]
        for p, proto in enumerate(agg["prototypes"]):
            m = mats[proto["material"]]
            if m["type"] != "dielectric":
                raise SystemExit(f"grain material {m['name']} is not a dielectric")
            bsdf = {"type": "dielectric", "int_ior": m["ior"], "ext_ior": 1.0}
            if m.get("ggx_alpha", 0) > 0:
                bsdf = {"type": "roughdielectric", "distribution": "ggx", "alpha": m["ggx_alpha"],
                        "sample_visible": True, "int_ior": m["ior"], "ext_ior": 1.0}
            shape = {"type": "ply", "filename": os.path.join(base, proto["ply"]), "face_normals": True, "bsdf": bsdf}
            if max(m["absorption"]) > 0:
                # Absorption is per unit of the prototype's space (grain radius): per world length it is a / R.
                shape["interior"] = medium_dict([x / R for x in m["absorption"]], [0.0, 0.0, 0.0])
            scene[f"proto{a}_{p}"] = {"type": "shapegroup", "grain": shape}
        for g, grain in enumerate(agg["grains"]):
            scene[f"grain{a}_{g}"] = {
                "type": "instance", "shapegroup": {"type": "ref", "id": f"proto{a}_{grain['prototype']}"},
                "to_world": mi.ScalarTransform4f(np.array(grain["matrix"]).reshape(4, 4).tolist())}
    return scene


def read_exr_rgb(mi, path):
    bmp = mi.Bitmap(path)
    chans = dict(bmp.split())
    if "R" in chans:
        return np.stack([np.array(chans[c], dtype=np.float64).reshape(bmp.height(), bmp.width()) for c in "RGB"], -1)
    return np.array(bmp, dtype=np.float64)[..., :3]


def render_ours(mi, args, case, scene_path, k, tmp):
    out = os.path.join(tmp, f"ours_{k}.exr")
    if not case.startswith("vpt"):
        cmd = [os.path.join(args.build, "core", "granular-render"), scene_path, "-o", out, "--technique", "ept",
               "--spp", str(args.spp), "--seed", str(k), "--quiet"]
    else:
        cmd = [os.path.join(args.build, "bench", "granular-validate"), "vpt", scene_path, out,
               "--spp", str(args.spp), "--seed", str(k)]
    subprocess.run(cmd, check=True)
    return read_exr_rgb(mi, out)


def render_mitsuba(mi, exp, base, args, case, k):
    if case.startswith("vpt"):
        phases = exp["aggregates"][0]["medium"]["phase"]
        same = all(np.allclose(phases[0], p) for p in phases[1:])
        if not same:
            img = None
            for c in range(3):
                scene = mi.load_dict(mitsuba_scene(mi, exp, base, args.spp, case, args.integrator, phase_channel=c))
                part = np.array(mi.render(scene, seed=k), dtype=np.float64)[..., :3]
                if img is None:
                    img = part.copy()
                img[..., c] = part[..., c]
            return img
    scene = mi.load_dict(mitsuba_scene(mi, exp, base, args.spp, case, args.integrator))
    return np.array(mi.render(scene, seed=k), dtype=np.float64)[..., :3]


def stats(a, b):
    """a, b: K x H x W x 3 stacks of independent renders."""
    K = a.shape[0]
    rows = {}
    for name, sel in (("R", 0), ("G", 1), ("B", 2), ("RGB", slice(None))):
        ma = a[..., sel].reshape(K, -1).mean(1)
        mb = b[..., sel].reshape(K, -1).mean(1)
        A, B = ma.mean(), mb.mean()
        sa, sb = ma.std(ddof=1) / np.sqrt(K), mb.std(ddof=1) / np.sqrt(K)
        rel = (A - B) / B
        se = np.sqrt(sa ** 2 + (A / B) ** 2 * sb ** 2) / B
        rows[name] = (A, sa, B, sb, rel, se)
    pa, pb = a.mean(0), b.mean(0)
    sa = a.std(0, ddof=1) / np.sqrt(K)
    sb = b.std(0, ddof=1) / np.sqrt(K)
    s = np.sqrt(sa ** 2 + sb ** 2)
    noisy = s > 0
    z = (pa - pb)[noisy] / s[noisy]
    exact = (~noisy).sum()
    exact_equal = np.abs(pa - pb)[~noisy].max() if exact else 0.0
    zs = dict(maxdiff=float(np.abs(pa - pb).max()), n=z.size, mean=z.mean(), std=z.std(), gt2=(np.abs(z) > 2).mean(), gt3=(np.abs(z) > 3).mean(),
              max=np.abs(z).max(), exact=int(exact), exact_maxdiff=float(exact_equal))
    return rows, zs


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build")
    ap.add_argument("--renders", type=int, default=32, help="independent renders per side (K)")
    ap.add_argument("--spp", type=int, default=32, help="samples per pixel of each render")
    ap.add_argument("--cases", default="ept,ept_clear,ept_furnace,vpt,ept_dof,ept_rough,texture,texture_flat")
    ap.add_argument("--out", default="out/validate")
    ap.add_argument("--integrator", default="volpathmis",
                    help="Mitsuba integrator: volpathmis (spectral MIS, default) or volpath (hero channel)")
    args = ap.parse_args()
    mi = mitsuba()
    check_tabphase_convention(mi)
    results = []
    for case in args.cases.split(","):
        scene_path = os.path.join(HERE, "scenes", f"validate_{case}.json")
        base = os.path.join(args.out, case)
        os.makedirs(base, exist_ok=True)
        subprocess.run([os.path.join(args.build, "bench", "granular-validate"), "export", scene_path, base], check=True)
        with open(os.path.join(base, "scene.json")) as f:
            exp = json.load(f)
        t0 = time.time()
        ours = np.stack([render_ours(mi, args, case, scene_path, k, base) for k in range(1, args.renders + 1)])
        t1 = time.time()
        theirs = np.stack([render_mitsuba(mi, exp, base, args, case, k) for k in range(1, args.renders + 1)])
        t2 = time.time()
        np.save(os.path.join(base, "ours.npy"), ours)
        np.save(os.path.join(base, "mitsuba.npy"), theirs)
        rows, zs = stats(ours, theirs)
        results.append((case, rows, zs, t1 - t0, t2 - t1))
        print(f"{case}: ours {t1 - t0:.1f} s, Mitsuba {t2 - t1:.1f} s", file=sys.stderr)

    K, spp = args.renders, args.spp
    print(f"## Validation against Mitsuba 3 `{args.integrator}` ({K} independent renders of {spp} spp per side)\n")
    print("| case | channel | ours (mean ± se) | Mitsuba (mean ± se) | relative difference ± se | difference / se |")
    print("|---|---|---|---|---|---|")
    for case, rows, zs, _, _ in results:
        for ch, (A, sa, B, sb, rel, se) in rows.items():
            print(f"| {case} | {ch} | {A:.5f} ± {sa:.5f} | {B:.5f} ± {sb:.5f} | {100 * rel:+.3f}% ± {100 * se:.3f}% | "
                  f"{rel / se:+.2f} |")
    print("\n| case | pixel-channels with noise | z mean | z std | \\|z\\|>2 | \\|z\\|>3 | max \\|z\\| | noiseless (max diff) | max pixel diff | time ours / Mitsuba (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for case, rows, zs, to, tm in results:
        print(f"| {case} | {zs['n']} | {zs['mean']:+.3f} | {zs['std']:.3f} | {100 * zs['gt2']:.2f}% | "
              f"{100 * zs['gt3']:.2f}% | {zs['max']:.2f} | {zs['exact']} ({zs['exact_maxdiff']:.2g}) | {zs['maxdiff']:.3g} | "
              f"{to:.0f} / {tm:.0f} |")


if __name__ == "__main__":
    main()
