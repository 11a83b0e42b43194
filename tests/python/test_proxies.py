"""Proxies (core/ppt.h) through `granular render` and JSON scenes: the setting's three values
and its default (auto: proxies under a narrow sun), the line saying what carries the low
orders, and one meaning of the word "proxies" in both. The delegate's side is
tests/hydra (granular:proxies); their accuracy is tests/core/test_ppt.cpp's."""
import json

import numpy as np
import pytest
from pxr import UsdLux

import granular_core as core
from conftest import ROOT, run_cli, small_scene

OPTIONS = ["--width", "24", "--height", "16", "--spp", "2", "--technique", "ept+vpt"]


def _sun_angle(angle):
    def mutate(stage):
        UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun")).CreateAngleAttr(angle)
    return mutate


def _ept_vpt_desc(stage, **size):
    """The stage's scene description (read_stage at the image `size`), technique ept+vpt."""
    from granular.usd_reader import read_stage
    desc = read_stage(str(stage), **size).desc
    s = desc.settings
    s.technique = core.Technique.EptVpt
    desc.settings = s
    return desc


def _low_orders(err):
    lines = [line.strip() for line in err.splitlines() if line.strip().startswith("after the first grain:")]
    assert len(lines) == 1, err
    return lines[0]


def test_auto_uses_proxies_under_a_narrow_sun_and_on_and_off_override_it(tmp_path, capsys):
    # Auto: proxies under a narrow sun; under a wide one where the medium right after the
    # first grain is measured biased (core/switching.h), which this scene's absorbing grains are.
    narrow = small_scene(tmp_path / "narrow.usda", _sun_angle(0.53))
    wide = small_scene(tmp_path / "wide.usda", _sun_angle(20.0))

    def switching(stage):
        return core.Scene.build(_ept_vpt_desc(stage, width=24)).switching[0]
    sw = switching(wide)
    assert sw["measured"] and sw["proxy_visits"] == sw["chosen"] > 0 and sw["uses_proxies"]
    # Off: the visits measured (under the narrow sun toward it too) stay explicit.
    off = f"explicit grains to bounce {2 * switching(narrow)['proxy_visits']}"
    expected = [(narrow, [], "proxies"), (wide, [], f"proxies for {sw['chosen']} visits"),
                (wide, ["--proxies", "on"], "proxies"), (narrow, ["--proxies", "off"], off)]
    for k, (stage, extra, level) in enumerate(expected):
        rc, _, err = run_cli(["render", stage, "-o", tmp_path / f"{k}.exr", *OPTIONS, *extra], capsys)
        assert rc == 0, err
        assert _low_orders(err).startswith(f"after the first grain: {level}"), err
        px = np.asarray(core.read_image_rgb(str(tmp_path / f"{k}.exr")).pixels)
        assert np.isfinite(px).all()


def test_a_switching_measurement_is_run_again_with_its_exit_bins(tmp_path):
    # Scene.measure_switch (bench/switching.py --exit-bins): every candidate forks in every
    # path; what leaves per exit bin sums to the albedo; a scene that measured nothing refuses.
    desc = _ept_vpt_desc(small_scene(tmp_path / "wide.usda", _sun_angle(20.0)), width=24)
    built = core.Scene.build(desc)
    bins = core.switch_exit_bins()
    assert [b[2] for b in bins[:2]] == ["back", "forward"] and bins[0][1] == 1.0 and bins[-1][0] == 0.0
    m = built.measure_switch(0, paths=1024, stop_early=False)
    assert m["paths"] == 1024 and not m["from_cache"]
    n = len(bins)
    assert len(m["exit_bias"]) == len(m["exit_bias_se"]) == n * len(m["candidates"])
    np.testing.assert_allclose(np.sum(m["exit_reference"], axis=0), m["albedo"], rtol=1e-5)
    assert not np.any(m["exit_bias"][-n:])  # the reference against itself
    s = desc.settings
    s.technique = core.Technique.Ept
    desc.settings = s
    with pytest.raises(ValueError, match="did not measure"):  # an explicit scene has nothing to measure with
        core.Scene.build(desc).measure_switch(0)


def test_the_explicit_reference_never_uses_proxies(tmp_path, capsys):
    # ept with proxies asked for: nothing reaches the proxies' AOV (a 20° sun, which
    # explicit grains find, so that the image is not black).
    wide = small_scene(tmp_path / "wide.usda", _sun_angle(20.0))
    rc, _, err = run_cli(["render", wide, "-o", tmp_path / "ept.exr", "--width", "24", "--height", "16", "--spp",
                          "16", "--technique", "ept", "--proxies", "on"], capsys)
    assert rc == 0, err
    img = core.read_exr(str(tmp_path / "ept.exr"))
    px, names = np.asarray(img.pixels), list(img.channels)
    assert px[..., names.index("R")].max() > 0
    for c in ("ppt.R", "ppt.G", "ppt.B"):
        assert not px[..., names.index(c)].any(), c


