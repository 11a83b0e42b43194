#!/usr/bin/env python3
"""Diffusion models against an exact random walk, in a half space (core/diffusion.h).

What DA replaces: a path scattering at depth z, arriving along ω_i, continues a random
walk until it leaves the medium. Under uniform light from outside its expected
contribution is the probability of escape (each further scattering weighted by the
albedo α). This script computes that probability by an exact walk (σ_t = 1,
Henyey–Greenstein phase g) for paths arriving heading down, sideways and up, and compares
the diffusion estimates of the same quantity:

  point   an isotropic point source at x (the former DA), dipole, D = 1/(3σ'_t), z_b = 2D
  beam    the photon beam (PBD): ω from the phase function, the first reduced scattering
          at t ~ σ'_t e^{−σ'_t t} (weight α'), escape when the beam leaves first
  beam+G  the beam with Grosjean's D = (2σ_a + σ'_s)/(3σ'_t²)
  beam zb the beam with z_b = 0.7104/σ'_t = 2.131 D (the Milne problem's exact extrapolation length)

at the paper's DA depth min(1/σ'_t, 0.5/σ_tr) (factor 1) and twice it.

Usage: python3 bench/diffusion_models.py [--photons 50000] [--seed 1]
Prints a markdown table of relative errors (model / walk − 1) for ω_i down / sideways / up.
"""
import argparse
import math

import numpy as np


def hg_cos(rng, g, n):
    u = rng.random(n)
    if abs(g) < 1e-6:
        return 1.0 - 2.0 * u
    s = (1.0 - g * g) / (1.0 - g + 2.0 * g * u)
    return (1.0 + g * g - s * s) / (2.0 * g)


def turn(rng, w, mu):
    """Directions at cosine mu to w (rows), uniform azimuth."""
    n = len(mu)
    phi = 2.0 * math.pi * rng.random(n)
    st = np.sqrt(np.maximum(0.0, 1.0 - mu * mu))
    helper = np.where(np.abs(w[:, 0:1]) > 0.9, np.array([[0.0, 1.0, 0.0]]), np.array([[1.0, 0.0, 0.0]]))
    s = np.cross(w, helper)
    s /= np.linalg.norm(s, axis=1)[:, None]
    t = np.cross(w, s)
    return w * mu[:, None] + s * (st * np.cos(phi))[:, None] + t * (st * np.sin(phi))[:, None]


def start_dirs(rng, wz, g, n):
    w0 = np.zeros((n, 3))
    w0[:, 2] = wz
    w0[:, 0] = math.sqrt(max(0.0, 1.0 - wz * wz))
    return turn(rng, w0, hg_cos(rng, g, n))


def walk_escape(rng, z0, wz, alpha, g, n):
    """Exact: escape probability of a walk scattering at depth z0 (z grows downwards)."""
    w = start_dirs(rng, wz, g, n)
    z = np.full(n, z0)
    wt = np.ones(n)
    alive = np.ones(n, bool)
    escaped = 0.0
    while alive.any():
        idx = np.nonzero(alive)[0]
        zn = z[idx] - np.log1p(-rng.random(len(idx))) * w[idx, 2]
        out = zn < 0
        escaped += wt[idx[out]].sum()
        alive[idx[out]] = False
        k = idx[~out]
        z[k] = zn[~out]
        wt[k] *= alpha
        w[k] = turn(rng, w[k], hg_cos(rng, g, len(k)))
        alive[k[(wt[k] < 1e-4) | (z[k] > 80.0)]] = False
    return escaped / n


def reduced(alpha, g, grosjean):
    sa = 1.0 - alpha
    sps = (1.0 - g) * alpha
    stp = sps + sa
    D = (2.0 * sa + sps) / (3.0 * stp * stp) if grosjean else 1.0 / (3.0 * stp)
    return stp, sps / stp, D, math.sqrt(sa / D)


def dipole_escape(h, D, s, zb):
    """Laterally integrated exitance φ/4 + (D/2)∂φ/∂n of a source at depth h (dipole)."""
    def one(x):
        e = np.exp(-s * np.abs(x))
        return e * (1.0 / (8.0 * D * s) + np.sign(x) / 4.0)
    return one(h) - one(-(h + 2.0 * zb))


def beam_escape(rng, z, wz, alpha, g, grosjean, zb_factor, n):
    stp, ap, D, s = reduced(alpha, g, grosjean)
    w = start_dirs(rng, wz, g, n)
    t = -np.log1p(-rng.random(n)) / stp
    zz = z + t * w[:, 2]
    return np.where(zz < 0, 1.0, ap * dipole_escape(np.maximum(zz, 0.0), D, s, zb_factor * D)).mean()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--photons", type=int, default=50000)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    dirs = (1.0, 0.0, -1.0)
    print("| albedo | g | depth | walk (down / side / up) | point | beam | beam+Grosjean D | beam, z_b = 2.131 D |")
    print("|---|---|---|---|---|---|---|---|")
    for alpha in (0.99, 0.9, 0.5):
        for g in (0.0, 0.7):
            stp, _, _, s = reduced(alpha, g, False)
            depth = min(1.0 / stp, 0.5 / s)
            for factor in (1, 2):
                z = factor * depth
                ref = [walk_escape(rng, z, wz, alpha, g, args.photons) for wz in dirs]
                cells = []
                D = 1.0 / (3.0 * stp)
                cells.append([float(dipole_escape(z, D, s, 2.0 * D))] * 3)
                for grosjean, zbf in ((False, 2.0), (True, 2.0), (False, 2.131)):
                    cells.append([beam_escape(rng, z, wz, alpha, g, grosjean, zbf, 8 * args.photons) for wz in dirs])
                fmt = lambda vals: " / ".join("%+.1f%%" % (100.0 * (v / r - 1.0)) for v, r in zip(vals, ref))
                print(f"| {alpha} | {g} | {factor}× = {z:.2f} mfp | " + " / ".join("%.3f" % r for r in ref) + " | "
                      + " | ".join(fmt(c) for c in cells) + " |", flush=True)


if __name__ == "__main__":
    main()
