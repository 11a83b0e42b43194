#!/usr/bin/env python3
"""fuzz_usd_stage — Atheris (libFuzzer for Python) target for the whole usd-core front end:
a small valid stage built in memory, mutated across everything the reader understands,
then rendered in-process through `granular render`'s own code (cli.cmd_render).

    .venv/bin/python fuzz/fuzz_usd_stage.py [libFuzzer flags] [CORPUS_DIR ...]   (make fuzz-usd)
    .venv/bin/python fuzz/fuzz_usd_stage.py FILE ...                            (replay inputs)

The input bytes are read by atheris.FuzzedDataProvider as: the command line's options
(technique, --frames, size, --camera, --crop, ...), then a list of mutations of the base
stage (see `base_stage`), each picking one of:
  - an attribute from ATTRS (lights, cameras, UsdPreviewSurface / UsdUVTexture /
    UsdPrimvarReader_float2 inputs, meshes, Cube, Sphere, PointInstancer, render settings
    and products, visibility, purpose, the primvars:granular:* of aggregates, prototypes
    and an ancestor) and sets a default, time samples or a block, of its own type or of
    another one (authored through Sdf, so usd-core keeps wrongly typed values), with
    NaN, inf, huge, tiny, negative values and arrays of wrong lengths;
  - a transform op of a prim (and the op order), a primvar's interpolation, a shader
    input's connection, a relationship's targets (material binding, render settings
    camera and products), a prim's type, active flag or applied API schemas, an
    instanced copy of a prim, a removed prim, the stage's time codes or render settings.
An input that starts with `#usda` is a stage instead (the regressions in fuzz/regressions/
are kept so, readable and independent of the byte layout above): its customLayerData's
`fuzzArgs` holds the options, {work} the folder of the files it names and {out} the output
folder; FUZZ_DUMP writes every input in that form.
Contract: cmd_render ends in granular's UserError or core.InputError (the command's
exit status 2), or renders an image whose every pixel is finite (Z may be +inf where
nothing is hit). Anything else raises here, and libFuzzer writes the input to its
artifacts: another exception (a Tf.ErrorException included: the reader must name the prim
and attribute), a crash, a non-finite pixel, a run beyond -timeout.

Costs are bounded in the render path itself (a wrapper of api.build_scene and of
usd_reader.read_stage, after core's validation has seen the values): at most 256 pixels,
20000 triangles, 4096 tiles per aggregate, 64 spheres per tile; a larger but valid scene
is skipped. FUZZ_VERBOSE=1 prints each input's options, mutations and outcome;
FUZZ_DUMP=DIR also writes each input's stage there as .usda (for regression tests).
"""
import io
import math
import os
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUILD = os.environ.get("GRANULAR_BUILD_DIR", os.path.join(ROOT, "build"))
for _p in (os.path.join(BUILD, "python"), os.path.join(ROOT, "python")):
    if _p not in sys.path:
        sys.path.insert(0, _p)
# Tiles and grain transport are cached on disk; keep the fuzzer's apart.
os.environ.setdefault("GRANULAR_CACHE_DIR", os.path.join(tempfile.gettempdir(), "granular-fuzz-usd-cache"))

import atheris  # noqa: E402

with atheris.instrument_imports(include=["granular"]):
    import granular  # noqa: E402,F401  (registers the schema plugin first)
    from granular import api, cli, usd_reader  # noqa: E402
    from granular.errors import UserError  # noqa: E402

import granular_core as core  # noqa: E402
import numpy as np  # noqa: E402
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade, Vt  # noqa: E402

VERBOSE = bool(os.environ.get("FUZZ_VERBOSE"))
DUMP = os.environ.get("FUZZ_DUMP")
SCENE = "fuzz://stage.usda"  # the name cmd_render opens: the input's in-memory stage

MAX_PIXELS = 256
MAX_TRIANGLES = 20000
MAX_CELLS = 4096
MAX_TILE_SPHERES = 64


def log(*a):
    if VERBOSE:
        print("fuzz:", *a, file=sys.stderr)


# ---- files the stage may name ----------------------------------------------------------------

WORK = tempfile.mkdtemp(prefix="fuzz_usd_stage_")
TEX = os.path.join(WORK, "tex.png")
SKY = os.path.join(WORK, "sky.exr")
NOT_AN_IMAGE = os.path.join(WORK, "text.png")


def _write_assets():
    core.write_png(TEX, core.Image(np.asarray([[(0.9, 0.1, 0.1), (0.1, 0.9, 0.1)],
                                               [(0.1, 0.1, 0.9), (0.5, 0.5, 0.5)]], dtype=np.float32), ["R", "G", "B"]))
    sky = np.asarray([[(0.4, 0.6, 1.0)] * 4, [(0.3, 0.25, 0.2)] * 4], dtype=np.float32)
    core.write_exr(SKY, core.Image(sky, ["R", "G", "B"]))
    with open(NOT_AN_IMAGE, "w") as f:
        f.write("not an image\n")


_write_assets()
ASSETS = [TEX, SKY, NOT_AN_IMAGE, "", "tex.png", os.path.join(WORK, "missing.png"), os.path.join(WORK, "tex.<UDIM>.png"),
          WORK, "/", "@@", "relative/../tex.png"]


# ---- the base stage ------------------------------------------------------------------------------

