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
       [--ref-spp 1024] [--targets 0.02,0.01] [--out out/bench/instanced_hybrid] [--threads T]
       [--da] [--absorption-scale S] [--material ice] [--slab-depth D] [--gradient G]
       [--sun E] [--sun-angle DEG]
Prints a markdown table and the ladders; each step's heap mean against the reference's with
its standard error (both images' variance AOVs).

--da compares the hybrid with DA in the heap's heterogeneous medium against
the hybrid without it (without `--instanced-da`: VPT to the end there) instead of EPT against
the hybrid; the reference is then the hybrid without DA at --ref-spp, so the table's
speed-up is DA's at equal error against what it replaces, and each step's "heap mean" is
DA's bias against VPT to the end (core/heterogeneous_diffusion.h). --absorption-scale S
multiplies the grains' absorption (the generator's quartz sand) by S: brighter grains
(S < 1) scatter longer, where DA takes more of the light. --material and --slab-depth go to the
generator: ice grains (nearly clear), a flat slab D grid cells deep instead of the cone,
its packing rate rising G times from bottom to top (a medium of varying density).
--sun E lights the heap by the generator's sun at irradiance E (default 0: the sky alone, as
every table of bench/README.md before the sun was measured), --sun-angle DEG wide: explicit
grains find a sun only by hitting its disk, so EPT's reference needs one of a few degrees.
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


# The renders compared: their command-line options, EPT's first (the reference's), or with
# --da the hybrid without DA in the heap's medium first.
VARIANTS = {"ept": ["--technique", "ept"], "hybrid": ["--technique", "hybrid"]}
DA_VARIANTS = {"hybrid, no DA": ["--technique", "hybrid"], "hybrid, DA": ["--technique", "hybrid", "--instanced-da"]}


def render(stage, out, size, spp, options, seed, threads=0):
    """Renders; returns the render's seconds, the scene's read and build seconds (NaN if not
    printed) and DA's share of the paths in percent (None if not printed)."""
    w, h = size
    cmd = [GRANULAR, "render", stage, "-o", out, "--width", str(w), "--height", str(h), "--spp", str(spp),
           "--seed", str(seed), "--threads", str(threads)] + list(options)
    r = subprocess.run(cmd, capture_output=True, text=True, check=True)
    m = re.search(r"render ([\d.]+) s", r.stdout + r.stderr)
    built = re.search(r"built in ([\d.]+) s", r.stdout + r.stderr)
    da = re.search(r"DA [\d.e+-]+ \(([\d.]+)% of paths\)", r.stdout + r.stderr)
    return (float(m.group(1)), float(built.group(1)) if built else float("nan"),
            float(da.group(1)) if da else None)


def load(path):
    """The image's RGB, primId, da.R/G/B AOV (DA's light; zero if absent) and variance.R/G/B
    AOV (each pixel's squared standard error)."""
    import granular_core as core
    im = core.read_exr(path)
    px = np.asarray(im.pixels, dtype=np.float64)
    ch = list(im.channels)
    rgb = px[..., [ch.index(c) for c in "RGB"]]
    dal = px[..., [ch.index("da." + c) for c in "RGB"]] if "da.R" in ch else np.zeros_like(rgb)
    var = px[..., [ch.index("variance." + c) for c in "RGB"]]
    return rgb, px[..., ch.index("primId")], dal, var


def mean_bias(img, var, ref, ref_var, mask):
    """The masked mean's relative difference from the reference's, per channel, and its
    standard error (pixels independent: the mean's variance is Σ var / N²)."""
    n = np.count_nonzero(mask)
    a, b = img[mask].mean(axis=0), ref[mask].mean(axis=0)
    se = np.sqrt(var[mask].sum(axis=0) + ref_var[mask].sum(axis=0)) / n
    return a / b - 1, se / b


