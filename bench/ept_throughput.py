#!/usr/bin/env python3
"""EPT benchmark: ray throughput through an aggregate against raw Embree, the set-up time
and memory of aggregates from 10^6 to 10^9 grains, and full EPT renders of the examples
with one and two threads.

Prints three markdown tables. Each throughput and set-up measurement runs in a fresh
process (so peak RSS belongs to one aggregate); the renders run in this process through
granular_core (the build's), timing the render alone (the scene is built first).
Usage: python3 bench/ept_throughput.py [--build build] [--seconds 2] [--sizes 1e6,...]
           [--examples sandcastle,snowslab,sugarcube,mixture] [--width 240] [--spp 8]
           [--threads 1,2] [--skip throughput,setup,renders]
"""
import argparse
import json
import os
import subprocess
import sys


def run(exe, *args, env=None):
    out = subprocess.run([exe, *args], check=True, capture_output=True, text=True, env=dict(os.environ, **(env or {})))
    return json.loads(out.stdout.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--build", default="build")
    ap.add_argument("--seconds", default="2")
    ap.add_argument("--sizes", default="1e6,1e7,1e8,1e9")
    ap.add_argument("--examples", default="sandcastle,snowslab,sugarcube,mixture")
    ap.add_argument("--width", type=int, default=240)
    ap.add_argument("--spp", type=int, default=8)
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--skip", default="", help="comma-separated tables to skip: throughput, setup, renders")
    a = ap.parse_args()
    skip = set(a.skip.split(","))
    exe = os.path.join(a.build, "bench", "granular-bench")
    if not os.path.exists(exe):
        sys.exit(f"{exe} not found: run 'make build' first")

    if "throughput" not in skip:
        throughput(exe, a)
    if "setup" not in skip:
        setup(exe, a)
    if "renders" not in skip:
        renders(a)


def throughput(exe, a):
    print("## EPT ray throughput (one thread)\n")
    print("Random rays: half from outside, half from random points inside, random directions. "
          "Path rays: recorded from paths through clear glass grains (IOR 1.5), each cast with the grain it "
          "starts at (EPT's hint: inside it, or leaving it) and again without.\n")
    print("| grain radius | grains | Embree rtcIntersect1 on the grain mesh (rays/s) | random rays (rays/s) | ratio "
          "| path rays (rays/s) | ratio | path rays without the hint (rays/s) | path rays inside a grain |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in ("0.02", "0.01"):
        m = run(exe, "throughput", "--grain-radius", r, "--seconds", a.seconds)
        print(f"| {m['grain_radius']} | {m['grains']:.3g} | {m['embree_rays_per_s']:.3g} | "
              f"{m['aggregate_rays_per_s']:.3g} | {m['ratio']:.3f} | {m['path_rays_per_s']:.3g} | "
              f"{m['path_ratio']:.3f} | {m['path_rays_no_hint_per_s']:.3g} | {m['path_inside_fraction']:.2f} |")


def setup(exe, a):
    print("\n## Aggregate set-up time and memory\n")
    print("| grains | tile spheres | cells (tiles) | set-up (s) | tile (s) | distance field (s) | aggregate memory (MiB) "
          "| process peak RSS (MiB) |")
    print("|---|---|---|---|---|---|---|---|")
    for n in a.sizes.split(","):
        # Beyond 10^10 grains, tiles of 512 spheres would exceed the 2^28 cells an aggregate
        # may hold: larger tiles (as a user sets tileSpheres) keep the cells near 4·10^7.
        grains = float(n)
        tile = 512
        while grains / tile > 6e7 and tile * 2 <= 65536:
            tile *= 2
        # The build itself, not a load from the build cache.
        m = run(exe, "setup", "--grains", n, "--tile-spheres", str(tile), env={"GRANULAR_CACHE_MAX_MB": "0"})
        print(f"| {m['grains']:.3g} | {m['tile_spheres']} | {m['cells']} | {m['setup_s']:.2f} | {m['tile_s']:.2f} | "
              f"{m['sdf_s']:.2f} | {m['aggregate_mib']:.1f} | {m['peak_rss_mib']:.0f} |")


def renders(a):
    """Full EPT renders of the examples at equal samples, per thread count: render seconds
    (scene built beforehand) and the speed-up of the largest count over one thread."""
    import time
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    sys.path[:0] = [os.path.join(os.path.abspath(a.build), "python"), os.path.join(root, "python")]
    import granular_core as core
    from granular.usd_reader import read_stage
    threads = [int(t) for t in a.threads.split(",")]
    print(f"\n## Full EPT renders ({a.width} px wide, {a.spp} spp; render seconds, scene built first)\n")
    print("| example | grains | " + " | ".join(f"{t} thread{'s' if t > 1 else ''} (s)" for t in threads) +
          f" | speed-up {threads[-1]} / {threads[0]} | image mean |")
    print("|---|---|" + "---|" * len(threads) + "---|---|")
    for name in a.examples.split(","):
        scene = read_stage(os.path.join(root, "examples", f"{name}.usda"), width=a.width)
        s = scene.desc.settings
        s.technique = core.Technique.Ept
        s.spp = a.spp
        times, mean = [], None
        for t in threads:
            s.threads = t
            scene.desc.settings = s
            built = core.Scene.build(scene.desc)
            r = core.Renderer(built)
            t0 = time.monotonic()
            r.render(pass_samples=a.spp)
            times.append(time.monotonic() - t0)
            mean = float(r.image().pixels[..., :3].mean())
        grains = sum(info["approx_grains"] for info in built.aggregates)
        print(f"| {name} | {grains:.3g} | " + " | ".join(f"{x:.2f}" for x in times) +
              f" | {times[0] / times[-1]:.2f}x | {mean:.4f} |", flush=True)


if __name__ == "__main__":
    main()
