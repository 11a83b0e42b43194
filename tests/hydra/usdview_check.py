#!/usr/bin/env python3
"""A real usdview (testusdview under Xvfb) on each example with the Granular renderer:
its converged viewport against usdrecord of the same camera, samples and seed; then
the Granular menu's commands run through their menu actions (statistics of the
aggregate, density export to a VDB whose grid holds σ_t, the EPT-only toggle, whose
image must match `granular render --technique ept`). Screenshots go to OUTDIR. Prints
a table; exits 1 on any failure.

Usage: usdview_check.py TESTUSDVIEW USDRECORD GRANULAR OUTDIR EXAMPLE.usda:AGGREGATE ...
Runs testusdview and usdrecord with Debian's python3 and the OpenUSD build's
$GRANULAR_USD_PYTHONPATH, with $GRANULAR_HD_PLUGINPATH (the delegate, the schema and
usdview_plugins) and $GRANULAR_USDVIEW_PYTHONPATH (the plugin's Python).
"""
import json
import os
import shutil
import subprocess
import sys

import numpy as np
from usdrecord_run import run_usdrecord

import granular_core as core
from pxr import Usd, UsdGeom

WIDTH = 240


def srgb8(linear):
    c = np.clip(linear, 0.0, 1.0)
    s = np.where(c <= 0.0031308, 12.92 * c, 1.055 * np.power(c, 1 / 2.4) - 0.055)
    return np.floor(s * 255 + 0.5)


def _codes(path):
    # read_image_rgb decodes an sRGB PNG to linear values; encode every image the same way.
    return srgb8(np.asarray(core.read_image_rgb(path).pixels)[..., :3])


def agreement(grab_png, reference, other_seed):
    """The grab against a reference render of the same samples, judged by the noise of two
    seeds: (bias of the mean, median |code difference| grab vs reference, the same for
    two seeds). Rays from usdview's camera differ from usdrecord's by float rounding, and
    in grains a tiny difference makes another path: pixels differ by noise, not by more.
    Medians ignore the world axes usdview draws over the image."""
    grab, ref, other = _codes(grab_png), _codes(reference), _codes(other_seed)
    if grab.shape != ref.shape:
        return float("inf"), float("inf"), 0.0
    bias = (grab.mean() - ref.mean()) / max(ref.mean(), 1e-6)
    return float(bias), float(np.median(np.abs(grab - ref))), float(np.median(np.abs(other - ref)))


