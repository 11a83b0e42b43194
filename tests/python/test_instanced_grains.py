"""Explicit grains from a PointInstancer (GranularInstancedAggregateAPI): the generated heap
read through usd-core into core's description, `granular info` reporting it, `granular
render` rendering its grains, and bad instancer data named prim.attribute with exit
status 2."""
import json
import re
import sys

import numpy as np
import pytest
from conftest import EXAMPLES, add_mesh, dome_world, run_cli
from pxr import Gf, Usd, UsdGeom, Vt

import granular_core as core
from granular import schema, usd_reader

sys.path.insert(0, str(EXAMPLES))
import make_grain_heap  # noqa: E402

HEAP = "/World/Heap"
SAND = "/World/Sand"


@pytest.fixture(scope="module")
def heap(tmp_path_factory):
    path = tmp_path_factory.mktemp("heap") / "heap.usdc"
    count = make_grain_heap.write(str(path), grains=3000, frames=2, seed=3)
    return str(path), count


def _read(path, time=None):
    stage = usd_reader.open_stage(path)
    scene = usd_reader.StageScene(path, stage, usd_reader.as_time_code(time, stage))
    return scene, usd_reader.read_instanced_grains(scene, stage.GetPrimAtPath(HEAP))


def test_generator_is_deterministic_and_non_overlapping(heap, tmp_path):
    path, count = heap
    assert 2000 < count < 4000
    again = tmp_path / "again.usdc"
    assert make_grain_heap.write(str(again), grains=3000, frames=2, seed=3) == count
    a, b = Usd.Stage.Open(path), Usd.Stage.Open(str(again))
    for name in ("positions", "scales", "protoIndices", "orientations", "velocities"):
        for t in (1, 2):
            va = np.asarray(a.GetPrimAtPath(HEAP).GetAttribute(name).Get(t))
            vb = np.asarray(b.GetPrimAtPath(HEAP).GetAttribute(name).Get(t))
            assert np.array_equal(va, vb), name
    # The grid's overlap check passes (build() raises otherwise) at both frames.
    for t in (1, 2):
        core.InstancedGrains().build(_read(path, t)[1])


def test_a_still_heap_generated_in_slabs_is_valid(tmp_path):
    """make_grain_heap.py --no-motion --slabs (the 10^8-grain stage of bench/README.md): one
    frame without motion, deterministic, its grains apart (the grid's overlap check)."""
    paths = [tmp_path / "a.usdc", tmp_path / "b.usdc"]
    counts = [make_grain_heap.write(str(p), grains=3000, frames=1, seed=5, motion=False, slabs=True) for p in paths]
    assert counts[0] == counts[1] and 2000 < counts[0] < 4000
    stages = [Usd.Stage.Open(str(p)) for p in paths]
    a, b = (s.GetPrimAtPath(HEAP) for s in stages)
    for name in ("positions", "scales", "protoIndices", "orientations"):
        assert np.array_equal(np.asarray(a.GetAttribute(name).Get()), np.asarray(b.GetAttribute(name).Get())), name
    assert not a.GetAttribute("velocities").HasAuthoredValue()
    _, desc = _read(str(paths[0]))
    assert desc.num_grains == counts[0] and not desc.has_motion
    core.InstancedGrains().build(desc)  # raises on overlapping grains


def test_an_ice_slab_is_flat_wide_and_clear(tmp_path):
    """make_grain_heap.py --material ice --slab-depth D (bench/README.md, DA in simulated
    grains' media): a square slab D grid cells deep, its grains apart, of ice's IOR and
    absorption per radius (granular.materials.ICE at the generator's grain size)."""
    from granular.materials import ICE
    path = tmp_path / "slab.usdc"
    count = make_grain_heap.write(str(path), grains=3000, frames=1, seed=2, motion=False, material=ICE,
                                  slab_depth=5)
    side = round((3000 / 5) ** 0.5)
    assert count == side * side * 5
    stage = Usd.Stage.Open(str(path))
    pos = np.asarray(stage.GetPrimAtPath(HEAP).GetAttribute("positions").Get())
    a, jitter = make_grain_heap.SPACING * make_grain_heap.RADIUS, make_grain_heap.JITTER * make_grain_heap.RADIUS
    assert pos[:, 1].min() >= 0.5 * a - jitter - 1e-6 and pos[:, 1].max() <= 4.5 * a + jitter + 1e-6
    assert np.ptp(pos[:, 0]) == pytest.approx((side - 1) * a, abs=2 * jitter + 1e-6)
    round_ = stage.GetPrimAtPath(HEAP + "/Prototypes/Round")
    assert round_.GetAttribute("primvars:granular:ior").Get() == pytest.approx(ICE.ior)
    expected = [x / make_grain_heap.RADIUS for x in ICE.absorption_per_radius(make_grain_heap.RADIUS)]
    assert list(round_.GetAttribute("primvars:granular:absorption").Get()) == pytest.approx(expected, rel=1e-6)
    _, desc = _read(str(path))
    core.InstancedGrains().build(desc)  # raises on overlapping grains


