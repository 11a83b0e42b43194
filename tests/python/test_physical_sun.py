"""A delta sun (a UsdLux distant light of angle 0) over smooth dielectric grains is rendered
as the physical sun, a 0.53° disk of the same irradiance (core/scene.h: widenedSuns), with
one warning from `granular render`; the image is the one of a stage that authors that disk
itself. The delegate's side is the granular:widenedSuns stat and a TF_WARN."""
import numpy as np
import pytest
from pxr import UsdLux

import granular_core as core
from conftest import add_mesh, run_cli, small_scene
from granular import schema

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


def _ept(tmp_path, capsys, name, angle, *extra, roughness=None):
    """The glass castle alone under a normalised sun of `angle` degrees, explicit grains
    (both grain types of the given roughness, where given)."""
    def mutate(stage):
        sun = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun"))
        sun.CreateAngleAttr(angle)
        sun.CreateNormalizeAttr(True)
        if roughness is not None:
            for grain in ("A", "B"):
                schema.apply_grain(stage.GetPrimAtPath(f"/World/Grains/{grain}"), roughness=roughness)
    stage = small_scene(tmp_path / f"{name}.usda", mutate)
    rc, _, err = run_cli(["render", stage, "-o", tmp_path / f"{name}.exr", "--technique", "ept", "--width", "24",
                          "--height", "16", "--spp", "64", *extra], capsys)
    assert rc == 0, err
    return _rgb(tmp_path / f"{name}.exr")


@pytest.mark.parametrize("roughness", [None, 0.3], ids=["smooth chains", "rough grains"])
def test_sun_regularization_shows_the_grains_the_narrow_sun_as_the_wider_disk(tmp_path, capsys, roughness):
    """With --sun-regularization 5 the castle's grains (far smaller than a pixel: the
    footprint does not bound it) see the 0.53° sun as a 5° disk of the same irradiance:
    a smooth chain from a grain meets that disk where it escapes; a rough grain samples it,
    and a direction its lobe samples that escapes meets it with that disk's MIS weights. So
    the castle alone (no other surface samples the sun) renders as under a 5° sun with the
    regularisation off; 0 keeps it exact."""
    regularised = _ept(tmp_path, capsys, "regularised", 0.53, "--sun-regularization", "5", roughness=roughness)
    wide = _ept(tmp_path, capsys, "wide", 5.0, "--sun-regularization", "0", roughness=roughness)
    exact = _ept(tmp_path, capsys, "exact", 0.53, "--sun-regularization", "0", roughness=roughness)
    assert regularised.mean() > 0.01
    np.testing.assert_allclose(regularised, wide, rtol=1e-5, atol=1e-6)
    assert not np.array_equal(regularised, exact)


def test_sun_regularization_out_of_range_names_the_option(tmp_path, capsys):
    stage = small_scene(tmp_path / "s.usda")
    for bad in ("-1", "nan", "90"):
        rc, _, err = run_cli(["render", stage, "-o", tmp_path / "s.exr", "--sun-regularization", bad, *OPTIONS],
                             capsys)
        assert rc != 0
        assert "--sun-regularization" in err and "must be in [0, 45] degrees" in err, err
        assert not (tmp_path / "s.exr").exists()


def test_sun_regularization_in_a_json_scene(tmp_path):
    scene = tmp_path / "s.json"
    scene.write_text('{"render": {"sun_regularization": 2.5}, "lights": [{"type": "distant"}]}')
    assert core.load_scene_json(str(scene)).settings.sun_regularization == 2.5
    assert core.RenderSettings().sun_regularization == 20.0
    bad = tmp_path / "bad.json"
    bad.write_text('{"render": {"sun_regularization": -1}}')
    with pytest.raises(core.InputError, match=r"render\.sun_regularization: -1 must be in \[0, 45\] degrees"):
        core.validate_scene_desc(core.load_scene_json(str(bad)))
