#!/usr/bin/env python3
"""Which renderer is right at small grains: our EPT, Mitsuba 3's explicit instancing, or
neither? Judged by `granular-reference` (bench/reference_double.cpp), a brute-force path
tracer in double precision of the same grains.

The scene is vs_explicit.py's: bench/scenes/validate_ept.json with the grain radius shrunk
so that the ball holds about N grains. Per N, K independent renders (seeds B+1..B+K,
B = --seed-base) each of
  ours       `granular-render --technique ept --threads 1`;
  reference  `granular-reference render --threads 1`;
  Mitsuba    (when the `mitsuba` package imports here or in .venv-mitsuba) the grains
             exported by `granular-validate export`, rendered as vs_explicit.py and
             validate_mitsuba.py build them (scalar_rgb, volpathmis, one thread), loaded
             once per N.
Each render's mean RGB over the ball mask (`granular-reference mean`: pixels whose centre
and four corners see the ball's boundary mesh) is one sample; the table gives each
renderer's mean of the K samples, its standard error, and the differences in standard
errors. Every process runs under `nice -n 10` on one thread.

Usage: python3 bench/reference_small_grains.py [--build build] [--grains 1e4,1e5,1e6]
           [--renders 16] [--spp 64] [--seed-base 0] [--size 64x48]
           [--out out/bench/reference_small_grains] [--no-mitsuba] [--furnace]
           [--mitsuba-offsets] [--selftest]
--furnace adds a table of the same balls with clear grains under a white dome (1 exactly,
but for paths cut at the maximum depth): whether a renderer creates or loses energy at the
interfaces alone.
--mitsuba-offsets adds the reference with Mitsuba's ray offsets, RayEpsilon (1 + max |p|)
along the normal instead of 1e-9 grain radii: whether those offsets explain Mitsuba.
--selftest checks the reference alone instead (a few seconds): its unit checks
(`granular-reference selftest`: Fresnel, chords of a box grain against slabs, Beer–Lambert,
a one-grain furnace), the ball of 10^5 clear grains under a white dome (every pixel exactly
1, no leak), and a Lambert floor under the dome and the delta sun (ρ (L_dome + E cos θ / π)
exactly where the floor is seen).
"""
import argparse
import json
import math
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from vs_explicit import ball_scene  # noqa: E402

NICE = ["nice", "-n", "10"]
# Mitsuba 3's spawn_ray offsets a new ray's origin by RayEpsilon (1 + max |p|) along the
# normal (mi.math.RayEpsilon, 3.9.1); the reference can do the same (--offset-rule).
MITSUBA_RAY_EPSILON = 8.940696716308594e-05
OFFSETS = "reference with Mitsuba's offsets"

# Run in the interpreter that has mitsuba: load the exported grains once, render K seeds.
MITSUBA_CHILD = r"""
import sys
import numpy as np
sys.path.insert(0, {here!r})
import json, validate_mitsuba as vm
import drjit as dr
mi = vm.mitsuba()
dr.set_thread_count(1)
base, spp, first, last = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
exp = json.load(open(base + "/scene.json"))
scene = mi.load_dict(vm.mitsuba_scene(mi, exp, base, spp, "ept", "volpathmis"))
imgs = [np.array(mi.render(scene, seed=k), dtype=np.float32)[..., :3] for k in range(first, last + 1)]
dr.set_thread_count(2)  # Bitmap.write never returns with a one-thread pool (Mitsuba 3.9.1)
for k, img in enumerate(imgs, first):
    mi.Bitmap(np.ascontiguousarray(img)).write(base + "/mitsuba_%d.exr" % k)
"""


def run(cmd, **kw):
    return subprocess.run(NICE + cmd, check=True, text=True, capture_output=True, **kw)


def mitsuba_python(disabled):
    """An interpreter that imports mitsuba: this one, else .venv-mitsuba's; or None."""
    if disabled:
        return None
    for py in (sys.executable, os.path.join(ROOT, ".venv-mitsuba", "bin", "python")):
        if os.path.exists(py) and subprocess.run([py, "-c", "import mitsuba, numpy"], capture_output=True).returncode == 0:
            return py
    return None


