"""UsdUVTexture on UsdPreviewSurface inputs, read by the usd-core front end: what the
network becomes in core's TextureDesc, how st of each interpolation reaches the triangles'
corners, cut-outs, and the errors a user can cause."""
import numpy as np
import pytest
from conftest import run_cli, small_scene
from pxr import Gf, Sdf, UsdGeom, UsdShade, Vt

import granular_core as core
from granular.usd_reader import read_stage


def _texture_png(path, rgb):
    """A 2 x 1 sRGB PNG of two linear colours (left, right)."""
    core.write_png(str(path), core.Image(np.asarray([rgb], dtype=np.float32), ["R", "G", "B"]))
    return path


def _network(stage, path, file, inputs=("diffuseColor",), output="rgb", varname="st", **tex_inputs):
    """A UsdPreviewSurface whose `inputs` read `output` of one UsdUVTexture of `file`."""
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, path + "/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    reader = UsdShade.Shader.Define(stage, path + "/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set(varname)
    tex = UsdShade.Shader.Define(stage, path + "/Texture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(file))
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    for k, (t, v) in tex_inputs.items():
        tex.CreateInput(k, t).Set(v)
    for name in inputs:
        type_name = Sdf.ValueTypeNames.Float if name in ("opacity",) else Sdf.ValueTypeNames.Color3f
        sh.CreateInput(name, type_name).ConnectToSource(tex.ConnectableAPI(), output)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat, sh


def _ground(stage, st=None, interpolation=UsdGeom.Tokens.vertex, indices=None, left_handed=False):
    """Two quads side by side (6 points): faces [0 1 4 3] and [1 2 5 4]."""
    m = UsdGeom.Mesh.Define(stage, "/World/Ground")
    m.CreatePointsAttr(Vt.Vec3fArray([(-1, 0, 1), (0, 0, 1), (1, 0, 1), (-1, 0, -1), (0, 0, -1), (1, 0, -1)]))
    m.CreateFaceVertexCountsAttr([4, 4])
    m.CreateFaceVertexIndicesAttr([0, 1, 4, 3, 1, 2, 5, 4])
    if left_handed:
        m.CreateOrientationAttr(UsdGeom.Tokens.leftHanded)
    if st is not None:
        pv = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, interpolation)
        pv.Set(Vt.Vec2fArray([Gf.Vec2f(*x) for x in st]))
        if indices is not None:
            pv.SetIndices(Vt.IntArray(indices))
    return m


def _read(tmp_path, mutate):
    scene = read_stage(str(small_scene(tmp_path / "s.usda", mutate)))
    ground = next(m for m in scene.desc.meshes if m.name == "/World/Ground")
    return scene, ground


# Vertex st of the six points: u along +X, v along -Z.
VERTEX_ST = [(0, 0), (0.5, 0), (1, 0), (0, 1), (0.5, 1), (1, 1)]
# The fan of face [0 1 4 3] is (0 1 4), (0 4 3); of [1 2 5 4] (1 2 5), (1 5 4).
CORNER_POINTS = [0, 1, 4, 0, 4, 3, 1, 2, 5, 1, 5, 4]


def test_a_textured_diffuse_color_becomes_a_core_texture(tmp_path):
    png = _texture_png(tmp_path / "t.png", [(1, 0, 0), (0, 1, 0)])

    def mutate(stage):
        mat, _ = _network(stage, "/World/Looks/Beach", png, wrapS=(Sdf.ValueTypeNames.Token, "repeat"),
                          wrapT=(Sdf.ValueTypeNames.Token, "mirror"),
                          scale=(Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.5, 0.5, 0.5, 1)),
                          bias=(Sdf.ValueTypeNames.Float4, Gf.Vec4f(0.1, 0, 0, 0)),
                          sourceColorSpace=(Sdf.ValueTypeNames.Token, "raw"))
        UsdShade.MaterialBindingAPI.Apply(_ground(stage, VERTEX_ST).GetPrim()).Bind(mat)

    scene, ground = _read(tmp_path, mutate)
    md = scene.desc.materials[ground.material]
    assert md.type == core.MaterialType.Lambert
    t = md.albedo_texture
    assert t.enabled and t.file == str(png) and t.source == "/World/Looks/Beach/Texture"
    assert (t.wrap_s, t.wrap_t) == (core.TextureWrap.Repeat, core.TextureWrap.Mirror)
    assert t.scale == pytest.approx((0.5, 0.5, 0.5, 1)) and t.bias == pytest.approx((0.1, 0, 0, 0))
    assert t.color_space == core.TextureColorSpace.Raw and t.channel == -1
    assert not md.emission_texture.enabled and not md.opacity_texture.enabled
    np.testing.assert_allclose(ground.mesh.uvs, np.asarray(VERTEX_ST)[CORNER_POINTS])


