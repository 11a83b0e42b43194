"""A delta sun (a UsdLux distant light of angle 0) over smooth dielectric grains is rendered
as the physical sun, a 0.53° disk of the same irradiance (core/scene.h: widenedSuns), with
one warning from `granular render`; the image is the one of a stage that authors that disk
itself. The delegate's side is the granular:widenedSuns stat and a TF_WARN."""
import numpy as np
from pxr import UsdLux

import granular_core as core
from conftest import add_mesh, run_cli, small_scene

OPTIONS = ["--width", "24", "--height", "16", "--spp", "2"]


def _sun(angle, normalize=None):
    """The sun's angle (and normalize), and a grey ground under the castle for it to light."""
    def mutate(stage):
        add_mesh(stage, "/World/Ground", core.make_box((-3.0, -0.1, -3.0), (3.0, 0.0, 3.0)))
        sun = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun"))
        sun.CreateAngleAttr(angle)
        if normalize is not None:
            sun.CreateNormalizeAttr(normalize)
    return mutate


def _rgb(path):
    return np.asarray(core.read_image_rgb(str(path)).pixels, dtype=np.float64)[..., :3]


def test_a_delta_sun_over_glass_grains_is_the_physical_sun_with_one_warning(tmp_path, capsys):
    delta = small_scene(tmp_path / "delta.usda", _sun(0.0))
    rc, _, err = run_cli(["render", delta, "-o", tmp_path / "delta.exr", *OPTIONS], capsys)
    assert rc == 0, err
    warnings = [line for line in err.splitlines() if "rendered as the physical sun" in line]
    assert warnings == ["warning: the delta sun /World/Sun is rendered as the physical sun, a disk of 0.53 degrees "
                        "with the same irradiance: light refracted through the smooth grains could never reach a "
                        "delta light (set its angle to choose another size)"], err
    disk = small_scene(tmp_path / "disk.usda", _sun(0.53, normalize=True))
    rc, _, err = run_cli(["render", disk, "-o", tmp_path / "disk.exr", *OPTIONS], capsys)
    assert rc == 0, err
    assert "physical sun" not in err
    a, b = _rgb(tmp_path / "delta.exr"), _rgb(tmp_path / "disk.exr")
    assert a.mean() > 0.01
    np.testing.assert_array_equal(a, b)


def test_no_physical_sun_keeps_the_delta_sun_without_a_warning(tmp_path, capsys):
    delta = small_scene(tmp_path / "delta.usda", _sun(0.0))
    rc, _, err = run_cli(["render", delta, "-o", tmp_path / "kept.exr", "--no-physical-sun", *OPTIONS], capsys)
    assert rc == 0, err
    assert "physical sun" not in err
    rc, _, err = run_cli(["render", delta, "-o", tmp_path / "widened.exr", *OPTIONS], capsys)
    assert rc == 0, err
    kept, widened = _rgb(tmp_path / "kept.exr"), _rgb(tmp_path / "widened.exr")
    # Lit either way, and not the same image: the delta is not sampled, the disk is (that
    # the two give the ground the same irradiance is core's test, tests/core/test_light.cpp).
    assert kept.mean() > 0.01 and not np.array_equal(kept, widened)


def test_frames_warn_once(tmp_path, capsys):
    delta = small_scene(tmp_path / "delta.usda", _sun(0.0))
    rc, _, err = run_cli(["render", delta, "-o", tmp_path / "f.#.exr", "--frames", "1:3", *OPTIONS], capsys)
    assert rc == 0, err
    assert sum("rendered as the physical sun" in line for line in err.splitlines()) == 1, err
