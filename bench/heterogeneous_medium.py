#!/usr/bin/env python3
"""The heterogeneous medium of explicit grains (core/grain_density.h,
core/heterogeneous_medium.h), three tables:

1. The packing-rate grid's build: time, grid memory (and the build's working memory),
   leaves and active voxels, for heaps of about 10^5 and 10^6 grains (examples/
   make_grain_heap.py's heap, its arrays made in memory without writing USD), default kernel
   (3 mean grain radii, voxel h/2), on the threads TBB finds.
2. How far the linear σ_t(f) = σ_t,ref f / f_ref is from the TT model's σ_t(f) (tt.h's
   formulas with the per-grain statistics of bench/README.md, "Teleportation-transport
   parameters"), f_ref = 0.6.
3. Transmittance through the 10^5-grain heap (σ_t,ref at the heap's bulk packing rate such
   that the base's diameter is 4 (and 40) mean free paths in red), along horizontal rays
   at heights from the foot to near the top: delta tracking (the flight's pass weight),
   ratio tracking, and ratio tracking with roulette; per estimate the density lookups, the
   time, the variance of one estimate (summed over the rays and channels), and the time (and
   the lookups) to a given error relative to delta tracking (variance × time, or lookups, per
   estimate), single-threaded, the least time of three runs.

Usage: .venv/bin/python bench/heterogeneous_medium.py [--build build] [--grains 100000,1000000]
       [--rays 64] [--samples 400]
Prints markdown tables.
"""
import argparse
import math
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def setup(build):
    for p in (os.path.join(ROOT, "python"), os.path.join(build, "python"), os.path.join(ROOT, "examples")):
        sys.path.insert(0, p)


def heap_desc(grains, seed=1):
    """make_grain_heap's heap (frame 1) as a core.InstancedGrainsDesc, in memory."""
    import granular_core as core
    import make_grain_heap as mg
    centres, sizes, quats, protos, height = mg.heap(grains, seed)

    def unit(tri):
        pts, idx = mg._unit_ball(tri)
        m = core.TriangleMesh()
        m.points = pts
        m.indices = idx.astype(np.uint32)
        return m

    prototypes = [unit(core.make_icosphere(2)), unit(core.make_rock(2, 0.3, seed))]
    desc = core.instanced_grains_desc("/World/Heap", prototypes, centres.astype(np.float32),
                                      sizes.astype(np.float32), protos.astype(np.int64), quats.astype(np.float32))
    return desc, height


def build_table(counts):
    import granular_core as core
    print("## Packing-rate grid build (default kernel h = 3 mean radii, voxel h/2)\n")
    print("| grains | build (s) | grains/s | leaves | active voxels | grid MiB | bytes/grain | build working MiB |")
    print("|---|---|---|---|---|---|---|---|")
    out = {}
    for n in counts:
        desc, height = heap_desc(n)
        t0 = time.perf_counter()
        d = core.build_grain_density(desc)
        wall = time.perf_counter() - t0
        st = d.stats
        print(f"| {st['grains']} | {wall:.2f} | {st['grains'] / wall:.3g} | {st['leaves']} | {st['active_voxels']} | "
              f"{st['bytes'] / 2**20:.1f} | {st['bytes'] / st['grains']:.1f} | {st['build_bytes'] / 2**20:.1f} |")
        out[n] = (desc, d, height)
    print()
    return out


def tt_table():
    # Per-grain TT statistics (β, λ_δ, α_s, λ_s in grain radii) from bench/README.md.
    grains = [("sphere, clear", 0.9989, 0.0490, 1.0, 1.5956), ("rock, clear", 0.7472, 0.7256, 1.0, 1.6626),
              ("rock, absorbing r", 0.7472, 0.7256, 0.8175, 1.6671),
              ("rock, absorbing b", 0.7472, 0.7256, 0.2563, 1.3757)]
    ratios = [0.1, 0.25, 0.5, 0.75, 0.9, 1.05]
    fref = 0.6

    def sigma(f, beta, ld, alpha, ls):
        lb = 4.0 / 3.0 * (1 - f) / f  # Dixmier, R = 1
        return 1.0 / (lb + (lb + ld) * (1 - beta) / beta + alpha * ls)

    print("## Linear σ_t against TT's σ_t(f), f_ref = 0.6: (f / f_ref) / (σ_TT(f) / σ_TT(f_ref))\n")
    print("| grains | " + " | ".join(f"f/f_ref = {r}" for r in ratios) + " |")
    print("|---|" + "---|" * len(ratios))
    for name, *p in grains:
        cells = [r / (sigma(r * fref, *p) / sigma(fref, *p)) for r in ratios]
        print(f"| {name} | " + " | ".join(f"{c:.3f}" for c in cells) + " |")
    print()


