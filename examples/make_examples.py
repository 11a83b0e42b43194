#!/usr/bin/env python3
"""Writes the bundled USD examples (sandcastle, snowslab, sugarcube, mixture, animated, macro,
frosted, sugarcube_spot, sugarcube_neon) with usd-core and the granular schema helpers:

    .venv/bin/python examples/make_examples.py [OUT_DIR]

Each scene: a /World with a camera, UsdLux lights, a ground with a UsdPreviewSurface,
aggregates (Meshes with GranularAggregateAPI) and their grain prototypes (invisible Meshes
with GranularGrainAPI under the /World/Grains scope), and render settings with the
resolution. Shapes come from core's procedural meshes, so the files are deterministic.
The sand castle's beach is a UsdUVTexture (textures/beach.png, written here) on the
ground's st. `animated` is a short shot (frames 1 to 3) for `granular render --frames`: its camera moves
(time samples on its transform) and its sun brightens between frames 2 and 3. `macro` is
a close-up with depth of field (fStop, focusDistance): the front grains of a heap sharp,
the heap behind them soft. `frosted` is sea glass: rough grains (GranularGrainAPI's
roughness). `mixture` holds grains of many sizes (GranularAggregateAPI sizes, sizeSpread).
`sugarcube_spot` lights the sugar cube by a spotlight's IES profile (profiles/narrow_spot.ies,
written here); `sugarcube_neon` by mesh lights (MeshLightAPI): a softbox and a neon ring.
"""
import math
import os
import sys

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, UsdShade, Vt

import granular  # noqa: F401  (registers the schema)
import granular_core as core
from granular import schema
from granular.materials import ICE, QUARTZ_SAND, SUCROSE


def new_stage(path, resolution):
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())
    UsdGeom.Scope.Define(stage, "/World/Grains")
    UsdGeom.Scope.Define(stage, "/World/Looks")
    UsdGeom.Scope.Define(stage, "/Render")
    settings = UsdRender.Settings.Define(stage, "/Render/Settings")
    settings.CreateResolutionAttr(Gf.Vec2i(*resolution))
    stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    return stage, settings


def _round(a, digits=5):
    return [round(float(x), digits) for x in a]


def mesh_from(stage, path, tri, translate=None, rotate_y=None, scale=None):
    """A UsdGeomMesh of a core.TriangleMesh (points rounded for readable, stable files)."""
    m = UsdGeom.Mesh.Define(stage, path)
    pts = np.asarray(tri.points, dtype=np.float64)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*_round(p)) for p in pts]))
    idx = [int(i) for i in tri.indices]
    m.CreateFaceVertexIndicesAttr(Vt.IntArray(idx))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([3] * (len(idx) // 3)))
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    m.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*_round(lo)), Gf.Vec3f(*_round(hi))]))
    xf = UsdGeom.Xformable(m)
    if translate is not None:
        xf.AddTranslateOp().Set(Gf.Vec3d(*translate))
    if rotate_y is not None:
        xf.AddRotateYOp().Set(rotate_y)
    if scale is not None:
        xf.AddScaleOp().Set(Gf.Vec3f(*scale))
    return m


def quad(stage, path, size, y=0.0):
    m = UsdGeom.Mesh.Define(stage, path)
    h = size / 2
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(-h, y, -h), Gf.Vec3f(-h, y, h), Gf.Vec3f(h, y, h), Gf.Vec3f(h, y, -h)]))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([4]))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray([0, 1, 2, 3]))
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    m.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(-h, y, -h), Gf.Vec3f(h, y, h)]))
    return m


def preview_material(stage, name, diffuse=None, opacity=None, ior=None):
    mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    sh = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    if diffuse is not None:
        sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*diffuse))
    if opacity is not None:
        sh.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(opacity)
    if ior is not None:
        sh.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(ior)
    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def textured_quad(stage, path, size, tiles, y=0.0):
    """quad() with texture coordinates st from (0, 0) to (tiles, tiles), per vertex."""
    m = quad(stage, path, size, y)
    st = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.vertex)
    st.Set(Vt.Vec2fArray([Gf.Vec2f(0, tiles), Gf.Vec2f(0, 0), Gf.Vec2f(tiles, 0), Gf.Vec2f(tiles, tiles)]))
    return m


