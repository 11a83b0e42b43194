"""Animation: `granular render --frames A:B[xSTEP]` reads every time-sampled value at the
frame's time, keeps the built scene when only the view changes and builds it anew when the
scene changes, names the files by frame and writes each frame atomically.

Every render uses a fixed seed and a fixed survival probability (--roulette: the automatic
one is tuned on timings, which differ between runs), so that two renders of the same
description draw the same random numbers and agree to the bit; the bounds below are float
rounding, not Monte Carlo noise."""
import contextlib
import io

import numpy as np
import pytest
from conftest import EXAMPLES, run_cli, run_script, small_scene
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade, Vt

import granular_core as core
from granular.cli import frame_text, main, parse_frames
from granular.errors import UserError
from granular.usd_reader import read_stage

# Small and quick: 32x24 pixels, 4 samples per pixel, small_scene's one small aggregate.
OPTIONS = ["--width", 32, "--height", 24, "--spp", 4, "--seed", 7, "--roulette", 0.5]


def _timed(stage, frames=(1, 3)):
    """Frames 1 to 3, a normalized sun and a diffuse ground under the castle: the sun's light
    reaches the camera from it (grains alone are specular and let little through at 4 spp)."""
    stage.SetStartTimeCode(frames[0])
    stage.SetEndTimeCode(frames[1])
    ground = UsdGeom.Mesh.Define(stage, "/World/Floor")
    ground.CreatePointsAttr(Vt.Vec3fArray([(-3, 0, -3), (-3, 0, 3), (3, 0, 3), (3, 0, -3)]))
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    ground.CreateDisplayColorAttr([(0.5, 0.45, 0.4)])
    # UsdLux: a distant light's intensity is the radiance of its 0.53 degree disc; normalized,
    # it is the irradiance.
    UsdLux.LightAPI(stage.GetPrimAtPath("/World/Sun")).CreateNormalizeAttr(True)


def _look_at(eye, target=(0.0, 0.15, 0.0)):
    return Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 1, 0)).GetInverse()


EYES = {1: (1.0, 0.8, 1.2), 2: (1.3, 0.7, 0.9), 3: (1.5, 0.6, 0.4)}


def _camera_op(stage):
    return UsdGeom.Xformable(stage.GetPrimAtPath("/World/Camera")).GetOrderedXformOps()[0]


def _moving_camera(stage):
    _timed(stage)
    op = _camera_op(stage)
    op.GetAttr().Clear()
    for t, eye in EYES.items():
        op.Set(_look_at(eye), t)


def _camera_still_at(t):
    def mutate(stage):
        _timed(stage)
        _camera_op(stage).Set(_look_at(EYES[t]))
    return mutate


def _render(scene, out, capsys, *extra):
    rc, _, err = run_cli(["render", scene, "-o", out, *OPTIONS, *extra], capsys)
    assert rc == 0, err
    assert "Traceback" not in err
    return err


def _pixels(path):
    """The EXR's colour as written (read_image_rgb would zero a NaN), all finite."""
    rgb = np.asarray(core.read_exr(str(path)).pixels, dtype=np.float64)[..., :3]
    assert np.isfinite(rgb).all(), path
    return rgb


def _frame_lines(err):
    return [line for line in err.splitlines() if line.startswith("frame ")]


# ---- the frame specification and the file names --------------------------------------------

