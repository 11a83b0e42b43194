#!/usr/bin/env python3
"""Accuracy matrix of the equivalent medium: explicit grains (EPT, the reference) against
EPT+VPT, the hybrid (EPT+VPT+DA) and EPT+VPT without level of detail, over the materials
and lights users make.

The scene: a ball (radius 1) of grains over a grey floor, seen close enough to fill most
of a small image, lit by a white dome (radiance 1) and optionally a sun. One factor at a
time is varied around a base case (rock grains, IOR 1.55, absorption 0.05 per grain
radius, packing rate 0.6, 100 grains across, dome only): grain shape, IOR, absorption,
packing rate, surface roughness, mixture, size, grains of many sizes (polydisperse), lighting. A case "A/B" applies both
cases' edits (e.g. size-25/absorption-0.0).

Per case and technique, `--seeds` independent renders (different seeds) give the mean
radiance per channel over the pixels that see the ball (primId); the bias of a technique
is (its mean − EPT's) / EPT's, with a standard error from both: per technique the larger
of the seeds' spread and the renders' own variance AOV (stats()).

Usage: python3 bench/accuracy_matrix.py [--build build] [--spp 256] [--seeds 4] [--threads 0]
         [--cases base,ior-2.4,size-25/absorption-0.0,...] [--techniques ept+vpt,hybrid,lod0]
         [--set KEY=VALUE ...] [--json out/accuracy.json]
         [--plot out/bench/accuracy_matrix.png]
       python3 bench/accuracy_matrix.py --replot out/accuracy.json --plot out/bench/accuracy_matrix.png
Prints a markdown table; --json keeps every number, --plot writes a heat map (matplotlib);
--replot draws (and tabulates) a saved --json without rendering. --set applies a render
setting (a JSON value) to every technique but EPT: `--set 'medium_model="exits"'`.
"""
import argparse
import copy
import json
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

SHAPES = {
    "sphere": {"icosphere": {"subdivisions": 2}},
    "rock": {"rock": {"subdivisions": 2, "roughness": 0.25, "seed": 2}},
    "flake": {"ellipsoid": {"radii": [1.0, 0.35, 0.8], "subdivisions": 2}},
    "crystal": {"box": {"lo": [-0.55, -0.55, -0.55], "hi": [0.55, 0.55, 0.55]}},
}


def base_scene():
    return {
        "render": {"width": 32, "height": 24, "spp": 16, "seed": 1, "technique": "ept"},
        "camera": {"look_at": {"eye": [0.3, 0.7, 2.6], "target": [0, -0.1, 0], "up": [0, 1, 0]},
                   "focal_length": 35, "horizontal_aperture": 36, "vertical_aperture": 27,
                   "clipping_range": [0.01, 100]},
        "materials": {
            "grain": {"type": "dielectric", "ior": 1.55, "absorption": 0.05},
            "floor": {"type": "lambert", "albedo": [0.5, 0.5, 0.5]},
        },
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-4, -1.3, -4], "hi": [4, -1.0, 4]}},
                    "material": "floor"}],
        "lights": [{"name": "sky", "type": "dome", "color": [1, 1, 1], "intensity": 1.0}],
        "aggregates": [{
            "name": "ball", "boundary": {"icosphere": {"subdivisions": 3, "radius": 1.0}},
            "grain_radius": 0.01, "packing_rate": 0.6, "seed": 3, "tile_spheres": 512,
            "prototypes": [{"name": "grain", "shape": SHAPES["rock"], "material": "grain"}],
            "weights": [1.0],
        }],
    }


def _set(path, value):
    def apply(s):
        node = s
        for k in path[:-1]:
            node = node[k]
        node[path[-1]] = value
    return apply


def _sun(angle):
    def apply(s):
        s["lights"].append({"name": "sun", "type": "distant", "direction": [-0.4, -1.0, -0.3], "angle": angle,
                            "intensity": 1.0, "normalize": True})
    return apply


def _mixture(s):
    # clear grains with absorbing ones, half and half
    s["materials"]["clear"] = {"type": "dielectric", "ior": 1.5, "absorption": 0.0}
    s["materials"]["grain"]["absorption"] = 0.5
    ag = s["aggregates"][0]
    ag["prototypes"].append({"name": "clear", "shape": SHAPES["sphere"], "material": "clear"})
    ag["weights"] = [0.5, 0.5]


