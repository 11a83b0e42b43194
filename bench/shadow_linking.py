#!/usr/bin/env python3
"""Shadow linking: that it is right, and what carrying a light's direct light by light
sampling alone costs.

A light whose shadow link leaves objects out, or whose shadows are off, has shadow rays
that pass those objects while every other ray still meets them; a direction sampled by
scattering whose way to the light crosses such an object's bounds has the light beyond it
counted where it was sampled, by one more shadow ray (core/ept.h, addDirectPastNonCasters),
so that MIS stays whole. Scenes (`granular-render`, JSON):

1. A grey floor seen from above under a white dome, a key sphere light and a 20° sun of
   irradiance 3, with a black slab out of view above it that shades half the floor from the
   sun and hides some of the dome (EPT). The slab left out of every light's shadow link, or
   every light's shadows off, must read the floor without the slab; the slab alone in the
   links (the floor left out) must read the slab without links.
2. The bright sand castle and the snow field of `hybrid_speedup.py` (96 x 72, the hybrid)
   under their sun and sky:
   - every light shadow-linked with only a speck far away left out, which changes nothing
     but the work (the bounds test at every sampled direction and emitter met, Embree's
     context filter on every surface shadow ray): the same image, and the cost;
   - a black umbrella out of view between the aggregate and the sun, left out of every
     light's shadow link: the image without it, and what the shadow rays past it cost;
     with it in the links (no links), its shadow;
   - the aggregate left out of the sun's link (no shadow from it on the ground; its
     shadows within itself stay), what a user gets;
   - the castle with explicit grains alone (EPT, every bounce a smooth one), with and
     without the umbrella left out: what the shadow rays cost after smooth bounces.

Per row: the image's mean, the difference to its reference (± their combined standard
error), the relative noise per sample (root mean square over pixels of the per-sample
standard deviation, over the image's mean), the render time (best of --repeat runs of the
same seed), and against the reference the speed at equal error, (noise² × time) of the
reference over the row's.

Usage: .venv/bin/python bench/shadow_linking.py [--spp 64] [--repeat 3] [--build build]
       [--out out/bench/shadow_linking]
"""
import argparse
import copy
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import hybrid_speedup  # noqa: E402  (its scenes)
from dome_sampling import measure, render  # noqa: E402

SPECK = {"name": "speck", "shape": {"box": {"lo": [50, 50, 50], "hi": [50.01, 50.01, 50.01]}}}


def floor_scene(slab=True):
    scene = {
        "render": {"width": 48, "height": 48, "spp": 4, "seed": 5, "technique": "ept"},
        "camera": {"look_at": {"eye": [0, 4, 0.01], "target": [0, 0, 0], "up": [0, 1, 0]},
                   "focal_length": 50, "horizontal_aperture": 20, "vertical_aperture": 20},
        "materials": {"grey": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]},
                      "black": {"type": "lambert", "albedo": [0, 0, 0]}},
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-3, -0.1, -3], "hi": [3, 0, 3]}}, "material": "grey"}],
        "lights": [{"name": "dome", "type": "dome"},
                   {"name": "key", "type": "sphere", "position": [1.5, 1.0, 0.2], "radius": 0.3, "intensity": 20},
                   {"name": "sun", "type": "distant", "direction": [-0.3, -1.0, -0.4], "angle": 20,
                    "intensity": 3, "normalize": True}],
    }
    if slab:
        scene["meshes"].append({"name": "slab", "shape": {"box": {"lo": [0.5, 2.5, 0.5], "hi": [3, 2.6, 3]}},
                                "material": "black"})
    return scene


def linked(scene, **link):
    s = copy.deepcopy(scene)
    for light in s["lights"]:
        light.update(copy.deepcopy(link))
    return s


