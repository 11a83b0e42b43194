"""Grain materials from measured optical data: quartz sand, ice (snow) and sucrose (sugar).

The schema's `absorption` is a coefficient per grain radius (GranularGrainAPI): the bulk
absorption coefficient sigma_a [1/m] times grainRadius [m], one value per linear-RGB
channel. A channel stands for the dominant wavelength of its Rec. 709 primary: red 611 nm,
green 549 nm, blue 465 nm (CHANNEL_NM). Each material says where its numbers come from, and
states the albedo a thick layer of it must have under a white sky (`target`, per channel);
`slab_albedo` renders that layer, tests/python/test_materials.py checks it against the
target, and bench/slab_albedo.py prints the table (examples/README.md, "Materials").

A layer's colour is set by sigma_a times the grain size (its albedo depends on the product
only), so a material measured as a bulk coefficient gives a different per-radius value at
every grain size (`absorption_per_radius`), and one fitted to a measured reflectance
(sand) keeps its per-radius value at every size.
"""
from dataclasses import dataclass

CHANNEL_NM = (611.0, 549.0, 465.0)


@dataclass(frozen=True)
class Prototype:
    name: str
    shape: dict  # a scene-JSON shape ({"rock": {...}}, {"ellipsoid": {...}}, {"box": {...}})
    weight: float
    dark: bool = False  # the material's darker minority grains (sand's heavy minerals)

    def mesh(self):
        """The shape as a core.TriangleMesh (what the examples author as the prototype)."""
        import granular_core as core
        (kind, p), = self.shape.items()
        if kind == "rock":
            return core.make_rock(p["subdivisions"], p["roughness"], p["seed"])
        if kind == "ellipsoid":
            return core.make_ellipsoid(tuple(p["radii"]), p["subdivisions"])
        if kind == "box":
            return core.make_box(tuple(p["lo"]), tuple(p["hi"]))
        raise ValueError(f"{self.name}: no mesh for shape {kind!r}")


@dataclass(frozen=True)
class Material:
    name: str
    ior: float
    packing_rate: float
    grain_radius_m: float  # the grain size the examples use (and slab_albedo's default)
    prototypes: tuple
    source: str
    # Either a bulk coefficient measured in 1/m at CHANNEL_NM...
    sigma_a_per_m: tuple = None
    # ...or per grain radius (a fit to a measured reflectance, independent of size).
    per_radius: tuple = None
    dark_per_radius: tuple = None
    # The white-sky albedo of a thick layer: (low, high) per channel.
    target: tuple = ()
    target_source: str = ""

    def absorption_per_radius(self, grain_radius_m):
        """The schema's absorption for grains of this radius (in metres)."""
        if self.per_radius is not None:
            return tuple(self.per_radius)
        if not grain_radius_m > 0:
            raise ValueError(f"{self.name}: grain radius must be > 0 m, got {grain_radius_m}")
        return tuple(s * grain_radius_m for s in self.sigma_a_per_m)

    def grain_absorptions(self, grain_radius_m=None, per_radius=None, dark_per_radius=None):
        """(light, dark): the absorption per grain radius of the material's grains and of
        its darker minority (the prototypes marked dark). light is per_radius, else the
        material's at grain_radius_m (default: the examples' size); dark is dark_per_radius,
        else the material's darker grains', else light."""
        if per_radius is not None:
            light = tuple(per_radius)
        else:
            light = self.absorption_per_radius(self.grain_radius_m if grain_radius_m is None else grain_radius_m)
        dark = dark_per_radius if dark_per_radius is not None else (self.dark_per_radius or light)
        return light, tuple(dark)


QUARTZ_SAND = Material(
    name="quartz_sand",
    ior=1.55,  # quartz: ordinary 1.544, extraordinary 1.553 at 589 nm
    packing_rate=0.6,
    grain_radius_m=0.00025,  # fine beach sand
    prototypes=(Prototype("round", {"rock": {"subdivisions": 2, "roughness": 0.2, "seed": 1}}, 0.6),
                Prototype("flat", {"ellipsoid": {"radii": [1.0, 0.55, 0.8], "subdivisions": 2}}, 0.3),
                Prototype("dark", {"rock": {"subdivisions": 2, "roughness": 0.3, "seed": 5}}, 0.1, dark=True)),
    # Fitted (bench/slab_albedo.py --fit) so that the layer meets the target below; the
    # dark tenth stands for the heavy minerals of beach sand (magnetite, ilmenite).
    per_radius=(0.0013, 0.0067, 0.023),
    dark_per_radius=(0.4, 0.6, 1.1),
    target=((0.37, 0.43), (0.30, 0.36), (0.21, 0.27)),
    source="quartz (IOR 1.55) whose colour comes from iron-oxide coatings and a tenth of dark heavy-mineral "
           "grains; absorption fitted to the target reflectance",
    target_source="dry, light quartz beach sand: visible reflectance rising from about 0.24 at 465 nm through "
                  "0.33 at 549 nm to 0.40 at 611 nm (the iron-oxide edge below 550 nm, Clark 1999, USGS "
                  "'Spectroscopy of rocks and minerals'; dry sand's solar albedo 0.35-0.45, Oke 1987, "
                  "'Boundary Layer Climates', table 1.1), our reading of those, +-0.03",
)

