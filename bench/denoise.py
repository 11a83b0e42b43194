#!/usr/bin/env python3
"""Denoising: relMSE against a high-sample reference of the raw beauty and of the beauty
denoised by `granular render --denoise` (Intel Open Image Denoise, guided by the albedo and
normal AOVs), at a ladder of sample counts, with each render's wall time.

relMSE is the mean over pixels and channels of (x − ref)² / (ref² + 0.01). The reference's
own noise (its raw relMSE would be about 1/ladder-ratio of the lowest count's) sets a floor
under the denoised column at high counts.

Usage: .venv/bin/python bench/denoise.py [--scenes sandcastle,snowslab] [--size 160x120]
       [--spp 4,16,64] [--ref-spp 1024] [--out out/bench/denoise]
Prints a markdown table.
"""
import argparse
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
GRANULAR = os.path.join(os.path.dirname(sys.executable), "granular")


def channels(path, names):
    import granular_core as core
    im = core.read_exr(path)
    px = np.asarray(im.pixels, dtype=np.float64)
    ch = list(im.channels)
    return px[..., [ch.index(n) for n in names]]


def render(scene, out, width, height, spp, denoise):
    cmd = [GRANULAR, "render", scene, "-o", out, "--width", str(width), "--height", str(height), "--spp", str(spp),
           "--seed", "1", "--quiet"] + (["--denoise"] if denoise else [])
    t0 = time.monotonic()
    subprocess.run(cmd, check=True)
    return time.monotonic() - t0


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="sandcastle,snowslab")
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--spp", default="4,16,64")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "denoise"))
    a = ap.parse_args()
    width, height = (int(v) for v in a.size.split("x"))
    os.makedirs(a.out, exist_ok=True)
    rgb, den = ["R", "G", "B"], ["denoised.R", "denoised.G", "denoised.B"]
    print(f"| scene ({width}×{height}) | spp | raw relMSE | denoised relMSE | raw / denoised | render + denoise (s) |")
    print("|---|---|---|---|---|---|")
    for name in a.scenes.split(","):
        scene = os.path.join(ROOT, "examples", name + ".usda")
        ref_path = os.path.join(a.out, f"{name}_ref.exr")
        render(scene, ref_path, width, height, a.ref_spp, False)
        ref = channels(ref_path, rgb)
        for spp in (int(s) for s in a.spp.split(",")):
            out = os.path.join(a.out, f"{name}_{spp}.exr")
            seconds = render(scene, out, width, height, spp, True)
            raw, d = relmse(channels(out, rgb), ref), relmse(channels(out, den), ref)
            print(f"| {name} | {spp} | {raw:.4f} | {d:.4f} | {raw / d:.1f}× | {seconds:.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
