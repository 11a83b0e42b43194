#!/usr/bin/env python3
"""Switching from measured error (core/switching.h): per aggregate of the examples and of the
hybrid speed-up scenes, the proxy visits chosen, the medium's measured bias right after the
first grain and after the chosen visits, and what the measurement cost.

Each scene is built with technique ept+vpt and an empty cache folder of its own, so the
seconds are those of a first build (a second build reads the measurement from the cache).

Usage: python3 bench/switching.py [--build build] [--examples a,b] [--no-bench-scenes]
Prints a markdown table.
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


def rows_of(core, desc, label):
    s = desc.settings
    s.technique = core.Technique.EptVpt
    desc.settings = s
    built = core.Scene.build(desc)
    out = []
    for info, sw in zip(built.aggregates, built.switching):
        if not sw["measured"]:
            continue
        k = sw["candidates"].index(sw["chosen"])
        out.append((label, info["name"], sw["chosen"], sw["uses_proxies"], worst(sw["bias"][0]),
                    worst(sw["bias"][k]), 100 * max(sw["bias_se"][k]), sw["seconds"], sw["paths"], sw["events"]))
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--examples", default=",".join(EXAMPLES))
    ap.add_argument("--no-bench-scenes", action="store_true")
    a = ap.parse_args()
    sys.path[:0] = [os.path.join(a.build, "python"), os.path.join(ROOT, "python"), HERE]
    os.environ["GRANULAR_CACHE_DIR"] = tempfile.mkdtemp(prefix="granular-switching-")
    import granular_core as core
    from granular.usd_reader import read_stage

    rows = []
    for name in filter(None, a.examples.split(",")):
        rows += rows_of(core, read_stage(os.path.join(ROOT, "examples", name + ".usda"), width=64).desc, name)
    if not a.no_bench_scenes:
        import json
        from hybrid_speedup import scenes
        with tempfile.TemporaryDirectory() as tmp:
            for name, desc in scenes().items():
                path = os.path.join(tmp, "scene.json")
                json.dump(desc, open(path, "w"))
                rows += rows_of(core, core.load_scene_json(path), name)
    print("| scene | aggregate | visits chosen | proxies | medium after the first grain, bias % | "
          "after the chosen visits, bias % ± s.e. | paths | walk steps | measured in s |")
    print("|---|---|---|---|---|---|---|---|---|")
    for label, agg, k, proxies, b0, bk, se, secs, paths, events in rows:
        print(f"| {label} | {agg} | {k} | {'yes' if proxies else 'no'} | {b0:+.1f} | {bk:+.2f} ± {se:.2f} | "
              f"{paths} | {events:.3g} | {secs:.2f} |")


if __name__ == "__main__":
    main()
