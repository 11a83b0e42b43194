"""The USD reader: what a stage becomes in core's SceneDesc."""
import math

import numpy as np
import pytest
from conftest import add_mesh, small_scene
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade, Vt

import granular_core as core
from granular import schema
from granular.usd_reader import read_stage, validate


def _preview(stage, path, **inputs):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, path + "/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    for k, (t, v) in inputs.items():
        sh.CreateInput(k, t).Set(v)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def test_small_scene_reads_into_one_aggregate_with_two_prototypes(tmp_path):
    scene = read_stage(str(small_scene(tmp_path / "s.usda")))
    validate(scene)
    d = scene.desc
    assert [a.name for a in d.aggregates] == ["/World/Castle"]
    agg = d.aggregates[0]
    assert [p.name for p in agg.prototypes] == ["/World/Grains/A", "/World/Grains/B"]
    assert agg.weights == pytest.approx([0.7, 0.3])
    assert (agg.grain_radius, agg.packing_rate, agg.seed, agg.tile_spheres) == (pytest.approx(0.03), pytest.approx(0.5), 3, 64)
    mats = [d.materials[p.material] for p in agg.prototypes]
    assert all(m.type == core.MaterialType.Dielectric for m in mats)
    assert mats[0].ior == pytest.approx(1.5) and mats[0].absorption == pytest.approx((0.2, 0.3, 0.5))
    assert mats[1].ior == pytest.approx(1.31) and mats[1].absorption == pytest.approx((0, 0, 0))
    # Prototypes are not ordinary geometry, and neither is the aggregate's boundary.
    assert d.meshes == []
    assert scene.camera_path == "/World/Camera"
    assert [l.type for l in d.lights] == [core.LightType.Distant]


def test_meshes_polygons_transforms_orientation_and_materials(tmp_path):
    def mutate(stage):
        quad = UsdGeom.Mesh.Define(stage, "/World/Ground")
        quad.CreatePointsAttr(Vt.Vec3fArray([(-1, 0, -1), (-1, 0, 1), (1, 0, 1), (1, 0, -1)]))
        quad.CreateFaceVertexCountsAttr([4])
        quad.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        xf = UsdGeom.Xformable(quad)
        xf.AddTranslateOp().Set(Gf.Vec3d(1, 2, 3))
        xf.AddScaleOp().Set(Gf.Vec3f(2, 2, 2))
        UsdShade.MaterialBindingAPI.Apply(quad.GetPrim()).Bind(
            _preview(stage, "/World/Looks/Sand", diffuseColor=(Sdf.ValueTypeNames.Color3f, (0.5, 0.4, 0.3))))
        glass = UsdGeom.Mesh.Define(stage, "/World/Glass")
        tri = core.make_icosphere(1)
        glass.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in tri.points]))
        glass.CreateFaceVertexCountsAttr([3] * tri.num_triangles)
        glass.CreateFaceVertexIndicesAttr([int(i) for i in tri.indices])
        glass.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
        UsdShade.MaterialBindingAPI.Apply(glass.GetPrim()).Bind(
            _preview(stage, "/World/Looks/Glass", opacity=(Sdf.ValueTypeNames.Float, 0.2),
                     ior=(Sdf.ValueTypeNames.Float, 1.45)))
        red = UsdGeom.Cube.Define(stage, "/World/Red")
        red.CreateSizeAttr(0.5)
        red.CreateDisplayColorAttr([(0.8, 0.1, 0.1)])
        # Not rendered: invisible, guide purpose, a grain prototype not named by anyone.
        hidden = UsdGeom.Sphere.Define(stage, "/World/Hidden")
        hidden.CreateVisibilityAttr(UsdGeom.Tokens.invisible)
        guide = UsdGeom.Sphere.Define(stage, "/World/Guide")
        guide.CreatePurposeAttr(UsdGeom.Tokens.guide)
        spare = add_mesh(stage, "/World/Spare", core.make_icosphere(1))
        schema.apply_grain(spare, invisible=False)

    scene = read_stage(str(small_scene(tmp_path / "s.usda", mutate)))
    validate(scene)
    d = scene.desc
    meshes = {m.name: m for m in d.meshes}
    assert sorted(meshes) == ["/World/Glass", "/World/Ground", "/World/Red"]
    ground = meshes["/World/Ground"]
    assert ground.mesh.num_triangles == 2
    # USD row-vector matrix -> core's column form: translation in the last column.
    xf = np.array(ground.xf)
    assert xf[:3, 3] == pytest.approx([1, 2, 3]) and np.diag(xf)[:3] == pytest.approx([2, 2, 2])
    sand = d.materials[ground.material]
    assert sand.type == core.MaterialType.Lambert and sand.albedo == pytest.approx((0.5, 0.4, 0.3))
    glass = meshes["/World/Glass"]
    gm = d.materials[glass.material]
    assert gm.type == core.MaterialType.Dielectric and gm.ior == pytest.approx(1.45)
    # leftHanded: the reader flips the triangles into core's right-handed winding (the
    # points were authored counter-clockwise, so the flipped sphere turns inside out).
    assert glass.mesh.signed_volume() < 0
    red = meshes["/World/Red"]
    assert red.mesh.num_triangles == 12
    assert d.materials[red.material].albedo == pytest.approx((0.8, 0.1, 0.1))


