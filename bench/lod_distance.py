#!/usr/bin/env python3
"""Level of detail as the camera recedes: time and error of the shortcut (RenderSettings
lod, core/ept.h) against the image without it, from grains 10 pixels wide to 0.01 pixel.

The scene is a ball of bright sand (radius 1, grain radius R, so about 0.6 / R^3 grains)
on a grey floor under a sun and a sky, built once; the camera then recedes along one
direction (Scene.set_view), so that a grain at the ball's near point spans W pixels.
At each distance, with the default integrator (hybrid, bundles of 16, tuned roulette) or
the one the options name:
  - the reference: no shortcut (lod 0), --ref-spp samples;
  - "off": no shortcut, --spp samples, another seed;
  - "on": lod 0.5 (the default), --spp samples, a third seed;
  - "all": every path takes the shortcut at its first grain (lod 1e9), as a volume would
    render it: the floor of what the shortcut can save.
Where the ball covers fewer pixels, only a window around it is rendered and every count of
samples is scaled up (up to 16x) so that rows have similar numbers of samples on sand;
times compare within a row.
Errors are over the pixels whose centre sees the ball (a ray-sphere test; the silhouette
is in them): bias is the relative difference of the masked mean from the reference's,
± its standard error from the pixel differences (which also holds the reference's noise);
relMSE is mean((x − ref)² / (ref² + 0.01)), the reference's noise included for both. The
equal-error speedup is relMSE·time off over relMSE·time on.

Usage: .venv/bin/python bench/lod_distance.py [--build build] [--out out/bench] [--spp 32]
       [--ref-spp 128] [--grain-radius 5e-4] [--widths 10,3,2,1,0.5,0.3,0.1,0.03,0.01]
       [--technique hybrid|ept+vpt] [--bundle-size 16]
Prints a markdown table; writes OUT/lod_distance_<technique>_b<bundle>.png when
matplotlib is available.
"""
import argparse
import json
import math
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

WIDTH, HEIGHT = 128, 96
FOCAL, H_APERTURE, V_APERTURE = 50.0, 36.0, 27.0
VIEW_DIR = np.array([0.45, 0.3, 1.0]) / np.linalg.norm([0.45, 0.3, 1.0])  # from the ball to the camera


def scene_json(R):
    return {
        "render": {"width": WIDTH, "height": HEIGHT, "spp": 1, "seed": 1, "sun_regularization": 0},  # the 5° sun exact
        "camera": {"look_at": {"eye": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0]},
                   "focal_length": FOCAL, "horizontal_aperture": H_APERTURE, "vertical_aperture": V_APERTURE},
        "materials": {
            "sand": {"type": "dielectric", "ior": 1.55, "absorption": [0.02, 0.035, 0.08]},
            "floor": {"type": "lambert", "albedo": [0.4, 0.38, 0.35]},
        },
        "meshes": [{"name": "floor", "shape": {"box": {"lo": [-200, -1.3, -200], "hi": [200, -1.0, 200]}},
                    "material": "floor"}],
        "lights": [
            {"name": "sun", "type": "distant", "direction": [-0.45, -0.8, -0.35], "angle": 5.0,
             "color": [1.0, 0.92, 0.8], "intensity": 6},
            {"name": "sky", "type": "dome", "color": [0.6, 0.75, 1.0], "intensity": 0.6},
        ],
        "aggregates": [{
            "name": "ball", "boundary": {"icosphere": {"subdivisions": 4}}, "grain_radius": R,
            "packing_rate": 0.6, "seed": 3,
            "prototypes": [{"name": "round", "shape": {"rock": {"subdivisions": 2, "roughness": 0.2, "seed": 1}},
                            "material": "sand"},
                           {"name": "flat", "shape": {"ellipsoid": {"radii": [1.0, 0.55, 0.8], "subdivisions": 2}},
                            "material": "sand"}],
            "weights": [0.6, 0.4],
        }],
    }


def pixel_angle():
    return (H_APERTURE / FOCAL) / WIDTH


def eye_for(grain_px, R):
    """The camera position where a grain (2R wide) at the ball's near point spans grain_px."""
    gap = 2 * R / (grain_px * pixel_angle())  # from the camera to the ball's surface
    return VIEW_DIR * (1.0 + gap), gap


def crop_for(eye):
    """The centred window (pixels) that holds the ball with a margin: beyond it there is
    only floor and sky, the same with and without the shortcut, so it is not rendered."""
    d = np.linalg.norm(eye)
    radius_px = math.tan(math.asin(1.0 / d)) / pixel_angle()
    side = 2 * math.ceil(1.25 * radius_px) + 4
    return min(WIDTH, side), min(HEIGHT, side)


