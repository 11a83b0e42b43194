"""scripts/gallery.py (`make gallery`): every example rendered, a contact sheet of them."""
import importlib.util
import subprocess
import sys

import numpy as np
from conftest import EXAMPLES, ROOT

import granular_core as core


def _gallery_module():
    spec = importlib.util.spec_from_file_location("gallery", ROOT / "scripts" / "gallery.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_box_downsample_averages_blocks():
    g = _gallery_module()
    px = np.arange(4 * 6 * 1, dtype=np.float32).reshape(4, 6, 1)
    small = g.box_downsample(px, 2)
    assert small.shape == (2, 3, 1)
    assert small[0, 0, 0] == np.mean([0, 1, 6, 7])
    assert small[1, 2, 0] == np.mean([16, 17, 22, 23])


def test_gallery_renders_every_example_and_a_contact_sheet(tmp_path):
    from pathlib import Path
    venv_granular = Path(sys.executable).parent / "granular"  # the command of the venv running the tests
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "gallery.py"), "--width", "32", "--spp", "1", "--out",
                        str(tmp_path), "--granular", str(venv_granular)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    names = sorted(p.stem for p in EXAMPLES.glob("*.usda"))
    rows = [line for line in r.stdout.splitlines() if line.startswith("| ") and not line.startswith("| example")]
    assert [row.split(" | ")[0][2:] for row in rows] == names
    for name in names:
        stem = name + (".0001" if name == "animated" else "")
        assert (tmp_path / f"{stem}.png").stat().st_size > 0
    sheet = core.read_image_rgb(str(tmp_path / "contact_sheet.png"))
    # Three columns of 16-pixel-wide thumbnails (32 / 2) with 4-pixel gutters; two rows.
    assert sheet.width == 3 * 16 + 4 * 4
    assert sheet.height > 2 * 8
    assert np.isfinite(np.asarray(sheet.pixels)).all()
