"""The codeless schema: registration, fallbacks, documentation, generation, authoring."""
import filecmp
import shutil
import subprocess
import sys

import pytest
from conftest import ROOT, add_mesh
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

import granular
import granular_core as core
from granular import schema

APIS = {schema.AGGREGATE_API: schema.AGGREGATE_PROPERTIES, schema.GRAIN_API: schema.GRAIN_PROPERTIES}


def test_schema_plugin_registers_both_apis():
    assert granular.schema_registered()
    reg = Usd.SchemaRegistry()
    for name in APIS:
        assert reg.FindAppliedAPIPrimDefinition(name) is not None, name
        assert Usd.SchemaRegistry.GetAPISchemaTypeName(Usd.SchemaRegistry.GetTypeFromSchemaTypeName(name)) == name
        assert Usd.SchemaRegistry.GetAPISchemaCanOnlyApplyToTypeNames(name) == ["Mesh"]


@pytest.mark.parametrize("api", sorted(APIS))
def test_every_property_has_its_fallback_type_interpolation_and_doc(api):
    d = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(api)
    assert d.GetDocumentation().strip(), f"{api} has no documentation"
    expected = APIS[api]
    assert sorted(d.GetPropertyNames()) == sorted(schema.attr_name(k) for k in expected)
    for base, (type_name, fallback) in expected.items():
        a = d.GetAttributeDefinition(schema.attr_name(base))
        assert str(a.GetTypeName()) == type_name, base
        assert a.GetMetadata("interpolation") == "constant", base
        doc = a.GetDocumentation()
        assert len(doc) > 30, f"{base}: documentation {doc!r}"
        value = a.GetFallbackValue()
        if isinstance(fallback, tuple) and type_name.endswith("[]"):
            assert list(value) == list(fallback), base
        elif isinstance(fallback, tuple):
            assert tuple(value) == pytest.approx(fallback), base
        else:
            assert value == pytest.approx(fallback), base


def test_fallbacks_are_the_core_defaults():
    # The schema's fallbacks and core's AggregateDesc defaults describe the same aggregate.
    ad = core.AggregateDesc()
    props = schema.AGGREGATE_PROPERTIES
    assert ad.grain_radius == pytest.approx(props["grainRadius"][1])
    assert ad.packing_rate == pytest.approx(props["packingRate"][1])
    assert ad.seed == props["seed"][1]
    assert ad.tile_spheres == props["tileSpheres"][1]
    assert core.MaterialDesc().ior == pytest.approx(schema.GRAIN_PROPERTIES["ior"][1])


def test_generated_files_are_up_to_date(tmp_path):
    """usdGenSchema run on schema.usda reproduces the committed generated files."""
    import jinja2  # noqa: F401  (usdGenSchema needs it; make installs it into .venv)
    src = ROOT / "schemas"
    for f in ("schema.usda", "plugInfo.json"):
        shutil.copy(src / f, tmp_path / f)
    r = subprocess.run(["bash", "-c", f'cd "{tmp_path}" && "{sys.executable}" -m pxr.Usd.usdGenSchema -q schema.usda .'],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    for f in ("generatedSchema.usda",):
        assert filecmp.cmp(src / f, tmp_path / f, shallow=False), f"schemas/{f} is stale: run `make schemas`"
    assert (tmp_path / "plugInfo.json").read_text() == (src / "plugInfo.json").read_text()


def _stage_with_grains():
    stage = Usd.Stage.CreateInMemory()
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Scope.Define(stage, "/World/Grains")
    a = add_mesh(stage, "/World/Grains/A", core.make_icosphere(1))
    b = add_mesh(stage, "/World/Grains/B", core.make_icosphere(1))
    box = add_mesh(stage, "/World/Castle", core.make_box((0, 0, 0), (1, 1, 1)))
    return stage, a, b, box


def test_authoring_writes_constant_primvars_that_read_back():
    stage, a, b, box = _stage_with_grains()
    schema.apply_grain(a, ior=1.55, absorption=(0.1, 0.2, 0.3))
    schema.apply_grain(b)
    schema.apply_aggregate(box, [a, b], grain_radius=0.02, packing_rate=0.55, weights=[2, 1], seed=7,
                           tile_spheres=256)
    prim = box.GetPrim()
    assert prim.HasAPI(schema.AGGREGATE_API)
    assert a.GetPrim().HasAPI(schema.GRAIN_API)
    # Prototypes are made invisible, so that no host draws them as geometry.
    assert UsdGeom.Imageable(a).ComputeVisibility() == UsdGeom.Tokens.invisible
    # Relative paths, resolved against the aggregate.
    protos = prim.GetAttribute("primvars:granular:prototypes").Get()
    assert list(protos) == ["../Grains/A", "../Grains/B"]
    assert [str(schema.resolve_prototype_path(prim, p)) for p in protos] == ["/World/Grains/A", "/World/Grains/B"]
    # Everything is an authored constant primvar: what Hydra delivers to a delegate.
    authored = {pv.GetPrimvarName() for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithAuthoredValues()}
    # (All but sizes and sizeSpread, authored only when given: equal sizes are the default
    # every renderer assumes.)
    assert {"granular:" + k for k in schema.AGGREGATE_PROPERTIES if k not in ("sizes", "sizeSpread")} <= authored
    assert "granular:sizes" not in authored
    schema.apply_aggregate(box, [a, b], sizes=[1.0, 0.5], size_spread=0.1, author_fallbacks=False)
    sized = schema.read_aggregate(prim)
    assert list(sized["sizes"].value) == pytest.approx([1.0, 0.5]) and sized["sizeSpread"].value == pytest.approx(0.1)
    for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvarsWithAuthoredValues():
        assert pv.GetInterpolation() == UsdGeom.Tokens.constant
    v = schema.read_aggregate(prim)
    assert v["grainRadius"].value == pytest.approx(0.02)
    assert v["packingRate"].value == pytest.approx(0.55)
    assert v["weights"].value == (2.0, 1.0)
    assert v["seed"].value == 7 and v["tileSpheres"].value == 256
    g = schema.read_grain(a.GetPrim())
    assert g["ior"].value == pytest.approx(1.55)
    assert g["absorption"].value == pytest.approx((0.1, 0.2, 0.3))
    assert schema.read_grain(b.GetPrim())["ior"].value == pytest.approx(1.5)


def test_unauthored_values_read_as_fallbacks_and_inherit_from_ancestors():
    stage, a, b, box = _stage_with_grains()
    schema.apply_aggregate(box, [a], author_fallbacks=False)
    prim = box.GetPrim()
    v = schema.read_aggregate(prim)
    assert not v["grainRadius"].authored and v["grainRadius"].value == pytest.approx(0.01)
    assert v["weights"].value == () and v["seed"].value == 1
    # The schema's fallback is what USD itself returns, too.
    assert prim.GetAttribute("primvars:granular:packingRate").Get() == pytest.approx(0.6)
    # A constant primvar on an ancestor is inherited (as UsdImaging does), and the
    # value knows where it was authored.
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World")).CreatePrimvar(
        "granular:grainRadius", Sdf.ValueTypeNames.Float, UsdGeom.Tokens.constant).Set(0.05)
    v = schema.read_aggregate(prim)
    assert v["grainRadius"].value == pytest.approx(0.05) and v["grainRadius"].source == "/World"