def ball_mask(eye, w, h):
    """Pixels of a centred w x h window whose centre ray hits the unit sphere (the camera
    looks at the origin, up +Y)."""
    back = eye / np.linalg.norm(eye)
    right = np.cross([0.0, 1.0, 0.0], back)
    right /= np.linalg.norm(right)
    up = np.cross(back, right)
    xs = (2 * (np.arange(w) + 0.5) / w - 1) * 0.5 * H_APERTURE / FOCAL * (w / WIDTH)
    ys = (1 - 2 * (np.arange(h) + 0.5) / h) * 0.5 * V_APERTURE / FOCAL * (h / HEIGHT)
    d = xs[None, :, None] * right + ys[:, None, None] * up - back
    d /= np.linalg.norm(d, axis=2, keepdims=True)
    b = d @ eye
    c = eye @ eye - 1.0
    return b * b - c > 0  # the sphere is ahead: the camera is outside, looking at its centre


def render(core, built, desc, out, eye, gap, crop, spp, seed, lod, technique, bundle):
    d = json.loads(json.dumps(desc))
    d["camera"]["look_at"]["eye"] = [float(v) for v in eye]
    d["camera"]["clipping_range"] = [gap * 1e-3, 1e4]
    d["camera"]["horizontal_aperture"] = H_APERTURE * crop[0] / WIDTH
    d["camera"]["vertical_aperture"] = V_APERTURE * crop[1] / HEIGHT
    d["render"].update(width=crop[0], height=crop[1], spp=spp, seed=seed, lod=lod, technique=technique,
                       bundle_size=bundle)
    path = os.path.join(out, "lod_view.json")
    json.dump(d, open(path, "w"))
    view = core.load_scene_json(path)
    built.set_view(view.camera, view.settings)
    r = core.Renderer(built)
    t0 = time.perf_counter()
    r.render(spp)
    seconds = time.perf_counter() - t0
    img = r.image()
    rgb = img.pixels[..., [img.channels.index(c) for c in ("R", "G", "B")]].astype(np.float64)
    return rgb, seconds, r.shortcut_fraction


