"""Reads a USD stage (usd-core) into core's plain SceneDesc.

This module reads and converts; core decides what the values mean, the same core the
Hydra delegate hands its values to: the granular schema (assemble_granular_scene), UsdLux
lights (light_from_usd), UsdGeomCamera (camera_from_usd), UsdPreviewSurface and UsdUVTexture
networks and displayColor (material_from_usd, display_color_from_usd), UsdGeomMesh topology
and primvar interpolation (mesh_from_usd, usd_primvar_at_corners), implicit surfaces
(implicit_surface_from_usd) and UsdRender settings (resolution_from_usd,
data_window_from_usd). Prims are handed over as plain records (prim_record): path, type,
attribute values as authored; core applies USD's fallbacks, checks and names errors.

What is read, at one time code: the caller's (read_stage's `time`, e.g. each frame of
`granular render --frames`), else the stage's start time code (or, without an authored
range, the earliest time sample). Every time-varying value is read at that time.
- UsdGeomMesh prims and the implicit surfaces (Cube, Sphere, Cylinder, Cone, Capsule) with
  world transforms, skipping invisible prims and the guide and proxy purposes;
- each mesh is handed to core with its granular primvars, applied API schemas and bound
  material, and core decides what is an aggregate, a prototype or ordinary geometry;
  prototypes that are not drawn (invisible) are read when core asks for them;
- one UsdGeomCamera (--camera, else the render settings' camera, else the first one);
- UsdLux lights; the bound material's surface network; displayColor without a material;
- a PointInstancer of simulated grains (GranularInstancedAggregateAPI, or every prototype
  a grain) is listed in scene.explicit_grains and, when surfaces are read, added to the
  description as explicit grains (read_instanced_grains, core's instancedGrainsFromUsd);
- the render settings prim's resolution and camera, and its first product's data window;
  without -o, its render products and vars (read_render_products, core's render_products.h).
Every problem a user can cause raises UserError naming the prim and the attribute;
`translate_core_error` turns core's InputError (named after SceneDesc fields) into the same.
"""
import math
import os

import numpy as np

# Crates are read with pread rather than mapped (unless the environment says otherwise):
# USD maps a .usdc and hands out arrays that point into the mapping, whose pages then count
# as this process's resident memory for as long as the stage is open (a simulated heap's
# arrays: 32 bytes a grain, 3 GB at 10^8 grains); an array read is ours only until core has
# converted it. Read by USD when it opens its first crate.
os.environ.setdefault("USDC_USE_PREAD", "1")
from pxr import Gf, Sdf, Tf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade  # noqa: E402

import granular_core as core

from . import schema
from .errors import UserError, describe_tf_error

DEFAULT_WIDTH, DEFAULT_HEIGHT = 640, 480

class StageScene:
    """A stage read into a SceneDesc, with what is needed to report errors in USD terms."""

    def __init__(self, path, stage, time):
        self.path = path
        self.stage = stage
        self.time = time
        self.desc = core.SceneDesc()
        self.camera_path = None
        self.aggregates = []     # per desc.aggregates entry: {"prim", "world_boundary", "prototypes"}
        self.explicit_grains = []  # PointInstancer prims of simulated grains (read_instanced_grains)
        self.light_links = []    # (name, membership query) of each light's lightLink and shadowLink (read_light)
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


def get_token(attr, time, default=None):
    v = attr.Get(time) if attr else None
    if v is None:
        return default
    if not isinstance(v, str):
        raise _bad(attr, v, "a token")
    return v


def get_array(attr, time, columns, dtype, expected, convert=True):
    """An array attribute as a numpy array of shape (N, columns) or (N,); None if unset.
    convert=False: the numbers keep their type (checked as for dtype; no copy: a view of
    USD's own array)."""
    v = attr.Get(time) if attr else None
    if v is None:
        return None
    if isinstance(v, (str, int, float, bool)):
        raise _bad(attr, v, expected)
    try:
        a = np.asarray(v)
        if a.dtype.kind not in ("f", "i", "u") or (dtype == np.int64 and a.dtype.kind == "f"):
            raise TypeError
        if convert:
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


