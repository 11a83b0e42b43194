#!/usr/bin/env python3
"""The hybrid against EPT on simulated grains at equal error: the generated heap
(examples/make_grain_heap.py) rendered by `granular render --technique ept` and `--technique
hybrid` at increasing samples per pixel, each image's relMSE against an EPT reference of many
samples, and the render time each needs to reach a target relMSE (interpolated on log-log axes
between the two ladder steps around it, as time_to_error.py does).

relMSE is the mean over the heap's pixels (primId of the instancer) and channels of
(x - ref)^2 / (ref^2 + 0.01). Times are the command's own "render" figure (the scene's read
and build, from the caches, left out; the set-up is reported apart).

Usage: .venv/bin/python bench/instanced_hybrid.py [--grains 100000] [--size 80x60]
       [--ref-spp 1024] [--targets 0.02,0.01] [--out out/bench/instanced_hybrid]
Prints a markdown table and the ladders.
"""
import argparse
import math
import os
import re
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
GRANULAR = os.path.join(os.path.dirname(sys.executable), "granular")


def render(stage, out, size, spp, technique, seed):
    w, h = size
    cmd = [GRANULAR, "render", stage, "-o", out, "--width", str(w), "--height", str(h), "--spp", str(spp),
           "--technique", technique, "--seed", str(seed)]
    r = subprocess.run(cmd, capture_output=True, text=True, check=True)
    m = re.search(r"render ([\d.]+) s", r.stdout + r.stderr)
    built = re.search(r"built in ([\d.]+) s", r.stdout + r.stderr)
    return float(m.group(1)), float(built.group(1)) if built else float("nan")


def load(path):
    import granular_core as core
    im = core.read_exr(path)
    px = np.asarray(im.pixels, dtype=np.float64)
    ch = list(im.channels)
    return px[..., [ch.index(c) for c in "RGB"]], px[..., ch.index("primId")]


def crossing(ladder, target):
    """Time at which relMSE reaches target, log-log between the steps around it; None if never."""
    for (t0, e0), (t1, e1) in zip(ladder, ladder[1:]):
        if e0 > target >= e1:
            f = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + f * (math.log(t1) - math.log(t0)))
    return ladder[0][0] if ladder and ladder[0][1] <= target else None


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grains", type=int, default=100000)
    ap.add_argument("--size", default="80x60")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--spp", default="2,4,8,16,32,64,128")
    ap.add_argument("--targets", default="0.05,0.02,0.01")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "instanced_hybrid"))
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    size = tuple(int(x) for x in args.size.split("x"))
    stage = os.path.join(args.out, "heap.usdc")
    subprocess.run([sys.executable, os.path.join(ROOT, "examples", "make_grain_heap.py"), stage, "--grains",
                    str(args.grains), "--frames", "1"], check=True, capture_output=True)
    ref_path = os.path.join(args.out, "ref.exr")
    if not os.path.exists(ref_path):
        render(stage, ref_path, size, args.ref_spp, "ept", 1000)
    ref, prim = load(ref_path)
    heap = prim == 1
    ladders, setup = {}, {}
    for technique in ("ept", "hybrid"):
        ladders[technique] = []
        for spp in [int(s) for s in args.spp.split(",")]:
            out = os.path.join(args.out, f"{technique}_{spp}.exr")
            seconds, built = render(stage, out, size, spp, technique, 1)
            setup[technique] = built
            img, _ = load(out)
            err = float((((img - ref) ** 2) / (ref ** 2 + 0.01))[heap].mean())
            bias = float(img[heap].mean() / ref[heap].mean() - 1)
            ladders[technique].append((seconds, err))
            print(f"  {technique} {spp} spp: {seconds:.2f} s, relMSE {err:.4g}, heap mean {100 * bias:+.2f}%",
                  flush=True)
    print(f"\n{args.grains} grains, {size[0]}x{size[1]}, EPT reference of {args.ref_spp} spp; "
          f"scene read and built: EPT {setup['ept']:.2f} s, hybrid {setup['hybrid']:.2f} s\n")
    print("| relMSE target | EPT (s) | hybrid (s) | speed-up |")
    print("|---|---|---|---|")
    for target in [float(t) for t in args.targets.split(",")]:
        a, b = crossing(ladders["ept"], target), crossing(ladders["hybrid"], target)
        fmt = lambda x: "not reached" if x is None else f"{x:.2f}"
        sp = f"{a / b:.1f}x" if a and b else "-"
        print(f"| {target} | {fmt(a)} | {fmt(b)} | {sp} |")


if __name__ == "__main__":
    main()
