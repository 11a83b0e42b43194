#!/usr/bin/env python3
"""Transform motion blur through both front ends: a box that slides and turns over the
camera's open shutter, rendered by usdrecord (hdGranular samples its transform from the
scene delegate) and by `granular render` (usd-core's transforms at the shutter's ends),
must give the same image within the noise of two seeds of the command line; the blur must
show (the blurred image differs from the still frame far beyond that noise); and the
render settings' disableMotionBlur must give the still frame in both. The stage runs at 48
time codes per second: transform blur is in time codes, so the rate must not matter.

Usage: usdrecord_motion_blur.py USDRECORD GRANULAR COMPARE OUTDIR
(USDRECORD runs with the OpenUSD build's Python, $GRANULAR_USD_PYTHONPATH and
$GRANULAR_HD_PLUGINPATH; GRANULAR is the venv's command; COMPARE is
build/bench/granular-compare.)
"""
import json
import os
import subprocess
import sys

import numpy as np

import granular_core as core
from pxr import Gf, Usd, UsdGeom, UsdLux, UsdRender

from usdrecord_run import run_usdrecord
from usdrecord_vs_granular import mean_tolerance

WIDTH, HEIGHT, SPP = 48, 32, 16  # 36 x 24 aperture; 16: the delegate's default samples per pixel


def write_stage(path, disable=False, outdir=None):
    """Floor, a box sliding 1.2 units and turning 45 degrees per frame about frame 1, a dome;
    the camera's shutter open over [-0.5, 0.5] frames. With `disable`, an active render
    settings prim (with one product, through which Hydra hands the value on) says
    disableMotionBlur."""
    stage = Usd.Stage.CreateNew(path)
    stage.SetTimeCodesPerSecond(48)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(1)
    UsdGeom.Xform.Define(stage, "/World")
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(24.0)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 100))
    cam.CreateShutterOpenAttr(-0.5)
    cam.CreateShutterCloseAttr(0.5)
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 1.2, 3.2))
    cam.AddRotateXOp().Set(-20.0)
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    UsdLux.DistantLight.Define(stage, "/World/Sun").CreateIntensityAttr(2.0)

    def box(name, lo, hi, color):
        m = UsdGeom.Mesh.Define(stage, name)
        pts = [Gf.Vec3f(hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2])
               for i in range(8)]
        faces = [(0, 4, 6, 2), (1, 3, 7, 5), (0, 1, 5, 4), (2, 6, 7, 3), (0, 2, 3, 1), (4, 5, 7, 6)]
        m.CreatePointsAttr(pts)
        m.CreateFaceVertexCountsAttr([4] * 6)
        m.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
        m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        m.CreateDisplayColorAttr([Gf.Vec3f(*color)])
        return m
    box("/World/Floor", (-3, -0.1, -3), (3, 0, 3), (0.5, 0.5, 0.5))
    mover = box("/World/Box", (-0.35, 0, -0.35), (0.35, 0.7, 0.35), (0.9, 0.3, 0.1))
    translate, rotate = mover.AddTranslateOp(), mover.AddRotateYOp()
    for t, x, angle in ((0, -1.2, 0.0), (2, 1.2, 90.0)):
        translate.Set(Gf.Vec3d(x, 0, 0), t)
        rotate.Set(angle, t)
    if disable:
        settings = UsdRender.Settings.Define(stage, "/Render/Settings")
        settings.CreateResolutionAttr(Gf.Vec2i(WIDTH, HEIGHT))
        settings.CreateCameraRel().SetTargets(["/World/Camera"])
        settings.CreateDisableMotionBlurAttr(True)
        product = UsdRender.Product.Define(stage, "/Render/Main")
        product.CreateProductNameAttr(os.path.join(outdir, "product_disabled.exr"))
        var = UsdRender.Var.Define(stage, "/Render/Vars/color")
        var.CreateSourceNameAttr("color")
        var.CreateDataTypeAttr("color4f")
        product.CreateOrderedVarsRel().SetTargets([var.GetPath()])
        settings.CreateProductsRel().SetTargets([product.GetPath()])
        stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    stage.GetRootLayer().Save()
    return path