def test_frame_specs_and_numbers():
    assert parse_frames("1:3") == [1.0, 2.0, 3.0]
    assert parse_frames("1:2x0.5") == [1.0, 1.5, 2.0]
    assert parse_frames("1:2x0.1")[3] == 1.3 and parse_frames("1:2x0.1")[-1] == 2.0  # A + k STEP, B included
    assert parse_frames("0:1x0.3") == [0.0, 0.3, 0.6, 0.9]
    assert parse_frames("5") == [5.0]
    assert parse_frames("-2:2x2") == [-2.0, 0.0, 2.0]
    assert [frame_text(f, 4) for f in (1, 12, 1.5, 0.25, -2, 12345)] == \
        ["0001", "0012", "0001.5", "0000.25", "-0002", "12345"]
    assert frame_text(2.5) == "2.5" and frame_text(3.0) == "3"
    for bad in ("3:1", "1:3x0", "1:3x-1", "1:nan", "inf:3", "a:3", "1:3xb", "1:2:3", "1x2", "1:", ":3", "1:3x", "",
                "1:1000000"):
        with pytest.raises(UserError) as e:
            parse_frames(bad)
        assert (e.value.object, e.value.attribute) == ("command line", "--frames"), bad


# ---- the reader reads at the given time --------------------------------------------------------

def test_reader_reads_every_time_sampled_value_at_the_given_time(tmp_path):
    def mutate(stage):
        _moving_camera(stage)
        cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
        cam.GetFocalLengthAttr().Clear()
        cam.GetFocalLengthAttr().Set(30.0, 1)
        cam.GetFocalLengthAttr().Set(50.0, 3)
        sun = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun"))
        for t, (i, c, x) in {1: (1.0, (1, 1, 1), 0.0), 3: (3.0, (1, 0, 0), 2.0)}.items():
            sun.GetIntensityAttr().Set(i, t)
            sun.CreateColorAttr().Set(Gf.Vec3f(*c), t)
            sun.CreateExposureAttr().Set(x, t)
        sun_op = UsdGeom.Xformable(sun).GetOrderedXformOps()[0]
        sun_op.Set(-60.0, 1)
        sun_op.Set(-30.0, 3)
        box = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Castle"))
        pts = np.array(box.GetPointsAttr().Get())
        for t, s in ((1, 1.0), (3, 2.0)):
            box.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy((pts * s).astype(np.float32)), t)
        rate = stage.GetPrimAtPath("/World/Castle").GetAttribute("primvars:granular:packingRate")
        rate.Set(0.5, 1)
        rate.Set(0.3, 3)
        ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
        ground.CreatePointsAttr(Vt.Vec3fArray([(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)]))
        ground.CreateFaceVertexCountsAttr([4])
        ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        move = UsdGeom.Xformable(ground).AddTranslateOp()
        move.Set(Gf.Vec3d(0, 0, 0), 1)
        move.Set(Gf.Vec3d(0, -1, 0), 3)
        mat = UsdShade.Material.Define(stage, "/World/Looks/Sand")
        sh = UsdShade.Shader.Define(stage, "/World/Looks/Sand/Surface")
        sh.CreateIdAttr("UsdPreviewSurface")
        color = sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f)
        color.Set(Gf.Vec3f(0.2, 0.2, 0.2), 1)
        color.Set(Gf.Vec3f(0.6, 0.4, 0.2), 3)
        mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(ground.GetPrim()).Bind(mat)
        settings = UsdRender.Settings.Define(stage, "/Render/Settings")
        settings.CreateResolutionAttr().Set(Gf.Vec2i(40, 30), 1)
        settings.GetResolutionAttr().Set(Gf.Vec2i(80, 60), 3)
        stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")

    path = str(small_scene(tmp_path / "s.usda", mutate))
    stage = Usd.Stage.Open(path)
    start = read_stage(path)  # no time: the stage's start, frame 1
    at1 = read_stage(path, stage=stage, time=1)
    at3 = read_stage(path, stage=stage, time=Usd.TimeCode(3))
    at2 = read_stage(path, stage=stage, time=2.0)  # linear interpolation between the samples
    for scene in (start, at1):
        d = scene.desc
        assert d.camera.focal_length == pytest.approx(30.0)
        assert (d.settings.width, d.settings.height) == (40, 30)
        assert d.lights[0].intensity == pytest.approx(1.0) and d.lights[0].color == pytest.approx((1, 1, 1))
        assert d.aggregates[0].packing_rate == pytest.approx(0.5)
    d1, d2, d3 = at1.desc, at2.desc, at3.desc
    assert d2.camera.focal_length == pytest.approx(40.0) and d3.camera.focal_length == pytest.approx(50.0)
    assert np.array(d3.camera.camera_to_world)[:3, 3] == pytest.approx(EYES[3])
    assert np.array(d2.camera.camera_to_world)[:3, 3] == pytest.approx(EYES[2])
    assert (d3.settings.width, d3.settings.height) == (80, 60)
    sun1, sun3 = d1.lights[0], d3.lights[0]
    assert (sun3.intensity, sun3.exposure) == (pytest.approx(3.0), pytest.approx(2.0))
    assert sun3.color == pytest.approx((1, 0, 0))
    assert not np.allclose(np.array(sun1.xf), np.array(sun3.xf))
    assert np.ptp(d3.aggregates[0].boundary.points, axis=0) == pytest.approx(
        2 * np.ptp(d1.aggregates[0].boundary.points, axis=0))
    assert d3.aggregates[0].packing_rate == pytest.approx(0.3)
    g1 = [m for m in d1.meshes if m.name == "/World/Ground"][0]
    g3 = [m for m in d3.meshes if m.name == "/World/Ground"][0]
    assert np.array(g1.xf)[1, 3] == pytest.approx(0.0) and np.array(g3.xf)[1, 3] == pytest.approx(-1.0)
    assert d1.materials[g1.material].albedo == pytest.approx((0.2, 0.2, 0.2))
    assert d3.materials[g3.material].albedo == pytest.approx((0.6, 0.4, 0.2))


