"""Every bundled example reads, builds and renders (small, 1 spp) to finite pixels in
which its aggregates are visible; the demo command writes EXR and PNG."""
import numpy as np
import pytest
from conftest import EXAMPLES, run_script

import granular_core as core
from granular.usd_reader import read_stage, validate

USD_EXAMPLES = sorted(p.name for p in EXAMPLES.glob("*.usda"))


def test_the_ten_examples_are_there():
    assert USD_EXAMPLES == ["animated.usda", "frosted.usda", "macro.usda", "mixture.usda", "sandcastle.usda",
                            "sandcastle_paper.usda", "snowslab.usda", "sugarcube.usda", "sugarcube_neon.usda",
                            "sugarcube_spot.usda"]


@pytest.mark.parametrize("name", USD_EXAMPLES)
def test_example_renders_without_nan(name):
    scene = read_stage(str(EXAMPLES / name), width=48)
    validate(scene)
    assert scene.desc.aggregates, "every example has an aggregate"
    assert scene.warnings == []
    s = scene.desc.settings
    s.spp = 1
    built = core.Scene.build(scene.desc)
    for info in built.aggregates:
        assert info["approx_grains"] > 1000
    # No sun measurement where it could add nothing: the dome's choice the most visits
    # already (the paper castle's towers; its beach, at fewer, is measured).
    most = [sw for sw in built.switching if sw["measured"] and sw["chosen"] == sw["candidates"][-1]]
    assert all("sun" not in sw for sw in most)
    if name == "sandcastle_paper.usda":
        assert most and "sun" in built.switching[-1]
    r = core.Renderer(built)
    assert r.render(1)
    px = r.image().pixels
    assert px.shape[:2] == (s.height, 48)
    rgb = px[..., :3]
    assert np.isfinite(rgb).all() and (rgb >= 0).all()
    # The scene is lit and something is hit (the aggregate sits in the frame centre).
    assert rgb.mean() > 0.01
    cy, cx = s.height // 2, 24
    assert px[cy - 2:cy + 3, cx - 2:cx + 3, 3].min() > 0


def test_render_command_writes_exr_and_png(tmp_path):
    exr, png = tmp_path / "c.exr", tmp_path / "c.png"
    r = run_script(["render", EXAMPLES / "sandcastle.usda", "-o", exr, "--png", png, "--width", 40, "--spp", 1],
                   timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and "wrote" in r.stderr
    assert exr.stat().st_size > 0 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = core.read_image_rgb(str(exr))
    assert (img.width, img.height) == (40, 27)  # 480x320 settings: --width alone keeps the aspect
    assert np.isfinite(img.pixels).all()


def test_info_reports_grains_tiles_and_transport(capsys):
    import json

    from granular.cli import main
    assert main(["info", str(EXAMPLES / "mixture.usda"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    (heap,) = report["aggregates"]
    assert heap["prim"] == "/World/Heap"
    assert heap["prototypes"] == ["/World/Grains/Red", "/World/Grains/Green", "/World/Grains/White",
                                  "/World/Grains/Pepper"]
    assert heap["weights"] == pytest.approx([0.15, 0.15, 0.45, 0.25])
    assert heap["sizes"] == pytest.approx([1.4, 1.4, 1.0, 0.6]) and heap["size_spread"] == pytest.approx(0.15)
    assert heap["max_grain_radius"] == pytest.approx(0.0015 * 1.4 * 1.15, rel=0.02)
    assert heap["grains"] > 10000
    t = heap["tiles"]
    assert t["cells"] >= t["inside"] + t["partial"] and t["partial"] > 0
    assert 0 < heap["tt"]["beta"] <= 1
    assert heap["mean_free_path"] == pytest.approx([1 / s for s in heap["rte"]["sigma_t"]], rel=1e-5)
    # What carries this aggregate's low orders, as the renderer measures it (core/switching.h).
    scene = read_stage(str(EXAMPLES / "mixture.usda"), width=32)
    s = scene.desc.settings
    s.technique = core.Technique.Hybrid
    scene.desc.settings = s
    built = core.Scene.build(scene.desc).switching[0]
    assert heap["switching"]["measured"] and heap["switching"]["proxy_visits"] == built["proxy_visits"] > 0
    assert main(["info", str(EXAMPLES / "mixture.usda")]) == 0
    text = capsys.readouterr().out
    for word in ("/World/Heap", "grains", "tiles", "inside", "partial", "TT", "RTE", "mean free path", "sizes",
                 f"proxies for {built['proxy_visits']} visits", "measured: the medium's bias"):
        assert word in text


def test_examples_are_what_make_examples_writes(tmp_path):
    """The .usda files are generated: examples/make_examples.py is their source."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("make_examples", EXAMPLES / "make_examples.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["make_examples.py", str(tmp_path)]) == 0
    for name in USD_EXAMPLES:
        assert (tmp_path / name).read_text() == (EXAMPLES / name).read_text(), \
            f"examples/{name} differs from what make_examples.py writes: rerun it"