def errors(x, ref, mask):
    lx, lr = x[mask] @ [0.2126, 0.7152, 0.0722], ref[mask] @ [0.2126, 0.7152, 0.0722]
    diff = lx - lr
    bias = diff.mean() / lr.mean()
    se = diff.std(ddof=1) / math.sqrt(len(diff)) / lr.mean()
    relmse = float(np.mean((x[mask] - ref[mask]) ** 2 / (ref[mask] ** 2 + 0.01)))
    return bias, se, relmse


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--ref-spp", type=int, default=128)
    ap.add_argument("--grain-radius", type=float, default=5e-4)
    ap.add_argument("--widths", default="10,3,2,1,0.5,0.3,0.1,0.03,0.01", help="grain widths in pixels")
    ap.add_argument("--technique", default="hybrid", choices=["ept+vpt", "hybrid"])
    ap.add_argument("--bundle-size", type=int, default=16,
                    help="paths of a pixel traced in lock-step; 1: no bundle switching, so that without the "
                         "shortcut every grain is explicit")
    a = ap.parse_args()
    sys.path.insert(0, os.path.join(os.path.abspath(a.build), "python"))
    try:
        import granular_core as core
    except ImportError:
        sys.exit(f"granular_core not found in {a.build}/python: build first (make build)")
    os.makedirs(a.out, exist_ok=True)
    R = a.grain_radius
    desc = scene_json(R)
    path = os.path.join(a.out, "lod_ball.json")
    json.dump(desc, open(path, "w"), indent=1)
    t0 = time.perf_counter()
    built = core.Scene.build(core.load_scene_json(path))
    agg = built.aggregates[0]
    print(f"# ball of ~{agg['approx_grains']:.3g} grains (R = {R:g}) built in {time.perf_counter() - t0:.1f} s",
          file=sys.stderr)

    rows = []
    for w in (float(s) for s in a.widths.split(",")):
        eye, gap = eye_for(w, R)
        crop = crop_for(eye)
        mask = ball_mask(eye, *crop)
        if not mask.any():
            sys.exit(f"grains {w:g} px wide: no pixel centre sees the ball; use a smaller --grain-radius")
        scale = int(min(16, max(1, round(WIDTH * HEIGHT / mask.sum()))))
        spp, ref_spp = a.spp * scale, a.ref_spp * scale
        view = (core, built, desc, a.out, eye, gap, crop)
        how = (a.technique, a.bundle_size)
        ref, t_ref, _ = render(*view, ref_spp, 100, 0.0, *how)
        off, t_off, _ = render(*view, spp, 1, 0.0, *how)
        on, t_on, frac = render(*view, spp, 2, 0.5, *how)
        _, t_all, _ = render(*view, spp, 3, 1e9, *how)
        b_off, se_off, m_off = errors(off, ref, mask)
        b_on, se_on, m_on = errors(on, ref, mask)
        # Of the paths that met the sand, taken as the ball's share of the pixels (an
        # estimate: silhouette pixels are partly sand, so it may exceed 100% a little).
        sand_frac = frac / (mask.sum() / (crop[0] * crop[1]))
        rows.append(dict(w=w, gap=gap, ball=int(mask.sum()), image=f"{crop[0]}x{crop[1]}", spp=spp, t_off=t_off, t_on=t_on, t_all=t_all,
                         frac=sand_frac, b_off=b_off, se_off=se_off, b_on=b_on, se_on=se_on, m_off=m_off,
                         m_on=m_on))
        print(f"# grains {w:g} px: off {t_off:.1f} s, on {t_on:.1f} s, bias on {100 * b_on:+.2f}%", file=sys.stderr)

    print(f"## Level of detail as the camera recedes (ball of sand, R = {R:g}, {WIDTH}x{HEIGHT}, {a.technique}, "
          f"bundles of {a.bundle_size}, {a.spp}+ spp; reference: no shortcut, {a.ref_spp // a.spp}x the samples)\n")
    print("| grain width (px) | camera to sand | window | ball pixels | spp | sand paths shortcut | time off (s) | "
          "time on (s) | time all (s) | speedup | bias off | bias on | relMSE off | relMSE on | equal-error speedup |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        eq = (r["m_off"] * r["t_off"]) / (r["m_on"] * r["t_on"]) if r["m_on"] > 0 else float("nan")
        print(f"| {r['w']:g} | {r['gap']:.3g} | {r['image']} | {r['ball']} | {r['spp']} | {100 * r['frac']:.0f}% | {r['t_off']:.2f} | "
              f"{r['t_on']:.2f} | {r['t_all']:.2f} | {r['t_off'] / r['t_on']:.2f}× | "
              f"{100 * r['b_off']:+.2f}% ± {100 * r['se_off']:.2f} | {100 * r['b_on']:+.2f}% ± {100 * r['se_on']:.2f} | "
              f"{r['m_off']:.3g} | {r['m_on']:.3g} | {eq:.2f}× |")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("\n(matplotlib not installed: no plot; apt-get install python3-matplotlib)", file=sys.stderr)
        return
    ws = [r["w"] for r in rows]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    ax1.semilogx(ws, [r["t_off"] / r["t_on"] for r in rows], "s-", color="C1", label="lod 0.5")
    ax1.semilogx(ws, [r["t_off"] / r["t_all"] for r in rows], "^:", color="C2", label="every path shortcut")
    ax1.axhline(1.0, color="C0", label="no shortcut")
    ax1.set_xlabel("grain width (pixels)")
    ax1.set_ylabel("speedup over no shortcut (equal samples)")
    ax1.invert_xaxis()
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend()
    ax2.errorbar(ws, [100 * r["b_off"] for r in rows], [200 * r["se_off"] for r in rows], fmt="o-", capsize=3,
                 label="no shortcut")
    ax2.errorbar(ws, [100 * r["b_on"] for r in rows], [200 * r["se_on"] for r in rows], fmt="s-", capsize=3,
                 label="lod 0.5")
    ax2.axhspan(-3, 3, color="0.9", zorder=0)
    ax2.set_xscale("log")
    ax2.invert_xaxis()
    ax2.set_xlabel("grain width (pixels)")
    ax2.set_ylabel("bias of the ball's mean vs reference (%, ±2 s.e.)")
    ax2.grid(True, which="both", alpha=0.3)
    ax2.legend()
    fig.suptitle(f"Level of detail as the camera recedes ({a.technique}, bundles of {a.bundle_size})")
    fig.tight_layout()
    png = os.path.join(a.out, f"lod_distance_{a.technique.replace('+', '_')}_b{a.bundle_size}.png")
    fig.savefig(png, dpi=110)
    print(f"\nplot: {png}", file=sys.stderr)


if __name__ == "__main__":
    main()
