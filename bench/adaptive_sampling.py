#!/usr/bin/env python3
"""Adaptive sampling (`--noise-threshold T`): where pixels stop, and how far from the truth.

A pixel stops once its standard error is at most T × (its luminance + 0.01) and, with its
own count, the per-sample spread its neighbours (within two pixels) had at the minimum of 16
samples meets that too (core/render.h). Without the neighbours, a pixel whose 16 first
samples happen to agree — an event of a few percent, a bounce onto a nearby bright object,
not yet made — stops there, wrong by that event's share.

Scenes (JSON, rendered through the Python bindings, EPT unless named):
1. a grey floor under a white dome with a small bright emitter beside it, found only by
   BSDF sampling (about 2.4% of a floor pixel's samples, each worth 10 times the rest);
2. a grey ball on a grey floor under a 5° sun and a dim sky;
3. the bright sand castle of `hybrid_speedup.py` (96 x 72, the hybrid).

Each is rendered at thresholds T with at most --spp samples, and once without a threshold at
--ref-spp samples (another seed) as the reference. Per threshold: the mean samples per
pixel, the share of pixels that stopped at the minimum, the render time, relMSE against the
reference (mean of (x − ref)² / (ref² + 0.01)), and the share of pixels whose luminance is
off by more than 3 T (ref + 0.01), three times what the threshold allows. With --baseline BUILD, the same for another build (each build in
its own process).

Usage: .venv/bin/python bench/adaptive_sampling.py [--thresholds 0.05,0.02] [--spp 1024]
       [--ref-spp 4096] [--build build] [--baseline OLD_BUILD] [--out out/bench/adaptive_sampling]
"""
import argparse
import copy
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def lamp_floor():
    return {
        "render": {"width": 48, "height": 48, "seed": 4, "technique": "ept"},
        "camera": {"look_at": {"eye": [0, 3, 0.001], "target": [0, 0, 0], "up": [0, 0, -1]},
                   "focal_length": 50, "horizontal_aperture": 10, "vertical_aperture": 10},
        "materials": {"grey": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]},
                      "glow": {"type": "lambert", "albedo": [0, 0, 0], "emission": [10, 10, 10]}},
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-5, -0.1, -5], "hi": [5, 0, 5]}}, "material": "grey"},
                   {"name": "lamp", "shape": {"icosphere": {"subdivisions": 2, "radius": 0.3}}, "material": "glow",
                    "transform": {"translate": [1.2, 1.0, 0]}}],
        "lights": [{"name": "sky", "type": "dome"}],
    }


def ball_on_floor():
    return {
        "render": {"width": 64, "height": 48, "seed": 4, "technique": "ept"},
        "camera": {"look_at": {"eye": [0, 0.6, 6], "target": [0, 0, 0], "up": [0, 1, 0]},
                   "focal_length": 50, "horizontal_aperture": 32, "vertical_aperture": 24},
        "materials": {"grey": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}},
        "meshes": [{"name": "ball", "shape": {"icosphere": {"subdivisions": 2, "radius": 1}}, "material": "grey"},
                   {"name": "floor", "shape": {"box": {"lo": [-20, -1.1, -20], "hi": [20, -1, 3]}}, "material": "grey"}],
        "lights": [{"name": "sun", "type": "distant", "direction": [-0.5, -1.0, -0.3], "angle": 5, "intensity": 2},
                   {"name": "sky", "type": "dome", "color": [0.02, 0.02, 0.02]}],
    }


def scenes():
    sys.path.insert(0, HERE)
    import hybrid_speedup
    castle = copy.deepcopy(hybrid_speedup.scenes()["bright sand"])
    castle["render"]["technique"] = "hybrid"
    return {"floor beside a bright emitter, dome": lamp_floor(), "ball on floor, sun and sky": ball_on_floor(),
            "bright sand castle (hybrid)": castle}


def worker(a):
    """One render in this process: --worker SCENE.json OUT.exr SPP THRESHOLD SEED; prints JSON."""
    import granular_core as core
    path, out, spp, threshold, seed = a.worker
    desc = core.load_scene_json(path)
    desc.settings.spp = int(spp)
    desc.settings.seed = int(seed)
    scene = core.Scene.build(desc)
    r = core.Renderer(scene)
    t0 = time.time()
    r.render(1, None, 0.5, noise_threshold=float(threshold))
    seconds = time.time() - t0
    core.write_exr(out, r.image())
    print(json.dumps({"seconds": seconds, "mean_spp": r.sample_counts["mean"], "minimum": r.min_adaptive_samples}))


def run(build, scene_path, out, spp, threshold, seed):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([os.path.join(build, "python"), os.path.join(ROOT, "python")]))
    p = subprocess.run([sys.executable, __file__, "--worker", scene_path, out, str(spp), str(threshold), str(seed)],
                       env=env, check=True, capture_output=True, text=True)
    return json.loads(p.stdout.strip().splitlines()[-1])


def luminance(path):
    import granular_core as core
    im = core.read_exr(path)
    px, ch = np.asarray(im.pixels, dtype=np.float64), list(im.channels)
    rgb = px[..., [ch.index(c) for c in "RGB"]]
    return rgb, rgb @ np.array([0.2126, 0.7152, 0.0722]), px[..., ch.index("sampleCount")]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--thresholds", default="0.05,0.02")
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--ref-spp", type=int, default=4096)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--baseline")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "adaptive_sampling"))
    ap.add_argument("--worker", nargs=5, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.worker:
        return worker(a)
    sys.path[:0] = [os.path.join(a.build, "python"), os.path.join(ROOT, "python")]
    os.makedirs(a.out, exist_ok=True)
    builds = [("this", a.build)] + ([("baseline", a.baseline)] if a.baseline else [])
    print("| scene | T | build | mean spp | stopped at the minimum | render s | relMSE | pixels off by > 3 T |")
    print("|---|---|---|---|---|---|---|---|")
    for i, (name, scene) in enumerate(scenes().items()):
        path = os.path.join(a.out, f"scene{i}.json")
        with open(path, "w") as f:
            json.dump(scene, f)
        ref_exr = os.path.join(a.out, f"scene{i}_ref.exr")
        run(a.build, path, ref_exr, a.ref_spp, 0.0, 99)
        ref_rgb, ref_lum, _ = luminance(ref_exr)
        for t in a.thresholds.split(","):
            for label, build in builds:
                exr = os.path.join(a.out, f"scene{i}_{label}_t{t}.exr")
                got = run(build, path, exr, a.spp, float(t), 1)
                rgb, lum, counts = luminance(exr)
                at_min = float(np.mean(counts == got["minimum"]))
                relmse = float(np.mean((rgb - ref_rgb) ** 2 / (ref_rgb ** 2 + 0.01)))
                off = float(np.mean(np.abs(lum - ref_lum) > 3 * float(t) * (ref_lum + 0.01)))
                print(f"| {name} | {t} | {label} | {got['mean_spp']:.1f} | {100 * at_min:.0f}% | {got['seconds']:.2f} | "
                      f"{relmse:.2e} | "
                      f"{100 * off:.1f}% |", flush=True)


if __name__ == "__main__":
    main()
