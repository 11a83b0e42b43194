#!/usr/bin/env python3
"""usdrecord --disableGpu --renderer Granular against `granular render`, at equal samples
and seed: the same core and the same per-pixel random streams, so the images may differ
only by the cameras' float rounding. Prints a table; exits 1 on a mismatch.

Usage: usdrecord_vs_granular.py USDRECORD GRANULAR COMPARE OUTDIR [EXAMPLE.usda ...]
(USDRECORD runs with the OpenUSD build's Python and $GRANULAR_USD_PYTHONPATH, GRANULAR is the venv's command, COMPARE
is build/bench/granular-compare.)
"""
import json
import os
import subprocess
import sys

from pxr import Usd, UsdGeom


def main():
    usdrecord, granular, compare, outdir, *scenes = sys.argv[1:]
    os.makedirs(outdir, exist_ok=True)
    width, spp, failed = 64, 16, False  # 16: the delegate's default samples per pixel
    print("| scene | bias | relMSE |")
    print("|---|---|---|")
    for scene in scenes:
        name = os.path.splitext(os.path.basename(scene))[0]
        cam = UsdGeom.Camera(Usd.Stage.Open(scene).GetPrimAtPath("/World/Camera"))
        h_ap, v_ap = cam.GetHorizontalApertureAttr().Get(), cam.GetVerticalApertureAttr().Get()
        height = int(round(width * v_ap / h_ap))
        hydra, ours = os.path.join(outdir, name + "_hydra.exr"), os.path.join(outdir, name + "_granular.exr")
        env = dict(os.environ)
        # usdrecord runs on the OpenUSD build's Python: its pxr, not this venv's usd-core.
        env["PYTHONPATH"] = os.environ.get("GRANULAR_USD_PYTHONPATH", "")
        subprocess.run([usdrecord, "--disableGpu", "--renderer", "Granular", "--enableDomeLightVisibility",
                        "--imageWidth", str(width),
                        "--camera", "/World/Camera", scene, hydra], check=True, env=env)
        subprocess.run([granular, "render", scene, "-o", ours, "--width", str(width), "--height", str(height),
                        "--spp", str(spp), "--seed", "0", "--camera", "/World/Camera", "--quiet"], check=True)
        r = json.loads(subprocess.run([compare, hydra, ours], check=True, capture_output=True, text=True).stdout)
        print(f"| {name} | {r['bias']:+.5f} | {r['relmse']:.3g} |")
        failed |= abs(r["bias"]) > 0.01 or r["relmse"] > 0.01
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