def test_a_json_scene_says_proxies_as_the_command_line_does(tmp_path):
    # The same words in the JSON scene's render block as on the command line, read by the
    # same core function: "on" in JSON renders what ProxyUse.On set on the description does.
    scene = json.loads((ROOT / "examples" / "bright_sand.json").read_text())
    scene["render"].update(width=16, height=12, spp=2, technique="ept+vpt", proxies="on")
    path = tmp_path / "on.json"
    path.write_text(json.dumps(scene))
    from_json = core.load_scene_json(str(path))
    assert from_json.settings.proxies == core.ProxyUse.On
    del scene["render"]["proxies"]
    path.write_text(json.dumps(scene))
    by_hand = core.load_scene_json(str(path))
    assert by_hand.settings.proxies == core.ProxyUse.Auto
    s = by_hand.settings
    s.proxies = core.proxy_use_from_name("on", "command line")
    by_hand.settings = s
    images = []
    for desc in (from_json, by_hand):
        built = core.Scene.build(desc)
        assert built.use_proxies
        r = core.Renderer(built)
        r.render(pass_samples=2)
        images.append(np.asarray(r.image().pixels))
    np.testing.assert_array_equal(images[0], images[1])
    scene["render"]["proxies"] = "sometimes"
    path.write_text(json.dumps(scene))
    try:
        core.load_scene_json(str(path))
    except core.InputError as e:
        assert "proxies" in str(e) and "sometimes" in str(e)
    else:
        raise AssertionError("an unknown proxies word was accepted")


def test_switch_for_view_measures_the_view_too_and_takes_the_larger_choice(tmp_path, capsys):
    # --switch-for-view (JSON switch_for_view, Hydra granular:switchForView): each aggregate
    # the camera sees is measured for this camera and these lights as well (core/switching.h:
    # measureViewSwitch), its visits the larger choice, said on the low-orders line; a
    # change of view, no rebuild. The same measurement through Scene.measure_view_switch.
    stage = small_scene(tmp_path / "wide.usda", _sun_angle(20.0))
    desc = _ept_vpt_desc(stage, width=24, height=16)  # OPTIONS' image: the same view
    built = core.Scene.build(desc)
    dome = built.switching[0]
    assert "view" not in dome
    s = desc.settings
    s.switch_for_view = True
    built.set_view(desc.camera, s)
    sw = built.switching[0]
    view = sw["view"]
    assert sw["proxy_visits"] == max(dome["chosen"], view["chosen"])
    assert sw["chosen"] == dome["chosen"] and view["candidates"] == dome["candidates"]
    assert np.isfinite(view["bias"]).all() and min(view["albedo"]) > 0  # the radiance the camera sees
    again = built.measure_view_switch(0)
    assert again["entries"] >= 16 and again["bias"] == view["bias"]
    lines = {}
    for flag in ([], ["--switch-for-view"]):
        rc, _, err = run_cli(["render", stage, "-o", tmp_path / "v.exr", *OPTIONS, *flag], capsys)
        assert rc == 0, err
        lines[bool(flag)] = _low_orders(err)
        assert np.isfinite(np.asarray(core.read_image_rgb(str(tmp_path / "v.exr")).pixels)).all()
    assert "for this view" not in lines[False] and "for this view" in lines[True], lines
    assert lines[True].startswith(f"after the first grain: proxies for {sw['proxy_visits']} visits"), lines


def test_switch_for_view_in_a_json_scene(tmp_path):
    scene = tmp_path / "s.json"
    scene.write_text('{"render": {"switch_for_view": true}, "lights": [{"type": "distant"}]}')
    assert core.load_scene_json(str(scene)).settings.switch_for_view is True
    assert core.RenderSettings().switch_for_view is False
    bad = tmp_path / "bad.json"
    bad.write_text('{"render": {"switch_for_view": 1}}')
    with pytest.raises(core.InputError, match=r"render\.switch_for_view"):
        core.load_scene_json(str(bad))


def test_under_a_narrow_sun_the_switch_is_measured_toward_the_sun_too(tmp_path, capsys):
    # Under a narrow sun each aggregate is also measured as the sun sees it (core/scene.h:
    # sunSwitchMeasure), whatever the camera: its visits are the larger choice, said on the
    # low-orders line that granular render prints and hdGranular reports. A wide sun: not.
    # The same measurement through Scene.measure_view_switch(sun=True).
    built, scenes = {}, {}
    for angle in (0.53, 20.0):
        stage = small_scene(tmp_path / f"sun{angle}.usda", _sun_angle(angle))
        scenes[angle] = core.Scene.build(_ept_vpt_desc(stage, width=24, height=16))
        built[angle] = scenes[angle].switching[0]
        rc, _, err = run_cli(["render", stage, "-o", tmp_path / "s.exr", *OPTIONS], capsys)
        assert rc == 0, err
        line = _low_orders(err)
        assert ("toward the sun" in line) == (angle < 5), line
    narrow = built[0.53]
    sun = narrow["sun"]
    assert narrow["proxy_visits"] == max(narrow["chosen"], sun["chosen"])
    assert sun["candidates"] == narrow["candidates"] and np.isfinite(sun["bias"]).all()
    assert min(sun["albedo"]) > 0  # the radiance scattered back toward the sun
    again = scenes[0.53].measure_view_switch(0, sun=True)
    assert again["bias"] == sun["bias"] and again["paths"] == sun["paths"] >= 2**14
    assert "sun" not in built[20.0]