@pytest.mark.parametrize("interpolation", ["vertex", "faceVarying", "indexedFaceVarying", "uniform", "constant"])
def test_st_of_every_interpolation_reaches_the_triangle_corners(tmp_path, interpolation):
    png = _texture_png(tmp_path / "t.png", [(1, 0, 0), (0, 1, 0)])
    face_vertex = [0, 1, 4, 3, 1, 2, 5, 4]
    if interpolation == "vertex":
        st, indices, expected = VERTEX_ST, None, np.asarray(VERTEX_ST)[CORNER_POINTS]
    elif interpolation == "faceVarying":  # a seam: the second face has its own u range
        st = [(0, 0), (0.5, 0), (0.5, 1), (0, 1), (2, 0), (3, 0), (3, 1), (2, 1)]
        fv_corners = [0, 1, 2, 0, 2, 3, 4, 5, 6, 4, 6, 7]
        indices, expected = None, np.asarray(st)[fv_corners]
    elif interpolation == "indexedFaceVarying":
        values = [(0, 0), (1, 0), (1, 1), (0, 1)]
        indices = [0, 1, 2, 3, 0, 1, 2, 3]
        st = values
        expected = np.asarray(values)[[0, 1, 2, 0, 2, 3] * 2]
    elif interpolation == "uniform":
        st, indices = [(0.25, 0.5), (0.75, 0.5)], None
        expected = np.asarray([(0.25, 0.5)] * 6 + [(0.75, 0.5)] * 6)
    else:
        st, indices, expected = [(0.3, 0.7)], None, np.asarray([(0.3, 0.7)] * 12)
    usd_interp = "faceVarying" if interpolation == "indexedFaceVarying" else interpolation
    assert face_vertex  # the faces the expectations above are written for

    def mutate(stage):
        mat, _ = _network(stage, "/World/Looks/Beach", png)
        UsdShade.MaterialBindingAPI.Apply(_ground(stage, st, usd_interp, indices).GetPrim()).Bind(mat)

    _, ground = _read(tmp_path, mutate)
    np.testing.assert_allclose(ground.mesh.uvs, expected)


def test_left_handed_meshes_keep_st_on_their_corners(tmp_path):
    png = _texture_png(tmp_path / "t.png", [(1, 0, 0), (0, 1, 0)])

    def mutate(stage):
        mat, _ = _network(stage, "/World/Looks/Beach", png)
        UsdShade.MaterialBindingAPI.Apply(_ground(stage, VERTEX_ST, left_handed=True).GetPrim()).Bind(mat)

    _, ground = _read(tmp_path, mutate)
    idx = np.asarray(ground.mesh.indices)
    # Whatever the winding, each corner's st is its point's.
    np.testing.assert_allclose(ground.mesh.uvs, np.asarray(VERTEX_ST)[idx])


def test_opacity_textures_and_thresholds_make_cutouts_and_plain_opacity_stays_glass(tmp_path):
    png = _texture_png(tmp_path / "t.png", [(0, 0, 0), (1, 1, 1)])

    def mutate(stage):
        cut, _ = _network(stage, "/World/Looks/Leaf", png, inputs=("opacity",), output="r")
        UsdShade.MaterialBindingAPI.Apply(_ground(stage, VERTEX_ST).GetPrim()).Bind(cut)
        masked = UsdShade.Material.Define(stage, "/World/Looks/Masked")
        sh = UsdShade.Shader.Define(stage, "/World/Looks/Masked/Surface")
        sh.CreateIdAttr("UsdPreviewSurface")
        sh.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(0.3)
        sh.CreateInput("opacityThreshold", Sdf.ValueTypeNames.Float).Set(0.5)
        masked.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
        box = UsdGeom.Mesh.Define(stage, "/World/Masked")
        box.CreatePointsAttr(Vt.Vec3fArray([(0, 0, 0), (1, 0, 0), (0, 1, 0)]))
        box.CreateFaceVertexCountsAttr([3])
        box.CreateFaceVertexIndicesAttr([0, 1, 2])
        UsdShade.MaterialBindingAPI.Apply(box.GetPrim()).Bind(masked)

    scene, ground = _read(tmp_path, mutate)
    leaf = scene.desc.materials[ground.material]
    assert leaf.type == core.MaterialType.Lambert and leaf.opacity_texture.enabled and leaf.opacity_texture.channel == 0
    masked = scene.desc.materials[next(m for m in scene.desc.meshes if m.name == "/World/Masked").material]
    assert masked.type == core.MaterialType.Lambert
    assert (masked.opacity, masked.opacity_threshold) == (pytest.approx(0.3), pytest.approx(0.5))