def test_a_graded_slab_is_four_times_denser_at_its_top(tmp_path):
    """make_grain_heap.py --slab-depth D --gradient 4: the slab's grains thinned with depth,
    each layer keeping 1/4 + 3/4 y/top of its cells (binomial counts, within 4 s.e.), the
    same slab's columns and camera as without the gradient, and deterministic."""
    side, depth = 40, 8
    path = tmp_path / "graded.usdc"
    count = make_grain_heap.write(str(path), grains=side * side * depth, frames=1, seed=3, motion=False,
                                  slab_depth=depth, gradient=4.0)
    again = make_grain_heap.write(str(tmp_path / "again.usdc"), grains=side * side * depth, frames=1, seed=3,
                                  motion=False, slab_depth=depth, gradient=4.0)
    assert count == again
    stage = Usd.Stage.Open(str(path))
    pos = np.asarray(stage.GetPrimAtPath(HEAP).GetAttribute("positions").Get())
    assert len(pos) == count
    a = make_grain_heap.SPACING * make_grain_heap.RADIUS
    layer = np.clip(np.floor(pos[:, 1] / a).astype(int), 0, depth - 1)
    for k in range(depth):
        # A layer's centres lie at (k + ½) a ± the jitter, and the keep chance is linear in
        # y: the layer keeps on average its centre's chance.
        p = 0.25 + 0.75 * (k + 0.5) / depth
        n = side * side
        assert abs(np.count_nonzero(layer == k) - n * p) <= 4 * np.sqrt(n * p * (1 - p)), k
    plain = tmp_path / "plain.usdc"
    make_grain_heap.write(str(plain), grains=side * side * depth, frames=1, seed=3, motion=False, slab_depth=depth)
    stages = [Usd.Stage.Open(str(x)) for x in (path, plain)]
    views = [s.GetPrimAtPath("/World/Camera").GetAttribute("xformOp:transform").Get() for s in stages]
    assert views[0] == views[1]
    _, desc = _read(str(path))
    core.InstancedGrains().build(desc)  # raises on overlapping grains


def test_heap_reads_into_core(heap):
    path, count = heap
    scene, desc = _read(path)
    assert desc.name == HEAP
    assert desc.num_grains == count
    assert [p.name for p in desc.prototypes] == [HEAP + "/Prototypes/Round", HEAP + "/Prototypes/Rock"]
    # Each prototype's GranularGrainAPI material, as for an aggregate's prototypes.
    assert [scene.desc.materials[p.material].ior for p in desc.prototypes] == pytest.approx([1.55, 1.55])
    assert desc.has_motion
    stage = Usd.Stage.Open(path)
    authored = np.asarray(stage.GetPrimAtPath(HEAP).GetAttribute("positions").Get(1))
    assert np.array_equal(desc.positions, authored)
    # Uniform scales read as one size each.
    assert np.array_equal(desc.scales, np.asarray(stage.GetPrimAtPath(HEAP).GetAttribute("scales").Get(1))[:, 0])
    # The second frame's positions, as authored there.
    _, later = _read(path, 2)
    assert np.array_equal(later.positions, np.asarray(stage.GetPrimAtPath(HEAP).GetAttribute("positions").Get(2)))
    assert not np.array_equal(later.positions, desc.positions)