# ---- rendering sequences -----------------------------------------------------------------------

def _sun_intensity(stage, samples, frames=(1, 3)):
    """The stage timed over frames, its sun's intensity only the given {time: value}."""
    _timed(stage, frames)
    a = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun")).GetIntensityAttr()
    a.Clear()
    for t, v in samples.items():
        a.Set(v, t)


def test_a_light_whose_intensity_doubles_doubles_the_image(tmp_path, capsys):
    scene = small_scene(tmp_path / "light.usda", lambda st: _sun_intensity(st, {1: 1.0, 2: 2.0, 3: 4.0}))
    err = _render(scene, tmp_path / "f.####.exr", capsys, "--frames", "1:3")
    lines = _frame_lines(err)
    # The scene is built anew for the light, but the aggregate is reused: no voxelising.
    assert len(lines) == 3 and all("rebuilt (lights changed; aggregates: 0 built, 1 reused)" in line
                                   for line in lines[1:]), err
    f1, f2, f3 = (_pixels(tmp_path / f"f.000{k}.exr") for k in (1, 2, 3))
    assert f1.mean() > 0.01, "the light reaches the camera"
    # Same seed, same random numbers: only the light's scale differs, so the images scale
    # by the same factor up to float rounding.
    scale = np.abs(f1).max()
    for factor, f in ((2.0, f2), (4.0, f3)):
        assert np.abs(f - factor * f1).max() <= 1e-4 * factor * scale


@pytest.fixture(scope="module")
def camera_animation(tmp_path_factory):
    """small_scene with only its camera moving over frames 1 to 3, rendered as a sequence
    with EXR and PNG; (folder, stderr)."""
    folder = tmp_path_factory.mktemp("camera")
    scene = small_scene(folder / "moving.usda", _moving_camera)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main([str(a) for a in ["render", scene, "-o", folder / "m.####.exr", "--png", folder / "m.####.png",
                                    *OPTIONS, "--frames", "1:3"]])
    assert rc == 0, err.getvalue()
    return folder, err.getvalue()


