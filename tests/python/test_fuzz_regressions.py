"""Stages that fuzz/fuzz_usd_stage.py found to escape the front end's contract (exit status
2 with one line naming the prim and the attribute, or a finite image): each renders here
through the command, as small as the finding allows."""
import ast
import inspect
import re

import numpy as np
from conftest import ROOT, run_cli
from pxr import Gf, Sdf, UsdGeom, UsdRender, UsdShade, Vt

import granular_core as core


def _render(scene_file, tmp_path, capsys, mutate, *extra):
    out = tmp_path / "out.exr"
    rc, _, err = run_cli(["render", scene_file(mutate), "-o", out, "--width", "8", "--height", "6", "--spp", "1",
                          "--technique", "ept", "--quiet", *extra], capsys)
    return rc, err.strip().splitlines(), out


def _op_order(path, ops):
    def mutate(stage):
        attr = stage.GetPrimAtPath(path).CreateAttribute("xformOpOrder", Sdf.ValueTypeNames.TokenArray)
        attr.Set(Vt.TokenArray(ops))
    return mutate


def test_an_op_order_naming_no_transform_op_names_the_prim_that_has_it(scene_file, tmp_path, capsys):
    # usd-core's XformCache raised a bare Tf error: "Invalid xform opType token 'missing'".
    rc, lines, out = _render(scene_file, tmp_path, capsys, _op_order("/World", ["xformOp:missing"]))
    assert rc == 2 and len(lines) == 1, lines
    assert re.fullmatch(r"error: /World\.xformOpOrder: .*'missing'.*", lines[0]), lines
    assert not out.exists()
    # an attribute that is not an op at all, on the camera itself
    rc, lines, _ = _render(scene_file, tmp_path, capsys, _op_order("/World/Camera", ["points"]))
    assert rc == 2 and lines[0].startswith("error: /World/Camera.xformOpOrder: "), lines


def test_a_display_color_of_one_number_is_refused_naming_it(scene_file, tmp_path, capsys):
    # A scalar displayColor (here inherited from an Xform, whose schema leaves its type
    # open) raised TypeError: len() of a float.
    def mutate(stage):
        UsdGeom.Cube.Define(stage, "/World/Box").CreateSizeAttr(0.1)
        UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/World")).CreatePrimvar(
            "displayColor", Sdf.ValueTypeNames.Float, UsdGeom.Tokens.constant).Set(0.5)
    rc, lines, out = _render(scene_file, tmp_path, capsys, mutate)
    assert rc == 2 and len(lines) == 1, lines
    assert re.fullmatch(r"error: /World\.primvars:displayColor: .*expected color3f\[\]", lines[0]), lines
    assert not out.exists()


def test_render_products_naming_no_prim_are_no_products(scene_file, tmp_path, capsys):
    # Its first target's invalid prim raised RuntimeError ("Accessed invalid null prim").
    def mutate(stage):
        rs = UsdRender.Settings.Define(stage, "/Render/Settings")
        rs.CreateProductsRel().SetTargets([Sdf.Path("/Render/Nope")])
        rs.CreateDataWindowNDCAttr(Gf.Vec4f(0, 0, 0.5, 0.5))
    rc, lines, out = _render(scene_file, tmp_path, capsys, mutate)
    assert rc == 0 and out.exists(), lines
    rc, _, err = run_cli(["render", scene_file(mutate), "-o", tmp_path / "w.exr", "--width", "8", "--height", "6",
                          "--spp", "1", "--technique", "ept"], capsys)
    assert rc == 0 and "/Render/Settings.dataWindowNDC: ignored" in err


def _aperture(name, value):
    def mutate(stage):
        UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera")).GetPrim().GetAttribute(name).Set(value)
    return mutate


def test_width_or_height_alone_needs_an_aspect_core_accepts(scene_file, tmp_path, capsys):
    # The other side came from horizontalAperture / verticalAperture unchecked:
    # ZeroDivisionError (0), ValueError (NaN), or a size beyond int (1e-30).
    for value in (0.0, float("nan")):
        out = tmp_path / "out.exr"
        rc, _, err = run_cli(["render", scene_file(_aperture("horizontalAperture", value)), "-o", out, "--width", "8",
                              "--spp", "1", "--technique", "ept", "--quiet"], capsys)
        assert rc == 2 and err.startswith("error: /World/Camera.horizontalAperture: "), err
        assert not out.exists()
    rc, _, err = run_cli(["render", scene_file(_aperture("verticalAperture", 1e-30)), "-o", tmp_path / "out.exr",
                          "--height", "6", "--spp", "1", "--technique", "ept", "--quiet"], capsys)
    assert rc == 2 and err.startswith("error: command line.--height: "), err


def test_a_transform2d_fed_by_its_own_output_is_a_cycle(scene_file, tmp_path, capsys):
    # _texture_st followed UsdTransform2d.inputs:in forever: RecursionError.
    png = tmp_path / "t.png"
    core.write_png(str(png), core.Image(np.full((1, 2, 3), 0.5, dtype=np.float32), ["R", "G", "B"]))

    def mutate(stage):
        ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
        ground.CreatePointsAttr(Vt.Vec3fArray([(-1, 0, 1), (1, 0, 1), (1, 0, -1), (-1, 0, -1)]))
        ground.CreateFaceVertexCountsAttr([4])
        ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
        mat = UsdShade.Material.Define(stage, "/World/Look")
        surface = UsdShade.Shader.Define(stage, "/World/Look/Surface")
        surface.CreateIdAttr("UsdPreviewSurface")
        tex = UsdShade.Shader.Define(stage, "/World/Look/Tex")
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(str(png))
        xf = UsdShade.Shader.Define(stage, "/World/Look/Xf")
        xf.CreateIdAttr("UsdTransform2d")
        xf.CreateInput("in", Sdf.ValueTypeNames.Float2).ConnectToSource(xf.ConnectableAPI(), "result")
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(xf.ConnectableAPI(), "result")
        surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
        mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
        UsdShade.MaterialBindingAPI.Apply(ground.GetPrim()).Bind(mat)
    rc, lines, out = _render(scene_file, tmp_path, capsys, mutate)
    assert rc == 2 and lines[-1] == "error: /World/Look/Xf.inputs:in: is connected in a cycle (to its own output)", lines
    assert not out.exists()


def test_the_stage_fuzzers_stand_ins_take_the_arguments_of_what_they_replace():
    # fuzz/fuzz_usd_stage.py puts bounded, checked stand-ins in place of api.build_scene and
    # cli._render_image; the command calls them as it calls those. A parameter added to one
    # and not to its stand-in stopped every fuzz run on its first input.
    from granular import api, cli

    tree = ast.parse((ROOT / "fuzz" / "fuzz_usd_stage.py").read_text())
    defs = {f.name: f for f in tree.body if isinstance(f, ast.FunctionDef)}
    for stand_in, original in (("_bounded_build_scene", api.build_scene), ("_checked_render_image", cli._render_image)):
        a = defs[stand_in].args
        assert [p.arg for p in a.posonlyargs + a.args + a.kwonlyargs] == list(inspect.signature(original).parameters), \
            stand_in