def test_camera_lights_and_render_settings(tmp_path):
    sky_file = tmp_path / "sky.png"
    empty = core.SceneDesc()
    empty.settings.width, empty.settings.height, empty.settings.spp = 8, 4, 1
    core.write_png(str(sky_file), core.Renderer(core.Scene.build(empty)).image())  # a black image
    ies_file = tmp_path / "profiles" / "spot.ies"
    ies_file.parent.mkdir()
    ies_file.write_text("IESNA:LM-63-2002\nTILT=NONE\n1 -1 1 2 1 1 2 0 0 0\n1 1 10\n0 90\n0\n10 0\n")

    def mutate(stage):
        cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
        cam.CreateFStopAttr(2.0)
        cam.CreateFocusDistanceAttr(7.5)
        cam.CreateHorizontalApertureAttr(30.0)
        cam.CreateVerticalApertureAttr(15.0)
        cam.CreateClippingRangeAttr(Gf.Vec2f(0.5, 50))
        second = UsdGeom.Camera.Define(stage, "/World/Second")
        second.CreateFocalLengthAttr(80.0)
        sun = UsdLux.DistantLight(stage.GetPrimAtPath("/World/Sun"))
        sun.CreateAngleAttr(12.0)
        sun.CreateExposureAttr(1.0)
        sun.CreateEnableColorTemperatureAttr(True)
        sun.CreateColorTemperatureAttr(3000.0)
        dome = UsdLux.DomeLight.Define(stage, "/World/Sky")
        dome.CreateTextureFileAttr(Sdf.AssetPath("sky.png"))
        rect = UsdLux.RectLight.Define(stage, "/World/Panel")
        rect.CreateWidthAttr(2.0)
        rect.CreateHeightAttr(0.5)
        rect.CreateNormalizeAttr(True)
        ball = UsdLux.SphereLight.Define(stage, "/World/Bulb")
        ball.CreateRadiusAttr(0.25)
        ball.CreateColorAttr((1.0, 0.5, 0.25))
        disk = UsdLux.DiskLight.Define(stage, "/World/Disk")
        disk.CreateRadiusAttr(0.2)
        shaping = UsdLux.ShapingAPI.Apply(disk.GetPrim())
        shaping.CreateShapingConeAngleAttr(30.0)
        shaping.CreateShapingIesFileAttr(Sdf.AssetPath("profiles/spot.ies"))  # relative to the stage
        shaping.CreateShapingIesAngleScaleAttr(0.5)
        shaping.CreateShapingIesNormalizeAttr(True)
        tube = UsdLux.CylinderLight.Define(stage, "/World/Tube")
        tube.CreateLengthAttr(2.0)
        UsdLux.PluginLight.Define(stage, "/World/Plugin")
        UsdGeom.Scope.Define(stage, "/Render")
        rs = UsdRender.Settings.Define(stage, "/Render/Settings")
        rs.CreateResolutionAttr(Gf.Vec2i(320, 100))
        rs.CreateCameraRel().SetTargets(["/World/Second"])

    path = str(small_scene(tmp_path / "s.usda", mutate))
    scene = read_stage(path)
    validate(scene)
    d = scene.desc
    # The render settings' camera and resolution.
    assert scene.camera_path == "/World/Second"
    assert d.camera.focal_length == pytest.approx(80.0)
    assert (d.settings.width, d.settings.height) == (320, 100)
    # --camera wins; --width alone keeps the camera's aperture aspect.
    scene = read_stage(path, camera="/World/Camera", width=300)
    c = scene.desc.camera
    assert (c.horizontal_aperture, c.vertical_aperture, c.clip_near, c.clip_far) == pytest.approx((30, 15, 0.5, 50))
    # Depth of field: a thin lens of radius focalLength / 10 / (2 fStop) scene units (USD's
    # focal length is in tenths of a unit; Hydra's HdCamera gives the same radius).
    assert (c.lens_radius, c.focus_distance) == pytest.approx((0.05 * c.focal_length / 2.0, 7.5))
    assert read_stage(path).desc.camera.lens_radius == 0  # /World/Second has no fStop: a pinhole
    assert (scene.desc.settings.width, scene.desc.settings.height) == (300, 150)
    lights = {l.name: l for l in scene.desc.lights}
    assert sorted(lights) == ["/World/Bulb", "/World/Disk", "/World/Panel", "/World/Sky", "/World/Sun", "/World/Tube"]
    sun = lights["/World/Sun"]
    assert sun.type == core.LightType.Distant and sun.angle == pytest.approx(12) and sun.exposure == pytest.approx(1)
    assert sun.color[2] < sun.color[0]  # 3000 K is reddish
    assert lights["/World/Sky"].texture_file == str(sky_file)
    panel = lights["/World/Panel"]
    assert (panel.type, panel.width, panel.height, panel.normalize) == (core.LightType.Rect, 2.0, 0.5, True)
    bulb = lights["/World/Bulb"]
    assert bulb.type == core.LightType.Sphere and bulb.radius == pytest.approx(0.25)
    assert bulb.color == pytest.approx((1.0, 0.5, 0.25))
    disk = lights["/World/Disk"]
    assert (disk.type, disk.radius) == (core.LightType.Disk, pytest.approx(0.2))
    # ShapingAPI applied: its authored cone and IES profile (resolved), the schema's
    # fallbacks for the rest.
    assert disk.shaping.enabled and (disk.shaping.cone_angle, disk.shaping.cone_softness) == (30.0, 0.0)
    assert disk.shaping.ies_file == str(ies_file)
    assert (disk.shaping.ies_angle_scale, disk.shaping.ies_normalize) == (0.5, True)
    tube = lights["/World/Tube"]
    assert (tube.type, tube.radius, tube.length) == (core.LightType.Cylinder, 0.5, 2.0)
    assert not tube.shaping.enabled and not bulb.shaping.enabled
    assert any("PluginLight lights are not supported" in w for w in scene.warnings)


