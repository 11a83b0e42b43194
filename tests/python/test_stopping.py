"""`granular render --noise-threshold` and `--time-limit`: adaptive sampling stops each pixel
at the delegate's rule (core's Film::pixelBelowNoiseThreshold, from two bundles and 16 samples
on) and the render once every pixel has, or at a deadline once every pixel has samples; it
says so, logs the samples per pixel it used, and writes a complete image."""
import re
import time

import numpy as np
from conftest import dome_card, run_cli
from pxr import Gf, Usd, UsdGeom, UsdLux

import granular_core as core
from granular.usd_reader import read_stage


def _ball_on_floor(path):
    """A grey ball on a grey floor under a dim uniform sky, seen level: the sky (the top
    half of the image) is a flat dark background, every sample of it the same; the ball and
    the floor around it, lit by what the ball leaves of the sky, are noisy."""
    stage = Usd.Stage.CreateNew(str(path))
    cam = UsdGeom.Camera.Define(stage, "/Camera")
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    UsdLux.DomeLight.Define(stage, "/Sky").CreateIntensityAttr(0.1)
    floor = UsdGeom.Mesh.Define(stage, "/Floor")
    floor.CreatePointsAttr([(-20, -1, 4), (20, -1, 4), (20, -1, -20), (-20, -1, -20)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    ball = UsdGeom.Sphere.Define(stage, "/Ball")
    UsdGeom.Xformable(ball).AddTranslateOp().Set(Gf.Vec3d(0, 0, -4))
    stage.Save()
    return str(path)


def _adaptive(path, threshold, spp, seed=1, threads=0):
    scene = read_stage(path, width=32, height=24)
    s = scene.desc.settings
    s.spp, s.seed, s.threads = spp, seed, threads
    r = core.Renderer(core.Scene.build(scene.desc))
    assert r.render(1, None, 0.25, noise_threshold=threshold)
    return r


def test_adaptive_sampling_spends_the_samples_where_the_noise_is(tmp_path):
    r = _adaptive(_ball_on_floor(tmp_path / "ball.usda"), 0.05, 512)
    counts = r.sample_count_map()
    minimum = r.min_adaptive_samples
    assert minimum == 16  # two bundles of one path (no media), 16 samples at least
    assert (counts[0] == minimum).all(), counts[0]  # the sky stopped as early as it may
    assert counts.min() >= minimum and counts.max() <= 512
    assert counts.max() >= 4 * minimum, counts.max()  # the noisy pixels went on
    c = r.sample_counts
    assert c["min"] == counts.min() and c["max"] == counts.max()
    assert abs(c["mean"] - counts.mean()) < 1e-9
    assert c["mean"] < 0.5 * 512


def test_an_adaptive_render_depends_on_neither_threads_nor_pass_sizes(tmp_path):
    path = _ball_on_floor(tmp_path / "ball.usda")
    one = _adaptive(path, 0.05, 128, threads=1)
    many = _adaptive(path, 0.05, 128, threads=0)
    np.testing.assert_array_equal(one.sample_count_map(), many.sample_count_map())
    np.testing.assert_array_equal(one.image().pixels, many.image().pixels)


def test_the_cli_logs_the_mean_and_most_samples_per_pixel(tmp_path, capsys):
    path = _ball_on_floor(tmp_path / "ball.usda")
    rc, _, err = run_cli(["render", path, "-o", tmp_path / "o.exr", "--width", 32, "--height", 24, "--spp", 256,
                          "--noise-threshold", 0.05], capsys)
    assert rc == 0, err
    m = re.search(r"adaptive sampling: ([0-9.]+) samples per pixel on average, (\d+) at most \(of 256\)", err)
    assert m, err
    mean, most = float(m.group(1)), int(m.group(2))
    assert 16 <= mean < most <= 256


def _samples(err):
    line = [x for x in err.splitlines() if "stopped at the" in x]
    return line[0] if line else None


def test_the_noise_threshold_stops_a_quiet_image_before_its_samples(tmp_path, capsys):
    scene = dome_card(tmp_path / "card.usda")
    out = tmp_path / "o.exr"
    rc, _, err = run_cli(["render", scene, "-o", out, "--width", 32, "--height", 24, "--spp", 4096,
                          "--noise-threshold", 0.05], capsys)
    assert rc == 0, err
    line = _samples(err)
    assert line is not None and line.strip().startswith("stopped at the noise threshold after"), err
    done = int(line.split("after ")[1].split(" of")[0])
    assert 16 <= done < 4096  # two bundles and 16 samples at least
    rgb = np.asarray(core.read_exr(str(out)).pixels, dtype=np.float64)[..., :3]
    assert np.isfinite(rgb).all() and rgb.min() > 0


def test_without_a_threshold_or_limit_every_sample_is_rendered(tmp_path, capsys):
    scene = dome_card(tmp_path / "card.usda")
    rc, _, err = run_cli(["render", scene, "-o", tmp_path / "o.exr", "--width", 16, "--height", 12, "--spp", 64],
                         capsys)
    assert rc == 0 and _samples(err) is None, err


def test_the_time_limit_stops_at_the_deadline_with_a_complete_image(tmp_path, capsys):
    scene = dome_card(tmp_path / "card.usda")
    out = tmp_path / "o.exr"
    t0 = time.monotonic()
    rc, _, err = run_cli(["render", scene, "-o", out, "--width", 64, "--height", 48, "--spp", 1000000,
                          "--time-limit", 1], capsys)
    assert rc == 0, err
    assert time.monotonic() - t0 < 30
    line = _samples(err)
    assert line is not None and line.strip().startswith("stopped at the time limit after"), err
    img = core.read_exr(str(out))
    rgb = np.asarray(img.pixels, dtype=np.float64)[..., :3]
    assert np.isfinite(rgb).all() and rgb.min() > 0  # every pixel has samples
