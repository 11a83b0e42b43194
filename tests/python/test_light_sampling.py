"""Next-event estimation picks each light by its weight (core: Light::pickWeight,
Scene::lightPick); `granular render` says the chances it took, by the lights' prim paths."""
import re

from pxr import UsdLux

from conftest import run_cli, small_scene
from granular import api, usd_reader

OPTIONS = ["--width", "16", "--height", "12", "--spp", "1"]


def _with_sky(angle):
    def mutate(stage):
        sun = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun"))
        sun.CreateAngleAttr(angle)
        sun.CreateNormalizeAttr(True)  # the same irradiance whatever its size
        UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(0.5)
    return mutate


def _picks(err):
    line = next(l for l in err.splitlines() if "light sampling picks:" in l)
    return {name: float(p) for name, p in re.findall(r"(/World/\w+) ([0-9.]+)%", line)}


def test_render_says_each_lights_chance_and_a_narrower_sun_takes_more(tmp_path, capsys):
    chances = {}
    for angle in (20.0, 0.53):
        stage = small_scene(tmp_path / f"sun{angle}.usda", _with_sky(angle))
        rc, _, err = run_cli(["render", stage, "-o", tmp_path / f"sun{angle}.exr", *OPTIONS], capsys)
        assert rc == 0, err
        picks = _picks(err)
        assert set(picks) == {"/World/Sun", "/World/Sky"}, err
        assert abs(sum(picks.values()) - 100.0) < 0.15, picks
        # The line is the scene's own (core: Scene::lightPicksText).
        assert api.build_scene(usd_reader.read_stage(str(stage), width=16)).light_picks in err
        chances[angle] = picks["/World/Sun"]
    # The same irradiance from a smaller disk: light sampling is all that finds it.
    assert chances[0.53] > chances[20.0] > 50.0, chances


def test_one_light_says_nothing(tmp_path, capsys):
    stage = small_scene(tmp_path / "sun.usda")
    rc, _, err = run_cli(["render", stage, "-o", tmp_path / "sun.exr", *OPTIONS], capsys)
    assert rc == 0, err
    assert "light sampling picks" not in err
