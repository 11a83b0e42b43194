"""Mesh lights (UsdLuxMeshLightAPI: core's LightType.Mesh, made by core/granular_prims.h from
the surface's triangles) through `granular render`: a quad that emits as the RectLight of the
same place, its back letting rays through, doubleSided emitting from both sides, the bound
material's emissiveColor tinting it as light:materialSyncMode says, and bad values refused
with the prim and the attribute named. hdGranular renders the same (tests/hydra:
AMeshLightLightsAsTheRectOfItsQuad...; tests/conformance: mesh_light*)."""
import numpy as np
from pxr import Gf, Sdf, UsdGeom, UsdLux, UsdShade

from conftest import floor_world, run_cli
from noise_check import block_chi2, noise_limit, rgb_and_variance

# A unit quad 3 above the floor, wound to face it (-z).
QUAD = [(-0.5, -0.5, 3), (-0.5, 0.5, 3), (0.5, 0.5, 3), (0.5, -0.5, 3)]


def _stage(path, light="mesh", points=QUAD, double_sided=None, tint=None, sync_mode=None, intensity=4.0,
           shaping=False):
    """A grey floor 15 below the camera under one light 3 above it: the quad with
    MeshLightAPI, or (light="rect") the RectLight of its place; `tint`: a bound material's
    emissiveColor."""
    stage = floor_world(path)
    if light == "rect":
        rect = UsdLux.RectLight.Define(stage, "/World/Panel")
        rect.CreateIntensityAttr(intensity)
        UsdGeom.Xformable(rect).AddTranslateOp().Set(Gf.Vec3d(0, 0, 3))
    else:
        panel = UsdGeom.Mesh.Define(stage, "/World/Panel")
        panel.CreatePointsAttr(points)
        panel.CreateFaceVertexCountsAttr([len(points)])
        panel.CreateFaceVertexIndicesAttr(list(range(len(points))))
        if double_sided is not None:
            panel.CreateDoubleSidedAttr(double_sided)
        api = UsdLux.MeshLightAPI.Apply(panel.GetPrim())
        lux = UsdLux.LightAPI(panel.GetPrim())
        lux.CreateIntensityAttr(intensity)
        if sync_mode is not None:
            lux.CreateMaterialSyncModeAttr(sync_mode)
        if shaping:
            UsdLux.ShapingAPI.Apply(panel.GetPrim()).CreateShapingConeAngleAttr(30.0)
        if tint is not None:
            material = UsdShade.Material.Define(stage, "/World/Glow")
            shader = UsdShade.Shader.Define(stage, "/World/Glow/Surface")
            shader.CreateIdAttr("UsdPreviewSurface")
            shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*tint))
            material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
            UsdShade.MaterialBindingAPI.Apply(panel.GetPrim()).Bind(material)
        assert api
    stage.Save()
    return str(path)


def _render(tmp_path, name, capsys, spp=8, seed=0, **kw):
    out = tmp_path / f"{name}.exr"
    rc, _, err = run_cli(["render", _stage(tmp_path / f"{name}.usda", **kw), "-o", out,
                          "--width", "16", "--height", "16", "--spp", str(spp), "--seed", str(seed)], capsys)
    assert rc == 0, err
    return rgb_and_variance(out), err


def test_a_quad_with_mesh_light_api_lights_the_floor_as_the_rect_light_of_its_place(tmp_path, capsys):
    # The camera above sees the quad's back, which lets its rays through: the floor alone.
    (mesh, var_mesh), err = _render(tmp_path, "mesh", capsys, spp=64)
    assert "not supported" not in err, err
    (rect, var_rect), _ = _render(tmp_path, "rect", capsys, light="rect", spp=64, seed=1)  # independent noise
    assert mesh.mean() > 0
    chi2, m = block_chi2(mesh, var_mesh, rect, var_rect)
    assert chi2 < noise_limit(m), (chi2, m)
    # Half the light: a falsified mesh light would be told from the rect.
    chi2, m = block_chi2(0.9 * mesh, 0.81 * var_mesh, rect, var_rect)
    assert chi2 > noise_limit(m), (chi2, m)


def test_a_quad_facing_away_lights_the_floor_only_when_double_sided(tmp_path, capsys):
    # Wound to face the camera: the pixels that see it have its radiance, 4 (the ones on its
    # edge, part of it), and the floor gets nothing. (At the spp and seed of the renders
    # below, whose camera rays are the same: the same pixels see it.)
    away = list(reversed(QUAD))
    (dark, _), _ = _render(tmp_path, "away", capsys, points=away, spp=64)
    seen = dark.max(axis=2) > 0
    assert 0 < seen.sum() < seen.size / 4
    assert np.all(dark[8, 8] == 4.0)
    # doubleSided, it lights the floor as the quad facing it does (the pixels that see it
    # left out).
    (front, var_front), _ = _render(tmp_path, "front", capsys, spp=64)
    (both, var_both), _ = _render(tmp_path, "both", capsys, points=away, double_sided=True, spp=64)
    assert np.all(both[8, 8] == 4.0)
    for image in (front, var_front, both, var_both):
        image[seen] = 0
    chi2, m = block_chi2(both, var_both, front, var_front)
    assert chi2 < noise_limit(m), (chi2, m)


def test_the_bound_materials_emissive_color_tints_the_light_unless_its_sync_mode_says_not(tmp_path, capsys):
    # One light and the same random numbers: a tint scales the image channel by channel.
    (plain, _), _ = _render(tmp_path, "plain", capsys)
    (tinted, _), _ = _render(tmp_path, "tinted", capsys, tint=(1.0, 0.5, 0.25))
    assert plain.mean() > 0
    np.testing.assert_allclose(tinted, plain * np.array([1.0, 0.5, 0.25]), rtol=1e-5, atol=1e-7)
    for mode in ("independent", "noMaterialResponse"):
        (untinted, _), _ = _render(tmp_path, mode, capsys, tint=(1.0, 0.5, 0.25), sync_mode=mode)
        np.testing.assert_array_equal(untinted, plain)


def test_shaping_on_a_mesh_light_is_warned_about_and_ignored(tmp_path, capsys):
    (plain, _), _ = _render(tmp_path, "plain", capsys)
    (shaped, _), err = _render(tmp_path, "shaped", capsys, shaping=True)
    assert "/World/Panel: ShapingAPI on a mesh light is not supported; ignored" in err, err
    np.testing.assert_array_equal(shaped, plain)


def test_bad_mesh_lights_name_the_prim_and_the_attribute(tmp_path, capsys):
    flat = [(-0.5, 0, 3), (0, 0, 3), (0.5, 0, 3)]
    for name, kw, message in (
            ("intensity", {"intensity": -1.0}, "/World/Panel.inputs:intensity: -1 must be finite and >= 0"),
            ("mode", {"sync_mode": "glow"},
             '/World/Panel.light:materialSyncMode: "glow" is not one of materialGlowTintsLight, independent, '
             'noMaterialResponse'),
            ("flat", {"points": flat}, "/World/Panel.points: the mesh has no area, so it cannot emit"),
            ("nan", {"points": [(-0.5, -0.5, 3), (float("nan"), 0.5, 3), (0.5, 0.5, 3)]}, "/World/Panel.points: ")):
        rc, _, err = run_cli(["render", _stage(tmp_path / f"{name}.usda", **kw), "-o", tmp_path / f"{name}.exr"],
                             capsys)
        assert rc == 2, err
        assert f"error: {message}" in err, err
        assert not (tmp_path / f"{name}.exr").exists()
