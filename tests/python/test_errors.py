"""Bad input: exit status 2, one line naming the prim and the attribute, no output file,
never a traceback."""
import math
import re

import pytest
from conftest import add_mesh, run_cli, run_script
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

import granular_core as core


def _set(path, name, type_name, value):
    def mutate(stage):
        prim = stage.GetPrimAtPath(path)
        attr = prim.GetAttribute(name)
        if not attr:
            attr = UsdGeom.PrimvarsAPI(prim).CreatePrimvar(
                name.replace("primvars:", ""), Sdf.ValueTypeNames.Find(type_name), UsdGeom.Tokens.constant).GetAttr()
        attr.Set(value)
    return mutate


def _both(first, second):
    def mutate(stage):
        first(stage)
        second(stage)
    return mutate


def _nan_point(path):
    def mutate(stage):
        a = UsdGeom.Mesh(stage.GetPrimAtPath(path)).GetPointsAttr()
        pts = list(a.Get())
        pts[0] = Gf.Vec3f(float("nan"), 0, 0)
        a.Set(Vt.Vec3fArray(pts))
    return mutate


def _open_boundary(stage):
    m = UsdGeom.Mesh(stage.GetPrimAtPath("/World/Castle"))
    m.GetFaceVertexIndicesAttr().Set(list(m.GetFaceVertexIndicesAttr().Get())[:-3])
    m.GetFaceVertexCountsAttr().Set(list(m.GetFaceVertexCountsAttr().Get())[:-1])


def _sphere_prototype(stage):
    UsdGeom.Sphere.Define(stage, "/World/Grains/Ball")
    stage.GetPrimAtPath("/World/Castle").GetAttribute("primvars:granular:prototypes").Set(["../Grains/A", "../Grains/Ball"])


def _api_on_xform(stage):
    UsdGeom.Xform.Define(stage, "/World/Thing").GetPrim().ApplyAPI("GranularAggregateAPI")


def _inherited_packing_rate(stage):
    stage.GetPrimAtPath("/World/Castle").RemoveProperty("primvars:granular:packingRate")
    UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World")).CreatePrimvar(
        "granular:packingRate", Sdf.ValueTypeNames.Float, UsdGeom.Tokens.constant).Set(0.7)


def _no_camera(stage):
    stage.RemovePrim("/World/Camera")


def _missing_dome_texture(stage):
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateTextureFileAttr(Sdf.AssetPath("nope.exr"))


