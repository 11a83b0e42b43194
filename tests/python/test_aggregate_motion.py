"""Transform motion blur of an aggregate through `granular render`: a box of sand sliding over
the camera's open shutter (aggregate_motion_stage.py) gets its world transforms at the
shutter's ends (core's AggregateDesc.shutterXf), and its blurred image differs from the still
frame far beyond noise and equals, within noise, the average of still frames at times spread
over the shutter (noise_check.py)."""
import numpy as np
import pytest
from aggregate_motion_stage import SAND, write_stage
from conftest import run_cli
from noise_check import block_chi2, noise_limit, rgb_and_variance

import granular_core as core
from granular import usd_reader
from granular.cli import main as cli_main

WIDTH, HEIGHT, SPP, SLICES = 48, 32, 64, 8


def _translation(m):
    return [m[0][3], m[1][3], m[2][3]]


def test_the_reader_samples_the_aggregates_transform_at_the_shutters_ends(tmp_path):
    # The shutter is open from frame 0.5 to 1.5 about frame 1 (24 time codes a second): the
    # box is at x = -1.2 + 1.2 t then.
    stage = write_stage(tmp_path / "s.usda")
    a = usd_reader.read_stage(stage).desc.aggregates[0]
    assert a.name == SAND
    assert _translation(a.xf) == pytest.approx([0, 0, 0], abs=1e-12)
    assert a.shutter_xf is not None
    assert _translation(a.shutter_xf[0]) == pytest.approx([-0.6, 0, 0], abs=1e-6)
    assert _translation(a.shutter_xf[1]) == pytest.approx([0.6, 0, 0], abs=1e-6)
    # A closed shutter, or one that does not move it: still.
    assert usd_reader.read_stage(write_stage(tmp_path / "shut.usda", shutter=(0, 0))).desc.aggregates[0].shutter_xf \
        is None
    d = usd_reader.read_stage(stage).desc
    core.still_frame(d)
    assert d.aggregates[0].shutter_xf is None


def test_a_turn_too_far_over_the_shutter_names_the_prim(tmp_path, capsys):
    # 280 degrees in two frames: 140 over the shutter, beyond what a linear blend can carry.
    rc, _, err = run_cli(["render", write_stage(tmp_path / "s.usda", turn=280.0), "-o", tmp_path / "x.exr",
                          "--width", 8, "--height", 8, "--spp", 1, "--quiet"], capsys)
    assert rc != 0
    assert SAND in err and "turns or flips too far over the shutter" in err, err


def _render(tmp_path, stage, name, seed, *extra):
    out = tmp_path / f"{name}_#.exr"
    argv = ["render", stage, "-o", out, "--width", WIDTH, "--height", HEIGHT, "--seed", seed, "--quiet", *extra]
    assert cli_main([str(a) for a in argv]) == 0
    found = sorted(tmp_path.glob(f"{name}_*.exr"))
    assert len(found) == 1, found
    return rgb_and_variance(found[0])


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    d = tmp_path_factory.mktemp("aggregate_motion")
    stage = write_stage(d / "sliding.usda")
    out = {
        "blurred": _render(d, stage, "blurred", 0, "--spp", SPP, "--frames", 1),
        "still": _render(d, stage, "still", 1, "--spp", SPP, "--frames", 1, "--no-motion-blur"),
    }
    # Still frames at the middles of SLICES equal slices of the shutter, SPP / SLICES samples each.
    rgb, var = 0.0, 0.0
    for k in range(SLICES):
        t = 0.5 + (k + 0.5) / SLICES
        a, v = _render(d, stage, f"slice{k}", 10 + k, "--spp", SPP // SLICES, "--frames", t, "--no-motion-blur")
        rgb, var = rgb + a / SLICES, var + v / SLICES ** 2
    out["average"] = (rgb, var)
    return out


def test_the_blurred_aggregate_differs_from_the_still_frame_beyond_noise(images):
    chi2, m = block_chi2(*images["blurred"], *images["still"])
    print(f"blurred vs still: chi2 {chi2:.1f} over {m} terms, limit {noise_limit(m):.1f}")
    assert m > 100 and chi2 > 4 * noise_limit(m)


def test_the_blurred_aggregate_is_the_average_of_still_frames_over_the_shutter(images):
    chi2, m = block_chi2(*images["blurred"], *images["average"])
    print(f"blurred vs the average of {SLICES} still frames: chi2 {chi2:.1f} over {m} terms, "
          f"limit {noise_limit(m):.1f}")
    assert m > 100 and chi2 < noise_limit(m)
    assert np.all(np.isfinite(images["blurred"][0]))