def usd_value(attr, time):
    """An attribute's value at `time` as core.UsdValue (authored type, values as found), or
    None when it has none; core checks the type and applies the meaning."""
    if not attr or not attr.HasValue():
        return None
    v = attr.Get(time)
    # A blocked value (None in a layer) is the schema's fallback, of the schema's type,
    # whatever type the block was authored with.
    type_name = schema.authored_type(attr) if attr.HasAuthoredValue() else str(attr.GetTypeName())
    if v is None and type_name == str(attr.GetTypeName()):
        return None
    out = core.UsdValue()
    out.type_name = type_name
    out.is_array = type_name.endswith("[]")
    out.is_string = type_name.replace("[]", "") in ("string", "token", "asset")
    if isinstance(v, Sdf.AssetPath):
        out.strings = [v.path]
        out.resolved_path = v.resolvedPath or ""
    elif isinstance(v, Sdf.AssetPathArray):
        out.strings = [x.path for x in v]
    elif out.is_string and v is not None:
        out.strings = [v] if isinstance(v, str) else [str(x) for x in v]
    elif v is not None and not isinstance(v, str):
        out.numbers = schema.numbers(v)
    return out


def prim_record(prim, names, time, xf_cache=None, record=None, authored_only=False):
    """prim's attributes `names` that hold a value (authored_only: an authored one, not the
    schema's fallback), as a core.UsdPrimRecord (its type as USD names it; its world
    transform when xf_cache is given)."""
    r = record if record is not None else core.UsdPrimRecord()
    r.path = str(prim.GetPath())
    r.type_name = str(prim.GetTypeName())
    attrs = {}
    for name in names:
        attr = prim.GetAttribute(name)
        if authored_only and not attr.HasAuthoredValue():
            continue
        v = usd_value(attr, time)
        if v is not None:
            attrs[name] = v
    r.attributes = attrs
    if xf_cache is not None:
        r.xf = world_matrix(xf_cache, prim)
    return r


def _core_call(fn, *args):
    try:
        return fn(*args)
    except core.InputError as e:
        raise translate_core_error(e) from None


# ---- geometry -----------------------------------------------------------------------------

def _topology(prim, time):
    """A Mesh's topology arrays (counts, indices, holes, orientation), type-checked."""
    mesh = UsdGeom.Mesh(prim)
    counts = get_array(mesh.GetFaceVertexCountsAttr(), time, 0, np.int64, "int[]")
    indices = get_array(mesh.GetFaceVertexIndicesAttr(), time, 0, np.int64, "int[]")
    holes = get_array(mesh.GetHoleIndicesAttr(), time, 0, np.int64, "int[]")
    orientation = get_token(mesh.GetOrientationAttr(), time, UsdGeom.Tokens.rightHanded)
    return counts, indices, np.zeros(0, np.int64) if holes is None else holes, orientation


def read_mesh(prim, time):
    """The Mesh's triangles in its own space (core.mesh_from_usd) and its topology as core
    expands primvars over it: (number of points, counts, indices, holes, orientation).
    UserError on bad data."""
    path = str(prim.GetPath())
    P = get_array(UsdGeom.Mesh(prim).GetPointsAttr(), time, 3, np.float64, "point3f[]")
    counts, indices, holes, orientation = _topology(prim, time)
    if P is None or len(P) == 0:
        raise UserError(path, "points", "has no points")
    if counts is None or len(counts) == 0:
        raise UserError(path, "faceVertexCounts", "has no faces")
    if indices is None:
        raise UserError(path, "faceVertexIndices", "has no value")
    if P.size and np.abs(P[np.isfinite(P)]).max(initial=0.0) > 3.0e38:
        raise UserError(path, "points", "has values that do not fit in a float")
    tri = _core_call(core.mesh_from_usd, path, P.astype(np.float32), counts, indices, holes, orientation)
    return tri, (len(P), counts, indices, holes, orientation)


