"""Tiles and the farm: `granular render --crop` (and UsdRenderSettings dataWindowNDC) renders
only a window of the image, `granular merge` joins such tiles, and `granular farm` renders a
frame sequence as Dask tasks of frames x tiles; in every case the result is the single-process
full render bit for bit (a pixel's samples depend on the seed, the pixel and the sample index
only; the roulette pre-render always covers the whole image). Comparisons are exact: equal
float32 values in every channel."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, BUILD, run_cli, run_script, small_scene
from pxr import Gf, UsdGeom, UsdLux, UsdRender, Vt

import granular_core as core
from granular.farm import grid, tile_windows
from granular.usd_reader import ndc_to_pixels

SIZE = ["--width", 40, "--height", 30, "--spp", 4, "--seed", 5]
DASK = Path(sys.executable).parent / "dask"


def _exr(path):
    img = core.read_exr(str(path))
    return img, {name: img.pixels[..., k] for k, name in enumerate(img.channels)}


def _same(a, b):
    """Two EXRs hold the same pixels in the same place, bit for bit."""
    (ia, ca), (ib, cb) = _exr(a), _exr(b)
    assert (ia.width, ia.height, ia.x, ia.y, ia.full_width, ia.full_height) == \
        (ib.width, ib.height, ib.x, ib.y, ib.full_width, ib.full_height)
    assert sorted(ca) == sorted(cb)
    for name in ca:
        assert np.array_equal(ca[name].view(np.uint32), cb[name].view(np.uint32)), name


def _animated(stage):
    """Frames 1 to 2, a camera that moves and a sun that brightens, over a ground."""
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(2)
    ground = UsdGeom.Mesh.Define(stage, "/World/Floor")
    ground.CreatePointsAttr(Vt.Vec3fArray([(-3, 0, -3), (-3, 0, 3), (3, 0, 3), (3, 0, -3)]))
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    ground.CreateDisplayColorAttr([(0.5, 0.45, 0.4)])
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/World/Camera")).GetOrderedXformOps()[0]
    op.GetAttr().Clear()
    for t, eye in {1: (1.0, 0.8, 1.2), 2: (1.3, 0.7, 0.9)}.items():
        op.Set(Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(0, 0.15, 0), Gf.Vec3d(0, 1, 0)).GetInverse(), t)
    sun = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun"))
    sun.GetIntensityAttr().Set(5.0, 1)
    sun.GetIntensityAttr().Set(8.0, 2)


# ---- tiles ---------------------------------------------------------------------------------

@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 7, 12, 16, 64])
@pytest.mark.parametrize("window", [(0, 40, 0, 30), (3, 10, 5, 6), (0, 1, 0, 1), (7, 19, 2, 33)])
def test_tile_windows_cover_the_window_once(n, window):
    x0, x1, y0, y1 = window
    cover = np.zeros((y1, x1), dtype=int)
    tiles = tile_windows(window, n)
    for a0, a1, b0, b1 in tiles:
        assert a0 < a1 and b0 < b1
        cover[b0:b1, a0:a1] += 1
    assert (cover[y0:y1, x0:x1] == 1).all()
    assert cover.sum() == (x1 - x0) * (y1 - y0)
    rows, cols = grid(n)
    assert rows * cols == n and rows <= cols
    assert len(tiles) == min(rows, y1 - y0) * min(cols, x1 - x0)


# ---- render --crop and merge ---------------------------------------------------------------

def _full_and_tiles(tmp_path, scene, opts, capsys):
    """Renders the full 40 x 30 image and its 4 tiles (--crop) with opts, each checked to
    name its pixels and keep its place in the image; the tiles' paths."""
    rc, _, err = run_cli(["render", scene, "-o", tmp_path / "full.exr", *opts], capsys)
    assert rc == 0, err
    tiles = []
    for k, (x0, x1, y0, y1) in enumerate(tile_windows((0, 40, 0, 30), 4)):
        out = tmp_path / f"tile{k}.exr"
        rc, _, err = run_cli(["render", scene, "-o", out, *opts, "--crop", f"{x0}:{x1},{y0}:{y1}"], capsys)
        assert rc == 0, err
        assert f"(pixels {x0}:{x1},{y0}:{y1})" in err
        img, _ = _exr(out)
        assert (img.x, img.y, img.width, img.height, img.full_width, img.full_height) == \
            (x0, y0, x1 - x0, y1 - y0, 40, 30)
        tiles.append(out)
    return tiles