P = "primvars:granular:"
CASES = {
    # name: (mutate, exact message or a list of fragments)
    "packing rate": (_set("/World/Castle", P + "packingRate", "float", 0.9),
                     "error: /World/Castle.primvars:granular:packingRate: 0.9 is outside (0, 0.64]"),
    "zero packing rate": (_set("/World/Castle", P + "packingRate", "float", 0.0),
                          "error: /World/Castle.primvars:granular:packingRate: 0 is outside (0, 0.64]"),
    "inherited packing rate": (_inherited_packing_rate,
                               "error: /World.primvars:granular:packingRate: 0.7 is outside (0, 0.64]"),
    "grain radius": (_set("/World/Castle", P + "grainRadius", "float", -0.5),
                     "error: /World/Castle.primvars:granular:grainRadius: -0.5 must be finite and > 0"),
    "grain radius too small": (_set("/World/Castle", P + "grainRadius", "float", 1e-6),
                               ["error: /World/Castle.primvars:granular:grainRadius: ", "too small"]),
    "tile spheres": (_set("/World/Castle", P + "tileSpheres", "int", 4),
                     "error: /World/Castle.primvars:granular:tileSpheres: 4 is outside [8, 100000]"),
    "seed": (_set("/World/Castle", P + "seed", "int", -3),
             "error: /World/Castle.primvars:granular:seed: -3 must be >= 0"),
    "missing prototype": (_set("/World/Castle", P + "prototypes", "string[]", ["../Grains/A", "../Grains/Nope"]),
                          'error: /World/Castle.primvars:granular:prototypes: prototype "../Grains/Nope" '
                          "(/World/Grains/Nope) does not exist"),
    "non-mesh prototype": (_sphere_prototype,
                           'error: /World/Castle.primvars:granular:prototypes: prototype "../Grains/Ball" '
                           "(/World/Grains/Ball) is a Sphere, not a Mesh"),
    "no prototypes": (_set("/World/Castle", P + "prototypes", "string[]", []),
                      "error: /World/Castle.primvars:granular:prototypes: is empty (at least one grain prototype "
                      "mesh is needed)"),
    "weights count": (_set("/World/Castle", P + "weights", "float[]", [1.0, 2.0, 3.0]),
                      "error: /World/Castle.primvars:granular:weights: has 3 entries but there are 2 prototypes"),
    "negative weight": (_set("/World/Castle", P + "weights", "float[]", [1.0, -1.0]),
                        "error: /World/Castle.primvars:granular:weights: weight 1 = -1 must be finite and >= 0"),
    "zero weights": (_set("/World/Castle", P + "weights", "float[]", [0.0, 0.0]),
                     "error: /World/Castle.primvars:granular:weights: are all zero"),
    "nan boundary point": (_nan_point("/World/Castle"), ["error: /World/Castle.points: point 0 is not finite"]),
    "nan prototype point": (_nan_point("/World/Grains/B"), ["error: /World/Grains/B.points: point 0 is not finite"]),
    "open boundary": (_open_boundary, ["error: /World/Castle.faceVertexIndices: open boundary: edge"]),
    "grain ior": (_set("/World/Grains/A", P + "ior", "float", 5.0),
                  "error: /World/Grains/A.primvars:granular:ior: 5 is outside [1, 4]"),
    "grain absorption": (_set("/World/Grains/A", P + "absorption", "color3f", Gf.Vec3f(-1, 0, 0)),
                         "error: /World/Grains/A.primvars:granular:absorption: (-1, 0, 0) has a negative component"),
    "sizes count": (_set("/World/Castle", P + "sizes", "float[]", [1.0]),
                    "error: /World/Castle.primvars:granular:sizes: has 1 entries but there are 2 prototypes"),
    "size range": (_set("/World/Castle", P + "sizes", "float[]", [1.0, 20.0]),
                   "error: /World/Castle.primvars:granular:sizes: size 1 = 20 is outside [0.1, 10]"),
    "size spread": (_set("/World/Castle", P + "sizeSpread", "float", 0.8),
                    "error: /World/Castle.primvars:granular:sizeSpread: 0.8 is outside [0, 0.5]"),
    "grain roughness": (_set("/World/Grains/A", P + "roughness", "float", 1.5),
                        "error: /World/Grains/A.primvars:granular:roughness: 1.5 is outside [0, 1]"),
    "api on a non-mesh": (_api_on_xform,
                          "error: /World/Thing: GranularAggregateAPI applies to a Mesh, not a Xform"),
    "light intensity": (_set("/World/Sun", "inputs:intensity", "float", -1.0),
                        "error: /World/Sun.inputs:intensity: -1 must be finite and >= 0"),
    "dome texture": (_missing_dome_texture, 'error: /World/Sky.inputs:texture:file: "nope.exr" cannot be found'),
    "no camera": (_no_camera, ["the stage has no UsdGeomCamera"]),
    "negative fStop": (_set("/World/Camera", "fStop", "float", -2.0),
                       "error: /World/Camera.fStop: -2 must be finite and >= 0 (0: no depth of field)"),
    # An fStop of 1e-15 made a lens 10^15 units wide: Embree's assertion aborted the process.
    "fStop faster than any lens": (_both(_set("/World/Camera", "fStop", "float", 1e-15),
                                         _set("/World/Camera", "focusDistance", "float", 0.1)),
                                   "error: /World/Camera.fStop: 1e-15 is below 0.5, the fastest a lens in air can be "
                                   "(0: no depth of field)"),
    "focus at 0": (_set("/World/Camera", "fStop", "float", 4.0),
                   "error: /World/Camera.focusDistance: 0 must be > 0 when fStop is set"),
}