def read_st(scene, prim, name, time, topology):
    """Primvar `name` (texture coordinates, any interpolation) at each corner of read_mesh's
    triangles (topology: read_mesh's), as (corners, 2) floats (core.usd_primvar_at_corners);
    None with a warning when the mesh has no such primvar."""
    path = str(prim.GetPath())
    pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance(name)
    if not (pv and pv.HasAuthoredValue()):
        scene.warn(f"{path}: has no primvars:{name} for its material's textures; they read st (0, 0) everywhere")
        return None
    attr = pv.GetAttr()
    src, attr_name = _where(attr)
    try:
        v = np.asarray(schema.flattened(pv, time), dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 2:
            raise TypeError
    except (TypeError, ValueError):
        raise UserError(src, attr_name, f"has a {attr.GetTypeName()} value, expected texCoord2f[]") from None
    value = core.UsdValue()
    value.type_name = str(attr.GetTypeName())
    value.is_array = True
    value.numbers = v.reshape(-1).tolist()
    value.interpolation = pv.GetInterpolation()
    value.source = src
    return _core_call(core.usd_primvar_at_corners, path, *topology, value, 2, attr_name)


def _tessellated(prim, time):
    """A UsdGeom implicit surface (Cube, Sphere, Cylinder, Cone, Capsule) as triangles in its
    own space, tessellated by core (usd_implicit.h) as for hdGranular."""
    return _core_call(core.implicit_surface_from_usd, prim_record(prim, core.usd_implicit_attribute_names(), time))


def _is_implicit(prim):
    return core.is_usd_implicit_surface(str(prim.GetTypeName())) and prim.IsA(UsdGeom.Gprim)


# ---- materials ------------------------------------------------------------------------------

def _network(mat, time):
    """The bound material's surface network as core.UsdMaterialNetwork: every shader
    upstream of its surface output with its inputs' values and connections."""
    net = core.UsdMaterialNetwork()
    net.material = str(mat.GetPath())
    surface, _, _ = mat.ComputeSurfaceSource()
    if not surface:
        return net
    net.surface = str(surface.GetPath())
    shaders, seen, stack = [], set(), [surface]
    while stack:
        shader = stack.pop()
        path = str(shader.GetPath())
        if path in seen:
            continue
        seen.add(path)
        rec = core.UsdShaderRecord()
        rec.path = path
        rec.type_name = str(shader.GetIdAttr().Get(time) or "")
        attrs, connections = {}, {}
        for inp in shader.GetInputs():
            attr = inp.GetAttr()
            if inp.HasConnectedSource():
                sources = inp.GetValueProducingAttributes(shaderOutputsOnly=True)
                if sources:
                    out = sources[0]
                    connections[attr.GetName()] = (str(out.GetPrim().GetPath()), out.GetBaseName())
                    stack.append(UsdShade.Shader(out.GetPrim()))
            v = usd_value(attr, time)
            if v is not None:
                attrs[attr.GetName()] = v
        rec.attributes = attrs
        rec.connections = connections
        shaders.append(rec)
    net.shaders = shaders
    return net


def _bound_material(scene, prim, time, cache):
    """Index of the MaterialDesc of prim's bound material (core.material_from_usd), -1 for
    the default material, or None when none is bound."""
    mat, _ = UsdShade.MaterialBindingAPI(prim).ComputeBoundMaterial()
    if not mat:
        return None
    key = str(mat.GetPath())
    if key not in cache:
        desc, st, warnings = _core_call(core.material_from_usd, _network(mat, time))
        for w in warnings:
            scene.warn(w)
        idx = -1 if desc is None else scene.desc.add_material(desc)
        if desc is not None:
            scene.material_st[idx] = st or None
        cache[key] = idx
    return cache[key]


def _display_color(scene, prim, time, topology=()):
    """prim's displayColor (inherited) through core (usd_shading.h: averaged, checked), or
    None; core makes it a Lambert for an ordinary mesh without a material. topology:
    read_mesh's, for a Mesh (core checks the count against the interpolation)."""
    pv = UsdGeom.PrimvarsAPI(prim).FindPrimvarWithInheritance("displayColor")
    if not (pv and pv.HasAuthoredValue()):
        return None
    v = schema.flattened(pv, time)
    if v is None:
        return None
    value = core.UsdValue()
    value.type_name = schema.authored_type(pv.GetAttr())
    value.is_array = value.type_name.endswith("[]")
    value.source = str(pv.GetAttr().GetPrim().GetPath())
    value.interpolation = pv.GetInterpolation()
    if isinstance(v, str):
        value.is_string, value.strings = True, [v]
    else:
        value.numbers = schema.numbers(v)
    color, warnings = _core_call(core.display_color_from_usd, value, str(prim.GetPath()), *topology)
    for w in warnings:
        scene.warn(w)
    return color


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
    shape = is_mesh or (drawn and not has_api and _is_implicit(prim))
    if not mp.active or not shape:
        return mp  # listed for core's error message only
    mp.granular = schema.primvar_values(prim, time=time)
    topology = ()  # a Mesh's, over which its primvars are expanded
    if is_mesh:
        mp.mesh, topology = read_mesh(prim, time)
    else:
        mp.mesh = _tessellated(prim, time)
    mp.instances = [world_matrix(xf_cache, prim)]
    scene.name(mp.path, mp.path, {"transform": (mp.path, "transform")})
    if drawn and _is_light(prim):  # MeshLightAPI: the surface is the light's body
        mp.light = read_light(scene, prim, xf_cache)
        mp.double_sided = bool(UsdGeom.Gprim(prim).GetDoubleSidedAttr().Get(time))
    # A boundary or grain with its API applied never uses a bound material: not read.
    if not has_api:
        idx = _bound_material(scene, prim, time, material_cache)
        if idx is None and drawn:
            mp.display_color = _display_color(scene, prim, time, topology)
        mp.material = -1 if idx is None else idx
        st = scene.material_st.get(idx)
        if st is not None and is_mesh:
            uvs = read_st(scene, prim, st, time, topology)
            if uvs is not None:
                mp.mesh.uvs = uvs
    return mp


def _instanced(scene, instancer, xf_cache, material_cache, prims):
    """A PointInstancer's prototypes drawn at its instances, as Hydra draws them: usd-core
    computes each instance's transform (positions, orientations, scales, the prototype
    root's own transform, inactiveIds and invisibleIds); every drawn prim of a prototype
    keeps its transform relative to the prototype root."""
    time = scene.time
    path = str(instancer.GetPath())
    pi = UsdGeom.PointInstancer(instancer)
    targets = pi.GetPrototypesRel().GetForwardedTargets()
    indices = get_array(pi.GetProtoIndicesAttr(), time, 0, np.int64, "int[]")
    if indices is None or len(indices) == 0:
        return
    bad = [int(i) for i in indices if not 0 <= i < len(targets)]
    if bad:
        raise UserError(path, "protoIndices", f"{bad[0]} is not the index of one of its {len(targets)} prototypes")
    xforms = pi.ComputeInstanceTransformsAtTime(time, time, UsdGeom.PointInstancer.IncludeProtoXform,
                                                UsdGeom.PointInstancer.IgnoreMask)
    if xforms is None or len(xforms) != len(indices):
        raise UserError(path, "positions", f"gives {0 if xforms is None else len(xforms)} instances for "
                                           f"{len(indices)} protoIndices (positions, orientations and scales "
                                           f"must have one value per instance)")
    mask = pi.ComputeMaskAtTime(time)
    world = xf_cache.GetLocalToWorldTransform(instancer)
    for j, target in enumerate(targets):
        root = scene.stage.GetPrimAtPath(target)
        if not root:
            raise UserError(path, "prototypes", f"target {target} is not a prim of the stage")
        chosen = [k for k in range(len(indices)) if indices[k] == j and (not mask or mask[k])]
        placed = [Gf.Matrix4d(xforms[k]) * world for k in chosen]
        if not placed:
            continue
        root_inverse = xf_cache.GetLocalToWorldTransform(root).GetInverse()
        it = iter(Usd.PrimRange(root, Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)))
        for prim in it:
            if prim.IsA(UsdGeom.Imageable):
                img = UsdGeom.Imageable(prim)
                if get_token(img.GetVisibilityAttr(), time) == UsdGeom.Tokens.invisible or \
                        get_token(img.GetPurposeAttr(), time) in (UsdGeom.Tokens.guide, UsdGeom.Tokens.proxy):
                    it.PruneChildren()
                    continue
            if prim.IsA(UsdGeom.PointInstancer):
                scene.warn(f"{prim.GetPath()}: a PointInstancer inside a prototype is not supported; skipped")
                it.PruneChildren()
                continue
            if not (prim.IsA(UsdGeom.Mesh) or _is_implicit(prim)):
                continue
            mp = _mesh_prim(scene, prim, xf_cache, material_cache, drawn=True)
            relative = xf_cache.GetLocalToWorldTransform(prim) * root_inverse
            mp.instances = [to_core_matrix(relative * m) for m in placed]
            mp.instance_ids = chosen  # the PointInstancer's instance indices (instanceId AOV)
            prims.append(mp)