def test_grid_finds_the_heap_from_above(heap):
    path, _ = heap
    _, desc = _read(path)
    grid = core.InstancedGrains()
    grid.build(desc)
    st = grid.stats
    assert st["grains"] == desc.num_grains
    assert st["bytes_per_grain"] <= 32
    # Straight down onto the apex: the first grain met is near the top of the cone.
    top = float(np.max(desc.positions[:, 1]))
    hit = grid.intersect((0.0, top + 1.0, 0.0), (0.0, -1.0, 0.0))
    assert hit is not None
    assert 1.0 - 0.03 < hit["t"] < 1.0 + 0.03
    assert hit["normal"][1] > 0
    assert grid.occluded((0.0, top + 1.0, 0.0), (0.0, -1.0, 0.0))
    assert grid.intersect((0.0, top + 1.0, 0.0), (0.0, 1.0, 0.0)) is None


def test_info_reports_explicit_grains(heap, capsys):
    path, count = heap
    rc, out, err = run_cli(["info", path, "--json"], capsys)
    assert rc == 0, err
    r = json.loads(out)
    assert r["aggregates"] == []
    (e,) = r["explicit_grains"]
    assert e["prim"] == HEAP and e["grains"] == count and e["rendered"] is True
    assert 0 < e["bytes_per_grain"] <= 32 and e["grid_bytes"] > 0 and e["build_seconds"] >= 0
    rc, out, err = run_cli(["info", path], capsys)
    assert rc == 0, err
    assert f"grains        {count}" in out and "traced grain by grain" in out


def test_render_draws_the_grains(heap, tmp_path, capsys):
    """The heap's grains are in the description (not its prototypes as meshes) and in the
    image: the primId AOV shows the instancer where the heap stands, the ground elsewhere."""
    path, count = heap
    scene = usd_reader.read_stage(path)
    assert [m.name for m in scene.desc.meshes] == ["/World/Ground"]
    assert scene.desc.num_instanced_grains == 1
    assert not any("explicit grains" in w for w in scene.warnings)
    out = tmp_path / "h.exr"
    rc, _, err = run_cli(["render", path, "-o", out, "--width", 32, "--height", 24, "--spp", 1], capsys)
    assert rc == 0, err
    img = core.read_exr(str(out))
    px, ch = np.asarray(img.pixels), list(img.channels)
    prim_id = px[..., ch.index("primId")]
    heap_id = 1  # traversal order: the ground (0), then the instancer
    assert (prim_id == heap_id).sum() > 20
    assert (prim_id == 0).sum() > 20
    assert np.isfinite(px[..., ch.index("R")]).all()


def test_the_generated_sun_lights_the_heap(tmp_path, capsys):
    """The generator's sun is a normalised distant light: its intensity is its irradiance
    whatever its angle. Without `normalize` a 0.53° sun of intensity 3 lit the ground by
    2·10^-4, against the sky's 0.94: the heap was lit by the sky alone. Now the sunlit ground
    (ρ/π · 3 sin 50° = 0.33 in red) outshines its sky light (ρ · 0.3 = 0.135 at most) about
    three times; --sun 0 leaves the sky alone."""
    paths = {}
    for sun in (3.0, 0.0):
        paths[sun] = str(tmp_path / f"heap_sun{sun:g}.usdc")
        make_grain_heap.write(paths[sun], grains=300, frames=1, seed=2, motion=False, sun=sun)
    light = next(l for l in usd_reader.read_stage(paths[3.0]).desc.lights if l.name == "/World/Sun")
    assert light.normalize and light.intensity == pytest.approx(3.0) and light.angle == pytest.approx(0.53)
    ground, var = {}, {}
    for sun, path in paths.items():
        out = tmp_path / f"g{sun:g}.exr"
        rc, _, err = run_cli(["render", path, "-o", out, "--width", 32, "--height", 24, "--spp", 16], capsys)
        assert rc == 0, err
        img = core.read_exr(str(out))
        px, ch = np.asarray(img.pixels, dtype=np.float64), list(img.channels)
        on_ground = px[..., ch.index("primId")] == 0
        ground[sun] = px[..., [ch.index(c) for c in "RGB"]][on_ground].mean(axis=0)
        var[sun] = px[..., [ch.index("variance." + c) for c in "RGB"]][on_ground].sum(axis=0) / on_ground.sum() ** 2
    ratio = ground[3.0] / ground[0.0]
    assert np.all((ratio > 2.0) & (ratio < 5.0)), ratio
    # What the sun adds is at most what it gives open ground (ρ/π · 3 sin 50°, the ground's
    # albedo ρ its displayColor), less where the heap shadows it (a small part of the view).
    sunlit = np.array([0.45, 0.4, 0.35]) / np.pi * 3.0 * np.sin(np.radians(50.0))
    added, se = ground[3.0] - ground[0.0], np.sqrt(var[3.0] + var[0.0])
    assert np.all(added < sunlit + 4 * se) and np.all(added > 0.5 * sunlit), (added, sunlit, se)


