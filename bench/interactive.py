#!/usr/bin/env python3
"""Interactive speed of the Granular delegate through UsdImagingGLEngine (as a viewport
drives it), for each example at 640×480 on this machine: from opening the stage to the
first image covering the viewport (the coarsest preview) and to the first
full-resolution pass, with the teleportation-transport (TT) and tile caches cold and
warm; and from a camera move (once the full build has landed) to the next first image and
first pass. --set KEY=VALUE sets
a renderer setting (a JSON value), e.g. --set granular:switchForView=true, which adds a
column: from the camera move to the view's own switch taking over (its measurement is made
apart: granular:viewSwitchPending), with the cache cold (warm, the view was measured
before). "Longest frame": the longest engine.Render call after the move in either run,
what a viewport's camera waits for.

--usdview: a real usdview instead (testusdview under Xvfb, the Granular renderer, the
stage's camera, its 597×540 viewport): seconds from the usdview process's start to the
first grab of the viewport that is not blank ("first image"), and to the call of the
test script ("usdview up": the window open, the stage loaded and the first frame's
Hydra sync done, which builds the aggregates' stand-ins and starts their full builds), with an
empty GRANULAR_CACHE_DIR (cold:
tiles, TT parameters and aggregate builds computed) and then with the cache it filled;
the demo stage by default.

Runs with the OpenUSD build's Python (Debian's python3 and /opt/openusd/lib/python):
  PXR_PLUGINPATH_NAME=build/hdGranular/plugin:schemas PYTHONPATH=/opt/openusd/lib/python \\
  LD_LIBRARY_PATH=/opt/openusd/lib /usr/bin/python3 bench/interactive.py [--size 640x480] [EXAMPLE ...]
  ... bench/interactive.py --usdview [--runs 3] [EXAMPLE ...]
Prints a Markdown table. Each measurement runs in a fresh process (a new delegate).
This file is also testusdview's --testScript (testUsdviewInputFunction below).
"""
import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

try:
    ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
except NameError:  # run by testusdview, which needs no paths
    ROOT = None
EXAMPLES = ["snowslab", "sugarcube", "sandcastle", "mixture"]  # the demo stage too when named
USDVIEW_EXAMPLES = ["sandcastle_paper"]
TESTUSDVIEW = "/opt/openusd/bin/testusdview"


def _process_start():
    """This process's start as a time.time() value (from /proc: its start in clock ticks
    since boot, and the uptime now)."""
    with open("/proc/self/stat") as f:
        ticks = int(f.read().rsplit(")", 1)[1].split()[19])
    with open("/proc/uptime") as f:
        uptime = float(f.read().split()[0])
    return time.time() - (uptime - ticks / os.sysconf("SC_CLK_TCK"))


def _blank(image, grid=48):
    """Whether a viewport grab is blank: a grid of samples holds only a few colours
    (usdview's background, its axes and frame: 3 with the HUD off). A Granular image, even
    the coarsest preview, holds dozens to hundreds. (One colour covering most of the grid
    is no sign of a blank: a converged, evenly lit ground quantises to one colour, as the
    sugar cube's does over 66–71% of its viewport.)"""
    w, h = image.width(), image.height()
    if w == 0 or h == 0:
        return True
    colours = set()
    for y in range(grid):
        for x in range(grid):
            colours.add(image.pixel(int((x + 0.5) * w / grid), int((y + 0.5) * h / grid)) & 0xFFFFFF)
    return len(colours) < 16


def testUsdviewInputFunction(appController):
    """Inside testusdview (--usdview): grabs the viewport until it is not blank; writes the
    seconds since this process started to $GRANULAR_BENCH_USDVIEW_OUT (and that grab to
    $GRANULAR_BENCH_USDVIEW_SHOT when set)."""
    from pxr.Usdviewq.qt import QtWidgets
    start = _process_start()
    called = time.time() - start
    appController._dataModel.viewSettings.showHUD = False
    limit, shown, grabs = float(os.environ.get("GRANULAR_BENCH_USDVIEW_LIMIT", "600")), None, 0
    while time.time() - start < limit:
        QtWidgets.QApplication.processEvents()
        grabs += 1
        shot = appController.GrabViewportShot()
        if not _blank(shot):
            shown = time.time() - start
            if os.environ.get("GRANULAR_BENCH_USDVIEW_SHOT"):  # to check what counted as an image
                shot.save(os.environ["GRANULAR_BENCH_USDVIEW_SHOT"], "PNG")
            break
        time.sleep(0.01)
    with open(os.environ["GRANULAR_BENCH_USDVIEW_OUT"], "w") as f:
        json.dump({"renderer": appController._stageView.rendererDisplayName, "first_image": shown,
                   "script_called": called, "grabs": grabs}, f)


