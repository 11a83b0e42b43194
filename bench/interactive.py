#!/usr/bin/env python3
"""Interactive speed of the Granular delegate through UsdImagingGLEngine (as a viewport
drives it), for each example at 640×480 on this machine: from opening the stage to the
first image covering the viewport (the coarsest preview) and to the first
full-resolution pass, with the teleportation-transport (TT) and tile caches cold and
warm; and from a camera move to the next first image and first pass.

Runs with the OpenUSD build's Python (Debian's python3 and /opt/openusd/lib/python):
  PXR_PLUGINPATH_NAME=build/hdGranular/plugin:schemas PYTHONPATH=/opt/openusd/lib/python \\
  LD_LIBRARY_PATH=/opt/openusd/lib /usr/bin/python3 bench/interactive.py [--size 640x480] [EXAMPLE ...]
Prints a Markdown table. Each measurement runs in a fresh process (a new delegate).
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLES = ["snowslab", "sugarcube", "sandcastle", "mixture"]


def _until(engine, stage, params, key, limit=600.0):
    """Renders frames until the stat `key` is set (>= 0), at most `limit` seconds."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < limit:
        engine.Render(stage.GetPseudoRoot(), params)
        if engine.GetRenderStats().get(key, -1.0) >= 0:
            return
        time.sleep(0.002)
    raise SystemExit(f"{key} not reported within {limit} s")


def measure(path, width, height):
    """One process: open, first image, first pass; camera move, first image, first pass."""
    from pxr import CameraUtil, Gf, Usd, UsdGeom, UsdImagingGL
    t_open = time.monotonic()
    stage = Usd.Stage.Open(path)
    p = UsdImagingGL.Engine.Parameters()
    p.gpuEnabled = False
    engine = UsdImagingGL.Engine(p)
    if not engine.SetRendererPlugin("HdGranularRendererPlugin"):
        raise SystemExit("the Granular delegate was not found (PXR_PLUGINPATH_NAME)")
    engine.SetRendererSetting("convergedSamplesPerPixel", 16)
    engine.SetRenderBufferSize(Gf.Vec2i(width, height))
    engine.SetFraming(CameraUtil.Framing(Gf.Rect2i(Gf.Vec2i(0, 0), width, height)))
    engine.SetRendererAov("color")
    camera = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera")).GetCamera(Usd.TimeCode.Default())
    camera.SetPerspectiveFromAspectRatioAndFieldOfView(width / height, camera.GetFieldOfView(
        Gf.Camera.FOVHorizontal), Gf.Camera.FOVHorizontal)
    frustum = camera.frustum
    engine.SetCameraState(frustum.ComputeViewMatrix(), frustum.ComputeProjectionMatrix())
    params = UsdImagingGL.RenderParams()

    def first_image_and_pass(t0):
        """Seconds from t0 to the first image and to the first full pass of this view."""
        _until(engine, stage, params, "granular:firstImageSeconds")
        image = time.monotonic() - t0
        _until(engine, stage, params, "granular:firstPassSeconds")
        return image, time.monotonic() - t0

    first, full = first_image_and_pass(t_open)
    # A small orbit step: the camera moves 0.05 units sideways.
    moved = Gf.Camera(camera)
    moved.transform = camera.transform * Gf.Matrix4d().SetTranslate(Gf.Vec3d(0.05, 0, 0))
    f = moved.frustum
    engine.SetCameraState(f.ComputeViewMatrix(), f.ComputeProjectionMatrix())
    move_first, move_full = first_image_and_pass(time.monotonic())
    return {"first_image": first, "first_pass": full, "move_first_image": move_first, "move_first_pass": move_full}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("examples", nargs="*", default=EXAMPLES)
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--measure", help=argparse.SUPPRESS)  # internal: one process's measurement
    a = ap.parse_args()
    width, height = (int(v) for v in a.size.split("x"))
    if a.measure:
        print(json.dumps(measure(a.measure, width, height)))
        return 0
    print(f"| example ({width}×{height}) | open → first image, TT cold (s) | open → first image, TT cached (s) | "
          "open → first full pass, cached (s) | camera move → first image (s) | camera move → first full pass (s) |")
    print("|---|---|---|---|---|---|")
    for name in a.examples:
        path = os.path.join(ROOT, "examples", name + ".usda")
        runs = {}
        with tempfile.TemporaryDirectory() as cache:
            for label in ("cold", "warm"):  # the second run finds what the first cached
                env = dict(os.environ, GRANULAR_CACHE_DIR=cache)
                out = subprocess.run([sys.executable, __file__, "--measure", path, "--size", a.size], env=env,
                                     check=True, capture_output=True, text=True).stdout
                runs[label] = json.loads(out.strip().splitlines()[-1])
        c, w = runs["cold"], runs["warm"]
        print(f"| {name} | {c['first_image']:.2f} | {w['first_image']:.2f} | {w['first_pass']:.2f} | "
              f"{w['move_first_image']:.3f} | {w['move_first_pass']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
