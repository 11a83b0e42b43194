"""Reads a USD stage (usd-core) into core's plain SceneDesc.

What is read, at one time code: the caller's (read_stage's `time`, e.g. each frame of
`granular render --frames`), else the stage's start time code (or, without an authored
range, the earliest time sample). Every time-varying value is read at that time:
transforms, points, visibility, camera and light attributes, material inputs, displayColor,
the granular primvars and the render settings' resolution.
- UsdGeomMesh prims (polygons triangulated by fans, world transforms, orientation),
  UsdGeomCube and UsdGeomSphere (tessellated), skipping invisible prims and the guide and
  proxy purposes;
- the granular schema: each mesh is handed to core (assemble_granular_scene, shared with
  the Hydra delegate) with its granular primvars, applied API schemas and bound material,
  and core decides what is an aggregate, a prototype or ordinary geometry; prototypes that
  are not drawn (invisible) are read when core asks for them;
- one UsdGeomCamera (--camera, else the render settings' camera, else the first one);
- UsdLux distant (angle), dome (lat-long texture file), rect and sphere lights with
  intensity, exposure, color, color temperature and normalize;
- a UsdPreviewSurface subset: diffuseColor -> Lambert, opacity < 1 -> dielectric of
  inputs:ior, emissiveColor -> emission; without a material, displayColor -> Lambert;
  diffuseColor, emissiveColor and opacity connected to a UsdUVTexture (file, wrapS/T,
  scale, bias, sourceColorSpace, st from a UsdPrimvarReader_float2's primvar of any
  interpolation) -> core textures; a textured opacity or an opacityThreshold > 0 makes a
  Lambert cut-out instead of glass;
- the render settings prim's resolution and camera, and its first product's
  dataWindowNDC (a crop).
Every problem a user can cause raises UserError naming the prim and the attribute;
`translate_core_error` turns core's InputError (named after SceneDesc fields) into the same.
"""
import math
import os
import re

import numpy as np
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade

import granular_core as core

from . import schema
from .errors import UserError

DEFAULT_WIDTH, DEFAULT_HEIGHT = 640, 480

# UsdPreviewSurface fallbacks (its specification).
_PREVIEW_DEFAULTS = {"diffuseColor": (0.18, 0.18, 0.18), "emissiveColor": (0.0, 0.0, 0.0), "opacity": 1.0,
                     "opacityThreshold": 0.0, "ior": 1.5}


class StageScene:
    """A stage read into a SceneDesc, with what is needed to report errors in USD terms."""

    def __init__(self, path, stage, time):
        self.path = path
        self.stage = stage
        self.time = time
        self.desc = core.SceneDesc()
        self.camera_path = None
        self.aggregates = []     # per desc.aggregates entry: {"prim", "world_boundary", "prototypes"}
        self.warnings = []
        self.material_st = {}    # material index -> the primvar its textures read (None: none)
        # core object name -> {core attribute: (prim path, USD attribute)}, "*": prim path
        self.names = {}

    def warn(self, message):
        if message not in self.warnings:
            self.warnings.append(message)

    def name(self, obj, prim_path, attrs):
        entry = {"*": (str(prim_path), "")}
        entry.update(attrs)
        self.names[obj] = entry


def translate_core_error(err, scene=None):
    """core.InputError (object/attribute in SceneDesc terms) -> UserError in USD terms."""
    obj, attr, detail = getattr(err, "object", ""), getattr(err, "attribute", ""), getattr(err, "detail", str(err))
    if scene is not None and obj in scene.names:
        entry = scene.names[obj]
        if attr in entry:
            prim, usd_attr = entry[attr]
            return UserError(prim, usd_attr, detail)
        return UserError(entry["*"][0], attr, detail)
    return UserError(obj, attr, detail)


def describe_tf_error(e):
    """The messages of a Tf.ErrorException on one line (without source locations)."""
    msgs = []
    for line in str(e).splitlines():
        line = line.strip()
        if not line:
            continue
        # "Error in 'Func' at line N in file F : 'message'"
        if " : '" in line:
            line = line.split(" : '", 1)[1].rstrip("'")
        msgs.append(re.sub(r"pxrInternal_v\w+?__pxrReserved__::", "", line))
    return " ".join(msgs[:1]) if msgs else str(e).strip()


def open_stage(path):
    if not os.path.exists(path):
        raise UserError(path, "", "no such file")
    if os.path.isdir(path):
        raise UserError(path, "", "is a directory, not a USD file")
    try:
        stage = Usd.Stage.Open(path)
    except Tf.ErrorException as e:
        raise UserError(path, "", "cannot open the stage: " + " ".join(describe_tf_error(e).split())) from None
    if stage is None:
        raise UserError(path, "", "cannot open the stage")
    return stage


def stage_time(stage):
    """The time a stage is read at when no time is given: its start time code, else
    (no authored range) the earliest time sample."""
    if stage.HasAuthoredTimeCodeRange():
        return Usd.TimeCode(stage.GetStartTimeCode())
    return Usd.TimeCode.EarliestTime()


