#!/usr/bin/env python3
"""`make gallery`: every bundled USD example rendered by `granular render` into
out/gallery/NAME.exr and NAME.png, a contact sheet of them (out/gallery/contact_sheet.png,
in the order of the table it prints), and a small copy of the sheet for the README
(docs/gallery.png with --docs).

    .venv/bin/python scripts/gallery.py [--width 480] [--spp 64] [--out out/gallery] [--docs]

Prints a markdown table: example, grains, resolution, samples, render seconds. The
animated example contributes its first frame. Exits 1 if a render fails.
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

import granular_core as core

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = os.path.join(ROOT, "examples")


def box_downsample(pixels, factor):
    """Mean of factor x factor blocks (the image cropped to a multiple of factor)."""
    h, w = (pixels.shape[0] // factor) * factor, (pixels.shape[1] // factor) * factor
    p = pixels[:h, :w]
    return p.reshape(h // factor, factor, w // factor, factor, -1).mean(axis=(1, 3))


def contact_sheet(images, columns, cell_width):
    """Linear RGB images, each scaled to cell_width (box filter, integer factor), on a
    dark grey sheet with a 4-pixel gutter."""
    thumbs = []
    for img in images:
        factor = max(1, img.shape[1] // cell_width)
        thumbs.append(box_downsample(img, factor))
    cw = max(t.shape[1] for t in thumbs)
    ch = max(t.shape[0] for t in thumbs)
    rows = (len(thumbs) + columns - 1) // columns
    gutter = 4
    sheet = np.full((rows * (ch + gutter) + gutter, columns * (cw + gutter) + gutter, 3), 0.02, np.float32)
    for n, t in enumerate(thumbs):
        r, c = divmod(n, columns)
        y, x = gutter + r * (ch + gutter), gutter + c * (cw + gutter)
        sheet[y:y + t.shape[0], x:x + t.shape[1]] = t[..., :3]
    return sheet


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "gallery"))
    ap.add_argument("--docs", action="store_true", help="also write docs/gallery.png (a small contact sheet)")
    ap.add_argument("--granular", default=os.path.join(ROOT, ".venv", "bin", "granular"))
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)
    names = sorted(n[:-5] for n in os.listdir(EXAMPLES) if n.endswith(".usda"))
    print("| example | grains | resolution | spp | render (s) |")
    print("|---|---|---|---|---|")
    images = []
    for name in names:
        stage = os.path.join(EXAMPLES, name + ".usda")
        # The shot renders its frame 1: names with a frame number (####, written 0001).
        stem, frames = (name + ".####", ["--frames", "1:1"]) if name == "animated" else (name, [])
        out = os.path.join(args.out, stem)
        cmd = [args.granular, "render", stage, "-o", out + ".exr", "--png", out + ".png", "--width", str(args.width),
               "--spp", str(args.spp), "--quiet"] + frames
        exr = out.replace("####", "0001") + ".exr"
        t0 = time.perf_counter()
        r = subprocess.run(cmd, capture_output=True, text=True)
        seconds = time.perf_counter() - t0
        if r.returncode != 0:
            print(f"{name}: granular render failed:\n{r.stderr}", file=sys.stderr)
            return 1
        info = json.loads(subprocess.run([args.granular, "info", stage, "--json"], check=True, capture_output=True,
                                         text=True).stdout)
        grains = sum(a["grains"] for a in info["aggregates"])
        img = core.read_exr(exr)
        print(f"| {name} | {grains:.3g} | {img.width}×{img.height} | {args.spp} | {seconds:.1f} |", flush=True)
        images.append(np.asarray(img.pixels)[..., :3])
    sheet = contact_sheet(images, columns=3, cell_width=args.width // 2)
    path = os.path.join(args.out, "contact_sheet.png")
    core.write_png(path, core.Image(sheet, ["R", "G", "B"]))
    print(f"\ncontact sheet: {path} ({', '.join(names)}, left to right, top to bottom)")
    if args.docs:
        os.makedirs(os.path.join(ROOT, "docs"), exist_ok=True)
        small = contact_sheet(images, columns=3, cell_width=160)
        core.write_png(os.path.join(ROOT, "docs", "gallery.png"), core.Image(small, ["R", "G", "B"]))
        print(f"docs copy: {os.path.join(ROOT, 'docs', 'gallery.png')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