@pytest.mark.parametrize("technique", ["ept", "hybrid"])
def test_crop_tiles_merge_into_the_full_render(tmp_path, scene_file, capsys, technique):
    tiles = _full_and_tiles(tmp_path, scene_file(), [*SIZE, "--technique", technique], capsys)
    rc, _, err = run_cli(["merge", *tiles, "-o", tmp_path / "merged.exr", "--png", tmp_path / "merged.png"], capsys)
    assert rc == 0, err
    assert "merged 4 tiles into 40x30" in err
    _same(tmp_path / "merged.exr", tmp_path / "full.exr")
    assert (tmp_path / "merged.png").exists()
    _, full = _exr(tmp_path / "full.exr")
    assert full["A"].mean() > 0.2  # the castle is in view: the comparison means something


def test_adaptive_crop_tiles_merge_into_the_full_render(tmp_path, scene_file, capsys):
    """With --noise-threshold a pixel stops by its neighbours too (core/render.h), and a tile
    traces the ring of neighbours around it, so the tiles still merge into the full render."""
    opts = ["--width", 40, "--height", 30, "--spp", 128, "--seed", 5, "--technique", "hybrid",
            "--noise-threshold", 0.003]
    tiles = _full_and_tiles(tmp_path, scene_file(), opts, capsys)
    rc, _, err = run_cli(["merge", *tiles, "-o", tmp_path / "merged.exr"], capsys)
    assert rc == 0, err
    _same(tmp_path / "merged.exr", tmp_path / "full.exr")
    _, full = _exr(tmp_path / "full.exr")
    counts = full["sampleCount"]
    assert counts.min() < counts.max() <= 128  # pixels stopped at different counts


def test_merge_of_a_part_keeps_its_place(tmp_path, scene_file, capsys):
    scene = scene_file()
    for k, crop in enumerate(["5:20,3:10", "20:31,3:10"]):
        assert run_cli(["render", scene, "-o", tmp_path / f"t{k}.exr", *SIZE, "--crop", crop], capsys)[0] == 0
    assert run_cli(["render", scene, "-o", tmp_path / "whole.exr", *SIZE, "--crop", "5:31,3:10"], capsys)[0] == 0
    rc, _, err = run_cli(["merge", tmp_path / "t0.exr", tmp_path / "t1.exr", "-o", tmp_path / "m.exr"], capsys)
    assert rc == 0, err
    assert "26x7 at (5, 3) of 40x30" in err
    _same(tmp_path / "m.exr", tmp_path / "whole.exr")


@pytest.mark.parametrize("crop, words", [
    ("0:41,0:30", "reaches outside the 40x30 image"),
    ("5:5,0:3", "is empty"),
    ("a:b,0:3", "is not X0:X1,Y0:Y1"),
    ("-1:3,0:3", "is not X0:X1,Y0:Y1"),
])
def test_bad_crops_are_refused(tmp_path, scene_file, capsys, crop, words):
    rc, _, err = run_cli(["render", scene_file(), "-o", tmp_path / "x.exr", *SIZE, f"--crop={crop}"], capsys)
    assert rc == 2
    assert err.startswith("error: ") and "--crop" in err and words in err and err.count("\n") == 1, err
    assert not (tmp_path / "x.exr").exists()


def test_merge_refuses_overlaps_and_missing_tiles(tmp_path, scene_file, capsys):
    scene = scene_file()
    for k, crop in enumerate(["0:25,0:30", "20:40,0:30"]):
        assert run_cli(["render", scene, "-o", tmp_path / f"t{k}.exr", *SIZE, "--crop", crop], capsys)[0] == 0
    rc, _, err = run_cli(["merge", tmp_path / "t0.exr", tmp_path / "t1.exr", "-o", tmp_path / "m.exr"], capsys)
    assert rc == 2 and f"tile {tmp_path / 't1.exr'}" in err and "overlaps" in err, err
    rc, _, err = run_cli(["merge", tmp_path / "t0.exr", tmp_path / "nope.exr", "-o", tmp_path / "m.exr"], capsys)
    assert rc == 2 and "nope.exr: no such file" in err, err
    assert not (tmp_path / "m.exr").exists()


# ---- dataWindowNDC -------------------------------------------------------------------------