def as_time_code(time, stage=None):
    """None (stage_time(stage)), a number or a Usd.TimeCode -> Usd.TimeCode."""
    if time is None:
        return stage_time(stage)
    if isinstance(time, Usd.TimeCode):
        return time
    if isinstance(time, bool) or not isinstance(time, (int, float)) or not math.isfinite(time):
        raise ValueError(f"time must be a finite number or a Usd.TimeCode, not {time!r}")
    return Usd.TimeCode(float(time))


def to_core_matrix(m):
    """Gf.Matrix4d (USD: row vectors, translation in the last row) -> core's column form."""
    return [[float(m[j][i]) for j in range(4)] for i in range(4)]


def world_matrix(xf_cache, prim):
    """prim's local-to-world transform in core's form. An xformOpOrder naming something that
    is no transform op makes usd-core raise without naming the prim: name the one (prim or
    ancestor) whose own ops fail."""
    try:
        return to_core_matrix(xf_cache.GetLocalToWorldTransform(prim))
    except Tf.ErrorException as e:
        message = " ".join(describe_tf_error(e).split())
        p = prim
        while p and not p.IsPseudoRoot():
            try:
                UsdGeom.XformCache(xf_cache.GetTime()).GetLocalTransformation(p)
            except Tf.ErrorException:
                break
            p = p.GetParent()
        raise UserError((p if p and not p.IsPseudoRoot() else prim).GetPath(), "xformOpOrder", message) from None


def _finite(v):
    return all(math.isfinite(x) for x in (v if isinstance(v, (tuple, list)) else (v,)))


# ---- typed attribute values ---------------------------------------------------------------
# A layer may author any type for any attribute (the schema's type is not enforced when a
# file is read); every value is checked before it reaches core.

def _where(attr):
    return str(attr.GetPrim().GetPath()), attr.GetName()


def _bad(attr, v, expected):
    prim, name = _where(attr)
    text = repr(v)
    return UserError(prim, name, f"has value {text if len(text) < 60 else text[:57] + '...'}, expected {expected}")


def get_number(attr, time, default=None):
    """A finite-or-not float (None -> default); anything but a number is a UserError."""
    v = attr.Get(time) if attr else None
    if v is None:
        return default
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise _bad(attr, v, "a number")
    return float(v)


def get_bool(attr, time, default=False):
    v = attr.Get(time) if attr else None
    if v is None:
        return default
    if not isinstance(v, bool):
        raise _bad(attr, v, "a bool")
    return v


def get_token(attr, time, default=None):
    v = attr.Get(time) if attr else None
    if v is None:
        return default
    if not isinstance(v, str):
        raise _bad(attr, v, "a token")
    return v


def get_vec(attr, time, n, default=None):
    """A tuple of n numbers (colors, Vec2/Vec3 values)."""
    v = attr.Get(time) if attr else None
    if v is None:
        return default
    try:
        if isinstance(v, str) or len(v) != n:
            raise TypeError
        out = tuple(float(x) for x in v)
        if any(isinstance(x, bool) for x in v):
            raise TypeError
    except (TypeError, ValueError):
        raise _bad(attr, v, f"{n} numbers") from None
    return out


def get_array(attr, time, columns, dtype, expected):
    """An array attribute as a numpy array of shape (N, columns) or (N,); None if unset."""
    v = attr.Get(time) if attr else None
    if v is None:
        return None
    if isinstance(v, (str, int, float, bool)):
        raise _bad(attr, v, expected)
    try:
        a = np.asarray(v)
        if a.dtype.kind not in ("f", "i", "u") or (dtype == np.int64 and a.dtype.kind == "f"):
            raise TypeError
        a = a.astype(dtype)
        if columns:
            if a.size == 0:
                return a.reshape(0, columns)
            if a.ndim != 2 or a.shape[1] != columns:
                raise TypeError
        elif a.ndim != 1:
            raise TypeError
    except (TypeError, ValueError):
        prim, name = _where(attr)
        raise UserError(prim, name, f"has a {type(v).__name__} value, expected {expected}") from None
    return a


def get_asset(attr, time):
    v = attr.Get(time) if attr else None
    if v is None:
        return None
    if not isinstance(v, Sdf.AssetPath):
        raise _bad(attr, v, "an asset path")
    return v


# ---- geometry -----------------------------------------------------------------------------

def read_mesh(prim, time):
    """The Mesh's triangles in its own space (core.TriangleMesh); UserError on bad data."""
    path = str(prim.GetPath())
    mesh = UsdGeom.Mesh(prim)
    P = get_array(mesh.GetPointsAttr(), time, 3, np.float64, "point3f[]")
    counts = get_array(mesh.GetFaceVertexCountsAttr(), time, 0, np.int64, "int[]")
    indices = get_array(mesh.GetFaceVertexIndicesAttr(), time, 0, np.int64, "int[]")
    if P is None or len(P) == 0:
        raise UserError(path, "points", "has no points")
    if counts is None or len(counts) == 0:
        raise UserError(path, "faceVertexCounts", "has no faces")
    if indices is None:
        raise UserError(path, "faceVertexIndices", "has no value")
    if P.size and np.abs(P[np.isfinite(P)]).max(initial=0.0) > 3.0e38:
        raise UserError(path, "points", "has values that do not fit in a float")
    try:
        tri = core.triangulate(P.astype(np.float32), counts, indices, path)
    except core.InputError as e:
        raise translate_core_error(e) from None
    if get_token(mesh.GetOrientationAttr(), time) == UsdGeom.Tokens.leftHanded:
        tri.flip()
    return tri


