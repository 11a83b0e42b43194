#!/usr/bin/env python3
"""usdrecord --renderSettingsPrimPath against `granular render` without -o: a stage whose
render settings name two products (beauty, albedo, normal, depth and primId vars; a
half-float beauty over half the image) must leave the same files from both front ends:
the same channels in the same pixel types and windows, and values within the noise of two
seeds of the command line (the delegate writes the products itself when its render
converges: usdrecord 24.08 only checks that they exist).

Usage: usdrecord_products.py USDRECORD PYTHON OUTDIR SCENE.usda
(USDRECORD runs with the OpenUSD build's Python, $GRANULAR_USD_PYTHONPATH and
$GRANULAR_HD_PLUGINPATH; PYTHON runs `granular.cli` with granular_core on its path.)
"""
import os
import struct
import subprocess
import sys

import numpy as np

import granular_core as core
from pxr import Gf, Usd, UsdGeom, UsdRender

from usdrecord_run import run_usdrecord
from usdrecord_vs_granular import widened_sun

WIDTH, SPP = 64, 16  # 16: the delegate's default samples per pixel


def products_stage(scene, outdir, tag, frames=False):
    """A stage over `scene` (its sun widened, usdrecord_vs_granular.py) with /Render/Settings
    naming /Render/Main and /Render/Half, written into outdir/tag/; with `frames`, frames 1
    and 2 and frame tokens in the product names."""
    folder = os.path.join(outdir, tag)
    os.makedirs(folder, exist_ok=True)
    for name in os.listdir(folder):
        if name.endswith(".exr"):
            os.remove(os.path.join(folder, name))
    path = widened_sun(scene, folder)
    stage = Usd.Stage.Open(path)
    if frames:
        stage.SetStartTimeCode(1)
        stage.SetEndTimeCode(2)
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
    height = int(WIDTH * cam.GetVerticalApertureAttr().Get() / cam.GetHorizontalApertureAttr().Get())
    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.CreateResolutionAttr(Gf.Vec2i(WIDTH, height))
    settings.CreateCameraRel().SetTargets(["/World/Camera"])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")

    def var(name, source, data_type, source_type="raw"):
        v = UsdRender.Var.Define(stage, f"/Render/Vars/{name}")
        v.CreateSourceNameAttr(source)
        v.CreateDataTypeAttr(data_type)
        v.CreateSourceTypeAttr(source_type)
        return v.GetPath()

    main = UsdRender.Product.Define(stage, "/Render/Main")
    main.CreateProductNameAttr(os.path.join(folder, "main.$F4.exr" if frames else "main.exr"))
    main.CreateOrderedVarsRel().SetTargets([var("color", "color", "color4f"), var("albedo", "albedo", "color3f"),
                                           var("normal", "N", "normal3f"), var("depth", "z", "float"),
                                           var("id", "primId", "int"),
                                           var("cryptoObject", "CryptoObject00", "color4f"),
                                           var("cryptoMaterial", "CryptoMaterial00", "color4f")])
    half = UsdRender.Product.Define(stage, "/Render/Half")
    half.CreateProductNameAttr(os.path.join(folder, "half.####.exr" if frames else "half.exr"))
    half.CreateDataWindowNDCAttr(Gf.Vec4f(0.0, 0.5, 1.0, 1.0))
    half.CreateOrderedVarsRel().SetTargets([var("beauty", "C.*", "half3", "lpe")])
    settings.CreateProductsRel().SetTargets([main.GetPath(), half.GetPath()])
    stage.GetRootLayer().Save()
    if frames:
        return path, [os.path.join(folder, f"{p}.000{f}.exr") for f in (1, 2) for p in ("main", "half")]
    return path, [os.path.join(folder, "main.exr"), os.path.join(folder, "half.exr")]


def exr_pixel_types(path):
    """{channel: 0 uint, 1 half, 2 float} from the EXR header's chlist, read by hand."""
    with open(path, "rb") as f:
        data = f.read()
    pos = 8
    while data[pos] != 0:
        name_end = data.index(b"\0", pos)
        type_end = data.index(b"\0", name_end + 1)
        size = struct.unpack_from("<i", data, type_end + 1)[0]
        if data[pos:name_end] == b"channels":
            raw, out, k = data[type_end + 5:type_end + 5 + size], {}, 0
            while raw[k] != 0:
                end = raw.index(b"\0", k)
                out[raw[k:end].decode()] = struct.unpack_from("<i", raw, end + 1)[0]
                k = end + 17
            return out
        pos = type_end + 5 + size
    return {}


def exr_layout(path):
    """(channels with pixel types, (x, y, width, height, full width, full height)) of an EXR."""
    img = core.read_exr(path)
    return exr_pixel_types(path), (img.x, img.y, img.width, img.height, img.full_width, img.full_height)