def textured_material(stage, name, file):
    """A UsdPreviewSurface whose diffuseColor is a UsdUVTexture (repeating, sRGB) of file,
    read at the primvar st."""
    mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    sh = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/Surface")
    sh.CreateIdAttr("UsdPreviewSurface")
    sh.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(0.8)
    reader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/St")
    reader.CreateIdAttr("UsdPrimvarReader_float2")
    reader.CreateInput("varname", Sdf.ValueTypeNames.Token).Set("st")
    tex = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/Texture")
    tex.CreateIdAttr("UsdUVTexture")
    tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(file)
    tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
    tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set("sRGB")
    tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
    sh.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(sh.ConnectableAPI(), "surface")
    return mat


def beach_texture(path, size=256):
    """Wind ripples in damp sand: a sRGB PNG, seamless (it repeats), deterministic."""
    y, x = np.mgrid[0:size, 0:size] / size
    two_pi = 2 * np.pi
    # Crests of 8 ripples per tile, bent by a slow wave; fine speckle from seeded noise.
    phase = two_pi * (8 * x + 0.35 * np.sin(two_pi * 2 * y) + 0.12 * np.sin(two_pi * 3 * (x + y)))
    crest = 0.5 + 0.5 * np.sin(phase)
    rng = np.random.default_rng(7)
    speckle = rng.normal(0.0, 0.06, (size, size))
    shade = 0.78 + 0.3 * crest ** 3 + speckle
    base = np.array([0.42, 0.36, 0.28])
    rgb = np.clip(base[None, None, :] * shade[..., None], 0.0, 1.0).astype(np.float32)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    core.write_png(path, core.Image(rgb, ["R", "G", "B"]))


def bind(prim, mat):
    UsdShade.MaterialBindingAPI.Apply(prim.GetPrim()).Bind(mat)


def camera(stage, eye, target, focal=35.0, aperture=(36.0, 24.0)):
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(focal)
    cam.CreateHorizontalApertureAttr(aperture[0])
    cam.CreateVerticalApertureAttr(aperture[1])
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 100.0))
    # Gf.Matrix4d.SetLookAt gives world-to-camera; the camera's transform is its inverse.
    m = Gf.Matrix4d().SetLookAt(Gf.Vec3d(*eye), Gf.Vec3d(*target), Gf.Vec3d(0, 1, 0)).GetInverse()
    UsdGeom.Xformable(cam).AddTransformOp().Set(m)
    return cam


def sun(stage, direction, irradiance, color=(1.0, 0.93, 0.82)):
    """The physical sun: a distant light of 0.53 degrees (USD's default angle) travelling
    along `direction`, normalised, so that `irradiance` is what it delivers to a surface
    facing it, whatever its angle."""
    light = UsdLux.DistantLight.Define(stage, "/World/Sun")
    light.CreateIntensityAttr(irradiance)
    light.CreateAngleAttr(0.53)
    light.CreateNormalizeAttr(True)
    light.CreateColorAttr(Gf.Vec3f(*color))
    d = Gf.Vec3d(*direction).GetNormalized()
    # Rotate local -Z onto d.
    rot = Gf.Rotation(Gf.Vec3d(0, 0, -1), d)
    UsdGeom.Xformable(light).AddTransformOp().Set(Gf.Matrix4d().SetRotate(rot))
    return light


def sky(stage, color, intensity):
    light = UsdLux.DomeLight.Define(stage, "/World/Sky")
    light.CreateColorAttr(Gf.Vec3f(*color))
    light.CreateIntensityAttr(intensity)
    return light


def grain(stage, name, tri, ior, absorption, roughness=0.0):
    m = mesh_from(stage, f"/World/Grains/{name}", tri)
    schema.apply_grain(m, ior=ior, absorption=absorption, roughness=roughness)
    return m


