#!/usr/bin/env python3
"""Light linking: what it gives and what it costs.

1. A grey floor (albedo 0.5) seen from above under a white dome and a key sphere light
   beside the view, with a second sphere light (a rim) and a 20° sun of irradiance 3 linked
   away from it (`"light_link": {"exclude": ["floor"]}`), against the floor with the rim
   there but black and no sun (a light's body still hides the sky behind it).
   `granular-render`, EPT: the linked floor must read the reference and, as it samples only
   the lights that reach it, be as quiet (relative s.e. per sample: the noise of one sample).
2. The sand castle example (`granular render`, the hybrid) with its sun's lightLink made
   non-trivial but holding every prim (includeRoot off, includes </World>): the same image
   as unlinked, so the difference in time is what the linking lookups cost.

Prints two markdown tables.

Usage: .venv/bin/python bench/light_linking.py [--spp 256] [--castle-spp 16] [--build build]
       [--out out/bench/light_linking]
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def floor_scene(spp, linked, reference):
    """The floor under the dome and a key bulb, with a rim bulb and the sun linked away from it
    (linked), or the rim black and no sun (reference), or all four lighting it."""
    lights = [{"name": "dome", "type": "dome"},
              {"name": "key", "type": "sphere", "position": [1.5, 1.0, 0.2], "radius": 0.3, "intensity": 20},
              {"name": "rim", "type": "sphere", "position": [-1.5, 1.0, -0.2], "radius": 0.3,
               "intensity": 0 if reference else 20},
              {"name": "sun", "type": "distant", "direction": [-0.3, -1.0, -0.4], "angle": 20,
               "intensity": 3, "normalize": True}]
    if reference:
        lights = lights[:3]
    if linked:
        for light in lights[2:]:
            light["light_link"] = {"exclude": ["floor"]}
    return {
        "render": {"width": 16, "height": 16, "spp": spp, "seed": 5, "technique": "ept"},
        "camera": {"look_at": {"eye": [0, 4, 0.01], "target": [0, 0, 0], "up": [0, 1, 0]},
                   "focal_length": 50, "horizontal_aperture": 20, "vertical_aperture": 20},
        "materials": {"grey": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}},
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-3, -0.1, -3], "hi": [3, 0, 3]}}, "material": "grey"}],
        "lights": lights,
    }


def read(core, exr):
    img = core.read_exr(exr)
    px = np.asarray(img.pixels)
    ch = list(img.channels)
    return px, ch


def floor_table(a, core):
    print("| floor | mean | bias % ± s.e. | s.e. per sample | render s |")
    print("|---|---|---|---|---|")
    rows = {}
    for name, linked, reference in (("dome and key, rim black (reference)", False, True),
                                    ("rim and sun linked away", True, False),
                                    ("all four lights", False, False)):
        path = os.path.join(a.out, f"floor_{len(rows)}.json")
        with open(path, "w") as f:
            json.dump(floor_scene(a.spp, linked, reference), f)
        exr, stats = path[:-5] + ".exr", path[:-5] + ".stats.json"
        subprocess.run([os.path.join(a.build, "core", "granular-render"), path, "-o", exr, "--quiet",
                        "--stats-json", stats], check=True)
        px, ch = read(core, exr)
        mean = px[..., ch.index("R")].mean()
        se = np.sqrt(px[..., ch.index("variance.R")].sum()) / px[..., 0].size
        with open(stats) as f:
            t = json.load(f)["render_s"]
        rows[name] = (mean, se)
        ref_mean, ref_se = rows["dome and key, rim black (reference)"]
        bias = f"{100 * (mean / ref_mean - 1):+.2f} ± {100 * np.hypot(se, ref_se) / ref_mean:.2f}"
        per_sample = se * np.sqrt(a.spp * px[..., 0].size) / mean
        print(f"| {name} | {mean:.4f} | {bias} | {per_sample:.3f} | {t:.2f} |", flush=True)


def castle_table(a, core):
    example = os.path.join(ROOT, "examples", "sandcastle.usda")
    layer = os.path.join(a.out, "sandcastle_linked.usda")
    with open(layer, "w") as f:
        f.write(f"""#usda 1.0
(
    subLayers = [@{example}@]
)
over "World"
{{
    over "Sun"
    {{
        uniform bool collection:lightLink:includeRoot = 0
        rel collection:lightLink:includes = </World>
    }}
}}
""")
    granular = os.path.join(os.path.dirname(sys.executable), "granular")
    print()
    print(f"| sand castle, {a.castle_spp} spp, 160 x 120 | render s (best of 3) | same image |")
    print("|---|---|---|")
    images = {}
    for name, stage in (("unlinked", example), ("sun linked to every prim", layer)):
        best = None
        for run in range(3):
            exr = os.path.join(a.out, f"castle_{len(images)}.exr")
            t0 = time.time()
            out = subprocess.run([granular, "render", stage, "-o", exr, "--spp", str(a.castle_spp), "--width", "160",
                                  "--height", "120"], check=True, capture_output=True, text=True).stderr
            line = [x for x in out.splitlines() if x.startswith("wrote ")][-1]
            t = float(line.split("(render ")[1].split(" s")[0])
            best = t if best is None else min(best, t)
        images[name] = read(core, exr)[0][..., :3]
        same = "—" if len(images) == 1 else str(bool(np.array_equal(images["unlinked"], images[name])))
        print(f"| {name} | {best:.2f} | {same} |", flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--castle-spp", type=int, default=16)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "light_linking"))
    a = ap.parse_args()
    sys.path[:0] = [os.path.join(a.build, "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    os.makedirs(a.out, exist_ok=True)
    floor_table(a, core)
    castle_table(a, core)


if __name__ == "__main__":
    main()