def test_a_camera_only_animation_reuses_the_built_scene(camera_animation):
    folder, err = camera_animation
    lines = _frame_lines(err)
    assert len(lines) == 3, err
    assert lines[0].startswith("frame 1: scene built")
    for k, line in ((2, lines[1]), (3, lines[2])):
        assert line.startswith(f"frame {k}: scene reused (new camera)"), line
        assert "rebuilt" not in line and f"m.000{k}.exr and " in line and f"m.000{k}.png" in line
    assert sorted(p.name for p in folder.iterdir() if p.name.startswith("m.")) == \
        ["m.0001.exr", "m.0001.png", "m.0002.exr", "m.0002.png", "m.0003.exr", "m.0003.png"]
    assert not [p for p in folder.iterdir() if "tmp" in p.name], "temporary files were left behind"
    f1, f2 = _pixels(folder / "m.0001.exr"), _pixels(folder / "m.0002.exr")
    assert not np.array_equal(f1, f2), "the camera moved"


def test_a_frame_of_a_moving_camera_equals_the_still_render_from_there(camera_animation, tmp_path, capsys):
    folder, _ = camera_animation
    still = small_scene(tmp_path / "still.usda", _camera_still_at(2))
    _render(still, tmp_path / "still.exr", capsys)
    frame2 = _pixels(folder / "m.0002.exr")
    assert frame2.mean() > 0.01, "lit"
    # The reused scene with the new view is the scene built for that view.
    np.testing.assert_array_equal(frame2, _pixels(tmp_path / "still.exr"))


BOX = ((-0.2, 0.0, -0.2), (0.2, 0.3, 0.2))


def _moving_boundary(how, t=None):
    """The castle's boundary moves from frame 1 to 2 (its points or its transform); with t,
    a still stage holding its frame-t value as the default."""
    def value(frame):
        if how == "points":
            s = 1.0 + 0.25 * (frame - 1)
            return Vt.Vec3fArray.FromNumpy(
                (np.array(core.make_box(*BOX).points) * np.float32(s)).astype(np.float32))
        return Gf.Vec3d(0.12 * (frame - 1), 0.0, 0.0)

    def mutate(stage):
        _timed(stage, (1, 2))
        prim = stage.GetPrimAtPath("/World/Castle")
        if how == "points":
            attr = UsdGeom.Mesh(prim).GetPointsAttr()
        else:
            attr = UsdGeom.Xformable(prim).AddTranslateOp().GetAttr()
        if t is not None:
            attr.Set(value(t))
            return
        attr.Clear()
        for frame in (1, 2):
            attr.Set(value(frame), frame)
    return mutate


@pytest.mark.parametrize("how", ["points", "transform"])
def test_a_moving_boundary_rebuilds_and_equals_the_still_render(how, tmp_path, capsys):
    moving = small_scene(tmp_path / "moving.usda", _moving_boundary(how))
    err = _render(moving, tmp_path / "b.##.exr", capsys, "--frames", "1:2")
    lines = _frame_lines(err)
    assert len(lines) == 2 and lines[1].startswith(
        "frame 2: scene rebuilt (1 aggregate changed; aggregates: 1 built, 0 reused)"), err
    still = small_scene(tmp_path / "still.usda", _moving_boundary(how, t=2))
    _render(still, tmp_path / "still.exr", capsys)
    f1, f2 = _pixels(tmp_path / "b.01.exr"), _pixels(tmp_path / "b.02.exr")
    assert f2.mean() > 0.01 and not np.array_equal(f1, f2), "lit, and the boundary moved"
    np.testing.assert_array_equal(f2, _pixels(tmp_path / "still.exr"))


