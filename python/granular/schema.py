"""The granular schema from Python: names, fallbacks, authoring and reading.

GranularAggregateAPI (on the boundary Mesh) and GranularGrainAPI (on each grain
prototype Mesh) keep every property as a constant primvar in the primvars:granular:
namespace (see schemas/README.md for why). The fallbacks here are the schema's
(schemas/schema.usda); a test checks that they agree. Readers apply them when a primvar
is not authored, exactly as a Hydra delegate must (Hydra delivers authored primvars only).
"""
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from .errors import UserError

AGGREGATE_API = "GranularAggregateAPI"
GRAIN_API = "GranularGrainAPI"
NAMESPACE = "primvars:granular:"

# base name -> (Sdf value type name, fallback)
AGGREGATE_PROPERTIES = {
    "grainRadius": ("float", 0.01),
    "packingRate": ("float", 0.6),
    "prototypes": ("string[]", ()),
    "weights": ("float[]", ()),
    "seed": ("int", 1),
    "tileSpheres": ("int", 512),
}
GRAIN_PROPERTIES = {
    "ior": ("float", 1.5),
    "absorption": ("color3f", (0.0, 0.0, 0.0)),
    "roughness": ("float", 0.0),
}


def attr_name(base):
    """'packingRate' -> 'primvars:granular:packingRate'."""
    return NAMESPACE + base


def _prim(p):
    return p.GetPrim() if hasattr(p, "GetPrim") else p


def _create(prim, base, table, value):
    type_name, _ = table[base]
    pv = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(
        "granular:" + base, Sdf.ValueTypeNames.Find(type_name), UsdGeom.Tokens.constant)
    pv.Set(value)
    return pv


def apply_aggregate(mesh, prototypes, grain_radius=None, packing_rate=None, weights=None, seed=None,
                    tile_spheres=None, relative_paths=True, author_fallbacks=True):
    """Makes `mesh` (a UsdGeom.Mesh or its prim) an aggregate boundary.

    prototypes: prims or paths of the grain prototype meshes; written as paths relative
    to the aggregate when relative_paths (they then survive referencing the asset under
    another prim). With author_fallbacks every property is authored, so that Hydra, which
    does not see schema fallbacks, gets a complete description. Returns the prim.
    """
    prim = _prim(mesh)
    if not prim.IsA(UsdGeom.Mesh):
        raise UserError(prim.GetPath(), "", f"{AGGREGATE_API} applies to a Mesh, not a {prim.GetTypeName() or 'typeless prim'}")
    prim.ApplyAPI(AGGREGATE_API)
    paths = []
    for p in prototypes:
        path = _prim(p).GetPath() if not isinstance(p, (str, Sdf.Path)) else Sdf.Path(str(p))
        if relative_paths and path.IsAbsolutePath():
            path = path.MakeRelativePath(prim.GetPath())
        paths.append(str(path))
    values = {
        "prototypes": Vt.StringArray(paths),
        "grainRadius": grain_radius,
        "packingRate": packing_rate,
        "weights": None if weights is None else Vt.FloatArray([float(w) for w in weights]),
        "seed": seed,
        "tileSpheres": tile_spheres,
    }
    for base, value in values.items():
        if value is None and author_fallbacks:
            value = AGGREGATE_PROPERTIES[base][1]
            if base == "weights":
                value = Vt.FloatArray([])
        if value is not None:
            _create(prim, base, AGGREGATE_PROPERTIES, value)
    return prim


def apply_grain(mesh, ior=None, absorption=None, roughness=None, invisible=True, author_fallbacks=True):
    """Makes `mesh` a grain prototype with a dielectric grain material.

    With invisible (the documented convention) the mesh is made invisible so that no
    renderer draws it as ordinary geometry. Returns the prim.
    """
    prim = _prim(mesh)
    if not prim.IsA(UsdGeom.Mesh):
        raise UserError(prim.GetPath(), "", f"{GRAIN_API} applies to a Mesh, not a {prim.GetTypeName() or 'typeless prim'}")
    prim.ApplyAPI(GRAIN_API)
    values = {"ior": ior, "absorption": None if absorption is None else Gf.Vec3f(*absorption), "roughness": roughness}
    for base, value in values.items():
        if value is None and author_fallbacks:
            value = GRAIN_PROPERTIES[base][1]
            if base == "absorption":
                value = Gf.Vec3f(*value)
        if value is not None:
            _create(prim, base, GRAIN_PROPERTIES, value)
    if invisible:
        UsdGeom.Imageable(prim).MakeInvisible()
    return prim


# ---- reading --------------------------------------------------------------------------