# ---- a small instancer to break -----------------------------------------------------------

def _instancer(path, positions=((0, 0, 0), (3, 0, 0)), indices=(0, 0), scales=None, api=True, proto="Mesh"):
    stage = dome_world(path)
    pi = UsdGeom.PointInstancer.Define(stage, SAND)
    if api:
        schema.apply_instanced_aggregate(pi)
    if proto == "Mesh":
        grain = add_mesh(stage, SAND + "/Protos/Round", core.make_icosphere(1))
        schema.apply_grain(grain, ior=1.31, invisible=False)
        target = grain.GetPath()
    else:
        target = UsdGeom.Xform.Define(stage, SAND + "/Protos/Round").GetPath()
    pi.CreatePrototypesRel().SetTargets([target])
    pi.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in positions]))
    pi.CreateProtoIndicesAttr(Vt.IntArray(list(indices)))
    if scales is not None:
        pi.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(*s) for s in scales]))
    stage.Save()
    return str(path)


def test_render_says_what_carries_the_heap_after_its_first_grain(heap, tmp_path, capsys):
    """Absorbing quartz: the rule on the heap's medium keeps low orders (core:
    Scene::explicitBouncesFor), carried by proxies at the grains' positions (kProxyOrders
    bounces a visit), then the heap's heterogeneous medium, said in core's words
    (Scene::instancedLowOrdersText); with proxies off, explicit grains carry the bounces."""
    path, _ = heap
    desc = usd_reader.read_stage(path).desc
    settings = desc.settings
    settings.da_instanced = True
    desc.settings = settings
    built = core.Scene.build(desc)
    info = built.instanced_grains[0]
    k = info["proxy_visits"]
    assert info["proxies"] and k > 0, info
    assert info["low_orders"] == f"proxies for {k} visits, then its heterogeneous medium (the rule for {2 * k} bounces)"
    args = ["render", path, "-o", tmp_path / "h.exr", "--width", 16, "--height", 12, "--spp", 1]
    for proxies, words in (("auto", info["low_orders"]),
                           ("off", f"explicit grains to bounce {2 * k}, then its heterogeneous medium")):
        rc, out, err = run_cli(args + ["--proxies", proxies], capsys)
        assert rc == 0, err
        line = next(l for l in (out + err).splitlines() if HEAP in l and "after the first grain" in l)
        assert line.endswith(f"after the first grain: {words}"), (proxies, line)


def test_render_says_whether_da_takes_the_heaps_deep_paths(heap, tmp_path, capsys):
    """The heap's medium gets DA where it is homogeneous (core: Scene::instancedDiffusionText),
    the transport line says the share of paths DA took; without --instanced-da (RenderSettings::
    daInstanced, off by default) VPT goes to the end there and the line says so; EPT has no
    medium to say it of."""
    path, _ = heap
    desc = usd_reader.read_stage(path).desc
    settings = desc.settings
    settings.da_instanced = True  # off by default
    desc.settings = settings
    words = core.Scene.build(desc).instanced_grains[0]["diffusion"]
    assert words == "DA where the medium is deep and its packing uniform within ±10% over the diffusion's reach"
    args = ["render", path, "-o", tmp_path / "h.exr", "--width", 16, "--height", 12, "--spp", 1]
    for extra, expected in ((["--instanced-da"], words), ([], "no DA (da_instanced off)")):
        rc, out, err = run_cli(args + extra, capsys)
        assert rc == 0, err
        lines = (out + err).splitlines()
        assert f"  {HEAP}: {expected}" in lines, lines
        transports = next(l for l in lines if "mean luminance by transport" in l)
        assert re.search(r"DA [\d.e+-]+ \([\d.]+% of paths\)", transports), transports
    rc, out, err = run_cli(args + ["--technique", "ept"], capsys)
    assert rc == 0, err
    assert not any(l.startswith(f"  {HEAP}: DA") or "no DA" in l for l in (out + err).splitlines())