def _mesh(stage, path, tri):
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in tri.points]))
    idx = [int(i) for i in tri.indices]
    m.CreateFaceVertexIndicesAttr(Vt.IntArray(idx))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([3] * (len(idx) // 3)))
    return m


def _surface(stage, path, **inputs):
    mat = UsdShade.Material.Define(stage, path)
    sh = UsdShade.Shader.Define(stage, path + "/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    for name, (type_name, value) in inputs.items():
        sh.CreateInput(name, type_name).Set(value)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat, sh


def _bind(prim, mat):
    UsdShade.MaterialBindingAPI.Apply(prim.GetPrim()).Bind(mat)


def base_stage():
    """A valid stage with one of each thing the reader reads: an aggregate /World/Castle of
    two grain prototypes (and a third prototype without the grain API), a textured ground,
    a glass Sphere, a Cube with displayColor, an unsupported Cylinder and PointInstancer,
    two cameras, the four UsdLux light types (the dome textured), a render settings prim
    with a product. Renders in a few milliseconds at 8x6, 1 spp, EPT."""
    from granular import schema
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Scope.Define(stage, "/World/Grains")
    a = _mesh(stage, "/World/Grains/A", core.make_icosphere(1))
    b = _mesh(stage, "/World/Grains/B", core.make_rock(1, 0.2, 3))
    c = _mesh(stage, "/World/Grains/C", core.make_icosphere(0))
    schema.apply_grain(a, ior=1.5, absorption=(0.2, 0.3, 0.5))
    schema.apply_grain(b, ior=1.31, roughness=0.3)
    UsdGeom.Imageable(c).MakeInvisible()
    castle = _mesh(stage, "/World/Castle", core.make_box((-0.2, 0.0, -0.2), (0.2, 0.3, 0.2)))
    schema.apply_aggregate(castle, [a, b], grain_radius=0.05, packing_rate=0.5, weights=[0.7, 0.3], seed=3,
                           tile_spheres=16)
    UsdGeom.Xformable(castle).AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, 0.0))

    UsdGeom.Scope.Define(stage, "/World/Looks")
    plain, _ = _surface(stage, "/World/Looks/Plain", diffuseColor=(Sdf.ValueTypeNames.Color3f, Gf.Vec3f(0.5, 0.5, 0.4)),
                        emissiveColor=(Sdf.ValueTypeNames.Color3f, Gf.Vec3f(0, 0, 0)),
                        opacity=(Sdf.ValueTypeNames.Float, 1.0), opacityThreshold=(Sdf.ValueTypeNames.Float, 0.0),
                        ior=(Sdf.ValueTypeNames.Float, 1.5))
    glass, _ = _surface(stage, "/World/Looks/Glass", opacity=(Sdf.ValueTypeNames.Float, 0.3),
                        ior=(Sdf.ValueTypeNames.Float, 1.4))
    textured, sh = _surface(stage, "/World/Looks/Textured")
    reader = UsdShade.Shader.Define(stage, "/World/Looks/Textured/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex = UsdShade.Shader.Define(stage, "/World/Looks/Textured/Tex")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(TEX))
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("clamp")
    tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(1, 1, 1, 1))
    tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(0, 0, 0, 0))
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")

    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    ground.CreatePointsAttr(Vt.Vec3fArray([(-1, 0, 1), (0, 0, 1), (1, 0, 1), (-1, 0, -1), (0, 0, -1), (1, 0, -1)]))
    ground.CreateFaceVertexCountsAttr(Vt.IntArray([4, 4]))
    ground.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 4, 3, 1, 2, 5, 4]))
    st = UsdGeom.PrimvarsAPI(ground).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray([(0, 0), (0.5, 0), (1, 0), (0, 1), (0.5, 1), (1, 1)]))
    _bind(ground, textured)
    ball = UsdGeom.Sphere.Define(stage, "/World/Ball")
    ball.CreateRadiusAttr(0.1)
    UsdGeom.Xformable(ball).AddTranslateOp().Set(Gf.Vec3d(0.4, 0.1, 0.2))
    _bind(ball, glass)
    block = UsdGeom.Cube.Define(stage, "/World/Block")
    block.CreateSizeAttr(0.15)
    UsdGeom.Xformable(block).AddTranslateOp().Set(Gf.Vec3d(-0.4, 0.075, 0.1))
    block.CreateDisplayColorAttr(Vt.Vec3fArray([(0.8, 0.2, 0.2)]))
    lamp = _mesh(stage, "/World/Lamp", core.make_box((-0.05, 0.5, -0.05), (0.05, 0.52, 0.05)))
    _bind(lamp, plain)
    UsdGeom.Cylinder.Define(stage, "/World/Pillar")
    inst = UsdGeom.PointInstancer.Define(stage, "/World/Instancer")
    UsdGeom.Sphere.Define(stage, "/World/Instancer/Proto").CreateRadiusAttr(0.02)
    inst.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Instancer/Proto")])
    inst.CreatePositionsAttr(Vt.Vec3fArray([(0.3, 0.02, -0.3)]))
    inst.CreateProtoIndicesAttr(Vt.IntArray([0]))

    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 1000))
    m = Gf.Matrix4d().SetLookAt(Gf.Vec3d(1.0, 0.8, 1.2), Gf.Vec3d(0, 0.15, 0), Gf.Vec3d(0, 1, 0)).GetInverse()
    UsdGeom.Xformable(cam).AddTransformOp().Set(m)
    cam2 = UsdGeom.Camera.Define(stage, "/World/Camera2")
    cam2.CreateFStopAttr(2.8)
    cam2.CreateFocusDistanceAttr(2.0)
    UsdGeom.Xformable(cam2).AddTranslateOp().Set(Gf.Vec3d(0.0, 0.2, 2.0))

    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(3.0)
    UsdGeom.Xformable(sun).AddRotateXOp().Set(-60.0)
    sky = UsdLux.DomeLight.Define(stage, "/World/Sky")
    sky.CreateIntensityAttr(0.5)
    sky.CreateTextureFileAttr(Sdf.AssetPath(SKY))
    panel = UsdLux.RectLight.Define(stage, "/World/Panel")
    panel.CreateIntensityAttr(5.0)
    panel.CreateWidthAttr(0.5)
    panel.CreateHeightAttr(0.5)
    UsdGeom.Xformable(panel).AddTranslateOp().Set(Gf.Vec3d(0, 1.5, 0))
    UsdGeom.Xformable(panel).AddRotateXOp().Set(-90.0)
    bulb = UsdLux.SphereLight.Define(stage, "/World/Bulb")
    bulb.CreateIntensityAttr(10.0)
    bulb.CreateRadiusAttr(0.05)
    UsdGeom.Xformable(bulb).AddTranslateOp().Set(Gf.Vec3d(0.5, 0.6, 0.5))

    UsdGeom.Scope.Define(stage, "/Render")
    rs = UsdRender.Settings.Define(stage, "/Render/Settings")
    rs.CreateResolutionAttr(Gf.Vec2i(8, 6))
    rs.CreateCameraRel().SetTargets([Sdf.Path("/World/Camera")])
    product = UsdRender.Product.Define(stage, "/Render/Product")
    product.CreateDataWindowNDCAttr(Gf.Vec4f(0, 0, 1, 1))
    rs.CreateProductsRel().SetTargets([product.GetPath()])
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    return stage.GetRootLayer().ExportToString()


BASE = base_stage()

# ---- values -----------------------------------------------------------------------------------

SPECIAL_FLOATS = [math.nan, math.inf, -math.inf, 0.0, -0.0, 5e-324, 1e-45, 1.2e-38, 1e-30, 1e-7, 1e7, 65504.0, 65520.0,
                  3.4028234e38, 3.5e38, 1e300, -1.0, -1e-30, -3.4e38, 1.0, 0.5, 2.0, 0.53, 100.0, 1e15, 2.0 ** 31,
                  2.0 ** 63]
