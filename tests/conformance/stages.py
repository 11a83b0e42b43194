"""Small generated USD stages for the conformance suite (tests/conformance/compare.py): each
valid-but-unusual or invalid, rendered through both USD front ends (`granular render` and
hdGranular), which must agree on the image or on the error.

Every stage is a function returning the .usda text (plain text, so that this module needs
no pxr), registered with @stage(name, description). A stage sits in a 24 x 18 view
(apertures 36 x 27) of /World/Camera unless it says otherwise; `time` is the time code it
is rendered at (None: the stage's default), `camera` the camera prim both front ends are
given (None: the command line picks it itself, from the render settings, while
hdGranular is handed `hydra_camera`).

    write_all(folder) -> [Stage]   writes every stage (and its textures) under folder
"""
import math
import os
from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

WIDTH = 24


@dataclass
class Stage:
    name: str
    description: str
    build: Callable = field(repr=False)
    time: Optional[float] = None
    camera: Optional[str] = "/World/Camera"
    hydra_camera: str = "/World/Camera"
    aperture: tuple = (36.0, 27.0)
    path: str = ""
    grains: bool = False  # has an aggregate (set by write_all)

    @property
    def height(self):
        """As usdrecord's frame recorder sizes its image: width / aspect, truncated."""
        h_ap, v_ap = self.aperture
        return max(int(WIDTH / (h_ap / v_ap)), 1)


STAGES = []


def stage(name, description, **kw):
    def register(fn):
        assert all(s.name != name for s in STAGES), name
        STAGES.append(Stage(name, description, fn, **kw))
        return fn
    return register


# ---- text pieces ------------------------------------------------------------------------------

def _v(p):
    return "(" + ", ".join(_num(x) for x in p) + ")"


def _num(x):
    if isinstance(x, float) and math.isnan(x):
        return "nan"
    return repr(float(x)) if isinstance(x, float) else str(x)


def _arr(ps):
    return "[" + ", ".join(_v(p) for p in ps) + "]"


def _look_at(eye, target, up=(0.0, 1.0, 0.0)):
    """USD matrix4d text of a camera at eye looking at target (the camera looks down -z)."""
    e, t, u = (np.asarray(v, float) for v in (eye, target, up))
    z = e - t
    z /= np.linalg.norm(z)
    x = np.cross(u, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rows = [(*x, 0.0), (*y, 0.0), (*z, 0.0), (*e, 1.0)]
    return "( " + ", ".join("(" + ", ".join(f"{float(v):.6g}" for v in r) + ")" for r in rows) + " )"


def camera(name="Camera", eye=(1.6, 1.2, 1.9), target=(0.0, 0.15, 0.0), focal=35.0, aperture=(36.0, 27.0),
           extra=""):
    return f"""
    def Camera "{name}"
    {{
        float2 clippingRange = (0.01, 100)
        float focalLength = {focal}
        float horizontalAperture = {aperture[0]}
        float verticalAperture = {aperture[1]}
        matrix4d xformOp:transform = {_look_at(eye, target)}
        uniform token[] xformOpOrder = ["xformOp:transform"]
{extra}
    }}
"""


# Box corners: index x + 2y + 4z; quads wound counter-clockwise seen from outside.
_BOX_FACES = [(0, 4, 6, 2), (1, 3, 7, 5), (0, 1, 5, 4), (2, 6, 7, 3), (0, 2, 3, 1), (4, 5, 7, 6)]


def box_points(lo, hi):
    return [(hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]) for i in range(8)]


def mesh(name, points, faces, extra="", api=(), material=None, display_color=None):
    schemas = list(api) + (["MaterialBindingAPI"] if material else [])
    meta = f' (\n        prepend apiSchemas = {_tokens(schemas)}\n    )' if schemas else ""
    lines = [f"        point3f[] points = {_arr(points)}",
             f"        int[] faceVertexCounts = {[len(f) for f in faces]}",
             f"        int[] faceVertexIndices = {[i for f in faces for i in f]}",
             '        uniform token subdivisionScheme = "none"']
    if material:
        lines.append(f"        rel material:binding = <{material}>")
    if display_color is not None:
        lines.append(f"        color3f[] primvars:displayColor = [{_v(display_color)}]")
    return f'\n    def Mesh "{name}"{meta}\n    {{\n' + "\n".join(lines) + "\n" + extra + "\n    }\n"


def _tokens(ts):
    return "[" + ", ".join(f'"{t}"' for t in ts) + "]"


def box(name, lo, hi, **kw):
    return mesh(name, box_points(lo, hi), _BOX_FACES, **kw)


def ground(material=None, display_color=(0.5, 0.5, 0.5), extra=""):
    pts = [(-2, 0, 2), (2, 0, 2), (2, 0, -2), (-2, 0, -2)]
    return mesh("Ground", pts, [(0, 1, 2, 3)], material=material,
                display_color=None if material else display_color, extra=extra)


def block(material=None, display_color=(0.7, 0.35, 0.2), extra=""):
    return box("Block", (-0.8, 0.0, -0.3), (-0.3, 0.5, 0.2), material=material,
               display_color=None if material else display_color, extra=extra)


def constant(type_name, name, value):
    return (f'        {type_name} primvars:granular:{name} = {value} (\n'
            '            interpolation = "constant"\n        )')


GRAIN_DEFAULTS = {"ior": ("float", "1.5"), "absorption": ("color3f", "(0.2, 0.3, 0.5)"), "roughness": ("float", "0")}


def grains(values=None, names=("A",), extra=""):
    """The prototypes /World/Grains/<name>: invisible boxes with GranularGrainAPI."""
    body = ""
    for n in names:
        vals = dict(GRAIN_DEFAULTS)
        vals.update((values or {}).get(n, {}))
        attrs = "\n".join(constant(tv[0], k, tv[1]) for k, tv in vals.items() if tv is not None)
        attrs += '\n        token visibility = "invisible"'
        pts = box_points((-1.0, -0.7, -0.6), (1.0, 0.7, 0.6)) if n == "A" else box_points((-0.6, -0.9, -0.8),
                                                                                            (0.6, 0.9, 0.8))
        body += mesh(n, pts, _BOX_FACES, api=["GranularGrainAPI"], extra=attrs).replace("\n    ", "\n        ")
    return f'\n    def Scope "Grains"\n    {{{body}{extra}\n    }}\n'


AGGREGATE_DEFAULTS = {
    "grainRadius": ("float", "0.02"),
    "packingRate": ("float", "0.55"),
    "prototypes": ("string[]", '["../Grains/A"]'),
    "seed": ("int", "3"),
    "tileSpheres": ("int", "64"),
}


def pile(values=None, points=None, faces=None, extra="", name="Pile"):
    """An aggregate /World/Pile: a 0.4 x 0.3 x 0.4 box of some 1000 grains; values
    override the authored primvars ((type, text), or None to leave one unauthored)."""
    vals = dict(AGGREGATE_DEFAULTS)
    vals.update(values or {})
    attrs = "\n".join(constant(t, k, v) for k, tv in vals.items() if tv is not None for t, v in [tv])
    pts = points or box_points((0.0, 0.0, -0.2), (0.4, 0.3, 0.2))
    return mesh(name, pts, faces or _BOX_FACES, api=["GranularAggregateAPI"], extra=attrs + extra)


def sun(angle=5.0, intensity=2.0, extra="", name="Sun"):
    return f"""
    def DistantLight "{name}"
    {{
        float inputs:angle = {angle}
        float inputs:intensity = {intensity}
        float3 xformOp:rotateXYZ = (-50, 30, 0)
        uniform token[] xformOpOrder = ["xformOp:rotateXYZ"]
{extra}
    }}
"""


def sky(intensity=0.3, extra="", name="Sky"):
    return f"""
    def DomeLight "{name}"
    {{
        float inputs:intensity = {intensity}
{extra}
    }}
"""