def material_grains(stage, material, names, absorption=None, dark_absorption=None):
    """The material's prototypes (granular.materials: the shapes, index and weights its slab
    test renders) as grain prims named `names`, absorbing as the material does at the
    examples' grain size unless absorption (and dark_absorption) are given. Returns the
    prims and their weights."""
    light, dark = material.grain_absorptions(per_radius=absorption, dark_per_radius=dark_absorption)
    prims = [grain(stage, name, p.mesh(), material.ior, dark if p.dark else light)
             for p, name in zip(material.prototypes, names)]
    return prims, [p.weight for p in material.prototypes]


def cylinder(radius, height, segments=48):
    return core.make_lathe([(radius, 0.0), (radius, height)], segments)


def cone(radius, height, segments=48):
    return core.make_lathe([(radius, 0.0), (0.0, height)], segments)


# ---- scenes ----------------------------------------------------------------------------------

def sandcastle(path):
    stage, _ = new_stage(path, (480, 320))
    camera(stage, eye=(2.5, 1.75, 3.1), target=(0.0, 0.5, 0.0))
    # As on a clear day: the sun gives about four times the sky's light on the ground.
    sun(stage, direction=(-0.45, -0.8, -0.35), irradiance=3.2)
    sky(stage, (0.6, 0.75, 1.0), 0.25)
    # A beach of rippled damp sand: a repeating texture, one tile per 2 units.
    beach_texture(os.path.join(os.path.dirname(path), "textures", "beach.png"))
    ground = textured_quad(stage, "/World/Ground", 12.0, tiles=6)
    bind(ground, textured_material(stage, "Beach", "./textures/beach.png"))

    # Quartz sand's grains, absorbing more (for pebbles: by eye) and more blue than red (a
    # yellow-brown tint).
    protos, weights = material_grains(stage, QUARTZ_SAND, ("Round", "Flat", "Dark"), (0.12, 0.24, 0.65),
                                      (0.7, 0.9, 1.5))

    # The values are authored on each part: Hydra (OpenUSD 24.08's UsdImaging) does not
    # hand a delegate the granular primvars a part would inherit from the castle Xform,
    # so inherited values would mean one thing in `granular render` and another in
    # usdview. The prototypes are named on each part, relative to it.
    UsdGeom.Xform.Define(stage, "/World/Castle")

    def part(name, tri, translate, seed):
        m = mesh_from(stage, f"/World/Castle/{name}", tri, translate=translate)
        schema.apply_aggregate(m, protos, seed=seed, tile_spheres=512, author_fallbacks=False)
        api = UsdGeom.PrimvarsAPI(m)
        api.CreatePrimvar("granular:grainRadius", Sdf.ValueTypeNames.Float, UsdGeom.Tokens.constant).Set(0.012)
        api.CreatePrimvar("granular:packingRate", Sdf.ValueTypeNames.Float, UsdGeom.Tokens.constant).Set(0.6)
        api.CreatePrimvar("granular:weights", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.constant).Set(
            Vt.FloatArray(weights))
        return m

    part("Base", core.make_box((-0.8, 0.0, -0.8), (0.8, 0.3, 0.8)), None, 1)
    part("Keep", core.make_box((-0.42, 0.3, -0.42), (0.42, 0.85, 0.42)), None, 2)
    part("KeepRoof", cone(0.36, 0.4), (0.0, 0.85, 0.0), 3)
    for k, (x, z) in enumerate([(-0.6, -0.6), (0.6, -0.6), (-0.6, 0.6), (0.6, 0.6)]):
        part(f"Tower{k + 1}", cylinder(0.17, 0.55), (x, 0.3, z), 10 + k)
        part(f"TowerRoof{k + 1}", cone(0.21, 0.28), (x, 0.85, z), 20 + k)
    stage.GetRootLayer().Save()


def snow_ground(stage):
    """The dark rock ground of the snow scenes."""
    bind(quad(stage, "/World/Ground", 12.0), preview_material(stage, "Rock", diffuse=(0.08, 0.08, 0.09)))