def _explicit_grains(prim):
    """Whether a PointInstancer holds a simulation's grains: GranularInstancedAggregateAPI, or
    every prototype a grain (GranularGrainAPI), which can only mean that."""
    if prim.HasAPI(schema.INSTANCED_AGGREGATE_API):
        return True
    targets = UsdGeom.PointInstancer(prim).GetPrototypesRel().GetForwardedTargets()
    roots = [prim.GetStage().GetPrimAtPath(t) for t in targets]
    return bool(roots) and all(r and r.HasAPI(schema.GRAIN_API) for r in roots)


def read_instanced_grains(scene, prim, xf_cache=None, material_cache=None, id=-1):
    """A PointInstancer's explicit grains at scene.time as core.InstancedGrainsDesc
    (core/instanced_grains.h): its arrays handed over as authored, each prototype root's own
    transform, the prototypes read when core asks. core checks everything and names
    prim.attribute; its grain materials are appended to scene.desc."""
    time = scene.time
    xf_cache = xf_cache or UsdGeom.XformCache(time)
    material_cache = {} if material_cache is None else material_cache
    pi = UsdGeom.PointInstancer(prim)
    targets = [str(t) for t in pi.GetPrototypesRel().GetForwardedTargets()]
    proto_xforms = []
    for t in targets:
        root = scene.stage.GetPrimAtPath(t)
        local = xf_cache.GetLocalTransformation(root)[0] if root and root.IsA(UsdGeom.Xformable) else Gf.Matrix4d(1)
        proto_xforms.append(to_core_matrix(local))

    def numbers(attr, columns, dtype, expected):
        # USD's own array, read when core asks for it and in place (10^8 instances are
        # gigabytes an array: one is held at a time).
        def read():
            a = get_array(attr, time, columns, dtype, expected, convert=False)
            return np.zeros(0, dtype) if a is None else a
        return read

    def lookup(path):
        p = scene.stage.GetPrimAtPath(path)
        return _mesh_prim(scene, p, xf_cache, material_cache, drawn=False) if p else None

    # invisibleIds and inactiveIds hide instances, as in every USD host: core checks every
    # instance as authored (errors name the authored index), then leaves them out.
    mask = pi.ComputeMaskAtTime(time)
    keep = None if not mask or all(mask) else np.asarray(mask, dtype=bool)
    try:
        return core.instanced_grains_from_usd(
            str(prim.GetPath()), prim.GetTypeName(), world_matrix(xf_cache, prim), targets, proto_xforms,
            numbers(pi.GetPositionsAttr(), 3, np.float32, "point3f[]"),
            numbers(pi.GetOrientationsAttr(), 4, np.float32, "quath[]"),  # (i, j, k, real), as USD holds it
            numbers(pi.GetScalesAttr(), 3, np.float32, "float3[]"),
            numbers(pi.GetProtoIndicesAttr(), 0, np.int64, "int[]"),
            numbers(pi.GetVelocitiesAttr(), 3, np.float32, "vector3f[]"),
            numbers(pi.GetAngularVelocitiesAttr(), 3, np.float32, "vector3f[]"),
            scene.desc, lookup, id, orientations_real_last=True, mask=keep,
            link_categories=link_categories(scene, str(prim.GetPath())))
    except core.InputError as e:
        raise translate_core_error(e) from None


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