def tool(args, name):
    sub = "core" if name == "granular-render" else "bench"
    return os.path.join(args.build, sub, name)


def region_means(args, scene_path, files):
    """Mean RGB over the ball mask of each image, averaged over the channels."""
    out = run([tool(args, "granular-reference"), "mean", scene_path] + files).stdout
    rows = [json.loads(line) for line in out.splitlines() if line.strip()]
    return [sum(r["mean"]) / 3.0 for r in rows], rows[0]["pixels"]


def mean_se(xs):
    m = sum(xs) / len(xs)
    var = sum((x - m) ** 2 for x in xs) / (len(xs) - 1)
    return m, math.sqrt(var / len(xs))


def furnace_scene(n):
    """The ball of clear grains alone under a white dome: every path returns exactly 1."""
    scene = ball_scene(n)
    for m in scene["materials"].values():
        m.pop("absorption", None)
    scene["meshes"] = []
    scene["lights"] = [{"name": "white", "type": "dome", "color": [1, 1, 1], "intensity": 1.0}]
    return scene


def render_n(args, n, mpy, furnace=False):
    w, h = args.width, args.height
    base = os.path.join(args.out, f"{'furnace_' if furnace else ''}n{n:.0e}")
    os.makedirs(base, exist_ok=True)
    scene = furnace_scene(n) if furnace else ball_scene(n)
    scene["render"].update(width=w, height=h, spp=args.spp)
    scene_path = os.path.join(base, "input.json")
    json.dump(scene, open(scene_path, "w"))
    R = scene["aggregates"][0]["grain_radius"]
    files = {"ours": [], "reference": [], "Mitsuba": [], OFFSETS: []}
    stats = []
    seeds = [args.seed_base + k for k in range(1, args.renders + 1)]
    for k in seeds:
        print(f"N {n:.0e}: seed {k} of {seeds[0]}..{seeds[-1]}", file=sys.stderr, flush=True)
        f = os.path.join(base, f"ours_{k}.exr")
        run([tool(args, "granular-render"), scene_path, "-o", f, "--technique", "ept", "--threads", "1",
             "--spp", str(args.spp), "--seed", str(k), "--width", str(w), "--height", str(h), "--quiet"])
        files["ours"].append(f)
        f, sj = os.path.join(base, f"reference_{k}.exr"), os.path.join(base, f"reference_{k}.json")
        run([tool(args, "granular-reference"), "render", scene_path, f, "--threads", "1", "--spp", str(args.spp),
             "--seed", str(k), "--width", str(w), "--height", str(h), "--stats-json", sj])
        files["reference"].append(f)
        stats.append(json.load(open(sj)))
        if args.mitsuba_offsets:
            f = os.path.join(base, f"reference_mioffsets_{k}.exr")
            run([tool(args, "granular-reference"), "render", scene_path, f, "--threads", "1", "--spp", str(args.spp),
                 "--seed", str(k), "--width", str(w), "--height", str(h), "--offset-rule", str(MITSUBA_RAY_EPSILON)])
            files[OFFSETS].append(f)
    if mpy:
        print(f"N {n:.0e}: Mitsuba (export, load once, {args.renders} renders)", file=sys.stderr, flush=True)
        run([tool(args, "granular-validate"), "export", scene_path, base])
        run([mpy, "-c", MITSUBA_CHILD.format(here=HERE), base, str(args.spp), str(seeds[0]), str(seeds[-1])],
            timeout=3600)
        files["Mitsuba"] = [os.path.join(base, f"mitsuba_{k}.exr") for k in seeds]
    res, worst, pixels = {}, {}, 0
    for name, fs in files.items():
        if fs:
            xs, pixels = region_means(args, scene_path, fs)
            res[name] = mean_se(xs)
            worst[name] = max(abs(x - 1.0) for x in xs)
    bad = sum(s["inconsistent"] for s in stats)
    if bad:
        raise SystemExit(f"N {n:.0e}: the reference counted {bad} inconsistent crossings (a leak)")
    return dict(n=n, grains=stats[0]["grains"], R=R, pixels=pixels, res=res, worst=worst,
                truncated=sum(s["truncated"] for s in stats), paths=len(stats) * w * h * args.spp,
                ref_s=sum(s["render_s"] for s in stats) / len(stats),
                rays=sum(s["rays"] for s in stats), mesh_inside=sum(s["mesh_inside_grain"] for s in stats))


