"""bench/image_compare.cpp (granular-compare), the error metric of the benchmarks: with two
references of independent noise, the reference's own share of relMSE (the floor) is
measured, and relMSE − floor is the test image's own error against the truth."""
import json
import subprocess

import numpy as np
import pytest
from conftest import BUILD

import granular_core as core

COMPARE = BUILD / "bench" / "granular-compare"


def _exr(path, rgb):
    core.write_exr(str(path), core.Image(np.ascontiguousarray(rgb, dtype=np.float32), ["R", "G", "B"]))
    return str(path)


def _compare(*paths):
    r = subprocess.run([str(COMPARE), *paths], capture_output=True, text=True, check=True)
    return json.loads(r.stdout)


@pytest.mark.skipif(not COMPARE.exists(), reason="granular-compare not built")
def test_the_reference_noise_floor_is_measured_and_removed(tmp_path):
    rng = np.random.default_rng(7)
    h, w = 96, 128
    truth = rng.uniform(0.3, 1.0, (h, w, 3))  # six test σ above zero: no pixel negative
    sigma_ref, sigma_test = 0.02, 0.05  # each reference half, the test image
    a = truth + rng.normal(0, sigma_ref, truth.shape)
    b = truth + rng.normal(0, sigma_ref, truth.shape)
    x = truth + rng.normal(0, sigma_test, truth.shape)
    c = _compare(_exr(tmp_path / "x.exr", x), _exr(tmp_path / "a.exr", a), _exr(tmp_path / "b.exr", b))
    # The arithmetic: the reference is the halves' mean, the floor their half difference.
    a32, b32, x32 = (v.astype(np.float32).astype(np.float64) for v in (a, b, x))
    r = 0.5 * (a32 + b32)
    wgt = 1.0 / (r * r + 0.01)
    assert c["relmse"] == pytest.approx(np.mean((x32 - r) ** 2 * wgt), rel=1e-5)
    assert c["floor"] == pytest.approx(np.mean((0.5 * (a32 - b32)) ** 2 * wgt), rel=1e-5)
    # The meaning: relMSE − floor estimates the test image's own error against the truth,
    # within the standard error of their per-pixel difference.
    own = (x32 - truth) ** 2 * wgt
    gap = (x32 - r) ** 2 * wgt - (0.5 * (a32 - b32)) ** 2 * wgt - own
    assert abs((c["relmse"] - c["floor"]) - own.mean()) < 4 * gap.std() / np.sqrt(gap.size)
    # Without removing it the floor is there: the reference's variance (σ²/2 of a mean of
    # two halves), weighted, within 4 standard errors of its per-pixel mean.
    floor_terms = (0.5 * (a32 - b32)) ** 2 * wgt
    expected = np.mean(0.5 * sigma_ref ** 2 * wgt)
    assert abs(c["floor"] - expected) < 4 * floor_terms.std() / np.sqrt(floor_terms.size)
    # One reference: no floor to measure.
    assert _compare(tmp_path / "x.exr", tmp_path / "a.exr")["floor"] == 0
