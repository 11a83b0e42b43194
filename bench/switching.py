#!/usr/bin/env python3
"""Switching from measured error (core/switching.h): per aggregate of the examples and of the
hybrid speed-up scenes, the proxy visits chosen, the medium's measured bias right after the
first grain and after the chosen visits (in all, and in the worst exit bin), and what the
measurement cost.

Each scene is built with technique ept+vpt and an empty cache folder of its own, so the
seconds are those of a first build (a second build reads the measurement from the cache).

With --view, the scenes are built with switch_for_view: each aggregate the camera sees is
measured for that view as well (switching.h: measureViewSwitch, the radiance the camera
sees under the scene's lights), and its columns follow. With --view-paths N, each such
aggregate is measured again with N paths, every candidate forking in every path
(Scene.measure_view_switch and Scene.measure_switch, stop_early=False), and a table per
aggregate sets the bias in what the camera sees beside the bias in the albedo.

With --exit-bins N, each aggregate is measured again with N paths, every candidate forking
in every path (Scene.measure_switch, stop_early=False), and a table per aggregate gives the
bias after each candidate's visits in all and per exit bin (switching.h: the exit
direction's cosine from the entry's normal, back toward the entry side or forward).

With --seeds N, each aggregate's dome measurement is made again on seeds 1 … N as the
scene makes it (Scene.measure_switch), and once on --truth-paths paths (2^20 by default)
with every candidate forking in every path, seed 1000: a table gives the choice on each
seed, each candidate's bias on the long measurement (the worst channel), and the largest
of those among the seeds' choices — how far the choice's noise can take the bias the
medium leaves.

Usage: python3 bench/switching.py [--build build] [--examples a,b] [--no-bench-scenes]
         [--scene extra.json ...] [--exit-bins N] [--view] [--view-paths N]
         [--seeds N [--truth-paths M]]
Prints markdown tables.
"""
import argparse
import os
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
EXAMPLES = ["sandcastle", "sandcastle_paper", "mixture", "macro", "frosted", "snowslab", "sugarcube"]


def worst(v):
    return 100 * max(v, key=abs)


def worst_bin(sw, k, bins):
    """The exit bin of candidate k's largest |bias| (any channel): its label, bias % and s.e. %."""
    n = len(bins)
    j = max(range(n), key=lambda j: max(abs(x) for x in sw["exit_bias"][k * n + j]))
    lo, hi, side = bins[j]
    return f"{lo:.1f}–{hi:.1f} {side}", worst(sw["exit_bias"][k * n + j]), 100 * max(sw["exit_bias_se"][k * n + j])