def _settings_prim(stage, path=None):
    """The active render settings prim: `path` (granular render --settings), else the
    stage's renderSettingsPrimPath, else the first RenderSettings prim."""
    if path:
        prim = stage.GetPrimAtPath(path)
        if not prim or not prim.IsA(UsdRender.Settings):
            raise UserError("command line", "--settings", f'"{path}" is not a RenderSettings prim of the stage')
        return prim
    s = UsdRender.Settings.GetStageRenderSettings(stage)
    if s:
        return s.GetPrim()
    for prim in stage.Traverse():
        if prim.IsA(UsdRender.Settings):
            return prim
    return None


def read_camera(scene, prim, xf_cache):
    """The camera prim through core (usd_camera.h)."""
    path = str(prim.GetPath())
    record = prim_record(prim, core.usd_camera_attribute_names(), scene.time, xf_cache)
    scene.desc.camera = _core_call(core.camera_from_usd, record, scene.stage.GetTimeCodesPerSecond())
    scene.camera_path = path
    # Later checks of the whole description (the field of view) name the camera's attributes.
    attrs = {k: (path, k) for k in ("focalLength", "horizontalAperture", "verticalAperture",
                                    "horizontalApertureOffset", "verticalApertureOffset", "clippingRange",
                                    "fStop", "focusDistance")}
    attrs["lensRadius"] = (path, "fStop")
    attrs["transform"] = (path, "transform")
    scene.name("camera", path, attrs)