def test_a_grain_roughness_that_changes_rebuilds_the_scene(tmp_path, capsys):
    """Every material input is compared between frames: a time-sampled grain roughness once
    left frame 2 rendered with frame 1's grains (18% dark on the frosted example)."""
    def mutate(stage):
        _timed(stage, (1, 2))
        a = stage.GetPrimAtPath("/World/Grains/A").GetAttribute("primvars:granular:roughness")
        if not a:
            a = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Grains/A")).CreatePrimvar(
                "granular:roughness", Sdf.ValueTypeNames.Float, UsdGeom.Tokens.constant).GetAttr()
        a.Set(0.05, 1)
        a.Set(0.9, 2)
    scene = small_scene(tmp_path / "rough.usda", mutate)
    err = _render(scene, tmp_path / "r.#.exr", capsys, "--frames", "1:2")
    lines = _frame_lines(err)
    # The grain material belongs to the aggregate's inputs: it alone is made anew.
    assert lines[1].startswith("frame 2: scene rebuilt (1 aggregate changed; aggregates: 1 built, 0 reused)"), lines[1]
    _render(scene, tmp_path / "still.#.exr", capsys, "--frames", "2")
    f1, f2 = _pixels(tmp_path / "r.1.exr"), _pixels(tmp_path / "r.2.exr")
    assert not np.array_equal(f1, f2)
    np.testing.assert_array_equal(f2, _pixels(tmp_path / "still.2.exr"))


def _frosted_with_rough_polish(path, samples):
    """examples/frosted.usda with its polished grains' roughness time-sampled ({frame: value})."""
    layer = Sdf.Layer.CreateNew(str(path))
    layer.subLayerPaths.append(str(EXAMPLES / "frosted.usda"))
    stage = Usd.Stage.Open(layer)
    stage.SetStartTimeCode(min(samples))
    stage.SetEndTimeCode(max(samples))
    attr = stage.OverridePrim("/World/Grains/Polished").CreateAttribute("primvars:granular:roughness",
                                                                         Sdf.ValueTypeNames.Float)
    for t, v in samples.items():
        attr.Set(v, t)
    layer.Save()
    return path


def test_the_frosted_example_with_a_time_sampled_roughness_renders_frame_2_as_alone(tmp_path, capsys):
    """The roughness of one of frosted.usda's grain prototypes changes from frame 1 to 2:
    compare_scenes finds the aggregate's inputs changed, so frame 2 of the sequence is the
    image frame 2 renders on its own, bit for bit."""
    scene = _frosted_with_rough_polish(tmp_path / "frosted.usda", {1: 0.0, 2: 0.6})
    size = ["--width", 24, "--height", 18, "--spp", 1]
    rc, _, err = run_cli(["render", scene, "-o", tmp_path / "seq.#.exr", "--frames", "1:2", *size, "--seed", 7,
                          "--roulette", 0.5], capsys)
    assert rc == 0, err
    lines = _frame_lines(err)
    assert lines[1].startswith("frame 2: scene rebuilt (1 aggregate changed; aggregates: 1 built, 0 reused)"), err
    rc, _, err = run_cli(["render", scene, "-o", tmp_path / "alone.#.exr", "--frames", "2:2", *size, "--seed", 7,
                          "--roulette", 0.5], capsys)
    assert rc == 0, err
    f1, f2 = _pixels(tmp_path / "seq.1.exr"), _pixels(tmp_path / "seq.2.exr")
    assert f2.mean() > 0.01 and not np.array_equal(f1, f2), "lit, and the grains changed"
    np.testing.assert_array_equal(f2, _pixels(tmp_path / "alone.2.exr"))


def test_compare_scenes_says_what_changed_between_frames(tmp_path):
    """core.compare_scenes on the descriptions the reader gives at two times: a moving camera
    is a view; a grain roughness lists its aggregate; a light is lights."""
    def changes(scene, a=1, b=2):
        return core.compare_scenes(read_stage(str(scene), time=a).desc, read_stage(str(scene), time=b).desc)

    camera = changes(small_scene(tmp_path / "camera.usda", _moving_camera))
    assert camera.level == core.SceneChange.View and camera.camera and not camera.settings
    assert camera.description == "new camera"
    rough = changes(_frosted_with_rough_polish(tmp_path / "rough.usda", {1: 0.0, 2: 0.6}))
    assert rough.level == core.SceneChange.Aggregates and list(rough.aggregates) == [0]
    assert not (rough.materials or rough.meshes or rough.lights)
    light = changes(small_scene(tmp_path / "light.usda", lambda st: _sun_intensity(st, {1: 1.0, 2: 2.0})))
    assert light.level == core.SceneChange.Lights and light.description == "lights changed"
    still = changes(small_scene(tmp_path / "still.usda", _timed))
    assert still.level == core.SceneChange.Unchanged and still.description == "unchanged"


