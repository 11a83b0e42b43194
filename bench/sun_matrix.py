#!/usr/bin/env python3
"""Sun matrix: explicit grains (EPT, the reference) against proxies (`proxies` on), the
medium after the explicit bounces (`proxies` off) and the medium right after the first
grain (off, no explicit bounces), under a normalised sun, over sun elevations and sun–view
phase angles.

The scenes: a ball (radius 1) or a slab (4 × 4 × 1) of grains 100 across the ball (radius
0.01), of the measured materials (python/granular/materials.py: quartz sand, ice,
sucrose) and a glass mixture (quartz sand with clear glass beads, 60 / 40), over a grey
floor, lit by a sun of the given angle (normalised: the same irradiance at any size) and
a dim sky (radiance 0.1). The camera looks at the object from elevation 30°; the sun's
azimuth is chosen so that the angle between the directions to the sun and to the camera
is the phase angle (combinations no azimuth gives are skipped). The mean over the
object's pixels, per seed; bias = (technique − EPT) / EPT with a standard error from the
seeds and the renders' variance AOV (accuracy_matrix.stats()). One slab is one draw of its
grains (packing, prototypes, rotations): explicit grains show all of it, proxies average
over the rotations, and the seeds' standard error does not count it (bench/README.md, "The
proxies' own error on the sunlit sucrose slab"). --realisations N renders N draws
(aggregate seeds 3, 4, ...) and reports the mean of each draw's bias against EPT of the
same draw, its standard error from their spread. The medium-only column
against the phase angle tells the shadow hiding (a deficit that grows towards phase 0)
from a free-path error (flat).

Usage: python3 bench/sun_matrix.py [--build build] [--materials quartz_sand,ice,sucrose,glass_mixture]
         [--shapes ball,slab] [--suns 20,5] [--elevations 15,45,80] [--phases 0,30,60,90,120,150]
         [--spp 64] [--seeds 2] [--realisations 1] [--width 32] [--height 24]
         [--techniques proxies,medium,medium-only]
         [--set KEY=VALUE ...] [--json out/bench/sun_matrix.json]
         [--plot out/bench/sun_matrix.png]
Prints a markdown table; --plot draws the medium-only and proxy biases against phase angle.
`default` is the hybrid as a user gets it, `view` the same with switch_for_view (the switch
measured for the camera and the sun too); `visits-K` (e.g. visits-16) proxies for K visits
after the first grain, nothing measured: how the bias falls with the switch to the medium.
--set applies a render setting to every technique but EPT: `--set lod=0` keeps the first
grain explicit where the level-of-detail shortcut would make it a proxy.
"""
import argparse
import json
import math
import os
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import accuracy_matrix  # noqa: E402  (its measure(): the object's mean per seed; save_figure)

# name -> (technique, proxies, explicit_bounces or None for the automatic count); `default`
# is the hybrid as a user gets it (proxies Auto).
TECHNIQUES = {"default": ("EptVpt", "Auto", None), "proxies": ("EptVpt", "On", None),
              "medium": ("EptVpt", "Off", None), "medium-only": ("EptVpt", "Off", 0),
              "view": ("EptVpt", "Auto", None)}
VIEW_ELEVATION = 30.0


def material_block(name):
    from granular import materials as gm
    if name == "glass_mixture":
        quartz = gm.MATERIALS["quartz_sand"]
        light, _ = quartz.grain_absorptions()
        mats = {"grain": {"type": "dielectric", "ior": quartz.ior, "absorption": list(light)},
                "glass": {"type": "dielectric", "ior": 1.5, "absorption": [0.0, 0.0, 0.0]}}
        protos = [{"name": "sand", "shape": quartz.prototypes[0].shape, "material": "grain"},
                  {"name": "bead", "shape": {"ellipsoid": {"radii": [1.0, 0.9, 0.95], "subdivisions": 2}},
                   "material": "glass"}]
        return mats, protos, [0.6, 0.4], quartz.packing_rate
    m = gm.MATERIALS[name]
    light, dark = m.grain_absorptions()
    mats = {"grain": {"type": "dielectric", "ior": m.ior, "absorption": list(light)},
            "dark": {"type": "dielectric", "ior": m.ior, "absorption": list(dark)}}
    protos = [{"name": p.name, "shape": p.shape, "material": "dark" if p.dark else "grain"} for p in m.prototypes]
    return mats, protos, [p.weight for p in m.prototypes], m.packing_rate


def sun_azimuth(elevation, phase):
    """The sun's azimuth (degrees, from the camera's) for this phase angle, or None."""
    e_s, e_v, p = (math.radians(x) for x in (elevation, VIEW_ELEVATION, phase))
    c = (math.cos(p) - math.sin(e_s) * math.sin(e_v)) / (math.cos(e_s) * math.cos(e_v))
    if abs(c) > 1.0:
        return None
    return math.degrees(math.acos(c))