def _link_collection(collection):
    """A light's link collection as usd_lights.h names it: its path and membership query, or
    None where it holds every prim (includeRoot alone, as UsdImaging's collection cache finds
    it trivial and gives Hydra no category)."""
    query = collection.ComputeMembershipQuery()
    if query.UsesPathExpansionRuleMap():
        rules = query.GetAsPathExpansionRuleMap()
        if len(rules) == 1 and rules.get(Sdf.Path.absoluteRootPath) == Usd.Tokens.expandPrims:
            return None
    return str(collection.GetCollectionPath()), query


def _text_value(type_name, text):
    """One string of type `type_name` ("token", "rel") as core.UsdValue."""
    v = core.UsdValue()
    v.type_name, v.is_string, v.strings = type_name, True, [text]
    return v


def read_light(scene, prim, xf_cache):
    """A UsdLux light through core (usd_lights.h), its light-link collections named in its
    record (scene.light_links keeps their queries for the prims' categories): added to the
    scene, or, for a surface with MeshLightAPI, returned (its MeshPrim's light, which core
    makes a mesh light of its triangles)."""
    record = prim_record(prim, core.usd_light_attribute_names(), scene.time, xf_cache)
    attrs = record.attributes
    api = UsdLux.LightAPI(prim)
    for collection, entry in ((api.GetLightLinkCollectionAPI(), core.USD_LIGHT_LINK),
                              (api.GetShadowLinkCollectionAPI(), core.USD_SHADOW_LINK)):
        link = _link_collection(collection)
        if link is not None:
            attrs[entry] = _text_value("token", link[0])
            scene.light_links.append(link)
    record.attributes = attrs
    light, warnings = _core_call(core.light_from_usd, record)
    for w in warnings:
        scene.warn(w)
    if light is not None and light.type == core.LightType.Mesh:
        return light
    if light is not None:
        scene.desc.add_light(light)
    return None


def _transform_varies(prim):
    """Whether the prim's world transform may change with time (its own ops or an ancestor's)."""
    while prim and not prim.IsPseudoRoot():
        if prim.IsA(UsdGeom.Xformable) and UsdGeom.Xformable(prim).TransformMightBeTimeVarying():
            return True
        prim = prim.GetParent()
    return False


def _transform_motion(scene, time):
    """Transform motion blur: with the camera's shutter open, each mesh and each aggregate
    whose world transform changes over it gets its transforms at the shutter's open and close
    (core's MeshDesc.shutterXf, AggregateDesc.shutterXf; it moves linearly between them; an
    aggregate is built where it stands at the frame and moved, aggregate_motion.h). A
    PointInstancer's flattened instances stay still."""
    c = scene.desc.camera
    if not c.shutter_close > c.shutter_open or time.IsDefault():
        return
    fps = scene.stage.GetTimeCodesPerSecond()
    at_open = UsdGeom.XformCache(Usd.TimeCode(time.GetValue() + c.shutter_open * fps))
    at_close = UsdGeom.XformCache(Usd.TimeCode(time.GetValue() + c.shutter_close * fps))

    def sample(items):
        moved = False
        for m in items:
            ok = m.instance_id < 0 and Sdf.Path.IsValidPathString(m.name)[0]
            prim = scene.stage.GetPrimAtPath(m.name) if ok else None
            if not prim or not _transform_varies(prim):
                continue
            a, b = world_matrix(at_open, prim), world_matrix(at_close, prim)
            if a != b:
                m.shutter_xf = (a, b)
                moved = True
        return moved
    meshes, aggregates = list(scene.desc.meshes), list(scene.desc.aggregates)
    if sample(meshes):
        scene.desc.meshes = meshes
    if sample(aggregates):
        scene.desc.aggregates = aggregates


