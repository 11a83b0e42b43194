#!/usr/bin/env python3
"""Transform motion blur of an aggregate through both front ends: a box of sand grains that
slides and turns over the camera's open shutter (tests/python/aggregate_motion_stage.py),
rendered by usdrecord --camera (hdGranular samples the aggregate's transform from the scene
delegate) and by `granular render` (usd-core's transforms at the shutter's ends), must give
the same image: at the same seed closer than two seeds of the command line are, and the
means within their noise; and the blur must show (granular render's still frame differs
from the Hydra image far more than two seeds differ, over 4 x 4 pixel blocks). At 16
samples a pixel the sun's glints on single grains make the variance AOV too rough for
noise_check.py's block test (two seeds of granular render fail it): the seeds are the noise.
The stage runs at 48 time codes per second: transform blur is in time codes, so the rate
must not matter.

Usage: usdrecord_aggregate_motion_blur.py USDRECORD GRANULAR COMPARE OUTDIR
(USDRECORD runs with the OpenUSD build's Python, $GRANULAR_USD_PYTHONPATH and
$GRANULAR_HD_PLUGINPATH; GRANULAR is the venv's command; COMPARE is
build/bench/granular-compare.)
"""
import json
import os
import subprocess
import sys

from usdrecord_motion_blur import block_difference
from usdrecord_run import run_usdrecord
from usdrecord_vs_granular import mean_tolerance

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
import aggregate_motion_stage  # noqa: E402

WIDTH, HEIGHT, SPP = 48, 32, 16  # 36 x 24 aperture; 16: the delegate's default samples per pixel


def main():
    usdrecord, granular, compare, outdir = sys.argv[1:5]
    os.makedirs(outdir, exist_ok=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.environ.get("GRANULAR_USD_PYTHONPATH", "")
    env["PXR_PLUGINPATH_NAME"] = os.environ.get("GRANULAR_HD_PLUGINPATH", "")
    # 30 degrees in two frames: 15 over the shutter (a linear blend pinches it by 0.9%).
    stage = aggregate_motion_stage.write_stage(os.path.join(outdir, "sliding.usda"), 48, (-0.5, 0.5), turn=30.0)
    out = {k: os.path.join(outdir, k + ".1.exr") for k in ("hydra", "ours", "ours_seed1", "ours_still")}
    written = os.path.join(outdir, "hydra_image.1.exr")
    run_usdrecord([usdrecord, "--disableGpu", "--renderer", "Granular", "--enableDomeLightVisibility",
                   "--imageWidth", str(WIDTH), "--camera", "/World/Camera", "--frames", "1", stage,
                   os.path.join(outdir, "hydra_image.#.exr")], [written], env=env)
    os.replace(written, out["hydra"])

    def render(image, seed, *extra):
        subprocess.run([granular, "render", stage, "-o", image.replace(".1.exr", ".#.exr"), "--width", str(WIDTH),
                        "--height", str(HEIGHT), "--spp", str(SPP), "--seed", str(seed), "--camera", "/World/Camera",
                        "--frames", "1", "--quiet", *extra], check=True)
    render(out["ours"], 0)
    render(out["ours_seed1"], 1)
    render(out["ours_still"], 1, "--no-motion-blur")

    def cmp(a, b):
        return json.loads(subprocess.run([compare, out[a], out[b]], check=True, capture_output=True,
                                         text=True).stdout)
    failed = False
    # Same seed: the images differ only where the cameras' rounding moves a path, so by less
    # than two seeds do, and the means by less than 1% or four standard errors.
    r, noise = cmp("hydra", "ours"), cmp("ours_seed1", "ours")
    tol = mean_tolerance(out["ours"], out["ours_seed1"])
    print("| comparison | bias | tolerance | relMSE | relMSE (two seeds) |")
    print("|---|---|---|---|---|")
    print(f"| hydra vs ours | {r['bias']:+.5f} | {tol:.5f} | {r['relmse']:.3g} | {noise['relmse']:.3g} |")
    failed |= abs(r["bias"]) > tol or r["relmse"] > noise["relmse"]
    # The blur shows in Hydra's image: over 4 x 4 pixel blocks (where the noise averages down
    # and the smear does not), the still frame differs from it far more than two seeds differ.
    blur = block_difference(out["ours_still"], out["hydra"])
    noise = block_difference(out["ours_seed1"], out["ours"])
    print(f"| ours_still vs hydra, 4x4 blocks | | | {blur:.3g} | {noise:.3g} |")
    failed |= not blur > 4 * noise
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