def unit(elevation, azimuth):
    e, a = math.radians(elevation), math.radians(azimuth)
    return [math.cos(e) * math.sin(a), math.sin(e), math.cos(e) * math.cos(a)]


def scene(material, shape, sun_angle, elevation, azimuth, aggregate_seed=3):
    mats, protos, weights, f = material_block(material)
    mats["floor"] = {"type": "lambert", "albedo": [0.5, 0.5, 0.5]}
    to_cam = unit(VIEW_ELEVATION, 0.0)
    to_sun = unit(elevation, azimuth)
    if shape == "ball":
        boundary, target, distance = {"icosphere": {"subdivisions": 3, "radius": 1.0}}, [0, 0, 0], 3.2
        floor_y = -1.0
    else:
        boundary, target, distance = {"box": {"lo": [-2, -1, -2], "hi": [2, 0, 2]}}, [0, -0.2, 0], 3.0
        floor_y = -1.0
    eye = [target[i] + distance * to_cam[i] for i in range(3)]
    return {
        # The sun as authored in every render (no regularisation): a technique's bias is the medium's.
        "render": {"width": 32, "height": 24, "spp": 16, "seed": 1, "technique": "ept", "sun_regularization": 0},
        "camera": {"look_at": {"eye": eye, "target": target, "up": [0, 1, 0]}, "focal_length": 35,
                   "horizontal_aperture": 36, "vertical_aperture": 27, "clipping_range": [0.01, 100]},
        "materials": mats,
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-8, floor_y - 0.3, -8], "hi": [8, floor_y, 8]}},
                    "material": "floor"}],
        "lights": [{"name": "sky", "type": "dome", "color": [1, 1, 1], "intensity": 0.1},
                   {"name": "sun", "type": "distant", "direction": [-x for x in to_sun], "angle": sun_angle,
                    "intensity": 1.0, "normalize": True}],
        "aggregates": [{"name": shape, "boundary": boundary, "grain_radius": 0.01, "packing_rate": f, "seed": aggregate_seed,
                        "tile_spheres": 512, "prototypes": protos, "weights": weights}],
    }


def run_case(core, material, shape, sun, elevation, phase, args, tmp):
    import numpy as np
    azimuth = sun_azimuth(elevation, phase)
    if azimuth is None:
        return None
    out = {"material": material, "shape": shape, "sun": sun, "elevation": elevation, "phase": phase,
           "azimuth": azimuth, "techniques": {}}
    draws = [3 + k for k in range(args.realisations)]  # aggregate seeds: 3 is the single draw's
    ref = {}  # per draw: EPT's mean and standard error
    for name, (technique, proxies, bounces) in [("ept", ("Ept", "Off", None))] + [(n, TECHNIQUES[n]) for n in args.techniques]:
        entry = {"seconds": 0.0, "draws": []}
        biases, bias_ses, all_means, all_ses = [], [], [], []
        for draw in draws:
            case = scene(material, shape, sun, elevation, azimuth, draw)
            case["render"].update(width=args.width, height=args.height)
            if bounces is not None:
                case["render"]["explicit_bounces"] = bounces
            case["render"]["switch_for_view"] = name == "view"
            if name != "ept":
                case["render"].update(args.overrides)
            variances = []
            means, _, _, seconds = accuracy_matrix.measure(core, case, technique, None, args.spp, args.seeds,
                                                           args.threads, tmp, proxies, variances)
            mean, se = accuracy_matrix.stats(means, variances)
            entry["seconds"] += seconds
            entry["draws"].append({"aggregate_seed": draw, "mean": mean.tolist(), "se": se.tolist(),
                                   "seed_means": [m.tolist() for m in means],
                                   "seed_variances": [v.tolist() for v in variances]})
            all_means.append(mean)
            all_ses.append(se)
            if name == "ept":
                ref[draw] = (mean, se)
            else:
                biases.append(100 * (mean - ref[draw][0]) / ref[draw][0])
                bias_ses.append(100 * np.hypot(se, ref[draw][1]) / ref[draw][0])
            print(f"{material:14s} {shape:5s} sun {sun:4g} elev {elevation:3g} phase {phase:4g} {name:12s} "
                  f"draw {draw} mean {np.round(mean, 4)} ({seconds:.1f} s)", file=sys.stderr, flush=True)
        n = len(draws)
        entry["mean"] = np.mean(all_means, axis=0).tolist()
        entry["se"] = (np.sqrt(np.sum(np.square(all_ses), axis=0)) / n).tolist()
        if biases:
            # Each draw's bias against EPT of the same draw; the standard error of their mean:
            # the renders' own, or with several draws the larger of it and their spread's.
            within = np.sqrt(np.sum(np.square(bias_ses), axis=0)) / n
            spread = np.std(biases, axis=0, ddof=1) / math.sqrt(n) if n > 1 else np.zeros_like(within)
            entry["bias_pct"] = np.mean(biases, axis=0).tolist()
            entry["bias_se_pct"] = np.maximum(within, spread).tolist()
        out["techniques"][name] = entry
    return out