def snow_grains(stage):
    """Ice flakes and pellets of 0.4 mm: ice's measured index and absorption
    (granular.materials.ICE: a faint blue only deep inside). Returns the prims and weights."""
    return material_grains(stage, ICE, ("Flake", "Pellet"))


def snowslab(path):
    stage, _ = new_stage(path, (400, 260))
    camera(stage, eye=(1.7, 1.05, 2.2), target=(0.0, 0.12, 0.0))
    sun(stage, direction=(-0.3, -0.55, -0.75), irradiance=1.2, color=(1.0, 0.97, 0.92))
    sky(stage, (0.55, 0.7, 1.0), 0.35)
    snow_ground(stage)
    grains, weights = snow_grains(stage)
    slab = mesh_from(stage, "/World/Snow", core.make_box((-0.9, 0.0, -0.55), (0.9, 0.3, 0.55)))
    schema.apply_aggregate(slab, grains, grain_radius=ICE.grain_radius_m, packing_rate=ICE.packing_rate,
                           weights=weights, seed=4, tile_spheres=512)
    stage.GetRootLayer().Save()


def sugarcube(path):
    """A sugar cube of 16 mm (about 30,000 crystals of 0.5 mm) on a wooden table, seen from
    10 cm: a crystal is about two pixels wide."""
    stage, _ = new_stage(path, (360, 270))
    k = 0.016 / 0.22  # the cube's edge over the camera's framing distance below
    camera(stage, eye=(0.75 * k, 0.62 * k, 0.95 * k), target=(0.0, 0.11 * k, 0.0), aperture=(36.0, 27.0))
    sun(stage, direction=(-0.5, -0.7, -0.3), irradiance=1.2)
    sky(stage, (0.8, 0.85, 1.0), 0.4)
    # A table from a UsdGeomCube (tessellated by the reader).
    table = UsdGeom.Cube.Define(stage, "/World/Table")
    table.CreateSizeAttr(1.0)
    UsdGeom.Xformable(table).AddTranslateOp().Set(Gf.Vec3d(0, -0.05, 0))
    UsdGeom.Xformable(table).AddScaleOp().Set(Gf.Vec3f(4.0, 0.1, 4.0))
    bind(table, preview_material(stage, "Wood", diffuse=(0.25, 0.13, 0.06)))
    # Sucrose crystals (granular.materials.SUCROSE): clear, index 1.56, box-like.
    crystals, weights = material_grains(stage, SUCROSE, ("Crystal", "Chip"))
    cube = mesh_from(stage, "/World/SugarCube", core.make_box((-0.008, 0.0, -0.008), (0.008, 0.016, 0.008)),
                     rotate_y=25.0)
    schema.apply_aggregate(cube, crystals, grain_radius=SUCROSE.grain_radius_m, packing_rate=SUCROSE.packing_rate,
                           weights=weights, seed=9, tile_spheres=512)
    stage.GetRootLayer().Save()


def mixture(path):
    stage, _ = new_stage(path, (400, 300))
    camera(stage, eye=(1.25, 0.95, 1.55), target=(0.0, 0.18, 0.0), aperture=(36.0, 27.0))
    sun(stage, direction=(-0.4, -0.75, -0.45), irradiance=0.9546)
    sky(stage, (0.7, 0.8, 1.0), 0.8)
    ground = quad(stage, "/World/Ground", 12.0)
    bind(ground, preview_material(stage, "Slate", diffuse=(0.3, 0.3, 0.32)))
    # Glass beads in three colours, and opaque pepper grains through a UsdPreviewSurface
    # binding (no GranularGrainAPI: Lambert grains).
    red = grain(stage, "Red", core.make_icosphere(2), 1.5, (0.15, 1.6, 1.8))
    green = grain(stage, "Green", core.make_icosphere(2), 1.5, (1.4, 0.2, 1.2))
    white = grain(stage, "White", core.make_rock(2, 0.15, 3), 1.5, (0.05, 0.05, 0.05))
    pepper = mesh_from(stage, "/World/Grains/Pepper", core.make_rock(2, 0.35, 8))
    UsdGeom.Imageable(pepper).MakeInvisible()
    bind(pepper, preview_material(stage, "Pepper", diffuse=(0.05, 0.04, 0.03)))
    heap = mesh_from(stage, "/World/Heap", core.make_lathe(
        [(0.55, 0.0), (0.5, 0.06), (0.38, 0.2), (0.22, 0.33), (0.0, 0.4)], 48))
    # Grains of many sizes: beads 1.4 times the white rocks, pepper 0.6 of them, every
    # grain's size spread by ±15% (weights count grains by number).
    schema.apply_aggregate(heap, [red, green, white, pepper], grain_radius=0.0015, packing_rate=0.58,
                           weights=[0.15, 0.15, 0.45, 0.25], seed=5, tile_spheres=512,
                           sizes=[1.4, 1.4, 1.0, 0.6], size_spread=0.15)
    stage.GetRootLayer().Save()


