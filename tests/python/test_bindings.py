"""The granular_core module: errors, GIL release, progress and cancellation, images."""
import threading
import time

import numpy as np
import pytest
from conftest import small_scene

import granular_core as core
from granular.usd_reader import read_stage


def test_input_error_carries_object_attribute_and_detail():
    with pytest.raises(core.InputError) as e:
        core.triangulate(np.zeros((3, 3)), [3], [0, 1, 7], "/World/M")
    assert isinstance(e.value, ValueError)
    assert (e.value.object, e.value.attribute) == ("/World/M", "faceVertexIndices")
    assert e.value.detail == "index 2 = 7 is out of range [0, 3)"
    assert str(e.value) == "/World/M.faceVertexIndices: index 2 = 7 is out of range [0, 3)"


def test_bad_arrays_are_errors_not_crashes():
    with pytest.raises(ValueError):
        core.TriangleMesh(np.zeros((4, 2)), [0, 1, 2])
    with pytest.raises(core.InputError):
        core.validate_closed(core.TriangleMesh(np.zeros((3, 3)), [0, 1, 5]), "m")
    with pytest.raises(core.InputError):  # negative and huge indices
        core.validate_mesh(core.TriangleMesh(np.zeros((3, 3)), [0, -1, 2**40]), "m")
    with pytest.raises(core.InputError):
        core.triangulate(np.zeros((3, 3)), [2**40], [0, 1, 2], "m")
    with pytest.raises(TypeError):
        core.make_box((0, 0), (1, 1, 1))
    d = core.SceneDesc()
    d.settings.width = 0
    with pytest.raises(core.InputError, match="render.width"):
        core.Scene.build(d)


def _small(tmp_path, width=64, spp=4):
    scene = read_stage(str(small_scene(tmp_path / "s.usda")), width=width)
    scene.desc.settings.spp = spp
    return core.Scene.build(scene.desc)


def test_render_releases_the_gil_and_reports_progress(tmp_path):
    built = _small(tmp_path, width=96, spp=6)
    calls = []
    ticks = []
    stop = threading.Event()

    def ticker():  # Python code that can only run while render() has released the GIL
        while not stop.is_set():
            ticks.append(time.monotonic())
            time.sleep(0.001)

    t = threading.Thread(target=ticker)
    t.start()
    r = core.Renderer(built)
    start = time.monotonic()
    try:
        assert r.render(2, lambda done, target, seconds: calls.append((done, target)))
    finally:
        stop.set()
        t.join()
    end = time.monotonic()
    assert calls == [(2, 6), (4, 6), (6, 6)]
    assert r.samples_per_pixel == 6
    during = [x for x in ticks if start < x < end]
    assert len(during) >= 5, "the ticker thread did not run during the render"


def test_an_exception_in_progress_cancels_and_propagates(tmp_path):
    r = core.Renderer(_small(tmp_path, spp=8))

    def progress(done, target, seconds):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        r.render(1, progress)
    assert r.samples_per_pixel == 1


def test_images_are_written_and_read_back(tmp_path):
    r = core.Renderer(_small(tmp_path, width=32, spp=1))
    r.render()
    img = r.image()
    assert img.channels == ["R", "G", "B", "A", "Z", "N.X", "N.Y", "N.Z"]
    core.write_exr(str(tmp_path / "a.exr"), img)
    back = core.read_image_rgb(str(tmp_path / "a.exr"))
    assert np.allclose(back.pixels.reshape(-1, 3), img.pixels[..., :3].reshape(-1, 3), atol=1e-6)
    with pytest.raises(core.InputError):
        core.write_image(str(tmp_path / "a.tiff"), img)
    with pytest.raises(RuntimeError):
        core.write_exr(str(tmp_path / "missing" / "a.exr"), img)
    assert not (tmp_path / "missing").exists()
