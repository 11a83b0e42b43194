#!/usr/bin/env python3
"""The colour a grain material gives a thick layer: a slab of grains (4 × 1 × 4 units,
grains of radius 0.002, 500 grains deep) under a white dome of radiance 1, seen from
straight above; the mean radiance over the slab is its albedo. Grains as the sand castle's
prototypes (round rocks and flat ellipsoids, 60 : 30, plus optionally 10% darker rocks), IOR
1.55, packing rate 0.6; the hybrid renders it (its medium agrees with explicit grains within
0.5%, bench/README.md).

Usage: .venv/bin/python bench/slab_albedo.py [--spp 64] ABSORPTION[,DARK_ABSORPTION] ...
where ABSORPTION is r,g,b per grain radius and DARK_ABSORPTION r,g,b of the darker tenth,
e.g. 0.004,0.009,0.028,0.4,0.6,1.1. Prints a markdown table.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "build", "python"))
import granular_core as core  # noqa: E402


def slab_scene(absorption, dark, spp):
    protos = [{"name": "round", "shape": {"rock": {"subdivisions": 2, "roughness": 0.2, "seed": 1}}, "material": "sand"},
              {"name": "flat", "shape": {"ellipsoid": {"radii": [1.0, 0.55, 0.8], "subdivisions": 2}},
               "material": "sand"}]
    weights = [0.6, 0.3]
    mats = {"sand": {"type": "dielectric", "ior": 1.55, "absorption": absorption}}
    if dark is not None:
        protos.append({"name": "dark", "shape": {"rock": {"subdivisions": 2, "roughness": 0.3, "seed": 5}},
                       "material": "dark"})
        mats["dark"] = {"type": "dielectric", "ior": 1.55, "absorption": dark}
        weights.append(0.1)
    return {"render": {"width": 24, "height": 24, "spp": spp, "seed": 1, "technique": "hybrid"},
            "camera": {"look_at": {"eye": [0, 30, 0], "target": [0, 0, 0], "up": [0, 0, -1]},
                       "focal_length": 50, "horizontal_aperture": 2, "vertical_aperture": 2,
                       "clipping_range": [0.01, 100]},
            "materials": mats,
            "lights": [{"name": "sky", "type": "dome", "color": [1, 1, 1], "intensity": 1.0}],
            "aggregates": [{"name": "slab", "boundary": {"box": {"lo": [-2, -1, -2], "hi": [2, 0, 2]}},
                            "grain_radius": 0.002, "packing_rate": 0.6, "seed": 3, "tile_spheres": 512,
                            "prototypes": protos, "weights": weights}]}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("materials", nargs="+")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--render", default=os.path.join(ROOT, "build", "core", "granular-render"))
    args = ap.parse_args()
    print("| absorption (per grain radius) | darker tenth | slab albedo (R G B) |")
    print("|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for m in args.materials:
            v = [float(x) for x in m.split(",")]
            absorption, dark = v[:3], (v[3:6] if len(v) > 3 else None)
            path, out = os.path.join(tmp, "slab.json"), os.path.join(tmp, "slab.exr")
            with open(path, "w") as f:
                json.dump(slab_scene(absorption, dark, args.spp), f)
            subprocess.run([args.render, path, "-o", out, "--quiet"], check=True)
            albedo = np.asarray(core.read_exr(out).pixels)[..., :3].reshape(-1, 3).mean(0)
            print(f"| {', '.join(f'{x:g}' for x in absorption)} | {', '.join(f'{x:g}' for x in dark) if dark else '—'} | "
                  f"{' '.join(f'{x:.3f}' for x in albedo)} |")


if __name__ == "__main__":
    main()