def test_api_applies_to_meshes_only():
    stage = Usd.Stage.CreateInMemory()
    x = UsdGeom.Xform.Define(stage, "/X")
    assert not x.GetPrim().CanApplyAPI(schema.AGGREGATE_API)
    assert UsdGeom.Mesh.Define(stage, "/M").GetPrim().CanApplyAPI(schema.AGGREGATE_API)
    with pytest.raises(granular.errors.UserError, match="applies to a Mesh, not a Xform"):
        schema.apply_aggregate(x, [])


def test_wrongly_typed_primvar_is_reported_with_its_name():
    # A file can author a type that contradicts the schema (the Python API refuses to).
    stage = Usd.Stage.CreateInMemory()
    stage.GetRootLayer().ImportFromString("""#usda 1.0
def Mesh "Castle" (prepend apiSchemas = ["GranularAggregateAPI"])
{
    string primvars:granular:seed = "seven" (interpolation = "constant")
}
""")
    with pytest.raises(granular.errors.UserError) as e:
        schema.read_aggregate(stage.GetPrimAtPath("/Castle"))
    assert str(e.value) == "/Castle.primvars:granular:seed: has type string, expected int"


def test_a_double_value_is_accepted_for_a_float_property():
    stage, a, b, box = _stage_with_grains()
    schema.apply_aggregate(box, [a])
    stage = Usd.Stage.CreateInMemory()
    stage.GetRootLayer().ImportFromString("""#usda 1.0
def Mesh "Castle" (prepend apiSchemas = ["GranularAggregateAPI"])
{
    double primvars:granular:packingRate = 0.5 (interpolation = "constant")
}
""")
    assert schema.read_aggregate(stage.GetPrimAtPath("/Castle"))["packingRate"].value == pytest.approx(0.5)


# Entries of `prototypes` as users write them, well and badly: core resolves them without
# USD, with SdfPath's syntax and words ("../" alone is left out: Sdf names no expectation).
PATHS = ["/", ".", "..", "/A/", "//A", "A//B", "../Grains/A", "A", "Grains/A", "../../../X", "../../..", "../..",
         "/A/../B", "A/../B", "a b", "/A.b", "/A.b:c", "/A{v=x}", "/A{v=x}B", "/A{v=x}{w=y}", "/A[/B]", "/A.b[/C]",
         "1A", "/A/1B", "é", "/Wörld", "./A", "A/.", "../.", "A.", "/A.b.c", "/A.b:", "-", "A-B", "/A/B.rel[/T].attr",
         "/A{v=}", "/A.expression", "/A.b.mapper[/T]", "/A{v}", "/A{v=x", "/A{=x}", "/A.b[/C]x", "/A.b[/C",
         "/A.b.mapper", "..A", "...", "/A:b", "/A.b::c", "/A.1b", "/ A", "/A{v=x.y}", ".b", "../A.b", "A/B{v=x}C/D"]


@pytest.mark.parametrize("text", PATHS)
def test_prototype_paths_resolve_as_sdf_resolves_them(text):
    anchor = Sdf.Path("/World/Castle")
    ok, why = Sdf.Path.IsValidPathString(text)
    if ok:
        p = Sdf.Path(text)
        a = p if p.IsAbsolutePath() else p.MakeAbsolutePath(anchor)
        expected = str(a) if p.IsPrimPath() and a.IsPrimPath() else f'"{text}" is not a prim path'
    else:
        expected = f'"{text}" is not a valid path ({why.strip()})'
    try:
        got = core.resolve_prototype_path(str(anchor), text)
    except core.InputError as e:
        assert (e.object, e.attribute) == ("/World/Castle", "primvars:granular:prototypes")
        got = e.detail
    assert got == expected
