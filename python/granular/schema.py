"""The granular schema from Python: names, fallbacks, authoring and reading.

GranularAggregateAPI (on the boundary Mesh) and GranularGrainAPI (on each grain
prototype Mesh) keep every property as a constant primvar in the primvars:granular:
namespace (see schemas/README.md for why). The fallbacks here are the schema's
(schemas/schema.usda), for authoring; a test checks that they agree with it and with
core, which applies them when a primvar is not authored (Hydra delivers authored
primvars only) and gives the values their meaning (core/granular_prims.h).
"""
import re

from pxr import Gf, Sdf, Tf, Usd, UsdGeom, Vt

from .errors import UserError, describe_tf_error

AGGREGATE_API = "GranularAggregateAPI"
GRAIN_API = "GranularGrainAPI"
# On a PointInstancer: every instance an explicit grain (a simulation's); no properties.
INSTANCED_AGGREGATE_API = "GranularInstancedAggregateAPI"
NAMESPACE = "primvars:granular:"

# base name -> (Sdf value type name, fallback)
AGGREGATE_PROPERTIES = {
    "grainRadius": ("float", 0.01),
    "packingRate": ("float", 0.6),
    "prototypes": ("string[]", ()),
    "weights": ("float[]", ()),
    "seed": ("int", 1),
    "tileSpheres": ("int", 512),
    "sizes": ("float[]", ()),
    "sizeSpread": ("float", 0.0),
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
                    tile_spheres=None, relative_paths=True, author_fallbacks=True, sizes=None, size_spread=None):
    """Makes `mesh` (a UsdGeom.Mesh or its prim) an aggregate boundary.

    prototypes: prims or paths of the grain prototype meshes; written as paths relative
    to the aggregate when relative_paths (they then survive referencing the asset under
    another prim). With author_fallbacks every property is authored, so that Hydra, which
    does not see schema fallbacks, gets a complete description — but sizes and size_spread
    only when given: their fallbacks are the equal-sized grains every renderer assumes.
    Returns the prim.
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
        "sizes": None if sizes is None else Vt.FloatArray([float(x) for x in sizes]),
        "sizeSpread": size_spread,
    }
    for base, value in values.items():
        if value is None and author_fallbacks and base not in ("sizes", "sizeSpread"):
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


def apply_instanced_aggregate(instancer):
    """Makes a PointInstancer an aggregate of explicit grains (each instance one grain of its
    prototype Mesh, see schemas/README.md). Returns the prim."""
    prim = _prim(instancer)
    if not prim.IsA(UsdGeom.PointInstancer):
        raise UserError(prim.GetPath(), "", f"{INSTANCED_AGGREGATE_API} applies to a PointInstancer, "
                                            f"not a {prim.GetTypeName() or 'typeless prim'}")
    prim.ApplyAPI(INSTANCED_AGGREGATE_API)
    return prim


# ---- reading --------------------------------------------------------------------------
# What the primvars mean (types, fallbacks, ranges, which prims are aggregates and
# prototypes) is core's, shared with the Hydra delegate (core/granular_prims.h); here they
# are only read from USD.

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


def authored_type(attr):
    """The type a layer authored (a file may contradict the schema's type, which
    UsdAttribute.GetTypeName reports instead)."""
    for spec in attr.GetPropertyStack(Usd.TimeCode.Default()):
        tn = getattr(spec, "typeName", None)
        if tn:
            return str(tn)
    return str(attr.GetTypeName())


def flattened(pv, time=Usd.TimeCode.Default()):
    """pv.ComputeFlattened(time), an error naming the attribute where usd-core cannot: its
    indices of another type than int[] (usd-core raised a bare Tf error, "No indices
    authored for indexed primvar"), or any other failure to flatten."""
    indices = pv.GetIndicesAttr()
    if indices and indices.HasAuthoredValue() and authored_type(indices) != "int[]":
        raise UserError(str(indices.GetPrim().GetPath()), indices.GetName(),
                        f"has a {authored_type(indices)} value, expected int[]")
    try:
        return pv.ComputeFlattened(time)
    except Tf.ErrorException as e:
        attr = pv.GetAttr()
        raise UserError(str(attr.GetPrim().GetPath()), attr.GetName(),
                        "cannot be read: " + " ".join(describe_tf_error(e).split())) from None


def numbers(v):
    """Numbers of a scalar, vector or array value, flattened; [] when there are none."""
    if isinstance(v, (bool, int, float)):
        return [float(v)]
    out = []
    try:
        for x in v:
            out.extend(numbers(x))
    except TypeError:
        return []
    return out


def primvar_value(pv, time=Usd.TimeCode.Default()):
    """A primvar as core.PrimvarValue (authored type, interpolation, the prim it was
    authored on, values as found), or None without a value."""
    import granular_core as core
    attr = pv.GetAttr()
    v = flattened(pv, time)
    type_name = authored_type(attr)
    # USD reads no value of a type that contradicts the schema's: core still gets the type
    # to report it.
    if v is None and type_name == str(attr.GetTypeName()):
        return None
    out = core.PrimvarValue()
    out.type_name = type_name
    out.interpolation = pv.GetInterpolation()
    out.source = str(attr.GetPrim().GetPath())
    out.is_array = out.type_name.endswith("[]")
    out.is_string = out.type_name.replace("[]", "") in ("string", "token")
    if v is not None:  # else: no value of that type, only the type, for core to report
        if out.is_string:
            out.strings = [v] if isinstance(v, str) else [str(x) for x in v]
        elif not isinstance(v, str):
            out.numbers = numbers(v)
    return out


def primvar_values(prim, names=None, time=Usd.TimeCode.Default()):
    """The granular primvars of prim that have a value, inherited as Hydra sees them:
    {base name: core.PrimvarValue} (names: default every property of both APIs)."""
    out = {}
    for base in names or (*AGGREGATE_PROPERTIES, *GRAIN_PROPERTIES):
        pv = _find(prim, base)
        value = primvar_value(pv, time) if pv is not None else None
        if value is not None:
            out[base] = value
    return out


def _snake(base):
    return re.sub(r"([A-Z])", r"_\1", base).lower()


def _read(prim, table, read, time):
    import granular_core as core
    path = str(prim.GetPath())
    found = primvar_values(prim, table, time)
    mp = core.MeshPrim()
    mp.path = path
    mp.granular = found
    try:
        values = read(mp)
    except core.InputError as e:
        raise UserError(e.object, e.attribute, e.detail) from None
    out = {}
    for base in table:
        value = getattr(values, _snake(base))
        value = tuple(value) if isinstance(value, list) else value
        pv = found.get(base)
        out[base] = Value(value, pv.source if pv else path, attr_name(base), pv is not None)
    return out


def read_aggregate(prim, time=Usd.TimeCode.Default()):
    """All GranularAggregateAPI values of prim as {base name: Value} (fallbacks where
    unauthored); a wrongly typed value is a UserError naming it."""
    import granular_core as core
    return _read(prim, AGGREGATE_PROPERTIES, core.read_aggregate_values, time)


def read_grain(prim, time=Usd.TimeCode.Default()):
    """All GranularGrainAPI values of prim as {base name: Value}."""
    import granular_core as core
    return _read(prim, GRAIN_PROPERTIES, core.read_grain_values, time)


def resolve_prototype_path(aggregate_prim, text):
    """A prototypes entry (absolute, or relative to the aggregate) as an absolute Sdf.Path,
    or raises UserError naming the aggregate's prototypes attribute."""
    import granular_core as core
    try:
        return Sdf.Path(core.resolve_prototype_path(str(aggregate_prim.GetPath()), text))
    except core.InputError as e:
        raise UserError(e.object, e.attribute, e.detail) from None
