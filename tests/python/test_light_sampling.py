"""Next-event estimation picks each light by its weight (core: Light::pickWeight,
Scene::lightPick); `granular render` says the chances it took, by the lights' prim paths.
Shadow rays stop at area lights as every other ray does (core: Scene::occluded), and pass
the objects a light's collection:shadowLink leaves out (core: Scene::castsShadow)."""
import math
import re

import numpy as np
from pxr import Gf, UsdGeom, UsdLux

from conftest import dome_world, run_cli, small_scene
from granular import api, usd_reader
from noise_check import rgb_and_variance

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


def test_render_says_what_each_linked_light_lights(tmp_path, capsys):
    """Light linking (core: Scene::lightLinksText): each linked light and how many of the
    scene's objects it lights; nothing when no light is linked."""
    def mutate(stage):
        _with_sky(20.0)(stage)
        UsdGeom.Cube.Define(stage, "/World/Block")
        link = UsdLux.LightAPI(stage.GetPrimAtPath("/World/Sun")).GetLightLinkCollectionAPI()
        link.GetExcludesRel().AddTarget("/World/Block")
    stage = small_scene(tmp_path / "linked.usda", mutate)
    rc, _, err = run_cli(["render", stage, "-o", tmp_path / "linked.exr", *OPTIONS], capsys)
    assert rc == 0, err
    assert "  light linking: /World/Sun lights 1 of 2 objects" in err.splitlines(), err  # the castle, not the block
    rc, _, err = run_cli(["render", small_scene(tmp_path / "sky.usda", _with_sky(20.0)), "-o", tmp_path / "sky.exr",
                          *OPTIONS], capsys)
    assert rc == 0 and "light linking" not in err, err


def _floor_in_view(path):
    """dome_world with a floor facing the camera 15 below it, which sees [-0.6, 0.6]^2 of it."""
    stage = dome_world(path)
    camera = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
    camera.CreateHorizontalApertureAttr(4.0)
    camera.CreateVerticalApertureAttr(4.0)
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-30, -30, 0), (30, -30, 0), (30, 30, 0), (-30, 30, 0)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    return stage


def _floor_and_card(path, card, exclude):
    """A floor facing the camera 15 below it under the uniform dome and a normalised 20° sun
    leaning 27° to +x; with `card`, a black card out of view (z = 7.5, x from 0.5) between
    the floor in view and the sun that hides some of the dome too; `exclude`: left out of
    both lights' collection:shadowLink."""
    stage = _floor_in_view(path)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateAngleAttr(20.0)
    sun.CreateIntensityAttr(3.0)
    sun.CreateNormalizeAttr(True)
    UsdGeom.Xformable(sun).AddRotateYOp().Set(26.6)
    if card:
        c = UsdGeom.Mesh.Define(stage, "/World/Card")
        c.CreatePointsAttr([(0.75, -4, 7.5), (5, -4, 7.5), (5, 4, 7.5), (0.75, 4, 7.5)])
        c.CreateFaceVertexCountsAttr([4])
        c.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        c.CreateDisplayColorAttr([(0, 0, 0)])
    if exclude:
        for light in ("/World/Sun", "/World/Sky"):
            link = UsdLux.LightAPI(stage.GetPrimAtPath(light)).GetShadowLinkCollectionAPI()
            link.GetExcludesRel().AddTarget("/World/Card")
    stage.Save()
    return str(path)


def test_objects_left_out_of_a_lights_shadow_link_cast_no_shadow_from_it(tmp_path, capsys):
    """The card left out of the sun's and the sky's collection:shadowLink: the floor is as
    without the card (black, it returns no light); in the links, its shadow darkens the
    floor. hdGranular renders the same (tests/hydra: ShadowLinking...; tests/conformance)."""
    means, errors = {}, {}
    for name, card, exclude in (("linked", True, True), ("open", False, False), ("shaded", True, False)):
        stage = _floor_and_card(tmp_path / f"{name}.usda", card, exclude)
        out = tmp_path / f"{name}.exr"
        rc, _, err = run_cli(["render", stage, "-o", out, "--width", "8", "--height", "8", "--spp", "32"], capsys)
        assert rc == 0, err
        if name == "linked":
            assert ("  shadow linking: /World/Sky: 1 of 2 objects cast shadows; "
                    "/World/Sun: 1 of 2 objects cast shadows") in err.splitlines(), err
        else:
            assert "shadow linking" not in err, err
        rgb, var = rgb_and_variance(out)
        means[name] = rgb[..., 0].mean()
        errors[name] = math.sqrt(var[..., 0].sum()) / rgb[..., 0].size
    assert abs(means["linked"] - means["open"]) < 4 * math.hypot(errors["linked"], errors["open"]), (means, errors)
    assert means["shaded"] < 0.6 * means["open"], means


def _floor_under(path, bulb):
    """A floor facing the camera 15 below it under the uniform dome; with `bulb`, a 20° sun
    behind the camera and a black sphere light of radius 7.5 centred on the camera."""
    stage = _floor_in_view(path)
    if bulb:
        sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
        sun.CreateAngleAttr(20.0)
        sun.CreateIntensityAttr(10.0)
        light = UsdLux.SphereLight.Define(stage, "/World/Bulb")
        light.CreateRadiusAttr(7.5)
        light.CreateIntensityAttr(0.0)
        UsdGeom.Xformable(light).AddTranslateOp().Set(Gf.Vec3d(0, 0, 15))
    stage.Save()
    return str(path)


def test_a_black_sphere_light_hides_the_sun_and_part_of_the_dome_from_shadow_rays(tmp_path, capsys):
    # The camera's rays start inside the bulb, which does not stop them. From the floor in
    # view (15 away, aperture 4 at focal length 50: [-0.6, 0.6]^2) the bulb hides the whole
    # sun and the projected solid angle pi (r/d)^2 cos(theta) of the dome (d to its centre,
    # cos(theta) = 15/d): the floor's radiance is that under the dome alone times
    # 1 - r^2 15 / d^3, as core's AreaLightOcclusion and hdGranular's tests have it.
    means, variances = [], []
    for bulb in (True, False):
        stage = _floor_under(tmp_path / f"floor{int(bulb)}.usda", bulb)
        out = tmp_path / f"floor{int(bulb)}.exr"
        rc, _, err = run_cli(["render", stage, "-o", out, "--width", "16", "--height", "16", "--spp", "64"], capsys)
        assert rc == 0, err
        rgb, var = rgb_and_variance(out)
        means.append(rgb[..., 0].mean())
        variances.append(var[..., 0].sum() / rgb[..., 0].size ** 2)
    n = 200
    x = -0.6 + 1.2 * (np.arange(n) + 0.5) / n
    d = np.sqrt(x[:, None] ** 2 + x[None, :] ** 2 + 225.0)
    exact = float(np.mean(1.0 - 7.5 ** 2 * 15.0 / d ** 3))
    ratio = means[0] / means[1]
    se = ratio * math.hypot(math.sqrt(variances[0]) / means[0], math.sqrt(variances[1]) / means[1])
    assert se > 0
    assert abs(ratio - exact) < 4 * se, (ratio, exact, se)
