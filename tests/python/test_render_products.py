"""`granular render` without -o: the render settings prim's products (core/render_products.h),
each an EXR of exactly its vars' channels in their pixel types; bad products refused before
anything is rendered, with no file left behind."""
import math
import os
import struct

import numpy as np
from pxr import Gf, UsdRender

import granular_core as core

from conftest import run_cli, small_scene

# EXR channel pixel types (OpenEXR file layout: chlist entries).
EXR_TYPES = {0: "uint", 1: "half", 2: "float"}


def exr_header(path):
    """{attribute name: (type name, raw bytes)} of an OpenEXR file's (single-part) header,
    read by hand so that the test does not trust the writer's own reader."""
    with open(path, "rb") as f:
        data = f.read()
    assert data[:4] == b"\x76\x2f\x31\x01", "not an OpenEXR file"
    pos, attrs = 8, {}
    while data[pos] != 0:
        name_end = data.index(b"\0", pos)
        type_end = data.index(b"\0", name_end + 1)
        size = struct.unpack_from("<i", data, type_end + 1)[0]
        value = data[type_end + 5:type_end + 5 + size]
        attrs[data[pos:name_end].decode()] = (data[name_end + 1:type_end].decode(), value)
        pos = type_end + 5 + size
    return attrs


def exr_channels(path):
    """[(channel name, pixel type)] in file order (OpenEXR sorts them by name)."""
    _, raw = exr_header(path)["channels"]
    out, pos = [], 0
    while raw[pos] != 0:
        end = raw.index(b"\0", pos)
        out.append((raw[pos:end].decode(), EXR_TYPES[struct.unpack_from("<i", raw, end + 1)[0]]))
        pos = end + 1 + 16
    return out


def exr_box(path, attr):
    return struct.unpack("<4i", exr_header(path)[attr][1])


MAIN_VARS = [("color", "color", "color4f", "raw"), ("albedo", "albedo", "color3f", "raw"),
             ("normal", "N", "normal3f", "raw"), ("depth", "z", "float", "raw"), ("id", "primId", "int", "raw")]
HALF_VARS = [("beautyHalf", "C.*", "half3", "lpe")]


def with_products(tmp_path, main_name="main.exr", main_vars=MAIN_VARS, half_name="half.exr", half_extra=None,
                  extra=None, frames=False):
    """small_scene with /Render/Settings (48x32, /World/Camera) naming two products:
    /Render/Main (main_vars) and /Render/Half (a half-float beauty at the upper half of the
    image, 2:1 pixels)."""
    def mutate(stage):
        if frames:
            stage.SetStartTimeCode(1)
            stage.SetEndTimeCode(2)
        settings = UsdRender.Settings.Define(stage, "/Render/Settings")
        settings.CreateResolutionAttr(Gf.Vec2i(48, 32))
        settings.CreateCameraRel().SetTargets(["/World/Camera"])
        stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")

        def var(name, source, type_, source_type):
            v = UsdRender.Var.Define(stage, f"/Render/Vars/{name}")
            v.CreateSourceNameAttr(source)
            v.CreateDataTypeAttr(type_)
            v.CreateSourceTypeAttr(source_type)
            return v.GetPath()

        main = UsdRender.Product.Define(stage, "/Render/Main")
        main.CreateProductNameAttr(str(tmp_path / main_name))
        main.CreateOrderedVarsRel().SetTargets([var(*v) for v in main_vars])
        half = UsdRender.Product.Define(stage, "/Render/Half")
        half.CreateProductNameAttr(str(tmp_path / half_name))
        half.CreateDataWindowNDCAttr(Gf.Vec4f(0.0, 0.5, 1.0, 1.0))
        half.CreatePixelAspectRatioAttr(2.0)
        half.CreateOrderedVarsRel().SetTargets([var(*v) for v in HALF_VARS + (half_extra or [])])
        settings.CreateProductsRel().SetTargets([main.GetPath(), half.GetPath()])
        if extra:
            extra(stage)
    return small_scene(tmp_path / "scene.usda", mutate)


