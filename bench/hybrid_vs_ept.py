#!/usr/bin/env python3
"""The hybrid against explicit grains (EPT, the reference) on any stage or JSON scene:
`--seeds` independent renders per technique through `granular render`, the mean radiance
per channel over the whole image, and the relative difference with its standard error
(from the spread of the seeds' image means).

Usage: .venv/bin/python bench/hybrid_vs_ept.py examples/mixture.usda [--width 160] [--height 120]
         [--spp 256] [--seeds 4] [--techniques ept+vpt,hybrid]
Prints a markdown table.
"""
import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "build", "python"))
import granular_core as core  # noqa: E402


def image_means(scene, technique, args, tmp):
    means = []
    for seed in range(1, args.seeds + 1):
        out = os.path.join(tmp, f"{technique.replace('+', '_')}_{seed}.exr")
        subprocess.run([args.granular, "render", scene, "-o", out, "--width", str(args.width), "--height",
                        str(args.height), "--spp", str(args.spp), "--seed", str(seed), "--technique", technique,
                        "--quiet"], check=True)
        means.append(np.asarray(core.read_exr(out).pixels)[..., :3].reshape(-1, 3).mean(0))
    means = np.array(means)
    return means.mean(0), means.std(0, ddof=1) / np.sqrt(len(means))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scene")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--techniques", default="ept+vpt,hybrid")
    ap.add_argument("--granular", default=os.path.join(ROOT, ".venv", "bin", "granular"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ref, ref_se = image_means(args.scene, "ept", args, tmp)
        print(f"{os.path.basename(args.scene)}: {args.width} x {args.height}, {args.spp} spp x {args.seeds} seeds\n")
        print("| technique | image mean (R G B) | difference from EPT % (R / G / B) ± SE |")
        print("|---|---|---|")
        print(f"| ept | {' '.join(f'{x:.5f}' for x in ref)} | reference |")
        for t in args.techniques.split(","):
            m, se = image_means(args.scene, t, args, tmp)
            rel = 100 * (m - ref) / ref
            err = 100 * np.sqrt(se ** 2 + ref_se ** 2) / ref
            print(f"| {t} | {' '.join(f'{x:.5f}' for x in m)} | "
                  f"{' / '.join(f'{x:+.2f}' for x in rel)} ± {' / '.join(f'{x:.2f}' for x in err)} |")


if __name__ == "__main__":
    main()
