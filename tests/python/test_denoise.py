"""`granular render --denoise`: core's Intel Open Image Denoise (core/denoise.h) guided by the
albedo and normal AOVs writes channels denoised.R/G/B beside the raw beauty, which stays as it
was; the albedo AOV is the first hit's reflectance; without the denoiser one warning and no
denoising."""
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
    if not core.denoiser_available():
        pytest.skip(core.denoiser_unavailable_reason())
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


def test_without_the_denoiser_the_image_is_written_undenoised_with_one_warning(tmp_path, capsys, monkeypatch):
    # As a build without Intel Open Image Denoise answers.
    monkeypatch.setattr(core, "denoiser_available", lambda: False)
    monkeypatch.setattr(core, "denoiser_unavailable_reason", lambda: "this build has no Intel Open Image Denoise")
    out = tmp_path / "o.exr"
    rc, _, err = run_cli(["render", dome_card(tmp_path / "card.usda", (0.3, 0.5, 0.7)), "-o", out, "--width", 16, "--height", 12,
                          "--spp", 1, "--denoise", "--quiet"], capsys)
    assert rc == 0, err
    lines = [x for x in err.splitlines() if x.startswith("warning:")]
    assert len(lines) == 1 and "Open Image Denoise" in lines[0] and "undenoised" in lines[0], err
    assert "denoised.R" not in core.read_exr(str(out)).channels


def test_the_core_denoiser_refuses_mismatched_or_non_finite_input():
    color = np.ones((4, 5, 3), np.float32)
    with pytest.raises(core.InputError, match="denoise.albedo"):
        core.denoise(color, np.ones((4, 4, 3), np.float32), color)
    bad = color.copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(core.InputError, match=r"denoise.color: not finite at pixel \(2, 1\)"):
        core.denoise(bad, color, color)
