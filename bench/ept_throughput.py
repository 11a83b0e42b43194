#!/usr/bin/env python3
"""EPT benchmark: ray throughput through an aggregate against raw Embree, and the
set-up time and memory of aggregates from 10^6 to 10^9 grains.

Prints two markdown tables. Each measurement runs in a fresh process (so peak RSS
belongs to one aggregate). Usage: python3 bench/ept_throughput.py [--build build]
"""
import argparse
import json
import os
import subprocess
import sys


def run(exe, *args):
    out = subprocess.run([exe, *args], check=True, capture_output=True, text=True, env=dict(os.environ))
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--build", default="build")
    ap.add_argument("--seconds", default="2")
    ap.add_argument("--sizes", default="1e6,1e7,1e8,1e9")
    a = ap.parse_args()
    exe = os.path.join(a.build, "bench", "granular-bench")
    if not os.path.exists(exe):
        sys.exit(f"{exe} not found: run 'make build' first")

    print("## EPT ray throughput (one thread)\n")
    print("| grain radius | grains | Embree rtcIntersect1 on the grain mesh (rays/s) | aggregate EPT rays (rays/s) | ratio |")
    print("|---|---|---|---|---|")
    for r in ("0.02", "0.01"):
        m = run(exe, "throughput", "--grain-radius", r, "--seconds", a.seconds)
        print(f"| {m['grain_radius']} | {m['grains']:.3g} | {m['embree_rays_per_s']:.3g} | "
              f"{m['aggregate_rays_per_s']:.3g} | {m['ratio']:.3f} |")

    print("\n## Aggregate set-up time and memory\n")
    print("| grains | cells (tiles) | set-up (s) | tile (s) | distance field (s) | aggregate memory (MiB) | process peak RSS (MiB) |")
    print("|---|---|---|---|---|---|---|")
    for n in a.sizes.split(","):
        m = run(exe, "setup", "--grains", n)
        print(f"| {m['grains']:.3g} | {m['cells']} | {m['setup_s']:.2f} | {m['tile_s']:.2f} | {m['sdf_s']:.2f} | "
              f"{m['aggregate_mib']:.1f} | {m['peak_rss_mib']:.0f} |")


if __name__ == "__main__":
    main()