def _motion_blur_disabled(settings):
    """UsdRender's disableMotionBlur as UsdRenderComputeSpec flattens it for Hydra: the
    settings prim's first render product's where authored there, else the settings prim's.
    The deprecated instantaneousShutter, true on either, turns blur off as well, as
    UsdRenderComputeSpec means it to ("for backwards-compatibility"; the schema's text closes
    the shutter at its open instead: the same image when the shutter opens at the frame).
    OpenUSD 24.08's HdRenderSettings shows neither the settings prim's value without a product
    nor instantaneousShutter (what hdGranular does then: hdGranular/README.md)."""
    def authored(attr):
        return bool(attr.Get()) if attr.HasAuthoredValue() else None
    products = [p for p in (settings.GetStage().GetPrimAtPath(t)
                            for t in UsdRender.Settings(settings).GetProductsRel().GetForwardedTargets())
                if p and p.IsA(UsdRender.Product)]
    own = UsdRender.SettingsBase(settings)
    disabled = bool(authored(own.GetDisableMotionBlurAttr()) or authored(own.GetInstantaneousShutterAttr()))
    if products:
        product = UsdRender.SettingsBase(products[0])
        override = authored(product.GetDisableMotionBlurAttr())
        disabled = (disabled if override is None else override) or bool(authored(product.GetInstantaneousShutterAttr()))
    return disabled


def link_categories(scene, path):
    """The light- and shadow-link collections (scene.light_links) that include the prim at path."""
    if not scene.light_links or not Sdf.Path.IsValidPathString(path)[0]:
        return []
    p = Sdf.Path(path)
    return [name for name, query in scene.light_links if query.IsPathIncluded(p)]


def _is_light(prim):
    return prim.HasAPI(UsdLux.LightAPI)


# ---- the stage ---------------------------------------------------------------------------------