def view_table(built, a, label, name, paths):
    """The bias after each candidate's visits in the albedo and in what the camera sees."""
    v = built.measure_view_switch(a, paths=paths, stop_early=False)
    d = built.measure_switch(a, paths=paths, stop_early=False)
    lines = [f"**{label}, {name}** ({paths} paths each; {v['entries']} of the camera's rays enter it; view "
             f"{v['seconds']:.1f} s, albedo {d['seconds']:.1f} s; bias % R / G / B ± s.e.)", "",
             "| visits | albedo (dome) | what the camera sees |", "|---|---|---|"]
    for c, visits in enumerate(v["candidates"][:-1]):
        cells = ["/".join(f"{100 * x:+.2f}" for x in m["bias"][c]) + " ± " +
                 "/".join(f"{100 * x:.2f}" for x in m["bias_se"][c]) for m in (d, v)]
        lines.append(f"| {visits} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def stability_row(built, a, label, name, seeds, truth_paths):
    """The dome's choice on seeds 1 … seeds against each candidate's bias on truth_paths."""
    chosen = [built.measure_switch(a, seed=s)["chosen"] for s in range(1, seeds + 1)]
    t = built.measure_switch(a, paths=truth_paths, stop_early=False, seed=1000)
    bias = {c: (worst(b), 100 * max(se)) for c, b, se in zip(t["candidates"], t["bias"], t["bias_se"])}
    reached = max(chosen, key=lambda c: abs(bias[c][0]))
    return t["candidates"][:-1], (f"| {label} | {name} | {', '.join(map(str, chosen))} | " +
                                  " | ".join(f"{bias[c][0]:+.2f} ± {bias[c][1]:.2f}" for c in t["candidates"][:-1]) +
                                  f" | {bias[reached][0]:+.2f} (after {reached}) | {t['seconds']:.1f} |")


def rows_of(core, desc, label, exit_paths, tables, view=False, view_paths=0, seeds=0, truth_paths=0, stability=None):
    s = desc.settings
    s.technique = core.Technique.EptVpt
    s.switch_for_view = view or view_paths > 0
    desc.settings = s
    built = core.Scene.build(desc)
    bins = core.switch_exit_bins()
    out = []
    for a, (info, sw) in enumerate(zip(built.aggregates, built.switching)):
        if not sw["measured"]:
            continue
        k = sw["candidates"].index(sw["chosen"])
        out.append((label, info["name"], sw["chosen"], sw["uses_proxies"], worst(sw["bias"][0]),
                    worst(sw["bias"][k]), 100 * max(sw["bias_se"][k]), worst_bin(sw, k, bins), sw["seconds"],
                    sw["paths"], sw["events"], sw.get("view"), sw["proxy_visits"]))
        if seeds:
            stability.append(stability_row(built, a, label, info["name"], seeds, truth_paths))
        if view_paths and "view" in sw:
            tables.append(view_table(built, a, label, info["name"], view_paths))
        if exit_paths:
            m = built.measure_switch(a, paths=exit_paths, stop_early=False)
            lines = [f"**{label}, {info['name']}** ({m['paths']} paths, {m['seconds']:.1f} s; bias % ± s.e., "
                     "the largest of the channels)", "",
                     "| visits | albedo | " + " | ".join(f"{lo:.1f}–{hi:.1f} {side}" for lo, hi, side in bins) + " |",
                     "|---" * (len(bins) + 2) + "|"]
            n = len(bins)
            for c, visits in enumerate(m["candidates"][:-1]):
                cells = [f"{worst(m['bias'][c]):+.2f} ± {100 * max(m['bias_se'][c]):.2f}"]
                cells += [f"{worst(m['exit_bias'][c * n + j]):+.2f} ± {100 * max(m['exit_bias_se'][c * n + j]):.2f}"
                          for j in range(n)]
                lines.append(f"| {visits}{' (chosen)' if visits == sw['chosen'] else ''} | " + " | ".join(cells) + " |")
            tables.append("\n".join(lines))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--examples", default=",".join(EXAMPLES))
    ap.add_argument("--no-bench-scenes", action="store_true")
    ap.add_argument("--scene", action="append", default=[], help="a JSON scene to add (repeatable)")
    ap.add_argument("--exit-bins", type=int, default=0, metavar="N",
                    help="measure each aggregate again with N paths and tabulate its exit bins")
    ap.add_argument("--view", action="store_true", help="measure the switch for each example's view too")
    ap.add_argument("--view-paths", type=int, default=0, metavar="N",
                    help="measure each aggregate the camera sees again with N paths, for the view and the dome")
    ap.add_argument("--seeds", type=int, default=0, metavar="N",
                    help="measure each aggregate's dome switch on seeds 1..N and against a long measurement")
    ap.add_argument("--truth-paths", type=int, default=1 << 20, metavar="M",
                    help="paths of the long measurement --seeds compares with (default 2^20)")
    a = ap.parse_args()
    sys.path[:0] = [os.path.join(a.build, "python"), os.path.join(ROOT, "python"), HERE]
    os.environ["GRANULAR_CACHE_DIR"] = tempfile.mkdtemp(prefix="granular-switching-")
    import granular_core as core
    from granular.usd_reader import read_stage

    rows, tables, stability = [], [], []
    extra = dict(seeds=a.seeds, truth_paths=a.truth_paths, stability=stability)
    for name in filter(None, a.examples.split(",")):
        rows += rows_of(core, read_stage(os.path.join(ROOT, "examples", name + ".usda"), width=64).desc, name,
                        a.exit_bins, tables, a.view, a.view_paths, **extra)
    for path in a.scene:
        rows += rows_of(core, core.load_scene_json(path), os.path.basename(path), a.exit_bins, tables, a.view,
                        a.view_paths, **extra)
    if not a.no_bench_scenes:
        import json
        from hybrid_speedup import scenes
        with tempfile.TemporaryDirectory() as tmp:
            for name, desc in scenes().items():
                path = os.path.join(tmp, "scene.json")
                json.dump(desc, open(path, "w"))
                rows += rows_of(core, core.load_scene_json(path), name, a.exit_bins, tables, a.view, a.view_paths,
                                **extra)
    view = a.view or a.view_paths > 0
    print("| scene | aggregate | visits chosen | proxies | medium after the first grain, bias % | "
          "after the chosen visits, bias % ± s.e. | its worst exit bin, bias % ± s.e. | paths | walk steps | "
          "measured in s |" + (" for the view: visits chosen, bias % ± s.e. there | its paths, s | visits taken |"
                               if view else ""))
    print("|---" * (13 if view else 10) + "|")
    for label, agg, k, proxies, b0, bk, se, (bin_label, bb, bse), secs, paths, events, v, taken in rows:
        line = (f"| {label} | {agg} | {k} | {'yes' if proxies else 'no'} | {b0:+.1f} | {bk:+.2f} ± {se:.2f} | "
                f"{bb:+.2f} ± {bse:.2f} ({bin_label}) | {paths} | {events:.3g} | {secs:.2f} |")
        if view:
            if v:
                kv = v["candidates"].index(v["chosen"])
                line += (f" {v['chosen']}, {worst(v['bias'][kv]):+.2f} ± {100 * max(v['bias_se'][kv]):.2f} | "
                         f"{v['paths']}, {v['seconds']:.1f} | {taken} |")
            else:
                line += f" (not seen) | | {taken} |"
        print(line)
    for t in tables:
        print()
        print(t)
    if stability:
        print()
        print(f"**The dome's choice on seeds 1 … {a.seeds}** against each candidate's bias on {a.truth_paths} paths "
              "(bias %, the worst channel, ± s.e.)")
        print()
        candidates = stability[0][0]  # every measurement's, all but the reference
        print("| scene | aggregate | chosen, seed by seed | " + " | ".join(f"after {k}" for k in candidates) +
              " | the largest chosen | long measurement, s |")
        print("|---" * (len(candidates) + 5) + "|")
        for _, line in stability:
            print(line)


if __name__ == "__main__":
    main()
