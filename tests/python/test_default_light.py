"""A stage without any light: `granular render` lights it with the default white dome
(radiance 1) and says so; --no-default-light renders it black. The delegate's side is in
tests/hydra (same stage through usdrecord, and the granular:defaultLight setting)."""
import numpy as np

import granular_core as core
from conftest import ROOT, run_cli

UNLIT = ROOT / "tests" / "hydra" / "snowslab_unlit.usda"
OPTIONS = ["--width", "24", "--height", "16", "--spp", "2", "--camera", "/World/Camera"]


def _rgb(path):
    return np.asarray(core.read_image_rgb(str(path)).pixels, dtype=np.float64)[..., :3]


def test_a_stage_without_lights_gets_the_default_dome_and_a_warning(tmp_path, capsys):
    out = tmp_path / "lit.exr"
    rc, _, err = run_cli(["render", UNLIT, "-o", out, *OPTIONS], capsys)
    assert rc == 0, err
    warnings = [line for line in err.splitlines() if line.startswith("warning: the stage has no light")]
    assert len(warnings) == 1
    rgb = _rgb(out)
    assert np.isfinite(rgb).all() and rgb.mean() > 0.05  # white snow under a white sky

    dark = tmp_path / "dark.exr"
    rc, _, err = run_cli(["render", UNLIT, "-o", dark, "--no-default-light", *OPTIONS], capsys)
    assert rc == 0, err
    assert "no light" not in err
    assert (_rgb(dark) == 0).all()


def test_a_lit_stage_gets_no_default_light(tmp_path, capsys):
    rc, _, err = run_cli(["render", ROOT / "examples" / "snowslab.usda", "-o", tmp_path / "s.exr", *OPTIONS], capsys)
    assert rc == 0, err
    assert "no light" not in err