def read_stage(path, camera=None, width=None, height=None, surfaces=True, need_camera=True, stage=None,
               time=None, settings_path=None):
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
        if prim.IsA(UsdGeom.PointInstancer) and _explicit_grains(prim):
            scene.explicit_grains.append(prim)  # read after the meshes (their ids come first)
            it.PruneChildren()
            continue
        if not surfaces:
            continue
        if _is_light(prim) and not (prim.IsA(UsdGeom.Mesh) or _is_implicit(prim)):
            read_light(scene, prim, xf_cache)
            continue  # a light; a surface with MeshLightAPI is a mesh light (_mesh_prim)
        if prim.IsA(UsdGeom.Mesh) or _is_implicit(prim):
            prims.append(_mesh_prim(scene, prim, xf_cache, material_cache, drawn=True))
        elif prim.IsA(UsdGeom.PointInstancer):
            _instanced(scene, prim, xf_cache, material_cache, prims)
            it.PruneChildren()  # its prototypes are drawn through it only
        elif prim.IsA(UsdGeom.Gprim):
            unsupported.setdefault(prim.GetTypeName(), str(prim.GetPath()))
    for type_name, example in unsupported.items():
        scene.warn(f"{example}: {type_name} prims are not supported; skipped")
    # The primId and aggregateId AOVs' ids: each listed prim's place in traversal order
    # (Hydra's are its render index's).
    for i, mp in enumerate(prims):
        mp.id = i
        mp.link_categories = link_categories(scene, mp.path)
    _assemble(scene, prims, xf_cache, material_cache)
    if surfaces:
        for k, prim in enumerate(scene.explicit_grains):
            scene.desc.add_instanced_grains(
                read_instanced_grains(scene, prim, xf_cache, material_cache, id=len(prims) + k))
    core.order_usd_lights(scene.desc)

    # Resolution and camera: command line, else the render settings prim, else defaults.
    settings = _settings_prim(stage, settings_path)
    res = None
    settings_camera = None
    if settings is not None:
        res = _core_call(core.resolution_from_usd, prim_record(settings, ("resolution",), time, authored_only=True))
        targets = UsdRender.Settings(settings).GetCameraRel().GetForwardedTargets()
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
        if settings is not None and _motion_blur_disabled(settings):
            core.still_frame(scene.desc)
        _transform_motion(scene, time)
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
    """The data window of the settings prim's first render product as the render's crop
    (core.data_window_from_usd): only those pixels are rendered, and the EXR keeps their
    place in the full image. Hydra hosts hand hdGranular the same value."""
    targets = UsdRender.Settings(settings).GetProductsRel().GetForwardedTargets()
    product = settings.GetStage().GetPrimAtPath(targets[0]) if targets else None
    product_record = None
    if product and product.IsA(UsdRender.Product):  # else none, no such prim, or not a product
        product_record = prim_record(product, ("dataWindowNDC",), time, authored_only=True)
    s = scene.desc.settings
    window, warnings = _core_call(core.data_window_from_usd,
                                  prim_record(settings, ("dataWindowNDC",), time, authored_only=True),
                                  product_record, s.width, s.height)
    for w in warnings:
        scene.warn(w)
    if window is not None:
        s.crop = window
        where = product_record if "dataWindowNDC" in product_record.attributes else None
        scene.names["render"]["crop"] = (where.path if where else str(settings.GetPath()), "dataWindowNDC")


def _rel_value(rel):
    """A relationship's first forwarded target as core.UsdValue (type "rel"), or None."""
    targets = rel.GetForwardedTargets() if rel else []
    if not targets:
        return None
    return _text_value("rel", str(targets[0]))


def _render_record(prim, names, time):
    """A settings or product prim's authored values (what a product inherits is decided by
    core), its camera relationship's target as attribute "camera"."""
    r = prim_record(prim, [n for n in names if n != "camera"], time, authored_only=True)
    cam = _rel_value(prim.GetRelationship("camera"))
    if cam is not None:
        attrs = dict(r.attributes)
        attrs["camera"] = cam
        r.attributes = attrs
    return r


def read_render_products(stage, time=None, settings_path=None):
    """The active render settings prim's products (core.render_product_from_usd: what each
    inherits, its vars' film channels and pixel types), at `time`: (settings prim or None,
    [core.RenderProductDesc], [warnings]). UserError naming prim.attribute on bad values."""
    time = as_time_code(time, stage)
    settings = _settings_prim(stage, settings_path)
    if settings is None:
        return None, [], []
    names = core.usd_render_product_attribute_names()
    settings_record = _render_record(settings, names, time)
    products, warnings = [], []
    for target in UsdRender.Settings(settings).GetProductsRel().GetForwardedTargets():
        prim = stage.GetPrimAtPath(target)
        if not prim or not prim.IsA(UsdRender.Product):
            raise UserError(str(settings.GetPath()), "products", f"target {target} is not a RenderProduct")
        var_records = []
        for vt in UsdRender.Product(prim).GetOrderedVarsRel().GetForwardedTargets():
            var = stage.GetPrimAtPath(vt)
            if not var or not var.IsA(UsdRender.Var):
                raise UserError(str(prim.GetPath()), "orderedVars", f"target {vt} is not a RenderVar")
            var_records.append(prim_record(var, core.usd_render_var_attribute_names(), time, authored_only=True))
        product, w = _core_call(core.render_product_from_usd, settings_record, _render_record(prim, names, time),
                                var_records)
        warnings += [x for x in w if x not in warnings]
        if product is not None:
            products.append(product)
    return settings, products, warnings


def validate(scene):
    """core's validation of the whole description, errors in USD terms."""
    try:
        core.validate_scene_desc(scene.desc)
    except core.InputError as e:
        raise translate_core_error(e, scene) from None