def test_ndc_to_pixels():
    assert ndc_to_pixels((0, 0, 1, 1), 40, 30) == (0, 40, 0, 30)
    # y up in NDC, rows down in pixels; partly covered pixels are in.
    assert ndc_to_pixels((0.25, 0.5, 0.5, 1.0), 40, 30) == (10, 20, 0, 15)
    assert ndc_to_pixels((0.26, 0.0, 0.5, 0.49), 40, 30) == (10, 20, 15, 30)
    # Float NDC values on a pixel edge do not pick up the next pixel.
    assert ndc_to_pixels((np.float32(0.3), 0, np.float32(0.7), 1), 1000, 10) == (300, 700, 0, 10)
    assert ndc_to_pixels((-0.5, -0.5, 1.5, 1.5), 40, 30) == (0, 40, 0, 30)
    assert ndc_to_pixels((1.1, 0, 1.5, 1), 40, 30) is None


def _data_window(ndc, product=True, on_product=False):
    """Render settings of 40x30 pixels with the data window `ndc` on the settings prim (or on
    its product), and a render product unless `product` is False."""
    def mutate(stage):
        rs = UsdRender.Settings.Define(stage, "/Render/Settings")
        rs.CreateResolutionAttr(Gf.Vec2i(40, 30))
        if product:
            p = UsdRender.Product.Define(stage, "/Render/Settings/Beauty")
            rs.CreateProductsRel().SetTargets([p.GetPath()])
            if on_product:
                p.CreateDataWindowNDCAttr(Gf.Vec4f(*ndc))
        if not on_product:
            rs.CreateDataWindowNDCAttr(Gf.Vec4f(*ndc))
        stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    return mutate


@pytest.mark.parametrize("on_product", [False, True])
def test_data_window_ndc_renders_its_pixels_only(tmp_path, scene_file, capsys, on_product):
    opts = ["--spp", 4, "--seed", 5]
    windowed = scene_file(_data_window((0.25, 0.5, 0.75, 1.0), on_product=on_product), name="windowed.usda")
    rc, _, err = run_cli(["render", windowed, "-o", tmp_path / "dw.exr", *opts], capsys)
    assert rc == 0, err
    # The same pixels by --crop on the full stage (the stage's window, overridden by --crop).
    rc, _, err = run_cli(["render", windowed, "-o", tmp_path / "crop.exr", *opts, "--crop", "10:30,0:15"], capsys)
    assert rc == 0, err
    _same(tmp_path / "dw.exr", tmp_path / "crop.exr")
    img, _ = _exr(tmp_path / "dw.exr")
    assert (img.x, img.y, img.width, img.height) == (10, 0, 20, 15)


def test_a_data_window_without_a_render_product_is_ignored_with_a_warning(tmp_path, scene_file, capsys):
    rc, _, err = run_cli(["render", scene_file(_data_window((0.25, 0.5, 0.75, 1.0), product=False)), "-o",
                          tmp_path / "x.exr", "--spp", 1], capsys)
    assert rc == 0, err
    assert "/Render/Settings.dataWindowNDC: ignored: a data window applies to render products" in err
    img, _ = _exr(tmp_path / "x.exr")
    assert (img.x, img.y, img.width, img.height) == (0, 0, 40, 30)


@pytest.mark.parametrize("ndc, words", [((0.5, 0, 0.5, 1), "is empty"), ((1.2, 0, 1.5, 1), "covers no pixel")])
def test_bad_data_windows_name_the_attribute(tmp_path, scene_file, capsys, ndc, words):
    rc, _, err = run_cli(["render", scene_file(_data_window(ndc)), "-o", tmp_path / "x.exr", "--spp", 1], capsys)
    assert rc == 2
    assert err.startswith("error: /Render/Settings.dataWindowNDC:") and words in err, err


def test_data_window_overscan_is_clipped_with_a_warning(tmp_path, scene_file, capsys):
    rc, _, err = run_cli(["render", scene_file(_data_window((-0.1, 0, 1.1, 1))), "-o", tmp_path / "x.exr",
                          "--spp", 1], capsys)
    assert rc == 0, err
    assert "overscan is not rendered" in err
    img, _ = _exr(tmp_path / "x.exr")
    assert (img.width, img.height, img.full_width) == (40, 30, 40)


# ---- granular farm -------------------------------------------------------------------------

