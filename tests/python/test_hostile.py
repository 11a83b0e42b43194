"""Hostile input and shared outputs through `granular render` and `granular merge`: prototypes
that make no sense, textures replaced behind the cache's back, texels that are not finite,
image headers that claim more than any reader allocates, planted links and two renders
writing one file. Each ends in one `error:` line naming the prim and attribute with exit 2,
or in a complete image; never in a crash, a clobbered file or a stale image."""
import os
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest
from conftest import BUILD, ROOT, run_cli, small_scene
from pxr import Sdf, UsdLux

import granular_core as core
from test_textures import _texture_png, textured_view

SMALL = ["--width", 16, "--height", 16, "--spp", 1]


def _render_error(tmp_path, capsys, mutate):
    scene = small_scene(tmp_path / "s.usda", mutate)
    out = tmp_path / "out.exr"
    rc, _, err = run_cli(["render", scene, "-o", out, *SMALL], capsys)
    assert rc == 2, err
    assert not out.exists()
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


# ---- prototypes ------------------------------------------------------------------------------

def _prototypes(paths):
    def mutate(stage):
        stage.GetPrimAtPath("/World/Castle").GetAttribute("primvars:granular:prototypes").Set(paths)
        stage.GetPrimAtPath("/World/Castle").GetAttribute("primvars:granular:weights").Set([1.0] * len(paths))
    return mutate


def _tower(names):
    """A second aggregate, /World/Tower (a copy of the castle), naming `names` as grains."""
    def mutate(stage):
        Sdf.CopySpec(stage.GetRootLayer(), "/World/Castle", stage.GetRootLayer(), "/World/Tower")
        tower = stage.GetPrimAtPath("/World/Tower")
        tower.GetAttribute("primvars:granular:prototypes").Set(names)
        tower.GetAttribute("primvars:granular:weights").Set([1.0] * len(names))
    return mutate


def _both(*mutations):
    def mutate(stage):
        for m in mutations:
            m(stage)
    return mutate


@pytest.mark.parametrize("case", ["itself", "another aggregate", "each other"])
def test_an_aggregate_as_a_grain_is_refused_by_name(case, tmp_path, capsys):
    c = "error: /World/Castle.primvars:granular:prototypes: prototype"
    if case == "itself":
        mutate, expected = _prototypes(["../Grains/A", "."]), f'{c} "." (/World/Castle) is this aggregate itself'
    elif case == "another aggregate":
        mutate = _both(_tower(["../Grains/A"]), _prototypes(["../Tower"]))
        expected = f'{c} "../Tower" (/World/Tower) is itself an aggregate (GranularAggregateAPI): a grain ' \
                   f'prototype is a plain mesh'
    else:
        mutate = _both(_tower(["../Castle"]), _prototypes(["../Tower"]))
        expected = f'{c} "../Tower" (/World/Tower) is itself an aggregate (GranularAggregateAPI): a grain ' \
                   f'prototype is a plain mesh'
    assert _render_error(tmp_path, capsys, mutate) == expected


# ---- textures --------------------------------------------------------------------------------

def _left_right(scene, out, capsys):
    rc, _, err = run_cli(["render", scene, "-o", out, "--width", 32, "--height", 32, "--spp", 4], capsys)
    assert rc == 0, err
    rgb = np.asarray(core.read_exr(str(out)).pixels)[..., :3]
    return rgb[8:24, 2:6].reshape(-1, 3).mean(axis=0), rgb[8:24, 26:30].reshape(-1, 3).mean(axis=0)


def test_a_texture_replaced_keeping_size_and_time_is_read_anew(tmp_path, capsys):
    """cp -p and rsync -a keep a file's size and modification time; the sRGB texture's cached
    linear copy must still follow the new content (its key once held whole seconds only)."""
    png = tmp_path / "t.png"
    _texture_png(png, [(0.8, 0.1, 0.1), (0.1, 0.8, 0.1)])  # red | green
    scene = small_scene(tmp_path / "s.usda", textured_view(png))
    left, right = _left_right(scene, tmp_path / "a.exr", capsys)
    assert left[0] > 4 * left[1] and right[1] > 4 * right[0], (left, right)
    before = os.stat(png)
    swapped = tmp_path / "swapped.png"
    _texture_png(swapped, [(0.1, 0.8, 0.1), (0.8, 0.1, 0.1)])  # green | red
    # Of the same size: readers stop at IEND, so the shorter file is padded after it.
    data, size = swapped.read_bytes(), before.st_size
    if len(data) < size:
        swapped.write_bytes(data + b"\0" * (size - len(data)))
    else:
        png.write_bytes(png.read_bytes() + b"\0" * (len(data) - size))
        os.utime(png, ns=(before.st_atime_ns, before.st_mtime_ns))
        before = os.stat(png)
        left, right = _left_right(scene, tmp_path / "a.exr", capsys)  # as first seen, at this size
        assert left[0] > 4 * left[1] and right[1] > 4 * right[0], (left, right)
    assert os.path.getsize(swapped) == before.st_size
    os.replace(swapped, png)
    os.utime(png, ns=(before.st_atime_ns, before.st_mtime_ns))
    left, right = _left_right(scene, tmp_path / "b.exr", capsys)
    assert left[1] > 4 * left[0] and right[0] > 4 * right[1], (left, right)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_a_dome_texture_with_texels_that_are_not_finite_is_refused_by_name(bad, tmp_path, capsys):
    sky = tmp_path / "sky.exr"
    texels = np.full((4, 8, 3), 0.5, dtype=np.float32)
    texels[1, 2, 0] = bad
    core.write_exr(str(sky), core.Image(texels, ["R", "G", "B"]))

    def mutate(stage):
        UsdLux.DomeLight.Define(stage, "/World/Sky").CreateTextureFileAttr(Sdf.AssetPath(str(sky)))
    assert _render_error(tmp_path, capsys, mutate) == \
        f'error: /World/Sky.inputs:texture:file: "{sky}" has 1 texel values that are not finite (NaN or infinity)'