def _amber_flint(s):
    # a mixture of amber rocks and flint flakes, 0.6 / 0.4, f 0.55
    s["materials"]["grain"] = {"type": "dielectric", "ior": 1.55, "absorption": [0.2, 0.6, 1.5]}
    s["materials"]["flint"] = {"type": "dielectric", "ior": 1.8, "absorption": 0.05}
    ag = s["aggregates"][0]
    ag["prototypes"].append({"name": "flake", "shape": {"ellipsoid": {"radii": [1.0, 0.6, 0.8], "subdivisions": 2}},
                             "material": "flint"})
    ag["weights"] = [0.6, 0.4]
    ag["packing_rate"] = 0.55


def _two_sizes(s):
    # polydisperse: the rocks and rocks half their size, half of each by number
    ag = s["aggregates"][0]
    ag["prototypes"].append({"name": "small", "shape": SHAPES["rock"], "material": "grain"})
    ag["weights"] = [0.5, 0.5]
    ag["sizes"] = [1.0, 0.5]


def _spread(s):
    # polydisperse: every rock's radius spread uniformly by ±30%
    s["aggregates"][0]["size_spread"] = 0.3


def _amber_flint_sizes(s):
    # the amber+flint mixture with flint flakes half the rocks' size and a ±20% spread: the
    # absorption per grainRadius makes the small flakes absorb half as much across
    _amber_flint(s)
    ag = s["aggregates"][0]
    ag["sizes"] = [1.0, 0.5]
    ag["size_spread"] = 0.2


def _size(across):
    def apply(s):
        s["aggregates"][0]["grain_radius"] = 1.0 / across
    return apply


# name -> list of edits of the base scene
CASES = {"base": []}
for shape in ("sphere", "flake", "crystal"):
    CASES[f"shape-{shape}"] = [_set(("aggregates", 0, "prototypes", 0, "shape"), SHAPES[shape])]
for ior in (1.31, 1.8, 2.4):
    CASES[f"ior-{ior}"] = [_set(("materials", "grain", "ior"), ior)]
CASES["ior-2.4-clear"] = [_set(("materials", "grain", "ior"), 2.4), _set(("materials", "grain", "absorption"), 0.0)]
for absorption in (0.0, 0.5, 2.0):
    CASES[f"absorption-{absorption}"] = [_set(("materials", "grain", "absorption"), absorption)]
CASES["absorption-chromatic"] = [_set(("materials", "grain", "absorption"), [0.02, 0.2, 1.0])]
for f in (0.3, 0.45):
    CASES[f"packing-{f}"] = [_set(("aggregates", 0, "packing_rate"), f)]
for roughness in (0.3, 0.7):
    CASES[f"roughness-{roughness}"] = [_set(("materials", "grain", "roughness"), roughness)]
CASES["mixture-clear+absorbing"] = [_mixture]
CASES["mixture-amber+flint"] = [_amber_flint]
CASES["polydisperse-two-sizes"] = [_two_sizes]
CASES["polydisperse-spread"] = [_spread]
CASES["polydisperse-amber+flint"] = [_amber_flint_sizes]
for across in (25, 50, 100, 400):
    CASES[f"size-{across}"] = [_size(across)]
CASES["sun-10deg"] = [_sun(10.0)]
CASES["sun-5deg"] = [_sun(5.0)]
CASES["sun-2deg"] = [_sun(2.0)]
CASES["sun-0.53deg"] = [_sun(0.53)]
CASES["sun-delta"] = [_sun(0.0)]  # the physical sun over smooth grains; delta over rough ones

# name -> (technique, lod or None for the default, proxies: Off, Auto (the default) or On)
TECHNIQUES = {"ept+vpt": ("EptVpt", None, "Auto"), "hybrid": ("Hybrid", None, "Auto"), "lod0": ("EptVpt", 0.0, "Auto"),
              "no-proxies": ("EptVpt", None, "Off"), "ppt": ("EptVpt", None, "On"), "ppt-hybrid": ("Hybrid", None, "On")}


def scene_for(case):
    s = base_scene()
    for part in case.split("/"):  # "size-25/absorption-0.0": both edits
        for edit in CASES[part]:
            edit(s)
    return s