SPECIAL_INTS = [0, 1, -1, 2, 7, 8, 64, 100000, 100001, 2 ** 31 - 1, -2 ** 31, 2 ** 32 - 1, 2 ** 63 - 1]
INT_RANGES = {"int": (-2 ** 31, 2 ** 31 - 1), "int64": (-2 ** 63, 2 ** 63 - 1), "uint": (0, 2 ** 32 - 1),
              "uchar": (0, 255)}
VEC = {"float2": (Gf.Vec2f, 2), "float3": (Gf.Vec3f, 3), "float4": (Gf.Vec4f, 4), "double2": (Gf.Vec2d, 2),
       "double3": (Gf.Vec3d, 3), "color3f": (Gf.Vec3f, 3), "point3f": (Gf.Vec3f, 3), "vector3f": (Gf.Vec3f, 3),
       "normal3f": (Gf.Vec3f, 3), "texCoord2f": (Gf.Vec2f, 2), "int2": (Gf.Vec2i, 2), "half3": (Gf.Vec3h, 3)}
ARRAYS = {"float": Vt.FloatArray, "double": Vt.DoubleArray, "half": Vt.HalfArray, "int": Vt.IntArray,
          "int64": Vt.Int64Array, "uint": Vt.UIntArray, "uchar": Vt.UCharArray, "bool": Vt.BoolArray,
          "string": Vt.StringArray, "token": Vt.TokenArray, "float2": Vt.Vec2fArray, "float3": Vt.Vec3fArray,
          "float4": Vt.Vec4fArray, "color3f": Vt.Vec3fArray, "point3f": Vt.Vec3fArray, "vector3f": Vt.Vec3fArray,
          "normal3f": Vt.Vec3fArray, "texCoord2f": Vt.Vec2fArray, "double3": Vt.Vec3dArray, "int2": Vt.Vec2iArray,
          "quath": Vt.QuathArray, "quatf": Vt.QuatfArray}
# What a wrongly typed value may be instead.
OTHER_TYPES = ["double", "half", "int", "int64", "uint", "bool", "string", "token", "asset", "float2", "float3",
               "float4", "color3f", "int2", "matrix4d", "quatf", "float[]", "double[]", "int[]", "float3[]",
               "color3f[]", "texCoord2f[]", "string[]", "token[]", "float"]
TEXT = ["", "st", "uv", "repeat", "clamp", "black", "mirror", "useMetadata", "sRGB", "raw", "auto", "latlong",
        "invisible", "inherited", "guide", "proxy", "render", "leftHanded", "rightHanded", "perspective",
        "orthographic", "constant", "vertex", "faceVarying", "uniform", "varying", "UsdPreviewSurface",
        "UsdUVTexture", "UsdPrimvarReader_float2", "/World/Grains/A", "../Grains/B", "\u00e9\u00df", "a" * 300]


def number(fdp, lo, hi):
    """A float: a special value, any double, or one in the plausible [lo, hi]."""
    k = fdp.ConsumeIntInRange(0, 7)
    if k == 0:
        return fdp.PickValueInList(SPECIAL_FLOATS)
    if k == 1:
        return fdp.ConsumeRegularFloat()
    return fdp.ConsumeFloatInRange(lo, hi) if lo < hi else lo


def integer(fdp, base, lo, hi):
    tlo, thi = INT_RANGES.get(base, (-2 ** 31, 2 ** 31 - 1))
    if fdp.ConsumeIntInRange(0, 5) == 0:
        return min(max(fdp.PickValueInList(SPECIAL_INTS), tlo), thi)
    return fdp.ConsumeIntInRange(max(lo, tlo), min(hi, thi))


def text(fdp, choices):
    k = fdp.ConsumeIntInRange(0, 7)
    if k == 0:
        return fdp.ConsumeUnicodeNoSurrogates(fdp.ConsumeIntInRange(0, 24))
    if k == 1 or not choices:
        return fdp.PickValueInList(TEXT)
    return fdp.PickValueInList(choices)


def scalar(fdp, base, hint):
    lo, hi, choices = hint.get("lo", -1.0), hint.get("hi", 1.0), hint.get("choices", [])
    if base in ("float", "double", "half"):
        return number(fdp, lo, hi)
    if base in INT_RANGES:
        return integer(fdp, base, int(max(min(lo, 2 ** 31 - 1), -2 ** 31)), int(max(min(hi, 2 ** 31 - 1), -2 ** 31)))
    if base == "bool":
        return fdp.ConsumeBool()
    if base in ("string", "token"):
        return text(fdp, [c for c in choices if isinstance(c, str)])
    if base == "asset":
        return Sdf.AssetPath(fdp.PickValueInList(ASSETS) if fdp.ConsumeIntInRange(0, 7) else text(fdp, []))
    if base in VEC:
        cls, n = VEC[base]
        if base == "int2":
            return cls(*(integer(fdp, "int", int(lo), int(hi)) for _ in range(n)))
        return cls(*(number(fdp, lo, hi) for _ in range(n)))
    if base == "matrix4d":
        if fdp.ConsumeBool():  # an affine matrix of plausible rotation, scale and translation
            m = Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(number(fdp, 0, 1), 1, 0), number(fdp, -180, 180)))
            m.SetTranslateOnly(Gf.Vec3d(*(number(fdp, -3, 3) for _ in range(3))))
            return m
        return Gf.Matrix4d(*(number(fdp, -2, 2) for _ in range(16)))
    if base in ("quatf", "quath", "quatd"):
        cls = {"quatf": Gf.Quatf, "quath": Gf.Quath, "quatd": Gf.Quatd}[base]
        return cls(number(fdp, -1, 1), *(number(fdp, -1, 1) for _ in range(3)))
    raise ValueError(base)


def value(fdp, type_name, hint):
    """A value of Sdf type `type_name`; arrays of the hint's natural length or not."""
    if not type_name.endswith("[]"):
        return scalar(fdp, type_name, hint)
    base = type_name[:-2]
    n = hint.get("len", 2)
    k = fdp.ConsumeIntInRange(0, 5)
    if k == 0:
        n = fdp.ConsumeIntInRange(0, 9)
    elif k == 1:
        n = max(0, n + fdp.ConsumeIntInRange(-2, 2))
    if base == "asset":
        return Sdf.AssetPathArray([scalar(fdp, "asset", hint) for _ in range(n)])
    if k == 2 and "base" in hint:  # the natural value with one element changed
        items = list(hint["base"])
        if items:
            items[fdp.ConsumeIntInRange(0, len(items) - 1)] = scalar(fdp, base, hint)
        return ARRAYS[base](items)
    return ARRAYS[base]([scalar(fdp, base, hint) for _ in range(n)])