def test_light_linking_names_each_lights_collection_and_the_prims_it_includes(tmp_path):
    """A light's collection:lightLink that does not hold every prim is named by its path; the
    prims it includes carry that name among their categories (core/usd_lights.h); a trivial
    one (includeRoot alone) links nothing; a shadowLink likewise names the prims that cast
    the light's shadows."""
    def mutate(stage):
        add_mesh(stage, "/World/Ground", core.make_box((-1, -0.1, -1), (1, 0, 1)))
        add_mesh(stage, "/World/Props/Wall", core.make_box((-1, 0, -1), (1, 1, -0.9)))
        sun = UsdLux.LightAPI(stage.GetPrimAtPath("/World/Sun"))
        sun.GetLightLinkCollectionAPI().GetExcludesRel().AddTarget("/World/Ground")
        key = UsdLux.SphereLight.Define(stage, "/World/Key")
        link = UsdLux.LightAPI(key).GetLightLinkCollectionAPI()
        link.GetIncludeRootAttr().Set(False)
        link.GetIncludesRel().AddTarget("/World/Props")
        link.GetIncludesRel().AddTarget("/World/Castle")
        UsdLux.LightAPI(key).GetShadowLinkCollectionAPI().GetExcludesRel().AddTarget("/World/Castle")
        UsdLux.DomeLight.Define(stage, "/World/Sky")

    scene = read_stage(str(small_scene(tmp_path / "s.usda", mutate)))
    d = scene.desc
    lights = {l.name: l.light_link for l in d.lights}
    assert lights == {"/World/Sun": "/World/Sun.collection:lightLink",
                      "/World/Key": "/World/Key.collection:lightLink", "/World/Sky": ""}
    shadows = {l.name: (l.shadow_link, l.shadows) for l in d.lights}
    assert shadows == {"/World/Sun": ("", True), "/World/Key": ("/World/Key.collection:shadowLink", True),
                       "/World/Sky": ("", True)}
    meshes = {m.name: list(m.link_categories) for m in d.meshes}
    assert meshes == {"/World/Ground": ["/World/Key.collection:shadowLink"],
                      "/World/Props/Wall": ["/World/Sun.collection:lightLink", "/World/Key.collection:lightLink",
                                            "/World/Key.collection:shadowLink"]}
    assert list(d.aggregates[0].link_categories) == ["/World/Sun.collection:lightLink",
                                                     "/World/Key.collection:lightLink"]
    assert not [w for w in scene.warnings if "shadow" in w]


