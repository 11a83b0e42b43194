#!/usr/bin/env python3
"""The tiles' growth schedule (core/packing.h, TileGrowth) against slow growth throughout and
faster ones: one core's packing seconds per tile and the near-contact numbers (neighbours per
sphere closer than 1.01, 1.02, 1.05 diameters; Skoge et al. 2006: faster growth leaves more
near-contacts), mean ± standard error over seeds 1..S.

Runs bench/tile_growth.cpp (the build's granular-tile-growth) and prints a markdown table.
Usage: python3 bench/tile_growth.py [--build build] [--cases 512:0.6:12,4096:0.6:2]
"""
import argparse
import json
import os
import subprocess

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--cases", default="512:0.6:12,4096:0.6:2", help="spheres:packing rate:seeds, comma-separated")
    a = ap.parse_args()
    exe = os.path.join(a.build, "bench", "granular-tile-growth")
    if not os.path.exists(exe):
        raise SystemExit(f"{exe} is missing: build the target granular-tile-growth first")
    rows = []
    for case in a.cases.split(","):
        n, f, seeds = case.split(":")
        out = subprocess.run([exe, n, f, seeds], check=True, capture_output=True, text=True).stdout
        rows += [json.loads(line) for line in out.splitlines() if line.strip()]
    print("| spheres, f | growth | s per tile | within 1.01 D | within 1.02 D | within 1.05 D |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['n']}, {r['f']:g} ({r['seeds']} seeds) | {r['schedule']} | {r['seconds']:.3f} | "
              f"{r['z1']:.2f} ± {r['z1_se']:.2f} | {r['z2']:.2f} ± {r['z2_se']:.2f} | {r['z5']:.2f} ± {r['z5_se']:.2f} |")


if __name__ == "__main__":
    main()
