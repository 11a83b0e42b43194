#!/usr/bin/env python3
"""Explicit grains from a simulation (core/instanced_grains.h): set-up time and memory of
the grid against the number of grains, and what tracing them costs.

    .venv/bin/python bench/instanced_grains.py [--grains 1e5,1e6,1e7] [--rays 200000]

Grains: a jittered cubic lattice (bounding spheres of radius up to 1.25 on a spacing of
2.7: the grid's cost, not a realistic density, is measured), random rotations, two
prototypes (an icosphere and a rock), like a grain solver's output but generated in numpy
so that large counts fit in memory. For each count: the description's arrays (input), the
grid's bytes and bytes per grain, the build time with and without the overlap check, the
process's resident memory grown by the first build (freed numpy memory may be reused, so
the grid's own count is the bound to read), the process's peak, and nearest-hit rays per
second from outside the block (random origins on a sphere around it, aimed at its inside;
a Python loop, so a lower bound). Prints a markdown table.

    .venv/bin/python bench/instanced_grains.py --stage HEAP.usdc [--technique ept|hybrid] [--width W]
           [--height H] [--spp N] [--threads T] [--exr OUT.exr] [--instanced-da]

A stage end to end, as `granular render` runs it (read, build, render, in one process): each
phase's seconds (wall clock, and CPU over all threads: on a shared machine the wall clock
includes other jobs' time) and the process's peak resident memory during it (the kernel's high-water
mark, reset at the phase's start), the scene build split as core reports it (grid, overlap
check, the medium with its packing-rate grid, proxy tables), and the peak beyond the
per-grain arrays core keeps (the interpreter and its libraries counted in it). One line of
JSON per phase, then a summary."""
import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
import granular_core as core  # noqa: E402


def rss_bytes(field="VmRSS:"):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(field):
                return int(line.split()[1]) * 1024
    return 0