def scale_absorption(stage_path, scale):
    """Multiplies every grain prototype's primvars:granular:absorption in the stage by scale."""
    from pxr import Gf, Usd
    stage = Usd.Stage.Open(stage_path)
    for prim in stage.Traverse():
        attr = prim.GetAttribute("primvars:granular:absorption")
        if attr and attr.HasAuthoredValue():
            attr.Set(Gf.Vec3f(*(scale * a for a in attr.Get())))
    stage.Save()


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
    ap.add_argument("--threads", type=int, default=0, help="render threads (0: all cores)")
    ap.add_argument("--da", action="store_true",
                    help="the hybrid with DA in the heap's medium against the hybrid without it (the reference)")
    ap.add_argument("--absorption-scale", type=float, default=1.0,
                    help="multiply the grains' absorption by this (1: the generator's quartz sand)")
    ap.add_argument("--material", choices=["quartz_sand", "ice"], default="quartz_sand",
                    help="the grains' material (make_grain_heap.py)")
    ap.add_argument("--slab-depth", type=int, help="a slab this many grid cells deep (make_grain_heap.py)")
    ap.add_argument("--gradient", type=float, default=1.0,
                    help="with --slab-depth: the slab's packing rate rises this many times to its top")
    ap.add_argument("--sun", type=float, default=0.0, help="the sun's irradiance (0: the sky alone)")
    ap.add_argument("--sun-angle", type=float, default=5.0, help="the sun's angular diameter, degrees")
    args = ap.parse_args()
    variants = DA_VARIANTS if args.da else VARIANTS
    names = list(variants)
    os.makedirs(args.out, exist_ok=True)
    size = tuple(int(x) for x in args.size.split("x"))
    stage = os.path.join(args.out, "heap.usdc")
    shape = ["--material", args.material] + (["--slab-depth", str(args.slab_depth)] if args.slab_depth else []) + \
        (["--gradient", str(args.gradient)] if args.gradient != 1.0 else []) + \
        ["--sun", str(args.sun), "--sun-angle", str(args.sun_angle)]
    subprocess.run([sys.executable, os.path.join(ROOT, "examples", "make_grain_heap.py"), stage, "--grains",
                    str(args.grains), "--frames", "1"] + shape, check=True, capture_output=True)
    if args.absorption_scale != 1.0:
        scale_absorption(stage, args.absorption_scale)
    lit = f"_sun{args.sun:g}_{args.sun_angle:g}" if args.sun > 0 else ""
    ref_path = os.path.join(args.out, f"ref_da_off_abs{args.absorption_scale:g}{lit}.exr" if args.da else
                            f"ref{lit}.exr")
    if not os.path.exists(ref_path):
        render(stage, ref_path, size, args.ref_spp, variants[names[0]], 1000, args.threads)
    ref, prim, _, ref_var = load(ref_path)
    heap = prim == 1
    ladders, setup = {}, {}
    for name in names:
        ladders[name] = []
        for spp in [int(s) for s in args.spp.split(",")]:
            out = os.path.join(args.out, f"{name.replace(', ', '_').replace(' ', '_')}_{spp}.exr")
            seconds, built, da_paths = render(stage, out, size, spp, variants[name], 1, args.threads)
            setup[name] = built
            img, _, dal, var = load(out)
            err = float((((img - ref) ** 2) / (ref ** 2 + 0.01))[heap].mean())
            bias, bias_se = mean_bias(img, var, ref, ref_var, heap)
            ladders[name].append((seconds, err))
            da = f", DA on {da_paths:.1f}% of paths" if da_paths is not None else ""
            if dal.any():  # DA's share of the heap's light, per channel
                share = dal[heap].mean(axis=0) / img[heap].mean(axis=0)
                da += f", DA's light {', '.join(f'{100 * x:.1f}%' for x in share)}"
            print(f"  {name} {spp} spp: {seconds:.2f} s, relMSE {err:.4g}, heap mean (R, G, B) "
                  f"{', '.join(f'{100 * b:+.2f}%' for b in bias)} ± {', '.join(f'{100 * e:.2f}' for e in bias_se)}"
                  f"{da}", flush=True)
    print(f"\n{args.grains} grains, {size[0]}x{size[1]}, reference: {names[0]} at {args.ref_spp} spp; "
          f"scene read and built: {names[0]} {setup[names[0]]:.2f} s, {names[1]} {setup[names[1]]:.2f} s\n")
    print(f"| relMSE target | {names[0]} (s) | {names[1]} (s) | speed-up |")
    print("|---|---|---|---|")
    for target in [float(t) for t in args.targets.split(",")]:
        a, b = crossing(ladders[names[0]], target), crossing(ladders[names[1]], target)
        fmt = lambda x: "not reached" if x is None else f"{x:.2f}"
        sp = f"{a / b:.1f}x" if a and b else "-"
        print(f"| {target} | {fmt(a)} | {fmt(b)} | {sp} |")


if __name__ == "__main__":
    main()