def rect_light(extra="", intensity=8.0, width=0.8, height=0.8):
    return f"""
    def RectLight "Panel"
    {{
        float inputs:intensity = {intensity}
        float inputs:width = {width}
        float inputs:height = {height}
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        double3 xformOp:translate = (0, 1.5, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
{extra}
    }}
"""


def sphere_light(extra="", intensity=6.0, radius=0.15):
    return f"""
    def SphereLight "Bulb"
    {{
        float inputs:intensity = {intensity}
        float inputs:radius = {radius}
        double3 xformOp:translate = (0.3, 1.0, 0.6)
        uniform token[] xformOpOrder = ["xformOp:translate"]
{extra}
    }}
"""


def disk_light(extra="", api=""):
    """A DiskLight of radius 0.3 facing down; api: its apiSchemas metadata line."""
    meta = f" (\n        {api}\n    )" if api else ""
    return f"""
    def DiskLight "Disk"{meta}
    {{
        float inputs:intensity = 10
        float inputs:radius = 0.3
        double3 xformOp:translate = (0, 1.2, 0)
        float3 xformOp:rotateXYZ = (-90, 0, 0)
        uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]
{extra}
    }}
"""


def preview_material(name, inputs, nodes=""):
    """A Material /World/Looks/<name> of one UsdPreviewSurface with `inputs` (lines)."""
    body = "\n".join("                " + i for i in inputs)
    return f"""
        def Material "{name}"
        {{
            token outputs:surface.connect = </World/Looks/{name}/Surface.outputs:surface>

            def Shader "Surface"
            {{
                uniform token info:id = "UsdPreviewSurface"
{body}
                token outputs:surface
            }}
{nodes}
        }}
"""


def looks(*materials):
    return '\n    def Scope "Looks"\n    {' + "".join(materials) + "\n    }\n"


def texture_nodes(material, file, varname="st", output="rgb", extra=()):
    ex = "\n".join("                " + e for e in extra)
    return f"""
            def Shader "St"
            {{
                uniform token info:id = "UsdPrimvarReader_float2"
                string inputs:varname = "{varname}"
                float2 outputs:result
            }}

            def Shader "Texture"
            {{
                uniform token info:id = "UsdUVTexture"
                asset inputs:file = @{file}@
                float2 inputs:st.connect = </World/Looks/{material}/St.outputs:result>
{ex}
                float3 outputs:rgb
                float outputs:r
            }}
"""


def usda(body, meta="", after=""):
    return f"""#usda 1.0
(
    defaultPrim = "World"
    metersPerUnit = 1
    upAxis = "Y"
{meta}
)

def Xform "World"
{{
{body}
}}
{after}"""


def scene(lights=None, objects=None, cam=None, meta="", after=""):
    """The usual view: camera, grey ground, a terracotta block, and `objects`, under
    `lights` (default: a 5-degree sun and a dim sky)."""
    lights = (sky() + sun()) if lights is None else lights
    objects = (block()) if objects is None else objects
    return usda((cam or camera()) + ground() + objects + lights, meta=meta, after=after)


def granular_scene(values=None, grain_values=None, names=("A",), lights=None, points=None, faces=None):
    return scene(lights=lights, objects=block() + grains(grain_values, names) + pile(values, points, faces))


TEX = {}  # name -> absolute path, filled by write_textures


