"""The switches that turn motion blur off in `granular render`: --no-motion-blur and the
render settings' disableMotionBlur, and the deprecated instantaneousShutter read as
disableMotionBlur, flattened as UsdRenderComputeSpec does (the settings prim's value,
overridden by its first product's where authored). A box that slides and turns over the
camera's open shutter and two explicit grains moving apart vertically: switched off, the
image is the still frame's (the same description: bit for bit at the same seed, within
noise at another) and differs from the blurred one far beyond noise (noise_check.py)."""
import pytest
import motion_blur_stage
from conftest import add_mesh, run_cli
from noise_check import block_chi2, noise_limit, rgb_and_variance
from pxr import Gf, UsdGeom, Vt

import granular_core as core
from granular import schema, usd_reader

WIDTH, HEIGHT, SPP = 48, 32, 16


def write_stage(path, shutter=(-0.5, 0.5), settings=None, product=None):
    """motion_blur_stage.write_stage's box (24 time codes per second), with two glass grains
    moving 0.8 units a frame apart; the product written beside the stage."""
    def grains(stage):
        pi = UsdGeom.PointInstancer.Define(stage, "/World/Grains")
        schema.apply_instanced_aggregate(pi)
        grain = add_mesh(stage, "/World/Grains/Protos/Round", core.make_icosphere(2))
        schema.apply_grain(grain, ior=1.5, absorption=(0.5, 1.0, 2.0))
        pi.CreatePrototypesRel().SetTargets([grain.GetPath()])
        pi.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(-0.9, 0.8, 0.6), Gf.Vec3f(0.9, 0.8, 0.6)]))
        pi.CreateProtoIndicesAttr(Vt.IntArray([0, 0]))
        pi.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(0.15)] * 2))
        pi.CreateVelocitiesAttr(Vt.Vec3fArray([Gf.Vec3f(0, 19.2, 0), Gf.Vec3f(0, -19.2, 0)]))
    return motion_blur_stage.write_stage(path, 24, shutter, settings, product, str(path) + ".product.exr",
                                         extra=grains)


def _is_still(path):
    desc = usd_reader.read_stage(path).desc
    moving = [m.name for m in desc.meshes if m.shutter_xf is not None]
    if desc.camera.shutter_open == desc.camera.shutter_close == 0 and not moving:
        return True
    assert desc.camera.shutter_close > desc.camera.shutter_open and moving == ["/World/Box"]
    return False


@pytest.mark.parametrize("settings, product, still", [
    (None, None, False),
    ({}, None, False),
    ({"disableMotionBlur": True}, None, True),
    ({"instantaneousShutter": True}, None, True),
    ({"instantaneousShutter": False}, None, False),
    ({}, {}, False),
    ({"instantaneousShutter": True}, {}, True),
    ({}, {"instantaneousShutter": True}, True),
    ({"disableMotionBlur": True}, {}, True),
    ({}, {"disableMotionBlur": True}, True),
    # The product's disableMotionBlur overrides the settings prim's switches; its own
    # instantaneousShutter still turns blur off (UsdRenderComputeSpec's order).
    ({"disableMotionBlur": True}, {"disableMotionBlur": False}, False),
    ({"instantaneousShutter": True}, {"disableMotionBlur": False}, False),
    ({}, {"disableMotionBlur": False, "instantaneousShutter": True}, True),
])
def test_which_settings_turn_blur_off(tmp_path, settings, product, still):
    assert _is_still(write_stage(tmp_path / "s.usda", settings=settings, product=product)) == still


def _render(tmp_path, capsys, stage, name, seed=0, *extra):
    out = tmp_path / f"{name}.exr"
    rc, _, err = run_cli(["render", stage, "-o", out, "--width", WIDTH, "--height", HEIGHT, "--spp", SPP,
                          "--seed", seed, "--quiet", *extra], capsys)
    assert rc == 0, err
    return rgb_and_variance(out)


@pytest.mark.parametrize("settings, product", [
    ({"instantaneousShutter": True}, None),
    ({}, {"instantaneousShutter": True}),
])
def test_instantaneous_shutter_renders_the_frames_instant(tmp_path, capsys, settings, product):
    """instantaneousShutter on the settings prim (no product) or on its product: the image is
    --no-motion-blur's bit for bit, the shutter-closed stage's within noise, and the blurred
    one's beyond noise."""
    moving = write_stage(tmp_path / "moving.usda")
    switched = _render(tmp_path, capsys, write_stage(tmp_path / "inst.usda", settings=settings, product=product),
                       "inst")
    flag = _render(tmp_path, capsys, moving, "flag", 0, "--no-motion-blur")
    closed = _render(tmp_path, capsys, write_stage(tmp_path / "closed.usda", shutter=(0, 0)), "closed", 1)
    blurred = _render(tmp_path, capsys, moving, "blurred", 1)
    assert (switched[0] == flag[0]).all()
    same, m = block_chi2(*switched, *closed)
    apart, _ = block_chi2(*switched, *blurred)
    print(f"vs the closed shutter: chi2 {same:.1f}; vs blurred: {apart:.1f}; {m} terms, limit {noise_limit(m):.1f}")
    assert m > 100 and same < noise_limit(m)
    assert apart > noise_limit(m)