def test_without_o_every_product_is_written_with_its_channels_and_types(tmp_path, capsys):
    scene = with_products(tmp_path)
    rc, _, err = run_cli(["render", scene, "--spp", "2", "--seed", "3"], capsys)
    assert rc == 0, err
    main, half = tmp_path / "main.exr", tmp_path / "half.exr"
    assert f"wrote {main}" in err and f"wrote {half}" in err
    # Each file holds exactly its vars' channels, in their types.
    assert sorted(exr_channels(main)) == sorted(
        [("R", "float"), ("G", "float"), ("B", "float"), ("A", "float"), ("albedo.R", "float"),
         ("albedo.G", "float"), ("albedo.B", "float"), ("N.X", "float"), ("N.Y", "float"), ("N.Z", "float"),
         ("Z", "float"), ("primId", "uint")])
    assert sorted(exr_channels(half)) == [("B", "half"), ("G", "half"), ("R", "half")]
    # Windows: the whole 48x32 image; the upper half (rows 0..15 from the top) of it.
    assert exr_box(main, "dataWindow") == (0, 0, 47, 31)
    assert exr_box(half, "dataWindow") == (0, 0, 47, 15)
    assert exr_box(half, "displayWindow") == (0, 0, 47, 31)
    assert struct.unpack("<f", exr_header(half)["pixelAspectRatio"][1])[0] == 2.0
    assert struct.unpack("<f", exr_header(main)["pixelAspectRatio"][1])[0] == 1.0

    # The values are the render's: the same stage through -o at the same seed and samples.
    ref = tmp_path / "ref.exr"
    rc, _, err = run_cli(["render", scene, "-o", ref, "--spp", "2", "--seed", "3", "--quiet"], capsys)
    assert rc == 0, err
    r = core.read_exr(str(ref))
    rch = list(r.channels)
    m = core.read_exr(str(main))
    for c in ("R", "G", "B", "A", "albedo.R", "N.Y", "Z"):
        np.testing.assert_array_equal(m.pixels[..., list(m.channels).index(c)], r.pixels[..., rch.index(c)], c)
    # primId: uint in the file, the film's int (-1: nothing hit) as its 32-bit pattern.
    # OpenImageIO reads a uint channel as float normalised by 2^32 - 1: undone here (exact
    # for the few small ids of this scene and for 2^32 - 1).
    ids = np.rint(m.pixels[..., list(m.channels).index("primId")].astype(np.float64) * (2**32 - 1)).astype(np.int64)
    want = r.pixels[..., rch.index("primId")].astype(np.int64)
    np.testing.assert_array_equal(np.where(want < 0, want + 2**32, want), ids)
    assert (want >= 0).any()
    h = core.read_exr(str(half))
    for c in ("R", "G", "B"):
        full = r.pixels[:16, :, rch.index(c)]
        got = h.pixels[..., list(h.channels).index(c)]
        # half: 11 significant bits, rounding to nearest.
        np.testing.assert_allclose(got, full, rtol=2.0 ** -11, atol=2.0 ** -24)


def test_an_unknown_source_name_warns_and_the_product_is_written_without_it(tmp_path, capsys):
    scene = with_products(tmp_path, half_extra=[("foo", "foo", "float", "raw")])
    rc, _, err = run_cli(["render", scene, "--spp", "1"], capsys)
    assert rc == 0, err
    assert err.count("warning: /Render/Vars/foo.sourceName:") == 1
    assert sorted(c for c, _ in exr_channels(tmp_path / "half.exr")) == ["B", "G", "R"]
    assert (tmp_path / "main.exr").exists()


def leftovers(tmp_path):
    return sorted(p.name for p in tmp_path.iterdir() if p.name not in ("scene.usda",) and p.is_file())


def test_a_product_in_a_missing_folder_is_refused_before_rendering(tmp_path, capsys):
    scene = with_products(tmp_path, half_name="no_such_folder/half.exr")
    rc, _, err = run_cli(["render", scene, "--spp", "1"], capsys)
    assert rc == 2
    assert "error: /Render/Half.productName: folder" in err and "does not exist" in err
    assert "spp" not in err.split("error:")[0]  # nothing rendered before it
    assert leftovers(tmp_path) == []


def test_a_data_type_that_does_not_fit_is_refused_with_no_file(tmp_path, capsys):
    scene = with_products(tmp_path, main_vars=MAIN_VARS[:3] + [("depth", "depth", "color3f", "raw")])
    rc, _, err = run_cli(["render", scene, "--spp", "1"], capsys)
    assert rc == 2
    assert "error: /Render/Vars/depth.dataType: color3f has 3 channels, but depth has 1" in err
    assert leftovers(tmp_path) == []


def test_no_o_and_no_products_is_a_usage_error(tmp_path, capsys):
    scene = small_scene(tmp_path / "scene.usda")
    rc, _, err = run_cli(["render", scene, "--spp", "1"], capsys)
    assert rc == 2
    assert "error: command line.-o: is required: the stage has no RenderSettings prim" in err
    scene = with_products(tmp_path, extra=lambda s: UsdRender.Settings(s.GetPrimAtPath("/Render/Settings"))
                          .GetProductsRel().SetTargets([]))
    rc, _, err = run_cli(["render", scene, "--spp", "1"], capsys)
    assert rc == 2
    assert "error: /Render/Settings.products: no render product to write" in err
    rc, _, err = run_cli(["render", scene, "--spp", "1", "--png", tmp_path / "x.png"], capsys)
    assert rc == 2 and "command line.--png: applies to -o" in err
    assert leftovers(tmp_path) == []


def test_frames_expand_frame_tokens(tmp_path, capsys):
    scene = with_products(tmp_path, main_name="main.$F4.exr", half_name="half.##.exr", frames=True)
    rc, _, err = run_cli(["render", scene, "--spp", "1", "--frames", "1:2"], capsys)
    assert rc == 0, err
    assert leftovers(tmp_path) == ["half.01.exr", "half.02.exr", "main.0001.exr", "main.0002.exr"]
    # Without --frames, the stage's start frame.
    for p in tmp_path.glob("*.exr"):
        p.unlink()
    rc, _, err = run_cli(["render", scene, "--spp", "1", "--quiet"], capsys)
    assert rc == 0, err
    assert leftovers(tmp_path) == ["half.01.exr", "main.0001.exr"]


def test_settings_option_picks_the_prim(tmp_path, capsys):
    scene = with_products(tmp_path)
    rc, _, err = run_cli(["render", scene, "--spp", "1", "--settings", "/Render/Main"], capsys)
    assert rc == 2 and 'command line.--settings: "/Render/Main" is not a RenderSettings prim' in err
    rc, _, err = run_cli(["render", scene, "--spp", "1", "--settings", "/Render/Settings", "--quiet"], capsys)
    assert rc == 0, err
    assert (tmp_path / "main.exr").exists() and (tmp_path / "half.exr").exists()