def stats_max_depth():
    return ball_scene(1e3)["render"].get("max_depth", 1 << 16)


def diff(a, b):
    """(a − b) / b in percent, its standard error, and the difference in standard errors."""
    (ma, sa), (mb, sb) = a, b
    s = math.hypot(sa, sb)
    return 100.0 * (ma - mb) / mb, 100.0 * s / mb, (ma - mb) / s if s > 0 else float("nan")


def selftest(args):
    ok = subprocess.run([tool(args, "granular-reference"), "selftest"]).returncode == 0
    base = os.path.join(args.out, "selftest")
    os.makedirs(base, exist_ok=True)
    ref = tool(args, "granular-reference")

    scene = furnace_scene(1e5)
    scene["render"].update(width=32, height=24)
    p = os.path.join(base, "furnace.json")
    json.dump(scene, open(p, "w"))
    img, sj = os.path.join(base, "furnace.exr"), os.path.join(base, "furnace_stats.json")
    run([ref, "render", p, img, "--spp", "8", "--threads", "1", "--stats-json", sj])
    st = json.load(open(sj))
    m, pixels = region_means(args, p, [img])
    # The mask's mean is 1 only if every masked pixel is: no sample can exceed 1.
    good = abs(m[0] - 1.0) < 1e-7 and st["inconsistent"] == 0 and st["truncated"] == 0
    print(f"{'ok  ' if good else 'FAIL'}  furnace: ball of {st['grains']} clear grains, {pixels} ball pixels, "
          f"mean {m[0]:.9f}, {st['rays']} rays, {st['inconsistent']} inconsistent, {st['truncated']} truncated")
    ok = ok and good

    # A Lambert floor under the dome and the delta sun, nothing else: every sample that
    # sees the floor's top is ρ (L + E cos θ / π) (NEE is exact and the continuation
    # escapes to the dome). The camera narrowed and the floor widened so that every pixel
    # sees its top.
    scene = ball_scene(1e4)
    scene["aggregates"] = []
    scene["camera"]["focal_length"] = 200
    scene["meshes"][0]["shape"] = {"box": {"lo": [-40, -1.3, -40], "hi": [40, -1.0, 40]}}
    scene["render"].update(width=32, height=24)
    p = os.path.join(base, "floor.json")
    json.dump(scene, open(p, "w"))
    img = os.path.join(base, "floor.exr")
    run([ref, "render", p, img, "--spp", "4", "--threads", "1"])
    sun = next(l for l in scene["lights"] if l["type"] == "distant")
    dome = next(l for l in scene["lights"] if l["type"] == "dome")
    d = sun["direction"]
    cos = -d[1] / math.sqrt(sum(x * x for x in d))
    albedo = scene["materials"]["floor"]["albedo"]
    expect = [a * (c * dome["intensity"] + sun["intensity"] * cos / math.pi) for a, c in zip(albedo, dome["color"])]
    got = json.loads(run([ref, "mean", p, img]).stdout)["mean"]
    err = max(abs(g / e - 1) for g, e in zip(got, expect))
    good = err < 1e-6
    print(f"{'ok  ' if good else 'FAIL'}  floor under dome and delta sun: every pixel ρ (L + E cos θ / π) = "
          f"{', '.join(f'{x:.6f}' for x in expect)}, image mean within {err:.1e} (relative)")
    ok = ok and good
    print("selftest passed" if ok else "selftest FAILED")
    return 0 if ok else 1


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--grains", default="1e4,1e5,1e6")
    ap.add_argument("--renders", type=int, default=16, help="independent renders per renderer (K)")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seed-base", type=int, default=0, help="render k uses seed base + k (independent reruns)")
    ap.add_argument("--size", default="64x48")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "reference_small_grains"))
    ap.add_argument("--no-mitsuba", action="store_true")
    ap.add_argument("--furnace", action="store_true",
                    help="also the ball of clear grains under a white dome (exactly 1), 4 renders of 16 spp")
    ap.add_argument("--mitsuba-offsets", action="store_true",
                    help="also the reference with Mitsuba's absolute ray offsets (a diagnosis)")
    ap.add_argument("--selftest", action="store_true")
    args = ap.parse_args()
    args.width, args.height = (int(v) for v in args.size.split("x"))
    os.makedirs(args.out, exist_ok=True)
    if args.selftest:
        return selftest(args)
    mpy = mitsuba_python(args.no_mitsuba)
    if not mpy:
        print("mitsuba not importable here nor in .venv-mitsuba: ours against the reference only", file=sys.stderr)
    rows = [render_n(args, float(g), mpy) for g in args.grains.split(",")]
    names = ["ours", "reference"] + (["Mitsuba"] if mpy else []) + ([OFFSETS] if args.mitsuba_offsets else [])
    print(f"{args.width}x{args.height}, {args.spp} spp, K = {args.renders} renders per renderer (seeds "
          f"{args.seed_base + 1}..{args.seed_base + args.renders}); "
          f"mean over the ball mask ({rows[0]['pixels']} pixels) of the RGB average, ± its standard error "
          f"over the K renders\n")
    pairs = [("ours", "reference")] + ([("Mitsuba", "reference"), ("ours", "Mitsuba")] if mpy else [])
    if args.mitsuba_offsets:
        pairs += [(OFFSETS, "reference")] + ([(OFFSETS, "Mitsuba")] if mpy else [])
    print("| grains | grain radius | " + " | ".join(f"{n} (mean ± se)" for n in names) + " | " +
          " | ".join(f"{a} − {b}" for a, b in pairs) + " |")
    print("|" + "---|" * (2 + len(names) + len(pairs)))
    for r in rows:
        res = r["res"]
        cells = [f"{r['grains']:.3g}", f"{r['R']:.4g}"] + [f"{res[n][0]:.5f} ± {res[n][1]:.5f}" for n in names]
        for a, b in pairs:
            rel, se, z = diff(res[a], res[b])
            cells.append(f"{rel:+.2f}% ± {se:.2f}% ({z:+.1f} se)")
        print("| " + " | ".join(cells) + " |")
    print()
    for r in rows:
        print(f"N {r['grains']}: reference {r['ref_s']:.2f} s per render, {r['rays']} rays, "
              f"{r['mesh_inside']} hits of the floor from inside a grain, 0 inconsistent crossings")
    if args.furnace:
        args.renders, args.spp, args.mitsuba_offsets = 4, 16, False
        names = [n for n in names if n != OFFSETS]
        rows = [render_n(args, float(g), mpy, furnace=True) for g in args.grains.split(",")]
        print(f"\nFurnace: the same balls of clear grains (absorption 0) alone under a white dome: every path "
              f"returns 1, but for those cut at the {stats_max_depth()} scattering events every renderer allows; "
              f"{args.renders} renders of {args.spp} spp, mean over the ball mask ± se, and the largest |render "
              f"mean − 1|\n")
        print("| grains | " + " | ".join(names) + " | paths cut at the maximum depth (reference) |")
        print("|" + "---|" * (2 + len(names)))
        for r in rows:
            print(f"| {r['grains']:.3g} | " + " | ".join(
                f"{r['res'][n][0]:.6f} ± {r['res'][n][1]:.6f} (worst {r['worst'][n]:.1e})" for n in names) +
                f" | {r['truncated']} of {r['paths']} camera paths |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