def tracking_table(desc, density, height, rays, samples, depth):
    import granular_core as core
    st = density.stats
    r = st["mean_radius"]
    # The heap's bulk packing rate: the median of f over voxels near its axis, low down.
    pts = np.array([[x, y, z] for x in np.linspace(-4 * r, 4 * r, 5) for y in np.linspace(0.2 * height, 0.4 * height, 5)
                    for z in np.linspace(-4 * r, 4 * r, 5)], dtype=np.float32)
    fbulk = float(np.median(density.packing_rate(pts)))
    # An optical depth `depth` along the base's diameter at the bulk's σ_t (red).
    base = height / math.tan(math.radians(31.0))
    sigma = tuple(float(depth / (2 * base) * c) for c in (1.0, 1.1, 1.2))
    med = core.HeterogeneousMedium(density, sigma, (0.9, 0.9, 0.9), fbulk)
    # Horizontal rays along +x at heights from the foot to near the top, off the axis in z.
    rng = np.random.default_rng(2)
    ys = rng.uniform(0.02 * height, 0.97 * height, rays)
    zs = rng.uniform(-0.3, 0.3, rays) * height
    origins = np.stack([np.full(rays, -2 * base), ys, zs], axis=1).astype(np.float32)
    dirs = np.tile(np.array([[1.0, 0.0, 0.0]], np.float32), (rays, 1))
    tmax = 4 * base
    print(f"## Transmittance through the heap of {st['grains']} grains: {rays} horizontal rays, {samples} estimates "
          f"each (σ_t,ref = ({sigma[0]:.3g}, {sigma[1]:.3g}, {sigma[2]:.3g}) per unit at f_ref = {fbulk:.3f}, the bulk: "
          f"an optical depth of {depth:g} to {1.2 * depth:g} across the base's diameter of {2 * base:.3g})\n")
    rows = {}
    for method in ("delta", "ratio", "ratio_roulette"):
        # The same estimates three times: the least time (the machine is shared).
        runs = [med.estimate_transmittance(origins, dirs, tmax, samples, seed=7, method=method) for _ in range(3)]
        res = runs[0]
        res["seconds"] = min(r["seconds"] for r in runs)
        n = rays * samples
        rows[method] = {"mean": np.asarray(res["mean"]), "vars": np.asarray(res["variance"]),
                        "var": float(np.asarray(res["variance"]).sum()),
                        "lookups": res["lookups"] / n, "us": 1e6 * res["seconds"] / n}
    T = rows["ratio"]["mean"]
    print(f"Mean transmittance over rays and channels {T.mean():.3g} (rays from {T.min():.2g} to {T.max():.2g}).\n")
    print("| estimator | lookups / estimate | µs / estimate | variance of one estimate (Σ rays, channels) | "
          "time to equal error (delta = 1) | lookups to equal error (delta = 1) |")
    print("|---|---|---|---|---|---|")
    ref = rows["delta"]["var"] * rows["delta"]["us"]
    refl = rows["delta"]["var"] * rows["delta"]["lookups"]
    for method, row in rows.items():
        eff = row["var"] * row["us"] / ref if ref > 0 else float("nan")
        effl = row["var"] * row["lookups"] / refl if refl > 0 else float("nan")
        print(f"| {method.replace('_', ' + ')} | {row['lookups']:.1f} | {row['us']:.2f} | {row['var']:.4g} | {eff:.3f} "
              f"| {effl:.3f} |")
    # The three agree (unbiased): the largest difference of a ray's means in standard errors,
    # over the (ray, channel) pairs where delta tracking's pass/collide count is large
    # enough for its sample variance to mean something (samples × min(T, 1 − T) >= 10).
    z, pairs = 0.0, 0
    Tm = rows["ratio"]["mean"]
    clt = samples * np.minimum(Tm, 1 - Tm) >= 10
    for other in ("ratio", "ratio_roulette"):
        both = clt & (rows["delta"]["vars"] > 0) & (rows[other]["vars"] > 0)
        se = np.sqrt((rows["delta"]["vars"] + rows[other]["vars"])[both] / samples)
        d = np.abs(rows["delta"]["mean"] - rows[other]["mean"])[both]
        pairs += int(both.sum())
        if both.any():
            z = max(z, float(np.max(d / se)))
    print(f"\nThe estimators agree: the largest difference of a ray's means, delta against the ratio trackers, "
          f"is {z:.2f} standard errors ({pairs} comparisons). The medium takes {med.bytes / 2**20:.1f} MiB.\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default=os.path.join(ROOT, "build"))
    ap.add_argument("--grains", default="100000,1000000")
    ap.add_argument("--rays", type=int, default=64)
    ap.add_argument("--samples", type=int, default=400)
    ap.add_argument("--depths", default="4,40", help="optical depths across the heap's base (default 4,40)")
    a = ap.parse_args()
    setup(os.path.abspath(a.build))
    counts = [int(float(x)) for x in a.grains.split(",")]
    built = build_table(counts)
    tt_table()
    desc, density, height = built[counts[0]]
    for depth in (float(x) for x in a.depths.split(",")):
        tracking_table(desc, density, height, a.rays, a.samples, depth)


if __name__ == "__main__":
    main()
