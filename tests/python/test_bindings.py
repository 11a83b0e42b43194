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
        assert r.render(1, lambda done, target, seconds: calls.append((done, target, seconds)), 0.005)
    finally:
        stop.set()
        t.join()
    end = time.monotonic()
    assert r.samples_per_pixel == 6
    # Called during the render with growing (fractional) sample counts, and at the end.
    assert len(calls) >= 2 and calls[-1][:2] == (6.0, 6)
    done = [c[0] for c in calls]
    assert done == sorted(done) and all(0 <= d <= 6 for d in done)
    assert all(c[1] == 6 for c in calls)
    during = [x for x in ticks if start < x < end]
    assert len(during) >= 5, "the ticker thread did not run during the render"


def test_an_exception_in_progress_cancels_and_propagates(tmp_path):
    r = core.Renderer(_small(tmp_path, width=96, spp=64))

    def progress(done, target, seconds):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        r.render(1, progress, 0.001)
    assert r.samples_per_pixel < 64


def test_images_are_written_and_read_back(tmp_path):
    r = core.Renderer(_small(tmp_path, width=32, spp=1))
    r.render()
    img = r.image()
    assert img.channels[:8] == ["R", "G", "B", "A", "Z", "N.X", "N.Y", "N.Z"]
    assert {"ept.R", "vpt.R", "da.R", "ppt.R"} <= set(img.channels)
    core.write_exr(str(tmp_path / "a.exr"), img)
    back = core.read_image_rgb(str(tmp_path / "a.exr"))
    assert np.allclose(back.pixels.reshape(-1, 3), img.pixels[..., :3].reshape(-1, 3), atol=1e-6)
    with pytest.raises(core.InputError):
        core.write_image(str(tmp_path / "a.tiff"), img)
    with pytest.raises(RuntimeError):
        core.write_exr(str(tmp_path / "missing" / "a.exr"), img)
    assert not (tmp_path / "missing").exists()


def test_media_follow_the_tt_relations(tmp_path):
    built = _small(tmp_path)
    (m,) = built.media()
    sigma_t = np.array(m["sigma_t"])
    assert (sigma_t > 0).all()
    # lambda_t = 1 / sigma_t, the mean free path; sigma_b = 3f / (4R(1 - f)) (Dixmier 1978),
    # the inverse mean free path between bounding spheres of radius R at packing rate f.
    assert np.array(m["mean_free_path"]) == pytest.approx(1 / sigma_t, rel=1e-5)
    R, f = m["grain_radius"], m["packing_rate"]
    assert m["sigma_b"] == pytest.approx(3 / (4 * R) * f / (1 - f), rel=1e-5)
    assert 0 < m["beta"] <= 1
    assert all(0 <= a <= 1 for a in m["albedo"])


@pytest.mark.parametrize("technique,lod", [("ept", 0), ("ept+vpt", 0), ("hybrid", 0), ("hybrid", 4)])
def test_every_technique_renders(tmp_path, technique, lod):
    scene = read_stage(str(small_scene(tmp_path / "s.usda")), width=32)
    s = scene.desc.settings
    s.spp, s.technique, s.roulette, s.lod = 2, core.technique_from_name(technique, "test"), 0.5, lod
    r = core.Renderer(core.Scene.build(scene.desc))
    assert r.render()
    assert np.isfinite(r.image().pixels[..., :3]).all()
    assert 0 <= r.shortcut_fraction <= 1 and (lod > 0 or r.shortcut_fraction == 0)
    # Every camera path counted, none ended by a numerical failure.
    assert r.paths == 32 * s.height * 2 and r.lost_paths == 0
    with pytest.raises(core.InputError, match="technique"):
        core.technique_from_name("dpt", "test")


def test_set_view_renders_as_a_fresh_build(tmp_path):
    scene = read_stage(str(small_scene(tmp_path / "s.usda")), width=32)
    scene.desc.settings.spp = 2
    built = core.Scene.build(scene.desc)
    old = core.Renderer(built)
    desc = scene.desc
    cam, s = desc.camera, desc.settings
    cam.focal_length *= 1.5
    s.width, s.height, s.lod = 24, 16, 0.0
    built.set_view(cam, s)  # cam and s are desc's own fields (pybind11 references)
    moved = core.Renderer(built)
    fresh = core.Renderer(core.Scene.build(desc))
    assert moved.render() and fresh.render()
    a, b = moved.image().pixels, fresh.image().pixels
    assert a.shape[:2] == (16, 24)
    assert np.array_equal(a[..., :3], b[..., :3])
    with pytest.raises(core.InputError, match="resolution"):  # made before the change
        old.render()
    s.technique = core.technique_from_name("ept", "test")
    with pytest.raises(core.InputError, match="technique"):
        built.set_view(cam, s)


def test_assembling_prims_from_python_with_a_lookup():
    def prim(path, mesh, apis):
        p = core.MeshPrim()
        p.path, p.mesh, p.api_schemas = path, mesh, apis
        return p

    def value(type_name, numbers=(), strings=()):
        v = core.PrimvarValue()
        v.type_name, v.numbers, v.strings = type_name, list(numbers), list(strings)
        v.is_array, v.is_string = type_name.endswith("[]"), bool(strings)
        return v

    box = prim("/W/Box", core.make_box((0, 0, 0), (1, 1, 1)), ["GranularAggregateAPI"])
    box.granular = {"prototypes": value("string[]", strings=["../G"]), "seed": value("int", [4])}
    box.instances = [[[1, 0, 0, 2], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]]
    grain = prim("/W/G", core.make_icosphere(1), ["GranularGrainAPI"])
    grain.granular = {"ior": value("float", [1.4])}
    asked = []

    def lookup(path):
        asked.append(path)
        return grain if path == "/W/G" else None

    desc = core.SceneDesc()
    core.assemble_granular_scene([box], desc, lookup)
    assert asked == ["/W/G"]
    (a,) = desc.aggregates
    assert (a.name, a.seed, a.grain_radius, a.xf[0][3]) == ("/W/Box", 4, pytest.approx(0.01), 2.0)
    assert [p.name for p in a.prototypes] == ["/W/G"] and desc.materials[a.prototypes[0].material].ior == pytest.approx(1.4)
    assert desc.meshes == []

    # No such prim, and an error raised by the lookup itself, which passes through unchanged.
    with pytest.raises(core.InputError, match=r'^/W/Box.primvars:granular:prototypes: prototype "../G" \(/W/G\) does not exist$'):
        core.assemble_granular_scene([box], core.SceneDesc(), lambda path: None)

    def broken(path):
        raise KeyError(path)

    with pytest.raises(KeyError):
        core.assemble_granular_scene([box], core.SceneDesc(), broken)