def usdview_first_image(path, cache, testusdview, limit):
    """One testusdview process on `path` with the cache folder `cache`: its report."""
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "report.json")
        env = dict(os.environ, GRANULAR_CACHE_DIR=cache, GRANULAR_BENCH_USDVIEW_OUT=out,
                   GRANULAR_BENCH_USDVIEW_LIMIT=str(limit))
        subprocess.run([shutil.which("xvfb-run"), "-a", "-s", "-screen 0 1280x800x24", "/usr/bin/python3", testusdview,
                        "--testScript", os.path.abspath(__file__), "--renderer", "Granular", "--camera",
                        "/World/Camera", path], env=env, check=True, timeout=limit + 120,
                       stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        with open(out) as f:
            r = json.load(f)
    if r["renderer"] != "Granular":
        raise SystemExit(f"usdview ran {r['renderer']!r}, not Granular (PXR_PLUGINPATH_NAME)")
    if r["first_image"] is None:
        raise SystemExit(f"{path}: no image in usdview within {limit} s")
    return r


def usdview_table(examples, runs, testusdview, limit):
    print("| stage (usdview, 597×540) | cold cache: usdview up (s) | cold cache: first image (s) | "
          "cached: usdview up (s) | cached: first image (s) |")
    print("|---|---|---|---|---|")
    for name in examples:
        path = os.path.join(ROOT, "examples", name + ".usda")
        cold, cached = [], []
        for _ in range(runs):
            with tempfile.TemporaryDirectory() as cache:
                cold.append(usdview_first_image(path, cache, testusdview, limit))
                cached.append(usdview_first_image(path, cache, testusdview, limit))

        def cell(reports, key):
            v = [r[key] for r in reports]
            return f"{statistics.median(v):.2f}" + (f" ({min(v):.2f}–{max(v):.2f})" if len(v) > 1 else "")
        print(f"| {name} | {cell(cold, 'script_called')} | {cell(cold, 'first_image')} | "
              f"{cell(cached, 'script_called')} | {cell(cached, 'first_image')} |", flush=True)


def _watch(engine, stage, params, t0, events, limit=600.0):
    """Renders frames until every event (a name and a test of the render stats) has been
    seen, at most `limit` seconds; returns the seconds from t0 to each, and the longest
    frame (one engine.Render call: what a viewport's camera waits for)."""
    seen, longest = {}, 0.0
    while len(seen) < len(events) and time.monotonic() - t0 < limit:
        t = time.monotonic()
        engine.Render(stage.GetPseudoRoot(), params)
        longest = max(longest, time.monotonic() - t)
        stats = engine.GetRenderStats()
        for name, test in events.items():
            if name not in seen and test(stats):
                seen[name] = time.monotonic() - t0
        time.sleep(0.002)
    missing = sorted(set(events) - set(seen))
    if missing:
        raise SystemExit(f"{', '.join(missing)} not seen within {limit} s")
    return seen, longest


def _reported(key):
    return lambda stats: stats.get(key, -1.0) >= 0


# The view's switch measured apart has landed (a build that measures it at each camera
# move has no such stat: at once).
_VIEW_SWITCH = {"view_switch": lambda stats: stats.get("granular:viewSwitchPending", False) is False}
_IMAGE_AND_PASS = {"image": _reported("granular:firstImageSeconds"), "pass": _reported("granular:firstPassSeconds")}


def measure(path, width, height, settings):
    """One process: open, first image, first pass; camera move, first image, first pass
    (and the view's switch, when it is measured)."""
    from pxr import CameraUtil, Gf, Usd, UsdGeom, UsdImagingGL
    t_open = time.monotonic()
    stage = Usd.Stage.Open(path)
    p = UsdImagingGL.Engine.Parameters()
    p.gpuEnabled = False
    engine = UsdImagingGL.Engine(p)
    if not engine.SetRendererPlugin("HdGranularRendererPlugin"):
        raise SystemExit("the Granular delegate was not found (PXR_PLUGINPATH_NAME)")
    engine.SetRendererSetting("convergedSamplesPerPixel", 16)
    for key, value in settings.items():
        engine.SetRendererSetting(key, value)
    engine.SetRenderBufferSize(Gf.Vec2i(width, height))
    engine.SetFraming(CameraUtil.Framing(Gf.Rect2i(Gf.Vec2i(0, 0), width, height)))
    engine.SetRendererAov("color")
    camera = UsdGeom.Camera(stage.GetPrimAtPath("/World/Camera")).GetCamera(Usd.TimeCode.Default())
    camera.SetPerspectiveFromAspectRatioAndFieldOfView(width / height, camera.GetFieldOfView(
        Gf.Camera.FOVHorizontal), Gf.Camera.FOVHorizontal)
    frustum = camera.frustum
    engine.SetCameraState(frustum.ComputeViewMatrix(), frustum.ComputeProjectionMatrix())
    params = UsdImagingGL.RenderParams()

    # The move comes once the full build has landed (not on stand-ins: a cold paper castle
    # finishes the stand-ins' first pass long before its build).
    built = {"built": lambda stats: stats.get("granular:fullBuildPending", False) is False}
    first, _ = _watch(engine, stage, params, t_open, dict(_IMAGE_AND_PASS, **built))
    # A small orbit step: the camera moves 0.05 units sideways.
    moved = Gf.Camera(camera)
    moved.transform = camera.transform * Gf.Matrix4d().SetTranslate(Gf.Vec3d(0.05, 0, 0))
    f = moved.frustum
    engine.SetCameraState(f.ComputeViewMatrix(), f.ComputeProjectionMatrix())
    view = bool(settings.get("granular:switchForView"))
    events = dict(_IMAGE_AND_PASS, **(_VIEW_SWITCH if view else {}))
    move, longest = _watch(engine, stage, params, time.monotonic(), events)
    out = {"first_image": first["image"], "first_pass": first["pass"], "move_first_image": move["image"],
           "move_first_pass": move["pass"], "move_longest_frame": longest}
    if view:
        out["move_view_switch"] = move["view_switch"]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("examples", nargs="*")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--usdview", action="store_true", help="time a real usdview (default stage: the demo)")
    ap.add_argument("--testusdview", default=TESTUSDVIEW)
    ap.add_argument("--runs", type=int, default=1, help="--usdview: cold and cached runs (median, range)")
    ap.add_argument("--limit", type=float, default=600.0, help="--usdview: seconds to wait for an image")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="a renderer setting, its value JSON (e.g. granular:switchForView=true)")
    ap.add_argument("--measure", help=argparse.SUPPRESS)  # internal: one process's measurement
    a = ap.parse_args()
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from accuracy_matrix import render_settings  # the benches' one --set parser
    settings = render_settings(ap, a.set)
    if a.usdview:
        usdview_table(a.examples or USDVIEW_EXAMPLES, a.runs, a.testusdview, a.limit)
        return 0
    width, height = (int(v) for v in a.size.split("x"))
    if a.measure:
        print(json.dumps(measure(a.measure, width, height, settings)))
        return 0
    view = bool(settings.get("granular:switchForView"))
    print(f"| example ({width}×{height}) | open → first image, TT cold (s) | open → first image, TT cached (s) | "
          "open → first full pass, cached (s) | camera move → first image (s) | camera move → first full pass (s) |"
          " camera move → longest frame (s) |" + (" camera move → the view's switch, cold (s) |" if view else ""))
    print("|---|---|---|---|---|---|---|" + ("---|" if view else ""))
    for name in a.examples or EXAMPLES:
        path = os.path.join(ROOT, "examples", name + ".usda")
        runs = {}
        with tempfile.TemporaryDirectory() as cache:
            for label in ("cold", "warm"):  # the second run finds what the first cached
                env = dict(os.environ, GRANULAR_CACHE_DIR=cache)
                cmd = [sys.executable, __file__, "--measure", path, "--size", a.size]
                for kv in a.set:
                    cmd += ["--set", kv]
                out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
                runs[label] = json.loads(out.strip().splitlines()[-1])
        c, w = runs["cold"], runs["warm"]
        print(f"| {name} | {c['first_image']:.2f} | {w['first_image']:.2f} | {w['first_pass']:.2f} | "
              f"{w['move_first_image']:.3f} | {w['move_first_pass']:.2f} | "
              f"{max(c['move_longest_frame'], w['move_longest_frame']):.3f} |"
              # The cold run's: the warm one finds the moved view's measurement cached.
              + (f" {c['move_view_switch']:.2f} |" if view else ""))
    return 0


# testusdview runs this file without a __name__.
if globals().get("__name__") == "__main__":
    sys.exit(main())
