"""PointInstancer and implicit surfaces in `granular render`: the prototypes are drawn at
every visible instance (and nowhere else), Cylinder, Cone and Capsule are tessellated by
core as in hdGranular, and bad instancer data names the attribute."""
import numpy as np
from conftest import dome_world, run_cli
from pxr import Gf, Usd, UsdGeom, Vt

from granular.usd_reader import read_stage

INSTANCER = "/World/Inst"


def _stage(path, positions, proto_indices, invisible=()):
    stage = dome_world(path)
    inst = UsdGeom.PointInstancer.Define(stage, INSTANCER)
    UsdGeom.Scope.Define(stage, INSTANCER + "/Protos")
    cube = UsdGeom.Cube.Define(stage, INSTANCER + "/Protos/Box")
    cube.CreateSizeAttr(1.0)
    cyl = UsdGeom.Cylinder.Define(stage, INSTANCER + "/Protos/Drum")
    cyl.CreateRadiusAttr(0.3)
    inst.CreatePrototypesRel().SetTargets([cube.GetPath(), cyl.GetPath()])
    inst.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(*p) for p in positions]))
    inst.CreateProtoIndicesAttr(Vt.IntArray(proto_indices))
    if invisible:
        inst.CreateIdsAttr(Vt.Int64Array(list(range(len(positions)))))
        inst.CreateInvisibleIdsAttr(Vt.Int64Array(list(invisible)))
    stage.Save()
    return str(path)


def test_prototypes_are_drawn_at_each_visible_instance_only(tmp_path):
    scene = read_stage(_stage(tmp_path / "a.usda", [(-1, 0, 0), (1, 0, 0), (0, 1.5, 0)], [0, 1, 0], invisible=[2]))
    by_name = {}
    for m in scene.desc.meshes:
        by_name.setdefault(m.name, []).append(np.asarray(m.xf)[:3, 3])
    # Not drawn where the prototypes stand: only through the instancer, id 2 hidden.
    assert sorted(by_name) == [INSTANCER + "/Protos/Box", INSTANCER + "/Protos/Drum"]
    assert [tuple(t) for t in by_name[INSTANCER + "/Protos/Box"]] == [(-1, 0, 0)]
    assert [tuple(t) for t in by_name[INSTANCER + "/Protos/Drum"]] == [(1, 0, 0)]


def test_instances_render_as_the_same_prims_placed_by_hand(tmp_path, capsys):
    """Three instanced boxes, one turned and scaled, render as three Cube prims with the
    same transforms (same seed: the same image)."""
    import granular_core as core
    positions = [(-2.0, 0, 0), (0, 0.3, 0), (2.0, 0, 0)]
    instanced = _stage(tmp_path / "inst.usda", positions, [0, 0, 0])
    stage = Usd.Stage.Open(instanced)
    inst = UsdGeom.PointInstancer(stage.GetPrimAtPath(INSTANCER))
    inst.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(1, 0, 0, 0), Gf.Quath(0.92388, 0, 0.38268, 0),
                                               Gf.Quath(1, 0, 0, 0)]))
    inst.CreateScalesAttr(Vt.Vec3fArray([Gf.Vec3f(1), Gf.Vec3f(1, 0.5, 1), Gf.Vec3f(0.7)]))
    stage.Save()
    by_hand = Usd.Stage.CreateNew(str(tmp_path / "hand.usda"))
    by_hand.GetRootLayer().subLayerPaths.append(instanced)
    by_hand.GetPrimAtPath(INSTANCER).SetActive(False)
    xforms = inst.ComputeInstanceTransformsAtTime(Usd.TimeCode.Default(), Usd.TimeCode.Default())
    for i, m in enumerate(xforms):
        cube = UsdGeom.Cube.Define(by_hand, f"/World/Box{i}")
        cube.CreateSizeAttr(1.0)
        cube.AddTransformOp().Set(Gf.Matrix4d(m))
    by_hand.Save()
    images = []
    for scene in (instanced, str(tmp_path / "hand.usda")):
        out = tmp_path / (scene.split("/")[-1] + ".exr")
        rc, _, err = run_cli(["render", scene, "-o", out, "--width", 96, "--height", 72, "--spp", 2], capsys)
        assert rc == 0, err
        im = core.read_exr(str(out))
        images.append(np.asarray(im.pixels, dtype=np.float64).reshape(im.height, im.width, -1)[..., :4])
    assert images[0][..., 3].sum() > 0
    np.testing.assert_allclose(images[0], images[1], atol=1e-5)


def test_bad_instancer_data_names_the_attribute(tmp_path, capsys):
    scene = _stage(tmp_path / "bad.usda", [(0, 0, 0), (1, 0, 0)], [0, 5])
    rc, _, err = run_cli(["render", scene, "-o", tmp_path / "x.exr", "--width", 16, "--height", 16, "--spp", 1],
                         capsys)
    assert rc == 2
    assert err.strip() == f"error: {INSTANCER}.protoIndices: 5 is not the index of one of its 2 prototypes"
    scene = _stage(tmp_path / "short.usda", [(0, 0, 0)], [0, 1])
    rc, _, err = run_cli(["render", scene, "-o", tmp_path / "y.exr", "--width", 16, "--height", 16, "--spp", 1],
                         capsys)
    assert rc == 2
    assert err.strip().startswith(f"error: {INSTANCER}.positions: gives 0 instances for 2 protoIndices")


def test_implicit_surfaces_take_usdgeom_fallbacks_and_refuse_bad_sizes(tmp_path, capsys):
    path = tmp_path / "shapes.usda"
    stage = Usd.Stage.CreateNew(str(path))
    cam = UsdGeom.Camera.Define(stage, "/Camera")
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 0, 10))
    for kind in (UsdGeom.Cylinder, UsdGeom.Cone, UsdGeom.Capsule):
        kind.Define(stage, "/" + kind.__name__)
    stage.Save()
    scene = read_stage(str(path))
    bounds = {m.name: (np.asarray(m.mesh.points).min(axis=0), np.asarray(m.mesh.points).max(axis=0))
              for m in scene.desc.meshes}
    # Axis Z: a cylinder and a cone 2 high of radius 1, a capsule 1 + 2 * 0.5 long.
    for name, half_z, radius in (("/Cylinder", 1.0, 1.0), ("/Cone", 1.0, 1.0), ("/Capsule", 1.0, 0.5)):
        lo, hi = bounds[name]
        np.testing.assert_allclose(hi, [radius, radius, half_z], atol=1e-5)
        np.testing.assert_allclose(lo, [-radius, -radius, -half_z], atol=1e-5)
    UsdGeom.Cone(stage.GetPrimAtPath("/Cone")).CreateHeightAttr(-1.0)
    stage.Save()
    rc, _, err = run_cli(["render", str(path), "-o", tmp_path / "x.exr", "--width", 16, "--height", 16, "--spp", 1],
                         capsys)
    assert rc == 2 and err.strip() == "error: /Cone.height: -1 must be finite and > 0"