def read_st(scene, prim, name, time, num_points):
    """Primvar `name` (texture coordinates, any interpolation) at each corner of read_mesh's
    triangles (of num_points points), as (corners, 2) floats; None with a warning when the
    mesh has no such primvar."""
    path = str(prim.GetPath())
    pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance(name)
    if not (pv and pv.HasAuthoredValue()):
        scene.warn(f"{path}: has no primvars:{name} for its material's textures; they read st (0, 0) everywhere")
        return None
    attr = pv.GetAttr()
    src, attr_name = _where(attr)
    try:
        v = np.asarray(pv.ComputeFlattened(time), dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 2:
            raise TypeError
    except (TypeError, ValueError):
        raise UserError(src, attr_name, f"has a {attr.GetTypeName()} value, expected texCoord2f[]") from None
    if not np.all(np.isfinite(v)):
        raise UserError(src, attr_name, "has values that are not finite")
    mesh = UsdGeom.Mesh(prim)
    counts = get_array(mesh.GetFaceVertexCountsAttr(), time, 0, np.int64, "int[]")
    indices = get_array(mesh.GetFaceVertexIndicesAttr(), time, 0, np.int64, "int[]")
    corners = core.triangulated_corners(counts).astype(np.int64)
    interp = pv.GetInterpolation()
    if interp == UsdGeom.Tokens.constant:
        where, expected = np.zeros_like(corners), 1
    elif interp == UsdGeom.Tokens.uniform:
        face = np.repeat(np.arange(len(counts)), np.maximum(counts - 2, 0) * 3)
        where, expected = face, len(counts)
    elif interp in (UsdGeom.Tokens.vertex, UsdGeom.Tokens.varying):
        where, expected = indices[corners], num_points
    else:  # faceVarying
        where, expected = corners, len(indices)
    if len(v) != expected:
        raise UserError(src, attr_name, f"has {len(v)} values; {interp} interpolation needs {expected}")
    uv = v[where].reshape(-1, 3, 2)
    if get_token(mesh.GetOrientationAttr(), time) == UsdGeom.Tokens.leftHanded:
        uv = uv[:, [0, 2, 1]]  # read_mesh flipped these triangles
    return uv.reshape(-1, 2).astype(np.float32)


def _tessellated(prim, time):
    """UsdGeomCube / UsdGeomSphere as triangles in their own space."""
    if prim.IsA(UsdGeom.Cube):
        size = get_number(UsdGeom.Cube(prim).GetSizeAttr(), time)
        if size is None or not _finite(size) or size <= 0:
            raise UserError(prim.GetPath(), "size", f"{size} must be finite and > 0")
        h = 0.5 * float(size)
        return core.make_box((-h, -h, -h), (h, h, h))
    radius = get_number(UsdGeom.Sphere(prim).GetRadiusAttr(), time)
    if radius is None or not _finite(radius) or radius <= 0:
        raise UserError(prim.GetPath(), "radius", f"{radius} must be finite and > 0")
    m = core.make_uv_sphere(64, 32)
    m.points = m.points * float(radius)
    return m


# ---- materials ------------------------------------------------------------------------------

# UsdUVTexture's tokens and outputs (its specification) in core's terms.
_WRAPS = {"useMetadata": core.TextureWrap.UseMetadata, "black": core.TextureWrap.Black,
          "clamp": core.TextureWrap.Clamp, "repeat": core.TextureWrap.Repeat, "mirror": core.TextureWrap.Mirror}
_COLOR_SPACES = {"auto": core.TextureColorSpace.Auto, "raw": core.TextureColorSpace.Raw,
                 "sRGB": core.TextureColorSpace.SRGB}
_CHANNELS = {"rgb": -1, "r": 0, "g": 1, "b": 2, "a": 3}
# The UsdPreviewSurface inputs read from a texture.
_TEXTURED_INPUTS = ("diffuseColor", "emissiveColor", "opacity")


def _input_attr(shader, name):
    """The attribute of shader's input `name`, or None when it has no such input."""
    inp = shader.GetInput(name)
    return inp.GetAttr() if inp else None


def _existing_file(prim_path, attr_name, asset):
    """An asset's resolved path; UserError naming the attribute when it cannot be found."""
    resolved = asset.resolvedPath
    if not resolved or not os.path.isfile(resolved):
        raise UserError(prim_path, attr_name, f'"{asset.path}" cannot be found')
    return resolved


def _source_shader(inp):
    """The shader output that produces inp's value (through node graphs), or None."""
    attrs = inp.GetValueProducingAttributes(shaderOutputsOnly=True)
    return attrs[0] if attrs else None


def _texture_st(scene, tex, time, input_name="st", seen=()):
    """The primvar name a UsdUVTexture's st reads (a UsdPrimvarReader_float2's varname, also
    through a UsdTransform2d's `in`), or None: its st is then the constant fallback (0, 0).
    seen: the UsdTransform2d shaders already followed (a cycle of them is an error)."""
    path = str(tex.GetPath())
    inp = tex.GetInput(input_name)
    if not inp or not inp.HasConnectedSource():
        scene.warn(f"{path}.inputs:{input_name}: not connected to a UsdPrimvarReader_float2; "
                   f"the texture reads st (0, 0) everywhere")
        return None
    out = _source_shader(inp)
    reader = UsdShade.Shader(out.GetPrim()) if out else None
    sid = reader.GetIdAttr().Get(time) if reader else None
    if sid == "UsdTransform2d":
        if reader.GetPath() in seen:
            raise UserError(str(reader.GetPath()), "inputs:in", "is connected in a cycle (to its own output)")
        scene.warn(f"{reader.GetPath()}: UsdTransform2d is not supported; st is read untransformed")
        return _texture_st(scene, reader, time, "in", seen + (reader.GetPath(),))
    if sid != "UsdPrimvarReader_float2":
        scene.warn(f"{path}.inputs:st: {sid!r} is not supported (only UsdPrimvarReader_float2); "
                   f"the texture reads st (0, 0) everywhere")
        return None
    v = _input_attr(reader, "varname")
    name = v.Get(time) if v else None
    if not name:
        raise UserError(str(reader.GetPath()), "inputs:varname", "names no primvar")
    return str(name)


def _texture(scene, shader, name, time):
    """The UsdUVTexture feeding shader's input `name` as (core.TextureDesc, st primvar name),
    or None when the input is not connected to one."""
    inp = shader.GetInput(name)
    if not inp or not inp.HasConnectedSource():
        return None
    out = _source_shader(inp)
    tex = UsdShade.Shader(out.GetPrim()) if out else None
    sid = tex.GetIdAttr().Get(time) if tex else None
    if sid != "UsdUVTexture":
        scene.warn(f"{shader.GetPath()}.inputs:{name}: connected to {sid!r}, which is not supported "
                   f"(only UsdUVTexture); using the input's own value")
        return None
    path = str(tex.GetPath())
    td = core.TextureDesc()
    td.source = path
    asset = get_asset(_input_attr(tex, "file"), time)
    if asset is None or not asset.path:
        raise UserError(path, "inputs:file", "names no image")
    if "<UDIM>" in asset.path:
        raise UserError(path, "inputs:file", f'"{asset.path}": UDIM textures are not supported')
    td.file = _existing_file(path, "inputs:file", asset)
    for attr, field in (("wrapS", "wrap_s"), ("wrapT", "wrap_t")):
        w = get_token(_input_attr(tex, attr), time, "useMetadata")
        if w not in _WRAPS:
            raise UserError(path, f"inputs:{attr}", f'"{w}" is not one of {", ".join(_WRAPS)}')
        setattr(td, field, _WRAPS[w])
    for attr, default in (("scale", (1.0, 1.0, 1.0, 1.0)), ("bias", (0.0, 0.0, 0.0, 0.0))):
        v = get_vec(_input_attr(tex, attr), time, 4, default)
        if not all(_finite(x) for x in v):
            raise UserError(path, f"inputs:{attr}", f"{v} is not finite")
        setattr(td, attr, list(v))
    cs = get_token(_input_attr(tex, "sourceColorSpace"), time, "auto")
    if cs not in _COLOR_SPACES:
        raise UserError(path, "inputs:sourceColorSpace", f'"{cs}" is not one of {", ".join(_COLOR_SPACES)}')
    td.color_space = _COLOR_SPACES[cs]
    output = out.GetBaseName()
    if output not in _CHANNELS:
        raise UserError(path, f"outputs:{output}", "is not an output of UsdUVTexture (rgb, r, g, b, a)")
    channel = _CHANNELS[output]
    if name == "opacity" and channel < 0:
        scene.warn(f"{shader.GetPath()}.inputs:opacity: connected to {path}.outputs:rgb; its r channel is used")
        channel = 0
    td.channel = channel
    return td, _texture_st(scene, tex, time)


def _input_value(scene, shader, name, time):
    inp = shader.GetInput(name)
    if not inp:
        return _PREVIEW_DEFAULTS[name], f"inputs:{name}"
    if inp.HasConnectedSource() and name not in _TEXTURED_INPUTS:
        scene.warn(f"{shader.GetPath()}.inputs:{name}: connections are not supported; "
                   f"using its own value or the fallback")
    default = _PREVIEW_DEFAULTS[name]
    attr = inp.GetAttr()
    v = get_vec(attr, time, 3, default) if isinstance(default, tuple) else get_number(attr, time, default)
    return v, f"inputs:{name}"


def _preview_surface(scene, prim, time, cache):
    """Index of the MaterialDesc of prim's bound UsdPreviewSurface, or None if there is none."""
    mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not mat:
        return None
    shader, _, _ = mat.ComputeSurfaceSource()
    if not shader:
        scene.warn(f"{mat.GetPath()}: no surface shader; using the default material")
        return -1
    sid = shader.GetIdAttr().Get(time)
    if sid != "UsdPreviewSurface":
        scene.warn(f"{shader.GetPath()}: shader {sid!r} is not supported (only UsdPreviewSurface); using the default material")
        return -1
    key = str(shader.GetPath())
    if key in cache:
        return cache[key]
    diffuse, _ = _input_value(scene, shader, "diffuseColor", time)
    emissive, _ = _input_value(scene, shader, "emissiveColor", time)
    opacity, _ = _input_value(scene, shader, "opacity", time)
    ior, _ = _input_value(scene, shader, "ior", time)
    threshold, _ = _input_value(scene, shader, "opacityThreshold", time)
    if not _finite(opacity) or not 0 <= opacity <= 1:
        raise UserError(key, "inputs:opacity", f"{opacity} is outside [0, 1]")
    if not _finite(threshold) or not 0 <= threshold <= 1:
        raise UserError(key, "inputs:opacityThreshold", f"{threshold} is outside [0, 1]")
    textures = {n: _texture(scene, shader, n, time) for n in _TEXTURED_INPUTS}
    md = core.MaterialDesc()
    md.name = key
    st = None
    if opacity < 1 and threshold == 0 and textures["opacity"] is None:
        # An untextured opacity without a threshold is glass.
        md.type = core.MaterialType.Dielectric
        md.ior = ior
        for n in ("diffuseColor", "emissiveColor"):
            if textures[n] is not None:
                scene.warn(f"{key}.inputs:{n}: a texture on a transparent (glass) material is ignored")
    else:
        # Lambert; a textured opacity or a threshold makes a cut-out (core: MaterialDesc.opacity).
        md.type = core.MaterialType.Lambert
        md.albedo = diffuse
        md.emission = emissive
        md.opacity = opacity
        md.opacity_threshold = threshold
        for n, field in (("diffuseColor", "albedo_texture"), ("emissiveColor", "emission_texture"),
                         ("opacity", "opacity_texture")):
            if textures[n] is None:
                continue
            td, name = textures[n]
            setattr(md, field, td)
            if name is not None and st is not None and name != st:
                scene.warn(f"{key}: textures read different primvars ({st!r}, {name!r}); {st!r} is used")
            st = st or name
    idx = scene.desc.add_material(md)
    scene.material_st[idx] = st
    scene.name(key, key, {"albedo": (key, "inputs:diffuseColor"), "ior": (key, "inputs:ior"),
                          "emission": (key, "inputs:emissiveColor")})
    cache[key] = idx
    return idx


def _display_color(scene, prim, time):
    """The mean of prim's displayColor (inherited), or None; core makes it a Lambert for an
    ordinary mesh without a material."""
    pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance("displayColor")
    if not (pv and pv.HasAuthoredValue()):
        return None
    v = pv.ComputeFlattened(time)
    if v is None:
        return None
    try:
        a = np.asarray(v, dtype=np.float64)  # of any authored type: a scalar has no len()
        if a.size == 0:
            return None
        c = a.reshape(-1, 3).mean(axis=0)
    except (TypeError, ValueError):
        prim_path, name = _where(pv.GetAttr())
        raise UserError(prim_path, name, f"has a {type(v).__name__} value, expected color3f[]") from None
    src = str(pv.GetAttr().GetPrim().GetPath())
    scene.name(str(prim.GetPath()) + ".displayColor", src, {"albedo": (src, "primvars:displayColor")})
    return tuple(float(x) for x in c)


# ---- prims for core's granular schema ----------------------------------------------------------

def _mesh_prim(scene, prim, xf_cache, material_cache, drawn):
    """prim as core.MeshPrim: its type, applied schemas and granular primvars; for a Mesh
    (and, when drawn, a Cube or Sphere) its triangles, world transform and material."""
    time = scene.time
    mp = core.MeshPrim()
    mp.path = str(prim.GetPath())
    is_mesh = prim.IsA(UsdGeom.Mesh)
    mp.type_name = "Mesh" if is_mesh else prim.GetTypeName()
    mp.active = prim.IsActive()
    mp.api_schemas = list(prim.GetAppliedSchemas())
    mp.visible = drawn
    has_api = prim.HasAPI(schema.AGGREGATE_API) or prim.HasAPI(schema.GRAIN_API)
    shape = is_mesh or (drawn and not has_api and (prim.IsA(UsdGeom.Cube) or prim.IsA(UsdGeom.Sphere)))
    if not mp.active or not shape:
        return mp  # listed for core's error message only
    mp.granular = schema.primvar_values(prim, time=time)
    mp.mesh = read_mesh(prim, time) if is_mesh else _tessellated(prim, time)
    mp.instances = [world_matrix(xf_cache, prim)]
    scene.name(mp.path, mp.path, {"transform": (mp.path, "transform")})
    # A boundary or grain with its API applied never uses a bound material: not read.
    if not has_api:
        idx = _preview_surface(scene, prim, time, material_cache)
        if idx is None and drawn:
            mp.display_color = _display_color(scene, prim, time)
        mp.material = -1 if idx is None else idx
        st = scene.material_st.get(idx)
        if st is not None and is_mesh:
            uvs = read_st(scene, prim, st, time, len(mp.mesh.points))
            if uvs is not None:
                mp.mesh.uvs = uvs
    return mp


def _assemble(scene, prims, xf_cache, material_cache):
    """core's granular schema on the listed prims; the prototypes core asks for that are
    not listed (not drawn) are read from the stage."""
    def lookup(path):
        prim = scene.stage.GetPrimAtPath(path)
        return _mesh_prim(scene, prim, xf_cache, material_cache, drawn=False) if prim else None

    try:
        core.assemble_granular_scene(prims, scene.desc, lookup)
    except core.InputError as e:
        raise translate_core_error(e) from None
    # Later errors about an aggregate (scene building) name its primvars where authored.
    granular = {mp.path: mp.granular for mp in prims}
    for a in scene.desc.aggregates:
        path = a.name
        found = granular.get(path, {})
        attrs = {base: (found[base].source if base in found else path, schema.attr_name(base))
                 for base in schema.AGGREGATE_PROPERTIES}
        attrs["transform"] = (path, "transform")
        scene.name(path, path, attrs)
        scene.aggregates.append({"prim": path, "world_boundary": a.boundary.transformed(a.xf),
                                 "prototypes": [p.name for p in a.prototypes]})


# ---- camera, lights, settings --------------------------------------------------------------

def _settings_prim(stage):
    s = UsdRender.Settings.GetStageRenderSettings(stage)
    if s:
        return s.GetPrim()
    for prim in stage.Traverse():
        if prim.IsA(UsdRender.Settings):
            return prim
    return None


def read_camera(scene, prim, xf_cache):
    path = str(prim.GetPath())
    cam = UsdGeom.Camera(prim)
    t = scene.time
    if get_token(cam.GetProjectionAttr(), t) == UsdGeom.Tokens.orthographic:
        raise UserError(path, "projection", "orthographic cameras are not supported (use perspective)")
    c = scene.desc.camera
    c.camera_to_world = world_matrix(xf_cache, prim)
    c.focal_length = get_number(cam.GetFocalLengthAttr(), t, 50.0)
    c.horizontal_aperture = get_number(cam.GetHorizontalApertureAttr(), t, 20.955)
    c.vertical_aperture = get_number(cam.GetVerticalApertureAttr(), t, 15.2908)
    c.horizontal_aperture_offset = get_number(cam.GetHorizontalApertureOffsetAttr(), t, 0.0)
    c.vertical_aperture_offset = get_number(cam.GetVerticalApertureOffsetAttr(), t, 0.0)
    c.clip_near, c.clip_far = get_vec(cam.GetClippingRangeAttr(), t, 2, (1.0, 1000000.0))
    # Depth of field: fStop 0 (USD's default) is a pinhole.
    f_stop = get_number(cam.GetFStopAttr(), t, 0.0)
    try:
        c.lens_radius = core.lens_radius_from_f_stop(c.focal_length, f_stop, path, "fStop")
    except core.InputError as e:
        raise translate_core_error(e) from None
    c.focus_distance = get_number(cam.GetFocusDistanceAttr(), t, 0.0)
    if c.lens_radius > 0 and not (math.isfinite(c.focus_distance) and c.focus_distance > 0):
        raise UserError(path, "focusDistance", f"{c.focus_distance} must be > 0 when fStop is set")
    scene.camera_path = path
    attrs = {k: (path, k) for k in ("focalLength", "horizontalAperture", "verticalAperture",
                                    "horizontalApertureOffset", "verticalApertureOffset", "clippingRange",
                                    "fStop", "focusDistance")}
    attrs["transform"] = (path, "transform")
    scene.name("camera", path, attrs)


_LIGHT_ATTRS = {k: "inputs:" + k for k in ("intensity", "exposure", "color", "normalize", "angle", "radius",
                                            "width", "height")}


def read_light(scene, prim, xf_cache):
    path = str(prim.GetPath())
    time = scene.time
    ld = core.LightDesc()
    ld.name = path
    if prim.IsA(UsdLux.DistantLight):
        ld.type = core.LightType.Distant
        ld.angle = get_number(UsdLux.DistantLight(prim).GetAngleAttr(), time, 0.53)
    elif prim.IsA(UsdLux.DomeLight) or (hasattr(UsdLux, "DomeLight_1") and prim.IsA(UsdLux.DomeLight_1)):
        ld.type = core.LightType.Dome
        fmt = get_token(prim.GetAttribute("inputs:texture:format"), time)
        if fmt not in (None, "automatic", "latlong"):
            raise UserError(path, "inputs:texture:format", f'"{fmt}" is not supported (use latlong)')
        asset = get_asset(prim.GetAttribute("inputs:texture:file"), time)
        if asset is not None and asset.path:
            resolved = _existing_file(path, "inputs:texture:file", asset)
            ld.texture_file = resolved
            scene.names[resolved] = {"*": (path, ""), "": (path, "inputs:texture:file")}
    elif prim.IsA(UsdLux.RectLight):
        ld.type = core.LightType.Rect
        rl = UsdLux.RectLight(prim)
        ld.width = get_number(rl.GetWidthAttr(), time, 1.0)
        ld.height = get_number(rl.GetHeightAttr(), time, 1.0)
        tex = get_asset(rl.GetTextureFileAttr(), time)
        if tex is not None and tex.path:
            scene.warn(f"{path}.inputs:texture:file: rect light textures are not supported; ignored")
    elif prim.IsA(UsdLux.SphereLight):
        ld.type = core.LightType.Sphere
        sl = UsdLux.SphereLight(prim)
        ld.radius = get_number(sl.GetRadiusAttr(), time, 0.5)
        if get_bool(sl.GetTreatAsPointAttr(), time):
            scene.warn(f"{path}.treatAsPoint: not supported; rendered as a sphere of inputs:radius")
    else:
        scene.warn(f"{path}: {prim.GetTypeName()} lights are not supported; skipped")
        return
    light = UsdLux.LightAPI(prim)
    ld.intensity = get_number(light.GetIntensityAttr(), time, 1.0)
    ld.exposure = get_number(light.GetExposureAttr(), time, 0.0)
    color = get_vec(light.GetColorAttr(), time, 3, (1.0, 1.0, 1.0))
    if get_bool(light.GetEnableColorTemperatureAttr(), time):
        t = get_number(light.GetColorTemperatureAttr(), time, 6500.0)
        if not _finite(t) or t <= 0:
            raise UserError(path, "inputs:colorTemperature", f"{t} must be finite and > 0")
        rgb = UsdLux.BlackbodyTemperatureAsRgb(t)
        color = tuple(c * float(k) for c, k in zip(color, rgb))
    ld.color = color
    ld.normalize = get_bool(light.GetNormalizeAttr(), time)
    ld.xf = world_matrix(xf_cache, prim)
    scene.desc.add_light(ld)
    attrs = {k: (path, v) for k, v in _LIGHT_ATTRS.items()}
    attrs["transform"] = (path, "transform")
    scene.name(path, path, attrs)


def _is_light(prim):
    return prim.HasAPI(UsdLux.LightAPI)


# ---- the stage ---------------------------------------------------------------------------------

def read_stage(path, camera=None, width=None, height=None, surfaces=True, need_camera=True, stage=None,
               time=None):
    """Reads the stage at `path` (or the open `stage`) into a StageScene, every value at
    `time` (a Usd.TimeCode or a number; None: stage_time, the stage's start). With
    surfaces=False only aggregates are read (for info and export); without need_camera a
    missing camera is no error."""
    stage = stage or open_stage(path)
    time = as_time_code(time, stage)
    scene = StageScene(path, stage, time)
    scene.name("render", path, {})
    xf_cache = UsdGeom.XformCache(time)
    material_cache = {}
    prims = []  # core.MeshPrim of every drawn mesh and every prim with GranularAggregateAPI
    cameras = []
    unsupported = {}

    it = iter(Usd.PrimRange.Stage(stage, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
    for prim in it:
        if prim.IsA(UsdGeom.Imageable):
            img = UsdGeom.Imageable(prim)
            vis = get_token(img.GetVisibilityAttr(), time)
            purpose = get_token(img.GetPurposeAttr(), time)
            if vis == UsdGeom.Tokens.invisible or purpose in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                it.PruneChildren()
                continue
        if prim.HasAPI(schema.AGGREGATE_API):
            prims.append(_mesh_prim(scene, prim, xf_cache, material_cache, drawn=True))
            continue
        if prim.IsA(UsdGeom.Camera):
            cameras.append(prim)
            continue
        if not surfaces:
            continue
        if _is_light(prim):
            read_light(scene, prim, xf_cache)
            continue
        if prim.IsA(UsdGeom.Mesh) or prim.IsA(UsdGeom.Cube) or prim.IsA(UsdGeom.Sphere):
            prims.append(_mesh_prim(scene, prim, xf_cache, material_cache, drawn=True))
        elif prim.IsA(UsdGeom.Gprim) or prim.IsA(UsdGeom.PointInstancer):
            unsupported.setdefault(prim.GetTypeName(), str(prim.GetPath()))
    for type_name, example in unsupported.items():
        scene.warn(f"{example}: {type_name} prims are not supported; skipped")
    _assemble(scene, prims, xf_cache, material_cache)

    # Resolution and camera: command line, else the render settings prim, else defaults.
    settings = _settings_prim(stage)
    res = None
    settings_camera = None
    if settings is not None:
        rs = UsdRender.Settings(settings)
        attr = rs.GetResolutionAttr()
        if attr.HasAuthoredValue():
            res = get_vec(attr, time, 2)
            if res is None or not all(_finite(x) and x == int(x) and 1 <= x <= 32768 for x in res):
                raise UserError(settings.GetPath(), "resolution", f"{res} is outside [1, 32768] x [1, 32768]")
            res = (int(res[0]), int(res[1]))
        targets = rs.GetCameraRel().GetForwardedTargets()
        if targets:
            settings_camera = (targets[0], settings.GetPath())

    cam_prim = None
    if camera:
        ok, _ = Sdf.Path.IsValidPathString(camera)
        p = stage.GetPrimAtPath(camera) if ok and Sdf.Path(camera).IsAbsolutePath() else None
        if not p:
            raise UserError("command line", "--camera", f'"{camera}" is not a prim of the stage')
        if not p.IsA(UsdGeom.Camera):
            raise UserError(camera, "", f"is a {p.GetTypeName() or 'typeless prim'}, not a Camera")
        cam_prim = p
    elif settings_camera:
        p = stage.GetPrimAtPath(settings_camera[0])
        if not p or not p.IsA(UsdGeom.Camera):
            raise UserError(settings_camera[1], "camera", f"target {settings_camera[0]} is not a Camera")
        cam_prim = p
    elif cameras:
        cam_prim = cameras[0]
    if cam_prim is not None:
        read_camera(scene, cam_prim, xf_cache)
    elif need_camera:
        raise UserError(path, "", "the stage has no UsdGeomCamera (add one, or pass --camera)")

    s = scene.desc.settings
    c = scene.desc.camera
    ha, va = c.horizontal_aperture, c.vertical_aperture
    # Apertures core refuses (0, NaN, ...) give no aspect: core's validation names them.
    aspect = ha / va if _finite((ha, va)) and ha > 0 and va > 0 else 4 / 3

    def derived(v, flag, what):
        n = max(1, round(v))
        if n > 32768:
            raise UserError("command line", flag, f"with the camera's aspect {aspect:.3g} makes the image "
                                                  f"{n:.3g} pixels {what}, beyond 32768 (give --width and --height)")
        return n
    if width and height:
        s.width, s.height = width, height
    elif width:
        s.width, s.height = width, derived(width / aspect, "--width", "high")
    elif height:
        s.width, s.height = derived(height * aspect, "--height", "wide"), height
    elif res:
        s.width, s.height = res
    else:
        s.width, s.height = DEFAULT_WIDTH, DEFAULT_HEIGHT
    if settings is not None:
        _read_data_window(scene, settings, time)
    return scene


def ndc_to_pixels(ndc, width, height):
    """A data window (xmin, ymin, xmax, ymax) in NDC -> the pixels (x0, x1, y0, y1) it covers
    (core.pixel_window_from_ndc: the delegate's conversion too); None when nothing of the
    image is left."""
    w = core.pixel_window_from_ndc(*(float(v) for v in ndc), width, height)
    return w if w[0] < w[1] and w[2] < w[3] else None


def _read_data_window(scene, settings, time):
    """The data window of the settings prim's first render product (UsdRender: the product's
    own dataWindowNDC, else the settings prim's) as the render's crop: only those pixels are
    rendered, and the EXR keeps their place in the full image. Hydra hosts hand hdGranular
    the same value (hdGranular/renderSettings.h)."""
    rs = UsdRender.Settings(settings)
    own = rs.GetDataWindowNDCAttr()
    targets = rs.GetProductsRel().GetForwardedTargets()
    product = settings.GetStage().GetPrimAtPath(targets[0]) if targets else None
    if not product or not product.IsA(UsdRender.Product):  # none, no such prim, or not a product
        if own.HasAuthoredValue():
            scene.warn(f"{settings.GetPath()}.dataWindowNDC: ignored: a data window applies to render products, "
                       f"and this settings prim has none (add one to its products)")
        return
    attr = UsdRender.Product(product).GetDataWindowNDCAttr()
    if not attr.HasAuthoredValue():
        attr = own
        if not attr.HasAuthoredValue():
            return
    path = str(attr.GetPrim().GetPath())
    ndc = get_vec(attr, time, 4)
    if ndc is None or not all(_finite(v) for v in ndc):
        raise UserError(path, "dataWindowNDC", f"{ndc} is not four finite numbers (xmin, ymin, xmax, ymax)")
    if not (ndc[0] < ndc[2] and ndc[1] < ndc[3]):
        raise UserError(path, "dataWindowNDC", f"{tuple(ndc)} is empty: xmin < xmax and ymin < ymax are needed")
    s = scene.desc.settings
    window = ndc_to_pixels(ndc, s.width, s.height)
    if window is None:
        raise UserError(path, "dataWindowNDC", f"{tuple(ndc)} covers no pixel of the {s.width}x{s.height} image")
    if ndc[0] < 0 or ndc[1] < 0 or ndc[2] > 1 or ndc[3] > 1:
        scene.warn(f"{path}.dataWindowNDC: {tuple(ndc)} reaches outside the image; overscan is not rendered, "
                   f"only the pixels inside (0, 0, 1, 1)")
    if window != (0, s.width, 0, s.height):
        s.crop = window
    scene.names["render"]["crop"] = (path, "dataWindowNDC")  # core's render.crop errors


def validate(scene):
    """core's validation of the whole description, errors in USD terms."""
    try:
        core.validate_scene_desc(scene.desc)
    except core.InputError as e:
        raise translate_core_error(e, scene) from None