def animated(path):
    """A small snow drift (snowslab's grains, so their transport is cached alike) filmed over
    frames 1 to 3: the camera circles it (frames 1-2: only the view changes, the renderer
    keeps the scene) and the sun brightens from frame 2 to 3 (a light change: built anew)."""
    stage, _ = new_stage(path, (320, 200))
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(3)
    cam = camera(stage, eye=(1.2, 0.8, 1.5), target=(0.0, 0.1, 0.0))
    op = UsdGeom.Xformable(cam).GetOrderedXformOps()[0]
    op.GetAttr().Clear()  # time samples only
    for frame, angle in ((1, 38.0), (2, 20.0), (3, 2.0)):
        a = math.radians(angle)
        eye = Gf.Vec3d(1.9 * math.sin(a), 0.8, 1.9 * math.cos(a))
        op.Set(Gf.Matrix4d().SetLookAt(eye, Gf.Vec3d(0.0, 0.1, 0.0), Gf.Vec3d(0, 1, 0)).GetInverse(), frame)
    light = sun(stage, direction=(-0.3, -0.55, -0.75), irradiance=1.0, color=(1.0, 0.97, 0.92))
    intensity = light.GetIntensityAttr()
    intensity.Clear()
    for frame, value in ((1, 1.0), (2, 1.0), (3, 1.75)):
        intensity.Set(value, frame)
    sky(stage, (0.55, 0.7, 1.0), 0.35)
    snow_ground(stage)
    grains, weights = snow_grains(stage)
    drift = mesh_from(stage, "/World/Drift", core.make_box((-0.35, 0.0, -0.25), (0.35, 0.22, 0.25)))
    schema.apply_aggregate(drift, grains, grain_radius=ICE.grain_radius_m, packing_rate=ICE.packing_rate,
                           weights=weights, seed=4, tile_spheres=512)
    stage.GetRootLayer().Save()


def macro(path):
    stage, _ = new_stage(path, (360, 240))
    # A short focal length in tenths of a unit (USD's convention; these scenes are in
    # metres), so that f/16 is a lens of radius 0.05 x 8 / 16 = 0.025 units, focused on the
    # heap's near slope, 0.45 in front of the camera; its top, the ground and the sky blur.
    cam = camera(stage, eye=(0.0, 0.22, 0.75), target=(0.0, 0.2, 0.0), focal=8.0, aperture=(7.2, 4.8))
    cam.CreateFStopAttr(16.0)
    cam.CreateFocusDistanceAttr(0.45)
    sun(stage, direction=(-0.4, -0.75, -0.45), irradiance=0.9546)
    sky(stage, (0.7, 0.8, 1.0), 0.8)
    ground = quad(stage, "/World/Ground", 12.0)
    bind(ground, preview_material(stage, "Slate", diffuse=(0.3, 0.3, 0.32)))
    amber = grain(stage, "Amber", core.make_rock(2, 0.2, 4), 1.55, (0.1, 0.5, 1.4))
    clear = grain(stage, "Clear", core.make_icosphere(2), 1.5, (0.02, 0.02, 0.02))
    heap = mesh_from(stage, "/World/Heap", core.make_lathe(
        [(0.45, 0.0), (0.4, 0.06), (0.3, 0.16), (0.16, 0.26), (0.0, 0.3)], 48))
    schema.apply_aggregate(heap, [amber, clear], grain_radius=0.012, packing_rate=0.58, weights=[0.6, 0.4],
                           seed=11, tile_spheres=512)
    stage.GetRootLayer().Save()


