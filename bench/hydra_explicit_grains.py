#!/usr/bin/env python3
"""Explicit grains through both USD front ends: what a PointInstancer of N simulated grains
costs `usdrecord --renderer Granular` (hdGranular: Hydra's sync of the instancer and its
prototypes, the delegate's reading into core's InstancedGrainsDesc, the scene build and the
render) against `granular render` (usd-core) on the same stage, and whether their images
agree.

    .venv/bin/python bench/hydra_explicit_grains.py USDRECORD GRANULAR COMPARE OUTDIR [--grains 1e4,1e5,1e6]

USDRECORD runs with the OpenUSD build's Python, $GRANULAR_USD_PYTHONPATH and
$GRANULAR_HD_PLUGINPATH as for tests/hydra/usdrecord_vs_granular.py; COMPARE is
build/bench/granular-compare. The stage (.usdc, written with usd-core): N absorbing octahedral
grains of two prototypes with GranularGrainAPI on a jittered lattice in a cube, under a sky, seen
whole by /World/Camera; 48 x 48 pixels at the delegate's 16 samples, seed 0. Times are each
process's wall clock (start-up included: a stage without grains gives the floor). Prints a
markdown table.
"""
import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "hydra"))
from usdrecord_run import run_usdrecord  # noqa: E402

WIDTH, SPP = 48, 16
OCTA_FACES = [0, 2, 4, 2, 1, 4, 1, 3, 4, 3, 0, 4, 2, 0, 5, 1, 2, 5, 3, 1, 5, 0, 3, 5]


def write_stage(path, n, seed=1):
    """n grains (0: none) in a cube of side 2 about the origin, 0.4 of a lattice spacing wide."""
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.Xform.Define(stage, "/World")
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateHorizontalApertureAttr(20.0)
    cam.CreateVerticalApertureAttr(20.0)
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 0, 6))
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    if n:
        side = int(np.ceil(n ** (1.0 / 3.0)))
        spacing = 2.0 / side
        rng = np.random.default_rng(seed)
        i = np.arange(n)
        grid = np.stack([i % side, (i // side) % side, i // (side * side)], 1).astype(np.float32)
        pos = (grid + 0.5) * spacing - 1.0 + rng.uniform(-0.05, 0.05, (n, 3)).astype(np.float32) * spacing
        q = rng.normal(size=(n, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        pi = UsdGeom.PointInstancer.Define(stage, "/World/Sim")
        pi.GetPrim().AddAppliedSchema("GranularInstancedAggregateAPI")
        pi.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(pos))
        pi.CreateOrientationsAttr(Vt.QuathArray([Gf.Quath(*map(float, x)) for x in q]))
        pi.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy((rng.uniform(size=n) < 0.3).astype(np.int32)))
        for k, (name, r, ior) in enumerate((("Round", 0.4, 1.5), ("Small", 0.3, 1.31))):
            mesh = UsdGeom.Mesh.Define(stage, f"/World/Sim/Protos/{name}")
            s = r * spacing
            mesh.CreatePointsAttr([(s, 0, 0), (-s, 0, 0), (0, s, 0), (0, -s, 0), (0, 0, s), (0, 0, -s)])
            mesh.CreateFaceVertexCountsAttr([3] * 8)
            mesh.CreateFaceVertexIndicesAttr(OCTA_FACES)
            mesh.GetPrim().AddAppliedSchema("GranularGrainAPI")
            primvars = UsdGeom.PrimvarsAPI(mesh)
            primvars.CreatePrimvar("granular:ior", Sdf.ValueTypeNames.Float).Set(ior)
            # Absorbing: clear glass under a uniform sky is a white furnace (radiance 1 everywhere).
            primvars.CreatePrimvar("granular:absorption", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(2, 4, 8))
            pi.GetPrototypesRel().AddTarget(mesh.GetPath())
    stage.GetRootLayer().Save()


def timed(cmd, outputs, env=None, usdrecord=False):
    t0 = time.perf_counter()
    if usdrecord:
        run_usdrecord(cmd, outputs, env=env)
    else:
        subprocess.run(cmd, check=True, capture_output=True, env=env)
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("usdrecord")
    ap.add_argument("granular")
    ap.add_argument("compare")
    ap.add_argument("outdir")
    ap.add_argument("--grains", default="1e4,1e5,1e6")
    args = ap.parse_args()
    os.makedirs(args.outdir, exist_ok=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.environ.get("GRANULAR_USD_PYTHONPATH", "")
    env["PXR_PLUGINPATH_NAME"] = os.environ.get("GRANULAR_HD_PLUGINPATH", "")
    print("| grains | usdrecord (hdGranular) s | granular render s | relMSE Hydra vs granular (same seed) | "
          "relMSE granular, two seeds |")
    print("|---|---|---|---|---|")
    for n in [0] + [int(float(x)) for x in args.grains.split(",")]:
        stage = os.path.join(args.outdir, f"grains_{n}.usdc")
        write_stage(stage, n)
        hydra, ours, other = (os.path.join(args.outdir, f"grains_{n}_{k}.exr") for k in ("hydra", "granular", "seed1"))
        t_hydra = timed([args.usdrecord, "--disableGpu", "--renderer", "Granular", "--enableDomeLightVisibility", "--imageWidth", str(WIDTH),
                         "--camera", "/World/Camera", stage, hydra], [hydra], env=env, usdrecord=True)
        common = [args.granular, "render", stage, "--width", str(WIDTH), "--height", str(WIDTH), "--spp", str(SPP),
                  "--camera", "/World/Camera", "--quiet"]
        t_cli = timed(common + ["-o", ours, "--seed", "0"], [ours])
        timed(common + ["-o", other, "--seed", "1"], [other])
        same = json.loads(subprocess.run([args.compare, hydra, ours], check=True, capture_output=True,
                                         text=True).stdout)
        noise = json.loads(subprocess.run([args.compare, other, ours], check=True, capture_output=True,
                                          text=True).stdout)
        print(f"| {n:.0e} | {t_hydra:.2f} | {t_cli:.2f} | {same['relmse']:.3g} | {noise['relmse']:.3g} |",
              flush=True)


if __name__ == "__main__":
    main()
