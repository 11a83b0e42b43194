#!/usr/bin/env python3
"""Fireflies under the physical sun: an example rendered under its own sun (the 0.53° disk)
at many seeds, against the same example under a wider sun of the same irradiance, with
explicit grains under a 5° sun as the reference for the bias (EPT cannot converge at 0.53°).

Noise is read per pixel against the mean of the set's other images (leave one out): a
glint's own shape is in that mean and is not counted, and an outlier cannot raise the mean
it is compared with. Per set: the percentiles 99, 99.9 and 99.99 and the largest of
pixel / leave-one-out mean (luminance, over the aggregates' pixels), and the pixels per
image above 2.5 and 4 times it; against the reference, the bias over the aggregates'
pixels (% R / G / B ± s.e. from both sets' spread over seeds) and the median over images
of the relative RMS of the luminance.

Usage: .venv/bin/python bench/fireflies.py [--examples macro,frosted] [--variants default,sun-20]
       [--seeds 48] [--spp 256] [--width 64] [--ref-seeds 16] [--ref-spp 1024] [--no-ref]
       [--out out/bench/fireflies]
Variants: `default` (the example as users render it), `reg-D` (`--sun-regularization D`),
`sun-A` (the example's distant light set to A degrees; its normalize attribute keeps the
irradiance), `sun-A+reg-D` (both); the reference is `sun-5+ept` (explicit grains, the
regularisation off). Images are kept under --out and reused when present:
delete them after a change to the renderer. Prints a markdown table per example.
"""
import argparse
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
GRANULAR = os.path.join(os.path.dirname(sys.executable), "granular")
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def sun_stage(example, angle, out):
    """A stage with the example as its sublayer and its distant light's angle set."""
    from pxr import Sdf, Usd, UsdLux
    path = os.path.join(out, f"{os.path.basename(example)[:-5]}_sun{angle:g}.usda")
    if not os.path.exists(path):
        source = Usd.Stage.Open(example)
        suns = [p.GetPath() for p in source.Traverse() if p.IsA(UsdLux.DistantLight)]
        if not suns:
            raise SystemExit(f"{example} has no distant light")
        stage = Usd.Stage.CreateNew(path)
        stage.GetRootLayer().subLayerPaths.append(os.path.abspath(example))
        stage.OverridePrim(suns[0]).CreateAttribute("inputs:angle", Sdf.ValueTypeNames.Float).Set(float(angle))
        stage.GetRootLayer().Save()
    return path


def variant_args(example, variant, out):
    """The stage and the extra options of a variant."""
    stage, extra = example, []
    for part in variant.split("+"):
        if part == "default":
            continue
        kind, _, value = part.partition("-")
        if kind == "sun":
            stage = sun_stage(example, float(value), out)
        elif kind == "reg":
            extra += ["--sun-regularization", value]
        elif kind == "ept":  # the reference's technique
            extra += ["--technique", "ept", "--sun-regularization", "0"]
        else:
            raise SystemExit(f"unknown variant {variant!r}")
    return stage, extra


def render_set(example, variant, seeds, spp, width, out):
    """The images of a variant, seeds 1..seeds (rendered where missing), as arrays."""
    import granular_core as core
    stage, extra = variant_args(example, variant, out)
    name = os.path.basename(example)[:-5]
    images = []
    for seed in range(1, seeds + 1):
        path = os.path.join(out, f"{name}_{variant}_{spp}spp_{width}px_{seed}.exr")
        if not os.path.exists(path):
            subprocess.run([GRANULAR, "render", stage, "-o", path, "--width", str(width), "--spp", str(spp),
                            "--seed", str(seed), "--quiet", *extra], check=True, stdout=subprocess.DEVNULL)
        im = core.read_exr(path)
        images.append((np.asarray(im.pixels, dtype=np.float64), list(im.channels)))
        print(f"  {name} {variant} seed {seed}", file=sys.stderr, end="\r", flush=True)
    print(" " * 60, file=sys.stderr, end="\r", flush=True)
    return images


def aggregate_pixels(images):
    """The pixels an aggregate covers in the first image of a set."""
    px, ch = images[0]
    return px[..., ch.index("aggregateId")] >= 0


def tails(rgb, mask):
    """Per image and pixel, luminance over the mean of the other images': the percentiles,
    the largest, and the counts per image above 2.5 and 4."""
    lum = rgb @ LUMINANCE
    n = len(lum)
    others = (lum.sum(axis=0)[None] - lum) / (n - 1)
    ratio = (lum / np.maximum(others, 1e-9))[:, mask]
    return np.percentile(ratio, [99, 99.9, 99.99]), ratio.max(), (ratio > 2.5).sum() / n, (ratio > 4).sum() / n


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", default="macro,frosted")
    ap.add_argument("--variants", default="default,sun-20")
    ap.add_argument("--seeds", type=int, default=48)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--ref-seeds", type=int, default=16)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--no-ref", action="store_true", help="no bias, no RMS: the tails alone")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "bench", "fireflies"))
    a = ap.parse_args()
    os.makedirs(a.out, exist_ok=True)
    for name in a.examples.split(","):
        example = os.path.join(ROOT, "examples", f"{name}.usda")
        ref = None
        if not a.no_ref:
            images = render_set(example, "sun-5+ept", a.ref_seeds, a.ref_spp, a.width, a.out)
            ref = np.array([px[..., :3] for px, _ in images])
            mask = aggregate_pixels(images)
            ref_means = ref[:, mask].mean(axis=1)
            ref_lum = ref.mean(axis=0) @ LUMINANCE
        print(f"\n{name}: {a.width} px, {a.spp} spp, seeds 1–{a.seeds}" +
              ("" if ref is None else f"; reference: EPT under a 5° sun, {a.ref_spp} spp, {a.ref_seeds} seeds"))
        print("| variant | bias % R / G / B ± s.e. | p99 | p99.9 | p99.99 | largest | > 2.5× per image | "
              "> 4× per image | RMS (median) |")
        print("|---|---|---|---|---|---|---|---|---|")
        for variant in a.variants.split(","):
            images = render_set(example, variant, a.seeds, a.spp, a.width, a.out)
            rgb = np.array([px[..., :3] for px, _ in images])
            if ref is None:
                mask = aggregate_pixels(images)
            (p99, p999, p9999), largest, above25, above4 = tails(rgb, mask)
            bias = rms = "—"
            if ref is not None:
                means = rgb[:, mask].mean(axis=1)
                b = 100 * (means.mean(axis=0) / ref_means.mean(axis=0) - 1)
                se = 100 * np.hypot(means.std(axis=0, ddof=1) / np.sqrt(len(means)),
                                    ref_means.std(axis=0, ddof=1) / np.sqrt(len(ref_means))) / ref_means.mean(axis=0)
                bias = " / ".join(f"{x:+.2f}" for x in b) + " ± " + " / ".join(f"{x:.2f}" for x in se)
                rel = [np.sqrt(np.mean(((x @ LUMINANCE - ref_lum)[mask] / np.maximum(ref_lum[mask], 1e-6)) ** 2))
                       for x in rgb]
                rms = f"{100 * np.median(rel):.1f}%"
            print(f"| {variant} | {bias} | {p99:.2f} | {p999:.2f} | {p9999:.2f} | {largest:.2f} | {above25:.2f} | "
                  f"{above4:.2f} | {rms} |", flush=True)


if __name__ == "__main__":
    main()