def main():
    usdrecord, python, outdir, scene = sys.argv[1:5]
    env = dict(os.environ)
    # usdrecord runs on the OpenUSD build's Python and finds the delegate there.
    env["PYTHONPATH"] = os.environ.get("GRANULAR_USD_PYTHONPATH", "")
    env["PXR_PLUGINPATH_NAME"] = os.environ.get("GRANULAR_HD_PLUGINPATH", "")
    stage_h, files_h = products_stage(scene, outdir, "hydra")
    stage_g, files_g = products_stage(scene, outdir, "granular")
    stage_o, files_o = products_stage(scene, outdir, "granular_seed1")
    run_usdrecord([usdrecord, "--disableGpu", "--renderer", "Granular", "--enableDomeLightVisibility",
                   "--imageWidth", str(WIDTH), "--camera", "/World/Camera", "--renderSettingsPrimPath",
                   "/Render/Settings", stage_h, os.path.join(outdir, "hydra", "fallback.png")], files_h, env=env)
    for stage, seed in ((stage_g, 0), (stage_o, 1)):
        subprocess.run([python, "-m", "granular.cli", "render", stage, "--spp", str(SPP), "--seed", str(seed),
                        "--quiet"], check=True)
    failed = False
    # Frame tokens: usdrecord --frames 1:2 and granular render --frames 1:2 write the same
    # files (usdrecord 24.08 looks for the product names unexpanded, so it warns and also
    # writes its own image; the delegate writes a frame that is not rendered again, the
    # scene holding still, from the last converged image).
    stage_f, files_f = products_stage(scene, outdir, "hydra_frames", frames=True)
    run_usdrecord([usdrecord, "--disableGpu", "--renderer", "Granular", "--imageWidth", str(WIDTH), "--camera",
                   "/World/Camera", "--renderSettingsPrimPath", "/Render/Settings", "--frames", "1:2", stage_f,
                   os.path.join(outdir, "hydra_frames", "fallback.####.png")], files_f, env=env)
    stage_fg, files_fg = products_stage(scene, outdir, "granular_frames", frames=True)
    subprocess.run([python, "-m", "granular.cli", "render", stage_fg, "--spp", "1", "--frames", "1:2", "--quiet"],
                   check=True)
    for fh, fg in zip(files_f, files_fg):
        if not os.path.exists(fg) or exr_layout(fh) != exr_layout(fg):
            print(f"{fh}: not as granular render's {fg}")
            failed = True
    print("| product | channel | mean (Hydra) | mean (granular) | tolerance | relMSE Hydra vs granular | "
          "relMSE two seeds |")
    print("|---|---|---|---|---|---|---|")
    for fh, fg, fo in zip(files_h, files_g, files_o):
        if exr_layout(fh) != exr_layout(fg):
            print(f"{fh}: layout {exr_layout(fh)} differs from granular render's {exr_layout(fg)}")
            failed = True
            continue
        h, g, o = core.read_exr(fh), core.read_exr(fg), core.read_exr(fo)
        ch = list(h.channels)
        # The Cryptomatte layers' names, hashes and manifests: the same objects and materials.
        meta = [{k: v for k, v in img.attributes if k.startswith("cryptomatte/")} for img in (h, g)]
        if any("CryptoObject00.R" in img.channels for img in (h, g)):
            if not meta[0] or meta[0] != meta[1]:
                print(f"{fh}: Cryptomatte metadata {meta[0]} differs from granular render's {meta[1]}")
                failed = True
        for c in ch:
            a, b, n = (img.pixels[..., list(img.channels).index(c)].astype(np.float64) for img in (h, g, o))
            if c == "primId":
                # OpenImageIO reads a uint channel normalised by 2^32 - 1 (-1, nothing hit: 1.0).
                a, b = np.rint(a * (2**32 - 1)), np.rint(b * (2**32 - 1))
                # Ids are each front end's own numbering; what was hit must agree.
                agree = np.mean((a == 2**32 - 1) == (b == 2**32 - 1))
                print(f"| {os.path.basename(fh)} | {c} | hit {np.mean(a != 2**32 - 1):.3f} | "
                      f"hit {np.mean(b != 2**32 - 1):.3f} | 0.98 | agree {agree:.3f} | |")
                failed |= agree < 0.98
                continue
            finite = np.isfinite(a) & np.isfinite(b) & np.isfinite(n)
            if c == "Z":
                failed |= bool(np.any(np.isfinite(a) != np.isfinite(b)) and
                               np.mean(np.isfinite(a) != np.isfinite(b)) > 0.02)
            a, b, n = a[finite], b[finite], n[finite]
            # Two seeds give the noise: each pixel's variance is half their squared difference.
            se = np.sqrt(np.sum((b - n) ** 2) / 2.0) / max(a.size, 1)
            tol = max(0.01 * max(abs(b.mean()), 1e-3), 4.0 * se)
            scale = np.mean(b ** 2) + 1e-12
            rel_h, rel_n = np.mean((a - b) ** 2) / scale, np.mean((b - n) ** 2) / scale
            print(f"| {os.path.basename(fh)} | {c} | {a.mean():.5g} | {b.mean():.5g} | {tol:.3g} | {rel_h:.3g} | "
                  f"{rel_n:.3g} |")
            failed |= abs(a.mean() - b.mean()) > tol or rel_h > max(rel_n, 1e-6)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