TIMES = [1.0, 2.0, 1.5, 0.0, -1.0, 3.0, 1e9, -1e9, 1e-9, 1.0000001]


class Skip(Exception):
    """The mutation could not be authored (usd-core refused it): not a finding."""


def author(stage, path, name, type_name, fdp, hint):
    """Sets attribute `name` of the prim at `path` in the root layer: its own type most of
    the time, else another one; a default, time samples, both, or a block."""
    layer = stage.GetRootLayer()
    spec = layer.GetPrimAtPath(path)
    if spec is None:
        raise Skip(f"no prim {path}")
    if fdp.ConsumeIntInRange(0, 7) == 0:
        type_name = fdp.PickValueInList(OTHER_TYPES)
    tn = Sdf.ValueTypeNames.Find(type_name)
    attr = spec.attributes.get(name)
    if attr is not None and attr.typeName != tn:
        spec.RemoveProperty(attr)
        attr = None
    if attr is None:
        attr = Sdf.AttributeSpec(spec, name, tn)
        if not attr:
            raise Skip(f"cannot create {path}.{name}")
    mode = fdp.ConsumeIntInRange(0, 9)
    if mode <= 5 or mode == 8:
        attr.default = value(fdp, type_name, hint)
    if mode in (6, 7, 8):
        if mode == 6:  # replace the samples; 7 and 8 add to them
            attr.ClearInfo("timeSamples")
        for _ in range(fdp.ConsumeIntInRange(1, 3)):
            layer.SetTimeSample(attr.path, fdp.PickValueInList(TIMES), value(fdp, type_name, hint))
    if mode == 9:
        attr.default = Sdf.ValueBlock()
    return f"{path}.{name} ({type_name}, mode {mode})"


# ---- the schema's attributes --------------------------------------------------------------------

def H(lo=-1.0, hi=1.0, **kw):
    kw.update(lo=lo, hi=hi)
    return kw


LIGHTS = ["/World/Sun", "/World/Sky", "/World/Panel", "/World/Bulb"]
CAMERAS = ["/World/Camera", "/World/Camera2"]
SURFACES = ["/World/Looks/Plain/Surface", "/World/Looks/Glass/Surface", "/World/Looks/Textured/Surface"]
TEXTURE = "/World/Looks/Textured/Tex"
READER = "/World/Looks/Textured/St"
PROTOTYPE_PATHS = ["../Grains/A", "../Grains/B", "../Grains/C", "/World/Grains/A", "/World/Grains/B", "Grains/A",
                   "../Castle", ".", "/World/Ball", "/World/Block", "/World/Camera", "/World/Grains", "/Nope",
                   "../Grains/A.primvars:x", "<bad>", "", "/World/Grains/A/", "../../../..", "/World/Lamp"]

ATTRS = []
for _l in LIGHTS:
    ATTRS += [(_l, "inputs:intensity", "float", H(0, 20)), (_l, "inputs:exposure", "float", H(-5, 5)),
              (_l, "inputs:color", "color3f", H(0, 1)), (_l, "inputs:colorTemperature", "float", H(1000, 20000)),
              (_l, "inputs:enableColorTemperature", "bool", H()), (_l, "inputs:normalize", "bool", H()),
              (_l, "inputs:shadow:enable", "bool", H())]
ATTRS += [("/World/Sun", "inputs:angle", "float", H(0, 10)), ("/World/Sky", "inputs:texture:file", "asset", H()),
          ("/World/Sky", "inputs:texture:format", "token",
           H(choices=["automatic", "latlong", "mirroredBall", "angular", "cubeMapVerticalCross"])),
          ("/World/Panel", "inputs:width", "float", H(0, 2)), ("/World/Panel", "inputs:height", "float", H(0, 2)),
          ("/World/Panel", "inputs:texture:file", "asset", H()), ("/World/Bulb", "inputs:radius", "float", H(0, 0.5)),
          ("/World/Bulb", "treatAsPoint", "bool", H()), ("/World/Sun", "inputs:radius", "float", H(0, 1)),
          ("/World/Sun", "collection:lightLink:includeRoot", "bool", H()),
          ("/World/Panel", "collection:lightLink:includeRoot", "bool", H()),
          ("/World/Sun", "collection:lightLink:expansionRule", "token",
           H(choices=["expandPrims", "explicitOnly", "expandPrimsAndProperties", "bogus"]))]
for _c in CAMERAS:
    ATTRS += [(_c, "focalLength", "float", H(1, 100)), (_c, "horizontalAperture", "float", H(1, 50)),
              (_c, "verticalAperture", "float", H(1, 50)), (_c, "horizontalApertureOffset", "float", H(-5, 5)),
              (_c, "verticalApertureOffset", "float", H(-5, 5)), (_c, "clippingRange", "float2", H(0.001, 100)),
              (_c, "fStop", "float", H(0, 32)), (_c, "focusDistance", "float", H(0, 10)),
              (_c, "projection", "token", H(choices=["perspective", "orthographic"]))]
for _s in SURFACES:
    ATTRS += [(_s, "inputs:diffuseColor", "color3f", H(0, 1)), (_s, "inputs:emissiveColor", "color3f", H(0, 5)),
              (_s, "inputs:opacity", "float", H(0, 1)), (_s, "inputs:opacityThreshold", "float", H(0, 1)),
              (_s, "inputs:ior", "float", H(1, 3)),
              (_s, "info:id", "token", H(choices=["UsdPreviewSurface", "UsdUVTexture", "ND_standard_surface"]))]
ATTRS += [(TEXTURE, "inputs:file", "asset", H()),
          (TEXTURE, "inputs:wrapS", "token", H(choices=["useMetadata", "black", "clamp", "repeat", "mirror"])),
          (TEXTURE, "inputs:wrapT", "token", H(choices=["useMetadata", "black", "clamp", "repeat", "mirror"])),
          (TEXTURE, "inputs:scale", "float4", H(-2, 2)), (TEXTURE, "inputs:bias", "float4", H(-1, 1)),
          (TEXTURE, "inputs:sourceColorSpace", "token", H(choices=["auto", "raw", "sRGB"])),
          (TEXTURE, "inputs:fallback", "float4", H(0, 1)),
          (TEXTURE, "info:id", "token", H(choices=["UsdUVTexture", "UsdPrimvarReader_float2", "UsdTransform2d"])),
          (READER, "inputs:varname", "token", H(choices=["st", "uv", "displayColor", "primvars:st", "points"])),
          (READER, "inputs:varname", "string", H(choices=["st", "uv"])),
          (READER, "info:id", "token", H(choices=["UsdPrimvarReader_float2", "UsdTransform2d", "UsdPrimvarReader_float"]))]