def cases():
    """(table, name, scene, technique, reference row's name or None; "~name": a reference the
    row is meant to differ from, its change shown alone)."""
    out = [("floor", "no slab (reference)", floor_scene(False), "ept", None),
           ("floor", "slab left out of every shadow link", linked(floor_scene(), shadow_link={"exclude": ["slab"]}),
            "ept", "no slab (reference)"),
           ("floor", "every light's shadows off", linked(floor_scene(), shadows=False), "ept", "no slab (reference)"),
           ("floor", "slab, no links (reference)", floor_scene(), "ept", None),
           ("floor", "slab alone in every shadow link", linked(floor_scene(), shadow_link={"include": ["slab"]}),
            "ept", "slab, no links (reference)")]
    agg = hybrid_speedup.scenes()
    # Toward the sun (from (0.45, 0.8, 0.35)), out of each camera's view.
    umbrellas = {"bright sand": ([1.8, 3.2, 1.4], 0.8), "snow field": ([2.7, 4.8, 2.1], 1.2)}
    for name, key in (("bright sand castle", "bright sand"), ("snow field", "snow field")):
        plain = copy.deepcopy(agg[key])
        plain["meshes"] = plain.get("meshes", []) + [SPECK]
        ref = f"{name} (reference)"
        out.append((name, ref, plain, "hybrid", None))
        out.append((name, f"{name}, every light shadow-linked (the speck left out)",
                    linked(plain, shadow_link={"exclude": ["speck"]}), "hybrid", ref))
        shaded = copy.deepcopy(plain)
        shaded["materials"]["black"] = {"type": "lambert", "albedo": [0, 0, 0]}
        centre, radius = umbrellas[key]
        shaded["meshes"].append({"name": "umbrella", "material": "black",
                                 "shape": {"ellipsoid": {"radii": [radius, radius, radius], "subdivisions": 3}},
                                 "transform": {"translate": centre}})
        out.append((name, f"{name}, a black umbrella left out of every shadow link",
                    linked(shaded, shadow_link={"exclude": ["umbrella", "speck"]}), "hybrid", ref))
        out.append((name, f"{name}, the umbrella casting its shadow", shaded, "hybrid", "~" + ref))
        unshaded = copy.deepcopy(plain)
        for light in unshaded["lights"]:
            if light["type"] == "distant":
                light["shadow_link"] = {"exclude": [plain["aggregates"][0]["name"], "speck"]}
        out.append((name, f"{name}, the aggregate left out of the sun's link", unshaded, "hybrid", "~" + ref))
        if key == "bright sand":  # explicit grains alone: every bounce a smooth one
            eref = f"{name}, EPT (reference)"
            out.append((name, eref, plain, "ept", None))
            out.append((name, f"{name}, EPT, the umbrella left out of every shadow link",
                        linked(shaded, shadow_link={"exclude": ["umbrella", "speck"]}), "ept", eref))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--repeat", type=int, default=3, help="renders per row; the best time is shown")
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "shadow_linking"))
    a = ap.parse_args()
    sys.path[:0] = [os.path.join(a.build, "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    os.makedirs(a.out, exist_ok=True)
    print("| scene | mean ± s.e. | − reference, % ± s.e. | noise per sample | render s | speed at equal error |")
    print("|---|---|---|---|---|---|")
    got = {}
    for i, (table, name, scene, technique, ref) in enumerate(cases()):
        path = os.path.join(a.out, f"case{i}")
        t = min(render(a.build, scene, technique, a.spp, path) for _ in range(a.repeat))
        m, se, ns = measure(core, path + ".exr", a.spp)
        got[name] = (m, se, ns, t)
        diff = speed = "—"
        if ref:
            rm, rse, rns, rt = got[ref.lstrip("~")]
            diff = f"{100 * (m / rm - 1):+.2f} ± {100 * np.hypot(se, rse) / rm:.2f}"
            if not ref.startswith("~"):
                speed = f"{(rns * rns * rt) / (ns * ns * t):.2f}×"
        print(f"| {name} | {m:.4f} ± {se:.4f} | {diff} | {ns:.3f} | {t:.2f} | {speed} |", flush=True)


if __name__ == "__main__":
    main()