def test_a_valid_instancer_reports(tmp_path, capsys):
    rc, out, err = run_cli(["info", _instancer(tmp_path / "ok.usda")], capsys)
    assert rc == 0, err
    assert "grains        2" in out


@pytest.mark.parametrize("kwargs, message", [
    ({"indices": (0, 1)}, f"error: {SAND}.protoIndices: instance 1 has 1, not the index of one of its 1 prototypes"),
    ({"positions": ((0, 0, 0),)}, f"error: {SAND}.positions: has 1 values but protoIndices has 2 (one per instance)"),
    ({"positions": ((0, 0, 0), (float("nan"), 0, 0))}, f"error: {SAND}.positions: instance 1 is at (nan, 0, 0)"),
    ({"scales": ((1, 1, 1), (1, 2, 1))}, f"error: {SAND}.scales: instance 1 has non-uniform scale (1, 2, 1)"),
    ({"scales": ((1, 1, 1), (0, 0, 0))}, f"error: {SAND}.scales: instance 1 has scale (0, 0, 0)"),
    ({"positions": ((0, 0, 0), (1.5, 0, 0))}, f"error: {SAND}.positions: instances 0 and 1 overlap"),
    ({"proto": "Xform"}, f"error: {SAND}.prototypes: target {SAND}/Protos/Round is a Xform, not a Mesh"),
])
def test_bad_instancer_data_is_named(tmp_path, capsys, kwargs, message):
    rc, out, err = run_cli(["info", _instancer(tmp_path / "bad.usda", **kwargs)], capsys)
    assert rc == 2, err
    assert err.startswith(message), err


def test_grain_prototypes_without_the_api_are_explicit_grains(tmp_path, capsys):
    """Every prototype a grain (GranularGrainAPI): simulated grains, not drawn as meshes at
    every instance."""
    path = _instancer(tmp_path / "noapi.usda", api=False)
    scene = usd_reader.read_stage(path)
    assert [str(p.GetPath()) for p in scene.explicit_grains] == [SAND]
    assert scene.desc.num_instanced_grains == 1
    assert list(scene.desc.meshes) == []


def test_aggregate_api_on_an_instancer_points_to_the_sibling(tmp_path, capsys):
    path = _instancer(tmp_path / "wrong.usda", api=False)
    stage = Usd.Stage.Open(path)
    stage.GetPrimAtPath(SAND).ApplyAPI(schema.AGGREGATE_API)
    stage.Save()
    rc, out, err = run_cli(["info", path], capsys)
    assert rc == 2
    assert err.startswith(f"error: {SAND}: GranularAggregateAPI applies to a Mesh, not a PointInstancer "
                          f"(explicit grains from a simulation: GranularInstancedAggregateAPI)"), err


# ---- motion blur ---------------------------------------------------------------------------

def _moving(path, shutter=(-0.5, 0.5), fps=24.0):
    """Two grains moving apart along x at 48 units per second (2 units per frame) under a
    camera whose shutter is open over `shutter` (time codes about the frame)."""
    p = _instancer(path, positions=((-3, 0, 0), (3, 0, 0)))
    stage = Usd.Stage.Open(p)
    stage.SetTimeCodesPerSecond(fps)
    UsdGeom.PointInstancer(stage.GetPrimAtPath(SAND)).CreateVelocitiesAttr(
        Vt.Vec3fArray([Gf.Vec3f(-48, 0, 0), Gf.Vec3f(48, 0, 0)]))
    cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
    cam.CreateShutterOpenAttr(shutter[0])
    cam.CreateShutterCloseAttr(shutter[1])
    stage.Save()
    return p


