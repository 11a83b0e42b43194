#!/usr/bin/env python3
"""Cold build: an example's read and build with an empty cache (GRANULAR_CACHE_DIR a fresh
directory: no tiles, TT parameters, proxy tables or build products), as from a fresh clone,
for one or more builds of the module side by side (say, before and after a change). Each
run is a process of its own (a fresh cache, the named build's granular_core); the runs of
the builds are interleaved, so that other jobs on the machine weigh on them alike.

Prints a markdown table of the runs (read, build, their CPU time, peak memory) and one of
each aggregate's tile packing, distance-field, set-up and switching-measurement seconds
(the median over the runs), with the measurement's paths and chosen visits (core/
switching.h; they are deterministic, so the first run's stand for all).

Usage: .venv/bin/python bench/cold_build.py [--example sandcastle_paper] [--runs 3]
           [--build before=/path/to/old/build --build after=build-cold] [--width 64]
With no --build: the build of GRANULAR_BUILD_DIR (default build/).
"""
import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def source_of(build_dir):
    """The source tree a build directory was configured from (its Python package goes with
    its module)."""
    with open(os.path.join(build_dir, "CMakeCache.txt")) as f:
        for line in f:
            if line.startswith("CMAKE_HOME_DIRECTORY:"):
                return line.split("=", 1)[1].strip()
    return ROOT


def child(example, width):
    """One cold read and build in this process (the module and package on PYTHONPATH);
    prints its numbers as JSON."""
    import granular  # noqa: F401  (the schema plugin)
    import granular_core as core
    from granular.usd_reader import read_stage

    path = os.path.join(ROOT, "examples", example + ".usda")  # the same stage for every build
    c0, t0 = time.process_time(), time.monotonic()
    scene = read_stage(path, width=width)
    c1, t1 = time.process_time(), time.monotonic()
    built = core.Scene.build(scene.desc)
    c2, t2 = time.process_time(), time.monotonic()
    aggregates = [{k: a[k] for k in ("name", "tile_seconds", "sdf_seconds", "setup_seconds", "cells")}
                  for a in built.aggregates]
    for a, sw in zip(aggregates, built.switching):
        measured = sw["measured"]
        a["switch_seconds"] = sw["seconds"] if measured else 0.0
        a["switch_paths"] = sw["paths"] if measured else 0
        a["switch_chosen"] = sw["chosen"] if measured else None
    print(json.dumps({"read": t1 - t0, "build": t2 - t1, "read_cpu": c1 - c0, "build_cpu": c2 - c1,
                      "peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                      "module": core.__file__, "aggregates": aggregates}))


def run_once(build_dir, example, width):
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ)
        env["GRANULAR_CACHE_DIR"] = cache
        env.pop("GRANULAR_CACHE_MAX_MB", None)  # the build cache on, as a user has it
        paths = [os.path.join(build_dir, "python"), os.path.join(source_of(build_dir), "python")]
        env["PYTHONPATH"] = os.pathsep.join(paths + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
        out = subprocess.run([sys.executable, os.path.abspath(__file__), "--child", "--example", example,
                              "--width", str(width)], env=env, check=True, capture_output=True, text=True).stdout
        result = json.loads(out.strip().splitlines()[-1])
        if os.listdir(cache) == []:
            raise RuntimeError("the build wrote nothing into its cache directory")
        return result


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--example", default="sandcastle_paper")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--build", action="append", default=[],
                    help="label=build directory (repeatable); default: GRANULAR_BUILD_DIR or build/")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(a.example, a.width)
        return
    builds = []
    for spec in a.build or ["current=" + os.environ.get("GRANULAR_BUILD_DIR", os.path.join(ROOT, "build"))]:
        label, _, path = spec.partition("=")
        builds.append((label, os.path.abspath(path if path else label)))
    results = {label: [] for label, _ in builds}
    for r in range(a.runs):
        for label, path in builds:
            results[label].append(run_once(path, a.example, a.width))
            res = results[label][-1]
            print(f"run {r + 1} {label}: read {res['read']:.2f} s, build {res['build']:.2f} s", file=sys.stderr,
                  flush=True)

    ncpu = os.cpu_count()
    print(f"{a.example}, empty cache, {a.runs} run(s) per build, interleaved; {ncpu} cores; "
          f"load average at the end {os.getloadavg()[0]:.1f}\n")
    print("| build | read + build, s (median; range) | build CPU, s (median) | peak MiB |")
    print("|---|---|---|---|")
    for label, _ in builds:
        rs = results[label]
        tot = [x["read"] + x["build"] for x in rs]
        cpu = [x["read_cpu"] + x["build_cpu"] for x in rs]
        print(f"| {label} | {statistics.median(tot):.1f} ({min(tot):.1f}–{max(tot):.1f}) | "
              f"{statistics.median(cpu):.1f} | {max(x['peak_mib'] for x in rs):.0f} |")

    print("\nPer aggregate, medians (s): tile packing / distance field / whole aggregate set-up / switching "
          "measurement, and the measurement's paths and chosen visits")
    names = [x["name"] for x in results[builds[0][0]][0]["aggregates"]]
    keys = ("tile_seconds", "sdf_seconds", "setup_seconds", "switch_seconds")
    print("| aggregate | cells | " + " | ".join(f"{label}: tile / field / set-up / switching | paths, visits"
                                               for label, _ in builds) + " |")
    print("|---|---|" + "---|---|" * len(builds))
    totals = {label: [0.0] * len(keys) for label, _ in builds}
    for n in names:
        row = [n, None]
        for label, _ in builds:
            per = [next(g for g in x["aggregates"] if g["name"] == n) for x in results[label]]
            row[1] = per[0]["cells"]
            vals = [statistics.median(g.get(k, 0.0) for g in per) for k in keys]
            for i, v in enumerate(vals):
                totals[label][i] += v
            row.append(" / ".join(f"{v:.2f}" for v in vals))
            chosen = per[0].get("switch_chosen")
            row.append("–" if chosen is None else f"{per[0]['switch_paths']}, {chosen}")
        print(f"| {row[0]} | {row[1]:.3g} | " + " | ".join(row[2:]) + " |")
    print("| sum | | " + " | ".join(" / ".join(f"{v:.2f}" for v in totals[label]) + " |"
                                     for label, _ in builds) + " |")


if __name__ == "__main__":
    main()