def textured_view(png):
    """The ground (two quads, clamped texture of png) beside the castle, filling the view of
    the camera from above."""
    def mutate(stage):
        mat, _ = _network(stage, "/World/Looks/Beach", png, wrapS=(Sdf.ValueTypeNames.Token, "clamp"),
                          wrapT=(Sdf.ValueTypeNames.Token, "clamp"))
        g = _ground(stage, [(0, 0), (0.5, 0), (1, 0), (0, 1), (0.5, 1), (1, 1)])
        UsdGeom.Xformable(g).AddTranslateOp().Set(Gf.Vec3d(0, 0, 2))  # beside the castle
        UsdShade.MaterialBindingAPI.Apply(g.GetPrim()).Bind(mat)
        cam = UsdGeom.Camera.Get(stage, "/World/Camera")
        m = Gf.Matrix4d().SetLookAt(Gf.Vec3d(0, 3, 2), Gf.Vec3d(0, 0, 2), Gf.Vec3d(0, 0, -1)).GetInverse()
        UsdGeom.Xformable(cam).ClearXformOpOrder()
        UsdGeom.Xformable(cam).AddTransformOp().Set(m)
        cam.CreateHorizontalApertureAttr(20.0)
        cam.CreateVerticalApertureAttr(20.0)
        cam.CreateFocalLengthAttr(40.0)
    return mutate


def test_a_textured_ground_renders_its_texture(tmp_path, capsys):
    """Left half red, right half green, seen from above under the stage's sun: the image's
    left and right quarters take the texture's colours (one meaning with hdGranular:
    tests/hydra compares usdrecord with this command on the sand castle's textured beach)."""
    png = _texture_png(tmp_path / "t.png", [(0.8, 0.1, 0.1), (0.1, 0.8, 0.1)])
    scene = small_scene(tmp_path / "s.usda", textured_view(png))
    exr = tmp_path / "out.exr"
    rc, _, err = run_cli(["render", scene, "-o", exr, "--width", 32, "--height", 32, "--spp", 4], capsys)
    assert rc == 0, err
    img = core.read_exr(str(exr))
    rgb = np.asarray(img.pixels)[..., :3]
    left, right = rgb[8:24, 2:6].reshape(-1, 3).mean(axis=0), rgb[8:24, 26:30].reshape(-1, 3).mean(axis=0)
    assert left[0] > 4 * left[1] and right[1] > 4 * right[0], (left, right)


def _textured_ground(png, **kw):
    def mutate(stage):
        mat, _ = _network(stage, "/World/Looks/Beach", png, **kw)
        UsdShade.MaterialBindingAPI.Apply(_ground(stage, VERTEX_ST).GetPrim()).Bind(mat)
    return mutate


@pytest.mark.parametrize("case", ["missing file", "wrap", "color space", "st count", "varname"])
def test_bad_textures_exit_2_naming_the_shader_and_input(case, tmp_path, capsys):
    png = _texture_png(tmp_path / "t.png", [(1, 0, 0), (0, 1, 0)])
    if case == "missing file":
        mutate, expected = _textured_ground(tmp_path / "nope.png"), \
            f'error: /World/Looks/Beach/Texture.inputs:file: "{tmp_path / "nope.png"}" cannot be found'
    elif case == "wrap":
        mutate = _textured_ground(png, wrapS=(Sdf.ValueTypeNames.Token, "tile"))
        expected = 'error: /World/Looks/Beach/Texture.inputs:wrapS: "tile" is not black, clamp, repeat, mirror or ' \
                   'useMetadata'
    elif case == "color space":
        mutate = _textured_ground(png, sourceColorSpace=(Sdf.ValueTypeNames.Token, "ACEScg"))
        expected = 'error: /World/Looks/Beach/Texture.inputs:sourceColorSpace: "ACEScg" is not auto, raw or sRGB'
    elif case == "st count":
        def mutate(stage):
            mat, _ = _network(stage, "/World/Looks/Beach", png)
            UsdShade.MaterialBindingAPI.Apply(_ground(stage, VERTEX_ST[:4]).GetPrim()).Bind(mat)
        expected = "error: /World/Ground.primvars:st: has 4 values; vertex interpolation needs 6"
    else:
        mutate, expected = _textured_ground(png), None

        def mutate(stage):  # noqa: F811
            mat, _ = _network(stage, "/World/Looks/Beach", png, varname="")
            UsdShade.MaterialBindingAPI.Apply(_ground(stage, VERTEX_ST).GetPrim()).Bind(mat)
        expected = "error: /World/Looks/Beach/St.inputs:varname: names no primvar"
    scene = small_scene(tmp_path / "s.usda", mutate)
    exr = tmp_path / "out.exr"
    rc, _, err = run_cli(["render", scene, "-o", exr, "--width", 16, "--height", 16, "--spp", 1], capsys)
    assert rc == 2, err
    assert err.strip().splitlines() == [expected]
    assert not exr.exists()