GROUND_ST = [(0, 0), (0.5, 0), (1, 0), (0, 1), (0.5, 1), (1, 1)]
ATTRS += [("/World/Ground", "points", "point3f[]", H(-2, 2, len=6)),
          ("/World/Ground", "faceVertexCounts", "int[]", H(0, 5, len=2, base=[4, 4])),
          ("/World/Ground", "faceVertexIndices", "int[]", H(-1, 7, len=8, base=[0, 1, 4, 3, 1, 2, 5, 4])),
          ("/World/Ground", "orientation", "token", H(choices=["leftHanded", "rightHanded"])),
          ("/World/Ground", "primvars:st", "texCoord2f[]", H(-2, 2, len=6, base=[Gf.Vec2f(*p) for p in GROUND_ST])),
          ("/World/Ground", "primvars:st:indices", "int[]", H(-1, 7, len=6)),
          ("/World/Ground", "primvars:uv", "float2[]", H(-2, 2, len=8)),
          ("/World/Castle", "points", "point3f[]", H(-0.5, 0.5, len=8)),
          ("/World/Castle", "faceVertexIndices", "int[]", H(-1, 9, len=36)),
          ("/World/Castle", "faceVertexCounts", "int[]", H(0, 4, len=12)),
          ("/World/Castle", "orientation", "token", H(choices=["leftHanded", "rightHanded"])),
          ("/World/Grains/A", "points", "point3f[]", H(-1, 1, len=12)),
          ("/World/Grains/B", "faceVertexCounts", "int[]", H(0, 4, len=3)),
          ("/World/Lamp", "points", "point3f[]", H(-1, 1, len=8)),
          ("/World/Block", "size", "double", H(0, 0.5)), ("/World/Ball", "radius", "double", H(0, 0.5)),
          ("/World/Block", "primvars:displayColor", "color3f[]", H(0, 1, len=1)),
          ("/World/Ball", "primvars:displayColor", "color3f[]", H(0, 1, len=1)),
          ("/World", "primvars:displayColor", "color3f[]", H(0, 1, len=1)),
          ("/World/Instancer", "positions", "point3f[]", H(-1, 1, len=1)),
          ("/World/Instancer", "protoIndices", "int[]", H(-1, 2, len=1)),
          ("/World/Instancer", "orientations", "quath[]", H(-1, 1, len=1)),
          ("/World/Pillar", "radius", "double", H(0, 1)),
          ("/Render/Settings", "resolution", "int2", H(1, 16)),
          ("/Render/Settings", "dataWindowNDC", "float4", H(-0.5, 1.5)),
          ("/Render/Settings", "pixelAspectRatio", "float", H(0.5, 2)),
          ("/Render/Product", "dataWindowNDC", "float4", H(-0.5, 1.5)),
          ("/Render/Product", "resolution", "int2", H(1, 16))]
for _p in ["/World", "/World/Castle", "/World/Ground", "/World/Ball", "/World/Grains/A", "/World/Camera", "/World/Sun",
           "/World/Grains", "/World/Lamp", "/World/Instancer"]:
    ATTRS += [(_p, "visibility", "token", H(choices=["inherited", "invisible"])),
              (_p, "purpose", "token", H(choices=["default", "render", "proxy", "guide"]))]
AGGREGATE_PRIMVARS = [("grainRadius", "float", H(0.02, 0.2)), ("packingRate", "float", H(0.05, 0.64)),
                      ("prototypes", "string[]", H(choices=PROTOTYPE_PATHS, len=2)),
                      ("weights", "float[]", H(0, 1, len=2)), ("seed", "int", H(0, 10)),
                      ("tileSpheres", "int", H(8, 64)), ("sizes", "float[]", H(0.5, 2, len=2)),
                      ("sizeSpread", "float", H(0, 0.5))]
GRAIN_PRIMVARS = [("ior", "float", H(1, 4)), ("absorption", "color3f", H(0, 2)), ("roughness", "float", H(0, 1))]
for _base, _t, _h in AGGREGATE_PRIMVARS:
    ATTRS += [("/World/Castle", "primvars:granular:" + _base, _t, _h), ("/World", "primvars:granular:" + _base, _t, _h)]
for _base, _t, _h in GRAIN_PRIMVARS:
    for _p in ["/World/Grains/A", "/World/Grains/B", "/World/Grains/C", "/World/Grains"]:
        ATTRS.append((_p, "primvars:granular:" + _base, _t, _h))
ATTRS.append(("/World/Castle", "primvars:granular:ior", "float", H(1, 2)))  # a grain value on an aggregate

PRIMS = ["/World", "/World/Castle", "/World/Grains", "/World/Grains/A", "/World/Grains/B", "/World/Grains/C",
         "/World/Ground", "/World/Ball", "/World/Block", "/World/Lamp", "/World/Pillar", "/World/Instancer",
         "/World/Camera", "/World/Camera2", "/World/Sun", "/World/Sky", "/World/Panel", "/World/Bulb", "/World/Looks",
         "/World/Looks/Textured", "/World/Looks/Textured/Tex", "/World/Looks/Textured/St", "/Render/Settings",
         "/Render/Product"]
XFORM_PRIMS = ["/World", "/World/Castle", "/World/Ground", "/World/Ball", "/World/Block", "/World/Camera",
               "/World/Camera2", "/World/Sun", "/World/Sky", "/World/Panel", "/World/Bulb", "/World/Grains/A",
               "/World/Grains"]
OPS = [("xformOp:translate", "double3", H(-3, 3)), ("xformOp:translate:extra", "float3", H(-3, 3)),
       ("xformOp:rotateXYZ", "float3", H(-360, 360)), ("xformOp:rotateX", "float", H(-360, 360)),
       ("xformOp:scale", "float3", H(-2, 2)), ("xformOp:transform", "matrix4d", H()),
       ("xformOp:orient", "quatf", H(-1, 1))]
OP_ORDER = ["xformOp:translate", "xformOp:translate:extra", "xformOp:rotateXYZ", "xformOp:rotateX", "xformOp:scale",
            "xformOp:transform", "xformOp:orient", "!resetXformStack!", "!invert!xformOp:translate",
            "!invert!xformOp:scale", "xformOp:missing", "xformOp:bogus:op", "points"]
PRIMVARS = [("/World/Ground", "primvars:st"), ("/World/Castle", "primvars:granular:grainRadius"),
            ("/World/Castle", "primvars:granular:prototypes"), ("/World/Castle", "primvars:granular:weights"),
            ("/World/Grains/A", "primvars:granular:ior"), ("/World/Grains/A", "primvars:granular:absorption"),
            ("/World/Block", "primvars:displayColor")]