def test_fractional_steps_name_files_by_frame_and_reuse_an_unchanged_scene(scene_file, tmp_path, capsys):
    scene = scene_file(_timed)  # nothing animated: every frame after the first reuses the scene as it is
    err = _render(scene, tmp_path / "s_###.exr", capsys, "--frames", "1:2x0.5", "--png", tmp_path / "p#.png")
    lines = _frame_lines(err)
    assert [line.split(":")[0] for line in lines] == ["frame 1", "frame 1.5", "frame 2"]
    assert all("scene reused (unchanged)" in line for line in lines[1:])
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix in (".exr", ".png")) == \
        ["p1.5.png", "p1.png", "p2.png", "s_001.5.exr", "s_001.exr", "s_002.exr"]
    np.testing.assert_array_equal(_pixels(tmp_path / "s_001.exr"), _pixels(tmp_path / "s_002.exr"))


def test_a_failure_mid_sequence_keeps_the_complete_frames_only(tmp_path, capsys):
    def mutate(stage):
        _sun_intensity(stage, {1: 5.0, 1.5: 5.0, 2: -1.0})  # bad from frame 2 on
    scene = small_scene(tmp_path / "bad.usda", mutate)
    out = tmp_path / "out"
    out.mkdir()
    rc, _, err = run_cli(["render", scene, "-o", out / "f.####.exr", "--png", out / "f.####.png", *OPTIONS,
                          "--frames", "1:3"], capsys)
    assert rc == 2, err
    assert err.strip().splitlines()[-1] == "error: /World/Sun.inputs:intensity: -1 must be finite and >= 0"
    assert sorted(p.name for p in out.iterdir()) == ["f.0001.exr", "f.0001.png"]
    assert core.read_image_rgb(str(out / "f.0001.exr")).width == 32


# ---- command-line errors -----------------------------------------------------------------------