def _single_process(scene, tmp_path, frames="1:2", extra=()):
    out = tmp_path / "single"
    out.mkdir(exist_ok=True)
    r = run_script(["render", scene, "-o", out / "f.####.exr", "--frames", frames, *SIZE, *extra, "--quiet"])
    assert r.returncode == 0, r.stderr
    return out


def test_farm_on_a_local_cluster_equals_the_single_process_render(tmp_path):
    scene = small_scene(tmp_path / "anim.usda", _animated)
    single = _single_process(scene, tmp_path)
    out = tmp_path / "farm"
    out.mkdir()
    r = run_script(["farm", scene, "-o", out / "f.####.exr", "--png", out / "f.####.png", "--frames", "1:2",
                    "--tiles", 4, "--workers", 2, *SIZE], timeout=300)
    assert r.returncode == 0, r.stderr
    assert "2 frames x 4 tiles = 8 tasks on a LocalCluster of 2 worker processes" in r.stderr
    assert "Traceback" not in r.stderr
    for f in ("0001", "0002"):
        _same(out / f"f.{f}.exr", single / f"f.{f}.exr")
        assert (out / f"f.{f}.png").exists()
    assert sorted(p.name for p in out.iterdir()) == ["f.0001.exr", "f.0001.png", "f.0002.exr", "f.0002.png"]


def test_farm_bad_scene_fails_at_once_without_frames(tmp_path):
    def bad(stage):
        stage.GetPrimAtPath("/World/Castle").GetAttribute("primvars:granular:packingRate").Set(0.9)
    scene = small_scene(tmp_path / "bad.usda", bad)
    out = tmp_path / "farm"
    out.mkdir()
    t0 = time.monotonic()
    r = run_script(["farm", scene, "-o", out / "f.####.exr", "--frames", "1:2", "--workers", 2, *SIZE], timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: /World/Castle.primvars:granular:packingRate:"), r.stderr
    assert list(out.iterdir()) == []
    assert time.monotonic() - t0 < 60


def _wait_for(predicate, seconds, what):
    t0 = time.monotonic()
    while time.monotonic() - t0 < seconds:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_farm_survives_a_killed_worker(tmp_path):
    """A scheduler and two workers started as a farm would start them (`dask scheduler`,
    `dask worker`, here without nannies, so a killed worker stays dead); one worker is killed
    by its process id while it renders a tile; the job completes, bit for bit."""
    from distributed import Client

    scene = small_scene(tmp_path / "anim.usda", _animated)
    extra = ["--spp", 64]  # tasks long enough to be caught running
    single = _single_process(scene, tmp_path, extra=extra)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "python"), str(BUILD / "python")])
    sched_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)]
    try:
        _wait_for(lambda: sched_file.exists() and sched_file.stat().st_size > 0, 60, "the scheduler")
        address = json.loads(sched_file.read_text())["address"]
        workers = [subprocess.Popen([str(DASK), "worker", address, "--nthreads", "1", "--no-nanny",
                                     "--no-dashboard", "--host", "127.0.0.1"], env=env, stdout=subprocess.DEVNULL,
                                    stderr=subprocess.DEVNULL) for _ in range(2)]
        procs += workers
        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
            pids = client.run(os.getpid)  # worker address -> process id
            assert sorted(pids.values()) == sorted(w.pid for w in workers)
            out = tmp_path / "farm"
            out.mkdir()
            farm = subprocess.Popen([sys.executable, "-m", "granular.cli", "farm", str(scene), "-o", str(out / "f.####.exr"), "--frames",
                                     "1:2", "--tiles", "4", "--scheduler", address, *map(str, SIZE), *map(str, extra),
                                     "--threads", "1"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                    text=True)
            busy = _wait_for(lambda: [w for w, keys in client.processing().items()
                                      if any(str(k).startswith("granular-tile") for k in keys)], 120,
                             "a tile task to run")
            victim = pids[busy[0]]
            os.kill(victim, signal.SIGKILL)
            killed_at = sorted(p.name for p in out.iterdir())
            _, stderr = farm.communicate(timeout=300)
        assert farm.returncode == 0, stderr
        assert killed_at != ["f.0001.exr", "f.0002.exr"], "the job had finished before the kill"
        assert [w.poll() for w in workers if w.pid == victim] == [-signal.SIGKILL]
        for f in ("0001", "0002"):
            _same(out / f"f.{f}.exr", single / f"f.{f}.exr")
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