INTERPOLATIONS = ["constant", "uniform", "vertex", "varying", "faceVarying", "bogus", ""]
INPUTS = [("/World/Looks/Textured/Surface", "inputs:diffuseColor", "color3f"),
          ("/World/Looks/Textured/Surface", "inputs:emissiveColor", "color3f"),
          ("/World/Looks/Textured/Surface", "inputs:opacity", "float"),
          ("/World/Looks/Textured/Surface", "inputs:ior", "float"),
          ("/World/Looks/Plain/Surface", "inputs:diffuseColor", "color3f"),
          ("/World/Looks/Glass/Surface", "inputs:opacity", "float"),
          (TEXTURE, "inputs:st", "float2"), (TEXTURE, "inputs:file", "asset"), (READER, "inputs:in", "float2"),
          ("/World/Looks/Textured", "outputs:surface", "token"), ("/World/Looks/Glass", "outputs:surface", "token")]
SOURCES = [TEXTURE + ".outputs:rgb", TEXTURE + ".outputs:r", TEXTURE + ".outputs:g", TEXTURE + ".outputs:a",
           TEXTURE + ".outputs:bogus", READER + ".outputs:result", "/World/Looks/Textured/Surface.outputs:surface",
           "/World/Looks/Plain/Surface.outputs:surface", "/World/Looks/Textured.inputs:color",
           "/World/Looks/Textured/Surface.inputs:diffuseColor", TEXTURE + ".inputs:st", "/Nope.outputs:x",
           "/World/Camera.outputs:x", "/World/Looks/Glass/Surface.outputs:surface"]
RELS = [("/World/Castle", "material:binding"), ("/World/Ground", "material:binding"), ("/World/Ball", "material:binding"),
        ("/World/Block", "material:binding"), ("/World/Grains/C", "material:binding"), ("/World", "material:binding"),
        ("/World/Grains/A", "material:binding"), ("/Render/Settings", "camera"), ("/Render/Settings", "products"),
        ("/Render/Product", "camera"), ("/World/Instancer", "prototypes"),
        # light linking: the collections' includes and excludes, on lights and elsewhere
        ("/World/Sun", "collection:lightLink:excludes"), ("/World/Panel", "collection:lightLink:includes"),
        ("/World/Bulb", "collection:shadowLink:excludes"), ("/World/Castle", "collection:lightLink:includes")]
TARGETS = ["/World/Looks/Plain", "/World/Looks/Glass", "/World/Looks/Textured", "/World/Camera", "/World/Camera2",
           "/World/Sun", "/Render/Product", "/Render/Settings", "/Nope", "/World/Camera.focalLength",
           "/World/Looks/Textured/Surface", "/World/Castle", "/World/Ground", "/World", "/"]
TYPES = ["Mesh", "Cube", "Sphere", "Cylinder", "Cone", "Capsule", "Xform", "Scope", "Camera", "DistantLight",
         "DomeLight", "DomeLight_1", "RectLight", "SphereLight", "DiskLight", "CylinderLight", "PointInstancer",
         "RenderSettings", "RenderProduct", "Material", "Shader", "", "NoSuchType"]
API_SCHEMAS = ["GranularAggregateAPI", "GranularGrainAPI", "MaterialBindingAPI", "LightAPI", "ShadowAPI",
               "NoSuchAPI", "CollectionAPI:x"]
RENDER_SETTINGS_PATHS = ["/Render/Settings", "/Render/Product", "/Nope", "", "/World/Camera", "Render/Settings"]


def m_attr(stage, fdp):
    path, name, type_name, hint = fdp.PickValueInList(ATTRS)
    return author(stage, path, name, type_name, fdp, hint)


def m_xform(stage, fdp):
    path = fdp.PickValueInList(XFORM_PRIMS)
    name, type_name, hint = fdp.PickValueInList(OPS)
    what = author(stage, path, name, type_name, fdp, hint)
    prim = stage.GetPrimAtPath(path)
    if not prim:  # not composed (an ancestor made inactive, m_active): the op's spec alone
        return what
    order = list(prim.GetAttribute("xformOpOrder").Get() or [])
    k = fdp.ConsumeIntInRange(0, 3)
    if k == 0:
        order.append(name)
    elif k == 1:
        order = [fdp.PickValueInList(OP_ORDER) for _ in range(fdp.ConsumeIntInRange(0, 4))]
    elif k == 2:
        order.insert(0, name)
    attr = prim.GetAttribute("xformOpOrder")
    if not attr:
        attr = prim.CreateAttribute("xformOpOrder", Sdf.ValueTypeNames.TokenArray, custom=False)
    attr.Set(Vt.TokenArray(order))
    return f"{what}; xformOpOrder {order}"


def _prim_spec(stage, path):
    """The root layer's spec of path; Skip when a mutation before removed it."""
    spec = stage.GetRootLayer().GetPrimAtPath(path)
    if spec is None:
        raise Skip(f"no {path}")
    return spec


def m_interpolation(stage, fdp):
    path, name = fdp.PickValueInList(PRIMVARS)
    spec = stage.GetRootLayer().GetPrimAtPath(path)
    attr = spec.attributes.get(name) if spec else None
    if not attr:
        raise Skip(f"no {path}.{name}")
    interp = fdp.PickValueInList(INTERPOLATIONS)
    attr.SetInfo("interpolation", interp)
    return f"{path}.{name} interpolation {interp!r}"


def m_connection(stage, fdp):
    path, name, type_name = fdp.PickValueInList(INPUTS)
    spec = _prim_spec(stage, path)
    attr = spec.attributes.get(name)
    if not attr:
        attr = Sdf.AttributeSpec(spec, name, Sdf.ValueTypeNames.Find(type_name))
    sources = [Sdf.Path(fdp.PickValueInList(SOURCES)) for _ in range(fdp.ConsumeIntInRange(0, 2))]
    if fdp.ConsumeIntInRange(0, 5) == 0:
        sources = [attr.path]  # a cycle
    attr.connectionPathList.explicitItems = sources
    return f"{path}.{name} connected to {[str(s) for s in sources]}"


def m_relationship(stage, fdp):
    path, name = fdp.PickValueInList(RELS)
    spec = _prim_spec(stage, path)
    rel = spec.relationships.get(name)
    if not rel:
        rel = Sdf.RelationshipSpec(spec, name, custom=False)
    targets = [Sdf.Path(fdp.PickValueInList(TARGETS)) for _ in range(fdp.ConsumeIntInRange(0, 2))]
    rel.targetPathList.explicitItems = targets
    return f"{path}.{name} -> {[str(t) for t in targets]}"