@pytest.mark.parametrize("argv,expected", [
    (["--frames", "3:1"], "error: command line.--frames: start 3 is after end 1"),
    (["--frames", "1:3x0"], "error: command line.--frames: step 0 must be > 0"),
    (["--frames", "1:3x-0.5"], "error: command line.--frames: step -0.5 must be > 0"),
    (["--frames", "1:nan"], "error: command line.--frames: end nan is not finite"),
    (["--frames", "1:inf"], "error: command line.--frames: end inf is not finite"),
    (["--frames", "one:3"], "error: command line.--frames: start 'one' is not a number"),
    (["--frames", "1-3"], "error: command line.--frames: start '1-3' is not a number"),
    (["--frames", "1:2:3"], "error: command line.--frames: '1:2:3' is not A:B or A:BxSTEP (e.g. 1:24 or 1:2x0.5)"),
    (["--frames", "1:1000000"], "error: command line.--frames: '1:1000000' has 1000000 frames, more than 100000"),
    (["--frames", "1:2x0.0000001"], ["error: command line.--frames: ", "more than 100000"]),
    (["--frames", "1:1.000001x0.0000004"], ["error: command line.--frames: step too small: frames "]),
    (["--frames", "1:3", "-o", "{tmp}/plain.exr"], ['error: command line.-o: "', "plain.exr\" has no run of '#'"]),
    (["--frames", "1:3", "--png", "{tmp}/plain.png"], ['error: command line.--png: "', "plain.png\" has no run"]),
    (["--frames", "1:3", "-o", "{tmp}/f.####.png"], ["error: command line.-o: ", "must end in .exr"]),
])
def test_bad_frame_options_exit_2_with_one_line_and_no_files(argv, expected, scene_file, tmp_path, capsys):
    scene = scene_file()
    out = tmp_path / "out"
    out.mkdir()
    argv = [a.replace("{tmp}", str(out)) for a in argv]
    if "-o" not in argv:
        argv += ["-o", str(out / "f.####.exr")]
    rc, _, err = run_cli(["render", scene, *argv, "--width", 16, "--height", 12, "--spp", 1], capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and len(lines) == 1, err
    if isinstance(expected, str):
        assert lines[0] == expected
    else:
        for fragment in expected:
            assert fragment in lines[0], lines[0]
    assert list(out.iterdir()) == []


def test_without_frames_the_stage_renders_once_at_its_start(tmp_path, capsys):
    scene = small_scene(tmp_path / "s.usda", lambda st: _sun_intensity(st, {1: 100.0, 2: 1.0, 3: 100.0}, (2, 3)))
    err = _render(scene, tmp_path / "one.####.exr", capsys, "--frames", "2")
    assert _frame_lines(err)[0].startswith("frame 2: scene built")
    _render(scene, tmp_path / "start.exr", capsys)  # no --frames: the start time, 2; '#' is no pattern
    np.testing.assert_array_equal(_pixels(tmp_path / "one.0002.exr"), _pixels(tmp_path / "start.exr"))
    assert sorted(p.name for p in tmp_path.iterdir() if p.suffix == ".exr") == ["one.0002.exr", "start.exr"]


def test_the_animated_example(tmp_path, capsys):
    """examples/animated.usda: its camera moves from frame 1 to 2 (the scene, with its
    equivalent media, is kept) and its sun brightens from 2 to 3 (built anew); frame 2 is
    the still render from frame 2's camera, media and all."""
    example = str(EXAMPLES / "animated.usda")
    err = _render(example, tmp_path / "a.#.exr", capsys, "--frames", "1:3")
    lines = _frame_lines(err)
    assert [line.split(";")[0] for line in lines] == [
        lines[0].split(";")[0], "frame 2: scene reused (new camera)", lines[2].split(";")[0]]
    assert lines[0].startswith("frame 1: scene built") and lines[2].startswith("frame 3: scene rebuilt (lights changed;")
    assert "VPT" in err, "the example's aggregate is deep enough for the media"

    stage = Usd.Stage.Open(example)
    op = _camera_op(stage)
    frame2 = op.Get(2)
    op.GetAttr().Clear()
    op.Set(frame2)
    stage.GetRootLayer().Export(str(tmp_path / "still.usda"))
    _render(tmp_path / "still.usda", tmp_path / "still.exr", capsys)
    f2 = _pixels(tmp_path / "a.2.exr")
    assert f2.mean() > 0.01
    np.testing.assert_array_equal(f2, _pixels(tmp_path / "still.exr"))


def test_the_installed_script_reports_a_bad_frame_range_in_one_line(scene_file, tmp_path):
    r = run_script(["render", scene_file(), "-o", tmp_path / "f.####.exr", "--frames", "3:1"], timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["error: command line.--frames: start 3 is after end 1"]
    assert not list(tmp_path.glob("f.*"))


# ---- every animated value: a sequence frame equals the frame rendered alone ----------------

def _primvar(stage, path, name, type_name):
    prim = stage.GetPrimAtPath(path)
    attr = prim.GetAttribute("primvars:granular:" + name)
    if attr:
        attr.Clear()
        return attr
    return UsdGeom.PrimvarsAPI(prim).CreatePrimvar("granular:" + name, type_name, UsdGeom.Tokens.constant).GetAttr()


# name -> (attribute getter, value at frame 1, value at frame 2)
ANIMATED = {
    "roughness": (lambda s: _primvar(s, "/World/Grains/A", "roughness", Sdf.ValueTypeNames.Float), 0.05, 0.9),
    "ior": (lambda s: _primvar(s, "/World/Grains/A", "ior", Sdf.ValueTypeNames.Float), 1.5, 1.9),
    "absorption": (lambda s: _primvar(s, "/World/Grains/B", "absorption", Sdf.ValueTypeNames.Color3f),
                   Gf.Vec3f(0, 0, 0), Gf.Vec3f(0.5, 0.2, 0.1)),
    "weights": (lambda s: _primvar(s, "/World/Castle", "weights", Sdf.ValueTypeNames.FloatArray),
                Vt.FloatArray([0.7, 0.3]), Vt.FloatArray([0.2, 0.8])),
    "sizes": (lambda s: _primvar(s, "/World/Castle", "sizes", Sdf.ValueTypeNames.FloatArray),
              Vt.FloatArray([1.0, 1.0]), Vt.FloatArray([1.0, 0.6])),
    "sun intensity": (lambda s: UsdLux.LightAPI(s.GetPrimAtPath("/World/Sun")).GetIntensityAttr(), 1.0, 2.5),
    "sun color": (lambda s: UsdLux.LightAPI(s.GetPrimAtPath("/World/Sun")).CreateColorAttr(),
                  Gf.Vec3f(1, 1, 1), Gf.Vec3f(1, 0.6, 0.3)),
    "sun angle": (lambda s: UsdLux.DistantLight(s.GetPrimAtPath("/World/Sun")).CreateAngleAttr(), 0.53, 8.0),
    "focal length": (lambda s: UsdGeom.Camera(s.GetPrimAtPath("/World/Camera")).GetFocalLengthAttr(), 35.0, 50.0),
    "fStop": (lambda s: UsdGeom.Camera(s.GetPrimAtPath("/World/Camera")).CreateFStopAttr(), 0.0, 2.0),
}


def _animated_values(names):
    def mutate(stage):
        _timed(stage, (1, 2))
        UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera")).CreateFocusDistanceAttr(1.6)
        for name in names:
            get, a, b = ANIMATED[name]
            attr = get(stage)
            attr.Set(a, 1)
            attr.Set(b, 2)
    return mutate


@pytest.mark.parametrize("name", list(ANIMATED))
def test_every_animated_value_renders_frame_2_of_a_sequence_as_alone(name, tmp_path, capsys):
    """Grain, aggregate, light and camera values time-sampled from frame 1 to 2: frame 2 of
    `--frames 1:2` is, bit for bit, frame 2 rendered on its own (compare_scenes finds every
    change; nothing of frame 1 is kept that frame 2 changed)."""
    scene = small_scene(tmp_path / "anim.usda", _animated_values([name]))
    _render(scene, tmp_path / "seq.#.exr", capsys, "--frames", "1:2")
    _render(scene, tmp_path / "alone.#.exr", capsys, "--frames", "2:2")
    f1, f2 = _pixels(tmp_path / "seq.1.exr"), _pixels(tmp_path / "seq.2.exr")
    assert not np.array_equal(f1, f2), f"{name} changes the image"
    np.testing.assert_array_equal(f2, _pixels(tmp_path / "alone.2.exr"))


def test_a_farm_of_two_workers_renders_every_animated_value_as_single_frames(tmp_path):
    """All of them animated at once, through `granular farm` with 2 worker processes and
    tiles: each frame equals that frame rendered alone in one process."""
    scene = small_scene(tmp_path / "all.usda", _animated_values(list(ANIMATED)))
    out = tmp_path / "farm"
    out.mkdir()
    r = run_script(["farm", scene, "-o", out / "f.#.exr", "--frames", "1:2", "--tiles", 2, "--workers", 2,
                    *OPTIONS], timeout=300)
    assert r.returncode == 0, r.stderr
    for frame in (1, 2):
        alone = tmp_path / f"alone{frame}.#.exr"
        r = run_script(["render", scene, "-o", alone, "--frames", f"{frame}:{frame}", *OPTIONS, "--quiet"])
        assert r.returncode == 0, r.stderr
        np.testing.assert_array_equal(_pixels(out / f"f.{frame}.exr"), _pixels(tmp_path / f"alone{frame}.{frame}.exr"))