def write_textures(folder):
    """A small checker PNG, a UDIM tile of it, and a lat-long sky EXR (written by granular_core)."""
    import granular_core as core
    os.makedirs(folder, exist_ok=True)
    yy, xx = np.mgrid[0:8, 0:8]
    check = ((xx // 2 + yy // 2) % 2).astype(np.float32)
    rgb = np.stack([0.2 + 0.7 * check, 0.6 - 0.3 * check, 0.3 + 0.1 * check], axis=-1).astype(np.float32)
    a = np.ones((8, 8, 1), np.float32) * (0.2 + 0.8 * check[..., None])
    img = core.Image(np.concatenate([rgb, a], axis=-1).astype(np.float32), ["R", "G", "B", "A"])
    TEX["checker"] = os.path.join(folder, "checker.png")
    core.write_png(TEX["checker"], img)
    TEX["udim"] = os.path.join(folder, "tile.<UDIM>.png")
    core.write_png(os.path.join(folder, "tile.1001.png"), img)
    # Lat-long sky: brighter and bluer upwards, warm near one azimuth.
    h, w = 16, 32
    v, u = np.mgrid[0:h, 0:w]
    up = 1.0 - (v + 0.5) / h
    warm = np.exp(-(((u + 0.5) / w - 0.3) ** 2) / 0.01) * (up > 0.4)
    sky_px = np.stack([0.3 + 0.5 * up + 3.0 * warm, 0.4 + 0.6 * up + 2.0 * warm, 0.6 + 0.9 * up + 0.5 * warm], -1)
    TEX["sky"] = os.path.join(folder, "sky.exr")
    core.write_exr(TEX["sky"], core.Image(sky_px.astype(np.float32), ["R", "G", "B"]))
    TEX["missing"] = os.path.join(folder, "no_such_texture.png")
    # An IES LM-63 profile without symmetry (rows at 0, 90, 180 and 270 degrees), so that its
    # orientation shows; and a file that is not one.
    rows = ["90 70 20 0 0", "20 60 40 5 0", "60 10 80 10 0", "30 30 30 30 0"]
    with open(os.path.join(folder, "spot.ies"), "w") as f:
        f.write("IESNA:LM-63-2002\n[TEST] conformance\nTILT=NONE\n1 -1 0.01 5 4 1 2 0 0 0\n1 1 10\n"
                "0 20 40 60 90\n0 90 180 270\n" + "\n".join(rows) + "\n")
    TEX["ies"] = os.path.join(folder, "spot.ies")
    with open(os.path.join(folder, "photo.ies"), "w") as f:
        f.write("a photograph, not a profile\n")
    TEX["ies_bad"] = os.path.join(folder, "photo.ies")
    return TEX


# ---- lights -----------------------------------------------------------------------------------

@stage("distant_angle0_grains", "a delta sun (angle 0) over smooth grains: made the physical 0.53-degree sun")
def _():
    return granular_scene(lights=sky() + sun(angle=0.0))


@stage("distant_angle0_no_grains", "a delta sun (angle 0) over diffuse surfaces only: stays a delta light")
def _():
    return scene(lights=sky() + sun(angle=0.0))


@stage("distant_angle053", "a distant light of 0.53 degrees (the sun's disk)")
def _():
    return scene(lights=sky() + sun(angle=0.53))


@stage("distant_angle30", "a wide distant light of 30 degrees, over grains")
def _():
    return granular_scene(lights=sky() + sun(angle=30.0))


@stage("dome_uniform", "a coloured uniform dome light only")
def _():
    return scene(lights=sky(1.0, extra="        color3f inputs:color = (0.6, 0.7, 1)"))


@stage("dome_texture", "a dome light of a lat-long EXR texture")
def _():
    return scene(lights=sky(1.0, extra=f"        asset inputs:texture:file = @{TEX['sky']}@\n"
                                       '        token inputs:texture:format = "latlong"'))


@stage("dome_texture_missing", "a dome light whose texture file does not exist")
def _():
    return scene(lights=sky(1.0, extra=f"        asset inputs:texture:file = @{TEX['missing']}@"))


@stage("rect_light", "a rect light above the scene, no other light")
def _():
    return scene(lights=rect_light())


@stage("rect_light_normalize", "a normalised rect light (power independent of its size)")
def _():
    return scene(lights=rect_light(extra="        bool inputs:normalize = 1", intensity=3.0, width=1.6, height=0.4))


@stage("sphere_light", "a sphere light of radius 0.15")
def _():
    return scene(lights=sphere_light())


@stage("sphere_light_point", "a sphere light of radius 0 (a point light)")
def _():
    return scene(lights=sphere_light(radius=0.0, intensity=3.0))


@stage("sphere_light_normalize", "a normalised sphere light")
def _():
    return scene(lights=sphere_light(extra="        bool inputs:normalize = 1", intensity=1.0, radius=0.3))


@stage("sphere_light_negative_radius", "a sphere light of radius -0.1 (invalid)")
def _():
    return scene(lights=sphere_light(radius=-0.1))


@stage("disk_light", "a disk light of radius 0.3 facing down, next to a dim sky")
def _():
    return scene(lights=sky(0.3) + disk_light())


@stage("cylinder_light", "a cylinder light of radius 0.05 and length 1, next to a dim sky")
def _():
    return scene(lights=sky(0.3) + """
    def CylinderLight "Tube"
    {
        float inputs:intensity = 10
        float inputs:length = 1
        float inputs:radius = 0.05
        double3 xformOp:translate = (0, 1.2, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
""")


@stage("light_exposure", "a sun of intensity 0.5 and exposure 2 (x4)")
def _():
    return scene(lights=sky() + sun(intensity=0.5, extra="        float inputs:exposure = 2"))


@stage("light_color", "a coloured rect light")
def _():
    return scene(lights=rect_light(extra="        color3f inputs:color = (1, 0.4, 0.1)"))


@stage("light_color_temperature", "a sun of colour temperature 3000 K (enabled)")
def _():
    return scene(lights=sky() + sun(extra="        bool inputs:enableColorTemperature = 1\n"
                                  "        float inputs:colorTemperature = 3000"))


@stage("light_color_temperature_off", "colour temperature 3000 K authored but not enabled")
def _():
    return scene(lights=sky() + sun(extra="        bool inputs:enableColorTemperature = 0\n"
                                  "        float inputs:colorTemperature = 3000"))


@stage("light_color_temperature_zero", "colour temperature 0 K enabled (invalid)")
def _():
    return scene(lights=sky() + sun(extra="        bool inputs:enableColorTemperature = 1\n"
                                  "        float inputs:colorTemperature = 0"))


@stage("light_color_temperature_negative", "colour temperature -1000 K enabled (invalid)")
def _():
    return scene(lights=sky() + sun(extra="        bool inputs:enableColorTemperature = 1\n"
                                  "        float inputs:colorTemperature = -1000"))


@stage("light_intensity_negative", "a sun of intensity -1 (invalid)")
def _():
    return scene(lights=sky() + sun(intensity=-1.0))


@stage("light_invisible", "an invisible sun next to a visible sky")
def _():
    return scene(lights=sky() + sun(extra='        token visibility = "invisible"'))


@stage("rect_light_texture", "a rect light with a texture file (its image on the light)")
def _():
    return scene(lights=rect_light(extra=f"        asset inputs:texture:file = @{TEX['checker']}@"))


@stage("light_shaping_cone", "a sphere light with ShapingAPI cone angle 20 (a spot)")
def _():
    return scene(lights=sphere_light(
        extra="        float inputs:shaping:cone:angle = 20\n        float inputs:shaping:cone:softness = 0.1"
    ).replace('def SphereLight "Bulb"', 'def SphereLight "Bulb" (\n        prepend apiSchemas = ["ShapingAPI"]\n    )')
                 + sky(0.1))


@stage("disk_light_focus", "a disk light with ShapingAPI: a soft 40° cone, focus 4 tinted blue")
def _():
    return scene(lights=sky(0.1) + disk_light(
        extra="        float inputs:shaping:cone:angle = 40\n        float inputs:shaping:cone:softness = 0.5\n"
              "        float inputs:shaping:focus = 4\n        color3f inputs:shaping:focusTint = (0.1, 0.2, 0.6)",
        api='prepend apiSchemas = ["ShapingAPI"]'))


@stage("light_ies", "a sphere light with an IES profile (no symmetry; named relative to the stage)")
def _():
    return scene(lights=sphere_light(
        extra="        asset inputs:shaping:ies:file = @./textures/spot.ies@\n"
              "        float3 xformOp:rotateXYZ = (-80, 20, 0)",
        intensity=30.0).replace('uniform token[] xformOpOrder = ["xformOp:translate"]',
                                'uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:rotateXYZ"]')
        .replace('def SphereLight "Bulb"', 'def SphereLight "Bulb" (\n        prepend apiSchemas = ["ShapingAPI"]\n    )')
        + sky(0.1))


@stage("light_ies_scaled_normalized", "a disk light's IES profile narrowed by angleScale 0.5 and normalised")
def _():
    return scene(lights=sky(0.1) + disk_light(
        extra=f"        asset inputs:shaping:ies:file = @{TEX['ies']}@\n"
              "        float inputs:shaping:ies:angleScale = 0.5\n        bool inputs:shaping:ies:normalize = 1",
        api='prepend apiSchemas = ["ShapingAPI"]'))


@stage("light_ies_not_a_profile", "an IES file that is not a profile (invalid)")
def _():
    return scene(lights=sky(0.1) + disk_light(
        extra=f"        asset inputs:shaping:ies:file = @{TEX['ies_bad']}@", api='prepend apiSchemas = ["ShapingAPI"]'))


@stage("cylinder_light_length_zero", "a cylinder light of length 0 (invalid)")
def _():
    return scene(lights=sky(0.3) + """
    def CylinderLight "Tube"
    {
        float inputs:length = 0
        double3 xformOp:translate = (0, 1.2, 0)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
""")


@stage("light_diffuse_zero", "a sun of inputs:diffuse 0 (not supported: a warning)")
def _():
    return scene(lights=sky() + sun(extra="        float inputs:diffuse = 0"))


NORMALIZED = "        bool inputs:normalize = 1\n"  # a sun of irradiance 2: linking shows


@stage("light_link_exclude", "a sun whose collection:lightLink excludes the ground (light linking)")
def _():
    return scene(lights=sky() + sun(extra=NORMALIZED + "        rel collection:lightLink:excludes = </World/Ground>"))


@stage("light_link_include", "a sun that lights the aggregate alone (includeRoot 0, includes the pile)")
def _():
    link = NORMALIZED + "        uniform bool collection:lightLink:includeRoot = 0\n" \
                        "        rel collection:lightLink:includes = </World/Pile>"
    return granular_scene(lights=sky() + sun(extra=link))


@stage("shadow_link", "a sun whose collection:shadowLink excludes the block (no shadow from it on the ground)")
def _():
    return scene(lights=sky() + sun(extra=NORMALIZED + "        rel collection:shadowLink:excludes = </World/Block>"))


@stage("shadow_link_aggregate", "a sun whose shadows the aggregate alone casts (includeRoot 0, includes the pile)")
def _():
    link = NORMALIZED + "        uniform bool collection:shadowLink:includeRoot = 0\n" \
                        "        rel collection:shadowLink:includes = </World/Pile>"
    return granular_scene(lights=sky() + sun(extra=link))


@stage("shadow_enable_off", "a sun and a sky of inputs:shadow:enable 0 (nothing casts their shadows)")
def _():
    off = "        bool inputs:shadow:enable = 0"
    return granular_scene(lights=sky(extra=off) + sun(extra=NORMALIZED + off))


GLOW_CARD = [(-0.2, 0.9, -0.2), (0.2, 0.9, -0.2), (0.2, 0.9, 0.2), (-0.2, 0.9, 0.2)]  # facing down


@stage("mesh_light", "a mesh with MeshLightAPI (a geometry light) and a dim sky")
def _():
    card = mesh("Glow", GLOW_CARD, [(0, 1, 2, 3)], api=["MeshLightAPI"], extra="        float inputs:intensity = 20")
    return scene(lights=sky(0.1) + card)


@stage("mesh_light_double_sided", "a mesh light wound to face up, doubleSided, normalised and warm")
def _():
    card = mesh("Glow", GLOW_CARD, [(3, 2, 1, 0)], api=["MeshLightAPI"],
                extra="        float inputs:intensity = 3\n        bool inputs:normalize = 1\n"
                      "        bool inputs:enableColorTemperature = 1\n        float inputs:colorTemperature = 3000\n"
                      "        uniform bool doubleSided = 1")
    return scene(lights=sky(0.1) + card)


def glowing_card(extra=""):
    """The card as a mesh light of intensity 20 bound to a material of emissiveColor (1, 0.4, 0.1)."""
    card = mesh("Glow", GLOW_CARD, [(0, 1, 2, 3)], api=["MeshLightAPI"], material="/World/Looks/M",
                extra="        float inputs:intensity = 20" + extra)
    return scene(lights=sky(0.1) + card, objects=block() + looks(preview_material(
        "M", ["color3f inputs:diffuseColor = (0.2, 0.2, 0.2)", "color3f inputs:emissiveColor = (1, 0.4, 0.1)"])))


@stage("mesh_light_tinted", "a mesh light tinted by its material's emissiveColor (materialGlowTintsLight)")
def _():
    return glowing_card()


@stage("mesh_light_untinted", "the tinted mesh light with light:materialSyncMode noMaterialResponse")
def _():
    return glowing_card('\n        uniform token light:materialSyncMode = "noMaterialResponse"')


@stage("mesh_light_sphere", "a Sphere with MeshLightAPI (an implicit surface as a light)")
def _():
    return scene(lights=sky(0.1) + """
    def Sphere "Glow" (
        prepend apiSchemas = ["MeshLightAPI"]
    )
    {
        double radius = 0.1
        float inputs:intensity = 30
        double3 xformOp:translate = (0.3, 0.7, 0.3)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
""")


@stage("mesh_light_link", "a mesh light whose collection:lightLink holds the block alone (includeRoot 0)")
def _():
    card = mesh("Glow", GLOW_CARD, [(0, 1, 2, 3)], api=["MeshLightAPI"],
                extra="        float inputs:intensity = 20\n        uniform bool collection:lightLink:includeRoot = 0\n"
                      "        rel collection:lightLink:includes = </World/Block>")
    return scene(lights=sky(0.1) + card)


@stage("mesh_light_instanced", "a PointInstancer of a small glowing card (MeshLightAPI), three instances")
def _():
    card = mesh("Glow", [(-0.08, 0.6, -0.08), (0.08, 0.6, -0.08), (0.08, 0.6, 0.08), (-0.08, 0.6, 0.08)],
                [(0, 1, 2, 3)], api=["MeshLightAPI"], extra="        float inputs:intensity = 40")
    card = card.replace("\n    ", "\n            ")
    return scene(lights=sky(0.1), objects=block() + f"""
    def PointInstancer "Lamps"
    {{
        point3f[] positions = [(0.3, 0, 0.5), (-0.4, 0, 0.4), (0.2, 0.2, -0.5)]
        int[] protoIndices = [0, 0, 0]
        rel prototypes = </World/Lamps/Protos/Glow>

        def Scope "Protos"
        {{{card}
        }}
    }}
""")


@stage("mesh_light_intensity_negative", "a mesh light of inputs:intensity -1 (invalid)")
def _():
    card = mesh("Glow", GLOW_CARD, [(0, 1, 2, 3)], api=["MeshLightAPI"], extra="        float inputs:intensity = -1")
    return scene(lights=sky(0.1) + card)


@stage("dome_texture_angular", 'a dome texture of format "angular" (not lat-long)')
def _():
    return scene(lights=sky(1.0, extra=f"        asset inputs:texture:file = @{TEX['sky']}@\n"
                                       '        token inputs:texture:format = "angular"'))


@stage("light_order", "a sun authored before the sky (the other stages author the sky first)")
def _():
    return scene(lights=sun() + sky())


@stage("no_light", "no light at all: the default dome, with a warning")
def _():
    return scene(lights="")


# ---- materials --------------------------------------------------------------------------------

def _on_block(material_text, **kw):
    return scene(objects=block(material="/World/Looks/M", **kw) + looks(material_text))


@stage("preview_diffuse", "UsdPreviewSurface diffuseColor on the block")
def _():
    return _on_block(preview_material("M", ["color3f inputs:diffuseColor = (0.1, 0.6, 0.3)"]))


@stage("preview_emissive", "an emissive block as the only light")
def _():
    return scene(lights="", objects=block(material="/World/Looks/M") + looks(preview_material(
        "M", ["color3f inputs:diffuseColor = (0, 0, 0)", "color3f inputs:emissiveColor = (4, 3, 2)"])))


@stage("preview_glass", "opacity 0.3, ior 1.33: a glass block")
def _():
    return _on_block(preview_material("M", ["float inputs:opacity = 0.3", "float inputs:ior = 1.33"]))


@stage("preview_opacity_threshold", "opacity 0.3 below opacityThreshold 0.5: cut out")
def _():
    return _on_block(preview_material("M", ["float inputs:opacity = 0.3", "float inputs:opacityThreshold = 0.5",
                                            "color3f inputs:diffuseColor = (0.9, 0.9, 0.1)"]))


@stage("preview_negative_diffuse", "diffuseColor (-1, 2, 0.5): out of [0, 1]")
def _():
    return _on_block(preview_material("M", ["color3f inputs:diffuseColor = (-1, 2, 0.5)"]))


@stage("preview_unknown_shader", "a material whose surface is not a UsdPreviewSurface")
def _():
    text = preview_material("M", ["color3f inputs:diffuseColor = (0.1, 0.6, 0.3)"]).replace(
        '"UsdPreviewSurface"', '"ND_standard_surface_surfaceshader"')
    return _on_block(text)


@stage("preview_emissive_negative", "emissiveColor (-1, 0, 0) (invalid)")
def _():
    return _on_block(preview_material("M", ["color3f inputs:emissiveColor = (-1, 0, 0)"]))


@stage("preview_ior_zero", "opacity 0.2 with ior 0 (invalid glass)")
def _():
    return _on_block(preview_material("M", ["float inputs:opacity = 0.2", "float inputs:ior = 0"]))


@stage("display_color_wrong_count", "a vertex displayColor of 3 values for 8 points")
def _():
    blk = block(display_color=None, extra='        color3f[] primvars:displayColor = [(1, 0, 0), (0, 1, 0), '
                                          '(0, 0, 1)] (\n            interpolation = "vertex"\n        )')
    return scene(objects=blk)


@stage("display_color", "displayColor on the ground and block, no material")
def _():
    return scene()


@stage("display_color_vertex", "a vertex-interpolated displayColor (averaged)")
def _():
    blk = block(display_color=None, extra='        color3f[] primvars:displayColor = [(1, 0, 0), (0, 1, 0), '
                                          '(0, 0, 1), (1, 1, 0), (0, 1, 1), (1, 0, 1), (1, 1, 1), (0, 0, 0)] (\n'
                                          '            interpolation = "vertex"\n        )')
    return scene(objects=blk)


# Texture networks on the block, st of `interpolation`.
_ST = {
    "vertex": [(0, 0), (1, 0), (0, 1), (1, 1), (0, 1), (1, 1), (0, 2), (1, 2)],
    "uniform": [(0.1, 0.1), (0.6, 0.1), (0.1, 0.6), (0.6, 0.6), (0.3, 0.3), (0.9, 0.9)],
    "faceVarying": [(0, 0), (2, 0), (2, 2), (0, 2)] * 6,
}


def _textured(inputs=("color3f inputs:diffuseColor.connect = </World/Looks/M/Texture.outputs:rgb>",),
              tex_extra=(), interpolation="vertex", st=None, file=None, lights=None):
    st = _ST[interpolation] if st is None else st
    st_text = (f"        texCoord2f[] primvars:st = {_arr(st)} (\n"
               f'            interpolation = "{interpolation}"\n        )')
    nodes = texture_nodes("M", file or TEX["checker"], extra=tex_extra)
    return scene(lights=lights, objects=block(material="/World/Looks/M", extra=st_text)
                 + looks(preview_material("M", list(inputs), nodes)))


@stage("texture_vertex_st", "a checker diffuseColor texture on vertex st")
def _():
    return _textured()


@stage("texture_facevarying_st", "the texture on face-varying st (repeating twice)")
def _():
    return _textured(interpolation="faceVarying", tex_extra=['token inputs:wrapS = "repeat"',
                                                             'token inputs:wrapT = "repeat"'])


@stage("texture_uniform_st", "the texture on uniform (per-face) st")
def _():
    return _textured(interpolation="uniform")


@stage("texture_wrap_clamp_mirror", "wrapS clamp, wrapT mirror on st beyond [0, 1]")
def _():
    return _textured(interpolation="faceVarying", tex_extra=['token inputs:wrapS = "clamp"',
                                                             'token inputs:wrapT = "mirror"'])


@stage("texture_wrap_unknown", 'wrapS "sideways": an unknown wrap token')
def _():
    return _textured(tex_extra=['token inputs:wrapS = "sideways"'])


@stage("texture_scale_bias", "scale (0.5, 2, 1, 1) and bias (0.1, -0.2, 0, 0)")
def _():
    return _textured(tex_extra=["float4 inputs:scale = (0.5, 2, 1, 1)", "float4 inputs:bias = (0.1, -0.2, 0, 0)"])


@stage("texture_colorspace_raw", "sourceColorSpace raw (no sRGB decoding)")
def _():
    return _textured(tex_extra=['token inputs:sourceColorSpace = "raw"'])


@stage("texture_colorspace_unknown", 'sourceColorSpace "ACEScg-ish": unknown')
def _():
    return _textured(tex_extra=['token inputs:sourceColorSpace = "ACEScg-ish"'])


@stage("texture_udim", "a UDIM texture path (tile.<UDIM>.png, tile 1001 present)")
def _():
    return _textured(file=TEX["udim"])


@stage("texture_missing_file", "the texture file does not exist")
def _():
    return _textured(file=TEX["missing"])


@stage("texture_st_count_mismatch", "vertex st with 5 values for 8 points")
def _():
    return _textured(st=_ST["vertex"][:5])


@stage("texture_emissive", "emissiveColor from the texture as the only light")
def _():
    return _textured(inputs=("color3f inputs:diffuseColor = (0, 0, 0)",
                             "color3f inputs:emissiveColor.connect = </World/Looks/M/Texture.outputs:rgb>"),
                     tex_extra=["float4 inputs:scale = (3, 3, 3, 1)"], lights="")


@stage("texture_opacity_cutout", "opacity from the texture's r above opacityThreshold 0.5")
def _():
    return _textured(inputs=("color3f inputs:diffuseColor = (0.2, 0.4, 0.9)",
                             "float inputs:opacity.connect = </World/Looks/M/Texture.outputs:r>",
                             "float inputs:opacityThreshold = 0.5"))


# ---- cameras ----------------------------------------------------------------------------------

@stage("camera_zero_aperture", "horizontalAperture 0 (invalid)")
def _():
    return scene(cam=camera().replace("float horizontalAperture = 36.0", "float horizontalAperture = 0"))


@stage("camera_clipping_inverted", "clippingRange (10, 1): near beyond far (invalid)")
def _():
    return scene(cam=camera().replace("(0.01, 100)", "(10, 1)"))


@stage("camera_long_focal", "focal length 100 (a narrow view)")
def _():
    return scene(cam=camera(focal=100.0))


@stage("camera_wide_aperture", "apertures 48 x 20: a wide image (24 x 10)", aperture=(48.0, 20.0))
def _():
    return scene(cam=camera(aperture=(48.0, 20.0)))


@stage("camera_offsets", "aperture offsets (6, -4) mm")
def _():
    return scene(cam=camera(extra="        float horizontalApertureOffset = 6\n"
                                  "        float verticalApertureOffset = -4"))


@stage("camera_clipping", "clippingRange (2.6, 100): the near plane cuts into the scene")
def _():
    return scene(cam=camera().replace("(0.01, 100)", "(2.6, 100)"))


@stage("camera_dof", "fStop 4, focusDistance 1.5: depth of field")
def _():
    return scene(cam=camera(extra="        float fStop = 4\n        float focusDistance = 1.5"))


@stage("camera_dof_fastest", "fStop 0.5 (the fastest lens allowed), focusDistance 1.5")
def _():
    return scene(cam=camera(extra="        float fStop = 0.5\n        float focusDistance = 1.5"))


@stage("camera_fstop_negative", "fStop -2 (invalid)")
def _():
    return scene(cam=camera(extra="        float fStop = -2\n        float focusDistance = 1.5"))


@stage("camera_focus_zero", "fStop 2 with focusDistance 0 (invalid)")
def _():
    return scene(cam=camera(extra="        float fStop = 2\n        float focusDistance = 0"))


@stage("camera_orthographic", "an orthographic camera of apertures 36 x 27 (tenths of a unit)")
def _():
    return scene(cam=camera(extra='        token projection = "orthographic"'))


# ---- implicit shapes, instancing --------------------------------------------------------------

def _shape(decl):
    return scene(objects=decl)


@stage("shape_cube", "a Cube of size 0.5")
def _():
    return _shape('\n    def Cube "Shape"\n    {\n        double size = 0.5\n        double3 xformOp:translate = '
                  '(0, 0.25, 0)\n        uniform token[] xformOpOrder = ["xformOp:translate"]\n'
                  '        color3f[] primvars:displayColor = [(0.2, 0.5, 0.8)]\n    }\n')


@stage("shape_sphere", "a Sphere of radius 0.3")
def _():
    return _shape('\n    def Sphere "Shape"\n    {\n        double radius = 0.3\n        double3 xformOp:translate = '
                  '(0, 0.3, 0)\n        uniform token[] xformOpOrder = ["xformOp:translate"]\n'
                  '        color3f[] primvars:displayColor = [(0.2, 0.5, 0.8)]\n    }\n')


@stage("shape_cone", "a Cone (radius 0.3, height 0.6, axis Y)")
def _():
    return _shape('\n    def Cone "Shape"\n    {\n        double radius = 0.3\n        double height = 0.6\n'
                  '        uniform token axis = "Y"\n        double3 xformOp:translate = (0, 0.3, 0)\n'
                  '        uniform token[] xformOpOrder = ["xformOp:translate"]\n'
                  '        color3f[] primvars:displayColor = [(0.2, 0.5, 0.8)]\n    }\n')


@stage("shape_cylinder", "a Cylinder (radius 0.25, height 0.5, axis X)")
def _():
    return _shape('\n    def Cylinder "Shape"\n    {\n        double radius = 0.25\n        double height = 0.5\n'
                  '        uniform token axis = "X"\n        double3 xformOp:translate = (0, 0.25, 0)\n'
                  '        uniform token[] xformOpOrder = ["xformOp:translate"]\n'
                  '        color3f[] primvars:displayColor = [(0.2, 0.5, 0.8)]\n    }\n')


@stage("shape_capsule", "a Capsule (radius 0.15, height 0.4, axis Y)")
def _():
    return _shape('\n    def Capsule "Shape"\n    {\n        double radius = 0.15\n        double height = 0.4\n'
                  '        uniform token axis = "Y"\n        double3 xformOp:translate = (0, 0.35, 0)\n'
                  '        uniform token[] xformOpOrder = ["xformOp:translate"]\n'
                  '        color3f[] primvars:displayColor = [(0.2, 0.5, 0.8)]\n    }\n')


@stage("point_instancer", "a PointInstancer of a cube mesh, three instances (one rotated)")
def _():
    proto = box("Cube", (-0.1, 0.0, -0.1), (0.1, 0.2, 0.1), display_color=(0.9, 0.8, 0.2))
    proto = proto.replace("\n    ", "\n            ")
    return scene(objects=block() + f"""
    def PointInstancer "Instancer"
    {{
        point3f[] positions = [(0, 0, 0.5), (0.4, 0, 0.3), (0.2, 0, -0.4)]
        int[] protoIndices = [0, 0, 0]
        quath[] orientations = [(1, 0, 0, 0), (0.9239, 0, 0.3827, 0), (1, 0, 0, 0)]
        rel prototypes = </World/Instancer/Protos/Cube>

        def Scope "Protos"
        {{{proto}
        }}
    }}
""")


@stage("mesh_purpose_proxy", "a second block of purpose proxy (not drawn by a final render)")
def _():
    extra = box("Proxy", (0.0, 0.0, 0.3), (0.5, 0.5, 0.8), display_color=(0.1, 0.8, 0.1),
                extra='        uniform token purpose = "proxy"')
    return scene(objects=block() + extra)


@stage("mesh_purpose_render_and_guide", "a block of purpose render (drawn) and one of purpose guide (not)")
def _():
    extra = box("Render", (0.0, 0.0, 0.3), (0.5, 0.5, 0.8), display_color=(0.1, 0.8, 0.1),
                extra='        uniform token purpose = "render"')
    extra += box("Guide", (0.2, 0.0, -0.8), (0.7, 0.5, -0.3), display_color=(0.9, 0.1, 0.9),
                 extra='        uniform token purpose = "guide"')
    return scene(objects=block() + extra)


@stage("mesh_invisible", "an invisible second block")
def _():
    extra = box("Hidden", (0.0, 0.0, 0.3), (0.5, 0.5, 0.8), display_color=(0.1, 0.8, 0.1),
                extra='        token visibility = "invisible"')
    return scene(objects=block() + extra)


@stage("mesh_hole_indices", "a ground of two quads, one of them a hole (holeIndices)")
def _():
    pts = [(-2, 0, 2), (0, 0, 2), (2, 0, 2), (-2, 0, -2), (0, 0, -2), (2, 0, -2)]
    g = mesh("Ground", pts, [(0, 1, 4, 3), (1, 2, 5, 4)], display_color=(0.5, 0.5, 0.5),
             extra="        int[] holeIndices = [1]")
    return usda(camera() + g + block() + sky() + sun())


@stage("mesh_ngon_left_handed", "a pentagon card, left-handed orientation")
def _():
    pts = [(0.0, 0.05, 0.9), (0.5, 0.05, 0.6), (0.4, 0.6, 0.4), (-0.1, 0.7, 0.5), (-0.3, 0.3, 0.8)]
    card = mesh("Card", pts, [(0, 1, 2, 3, 4)], display_color=(0.2, 0.3, 0.9),
                extra='        uniform token orientation = "leftHanded"')
    return scene(objects=block() + card)


@stage("mesh_catmull_clark", "the block with subdivisionScheme catmullClark (drawn as its cage)")
def _():
    return scene(objects=block().replace('uniform token subdivisionScheme = "none"',
                                         'uniform token subdivisionScheme = "catmullClark"'))


@stage("mesh_mirrored", "the block under a negative scale (-1, 1, 1): mirrored, winding flipped")
def _():
    return scene(objects=f"""
    def Xform "Mirror"
    {{
        float3 xformOp:scale = (-1, 1, 1)
        uniform token[] xformOpOrder = ["xformOp:scale"]
{block().replace(chr(10) + "    ", chr(10) + "        ")}
    }}
""")


def native_instances(lights=None):
    """Two instanceable references /World/A and /World/B to one prototype block."""
    blk = box("Box", (-0.15, 0.0, -0.15), (0.15, 0.3, 0.15), display_color=(0.9, 0.7, 0.1))
    blk = blk.replace(chr(10) + "    ", chr(10) + "        ")
    return scene(lights=lights, objects=block() + """
    def Xform "A" (
        instanceable = true
        prepend references = </Proto>
    )
    {
        double3 xformOp:translate = (0.3, 0, 0.5)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }

    def Xform "B" (
        instanceable = true
        prepend references = </Proto>
    )
    {
        double3 xformOp:translate = (0.5, 0, -0.4)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
""", after=f"""
class Xform "Proto"
{{{blk}
}}
""")


@stage("native_instances", "two instanceable references to one prototype block (native instancing)")
def _():
    return native_instances()


@stage("light_link_native_instances", "native_instances under a sun whose collection:lightLink excludes instance B")
def _():
    return native_instances(lights=sky() + sun(extra=NORMALIZED + "        rel collection:lightLink:excludes = </World/B>"))


@stage("animated_points", "the block's points sampled (it grows), rendered at frame 2", time=2.0)
def _():
    p1 = box_points((-0.8, 0.0, -0.3), (-0.3, 0.5, 0.2))
    p3 = box_points((-0.8, 0.0, -0.3), (-0.1, 0.9, 0.4))
    text = scene(objects=block(), meta="    startTimeCode = 1\n    endTimeCode = 3")
    return text.replace(f"point3f[] points = {_arr(p1)}",
                        f"point3f[] points.timeSamples = {{1: {_arr(p1)}, 3: {_arr(p3)}}}", 1)


@stage("granular_instanced", "an aggregate inside two instanceable references (relative prototypes)")
def _():
    grains_text = grains().replace(chr(10) + "    ", chr(10) + "        ")
    pile_text = pile(values={"prototypes": ("string[]", '["../Grains/A"]')}).replace(chr(10) + "    ",
                                                                                     chr(10) + "        ")
    return scene(objects=block() + """
    def Xform "HeapA" (
        instanceable = true
        prepend references = </HeapProto>
    )
    {
        double3 xformOp:translate = (0, 0, 0.2)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }

    def Xform "HeapB" (
        instanceable = true
        prepend references = </HeapProto>
    )
    {
        double3 xformOp:translate = (-0.2, 0, -0.6)
        uniform token[] xformOpOrder = ["xformOp:translate"]
    }
""", after=f"""
class Xform "HeapProto"
{{{grains_text}{pile_text}
}}
""")


# ---- time samples -----------------------------------------------------------------------------

@stage("animated_light_intensity", "a sun's intensity sampled 1 at frame 1, 5 at frame 3, rendered at 2", time=2.0)
def _():
    return scene(lights=sky() + sun().replace("float inputs:intensity = 2.0",
                                      "float inputs:intensity.timeSamples = {1: 1, 3: 5}"),
                 meta="    startTimeCode = 1\n    endTimeCode = 3")


@stage("animated_transform", "the block's translation sampled, rendered at frame 2", time=2.0)
def _():
    blk = block(extra='        double3 xformOp:translate.timeSamples = {1: (0, 0, 0), 3: (0.4, 0.2, 0.6)}\n'
                      '        uniform token[] xformOpOrder = ["xformOp:translate"]')
    return scene(objects=blk, meta="    startTimeCode = 1\n    endTimeCode = 3")


@stage("animated_camera", "the camera's focal length sampled 25 at frame 1, 60 at frame 3, rendered at 3", time=3.0)
def _():
    return scene(cam=camera().replace("float focalLength = 35.0", "float focalLength.timeSamples = {1: 25, 3: 60}"),
                 meta="    startTimeCode = 1\n    endTimeCode = 3")


@stage("animated_visibility", "a second block visible at frame 1, invisible from frame 2, rendered at 2", time=2.0)
def _():
    extra = box("Blink", (0.0, 0.0, 0.3), (0.5, 0.5, 0.8), display_color=(0.1, 0.8, 0.1),
                extra='        token visibility.timeSamples = {1: "inherited", 2: "invisible"}')
    return scene(objects=block() + extra, meta="    startTimeCode = 1\n    endTimeCode = 3")


# ---- render settings --------------------------------------------------------------------------

def _settings(settings_body, product_body=None, cam_rel="</World/Camera>"):
    product = ""
    products = ""
    if product_body is not None:
        products = "        rel products = </Render/Product>\n"
        product = f"""
    def RenderProduct "Product"
    {{
        rel camera = {cam_rel}
{product_body}
    }}
"""
    return f"""
def Scope "Render"
{{
    def RenderSettings "Settings"
    {{
        rel camera = {cam_rel}
        uniform int2 resolution = (48, 36)
{products}{settings_body}
    }}
{product}}}
"""


_SETTINGS_META = '    renderSettingsPrimPath = "/Render/Settings"'


def _window(ndc):
    return f"        uniform float4 dataWindowNDC = {ndc}"


@stage("render_settings_camera", "render settings (resolution 48 x 36, both given 24 x 18) naming a second camera; the "
       "command line is given no --camera",
       camera=None, hydra_camera="/World/Side")
def _():
    side = camera("Side", eye=(-1.8, 0.9, 1.2), target=(0, 0.2, 0))
    return scene(objects=block() + side, meta=_SETTINGS_META, after=_settings("", cam_rel="</World/Side>"))


@stage("render_settings_data_window", "a product's dataWindowNDC (0.25, 0.2, 0.75, 0.9)")
def _():
    return scene(meta=_SETTINGS_META, after=_settings("", _window("(0.25, 0.2, 0.75, 0.9)")))


@stage("render_settings_data_window_outside", "dataWindowNDC (-0.3, 0.5, 0.6, 1.4): partly outside (clipped)")
def _():
    return scene(meta=_SETTINGS_META, after=_settings("", _window("(-0.3, 0.5, 0.6, 1.4)")))


@stage("render_settings_data_window_empty", "dataWindowNDC (0.6, 0.2, 0.4, 0.8): empty")
def _():
    return scene(meta=_SETTINGS_META, after=_settings("", _window("(0.6, 0.2, 0.4, 0.8)")))


@stage("render_settings_data_window_no_product", "dataWindowNDC on a settings prim without products")
def _():
    return scene(meta=_SETTINGS_META, after=_settings(_window("(0.25, 0.25, 0.75, 0.75)")))


# ---- the granular schema ----------------------------------------------------------------------

@stage("granular_valid", "a valid aggregate of ~1000 box grains under a sun and a sky")
def _():
    return granular_scene()


@stage("granular_fallbacks", "an aggregate authoring only its prototypes (every other value falls back)")
def _():
    return granular_scene({"grainRadius": ("float", "0.03"), "packingRate": None, "seed": None,
                           "tileSpheres": None})


@stage("grain_radius_zero", "grainRadius 0 (invalid)")
def _():
    return granular_scene({"grainRadius": ("float", "0")})


@stage("grain_radius_negative", "grainRadius -0.02 (invalid)")
def _():
    return granular_scene({"grainRadius": ("float", "-0.02")})


@stage("grain_radius_double", "grainRadius authored as a double (accepted)")
def _():
    return granular_scene({"grainRadius": ("double", "0.02")})


@stage("grain_radius_string", 'grainRadius authored as a string "big" (wrong type)')
def _():
    return granular_scene({"grainRadius": ("string", '"big"')})


@stage("grain_radius_vertex", "grainRadius with vertex interpolation (must be constant)")
def _():
    text = granular_scene({"grainRadius": ("float[]", "[0.02, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02]")})
    return text.replace('float[] primvars:granular:grainRadius = [0.02, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02] (\n'
                        '            interpolation = "constant"',
                        'float[] primvars:granular:grainRadius = [0.02, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02, 0.02] (\n'
                        '            interpolation = "vertex"')


@stage("packing_rate_high", "packingRate 0.9 (above 0.64)")
def _():
    return granular_scene({"packingRate": ("float", "0.9")})


@stage("packing_rate_zero", "packingRate 0 (invalid)")
def _():
    return granular_scene({"packingRate": ("float", "0")})


@stage("prototypes_empty", "prototypes [] (at least one needed)")
def _():
    return granular_scene({"prototypes": ("string[]", "[]")})


@stage("prototypes_missing_prim", "a prototype path to no prim")
def _():
    return granular_scene({"prototypes": ("string[]", '["../Grains/Nothing"]')})


@stage("prototypes_not_a_path", 'a prototype "::bad::" that is not a prim path')
def _():
    return granular_scene({"prototypes": ("string[]", '["::bad::"]')})


@stage("prototypes_not_a_mesh", "a prototype naming the camera")
def _():
    return granular_scene({"prototypes": ("string[]", '["../Camera"]')})


@stage("weights_valid_two", "two prototypes weighted 0.7 / 0.3")
def _():
    return granular_scene({"prototypes": ("string[]", '["../Grains/A", "../Grains/B"]'),
                           "weights": ("float[]", "[0.7, 0.3]")}, names=("A", "B"))


@stage("weights_zero", "weights [0] (all zero)")
def _():
    return granular_scene({"weights": ("float[]", "[0]")})


@stage("weights_negative", "weights [-1, 2] for two prototypes")
def _():
    return granular_scene({"prototypes": ("string[]", '["../Grains/A", "../Grains/B"]'),
                           "weights": ("float[]", "[-1, 2]")}, names=("A", "B"))


@stage("weights_length_mismatch", "three weights for one prototype")
def _():
    return granular_scene({"weights": ("float[]", "[1, 2, 3]")})


@stage("seed_negative", "seed -1 (invalid)")
def _():
    return granular_scene({"seed": ("int", "-1")})


@stage("seed_large", "seed 2000000000 (valid)")
def _():
    return granular_scene({"seed": ("int", "2000000000")})


@stage("tile_spheres_few", "tileSpheres 4 (below 8)")
def _():
    return granular_scene({"tileSpheres": ("int", "4")})


@stage("tile_spheres_many", "tileSpheres 200000 (above 100000)")
def _():
    return granular_scene({"tileSpheres": ("int", "200000")})


@stage("sizes_valid", "two prototypes of sizes 1 and 1.6, spread 0.2")
def _():
    return granular_scene({"prototypes": ("string[]", '["../Grains/A", "../Grains/B"]'),
                           "sizes": ("float[]", "[1, 1.6]"), "sizeSpread": ("float", "0.2")}, names=("A", "B"))


@stage("sizes_out_of_range", "sizes [0.05] (below 0.1)")
def _():
    return granular_scene({"sizes": ("float[]", "[0.05]")})


@stage("sizes_length_mismatch", "two sizes for one prototype")
def _():
    return granular_scene({"sizes": ("float[]", "[1, 2]")})


@stage("size_spread_high", "sizeSpread 0.8 (above 0.5)")
def _():
    return granular_scene({"sizeSpread": ("float", "0.8")})


@stage("grain_ior_low", "grain ior 0.5 (below 1)")
def _():
    return granular_scene(grain_values={"A": {"ior": ("float", "0.5")}})


@stage("grain_absorption_negative", "grain absorption (-1, 0, 0)")
def _():
    return granular_scene(grain_values={"A": {"absorption": ("color3f", "(-1, 0, 0)")}})


@stage("grain_roughness_valid", "rough grains (roughness 0.5)")
def _():
    return granular_scene(grain_values={"A": {"roughness": ("float", "0.5")}})


@stage("grain_roughness_high", "grain roughness 1.5 (above 1)")
def _():
    return granular_scene(grain_values={"A": {"roughness": ("float", "1.5")}})


@stage("grain_no_api_material", "a prototype without GranularGrainAPI, of a glass UsdPreviewSurface")
def _():
    text = granular_scene(grain_values={"A": {k: None for k in GRAIN_DEFAULTS}})
    text = text.replace('prepend apiSchemas = ["GranularGrainAPI"]',
                        'prepend apiSchemas = ["MaterialBindingAPI"]')
    text = text.replace('token visibility = "invisible"',
                        'token visibility = "invisible"\n            rel material:binding = </World/Looks/M>')
    return text.replace('\n    def Scope "Grains"', looks(preview_material(
        "M", ["float inputs:opacity = 0", "float inputs:ior = 1.31"])) + '\n    def Scope "Grains"', 1)


@stage("boundary_open", "an aggregate boundary missing its top face (not closed)")
def _():
    return granular_scene(faces=[f for i, f in enumerate(_BOX_FACES) if i != 3])


@stage("boundary_nan_point", "an aggregate boundary with a NaN point")
def _():
    pts = box_points((0.0, 0.0, -0.2), (0.4, 0.3, 0.2))
    pts[7] = (float("nan"), 0.3, 0.2)
    return granular_scene(points=pts)


# ---- explicit grains (a PointInstancer of a simulation's grains) --------------------------------

_OCTA_FACES = [(0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4), (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)]


def _octahedron(r):
    return [(r, 0.0, 0.0), (-r, 0.0, 0.0), (0.0, r, 0.0), (0.0, -r, 0.0), (0.0, 0.0, r), (0.0, 0.0, -r)]


def grain_layout(nx=5, nz=5):
    """(positions, protoIndices, orientations, scales) of nx x nz grains on the ground beside
    the block, 0.3 apart (no two bounding spheres touch), each several pixels wide in the
    suite's image; prototypes alternate A, B."""
    pos, idx, rot, scl = [], [], [], []
    for i in range(nx * nz):
        x, z = i % nx, i // nx
        s = round(0.8 + 0.05 * (i % 5), 4)
        pos.append((round(-0.1 + 0.3 * x, 4), round(0.13 * s, 4), round(-0.5 + 0.3 * z, 4)))
        idx.append(i % 2)
        rot.append((0.92388, 0.0, 0.38268, 0.0) if i % 3 == 1 else (1.0, 0.0, 0.0, 0.0))
        scl.append((s, s, s))
    return pos, idx, rot, scl


def grain_instancer(api=True, grain_values=True, binding=None, edit=None, extra=""):
    """/World/Sim: a PointInstancer (with GranularInstancedAggregateAPI unless api is False) of
    grain_layout()'s 25 grains: prototype A an octahedron of radius 0.13, B a box of half-size
    0.085, both with GranularGrainAPI and its values (ior, absorption) unless grain_values is
    False, then bound to `binding` if given. `edit(positions, indices)` may change the arrays."""
    pos, idx, rot, scl = grain_layout()
    if edit:
        edit(pos, idx)
    protos = ""
    for name, pts, faces, absorption in (("A", _octahedron(0.13), _OCTA_FACES, "(2, 3, 5)"),
                                         ("B", box_points((-0.085,) * 3, (0.085,) * 3), _BOX_FACES, "(1, 1, 1)")):
        attrs = "\n".join([constant("float", "ior", "1.5"), constant("color3f", "absorption", absorption)]) \
            if grain_values else ""
        if binding:
            attrs += f"\n        rel material:binding = <{binding}>"
        protos += mesh(name, pts, faces, api=["GranularGrainAPI"] if grain_values else [],
                       material=None, extra=attrs).replace("\n    ", "\n            ")
    if binding:
        protos = protos.replace('def Mesh "A"', 'def Mesh "A" (\n                prepend apiSchemas = '
                                '["MaterialBindingAPI"]\n            )', 1)
        protos = protos.replace('def Mesh "B"', 'def Mesh "B" (\n                prepend apiSchemas = '
                                '["MaterialBindingAPI"]\n            )', 1)
    meta = ' (\n        prepend apiSchemas = ["GranularInstancedAggregateAPI"]\n    )' if api else ""
    quats = "[" + ", ".join(_v(q) for q in rot) + "]"
    return f"""
    def PointInstancer "Sim"{meta}
    {{
        rel prototypes = [</World/Sim/Protos/A>, </World/Sim/Protos/B>]
        int[] protoIndices = {list(idx)}
        point3f[] positions = {_arr(pos)}
        quath[] orientations = {quats}
        float3[] scales = {_arr(scl)}
{extra}
        def Scope "Protos"
        {{{protos}
        }}
    }}
"""


@stage("explicit_grains", "25 simulated grains of two prototypes: a PointInstancer with "
       "GranularInstancedAggregateAPI (explicit grains)")
def _():
    return scene(objects=block() + grain_instancer())


@stage("explicit_grains_no_api", "the same instancer without the API: every prototype has GranularGrainAPI "
       "(its primvars, which Hydra sees)")
def _():
    return scene(objects=block() + grain_instancer(api=False))


@stage("explicit_grains_bound_material", "the instancer with the API, its prototypes bound to a glass "
       "UsdPreviewSurface without GranularGrainAPI: explicit grains for granular render, instanced glass meshes "
       "for hdGranular (which does not see the API), the same image")
def _():
    return scene(objects=looks(preview_material("M", ["float inputs:opacity = 0", "float inputs:ior = 1.31"])) +
                 block() + grain_instancer(grain_values=False, binding="/World/Looks/M"))


@stage("explicit_grains_invisible_ids", "the instancer with invisibleIds hiding every other grain")
def _():
    return scene(objects=block() + grain_instancer(extra="        int64[] invisibleIds = [0, 2, 4, 6, 8, 10, 12, 14, "
                                                         "16, 18, 20, 22, 24]"))


@stage("explicit_grains_motion_blur", "the grains moving (velocities 4.8 along x, angularVelocities 720 deg/s "
       "about y) under a shutter open over (-0.5, 0.5) time codes at 24 per second")
def _():
    n = len(grain_layout()[0])
    motion = (f"        vector3f[] velocities = {_arr([(4.8, 0.0, 0.0)] * n)}\n"
              f"        vector3f[] angularVelocities = {_arr([(0.0, 720.0, 0.0)] * n)}")
    cam = camera(extra="        double shutter:open = -0.5\n        double shutter:close = 0.5")
    return scene(objects=block() + grain_instancer(extra=motion), cam=cam)


@stage("explicit_grains_xform_prototype", "the instancer with the API, its prototype B an Xform over the box "
       "Mesh (a grain prototype must be one Mesh)")
def _():
    text = scene(objects=block() + grain_instancer())
    start = text.index('            def Mesh "B"')
    end = text.index("\n        }\n    }\n", start)
    box_text = text[start:end].replace("\n", "\n    ").replace('def Mesh "B"', 'def Mesh "Box"', 1)
    return text[:start] + '            def Xform "B"\n            {\n    ' + box_text + "\n            }" + text[end:]


@stage("explicit_grains_nan_position", "an explicit grain at a NaN position")
def _():
    def edit(pos, idx):
        pos[3] = (float("nan"), 0.1, 0.2)
    return scene(objects=block() + grain_instancer(edit=edit))


@stage("explicit_grains_proto_index", "an explicit grain's protoIndices entry 2 of two prototypes")
def _():
    def edit(pos, idx):
        idx[4] = 2
    return scene(objects=block() + grain_instancer(edit=edit))


@stage("explicit_grains_overlap", "two explicit grains 0.05 apart (their bounding spheres interpenetrate)")
def _():
    def edit(pos, idx):
        pos[6] = (pos[5][0] + 0.05, pos[5][1], pos[5][2])
    return scene(objects=block() + grain_instancer(edit=edit))


def write_all(folder):
    """Writes every stage as folder/<name>.usda (textures in folder/textures); returns STAGES."""
    os.makedirs(folder, exist_ok=True)
    write_textures(os.path.join(folder, "textures"))
    for s in STAGES:
        s.path = os.path.join(folder, s.name + ".usda")
        with open(s.path, "w") as f:
            text = s.build()
            f.write(text)
        # Grains make paths chaotic (compare.py then compares within noise): aggregates and
        # explicit grains alike.
        s.grains = "GranularAggregateAPI" in text or "GranularInstancedAggregateAPI" in text or \
            "GranularGrainAPI" in text
    return STAGES


if __name__ == "__main__":
    import sys
    out = sys.argv[1] if len(sys.argv) > 1 else "out/conformance/stages"
    for s in write_all(out):
        print(f"{s.name}: {s.description}")
    print(f"{len(STAGES)} stages in {out}")