def measure(core, scene, technique, lod, spp, seeds, threads, tmp, proxies="Auto", variances=None):
    """Per seed (1000, 1001, ...), the mean RGB over the ball's pixels (primId 1); the pixel
    count, the build's seconds and the renders' seconds. The scene is built once; each seed
    is a new view of it (Scene.set_view). Given a list, `variances` gets per seed the
    variance of that mean that the render itself estimates (its variance AOV, summed over
    the pixels, over their count squared)."""
    import numpy as np
    with open(tmp, "w") as f:
        json.dump(scene, f)
    desc = core.load_scene_json(tmp)
    aggs = desc.aggregates
    aggs[0].id = 1
    desc.aggregates = aggs
    s = desc.settings
    s.technique = getattr(core.Technique, technique)
    s.spp = spp
    s.threads = threads
    if lod is not None:
        s.lod = lod
    s.proxies = getattr(core.ProxyUse, proxies)
    s.sun_regularization = 0.0  # the sun as authored: the reference exact, a technique's bias the medium's
    desc.settings = s
    t0 = time.monotonic()
    built = core.Scene.build(desc)
    build_seconds = time.monotonic() - t0
    means, render_seconds, pixels = [], 0.0, 0
    for k in range(seeds):
        s.seed = 1000 + k
        built.set_view(desc.camera, s)
        t0 = time.monotonic()
        r = core.Renderer(built)
        r.render(pass_samples=spp)
        render_seconds += time.monotonic() - t0
        img = r.image()
        px = img.pixels
        mask = px[..., list(img.channels).index("primId")] == 1
        means.append(px[mask][:, :3].astype(np.float64).mean(axis=0))
        if variances is not None:
            v = [list(img.channels).index(f"variance.{c}") for c in "RGB"]
            variances.append(px[mask][:, v].astype(np.float64).sum(axis=0) / float(mask.sum()) ** 2)
        pixels = int(mask.sum())
    return means, pixels, build_seconds, render_seconds


def render_settings(ap, pairs, reserved=()):
    """The render settings of repeated --set KEY=VALUE options (JSON values), as a dict; a
    usage error (ap.error) for a pair without '=', a value that is not JSON, or a key the
    benchmark sets itself (reserved)."""
    out = {}
    for kv in pairs:
        key, sep, value = kv.partition("=")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            sep = ""
        if not sep or not key:
            ap.error(f"--set {kv!r}: expected KEY=VALUE with a JSON value")
        if key in reserved:
            ap.error(f"--set {key}: set by the benchmark itself ({', '.join(sorted(reserved))})")
    return out


def stats(values, variances=None):
    """Mean and standard error of the mean of a list of RGB arrays. Given the renders' own
    variances of each value (measure()), the standard error is the larger of the two
    estimates: the seeds' spread alone has n − 1 degrees of freedom (with 4 seeds it is
    off by 40% one time in three), the variance AOV misses rare bright samples."""
    import numpy as np
    a = np.array(values)
    n = len(a)
    se = a.std(axis=0, ddof=1) / math.sqrt(n) if n > 1 else np.full(3, np.nan)
    if variances is not None and len(variances) == n:
        se = np.fmax(se, np.sqrt(np.mean(np.array(variances), axis=0) / n))
    return a.mean(axis=0), se


def run_case(core, case, techniques, spp, seeds, threads, tmp, log, explicit_bounces=None, overrides=None):
    scene = scene_for(case)
    if explicit_bounces is not None:
        scene["render"]["explicit_bounces"] = explicit_bounces
    out = {"case": case, "techniques": {}}
    for name, (technique, lod, proxies) in [("ept", ("Ept", None, "Auto"))] + [(t, TECHNIQUES[t]) for t in techniques]:
        variances = []
        rendered = scene
        if overrides and name != "ept":  # --set: every technique but the reference
            rendered = copy.deepcopy(scene)
            rendered["render"].update(overrides)
        means, pixels, build_s, render_s = measure(core, rendered, technique, lod, spp, seeds, threads, tmp, proxies,
                                                   variances)
        mean, se = stats(means, variances)
        out["techniques"][name] = {"mean": mean.tolist(), "se": se.tolist(), "seconds": render_s,
                                   "build_seconds": build_s, "pixels": pixels}
        log(f"{case:26s} {name:8s} mean {mean.round(5)} ± {se.round(5)} (build {build_s:.1f} s, "
            f"render {render_s:.1f} s)")
    ref = out["techniques"]["ept"]
    import numpy as np
    rm, rs = np.array(ref["mean"]), np.array(ref["se"])
    for name in techniques:
        t = out["techniques"][name]
        tm, ts = np.array(t["mean"]), np.array(t["se"])
        t["bias"] = ((tm - rm) / rm).tolist()
        t["bias_se"] = (np.sqrt(ts ** 2 + (tm / rm * rs) ** 2) / rm).tolist()
    return out


