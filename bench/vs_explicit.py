#!/usr/bin/env python3
"""Our procedural EPT against what users would pick instead: explicit instancing in Mitsuba 3
(one `instance` of a `shapegroup` per grain), at equal samples, as the aggregate grows.

The scene is bench/scenes/validate_ept.json (a ball of amber rocks and flint flakes over a
floor, dome and delta sun) with the grain radius shrunk so that the ball holds about N
grains (N = packing rate x (ball radius / R)^3 bounding spheres). Per N: `granular-validate
export` writes every grain's matrix; Mitsuba 3 (scalar_rgb, one thread, volpathmis, as
validate_mitsuba.py builds it) loads and renders it in a fresh process; ours renders the
same scene with `granular-render --technique ept --threads 1` in a fresh process. Each side
reports its scene build time, its render time and its process peak RSS, and the image mean
(the two must agree within noise: both are unbiased renders of the same grains).

Usage: .venv/bin/python bench/vs_explicit.py [--build build] [--grains 1e3,1e4,1e5,1e6]
           [--sizes 64x48,256x192] [--spp 16] [--out out/bench/vs_explicit]
Needs the `mitsuba` package (PyPI) in the interpreter that runs it. Prints a markdown table.
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

# Run in a fresh interpreter: load the exported scene into Mitsuba, render it, report.
MITSUBA_CHILD = r"""
import json, resource, sys, time
import numpy as np
sys.path.insert(0, {here!r})
import validate_mitsuba as vm
import drjit as dr
mi = vm.mitsuba()
dr.set_thread_count(1)
base, spp, width, height = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
exp = json.load(open(base + "/scene.json"))
exp["width"], exp["height"] = width, height
t0 = time.monotonic()
scene = mi.load_dict(vm.mitsuba_scene(mi, exp, base, spp, "ept", "volpathmis"))
t1 = time.monotonic()
img = np.array(mi.render(scene, seed=1), dtype=np.float64)[..., :3]
t2 = time.monotonic()
print(json.dumps(dict(build_s=t1 - t0, render_s=t2 - t1, mean=float(img.mean()),
                      peak_mib=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)))
"""


def peak_rss_of(cmd):
    """Runs cmd under /usr/bin/time -v; returns (stdout, peak RSS in MiB)."""
    r = subprocess.run(["/usr/bin/time", "-v"] + cmd, capture_output=True, text=True, check=True)
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
    return r.stdout, (int(m.group(1)) / 1024 if m else float("nan"))


def ours(core, args, scene_path, width, height, out):
    exr, stats = out + ".exr", out + ".json"
    _, peak = peak_rss_of([os.path.join(args.build, "core", "granular-render"), scene_path, "-o", exr,
                           "--technique", "ept", "--threads", "1", "--spp", str(args.spp), "--seed", "1",
                           "--width", str(width), "--height", str(height), "--quiet", "--stats-json", stats])
    s = json.load(open(stats))
    import numpy as np
    img = core.read_image_rgb(exr)
    return dict(build_s=s["build_s"], render_s=s["render_s"], mean=float(np.asarray(img.pixels)[..., :3].mean()),
                peak_mib=peak)


def theirs(args, base, width, height):
    child = MITSUBA_CHILD.format(here=HERE)
    r = subprocess.run([sys.executable, "-c", child, base, str(args.spp), str(width), str(height)],
                       capture_output=True, text=True, check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def ball_scene(n):
    """bench/scenes/validate_ept.json (a dict) with the grain radius shrunk so that its ball of
    radius 1 holds about n grains: N = packing rate x (1 / R)^3 bounding spheres."""
    text = open(os.path.join(HERE, "scenes", "validate_ept.json")).read()
    scene = json.loads("\n".join(line for line in text.splitlines() if not line.lstrip().startswith("//")))
    agg = scene["aggregates"][0]
    agg["grain_radius"] = (agg["packing_rate"] / n) ** (1.0 / 3.0)
    return scene


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--grains", default="1e3,1e4,1e5,1e6")
    ap.add_argument("--sizes", default="64x48,256x192")
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "vs_explicit"))
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    from validate_mitsuba import mitsuba  # noqa: F401  (fails early without the package)
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]
    sys.path[:0] = [os.path.join(args.build, "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    rows = []
    for n in [float(g) for g in args.grains.split(",")]:
        scene = ball_scene(n)
        base = os.path.join(args.out, f"n{n:.0e}")
        os.makedirs(base, exist_ok=True)
        scene_path = os.path.join(base, "input.json")
        json.dump(scene, open(scene_path, "w"))
        r = subprocess.run([os.path.join(args.build, "bench", "granular-validate"), "export", scene_path, base],
                           capture_output=True, text=True, check=True)
        grains = sum(len(a["grains"]) for a in json.load(open(os.path.join(base, "scene.json")))["aggregates"])
        for (w, h) in sizes:
            print(f"{grains} grains, {w}x{h}: ours ...", file=sys.stderr, flush=True)
            a = ours(core, args, scene_path, w, h, os.path.join(base, f"ours_{w}x{h}"))
            print(f"  {a}\n  Mitsuba ...", file=sys.stderr, flush=True)
            b = theirs(args, base, w, h)
            print(f"  {b}", file=sys.stderr, flush=True)
            rows.append((grains, w, h, a, b))
    print(f"{args.spp} spp, one thread each; build = scene load and acceleration structures (Mitsuba: "
          f"from the exported grain list), peak = process peak RSS\n")
    print("| grains | image | ours render (s) | Mitsuba render (s) | render speed-up | ours build (s) | "
          "Mitsuba build (s) | ours peak (MiB) | Mitsuba peak (MiB) | mean ours / Mitsuba |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for grains, w, h, a, b in rows:
        print(f"| {grains:.3g} | {w}x{h} | {a['render_s']:.2f} | {b['render_s']:.2f} | "
              f"{b['render_s'] / a['render_s']:.2f}x | {a['build_s']:.2f} | {b['build_s']:.2f} | "
              f"{a['peak_mib']:.0f} | {b['peak_mib']:.0f} | {a['mean']:.4f} / {b['mean']:.4f} |")


if __name__ == "__main__":
    main()