def _check(rc, err, expected, outputs):
    lines = err.strip().splitlines()
    assert rc == 2, err
    assert len(lines) == 1, err
    if isinstance(expected, str):
        assert lines[0] == expected
    else:
        for fragment in expected:
            assert fragment in lines[0], lines[0]
    assert "Traceback" not in err
    for o in outputs:
        assert not o.exists(), f"{o} was left behind"
        assert not o.with_name(o.name + ".tmp").exists()


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_stage_exits_2_naming_prim_and_attribute(case, scene_file, tmp_path, capsys):
    mutate, expected = CASES[case]
    scene = scene_file(mutate)
    exr, png = tmp_path / "out.exr", tmp_path / "out.png"
    rc, out, err = run_cli(["render", scene, "-o", exr, "--png", png, "--width", 32, "--height", 24, "--spp", 1],
                           capsys)
    _check(rc, err, expected, [exr, png])


def test_the_unbroken_scene_renders(scene_file, tmp_path, capsys):
    # The cases above break a scene that is otherwise fine.
    exr = tmp_path / "out.exr"
    rc, out, err = run_cli(["render", scene_file(), "-o", exr, "--width", 32, "--height", 24, "--spp", 1,
                            "--quiet"], capsys)
    assert rc == 0, err
    assert exr.exists() and err == ""


def test_malformed_and_missing_stages(tmp_path, capsys):
    bad = tmp_path / "bad.usda"
    bad.write_text('#usda 1.0\ndef Mesh "Castle" {\n  float3[] points = [(0, 0, 0\n}\n')
    out = tmp_path / "out.exr"
    rc, _, err = run_cli(["render", bad, "-o", out], capsys)
    _check(rc, err, [f"error: {bad}: cannot open the stage: "], [out])
    rc, _, err = run_cli(["info", tmp_path / "nope.usda"], capsys)
    _check(rc, err, f"error: {tmp_path / 'nope.usda'}: no such file", [])
    notusd = tmp_path / "x.usda"
    notusd.write_bytes(b"\x00\x01garbage")
    rc, _, err = run_cli(["info", notusd], capsys)
    _check(rc, err, [f"error: {notusd}: cannot open the stage"], [])


def test_command_line_errors(scene_file, tmp_path, capsys):
    scene = scene_file()
    cases = [
        (["render", scene, "-o", tmp_path / "missing" / "o.exr"], ["error: command line.-o: folder", "does not exist"]),
        (["render", scene, "-o", tmp_path / "o.png"], ['error: command line.-o: "', 'must end in .exr']),
        (["render", scene, "-o", tmp_path / "o.exr", "--png", tmp_path / "o.jpg"], ["command line.--png"]),
        (["render", scene, "-o", tmp_path / "o.exr", "--camera", "/World/Nope"],
         'error: command line.--camera: "/World/Nope" is not a prim of the stage'),
        (["render", scene, "-o", tmp_path / "o.exr", "--camera", "/World/Sun"],
         "error: /World/Sun: is a DistantLight, not a Camera"),
        (["render", scene, "-o", tmp_path / "o.exr", "--spp", "0"],
         "error: command line.--spp: 0 is outside [1, 1000000]"),
        (["render", scene, "-o", tmp_path / "o.exr", "--width", "x"],
         "error: command line.--width: 'x' is not an integer"),
        (["render", scene], ["error: command line.-o: is required"]),
        (["render", scene, "-o", tmp_path / "o.exr", "--technique", "dpt"],
         ["error: command line.--technique: invalid choice"]),
        (["render", scene, "-o", tmp_path / "o.exr", "--lod", "-1"],
         "error: command line.--lod: -1 must be finite and >= 0"),
        (["render", scene, "-o", tmp_path / "o.exr", "--roulette", "9"],
         "error: command line.--roulette: 9 must be in (0, 8] (above 1: splitting), or negative for automatic"),
        (["render", scene, "-o", tmp_path / "o.exr", "--frobnicate"],
         ["error: command line.--frobnicate: is not an option"]),
        (["export-vdb", scene, "--prim", "/World/Castle", "-o", tmp_path / "d.exr"], ["must end in .vdb"]),
        (["export-vdb", scene, "--prim", "/World/Castle", "-o", tmp_path / "d.vdb", "--voxel-size", "-1"],
         "error: command line.--voxel-size: -1 must be finite and > 0"),
    ]
    for argv, expected in cases:
        rc, _, err = run_cli(argv, capsys)
        lines = err.strip().splitlines()
        assert rc == 2 and len(lines) == 1, (argv, err)
        first = re.sub(r" \(see granular [a-z-]+ --help\)$", "", lines[0])
        if isinstance(expected, str):
            assert first == expected, argv
        else:
            for fragment in expected:
                assert fragment in first, (argv, first)
        assert not list(tmp_path.glob("o.*")) and not list(tmp_path.glob("d.*")), argv


