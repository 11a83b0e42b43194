#!/usr/bin/env python3
"""Stand-ins: what a viewport shows before the aggregates are built (core/scene.h,
SceneDetail::StandIns: each aggregate's medium alone, from the camera on), against the
full hybrid that replaces them. For each example: the stand-ins' build time and the full
build's, with the build cache empty (cold) and filled (cached), and how far the stand-ins'
image is from the hybrid's at equal samples: the relative difference of the image mean
per channel over covered pixels, and the 90th percentile and largest relative difference
of 8×8-pixel block means (a brightness jump the eye would see at the switch), each beside
the same numbers for two seeds of the hybrid (the noise floor).

Usage: .venv/bin/python bench/stand_ins.py [--examples snowslab,sandcastle_paper] [--width 160] [--spp 64]
Prints a markdown table.
"""
import argparse
import os
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "python"))


def image(built):
    import granular_core as core
    r = core.Renderer(built)
    r.render(1)
    im = r.image()
    ch = list(im.channels)
    px = np.asarray(im.pixels, dtype=np.float64)
    return px[..., [ch.index(c) for c in ("R", "G", "B")]], px[..., ch.index("A")]


def compare(a, b, alpha):
    """(per-channel relative difference of the means, p90 and max of block-mean differences)."""
    covered = alpha > 0.5
    means = [(a[..., c][covered].mean() - b[..., c][covered].mean()) / b[..., c][covered].mean() for c in range(3)]
    h, w = alpha.shape
    diffs = []
    for y in range(0, h - 7, 8):
        for x in range(0, w - 7, 8):
            if covered[y:y + 8, x:x + 8].mean() < 0.99:
                continue
            la = a[y:y + 8, x:x + 8].mean()
            lb = b[y:y + 8, x:x + 8].mean()
            diffs.append(abs(la - lb) / max(lb, 1e-6))
    diffs = np.array(diffs) if diffs else np.zeros(1)
    return means, float(np.percentile(diffs, 90)), float(diffs.max())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", default="snowslab,sugarcube,sandcastle,mixture,macro,sandcastle_paper")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--spp", type=int, default=64)
    a = ap.parse_args()
    import granular  # noqa: F401  (the schema plugin)
    import granular_core as core
    from granular.usd_reader import read_stage

    print(f"| example ({a.width} px, {a.spp} spp) | stand-ins built, cold / cached (s) | full build, cold / cached (s) "
          f"| stand-ins − hybrid, mean R/G/B (%) | 8×8 blocks: p90 / max (%) | hybrid seed 1 − seed 2: mean R/G/B (%) "
          f"| blocks p90 / max (%) |")
    print("|---|---|---|---|---|---|---|")
    for name in a.examples.split(","):
        path = os.path.join(ROOT, "examples", name + ".usda")
        times = {}
        with tempfile.TemporaryDirectory() as cache:
            os.environ["GRANULAR_CACHE_DIR"] = cache
            for state in ("cold", "cached"):
                scene = read_stage(path, width=a.width)
                s = scene.desc.settings
                s.spp = a.spp
                t0 = time.monotonic()
                stand_ins = core.Scene.build(scene.desc, None, None, True)
                t1 = time.monotonic()
                full = core.Scene.build(scene.desc, stand_ins)
                t2 = time.monotonic()
                times[state] = (t1 - t0, t2 - t1)
            s.seed = 1
            stand_ins.set_view(scene.desc.camera, s)
            full.set_view(scene.desc.camera, s)
            first, alpha = image(stand_ins)
            hybrid1, _ = image(full)
            s.seed = 2
            full.set_view(scene.desc.camera, s)
            hybrid2, _ = image(full)
        jump, p90, worst = compare(first, hybrid1, alpha)
        noise, np90, nworst = compare(hybrid2, hybrid1, alpha)
        pct = lambda v: " / ".join(f"{100 * x:+.1f}" for x in v)  # noqa: E731
        print(f"| {name} | {times['cold'][0]:.2f} / {times['cached'][0]:.2f} | {times['cold'][1]:.1f} / "
              f"{times['cached'][1]:.1f} | {pct(jump)} | {100 * p90:.1f} / {100 * worst:.1f} | {pct(noise)} | "
              f"{100 * np90:.1f} / {100 * nworst:.1f} |", flush=True)


if __name__ == "__main__":
    main()
