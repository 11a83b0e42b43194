#!/usr/bin/env python3
"""Time to an error: the render time `granular render` needs to bring an image within
relMSE 0.01 of a high-sample reference, four ways: raw (fixed samples per pixel),
adaptive (`--noise-threshold`, per pixel), denoised (`--denoise`) and adaptive plus
denoised.

relMSE is the mean over pixels and channels of (x − ref)² / (ref² + 0.01), as in
denoise.py. Each way runs a ladder (samples per pixel, or noise thresholds) until it is
below the target; the time to the target is interpolated between the two ladder steps
around it on log–log axes. The time is the command's own "render" figure (the passes, the
denoiser and the writing; the scene read and built before it, from the caches, is left
out). A raw and a denoised image come from the same render, as do the adaptive pair.

Usage: .venv/bin/python bench/time_to_error.py [--scenes sandcastle_paper,sandcastle,snowslab,macro]
       [--size 160x120] [--ref-spp 4096] [--out out/bench/time_to_error]
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
TARGET = 0.01
RGB, DENOISED = ["R", "G", "B"], ["denoised.R", "denoised.G", "denoised.B"]


def channels(path, names):
    import granular_core as core
    im = core.read_exr(path)
    px = np.asarray(im.pixels, dtype=np.float64)
    ch = list(im.channels)
    return px[..., [ch.index(n) for n in names]]


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def render(scene, out, width, height, spp, seed, extra):
    cmd = [GRANULAR, "render", scene, "-o", out, "--width", str(width), "--height", str(height), "--spp", str(spp),
           "--seed", str(seed)] + extra
    p = subprocess.run(cmd, check=True, capture_output=True, text=True)
    m = re.search(r"\(render ([0-9.]+) s", p.stderr)
    if not m:
        raise SystemExit(f"no render time in the log of {' '.join(cmd)}:\n{p.stderr}")
    return float(m.group(1))


def crossing(points):
    """Seconds at which relMSE reaches TARGET, interpolated log–log between the ladder's
    steps around it (None when never reached)."""
    for (t0, e0), (t1, e1) in zip(points, points[1:]):
        if e0 > TARGET >= e1:
            if e1 <= 0 or e0 <= 0 or t0 <= 0:
                return t1
            u = (math.log(e0) - math.log(TARGET)) / (math.log(e0) - math.log(e1))
            return math.exp(math.log(t0) + u * (math.log(t1) - math.log(t0)))
    if points and points[0][1] <= TARGET:
        return points[0][0]
    return None


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="sandcastle_paper,sandcastle,snowslab,macro")
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--spp", default="1,2,4,8,16,32,64,128,256,512,1024")
    ap.add_argument("--thresholds", default="0.5,0.3,0.2,0.12,0.08,0.05,0.03,0.02,0.012")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "time_to_error"))
    a = ap.parse_args()
    width, height = (int(v) for v in a.size.split("x"))
    os.makedirs(a.out, exist_ok=True)
    rows, ladders = [], []
    for name in a.scenes.split(","):
        scene = os.path.join(ROOT, "examples", name + ".usda")
        ref_path = os.path.join(a.out, f"{name}_ref{a.ref_spp}.exr")
        if not os.path.exists(ref_path):
            render(scene, ref_path, width, height, a.ref_spp, 99, [])
        ref = channels(ref_path, RGB)
        ways = {"raw": [], "denoised": [], "adaptive": [], "adaptive + denoised": []}

        def climb(steps, raw, denoised):
            """Renders each (file tag, label, spp, extra options) step until both ways are below
            the target, appending (seconds, relMSE) to ways[raw] and ways[denoised]."""
            for tag, label, spp, extra in steps:
                out = os.path.join(a.out, f"{name}_{tag}.exr")
                t = render(scene, out, width, height, spp, 1, ["--denoise"] + extra)
                e_raw, e_den = relmse(channels(out, RGB), ref), relmse(channels(out, DENOISED), ref)
                ways[raw].append((t, e_raw))
                ways[denoised].append((t, e_den))
                ladders.append(f"{name} {label}: {t:.2f} s, raw {e_raw:.4f}, denoised {e_den:.4f}")
                if e_raw <= TARGET and e_den <= TARGET:
                    break

        counts = [int(x) for x in a.spp.split(",")]
        climb([(str(n), f"{n} spp", n, []) for n in counts], "raw", "denoised")
        climb([(f"t{t}", f"threshold {t}", max(counts), ["--noise-threshold", t]) for t in a.thresholds.split(",")],
              "adaptive", "adaptive + denoised")
        times = {w: crossing(sorted(p)) for w, p in ways.items()}
        rows.append((name, times))
        print(f"{name}: " + ", ".join(f"{w} {t if t is None else round(t, 2)}" for w, t in times.items()), flush=True)
    print()
    print(f"| scene ({width}×{height}, to relMSE {TARGET}) | raw (s) | denoised (s) | adaptive (s) | adaptive + denoised (s) |")
    print("|---|---|---|---|---|")
    for name, times in rows:
        base = times["raw"]
        print(f"| {name} | " + " | ".join(
            "not reached" if t is None else f"{t:.2f}" + (f" ({base / t:.1f}×)" if base and w != "raw" else "")
            for w, t in times.items()) + " |")
    print()
    for line in ladders:
        print("    " + line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