def test_installed_script_reports_one_line_and_status_2(scene_file, tmp_path):
    scene = scene_file(_set("/World/Castle", P + "packingRate", "float", 0.9))
    out = tmp_path / "out.exr"
    r = run_script(["render", scene, "-o", out, "--width", 16, "--height", 16, "--spp", 1], timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["error: /World/Castle.primvars:granular:packingRate: 0.9 is outside (0, 0.64]"]
    assert not out.exists()


def _retype(path, name, type_name, value):
    """Authors `name` on `path` with a type the schema does not have (a file can; the
    Usd API cannot)."""
    def mutate(stage):
        layer = stage.GetRootLayer()
        spec = layer.GetPrimAtPath(path)
        if name in spec.attributes:
            spec.RemoveProperty(spec.attributes[name])
        attr = Sdf.AttributeSpec(spec, name, Sdf.ValueTypeNames.Find(type_name))
        attr.default = value
    return mutate


RETYPED = [
    ("/World/Sun", "inputs:intensity", "string", "bright"),
    ("/World/Sun", "inputs:angle", "bool", True),
    ("/World/Sun", "inputs:color", "float", 1.0),
    ("/World/Sun", "inputs:normalize", "float", 1.0),
    ("/World/Camera", "focalLength", "string", "long"),
    ("/World/Camera", "clippingRange", "float", 1.0),
    ("/World/Camera", "projection", "float", 1.0),
    ("/World/Castle", "points", "string[]", ["a", "b", "c"]),
    ("/World/Castle", "points", "float[]", [0.0, 1.0]),
    ("/World/Castle", "faceVertexIndices", "float[]", [0.5, 1.0, 2.0]),
    ("/World/Castle", "visibility", "int", 3),
    ("/World/Grains/A", "points", "int", 3),
    ("/World/Castle", "primvars:granular:prototypes", "string", "../Grains/A"),
    ("/World/Castle", "primvars:granular:weights", "string[]", ["1", "2"]),
]


@pytest.mark.parametrize("path,name,type_name,value", RETYPED, ids=[f"{p}.{n}:{t}" for p, n, t, _ in RETYPED])
def test_a_wrongly_typed_attribute_is_a_user_error(path, name, type_name, value, scene_file, tmp_path, capsys):
    scene = scene_file(_retype(path, name, type_name, value))
    out = tmp_path / "out.exr"
    rc, _, err = run_cli(["render", scene, "-o", out, "--width", 16, "--height", 16, "--spp", 1], capsys)
    _check(rc, err, [f"error: {path}.{name}: has "], [out])