def test_a_value_blocked_with_another_type_is_the_schemas_fallback(tmp_path, capsys):
    """`string inputs:exposure = None` (fuzz_usd_stage): a block falls back to the schema's
    value, a float, which the reader took for the string the block was typed as and broke
    on (a Python TypeError, exit 1). It is the fallback, as any host reads it."""
    from conftest import run_cli

    def mutate(stage):
        spec = stage.GetRootLayer().GetPrimAtPath("/World/Sun")
        Sdf.AttributeSpec(spec, "inputs:exposure", Sdf.ValueTypeNames.String).default = Sdf.ValueBlock()
        Sdf.AttributeSpec(spec, "inputs:angle", Sdf.ValueTypeNames.Token).default = Sdf.ValueBlock()
    path = small_scene(tmp_path / "s.usda", mutate)
    sun = read_stage(str(path)).desc.lights[0]
    assert (sun.exposure, sun.angle) == (0.0, pytest.approx(0.53))  # UsdLux's fallbacks
    rc, _, err = run_cli(["render", path, "-o", tmp_path / "o.exr", "--width", 8, "--height", 6, "--spp", 1], capsys)
    assert rc == 0, err


def test_info_mode_needs_no_camera_and_reads_no_surfaces(tmp_path):
    def mutate(stage):
        stage.RemovePrim("/World/Camera")
        UsdGeom.Cube.Define(stage, "/World/Box")
    scene = read_stage(str(small_scene(tmp_path / "s.usda", mutate)), surfaces=False, need_camera=False)
    assert len(scene.desc.aggregates) == 1 and scene.desc.meshes == [] and scene.desc.lights == []


def test_prototypes_inside_an_instanceable_asset_and_relative_paths_survive_referencing(tmp_path):
    asset = small_scene(tmp_path / "asset.usda")

    stage = Usd.Stage.CreateNew(str(tmp_path / "shot.usda"))
    UsdGeom.Xform.Define(stage, "/Shot")
    ref = stage.DefinePrim("/Shot/CastleA")
    ref.GetReferences().AddReference(str(asset), "/World")
    ref.SetInstanceable(True)
    ref2 = stage.DefinePrim("/Shot/CastleB")
    ref2.GetReferences().AddReference(str(asset), "/World")
    UsdGeom.Xformable(ref2).AddTranslateOp().Set(Gf.Vec3d(2, 0, 0))
    stage.GetRootLayer().Save()
    scene = read_stage(str(tmp_path / "shot.usda"))
    validate(scene)
    names = sorted(a.name for a in scene.desc.aggregates)
    assert names == ["/Shot/CastleA/Castle", "/Shot/CastleB/Castle"]
    b = [a for a in scene.desc.aggregates if a.name == "/Shot/CastleB/Castle"][0]
    assert [p.name for p in b.prototypes] == ["/Shot/CastleB/Grains/A", "/Shot/CastleB/Grains/B"]
    assert np.array(b.xf)[0, 3] == pytest.approx(2.0)


def test_grain_sizes_and_spread_reach_the_aggregate(tmp_path):
    """GranularAggregateAPI sizes and sizeSpread (polydisperse grains) in core's terms; the
    same primvars reach hdGranular through core's granular_prims (one meaning)."""
    def mutate(stage):
        api = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World/Castle"))
        api.CreatePrimvar("granular:sizes", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.constant).Set(
            Vt.FloatArray([1.0, 0.4]))
        api.CreatePrimvar("granular:sizeSpread", Sdf.ValueTypeNames.Float, UsdGeom.Tokens.constant).Set(0.25)

    scene = read_stage(str(small_scene(tmp_path / "s.usda", mutate)))
    validate(scene)
    agg = scene.desc.aggregates[0]
    assert agg.sizes == pytest.approx([1.0, 0.4])
    assert agg.size_spread == pytest.approx(0.25)
    # Unauthored: equal sizes.
    plain = read_stage(str(small_scene(tmp_path / "p.usda"))).desc.aggregates[0]
    assert list(plain.sizes) == [] and plain.size_spread == 0

