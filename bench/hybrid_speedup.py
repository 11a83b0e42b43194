#!/usr/bin/env python3
"""Hybrid benchmark: relative MSE against a converged EPT reference versus render time,
for EPT, EPT+VPT and EPT+VPT+DA (hybrid), on four scenes — bright sand, dark grains,
a mixture with glass-like grains and a snow field seen from afar — and the equal-error speedup of each over EPT.

Each technique renders the scene at a ladder of sample counts; relMSE (mean over
pixels and channels of (x − ref)² / (ref² + 0.01), bench/image_compare.cpp) and the
bias of the image mean are measured against an EPT render with --ref-spp samples.
For an unbiased estimator relMSE × time is constant; the equal-error speedup over EPT
is the ratio of those products (median over the ladder's upper half).

The reference is the mean of two EPT renders of --ref-spp / 2 samples on independent
seeds. Its own noise adds the same floor to every entry (E[(x − r)²] = bias² + Var(x) +
Var(r)); half their difference measures it (granular-compare with two references), and
the second speed-up table removes it: (relMSE − floor) × time, the images' own error.
The floor penalises the technique that converges fastest, whose error at the ladder's top
comes nearest to it.

Usage: python3 bench/hybrid_speedup.py [--build build] [--out out/bench] [--ref-spp 1024] [--set KEY=VALUE]
Prints markdown tables; writes OUT/hybrid_speedup.png when matplotlib is available.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def scenes():
    base = json.load(open(os.path.join(ROOT, "examples", "bright_sand.json")))
    base["render"].update(width=96, height=72, spp=4)
    base["aggregates"][0]["grain_radius"] = 0.006
    out = {}
    bright = json.loads(json.dumps(base))
    bright["materials"]["sand"]["absorption"] = [0.004, 0.007, 0.015]
    out["bright sand"] = bright
    dark = json.loads(json.dumps(base))
    dark["materials"]["sand"]["absorption"] = [0.9, 1.2, 2.0]
    out["dark grains"] = dark
    mix = json.loads(json.dumps(base))
    mix["materials"]["sand"]["absorption"] = [0.02, 0.035, 0.08]
    mix["materials"]["glass"] = {"type": "dielectric", "ior": 1.5, "absorption": [0.0, 0.0, 0.0]}
    protos = mix["aggregates"][0]["prototypes"]
    protos.append({"name": "glass_bead", "shape": {"ellipsoid": {"radii": [1.0, 0.9, 0.95], "subdivisions": 2}},
                   "material": "glass"})
    mix["aggregates"][0]["weights"] = [0.35, 0.25, 0.4]
    out["mixture with glass"] = mix
    # Mostly deep, bright material seen from afar: a snow field (ice grains, IOR 1.31,
    # nearly clear) 6 units wide and 0.6 deep, where DA should carry most of the light.
    snow = json.loads(json.dumps(base))
    snow["materials"]["snow"] = {"type": "dielectric", "ior": 1.31, "absorption": [0.002, 0.001, 0.0005]}
    field = snow["aggregates"][0]
    field["name"] = "snow_field"
    field["boundary"] = {"box": {"lo": [-3.0, 0.0, -3.0], "hi": [3.0, 0.6, 3.0]}}
    field["prototypes"] = [{"name": "snow", "shape": {"rock": {"subdivisions": 2, "roughness": 0.15, "seed": 3}},
                            "material": "snow"}]
    field["weights"] = [1.0]
    snow["camera"]["look_at"] = {"eye": [4.5, 3.2, 5.5], "target": [0.0, 0.2, 0.0], "up": [0, 1, 0]}
    out["snow field"] = snow
    return out


def render(exe, scene_path, out_exr, spp, technique, seed):
    stats = out_exr + ".json"
    subprocess.run([exe, scene_path, "-o", out_exr, "--spp", str(spp), "--technique", technique, "--seed", str(seed),
                    "--quiet", "--stats-json", stats], check=True)
    return json.load(open(stats))


def compare(exe, a, *refs):
    r = subprocess.run([exe, a, *refs], check=True, capture_output=True, text=True)
    return json.loads(r.stdout)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--ladder", default="4,8,16,32,64")
    ap.add_argument("--scenes", default="", help="comma-separated subset of scene names")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a render setting for every scene (JSON value), e.g. --set da_min_order=8; the EPT "
                         "reference is rendered without it")
    a = ap.parse_args()
    from accuracy_matrix import render_settings
    overrides = render_settings(ap, a.set)
    render_exe = os.path.join(a.build, "core", "granular-render")
    compare_exe = os.path.join(a.build, "bench", "granular-compare")
    for e in (render_exe, compare_exe):
        if not os.path.exists(e):
            sys.exit(f"{e} not found: build first (make build)")
    os.makedirs(a.out, exist_ok=True)
    ladder = [int(s) for s in a.ladder.split(",")]
    techniques = ["ept", "ept+vpt", "hybrid"]
    results = {}
    for name, desc in scenes().items():
        if a.scenes and name not in a.scenes.split(","):
            continue
        tag = name.replace(" ", "_")
        path = os.path.join(a.out, tag + ".json")
        json.dump(desc, open(path, "w"), indent=1)
        refs = [os.path.join(a.out, f"{tag}_ref_{half}.exr") for half in "ab"]
        ref_path = path
        if overrides:  # the reference above keeps the defaults; the ladder gets the overrides
            desc["render"].update(overrides)
            path = os.path.join(a.out, tag + "_set.json")
            json.dump(desc, open(path, "w"), indent=1)
        for seed, ref in enumerate(refs, 1000):
            if not os.path.exists(ref):
                st = render(render_exe, ref_path, ref, a.ref_spp // 2, "ept", seed)
                print(f"# {name}: reference EPT {a.ref_spp // 2} spp (seed {seed}) in {st['render_s']:.1f} s",
                      file=sys.stderr)
        rows = []
        for t in techniques:
            for spp in ladder:
                img = os.path.join(a.out, f"{tag}_{t.replace('+', '_')}_{spp}.exr")
                st = render(render_exe, path, img, spp, t, 1)
                c = compare(compare_exe, img, *refs)
                rows.append({"technique": t, "spp": spp, "time": st["render_s"], "build": st["build_s"],
                             "relmse": c["relmse"], "floor": c["floor"], "bias": c["bias"], "pa": st["pa"]})
        results[name] = rows

    print("## Hybrid against a converged EPT reference\n")
    print(f"Reference: EPT, 2 × {a.ref_spp // 2} spp. relMSE = mean((x − ref)² / (ref² + 0.01)); floor = the "
          "reference's own share of it; bias = relative difference of the image means.\n")
    print("| scene | technique | spp | render time (s) | relMSE | floor | bias | P_a |")
    print("|---|---|---|---|---|---|---|---|")
    for name, rows in results.items():
        for r in rows:
            print(f"| {name} | {r['technique']} | {r['spp']} | {r['time']:.2f} | {r['relmse']:.4g} | "
                  f"{r['floor']:.3g} | {r['bias']:+.4f} | {r['pa']:.2f} |")

    def error(r, net):
        """relMSE, or with net its part beyond the floor; None where noise leaves none."""
        e = r["relmse"] - (r["floor"] if net else 0.0)
        return e if e > 0 else None

    def speedups(net):
        eff = {}
        for name, rows in results.items():
            for t in techniques:
                rs = [r for r in rows if r["technique"] == t][len(ladder) // 2:]
                # Floors come from the same two references, so they agree row to row.
                es = [error(r, net) for r in rs]
                eff[name, t] = None if None in es else statistics.median(e * r["time"] for e, r in zip(es, rs))
        return eff

    def ratio(a, b):
        return "below the floor" if a is None or b is None else f"{a / b:.2f}×"

    for net in (False, True):
        what = "relMSE − floor" if net else "relMSE"
        print(f"\n## Equal-error speedup over EPT (median of ({what}) × time over the ladder's upper half)\n")
        print(f"| scene | EPT ({what})×s | EPT+VPT speedup | EPT+VPT+DA speedup | hybrid bias at top spp |")
        print("|---|---|---|---|---|")
        eff = speedups(net)
        for name, rows in results.items():
            top = [r for r in rows if r["technique"] == "hybrid"][-1]
            e = eff[name, "ept"]
            print(f"| {name} | {'—' if e is None else f'{e:.4g}'} | {ratio(e, eff[name, 'ept+vpt'])} | "
                  f"{ratio(e, eff[name, 'hybrid'])} | {top['bias']:+.4f} |")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("\n(matplotlib not installed: no plot; apt-get install python3-matplotlib)", file=sys.stderr)
        return
    fig, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 4), squeeze=False)
    for ax, (name, rows) in zip(axes[0], results.items()):
        for t in techniques:
            rs = [r for r in rows if r["technique"] == t and error(r, True) is not None]
            ax.loglog([r["time"] for r in rs], [error(r, True) for r in rs], "o-", label=t)
        ax.set_title(name)
        ax.set_xlabel("render time (s)")
        ax.set_ylabel("relMSE vs EPT reference, less its noise")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    png = os.path.join(a.out, "hybrid_speedup.png")
    fig.savefig(png, dpi=110)
    print(f"\nplot: {png}", file=sys.stderr)


if __name__ == "__main__":
    main()
