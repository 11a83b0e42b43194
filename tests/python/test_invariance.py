"""Invariance: a stage moved, scaled or turned as a whole renders the same image.

- Moved by 10^3 or 10^6 units: render space (core/scene_desc.h, renderOrigin) takes the
  whole-unit move out in double before anything is stored in float, so the image is the
  same to the bit; further away, a stage whose grains float cannot resolve is refused by
  name, never rendered without them.
- Scaled by 10^-3 or 10^3 (grain radius with it; grain absorption is per grain radius, so
  it scales with the grains by itself): the same grains, so only Monte Carlo noise differs.
  The bound is four standard errors of the difference of two independent renders, estimated
  from two render seeds of the original.
- Turned: the tiles stay aligned with the world's axes, so a turned aggregate holds other
  grains (another realisation of the same packing). The bound is four standard deviations
  of the image mean over realisations (aggregate seeds) of the original.
"""
import numpy as np
import pytest
from conftest import run_cli, small_scene
from pxr import Gf, UsdGeom, UsdLux

import granular_core as core

OPTIONS = ["--width", 48, "--height", 32, "--spp", 16, "--technique", "ept"]


def _stage(path, op=None, value=None, seed=3, radius=0.015):
    """small_scene under a white dome only (no sun), its grains half as large, /World
    moved, scaled or turned by one xform op (the camera with it)."""
    def mutate(stage):
        stage.RemovePrim("/World/Sun")
        UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
        castle = stage.GetPrimAtPath("/World/Castle")
        scale = value if op == "scale" else 1.0
        castle.GetAttribute("primvars:granular:grainRadius").Set(radius * scale)
        castle.GetAttribute("primvars:granular:seed").Set(seed)
        world = UsdGeom.Xformable(stage.GetPrimAtPath("/World"))
        if op == "translate":
            world.AddTranslateOp().Set(Gf.Vec3d(value, value, value))
        elif op == "scale":
            world.AddScaleOp().Set(Gf.Vec3f(value, value, value))
            # The clipping range is in the camera's own units; keep the scene inside it.
            cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
            cam.CreateClippingRangeAttr(Gf.Vec2f(1e-3, 1e6))
        elif op == "rotate":
            world.AddRotateXYZOp().Set(Gf.Vec3f(*value))
    return small_scene(path, mutate)


def _render(path, out, capsys, seed=1):
    rc, _, err = run_cli(["render", path, "-o", out, "--seed", seed, *OPTIONS], capsys)
    assert rc == 0, err
    rgb = np.asarray(core.read_exr(str(out)).pixels, dtype=np.float64)[..., :3]  # as written: no NaN zeroed
    assert np.isfinite(rgb).all()
    return rgb


@pytest.fixture(scope="module")
def original(tmp_path_factory):
    folder = tmp_path_factory.mktemp("original")
    return folder, _stage(folder / "original.usda")


@pytest.mark.parametrize("distance", [1e3, 1e6])
def test_a_moved_stage_renders_the_same_image_to_the_bit(original, tmp_path, capsys, distance):
    folder, path = original
    base = _render(path, tmp_path / "base.exr", capsys)
    moved = _render(_stage(tmp_path / "moved.usda", "translate", distance), tmp_path / "moved.exr", capsys)
    assert base.mean() > 0.05, "the grains are lit"
    np.testing.assert_array_equal(moved, base)


def test_a_stage_too_far_for_its_grains_is_refused_by_name(tmp_path, capsys):
    path = _stage(tmp_path / "far.usda", "translate", 1e14)
    out = tmp_path / "far.exr"
    rc, _, err = run_cli(["render", path, "-o", out, *OPTIONS], capsys)
    assert rc == 2, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("error: /World/Castle.primvars:granular:grainRadius: grains of radius 0.015 cannot be "
                           "resolved"), line
    assert "from the world origin" in line
    assert not out.exists()


def _mc_standard_error(a, b):
    """Standard error of one render's image mean, from two renders that differ only in their
    seed: the pixels' sample noise is independent, var(a - b) = 2 var(a) per pixel."""
    return float(np.sqrt(np.mean((a - b) ** 2) / 2 / a.size))


@pytest.mark.parametrize("factor", [1e-3, 1e3])
def test_a_scaled_stage_renders_the_same_image_within_noise(original, tmp_path, capsys, factor):
    folder, path = original
    a = _render(path, tmp_path / "a.exr", capsys, seed=1)
    b = _render(path, tmp_path / "b.exr", capsys, seed=2)
    se = _mc_standard_error(a, b)
    scaled = _render(_stage(tmp_path / "scaled.usda", "scale", factor), tmp_path / "scaled.exr", capsys, seed=1)
    assert a.mean() > 0.05 and se > 0
    assert abs(scaled.mean() - a.mean()) <= 4 * np.sqrt(2) * se, (scaled.mean(), a.mean(), se)


def test_a_turned_stage_renders_the_same_image_within_the_spread_of_realisations(tmp_path, capsys):
    means = [_render(_stage(tmp_path / f"seed{s}.usda", seed=s), tmp_path / f"seed{s}.exr", capsys, seed=s).mean()
             for s in range(1, 7)]
    spread = float(np.std(means, ddof=1))
    turned = _render(_stage(tmp_path / "turned.usda", "rotate", (10.0, 30.0, 5.0)), tmp_path / "turned.exr",
                     capsys).mean()
    assert spread > 0
    assert abs(turned - np.mean(means)) <= 4 * spread * np.sqrt(1 + 1 / len(means)), (turned, means)