def _row_alpha(tmp_path, capsys, path, name):
    """Alpha of the middle row of a 64x32 render of the stage."""
    out = tmp_path / name
    rc, _, err = run_cli(["render", path, "-o", out, "--width", 64, "--height", 32, "--spp", 32, "--quiet"], capsys)
    assert rc == 0, err
    img = core.read_exr(str(out))
    px, ch = np.asarray(img.pixels), list(img.channels)
    return px[16, :, ch.index("A")]


def _assert_smeared(blurred, still):
    """The blurred row covers a wider span than the still one, with more partly covered pixels."""
    assert (blurred > 0.02).sum() >= (still > 0.02).sum() + 4
    assert ((blurred > 0.05) & (blurred < 0.95)).sum() > ((still > 0.05) & (still < 0.95)).sum()


def test_camera_shutter_is_read_in_seconds(tmp_path):
    scene = usd_reader.read_stage(_moving(tmp_path / "m.usda", shutter=(-0.25, 0.5), fps=25.0))
    assert scene.desc.camera.shutter_open == pytest.approx(-0.01)
    assert scene.desc.camera.shutter_close == pytest.approx(0.02)


def test_motion_blur_smears_the_grains_over_the_shutter(tmp_path, capsys):
    """Alpha (coverage) of the row through the grains: still, each grain covers its own
    disc; blurred over a frame, each sweeps 2 units each way, so the covered span widens and
    its edge pixels are partly covered."""
    _assert_smeared(_row_alpha(tmp_path, capsys, _moving(tmp_path / "b.usda"), "b.exr"),
                    _row_alpha(tmp_path, capsys, _moving(tmp_path / "s.usda", shutter=(0, 0)), "s.exr"))


def test_a_shutter_that_closes_before_it_opens_is_named(tmp_path, capsys):
    rc, out, err = run_cli(["render", _moving(tmp_path / "bad.usda", shutter=(0.5, -0.5)), "-o",
                            tmp_path / "x.exr", "--width", 8, "--height", 8, "--spp", 1], capsys)
    assert rc == 2
    assert err.startswith("error: /World/Camera.shutter:close: -0.5 is before shutter:open 0.5"), err


def test_invisible_ids_hide_grains(tmp_path):
    """invisibleIds (and inactiveIds) hide instances, as USD hosts and the Hydra delegate do."""
    path = _instancer(tmp_path / "hidden.usda", positions=((-3, 0, 0), (0, 0, 0), (3, 0, 0)), indices=(0, 0, 0))
    stage = Usd.Stage.Open(path)
    pi = UsdGeom.PointInstancer(stage.GetPrimAtPath(SAND))
    pi.CreateInvisibleIdsAttr([1])
    stage.Save()
    scene, desc = _read_at(path, SAND)
    assert desc.num_grains == 2
    assert np.array_equal(desc.positions, np.array([[-3, 0, 0], [3, 0, 0]], np.float32))