class Value:
    """A resolved primvar: its value, where it came from (prim path) and its attribute name."""

    def __init__(self, value, source, name, authored):
        self.value = value
        self.source = source
        self.name = name
        self.authored = authored


def _find(prim, base):
    """The primvar as Hydra sees it: on the prim, else a constant primvar inherited from
    an ancestor; None when neither has a value."""
    api = UsdGeom.PrimvarsAPI(prim)
    pv = api.FindPrimvarWithInheritance("granular:" + base)
    if pv and pv.HasAuthoredValue():
        return pv
    return None


_SCALAR_TYPES = {"float": ("float", "double", "half"), "int": ("int", "int64", "uint", "uint64", "uchar")}


def _authored_type(attr):
    """The type a layer authored (a file may contradict the schema's type, which
    UsdAttribute.GetTypeName reports instead)."""
    for spec in attr.GetPropertyStack(Usd.TimeCode.Default()):
        tn = getattr(spec, "typeName", None)
        if tn:
            return str(tn)
    return str(attr.GetTypeName())


def _check_type(pv, expected):
    name = pv.GetAttr().GetName()
    src = pv.GetAttr().GetPrim().GetPath()
    actual = _authored_type(pv.GetAttr())
    if expected in _SCALAR_TYPES:
        if actual not in _SCALAR_TYPES[expected]:
            raise UserError(src, name, f"has type {actual}, expected {expected}")
    elif expected == "float[]":
        if actual not in ("float[]", "double[]", "half[]"):
            raise UserError(src, name, f"has type {actual}, expected float[]")
    elif expected == "color3f":
        if actual not in ("color3f", "color3d", "color3h", "float3", "double3", "half3", "vector3f"):
            raise UserError(src, name, f"has type {actual}, expected color3f")
    elif actual != expected:
        raise UserError(src, name, f"has type {actual}, expected {expected}")
    interp = pv.GetInterpolation()
    if interp != UsdGeom.Tokens.constant:
        raise UserError(src, name, f"has interpolation {interp}, expected constant")


def read_property(prim, base, table, time=Usd.TimeCode.Default()):
    """Value of a granular primvar of prim (inherited like Hydra does), else the fallback."""
    type_name, fallback = table[base]
    pv = _find(prim, base)
    if pv is None:
        return Value(fallback, str(prim.GetPath()), attr_name(base), False)
    _check_type(pv, type_name)
    v = pv.ComputeFlattened(time)
    src = str(pv.GetAttr().GetPrim().GetPath())
    name = pv.GetAttr().GetName()
    if v is None:
        return Value(fallback, str(prim.GetPath()), attr_name(base), False)
    try:
        if type_name == "float":
            v = float(v)
        elif type_name == "int":
            if isinstance(v, float) or isinstance(v, bool):
                raise TypeError
            v = int(v)
        elif type_name == "float[]":
            v = tuple(float(x) for x in v)
        elif type_name == "string[]":
            if isinstance(v, str):
                raise TypeError
            v = tuple(x if isinstance(x, str) else _fail() for x in v)
        elif type_name == "color3f":
            if len(v) != 3:
                raise TypeError
            v = (float(v[0]), float(v[1]), float(v[2]))
    except (TypeError, ValueError):
        raise UserError(src, name, f"has value {v!r}, expected a {type_name}") from None
    return Value(v, src, name, True)


def _fail():
    raise TypeError


def read_aggregate(prim, time=Usd.TimeCode.Default()):
    """All GranularAggregateAPI values of prim as {base name: Value}."""
    return {k: read_property(prim, k, AGGREGATE_PROPERTIES, time) for k in AGGREGATE_PROPERTIES}


def read_grain(prim, time=Usd.TimeCode.Default()):
    """All GranularGrainAPI values of prim as {base name: Value}."""
    return {k: read_property(prim, k, GRAIN_PROPERTIES, time) for k in GRAIN_PROPERTIES}


def resolve_prototype_path(aggregate_prim, text):
    """A prototypes entry (absolute, or relative to the aggregate) as an absolute Sdf.Path,
    or raises UserError naming the aggregate's prototypes attribute."""
    obj = aggregate_prim.GetPath()
    if not text:
        raise UserError(obj, attr_name("prototypes"), "has an empty path")
    ok, why = Sdf.Path.IsValidPathString(text)
    if not ok:
        raise UserError(obj, attr_name("prototypes"), f'"{text}" is not a valid path ({why})')
    path = Sdf.Path(text)
    if not path.IsAbsolutePath():
        path = path.MakeAbsolutePath(obj)
    if path.isEmpty or not path.IsPrimPath():
        raise UserError(obj, attr_name("prototypes"), f'"{text}" is not a prim path')
    return path