def test_a_transform2d_between_reader_and_texture_is_read_through_with_a_warning(tmp_path):
    """UsdTransform2d is not applied (said once); the primvar behind its `in` still is
    (hdGranular follows the same `in` connection)."""
    png = _texture_png(tmp_path / "t.png", [(1, 0, 0), (0, 1, 0)])

    def mutate(stage):
        mat, _ = _network(stage, "/World/Looks/Beach", png)
        xf = UsdShade.Shader.Define(stage, "/World/Looks/Beach/Transform")
        xf.CreateIdAttr("UsdTransform2d")
        reader = UsdShade.Shader.Get(stage, "/World/Looks/Beach/St")
        xf.CreateInput("in", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        xf.CreateInput("scale", Sdf.ValueTypeNames.Float2).Set(Gf.Vec2f(2, 2))
        tex = UsdShade.Shader.Get(stage, "/World/Looks/Beach/Texture")
        tex.GetInput("st").ConnectToSource(xf.ConnectableAPI(), "result")
        UsdShade.MaterialBindingAPI.Apply(_ground(stage, VERTEX_ST).GetPrim()).Bind(mat)

    scene, ground = _read(tmp_path, mutate)
    np.testing.assert_allclose(ground.mesh.uvs, np.asarray(VERTEX_ST)[CORNER_POINTS])
    assert any("UsdTransform2d is not supported" in w for w in scene.warnings)



def test_without_a_writable_cache_an_srgb_texture_still_renders_and_the_user_is_told(tmp_path, capsys, monkeypatch):
    """The linear copy of an sRGB texture lives in the cache; without one the texels are
    decoded after filtering instead, and `granular render` says so (core's texture warning)."""
    png = _texture_png(tmp_path / "t.png", [(0.8, 0.1, 0.1), (0.1, 0.8, 0.1)])
    scene = small_scene(tmp_path / "s.usda", textured_view(png))
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    monkeypatch.setenv("GRANULAR_CACHE_DIR", str(blocker / "cache"))
    exr = tmp_path / "out.exr"
    rc, _, err = run_cli(["render", scene, "-o", exr, "--width", 32, "--height", 32, "--spp", 4], capsys)
    assert rc == 0, err
    assert f'warning: /World/Looks/Beach/Texture: no writable cache for the linear copy of "{png}"; its sRGB ' \
           f'values are decoded after filtering' in err.splitlines(), err
    rgb = np.asarray(core.read_exr(str(exr)).pixels)[..., :3]
    left, right = rgb[8:24, 2:6].reshape(-1, 3).mean(axis=0), rgb[8:24, 26:30].reshape(-1, 3).mean(axis=0)
    assert left[0] > 4 * left[1] and right[1] > 4 * right[0], (left, right)


@pytest.mark.parametrize("name", ["st", "displayColor"])
def test_primvar_indices_of_another_type_are_refused_naming_them(name, tmp_path, capsys):
    # Indices of another type than int[] (fuzz_usd_stage: a matrix4d) made usd-core's
    # ComputeFlattened raise a bare Tf error, "No indices authored for indexed primvar".
    png = _texture_png(tmp_path / "t.png", [(1, 0, 0), (0, 1, 0)])

    def mutate(stage):
        if name == "st":
            _textured_ground(png)(stage)
        else:
            UsdGeom.PrimvarsAPI(_ground(stage)).CreatePrimvar(
                "displayColor", Sdf.ValueTypeNames.Color3fArray, UsdGeom.Tokens.constant).Set([(1, 0, 0)])
        spec = stage.GetRootLayer().GetPrimAtPath("/World/Ground")
        Sdf.AttributeSpec(spec, f"primvars:{name}:indices", Sdf.ValueTypeNames.Matrix4d).default = Gf.Matrix4d(1)
    scene = small_scene(tmp_path / "s.usda", mutate)
    rc, _, err = run_cli(["render", scene, "-o", tmp_path / "o.exr", "--width", 8, "--height", 6, "--spp", 1,
                          "--technique", "ept"], capsys)
    assert rc == 2
    assert err.strip().splitlines()[-1] == \
        f"error: /World/Ground.primvars:{name}:indices: has a matrix4d value, expected int[]", err
    assert not (tmp_path / "o.exr").exists()
