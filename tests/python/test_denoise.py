"""`granular render --denoise`: Intel Open Image Denoise (pyoidn) guided by the albedo and
normal AOVs writes channels denoised.R/G/B beside the raw beauty, which stays as it was;
the albedo AOV is the first hit's reflectance; without pyoidn one warning and no denoising."""
import sys

import numpy as np
import pytest
from conftest import EXAMPLES, dome_card, run_cli

import granular_core as core


def _channels(path, names):
    im = core.read_exr(str(path))
    px = np.asarray(im.pixels, dtype=np.float64)
    ch = list(im.channels)
    return px[..., [ch.index(n) for n in names]]


def test_the_albedo_aov_is_the_first_hits_reflectance(tmp_path, capsys):
    out = tmp_path / "card.exr"
    rc, _, err = run_cli(["render", dome_card(tmp_path / "card.usda", (0.3, 0.5, 0.7)), "-o", out, "--width", 16, "--height", 12,
                          "--spp", 2], capsys)
    assert rc == 0, err
    albedo = _channels(out, ["albedo.R", "albedo.G", "albedo.B"])
    np.testing.assert_allclose(albedo.reshape(-1, 3), np.tile([0.3, 0.5, 0.7], (16 * 12, 1)), atol=1e-6)


def test_denoising_adds_channels_keeps_the_raw_beauty_and_lowers_the_error(tmp_path, capsys):
    pytest.importorskip("pyoidn")
    scene = str(EXAMPLES / "sugarcube.usda")
    size = ["--width", 64, "--height", 48, "--seed", 3]
    raw, den, ref = tmp_path / "raw.exr", tmp_path / "den.exr", tmp_path / "ref.exr"
    for out, extra in ((raw, ["--spp", 4]), (den, ["--spp", 4, "--denoise", "--png", tmp_path / "den.png"]),
                       (ref, ["--spp", 256])):
        rc, _, err = run_cli(["render", scene, "-o", out, *size, *extra, "--quiet"], capsys)
        assert rc == 0, err
    rgb = ["R", "G", "B"]
    # The raw beauty is untouched (same seed: bit for bit).
    np.testing.assert_array_equal(_channels(raw, rgb), _channels(den, rgb))
    reference = _channels(ref, rgb)
    denoised = _channels(den, ["denoised.R", "denoised.G", "denoised.B"])
    assert np.isfinite(denoised).all()

    def relmse(x):
        return float(np.mean((x - reference) ** 2 / (reference ** 2 + 1e-2)))
    # The reference's own noise (256 spp) is 64x below the raw image's: the denoised image
    # must be much nearer to it than the raw one is.
    assert relmse(denoised) < 0.5 * relmse(_channels(raw, rgb)), (relmse(denoised), relmse(_channels(raw, rgb)))
    assert (tmp_path / "den.png").exists()


def test_without_pyoidn_the_image_is_written_undenoised_with_one_warning(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "pyoidn", None)  # import pyoidn raises ImportError
    out = tmp_path / "o.exr"
    rc, _, err = run_cli(["render", dome_card(tmp_path / "card.usda", (0.3, 0.5, 0.7)), "-o", out, "--width", 16, "--height", 12,
                          "--spp", 1, "--denoise", "--quiet"], capsys)
    assert rc == 0, err
    lines = [x for x in err.splitlines() if x.startswith("warning:")]
    assert len(lines) == 1 and "pyoidn" in lines[0], err
    assert "denoised.R" not in core.read_exr(str(out)).channels