def test_the_instancer_arrays_are_read_in_place_one_at_a_time(heap):
    """core reads USD's own arrays (half-float quaternions, real last; int indices) where they
    lie, asking for each when it converts it and letting go of it before the next: 10^8
    instances are gigabytes an array. The grains are those of float copies in core's order."""
    import weakref
    path, count = heap
    stage = Usd.Stage.Open(path)
    prim = stage.GetPrimAtPath(HEAP)
    usd = {name: np.asarray(prim.GetAttribute(name).Get(1))
           for name in ("positions", "orientations", "scales", "protoIndices", "velocities", "angularVelocities")}
    assert usd["orientations"].dtype == np.float16 and usd["protoIndices"].dtype == np.int32
    asked, alive = [], []

    def source(name):
        def read():
            # The array handed over before this one is no longer held by core.
            assert all(ref() is None for ref in alive), (name, asked)
            asked.append(name)
            a = usd[name].copy()
            alive.append(weakref.ref(a))
            return a
        return read

    def lookup(p):
        mp = core.MeshPrim()
        mp.path = p
        mp.mesh = core.make_icosphere(1)
        return mp

    args = (HEAP, "PointInstancer", np.eye(4).tolist(), [HEAP + "/Prototypes/Round", HEAP + "/Prototypes/Rock"], [])
    names = ("positions", "orientations", "scales", "protoIndices", "velocities", "angularVelocities")
    viewed = core.instanced_grains_from_usd(*args, *(source(n) for n in names), core.SceneDesc(), lookup,
                                            orientations_real_last=True)
    assert asked == ["positions", "velocities", "angularVelocities", "orientations", "scales", "protoIndices"]
    flat = [usd[n].astype(np.float32).reshape(-1) for n in names]
    flat[1] = usd["orientations"][:, [3, 0, 1, 2]].astype(np.float32).reshape(-1)
    flat[3] = usd["protoIndices"].astype(np.int64)
    copied = core.instanced_grains_from_usd(*args, *flat, core.SceneDesc(), lookup)
    assert viewed.num_grains == copied.num_grains == count
    assert np.array_equal(viewed.positions, copied.positions) and np.array_equal(viewed.scales, copied.scales)
    # Orientations and indices: the grids built from both place every grain alike.
    a, b = core.InstancedGrains(), core.InstancedGrains()
    a.build(viewed)
    b.build(copied)
    rng = np.random.default_rng(5)
    hits = 0
    for _ in range(64):
        o = rng.normal(size=3)
        o = 3 * o / np.linalg.norm(o)
        d = rng.uniform([-0.2, 0.0, -0.2], [0.2, 0.1, 0.2]) - o  # at the heap's lower part
        h = a.intersect(tuple(o), tuple(d))
        assert h == b.intersect(tuple(o), tuple(d))
        hits += h is not None
    assert hits >= 16
    # A mask leaves instances out after the checks, in order.
    keep = np.arange(count) % 3 != 1
    masked = core.instanced_grains_from_usd(*args, *flat, core.SceneDesc(), lookup, mask=keep)
    assert np.array_equal(masked.positions, copied.positions[keep])
    # Arrays in the other byte order are converted, not read as if native.
    swapped = [f.astype(f.dtype.newbyteorder(">")) for f in flat]
    converted = core.instanced_grains_from_usd(*args, *swapped, core.SceneDesc(), lookup)
    assert np.array_equal(converted.positions, copied.positions)
    assert np.array_equal(converted.scales, copied.scales)


def _read_at(path, prim_path):
    stage = usd_reader.open_stage(path)
    scene = usd_reader.StageScene(path, stage, usd_reader.as_time_code(None, stage))
    return scene, usd_reader.read_instanced_grains(scene, stage.GetPrimAtPath(prim_path))


def test_a_moving_mesh_blurs_over_the_shutter(tmp_path, capsys):
    """Transform motion blur of an ordinary mesh: a cube whose translate is time-sampled gets
    its world transforms at the shutter's ends (core's MeshDesc.shutterXf), and its alpha
    footprint widens over the shutter as the grains' does."""
    def stage(name, shutter):
        path = tmp_path / name
        s = dome_world(path)
        s.SetTimeCodesPerSecond(24)
        s.SetStartTimeCode(1)
        s.SetEndTimeCode(1)
        cube = UsdGeom.Cube.Define(s, "/World/Box")
        op = UsdGeom.Xformable(cube).AddTranslateOp()
        op.Set(Gf.Vec3d(-2, 0, 0), 0)
        op.Set(Gf.Vec3d(2, 0, 0), 2)
        cam = UsdGeom.Camera(s.GetPrimAtPath("/World/Camera"))
        cam.CreateShutterOpenAttr(shutter[0])
        cam.CreateShutterCloseAttr(shutter[1])
        s.Save()
        return str(path)

    blurred_stage, still_stage = stage("m.usda", (-0.5, 0.5)), stage("s.usda", (0, 0))
    (box,) = [m for m in usd_reader.read_stage(blurred_stage).desc.meshes if m.name == "/World/Box"]
    assert box.shutter_xf is not None
    assert box.shutter_xf[0][0][3] == pytest.approx(-1.0) and box.shutter_xf[1][0][3] == pytest.approx(1.0)
    assert all(m.shutter_xf is None for m in usd_reader.read_stage(still_stage).desc.meshes)

    _assert_smeared(_row_alpha(tmp_path, capsys, blurred_stage, "b.exr"),
                    _row_alpha(tmp_path, capsys, still_stage, "s.exr"))
