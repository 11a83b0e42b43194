#!/usr/bin/env python3
"""The colour a grain material gives a thick layer: a slab 4000 grain radii deep under a
white dome of radiance 1, seen from straight above; the mean radiance is its white-sky
albedo (python/granular/materials.py: slab_scene). The hybrid renders it (its medium agrees
with explicit grains within 0.5%, bench/README.md).

    .venv/bin/python bench/slab_albedo.py [--spp 64]            # the measured materials
    .venv/bin/python bench/slab_albedo.py --absorption 0.004,0.009,0.028,0.4,0.6,1.1 ...
    .venv/bin/python bench/slab_albedo.py --fit quartz_sand      # fit per-radius absorption

The first prints, per material of materials.py, its absorption per grain radius at the
examples' grain size, the rendered albedo with its standard error, and the target. The
second renders the sand's grain shapes with the given absorption (r,g,b per grain radius,
and optionally r,g,b of the darker tenth). The third bisects each channel's absorption
(the darker grains' fixed) until the layer meets the middle of the material's target.
"""
import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "build", "python"))
sys.path.insert(0, os.path.join(ROOT, "python"))
from granular.materials import MATERIALS, QUARTZ_SAND, slab_albedo  # noqa: E402


def fmt(v, digits=3):
    return " ".join(f"{x:.{digits}f}" for x in v)


def fit(material, spp, iterations):
    """Per-channel bisection in log absorption: the albedo falls as absorption grows."""
    target = np.array([(lo + hi) / 2 for lo, hi in material.target])
    lo, hi = np.full(3, 1e-5), np.full(3, 1.0)
    for _ in range(iterations):
        mid = np.sqrt(lo * hi)
        albedo, _ = slab_albedo(material, spp=spp, per_radius=tuple(mid))
        too_dark = albedo < target
        hi = np.where(too_dark, mid, hi)
        lo = np.where(too_dark, lo, mid)
        print(f"absorption {fmt(mid, 5)} -> albedo {fmt(albedo)} (target {fmt(target)})", flush=True)
    return np.sqrt(lo * hi)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--absorption", nargs="+", default=[])
    ap.add_argument("--fit", choices=sorted(MATERIALS))
    ap.add_argument("--iterations", type=int, default=10)
    args = ap.parse_args()
    if args.fit:
        best = fit(MATERIALS[args.fit], args.spp, args.iterations)
        print(f"fitted absorption per grain radius: {', '.join(f'{x:.2g}' for x in best)}")
        return 0
    if args.absorption:
        print("| absorption (per grain radius) | darker tenth | slab albedo (R G B) | standard error |")
        print("|---|---|---|---|")
        for m in args.absorption:
            v = [float(x) for x in m.split(",")]
            dark = v[3:6] if len(v) > 3 else v[:3]
            albedo, se = slab_albedo(QUARTZ_SAND, spp=args.spp, per_radius=tuple(v[:3]), dark_per_radius=tuple(dark))
            print(f"| {', '.join(f'{x:g}' for x in v[:3])} | {', '.join(f'{x:g}' for x in v[3:6]) or '—'} | "
                  f"{fmt(albedo)} | {fmt(se, 4)} |")
        return 0
    print("| material | grain radius | absorption per radius (R G B) | slab albedo (R G B) | standard error | "
          "target (R G B) |")
    print("|---|---|---|---|---|---|")
    for name, m in MATERIALS.items():
        r = m.grain_radius_m  # the examples' grain size
        albedo, se = slab_albedo(m, spp=args.spp)
        target = " ".join(f"{lo:.3g}–{hi:.3g}" for lo, hi in m.target)
        print(f"| {name} | {r * 1000:g} mm | {', '.join(f'{x:.2g}' for x in m.absorption_per_radius(r))} | "
              f"{fmt(albedo)} | {fmt(se, 4)} | {target} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