def m_type(stage, fdp):
    path = fdp.PickValueInList(PRIMS)
    spec = _prim_spec(stage, path)
    spec.typeName = fdp.PickValueInList(TYPES)
    return f"{path} type {spec.typeName!r}"


def m_active(stage, fdp):
    path = fdp.PickValueInList(PRIMS)
    spec = _prim_spec(stage, path)
    spec.active = fdp.ConsumeBool()
    return f"{path} active {spec.active}"


def m_api(stage, fdp):
    path = fdp.PickValueInList(PRIMS)
    spec = _prim_spec(stage, path)
    apis = [fdp.PickValueInList(API_SCHEMAS) for _ in range(fdp.ConsumeIntInRange(0, 3))]
    spec.SetInfo("apiSchemas", Sdf.TokenListOp.Create(prependedItems=apis))
    return f"{path} apiSchemas {apis}"


def m_remove(stage, fdp):
    path = fdp.PickValueInList(PRIMS)
    stage.RemovePrim(path)
    return f"{path} removed"


def m_copy(stage, fdp):
    """An internal reference to a prim, instanceable or not: instance proxies, and the
    same prim paths (prototypes, materials) seen from another place."""
    source = fdp.PickValueInList(["/World/Castle", "/World/Grains", "/World/Ground", "/World/Ball", "/World/Sun",
                                  "/World/Camera", "/World/Looks", "/World", "/World/Lamp"])
    path = f"/World/Copy{fdp.ConsumeIntInRange(0, 2)}"
    prim = stage.DefinePrim(path, "Xform")
    prim.GetReferences().AddInternalReference(source)
    prim.SetInstanceable(fdp.ConsumeBool())
    UsdGeom.Xformable(prim).AddTranslateOp(opSuffix="copy").Set(Gf.Vec3d(*(number(fdp, -1, 1) for _ in range(3))))
    return f"{path} references {source}, instanceable {prim.IsInstanceable()}"


def m_stage(stage, fdp):
    k = fdp.ConsumeIntInRange(0, 3)
    if k == 0:
        stage.SetStartTimeCode(fdp.PickValueInList(TIMES + [math.nan, math.inf]))
        stage.SetEndTimeCode(fdp.PickValueInList(TIMES + [math.inf]))
        return f"time codes {stage.GetStartTimeCode()}:{stage.GetEndTimeCode()}"
    if k == 1:
        p = fdp.PickValueInList(RENDER_SETTINGS_PATHS)
        stage.SetMetadata("renderSettingsPrimPath", p)
        return f"renderSettingsPrimPath {p!r}"
    if k == 2:
        stage.SetMetadata("metersPerUnit", number(fdp, 0.001, 10))
        return "metersPerUnit"
    stage.SetMetadata("upAxis", fdp.PickValueInList(["Y", "Z", "X"]))
    return "upAxis"


MUTATIONS = [m_attr] * 12 + [m_xform] * 2 + [m_interpolation, m_connection, m_relationship, m_type, m_active, m_api,
                                              m_remove, m_copy, m_stage]

# ---- the command line -----------------------------------------------------------------------------


def rare(fdp, n):
    """True once in n (never for exhausted input: no bytes, the plain command)."""
    return fdp.ConsumeIntInRange(0, n - 1) == n - 1


def command_line(fdp, out):
    """`granular render` options from the input; always 1 spp on one thread."""
    argv = ["render", SCENE, "--spp", "1", "--threads", "1"]
    frames = rare(fdp, 8)
    if frames:
        argv += ["--frames", fdp.PickValueInList(["1:2", "0:1x0.5", "1", "2:3", "-1:1", "1:2x0.25"])]
    argv += ["-o", os.path.join(out, "out.####.exr" if frames else "out.exr")]
    if rare(fdp, 4):
        argv += ["--png", os.path.join(out, "out.####.png" if frames else "out.png")]
    argv += ["--technique", fdp.PickValueInList(["ept"] * 5 + ["hybrid"] * 2 + ["ept+vpt"])]
    size = fdp.ConsumeIntInRange(0, 9)
    if size <= 5:
        argv += ["--width", "8", "--height", "6"]
    elif size == 7:
        argv += ["--width", "8"]
    elif size == 8:
        argv += ["--height", "6"]
    # 6, 9: the render settings' resolution (else 640x480, which the cost bound skips)
    cam = fdp.ConsumeIntInRange(0, 9)
    if cam == 8:
        argv += ["--camera", "/World/Camera2"]
    elif cam == 9:
        argv += ["--camera", fdp.PickValueInList(["/World/Camera", "/World/Sun", "/Nope", "World/Camera",
                                                  "/World/Camera.focalLength", "/World/Copy0/Camera"])]
    if rare(fdp, 8):
        argv += ["--crop", fdp.PickValueInList(["0:4,0:3", "2:8,1:6", "7:8,5:6", "0:16,0:12"])]
    if rare(fdp, 4):
        argv += ["--lod", fdp.PickValueInList(["0", "2", "1e30"])]
    if rare(fdp, 6):
        argv += ["--roulette", fdp.PickValueInList(["0.5", "1", "1e-30"])]
    if rare(fdp, 4):
        argv.append("--no-physical-sun")
    if rare(fdp, 4):
        argv.append("--no-default-light")
    if rare(fdp, 4):
        argv += ["--exposure", fdp.PickValueInList(["-3", "10", "1000"])]
    if fdp.ConsumeBool():
        argv += ["--seed", str(fdp.ConsumeIntInRange(0, 3))]
    if fdp.ConsumeBool():
        argv.append("--quiet")
    return argv


# ---- the render path, with costs bounded ----------------------------------------------------------

class TooCostly(Exception):
    """A valid scene beyond the fuzzing budget: skipped, not a finding."""


_current = {}
_read_stage, _build_scene, _render_image, _open_stage = (usd_reader.read_stage, api.build_scene, cli._render_image,
                                                         usd_reader.open_stage)


def _fuzz_open_stage(path):
    return _current["stage"] if path == SCENE else _open_stage(path)


def _pixels(s):
    x0, x1, y0, y1 = s.crop
    return (x1 - x0) * (y1 - y0) if (x0, x1, y0, y1) != (0, 0, 0, 0) else s.width * s.height


def _bounded_read_stage(*a, **kw):
    scene = _read_stage(*a, **kw)
    if _pixels(scene.desc.settings) > MAX_PIXELS:
        usd_reader.validate(scene)
        raise TooCostly(f"{scene.desc.settings.width}x{scene.desc.settings.height} pixels")
    return scene