def table(results, techniques):
    lines = ["| case | EPT mean (R G B) | " + " | ".join(f"{t} bias % (R / G / B) ± SE" for t in techniques) + " |",
             "|---|---|" + "---|" * len(techniques)]
    for r in results:
        ept = r["techniques"]["ept"]
        row = [r["case"], " ".join(f"{v:.4f}" for v in ept["mean"])]
        for t in techniques:
            b, s = r["techniques"][t]["bias"], r["techniques"][t]["bias_se"]
            row.append(" / ".join(f"{100 * v:+.1f}" for v in b) + f" ± {100 * max(s):.1f}")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def plot(results, techniques, path):
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib not available: no plot", file=sys.stderr)
        return
    import numpy as np
    cols = [f"{t} {c}" for t in techniques for c in "RGB"]
    data = np.array([[100 * r["techniques"][t]["bias"][c] for t in techniques for c in range(3)] for r in results])
    fig, ax = plt.subplots(figsize=(1.0 + 0.5 * len(cols), 0.5 + 0.32 * len(results)))
    lim = min(6.0, max(2.0, float(np.nanmax(np.abs(data)))))  # beyond ±6%: saturated (the numbers say it)
    im = ax.imshow(data, cmap="RdBu_r", vmin=-lim, vmax=lim, aspect="auto")
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(results)), [r["case"] for r in results], fontsize=7)
    for i in range(data.shape[0]):
        for j in range(data.shape[1]):
            ax.text(j, i, f"{data[i, j]:+.1f}", ha="center", va="center", fontsize=5)
    fig.colorbar(im, ax=ax, label="bias against EPT (%)")
    save_figure(fig, path)


def save_figure(fig, path):
    """Writes a figure (its folder made), saying so on stderr."""
    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    fig.savefig(path, dpi=150)
    print(f"wrote {path}", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--techniques", default="ept+vpt,hybrid,lod0")
    ap.add_argument("--explicit-bounces", type=int, default=None,
                    help="render setting explicit_bounces for every case (default: the renderer's, automatic)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a render setting (JSON value) for every technique but the EPT reference, e.g. "
                         "--set 'medium_model=\"exits\"'")
    ap.add_argument("--json")
    ap.add_argument("--plot")
    ap.add_argument("--replot", metavar="JSON", help="table and plot of a saved --json; renders nothing")
    args = ap.parse_args()
    if args.replot:
        with open(args.replot) as f:
            saved = json.load(f)
        results = saved["results"]
        techniques = [t for t in results[0]["techniques"] if t != "ept"]
        print(table(results, techniques))
        if args.plot:
            plot(results, techniques, args.plot)
        return
    sys.path[:0] = [os.path.join(args.build, "python"), os.path.join(ROOT, "python")]
    import granular_core as core
    cases = [c for c in args.cases.split(",") if c]
    techniques = [t for t in args.techniques.split(",") if t]
    for c in cases:
        for part in c.split("/"):
            if part not in CASES:
                ap.error(f"unknown case {part!r} (one of {', '.join(CASES)}; A/B combines two)")
    for t in techniques:
        if t not in TECHNIQUES:
            ap.error(f"unknown technique {t!r} (one of {', '.join(TECHNIQUES)})")
    tmp = os.path.join(args.build, "accuracy_matrix_scene.json")
    log = lambda m: print(m, file=sys.stderr, flush=True)
    overrides = render_settings(ap, args.set, reserved=("technique", "proxies", "lod", "spp", "seed", "threads",
                                                        "sun_regularization", "explicit_bounces"))
    results = [run_case(core, c, techniques, args.spp, args.seeds, args.threads, tmp, log, args.explicit_bounces,
                        overrides) for c in cases]
    print(f"spp {args.spp} x {args.seeds} seeds per technique; bias = (technique − EPT) / EPT over the ball's pixels; "
          "s.e.: the larger of the seeds' spread and the renders' variance AOV\n")
    print(table(results, techniques))
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w") as f:
            json.dump({"spp": args.spp, "seeds": args.seeds, "results": results}, f, indent=1)
    if args.plot:
        plot(results, techniques, args.plot)


if __name__ == "__main__":
    main()