def _png_claiming(path, width, height):
    """A PNG whose header claims width x height RGB pixels, with a few bytes of data."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xffffffff)
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) +
                     chunk(b"IEND", b""))
    return path


def test_an_image_header_claiming_too_many_pixels_is_refused_before_reading(tmp_path, capsys):
    png = _png_claiming(tmp_path / "huge.png", 60000, 30000)

    def mutate(stage):
        UsdLux.DomeLight.Define(stage, "/World/Sky").CreateTextureFileAttr(Sdf.AssetPath(str(png)))
    line = _render_error(tmp_path, capsys, mutate)
    assert line.startswith("error: /World/Sky.inputs:texture:file: cannot read image: its header says 60000x30000 "
                           "with 3 channels, beyond the limit of 65536 pixels a side, 268435456 pixels in all"), line


# ---- merge -------------------------------------------------------------------------------------

def test_merge_refuses_a_tile_that_is_not_one_of_ours(tmp_path, capsys):
    """An 8-bit sRGB PNG holds display values, not linear radiance: never merged as a tile."""
    png = _texture_png(tmp_path / "tile.png", [(0.5, 0.5, 0.5), (0.2, 0.2, 0.2)])
    out = tmp_path / "merged.exr"
    rc, _, err = run_cli(["merge", png, "-o", out], capsys)
    assert rc == 2, err
    assert err.strip() == f"error: {png}: is not a tile of granular render (an OpenEXR it wrote, read as png): merge " \
                          f"joins only those, whose pixels are linear radiance"
    assert not out.exists()


# ---- outputs -------------------------------------------------------------------------------

def test_a_link_planted_beside_the_output_is_never_followed(tmp_path, capsys):
    """The temporary file is new (O_EXCL, a name nobody can guess): a link where the former
    fixed name OUT.exr.tmp was, pointing at another file, leaves that file as it was."""
    victim = tmp_path / "precious.txt"
    victim.write_text("keep me")
    out = tmp_path / "out.exr"
    os.symlink(victim, str(out) + ".tmp")
    scene = small_scene(tmp_path / "s.usda")
    rc, _, err = run_cli(["render", scene, "-o", out, *SMALL], capsys)
    assert rc == 0, err
    assert victim.read_text() == "keep me"
    assert core.read_exr(str(out)).width == 16
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr", "out.exr.tmp", "precious.txt", "s.usda"]


def test_two_renders_writing_one_file_leave_one_whole_image_and_the_later_says_so(tmp_path):
    scene = small_scene(tmp_path / "s.usda")
    out = tmp_path / "out.exr"
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "python"), str(BUILD / "python")]))
    args = [sys.executable, "-m", "granular.cli", "render", str(scene), "-o", str(out), "--width", "64", "--height",
            "48", "--spp", "1024", "--threads", "1", "--roulette", "0.5"]
    procs = [subprocess.Popen(args + ["--seed", str(seed)], stderr=subprocess.PIPE, text=True, env=env)
             for seed in (1, 2)]
    errs = [p.communicate(timeout=300)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    image = np.asarray(core.read_exr(str(out)).pixels)
    # The file is one process's image, whole: the one that wrote last, which said so.
    said = [e for e in errs if "was written by another process during this render" in e]
    assert len(said) == 1, errs
    writer = errs.index(said[0])
    reference = tmp_path / "reference.exr"
    rc = subprocess.run(args[:6] + [str(reference)] + args[7:] + ["--seed", str(1 + writer)], env=env,
                        capture_output=True).returncode
    assert rc == 0
    np.testing.assert_array_equal(image, np.asarray(core.read_exr(str(reference)).pixels))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.exr", "reference.exr", "s.usda"], "temporaries left"