def frosted(path):
    """Sea glass: pebbles of frosted glass (GGX roughness 0.35 to 0.6) in green, blue and
    white, worn smooth-edged, in a heap on slate beside a few clear, polished ones."""
    stage, _ = new_stage(path, (400, 300))
    camera(stage, eye=(0.62, 0.55, 0.78), target=(0.0, 0.12, 0.0), aperture=(36.0, 27.0))
    sun(stage, direction=(-0.45, -0.7, -0.5), irradiance=1.0)
    sky(stage, (0.7, 0.8, 1.0), 0.5)
    ground = quad(stage, "/World/Ground", 12.0)
    bind(ground, preview_material(stage, "Slate", diffuse=(0.3, 0.3, 0.32)))
    pebble = core.make_ellipsoid((1.0, 0.55, 0.8), 2)
    green = grain(stage, "Green", pebble, 1.52, (0.9, 0.12, 0.7), roughness=0.5)
    blue = grain(stage, "Blue", core.make_rock(2, 0.12, 6), 1.52, (1.1, 0.45, 0.08), roughness=0.6)
    white = grain(stage, "White", core.make_rock(2, 0.18, 2), 1.52, (0.03, 0.03, 0.03), roughness=0.35)
    polished = grain(stage, "Polished", pebble, 1.52, (0.02, 0.02, 0.02))
    heap = mesh_from(stage, "/World/Heap", core.make_lathe(
        [(0.5, 0.0), (0.45, 0.06), (0.34, 0.18), (0.2, 0.29), (0.0, 0.35)], 48))
    schema.apply_aggregate(heap, [green, blue, white, polished], grain_radius=0.014, packing_rate=0.55,
                           weights=[0.3, 0.25, 0.3, 0.15], seed=13, tile_spheres=512)
    stage.GetRootLayer().Save()


def sandcastle_paper(path):
    """The sand castle at the paper's scale: the same castle (sandcastle.usda, a sublayer)
    of quarter-millimetre grains of light quartz sand (granular.materials.QUARTZ_SAND) —
    1.3·10^10 of them — standing on a beach that is itself an aggregate of the same sand
    (12 x 12 m, 25 cm deep: 3.3·10^11 grains, in tiles of 4096) instead of the textured
    plane, under the physical sun and the same sky, at 640 x 480."""
    stage = Usd.Stage.CreateNew(path)
    stage.GetRootLayer().subLayerPaths.append("./sandcastle.usda")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    parts = ["Base", "Keep", "KeepRoof"] + [f"Tower{k}" for k in range(1, 5)] + [f"TowerRoof{k}" for k in range(1, 5)]
    for part in parts:
        over = stage.OverridePrim(f"/World/Castle/{part}")
        UsdGeom.PrimvarsAPI(over).CreatePrimvar("granular:grainRadius", Sdf.ValueTypeNames.Float,
                                                UsdGeom.Tokens.constant).Set(QUARTZ_SAND.grain_radius_m)
    # Light quartz sand whose thick layer reflects what dry beach sand does (0.40, 0.33,
    # 0.24; examples/README.md, "Materials"). The pebble castle's absorption would make
    # quarter-millimetre sand dark brown (0.12, 0.07, 0.03).
    names = ("Round", "Flat", "Dark")  # sandcastle's grains, QUARTZ_SAND's prototypes
    light, dark = QUARTZ_SAND.grain_absorptions()
    for proto, name in zip(QUARTZ_SAND.prototypes, names):
        absorption = dark if proto.dark else light
        UsdGeom.PrimvarsAPI(stage.OverridePrim(f"/World/Grains/{name}")).CreatePrimvar(
            "granular:absorption", Sdf.ValueTypeNames.Color3f, UsdGeom.Tokens.constant).Set(Gf.Vec3f(*absorption))
    # The beach: a slab of the castle's sand just below its base (a gap of one grain, so
    # that the two boundaries never share a face); the textured plane is hidden.
    UsdGeom.Imageable(stage.OverridePrim("/World/Ground")).CreateVisibilityAttr(UsdGeom.Tokens.invisible)
    r = QUARTZ_SAND.grain_radius_m
    beach = mesh_from(stage, "/World/Beach", core.make_box((-6.0, -0.25, -6.0), (6.0, -r, 6.0)))
    schema.apply_aggregate(beach, [stage.GetPrimAtPath(f"/World/Grains/{n}") for n in names], grain_radius=r,
                           packing_rate=QUARTZ_SAND.packing_rate, weights=[p.weight for p in QUARTZ_SAND.prototypes],
                           seed=30, tile_spheres=4096)
    cam = UsdGeom.Camera(stage.OverridePrim("/World/Camera"))
    cam.CreateVerticalApertureAttr(27.0)  # 4:3
    settings = UsdRender.Settings(stage.OverridePrim("/Render/Settings"))
    settings.CreateResolutionAttr(Gf.Vec2i(640, 480))
    stage.GetRootLayer().Save()


