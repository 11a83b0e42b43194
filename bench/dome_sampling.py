#!/usr/bin/env python3
"""Sky light at reflecting surfaces: the noise a constant dome leaves, and what sampling it
over the surface's hemisphere by cosine (core/light.h) saves.

Next-event estimation at a surface that only reflects (a Lambert mesh, the exit of a
diffusion step) draws a constant dome's directions cosine-weighted over the surface's
hemisphere; over the whole sphere half of them pointed below the surface and counted nothing.
Scenes (`granular-render`, JSON):

1. a grey floor with a grey box on it under a white dome (EPT);
2. the bright sand castle of `hybrid_speedup.py` (96 x 72) under its sky alone, and under its
   sun and sky (the hybrid);
3. the snow field of `hybrid_speedup.py` under its sky alone, and under its sun and sky.

For each, the image's mean, its relative noise per sample (the root mean square over pixels
of the per-sample standard deviation, over the image's mean) and the render time; with
--baseline BUILD, the same for another build, the difference of the means (± their
combined standard error: both unbiased, it must be noise) and the speed-up at equal error,
(noise² × time) of the baseline over this build's.

Usage: .venv/bin/python bench/dome_sampling.py [--spp 64] [--build build] [--baseline OLD_BUILD]
       [--out out/bench/dome_sampling]
"""
import argparse
import copy
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import hybrid_speedup  # noqa: E402  (its scenes)


def floor_scene():
    return {
        "render": {"width": 32, "height": 32, "spp": 4, "seed": 3, "technique": "ept"},
        "camera": {"look_at": {"eye": [2.5, 2.5, 2.5], "target": [0, 0.2, 0], "up": [0, 1, 0]},
                   "focal_length": 35, "horizontal_aperture": 36, "vertical_aperture": 36},
        "materials": {"grey": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}},
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-4, -0.1, -4], "hi": [4, 0, 4]}}, "material": "grey"},
                   {"name": "box", "shape": {"box": {"lo": [-0.5, 0, -0.5], "hi": [0.5, 1, 0.5]}}, "material": "grey"}],
        "lights": [{"name": "dome", "type": "dome"}],
    }


def scenes():
    out = {"grey floor and box, dome": (floor_scene(), "ept")}
    agg = hybrid_speedup.scenes()
    for name, key in (("bright sand castle", "bright sand"), ("snow field", "snow field")):
        sunlit = agg[key]
        sky = copy.deepcopy(sunlit)
        sky["lights"] = [l for l in sky["lights"] if l["type"] == "dome"]
        out[f"{name}, sky"] = (sky, "hybrid")
        out[f"{name}, sun and sky"] = (sunlit, "hybrid")
    return out


def render(build, scene, technique, spp, path):
    with open(path + ".json", "w") as f:
        json.dump(scene, f)
    subprocess.run([os.path.join(build, "core", "granular-render"), path + ".json", "-o", path + ".exr", "--spp",
                    str(spp), "--technique", technique, "--quiet", "--stats-json", path + ".stats.json"], check=True)
    with open(path + ".stats.json") as f:
        return json.load(f)["render_s"]


def measure(core, exr, spp):
    img = core.read_exr(exr)
    px, ch = np.asarray(img.pixels), list(img.channels)
    beauty = np.stack([px[..., ch.index(c)] for c in "RGB"], -1)
    var = np.stack([px[..., ch.index(f"variance.{c}")] for c in "RGB"], -1)  # of each pixel's mean
    mean = beauty.mean()
    se = np.sqrt(var.sum()) / beauty.size  # of the image's mean
    per_sample = np.sqrt(var.mean() * spp) / mean
    return mean, se, per_sample


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--baseline", help="another build's directory, rendered alike for comparison")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "dome_sampling"))
    a = ap.parse_args()
    sys.path[:0] = [os.path.join(a.build, "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    os.makedirs(a.out, exist_ok=True)
    builds = [("this", a.build)] + ([("baseline", a.baseline)] if a.baseline else [])
    if a.baseline:
        print("| scene | mean | baseline − this, % ± s.e. | noise per sample: this / baseline "
              "| render s: this / baseline | speed-up at equal error |")
        print("|---|---|---|---|---|---|")
    else:
        print("| scene | mean ± s.e. | noise per sample | render s |")
        print("|---|---|---|---|")
    for i, (name, (scene, technique)) in enumerate(scenes().items()):
        got = {}
        for label, build in builds:
            path = os.path.join(a.out, f"scene{i}_{label}")
            t = render(build, scene, technique, a.spp, path)
            got[label] = measure(core, path + ".exr", a.spp) + (t,)
        m, se, ns, t = got["this"]
        if not a.baseline:
            print(f"| {name} | {m:.4f} ± {se:.4f} | {ns:.3f} | {t:.2f} |", flush=True)
            continue
        bm, bse, bns, bt = got["baseline"]
        diff = f"{100 * (bm / m - 1):+.2f} ± {100 * np.hypot(se, bse) / m:.2f}"
        speedup = (bns * bns * bt) / (ns * ns * t)
        print(f"| {name} | {m:.4f} | {diff} | {ns:.3f} / {bns:.3f} | {t:.2f} / {bt:.2f} | {speedup:.2f}× |",
              flush=True)


if __name__ == "__main__":
    main()