def block_difference(a, b):
    """Sum of squared differences of the two images' 4 x 4 pixel block means (RGB)."""
    def blocks(path):
        x = np.asarray(core.read_image_rgb(path).pixels, dtype=np.float64)[..., :3]
        h, w = x.shape[0] // 4 * 4, x.shape[1] // 4 * 4
        return x[:h, :w].reshape(h // 4, 4, w // 4, 4, 3).mean(axis=(1, 3))
    return float(np.sum((blocks(a) - blocks(b)) ** 2))


def main():
    usdrecord, granular, compare, outdir = sys.argv[1:5]
    os.makedirs(outdir, exist_ok=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.environ.get("GRANULAR_USD_PYTHONPATH", "")
    env["PXR_PLUGINPATH_NAME"] = os.environ.get("GRANULAR_HD_PLUGINPATH", "")
    moving = write_stage(os.path.join(outdir, "moving.usda"))
    disabled = write_stage(os.path.join(outdir, "disabled.usda"), disable=True, outdir=outdir)
    # Frame 1 of each (usdrecord and --frames name files by a run of '#').
    out = {k: os.path.join(outdir, k + ".1.exr") for k in
           ("hydra", "hydra_disabled", "ours", "ours_seed1", "ours_still", "ours_still_seed1", "ours_disabled")}

    def record(stage, image, *extra):
        run_usdrecord([usdrecord, "--disableGpu", "--renderer", "Granular", "--enableDomeLightVisibility",
                       "--imageWidth", str(WIDTH), "--camera", "/World/Camera", "--frames", "1", *extra, stage,
                       os.path.join(outdir, "hydra_image.#.exr")], [image], env=env)
        if image != out["hydra"]:
            return
        os.replace(os.path.join(outdir, "hydra_image.1.exr"), image)

    def render(stage, image, seed=0, *extra):
        subprocess.run([granular, "render", stage, "-o", image.replace(".1.exr", ".#.exr"), "--width", str(WIDTH), "--height", str(HEIGHT),
                        "--spp", str(SPP), "--seed", str(seed), "--camera", "/World/Camera", "--frames", "1",
                        "--quiet", *extra], check=True)

    record(moving, out["hydra"])
    # With a render settings prim, usdrecord leaves the image to its product (the delegate
    # writes it when the render converges).
    out["hydra_disabled"] = os.path.join(outdir, "product_disabled.exr")
    record(disabled, out["hydra_disabled"], "--renderSettingsPrimPath", "/Render/Settings")
    render(moving, out["ours"])
    render(moving, out["ours_seed1"], 1)
    render(moving, out["ours_still"], 0, "--no-motion-blur")
    render(moving, out["ours_still_seed1"], 1, "--no-motion-blur")
    render(disabled, out["ours_disabled"])

    def cmp(a, b):
        return json.loads(subprocess.run([compare, out[a], out[b]], check=True, capture_output=True,
                                         text=True).stdout)
    failed = False
    print("| comparison | bias | tolerance | relMSE | relMSE (two seeds) |")
    print("|---|---|---|---|---|")
    # Same seed: the images differ only where the cameras' rounding moves a path, so by less
    # than two seeds do, and the means by less than 1% or four standard errors.
    for test, ref, other in (("hydra", "ours", "ours_seed1"), ("hydra_disabled", "ours_still", "ours_still_seed1")):
        r, noise = cmp(test, ref), cmp(other, ref)
        tol = mean_tolerance(out[ref], out[other])
        print(f"| {test} vs {ref} | {r['bias']:+.5f} | {tol:.5f} | {r['relmse']:.3g} | {noise['relmse']:.3g} |")
        failed |= abs(r["bias"]) > tol or r["relmse"] > noise["relmse"]
    # disableMotionBlur read by granular render: the still frame's description, bit for bit.
    r = cmp("ours_disabled", "ours_still")
    print(f"| ours_disabled vs ours_still | {r['bias']:+.5f} | 0 | {r['relmse']:.3g} | |")
    failed |= r["relmse"] != 0
    # The blur shows: over 4 x 4 pixel blocks (where the noise averages down and the smear
    # does not), the still frame differs from the blurred one far more than two seeds do
    # (without blur the two differences would have the same expectation; measured 12x).
    blur, noise = block_difference(out["ours_still"], out["ours"]), block_difference(out["ours_seed1"], out["ours"])
    print(f"| ours_still vs ours, 4x4 blocks | | | {blur:.3g} | {noise:.3g} |")
    failed |= not blur > 4 * noise
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