def narrow_spot_profile(path):
    """An IES LM-63 profile of a narrow spotlight (written here, deterministic): a beam of
    about 10 degrees (half its peak at 7.5 degrees off the axis) over a faint spill that
    fades out by 70 degrees; photometric type C, rotationally symmetric, lower half only."""
    theta = np.arange(0, 90.5, 1.0)
    candela = 1200 * np.exp(-((theta / 9.0) ** 2)) + 40 * np.clip(1 - theta / 70.0, 0, None) ** 2
    numbers = lambda v: " ".join(f"{x:.4g}" for x in v)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.write("IESNA:LM-63-2002\n[TEST] hdGranular example profile\n[LUMINAIRE] narrow spot, 10 degree beam\n"
                f"TILT=NONE\n1 -1 1 {len(theta)} 1 1 2 0 0 0\n1 1 12\n{numbers(theta)}\n0\n{numbers(candela)}\n")


def sugarcube_shoot(path, sky):
    """A new stage at path over sugarcube.usda (a sublayer) with its sun off and its sky at
    intensity `sky`, for a product shoot's own lights."""
    stage = Usd.Stage.CreateNew(path)
    stage.GetRootLayer().subLayerPaths.append("./sugarcube.usda")
    stage.SetDefaultPrim(stage.GetPrimAtPath("/World"))
    stage.OverridePrim("/World/Sun").SetActive(False)
    UsdLux.DomeLight(stage.OverridePrim("/World/Sky")).CreateIntensityAttr(sky)
    return stage


def aim(xformable, at, target):
    """Places a prim at `at` with its -Z (a light's axis, a quad's front) toward `target`."""
    rot = Gf.Rotation(Gf.Vec3d(0, 0, -1), (target - at).GetNormalized())
    UsdGeom.Xformable(xformable).AddTransformOp().Set(Gf.Matrix4d().SetRotate(rot).SetTranslateOnly(at))


def sugarcube_spot(path):
    """The sugar cube (sugarcube.usda, a sublayer) as on a product shoot: its sun and sky
    off, a small sphere light with the narrow spot's IES profile (profiles/narrow_spot.ies,
    normalised) aimed at it from above and to the left, and a dim sky for fill."""
    narrow_spot_profile(os.path.join(os.path.dirname(path), "profiles", "narrow_spot.ies"))
    stage = sugarcube_shoot(path, sky=0.04)
    spot = UsdLux.SphereLight.Define(stage, "/World/Spot")
    spot.CreateRadiusAttr(0.02)
    spot.CreateIntensityAttr(0.9)
    spot.CreateColorAttr(Gf.Vec3f(1.0, 0.95, 0.88))
    aim(spot, Gf.Vec3d(-0.035, 0.12, 0.045), Gf.Vec3d(0.0, 0.006, 0.0))  # its -Z, the profile's axis, on the cube
    shaping = UsdLux.ShapingAPI.Apply(spot.GetPrim())
    shaping.CreateShapingIesFileAttr(Sdf.AssetPath("./profiles/narrow_spot.ies"))
    shaping.CreateShapingIesNormalizeAttr(True)
    stage.GetRootLayer().Save()


