#!/usr/bin/env python3
"""Teleportation-transport parameters (core/tt.h) of a few grain prototypes.

Runs `granular-bench tt` (uncached estimation, IOR 1.5 grains, clear and absorbing with
absorption (0.1, 0.3, 1.0) per grain radius) and prints a markdown table: the per-grain
statistics with their standard errors (lengths in grain radii), then the medium they
give for grain radius R = 0.01 and packing rate f = 0.6 (sigma_t in 1/length, mean free
path 1/sigma_t in scene length), and the estimation time.
Usage: python3 bench/tt_params.py [--build build] [--rays N]
"""
import argparse
import json
import os
import subprocess
import sys


def pm(v, se, digits=4):
    return f"{v:.{digits}f} ± {se:.{digits}f}"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build")
    ap.add_argument("--rays", default=str(1 << 18))
    a = ap.parse_args()
    exe = os.path.join(a.build, "bench", "granular-bench")
    if not os.path.exists(exe):
        sys.exit(f"{exe} not found: build the project first")
    out = subprocess.run([exe, "tt", "--rays", a.rays], check=True, capture_output=True, text=True)
    rows = [json.loads(line) for line in out.stdout.splitlines() if line.strip()]

    print(f"## Teleportation transport, {rows[0]['rays']} rays per prototype (lengths in grain radii)\n")
    print("| prototype | material | β | λ_δ | channel | α_s | λ_s | g | σ_t (R=0.01, f=0.6) | mean free path | time (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        channels = range(1) if r["material"] == "clear" else range(3)  # clear: the channels are equal
        for c in channels:
            first = c == 0
            print("| {} | {} | {} | {} | {} | {} | {} | {} | {:.2f} | {:.5f} | {} |".format(
                r["prototype"] if first else "", r["material"] if first else "",
                pm(r["beta"], r["beta_se"]) if first else "", pm(r["lambda_delta"], r["lambda_delta_se"]) if first else "",
                "rgb" if r["material"] == "clear" else "rgb"[c],
                pm(r["albedo"][c], r["albedo_se"][c]), pm(r["lambda_s"][c], r["lambda_s_se"][c]),
                pm(r["g"][c], r["g_se"][c]), r["sigma_t"][c], r["mean_free_path"][c],
                f"{r['seconds']:.2f}" if first else ""))


if __name__ == "__main__":
    main()