def table(results, names):
    lines = ["| material | shape | sun | elev | phase | EPT mean (lum.) | "
             + " | ".join(f"{n} bias % (R/G/B) ± SE" for n in names) + " |",
             "|" + "---|" * (6 + len(names))]
    for r in results:
        t = r["techniques"]
        lum = sum(w * v for w, v in zip((0.2126, 0.7152, 0.0722), t["ept"]["mean"]))
        cells = []
        for n in names:
            b, se = t[n]["bias_pct"], t[n]["bias_se_pct"]
            cells.append(" / ".join(f"{x:+.1f}" for x in b) + f" ± {max(se):.1f}")
        lines.append(f"| {r['material']} | {r['shape']} | {r['sun']:g}° | {r['elevation']:g}° | {r['phase']:g}° | "
                     f"{lum:.4f} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(results, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not available: no plot", file=sys.stderr)
        return
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, name in zip(axes, [n for n in ("medium-only", "proxies", "default") if n in results[0]["techniques"]][:2]):
        groups = {}
        for r in results:
            key = (r["material"], r["shape"], r["sun"], r["elevation"])
            lum = lambda v: sum(w * x for w, x in zip((0.2126, 0.7152, 0.0722), v))
            groups.setdefault(key, []).append((r["phase"], lum(r["techniques"][name]["bias_pct"])))
        for key, pts in groups.items():
            pts.sort()
            ax.plot([p for p, _ in pts], [b for _, b in pts], marker="o",
                    label=f"{key[0]} {key[1]} {key[2]:g}° sun, elev {key[3]:g}°")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(f"{name}: bias against explicit grains")
        ax.set_xlabel("sun–view phase angle (degrees)")
    axes[0].set_ylabel("bias of the luminance (%)")
    axes[1].legend(fontsize=6)
    accuracy_matrix.save_figure(fig, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--materials", default="quartz_sand,ice,sucrose,glass_mixture")
    ap.add_argument("--shapes", default="ball,slab")
    ap.add_argument("--suns", default="20,5")
    ap.add_argument("--elevations", default="15,45,80")
    ap.add_argument("--phases", default="0,30,60,90,120,150")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--realisations", type=int, default=1,
                    help="draws of the grains (aggregate seeds 3, 4, ...): the bias is the mean of each draw's")
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--height", type=int, default=24)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--techniques", default="proxies,medium,medium-only",
                    help="compared with EPT, of " + ", ".join(TECHNIQUES) + ", visits-K (proxies for K visits)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a render setting (JSON value) for every technique but the EPT reference, e.g. --set lod=0")
    ap.add_argument("--json")
    ap.add_argument("--plot")
    args = ap.parse_args()
    # What measure() and the techniques set on every render would silently win over --set.
    args.overrides = accuracy_matrix.render_settings(
        ap, args.set, reserved=("technique", "proxies", "spp", "seed", "threads", "sun_regularization",
                                "switch_for_view", "width", "height"))
    args.techniques = [t for t in args.techniques.split(",") if t]
    for t in args.techniques:  # visits-K: proxies on for K visits after the first grain, measured nothing
        if t.startswith("visits-") and t[7:].isdigit():
            TECHNIQUES[t] = ("EptVpt", "On", 2 * int(t[7:]))  # kProxyOrders explicit bounces a visit
    unknown = [t for t in args.techniques if t not in TECHNIQUES]
    if unknown or not args.techniques:
        ap.error(f"--techniques: {', '.join(unknown) or 'none given'}; choose from {', '.join(TECHNIQUES)}")
    if args.seeds < 2:
        ap.error("--seeds must be at least 2 (the standard error comes from their spread)")
    if args.realisations < 1:
        ap.error("--realisations must be at least 1")
    sys.path[:0] = [os.path.join(args.build, "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    floats = lambda s: [float(x) for x in s.split(",") if x]
    results = []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = os.path.join(tmpdir, "scene.json")
        for material in args.materials.split(","):
            for shape in args.shapes.split(","):
                for sun in floats(args.suns):
                    for elevation in floats(args.elevations):
                        for phase in floats(args.phases):
                            r = run_case(core, material, shape, sun, elevation, phase, args, tmp)
                            if r is not None:
                                results.append(r)
    print(f"spp {args.spp} x {args.seeds} seeds x {args.realisations} draws of the grains, {args.width}x{args.height}; "
          f"bias = (technique − EPT) / EPT over the object's pixels, averaged over the draws; s.e.: the larger of the "
          f"seeds' spread and the renders' variance AOV, and with several draws of the draws' spread\n")
    print(table(results, args.techniques))
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as f:
            json.dump({"spp": args.spp, "seeds": args.seeds, "realisations": args.realisations, "results": results},
                      f, indent=1)
    if args.plot and results:
        plot(results, args.plot)


if __name__ == "__main__":
    main()
