"""The equivalent medium's model (RenderSettings.medium_model; core/vpt.h): tt, Meng et al.
2015's teleportation transport, or exits, flights to the next grain met with each
scattering's light moved as the grain lets it out. One meaning through the command line
(--medium-model), JSON scenes ("medium_model") and the bindings; Hydra's
granular:mediumModel is tested in tests/hydra."""
import json

import numpy as np
import pytest

from pxr import UsdLux

import granular_core as core
from conftest import run_cli, small_scene

OPTIONS = ["--width", "24", "--height", "16", "--spp", "4", "--technique", "ept+vpt"]


def _sky(stage):
    UsdLux.DomeLight.Define(stage, "/World/Sky")  # light that paths in the medium bring back


def _low_orders(err):
    lines = [line.strip() for line in err.splitlines() if line.strip().startswith("after the first grain:")]
    assert len(lines) == 1, err
    return lines[0]


def test_the_command_line_renders_either_model_and_says_which(tmp_path, capsys):
    stage = small_scene(tmp_path / "s.usda", _sky)
    images, lines = {}, {}
    for model in ("tt", "exits"):
        out = tmp_path / f"{model}.exr"
        rc, _, err = run_cli(["render", stage, "-o", out, *OPTIONS, "--medium-model", model], capsys)
        assert rc == 0, err
        lines[model] = _low_orders(err)
        images[model] = np.asarray(core.read_image_rgb(str(out)).pixels)
        assert np.isfinite(images[model]).all()
    assert "(exits)" in lines["exits"] and "exits" not in lines["tt"], lines
    assert not np.array_equal(images["tt"], images["exits"])
    rc, _, _ = run_cli(["render", stage, "-o", tmp_path / "bad.exr", *OPTIONS, "--medium-model", "tele"], capsys)
    assert rc != 0


def test_json_scenes_and_the_bindings_name_it_alike(tmp_path):
    assert core.RenderSettings().medium_model == core.MediumModel.Tt
    assert core.medium_model_from_name("exits", "x") == core.MediumModel.Exits
    assert core.medium_model_name(core.MediumModel.Exits) == "exits"
    scene = tmp_path / "s.json"
    scene.write_text(json.dumps({"render": {"medium_model": "exits"}, "lights": [{"type": "distant"}]}))
    assert core.load_scene_json(str(scene)).settings.medium_model == core.MediumModel.Exits
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"render": {"medium_model": "teleport"}}))
    with pytest.raises(core.InputError, match=r"medium_model.*teleport"):
        core.load_scene_json(str(bad))


def test_a_built_scene_takes_the_model_only_from_a_new_build(tmp_path):
    # The model decides every aggregate's medium: a new build, never a change of view.
    from granular.usd_reader import read_stage
    desc = read_stage(str(small_scene(tmp_path / "s.usda")), width=24).desc
    s = desc.settings
    s.technique = core.Technique.EptVpt
    desc.settings = s
    built = core.Scene.build(desc)
    s.medium_model = core.MediumModel.Exits
    with pytest.raises(core.InputError, match="medium_model"):
        built.set_view(desc.camera, s)
    desc.settings = s
    assert "(exits)" in core.Scene.build(desc).low_orders_text(0)