ICE = Material(
    name="ice",
    ior=1.31,  # ice Ih at 550 nm (Warren & Brandt 2008)
    packing_rate=0.45,  # snow of density 0.41 g/cm^3 (ice 0.917)
    grain_radius_m=0.0004,  # aged snow (fresh snow's grains are finer)
    prototypes=(Prototype("flake", {"ellipsoid": {"radii": [1.0, 0.35, 0.9], "subdivisions": 2}}, 0.5),
                Prototype("pellet", {"rock": {"subdivisions": 2, "roughness": 0.25, "seed": 11}}, 0.5)),
    # Bulk absorption of pure ice: above 600 nm Warren & Brandt (2008, JGR 113, D14220; with
    # Grenfell & Perovich 1981); at 400-600 nm Picard et al. (2016, The Cryosphere 10),
    # about ten times Warren & Brandt's there, which they argue is the likelier value.
    sigma_a_per_m=(0.13, 0.05, 0.02),
    target=((0.955, 0.99), (0.965, 0.995), (0.97, 1.0)),
    source="ice Ih, IOR 1.31; absorption 0.13, 0.05, 0.02 /m at 611, 549, 465 nm (Warren & Brandt 2008; "
           "Picard et al. 2016 below 600 nm)",
    target_source="deep clean snow reflects 0.96-0.99 of visible light, least in the red (measured at the South "
                  "Pole, Grenfell, Warren & Mullen 1994, JGR 99; modelled, Warren & Wiscombe 1980), +-0.005 for "
                  "the red's lower and the blue's upper end",
)

SUCROSE = Material(
    name="sucrose",
    ior=1.56,  # sucrose crystal's principal indices 1.540, 1.567, 1.572 (mean 1.56)
    packing_rate=0.55,
    grain_radius_m=0.00025,  # granulated sugar
    prototypes=(Prototype("crystal", {"box": {"lo": [-1.0, -0.7, -0.55], "hi": [1.0, 0.7, 0.55]}}, 0.7),
                Prototype("chip", {"box": {"lo": [-0.8, -0.8, -0.4], "hi": [0.8, 0.8, 0.4]}}, 0.3)),
    # Clear crystals: pure sucrose does not absorb in the visible; the colour of refined
    # sugar (ICUMSA units) is that of the syrup film left on the crystals, not of the crystal.
    sigma_a_per_m=(0.0, 0.0, 0.0),
    target=((0.985, 1.0), (0.985, 1.0), (0.985, 1.0)),
    source="sucrose crystals, IOR 1.56 (mean of the principal indices 1.540, 1.567, 1.572), clear",
    target_source="a layer of clear grains loses nothing: it reflects all light but what leaves through the "
                  "slab's bottom and sides (under 1.5% for this slab, 4000 grain radii deep)",
)

MATERIALS = {m.name: m for m in (QUARTZ_SAND, ICE, SUCROSE)}


def slab_scene(material, grain_radius_m=None, spp=64, seed=1, per_radius=None, dark_per_radius=None):
    """The scene (core's JSON description, a dict) of a thick layer under a white dome of
    radiance 1, seen from straight above: the mean radiance over the image is the layer's
    white-sky albedo. The slab is 4000 grain radii deep and ten times wider than the view,
    so that what leaks through its bottom and sides is a fraction of a percent. Lengths are
    in grain radii (the albedo does not depend on the scale), the absorption is the
    material's at grain_radius_m (default: the examples' size) unless per_radius (and
    dark_per_radius) are given."""
    r = 0.001
    absorption, dark = material.grain_absorptions(grain_radius_m, per_radius, dark_per_radius)
    mats = {"grain": {"type": "dielectric", "ior": material.ior, "absorption": list(absorption)},
            "dark": {"type": "dielectric", "ior": material.ior, "absorption": list(dark)}}
    protos = [{"name": p.name, "shape": p.shape, "material": "dark" if p.dark else "grain"} for p in material.prototypes]
    return {"render": {"width": 24, "height": 24, "spp": spp, "seed": seed, "technique": "hybrid"},
            "camera": {"look_at": {"eye": [0, 30, 0], "target": [0, 0, 0], "up": [0, 0, -1]},
                       "focal_length": 50, "horizontal_aperture": 2, "vertical_aperture": 2,
                       "clipping_range": [0.01, 100]},
            "materials": mats,
            "lights": [{"name": "sky", "type": "dome", "color": [1, 1, 1], "intensity": 1.0}],
            "aggregates": [{"name": "slab", "boundary": {"box": {"lo": [-6, -4000 * r, -6], "hi": [6, 0, 6]}},
                            "grain_radius": r, "packing_rate": material.packing_rate, "seed": 3,
                            "tile_spheres": 512, "prototypes": protos,
                            "weights": [p.weight for p in material.prototypes]}]}


def slab_albedo(material, grain_radius_m=None, spp=64, seed=1, **absorption):
    """Renders slab_scene; returns (albedo, standard error), each per channel. The pixels
    are independent estimates, so the standard error is their spread over sqrt(pixels)."""
    import json
    import os
    import tempfile

    import numpy as np

    import granular_core as core
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "slab.json")
        with open(path, "w") as f:
            json.dump(slab_scene(material, grain_radius_m, spp, seed, **absorption), f)
        desc = core.load_scene_json(path)
    renderer = core.Renderer(core.Scene.build(desc))
    renderer.render(spp)
    px = np.asarray(renderer.image().pixels, dtype=np.float64)[..., :3].reshape(-1, 3)
    return px.mean(0), px.std(0, ddof=1) / np.sqrt(len(px))
