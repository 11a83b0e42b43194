#!/usr/bin/env python3
"""Wall time of `granular farm` (Dask LocalCluster) against the single-process
`granular render --frames` of the same sequence: 1 and 2 worker processes, 1, 4 and 16 tiles
per frame. Every farm output is compared with the single-process frames bit for bit.

  .venv/bin/python bench/farm.py [--scene examples/animated.usda] [--frames 1:2.5x0.5]
                                 [--size 640x480] [--spp 32] [--workers 1,2] [--tiles 1,4,16]

Prints a Markdown table: wall seconds (the whole command, as a user waits for it: start-up,
scene reading, cluster start, rendering, merging, writing), overhead against the single
process (wall / single − 1), scene builds and whether every frame is identical. The TT and
tile caches are warmed by a first single-process run, so that no configuration pays for them.
"""
import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [os.path.join(ROOT, "python"), os.path.join(ROOT, "build", "python")]
GRANULAR = os.path.join(os.path.dirname(sys.executable), "granular")


def run(argv):
    t0 = time.monotonic()
    r = subprocess.run([GRANULAR, *map(str, argv)], capture_output=True, text=True)
    wall = time.monotonic() - t0
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(map(str, argv))} failed:\n{r.stderr}")
    return wall, r.stderr


def identical(folder, reference, names):
    import granular_core as core
    for name in names:
        a = core.read_exr(os.path.join(folder, name))
        b = core.read_exr(os.path.join(reference, name))
        if a.channels != b.channels or not np.array_equal(a.pixels.view(np.uint32), b.pixels.view(np.uint32)):
            return False
    return True


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default=os.path.join(ROOT, "examples", "animated.usda"))
    ap.add_argument("--frames", default="1:2.5x0.5")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--tiles", default="1,4,16")
    a = ap.parse_args()
    w, h = a.size.split("x")
    common = ["--frames", a.frames, "--width", w, "--height", h, "--spp", a.spp, "--quiet"]
    cores = os.cpu_count()
    with tempfile.TemporaryDirectory() as tmp:
        single = os.path.join(tmp, "single")
        os.makedirs(single)
        run(["render", a.scene, "-o", os.path.join(single, "f.####.exr"), *common])  # warms the caches
        wall_single, _ = run(["render", a.scene, "-o", os.path.join(single, "f.####.exr"), *common])
        names = sorted(os.listdir(single))
        rows = [("single process (render --frames)", 1, "-", "-", wall_single, "-", "-", "reference")]
        for workers in [int(x) for x in a.workers.split(",")]:
            for tiles in [int(x) for x in a.tiles.split(",")]:
                out = os.path.join(tmp, f"w{workers}t{tiles}")
                os.makedirs(out)
                wall, err = run(["farm", a.scene, "-o", os.path.join(out, "f.####.exr"), "--workers", workers,
                                 "--tiles", tiles, *common[:-1]])
                summary = [line for line in err.splitlines() if " tasks in " in line][-1]
                builds = summary.split("(")[1].split(" scene builds")[0]
                same = identical(out, single, names)
                rows.append((f"farm, {workers} worker{'s' if workers > 1 else ''}", workers, tiles,
                             len(names) * tiles, wall, f"{100 * (wall / wall_single - 1):+.1f}%", builds,
                             "yes" if same else "NO"))
    print(f"{os.path.relpath(a.scene, ROOT)}, frames {a.frames} ({len(names)}), {a.size}, {a.spp} spp, "
          f"{cores} cores\n")
    print("| run | workers | tiles/frame | tasks | wall s | overhead | scene builds | bit-identical |")
    print("|---|---|---|---|---|---|---|---|")
    for name, workers, tiles, tasks, wall, over, builds, same in rows:
        print(f"| {name} | {workers} | {tiles} | {tasks} | {wall:.1f} | {over} | {builds} | {same} |")


if __name__ == "__main__":
    main()