def torus(major, minor, segments, sides):
    """A closed torus about +Y in the XZ plane: points, and quads wound counter-clockwise seen
    from outside (its front, the side a mesh light emits from)."""
    points, faces = [], []
    for i in range(segments):
        a = 2 * math.pi * i / segments
        for j in range(sides):
            b = 2 * math.pi * j / sides
            rho = major + minor * math.cos(b)
            points.append((rho * math.cos(a), minor * math.sin(b), rho * math.sin(a)))
    for i in range(segments):
        for j in range(sides):
            i1, j1 = (i + 1) % segments, (j + 1) % sides
            faces.append([i * sides + j, i * sides + j1, i1 * sides + j1, i1 * sides + j])
    return points, faces


def sugarcube_neon(path):
    """The sugar cube (sugarcube.usda, a sublayer) lit by mesh lights (UsdLuxMeshLightAPI):
    a white softbox (a quad) above and to the left, and a pink neon ring (a torus) on the
    table around the cube; its sun off and its sky dimmed."""
    stage = sugarcube_shoot(path, sky=0.02)
    # The softbox, 4 x 3 cm, its front (counter-clockwise seen from the cube) facing the cube.
    box = UsdGeom.Mesh.Define(stage, "/World/Softbox")
    box.CreatePointsAttr([(-0.02, -0.015, 0), (-0.02, 0.015, 0), (0.02, 0.015, 0), (0.02, -0.015, 0)])
    box.CreateFaceVertexCountsAttr([4])
    box.CreateFaceVertexIndicesAttr([0, 1, 2, 3])  # facing -Z
    aim(box, Gf.Vec3d(-0.05, 0.09, 0.03), Gf.Vec3d(0.0, 0.006, 0.0))
    UsdLux.MeshLightAPI.Apply(box.GetPrim())
    UsdLux.LightAPI(box.GetPrim()).CreateIntensityAttr(120.0)
    UsdLux.LightAPI(box.GetPrim()).CreateColorAttr(Gf.Vec3f(1.0, 0.96, 0.9))
    # The neon ring: a torus of radius 2.2 cm and tube 1.2 mm lying on the table.
    points, faces = torus(0.022, 0.0012, 96, 8)
    ring = UsdGeom.Mesh.Define(stage, "/World/Neon")
    ring.CreatePointsAttr(points)
    ring.CreateFaceVertexCountsAttr([4] * len(faces))
    ring.CreateFaceVertexIndicesAttr([i for f in faces for i in f])
    ring.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    UsdGeom.Xformable(ring).AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0012, 0.0))
    UsdLux.MeshLightAPI.Apply(ring.GetPrim())
    UsdLux.LightAPI(ring.GetPrim()).CreateIntensityAttr(8.0)
    UsdLux.LightAPI(ring.GetPrim()).CreateColorAttr(Gf.Vec3f(1.0, 0.2, 0.55))
    stage.GetRootLayer().Save()


SCENES = {"sandcastle": sandcastle, "snowslab": snowslab, "sugarcube": sugarcube, "mixture": mixture,
          "animated": animated, "macro": macro, "frosted": frosted, "sandcastle_paper": sandcastle_paper,
          "sugarcube_spot": sugarcube_spot, "sugarcube_neon": sugarcube_neon}


def main(argv):
    out = argv[1] if len(argv) > 1 else os.path.dirname(os.path.abspath(__file__))
    for name, make in SCENES.items():
        path = os.path.join(out, f"{name}.usda")
        if os.path.exists(path):
            os.remove(path)
        make(path)
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
