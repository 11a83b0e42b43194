"""`granular render --noise-threshold` and `--time-limit`: the render stops early by the
delegate's rule (core's Film::belowNoiseThreshold after a pass, from two bundles on) or at a
deadline once every pixel has samples, says so, and writes a complete image."""
import time

import numpy as np
from conftest import dome_card, run_cli

import granular_core as core


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
    assert 32 <= done < 4096  # two bundles at least
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