def _cells(a):
    """Aggregate::build's cell count, bounded above (as fuzz_common.h's estimatedCells; the
    smallest grains give the smallest tile, the largest the widest margin)."""
    r_tile = (3.0 * a.packing_rate / (4.0 * math.pi * a.tile_spheres)) ** (1.0 / 3.0)
    sizes = list(a.sizes) or [1.0]
    edge = a.grain_radius * min(sizes) * (1.0 - a.size_spread) / r_tile
    margin = 2.0 * a.grain_radius * max(sizes) * (1.0 + a.size_spread)
    b = a.boundary.transformed(a.xf).bounds()
    cells = 1.0
    for k in range(3):
        cells *= math.ceil((b["hi"][k] - b["lo"][k] + margin) / edge)
    return cells


def _bounded_build_scene(scene, previous=None, log=None):
    usd_reader.validate(scene)  # the values as read, before any cost decision
    d = scene.desc
    triangles = sum(m.mesh.num_triangles for m in d.meshes)
    for a in d.aggregates:
        triangles += a.boundary.num_triangles + sum(p.mesh.num_triangles for p in a.prototypes)
        if a.tile_spheres > MAX_TILE_SPHERES:
            raise TooCostly(f"{a.name}: {a.tile_spheres} tile spheres")
        cells = _cells(a)
        if not cells <= MAX_CELLS:
            raise TooCostly(f"{a.name}: ~{cells:.3g} cells")
    if triangles > MAX_TRIANGLES:
        raise TooCostly(f"{triangles} triangles")
    if _pixels(d.settings) > MAX_PIXELS:
        raise TooCostly("pixels")
    return _build_scene(scene, previous, log=log)


def _checked_render_image(args, built):
    renderer, image = _render_image(args, built)
    px = np.asarray(image.pixels)
    for k, name in enumerate(image.channels):
        c = px[..., k]
        bad = np.isnan(c) if name == "Z" else ~np.isfinite(c)
        if bad.any():
            y, x = np.argwhere(bad)[0]
            raise AssertionError(f"non-finite pixel: channel {name} at ({x}, {y}) is {c[y, x]}")
    _current["rendered"] += 1
    return renderer, image


class _QuietProgress(cli.Progress):
    """The progress bar on the stderr of the moment (the harness's sink), not the one
    Progress bound when it was defined."""

    def __init__(self, enabled, stream=None, unit="spp"):
        super().__init__(enabled, sys.stderr, unit)


usd_reader.open_stage = _fuzz_open_stage
usd_reader.read_stage = _bounded_read_stage
api.build_scene = _bounded_build_scene
cli._render_image = _checked_render_image
cli.Progress = _QuietProgress

PARSER = cli.build_parser()
STATS = {"inputs": 0, "rendered": 0, "refused": 0, "too costly": 0, "mutations": 0, "not authored": 0}
_last_stats = [time.monotonic()]


def _stats():
    now = time.monotonic()
    if now - _last_stats[0] > 30:
        _last_stats[0] = now
        print("fuzz_usd_stage: " + ", ".join(f"{k} {v}" for k, v in STATS.items()), file=sys.stderr, flush=True)


def dump(stage, argv, out):
    """The input as a .usda that replays by itself (usda_input): the stage, with the command's
    options in its customLayerData and the fuzzer's folders as {work} and {out}."""
    layer = Sdf.Layer.CreateAnonymous(".usda")
    layer.TransferContent(stage.GetRootLayer())
    data = dict(layer.customLayerData)
    data["fuzzArgs"] = " ".join(argv[2:])
    layer.customLayerData = data
    text = layer.ExportToString().replace(out, "{out}").replace(WORK, "{work}")
    with open(os.path.join(DUMP, f"input{STATS['inputs']}.usda"), "w") as f:
        f.write(text)


def usda_input(data, out):
    """An input that is a .usda (a regression in fuzz/regressions/, or what the fuzzer makes
    of one): (stage, argv), the options from customLayerData's fuzzArgs (default: 8x6, EPT);
    (None, None) when usd-core cannot read it."""
    text = data.decode("utf-8", "replace").replace("{work}", WORK).replace("{out}", out)
    stage = Usd.Stage.CreateInMemory()
    try:
        ok = stage.GetRootLayer().ImportFromString(text)
        args = stage.GetRootLayer().customLayerData.get("fuzzArgs")
    except Tf.ErrorException:
        ok = False
    if not ok:
        STATS["not authored"] += 1
        log("not a stage usd-core reads")
        return None, None
    if not isinstance(args, str):
        args = f"--spp 1 --threads 1 -o {out}/out.exr --width 8 --height 6 --technique ept"
    return stage, ["render", SCENE] + args.replace("{out}", out).split()


def TestOneInput(data):
    fdp = atheris.FuzzedDataProvider(data)
    STATS["inputs"] += 1
    out = tempfile.mkdtemp(dir=WORK)
    try:
        if data.startswith(b"#usda"):
            stage, argv = usda_input(data, out)
            if stage is None:
                return
        else:
            argv = command_line(fdp, out)
            stage = Usd.Stage.CreateInMemory()
            stage.GetRootLayer().ImportFromString(BASE)
            done = []
            for _ in range(fdp.ConsumeIntInRange(0, 16)):
                if fdp.remaining_bytes() == 0:
                    break
                mutate = fdp.PickValueInList(MUTATIONS)
                STATS["mutations"] += 1
                try:
                    done.append(mutate(stage, fdp))
                except (Skip, Tf.ErrorException, ValueError, OverflowError, TypeError) as e:
                    STATS["not authored"] += 1
                    log(f"  not authored ({mutate.__name__}): {type(e).__name__}: {' '.join(str(e).split())[:200]}")
            log("mutations:", *(f"\n  {d}" for d in done))
        log("argv:", " ".join(argv))
        if DUMP:
            dump(stage, argv, out)
        _current.update(stage=stage, rendered=0)
        stderr = sys.stderr
        if not VERBOSE:
            sys.stderr = io.StringIO()  # the command's log and warnings
        try:
            args = PARSER.parse_args(argv)
            cli.cmd_render(args)
            log(f"rendered {_current['rendered']} image(s)")
        except TooCostly as e:
            STATS["too costly"] += 1
            log("too costly:", e)
        except (UserError, core.InputError) as e:
            STATS["refused"] += 1
            log("refused:", e)
        finally:
            sys.stderr = stderr
        STATS["rendered"] += _current["rendered"] > 0
    finally:
        _current.clear()
        for name in os.listdir(out):
            os.remove(os.path.join(out, name))
        os.rmdir(out)
        _stats()


def main():
    atheris.Setup(sys.argv, TestOneInput)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