def main():
    testusdview, usdrecord, granular, outdir, *cases = sys.argv[1:]
    os.makedirs(outdir, exist_ok=True)
    usd_env = dict(os.environ)
    usd_env["PYTHONPATH"] = os.environ["GRANULAR_USDVIEW_PYTHONPATH"]
    usd_env["PXR_PLUGINPATH_NAME"] = os.environ["GRANULAR_HD_PLUGINPATH"]
    xvfb = shutil.which("xvfb-run")
    failed = []
    print("| example | converged image in usdview (s) | viewport vs usdrecord (8-bit sRGB) | "
          "EPT toggle vs granular render --technique ept | menu commands |")
    print("|---|---|---|---|---|")
    for case in cases:
        scene, aggregate = case.split(":")
        name = os.path.splitext(os.path.basename(scene))[0]
        stage = Usd.Stage.Open(scene)  # kept: a prim of a freed stage is invalid
        cam = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera"))
        # The camera's aspect, as usdrecord sizes its image (truncated).
        HEIGHT = int(WIDTH * cam.GetVerticalApertureAttr().Get() / cam.GetHorizontalApertureAttr().Get())
        env = dict(usd_env, GRANULAR_USDVIEW_OUT=outdir, GRANULAR_USDVIEW_NAME=name,
                   GRANULAR_USDVIEW_SIZE=f"{WIDTH},{HEIGHT}", GRANULAR_USDVIEW_AGGREGATE=aggregate)
        report_path = os.path.join(outdir, name + ".json")
        if os.path.exists(report_path):
            os.remove(report_path)
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "usdview_script.py")
        subprocess.run([xvfb, "-a", "-s", "-screen 0 1280x800x24", "/usr/bin/python3", testusdview,
                        "--testScript", script, "--renderer", "Granular", scene],
                       env=env, check=True, timeout=1200, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        with open(report_path) as f:
            r = json.load(f)

        hydra = os.path.join(outdir, name + "_usdrecord.exr")
        run_usdrecord(["/usr/bin/python3", usdrecord, "--disableGpu", "--renderer", "Granular",
                       "--enableDomeLightVisibility", "--imageWidth", str(WIDTH), "--camera", "/World/Camera",
                       scene, hydra], [hydra], env=usd_env, timeout=1200, stdout=subprocess.DEVNULL)
        renders = {}
        # The EPT toggle is compared with the sun exact on both sides (the script sets the
        # delegate's granular:sunRegularization to 0 before it): explicit grains' widened glints
        # exceed 1 in about 1% of pixels, and usdview presents the float buffer filtered, which
        # spreads them into their neighbours before its 8-bit grab clips them (3% on the snow
        # slab's mean code). The delegate hands the setting to the same core as granular
        # render (test_hdgranular.cpp: SunRegularization...).
        for technique, seed in (("hybrid", 1), ("ept", 0), ("ept", 1)):
            path = renders[technique, seed] = os.path.join(outdir, f"{name}_granular_{technique}_seed{seed}.exr")
            exact = ["--sun-regularization", "0"] if technique == "ept" else []
            subprocess.run([granular, "render", scene, "-o", path, "--width", str(WIDTH), "--height", str(HEIGHT),
                            "--spp", "16", "--technique", technique, "--seed", str(seed), "--camera",
                            "/World/Camera", "--quiet", *exact], check=True, timeout=1200)
        hyb = agreement(os.path.join(outdir, name + "_hybrid.png"), hydra, renders["hybrid", 1])
        ept = agreement(os.path.join(outdir, name + "_ept.png"), renders["ept", 0], renders["ept", 1])

        info = json.loads(subprocess.run([granular, "info", scene, "--json"], check=True, capture_output=True,
                                         text=True).stdout)
        sigma_t = [sum(a["rte"]["sigma_t"]) / 3 for a in info["aggregates"] if a["prim"] == aggregate]
        messages = {title: text for kind, title, text in r["messages"] if kind == "info"}
        stats = messages.get("Granular statistics", "")
        export = messages.get("Export coarse density", "")
        grid = float(export.split("= ")[1].split(" ")[0]) if "= " in export else float("nan")
        checks = {
            "renderer is Granular": r["renderer"] == "Granular",
            "converged": r["converged"] and r.get("ept_converged", False),
            "menu has the four commands": r["menu"] == ["Export Coarse Density to VDB...", "Light Links of Selected Light",
                                                        "Statistics of Selected Prim", "Toggle EPT-only Reference"],
            "statistics name the aggregate": stats.startswith(aggregate + "\n") and "sigma_t" in stats,
            "VDB written with grid density": bool(r["vdb"]) and [g["name"] for g in core.read_vdb_grids(r["vdb"])]
            == ["density"],
            "the grid holds sigma_t": bool(sigma_t) and abs(grid - sigma_t[0]) <= 1e-4 * sigma_t[0],
            "toggle sets technique ept": r.get("technique_after_toggle") == "ept",
            # Same samples: no bias beyond 8-bit rounding, differences no larger than noise.
            "viewport matches usdrecord": abs(hyb[0]) <= 0.01 and hyb[1] <= hyb[2] + 1,
            "EPT viewport matches granular render": abs(ept[0]) <= 0.01 and ept[1] <= ept[2] + 1,
        }
        bad = [k for k, ok in checks.items() if not ok]
        print(f"| {name} | {r['seconds']:.2f} | bias {100 * hyb[0]:+.2f}%, median {hyb[1]:.0f} codes "
              f"(two seeds: {hyb[2]:.0f}) | bias {100 * ept[0]:+.2f}%, median {ept[1]:.0f} codes (two seeds: "
              f"{ept[2]:.0f}) | {'ok' if not bad else 'FAILED: ' + ', '.join(bad)} |")
        if bad:
            failed.append(name)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