def lattice(n, seed):
    """n grains on a jittered lattice: positions, orientations (w, x, y, z), scales, indices."""
    rng = np.random.default_rng(seed)
    side = int(np.ceil(n ** (1.0 / 3.0)))
    spacing = 2.7  # the rock reaches 1.25 from its origin: bounding spheres never overlap
    idx = np.arange(n, dtype=np.int64)
    grid = np.stack([idx % side, (idx // side) % side, idx // (side * side)], axis=1).astype(np.float32)
    positions = grid * spacing + rng.uniform(-0.04, 0.04, (n, 3)).astype(np.float32)
    q = rng.normal(size=(n, 4)).astype(np.float32)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    scales = np.repeat(rng.uniform(0.8, 1.0, n).astype(np.float32)[:, None], 3, axis=1)
    indices = (rng.uniform(size=n) < 0.3).astype(np.int64)
    return positions, q, scales, indices, side * spacing


def prototype_lookup(path):
    mp = core.MeshPrim()
    mp.path = path
    mp.mesh = core.make_icosphere(1) if path.endswith("Round") else core.make_rock(1, 0.25, 3)
    return mp


def run(n, rays, seed):
    positions, q, scales, indices, extent = lattice(n, seed)
    desc_holder = core.SceneDesc()
    desc = core.instanced_grains_from_usd(
        "/Sim", "PointInstancer", np.eye(4).tolist(), ["/Sim/Round", "/Sim/Rock"], [],
        positions.reshape(-1), q.reshape(-1), scales.reshape(-1), indices, np.zeros(0, np.float32),
        np.zeros(0, np.float32), desc_holder, prototype_lookup)
    del positions, q, scales, indices
    row = {"grains": desc.num_grains}
    for check in (False, True):
        grid = core.InstancedGrains()
        before = rss_bytes()
        t0 = time.perf_counter()
        grid.build(desc, check_overlaps=check)
        seconds = time.perf_counter() - t0
        grown = rss_bytes() - before
        st = grid.stats
        key = "checked" if check else "unchecked"
        row[key + "_s"] = seconds
        row[key + "_rss"] = grown
        row["input"] = st["input_bytes"]
        row["grid"] = st["grid_bytes"]
        row["per_grain"] = st["bytes_per_grain"]
        if not check:
            del grid
    rng = np.random.default_rng(seed + 1)
    centre = np.full(3, 0.5 * extent)
    d = rng.normal(size=(rays, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origins = centre + d * extent
    targets = centre + rng.uniform(-0.4, 0.4, (rays, 3)) * extent
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t0 = time.perf_counter()
    hits = 0
    for o, v in zip(origins, dirs):
        hits += grid.intersect(tuple(o), tuple(v)) is not None
    row["rays_per_s"] = rays / (time.perf_counter() - t0)
    row["peak"] = rss_bytes("VmHWM:")
    row["hit_fraction"] = hits / rays
    return row


def _status(*fields):
    """Fields of /proc/self/status in bytes."""
    out = {}
    with open("/proc/self/status") as f:
        for line in f:
            key = line.split(":")[0]
            if key in fields:
                out[key] = int(line.split()[1]) * 1024
    return out


def _reset_peak():
    """The kernel's peak resident set (VmHWM) back to the current one."""
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")


def stage_run(args):
    """Reads, builds and renders a stage as `granular render` does, phase by phase."""
    import json

    from granular import api, cli
    from granular.usd_reader import read_stage
    phases = []
    peak = {"VmHWM": 0}

    def phase(name, fn):
        _reset_peak()
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        st = _status("VmHWM", "VmRSS", "RssAnon", "RssFile")
        row = {"phase": name, "seconds": round(time.perf_counter() - t0, 3),
               "cpu_seconds": round(time.process_time() - c0, 3),
               "peak_mib": round(st["VmHWM"] / 2**20), "rss_mib": round(st["VmRSS"] / 2**20),
               "anon_mib": round(st["RssAnon"] / 2**20), "file_mib": round(st["RssFile"] / 2**20)}
        peak["VmHWM"] = max(peak["VmHWM"], st["VmHWM"])
        phases.append(row)
        print(json.dumps(row), flush=True)
        return out

    base = _status("VmRSS")["VmRSS"]
    argv = ["render", args.stage, "-o", args.exr or os.devnull, "--technique", args.technique, "--width",
            str(args.width), "--height", str(args.height), "--spp", str(args.spp), "--threads", str(args.threads)]
    if args.instanced_da:
        argv.append("--instanced-da")
    opts = cli.build_parser().parse_args(argv)
    scene = phase("read", lambda: read_stage(args.stage, width=args.width, height=args.height))
    cli._apply_options(opts, scene)
    built = phase("build", lambda: api.build_scene(scene))
    info = built.instanced_grains
    for g in info:
        print(json.dumps({k: g.get(k) for k in ("name", "grains", "input_bytes", "grid_bytes", "grid_seconds",
                                                  "overlap_seconds", "medium_seconds", "density_seconds",
                                                  "density_bytes", "tables_seconds", "has_medium")}), flush=True)

    def render():
        renderer = core.Renderer(built)
        renderer.render(args.spp, None, 0.5)
        return renderer.image()
    image = phase("render", render)
    if args.exr:
        core.write_exr(args.exr, image)
    inputs = sum(g["input_bytes"] for g in info)
    grains = sum(g["grains"] for g in info)
    set_up = sum(p["seconds"] for p in phases if p["phase"] in ("read", "build"))
    print(json.dumps({"grains": grains, "input_mib": round(inputs / 2**20), "baseline_mib": round(base / 2**20),
                      "set_up_seconds": round(set_up, 2), "peak_mib": round(peak["VmHWM"] / 2**20),
                      "peak_beyond_input_mib": round((peak["VmHWM"] - inputs) / 2**20),
                      "bytes_per_grain_beyond_input": round((peak["VmHWM"] - inputs) / max(1, grains), 1)}), flush=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--grains", default="1e5,1e6,1e7")
    ap.add_argument("--rays", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--stage", help="a stage to read, build and render end to end (see above)")
    ap.add_argument("--technique", default="hybrid", choices=("ept", "ept+vpt", "hybrid"))
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--spp", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--exr", help="with --stage: write the image here")
    ap.add_argument("--instanced-da", action="store_true", help="with --stage: DA in the instancers' media too")
    args = ap.parse_args()
    if args.stage:
        return stage_run(args)
    print("| grains | input (MiB) | grid (MiB) | bytes/grain | build (s) | build + overlap check (s) | "
          "RSS grown by the build (MiB) | peak RSS (MiB) | rays/s (Python loop) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in [int(float(x)) for x in args.grains.split(",")]:
        r = run(n, args.rays, args.seed)
        print(f"| {r['grains']:.3g} | {r['input'] / 2**20:.0f} | {r['grid'] / 2**20:.1f} | {r['per_grain']:.1f} | "
              f"{r['unchecked_s']:.2f} | {r['checked_s']:.2f} | {r['unchecked_rss'] / 2**20:.0f} | {r['peak'] / 2**20:.0f} | "
              f"{r['rays_per_s']:.3g} ({100 * r['hit_fraction']:.0f}% hit) |", flush=True)


if __name__ == "__main__":
    main()
