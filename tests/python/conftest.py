"""Shared fixtures of the Python suite: a small valid stage to break in each error test,
and ways to run the `granular` command (in-process, and as the installed script)."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
BUILD = Path(os.environ.get("GRANULAR_BUILD_DIR", ROOT / "build"))
# The venv's .pth file provides these; repeat them so that `pytest` works from any venv
# where the module was built.
for p in (ROOT / "python", BUILD / "python"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))
# Tiles and grain transport are cached on disk: keep the tests' cache in the build tree
# (as ctest does), so that a second run is quick and nothing is written to ~/.cache.
os.environ.setdefault("GRANULAR_CACHE_DIR", str(BUILD / "cache"))

import granular  # noqa: E402  (registers the schema plugin before pxr builds its registry)
import granular_core as core  # noqa: E402,F401  (fails loudly if the module is not built)
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdRender, Vt  # noqa: E402

from granular import schema  # noqa: E402
from granular.cli import main as cli_main  # noqa: E402
from motion_blur_stage import add_mesh  # noqa: E402,F401  (the tests' mesh from core's)

EXAMPLES = ROOT / "examples"
GRANULAR = Path(sys.executable).parent / "granular"


def dome_world(path):
    """A new stage at `path` with /World, /World/Camera 15 units up +z looking down -z, and a
    uniform dome /World/Sky: what the instancer tests put their prims into."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 0, 15))
    UsdLux.DomeLight.Define(stage, "/World/Sky")
    return stage


def floor_world(path):
    """A new stage at `path` with /World, /World/Camera 15 units up +z looking down -z, and a
    grey floor /World/Floor (60 x 60, at z = 0) filling its view; no light."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 0, 15))
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-30, -30, 0), (30, -30, 0), (30, 30, 0), (-30, 30, 0)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    return stage


def dome_card(path, color=(0.5, 0.5, 0.5)):
    """A Lambert card of displayColor `color` filling the view of /Camera under a uniform
    dome: every sample of a pixel carries nearly the same radiance (little noise)."""
    stage = Usd.Stage.CreateNew(str(path))
    cam = UsdGeom.Camera.Define(stage, "/Camera")
    UsdGeom.Xformable(cam).AddTranslateOp().Set(Gf.Vec3d(0, 0, 5))
    UsdLux.DomeLight.Define(stage, "/Sky")
    card = UsdGeom.Mesh.Define(stage, "/Card")
    card.CreatePointsAttr(Vt.Vec3fArray([(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)]))
    card.CreateFaceVertexCountsAttr([4])
    card.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    card.CreateDisplayColorAttr([color])
    stage.Save()
    return str(path)


def small_scene(path, mutate=None):
    """A valid one-aggregate stage at `path`: /World/Castle (a box of two grain types,
    /World/Grains/A and /World/Grains/B), /World/Camera, /World/Sun; mutate(stage) edits
    it before it is saved. Renders in well under a second at 48x32, 1 spp."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.Xform.Define(stage, "/World")
    UsdGeom.Scope.Define(stage, "/World/Grains")
    a = add_mesh(stage, "/World/Grains/A", core.make_icosphere(1))
    b = add_mesh(stage, "/World/Grains/B", core.make_rock(1, 0.2, 3))
    schema.apply_grain(a, ior=1.5, absorption=(0.2, 0.3, 0.5))
    schema.apply_grain(b, ior=1.31)
    box = add_mesh(stage, "/World/Castle", core.make_box((-0.2, 0.0, -0.2), (0.2, 0.3, 0.2)))
    schema.apply_aggregate(box, [a, b], grain_radius=0.03, packing_rate=0.5, weights=[0.7, 0.3], seed=3,
                           tile_spheres=64)
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(35.0)
    m = Gf.Matrix4d().SetLookAt(Gf.Vec3d(1.0, 0.8, 1.2), Gf.Vec3d(0, 0.15, 0), Gf.Vec3d(0, 1, 0)).GetInverse()
    UsdGeom.Xformable(cam).AddTransformOp().Set(m)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(5.0)
    UsdGeom.Xformable(sun).AddRotateXOp().Set(-60.0)
    if mutate is not None:
        mutate(stage)
    stage.GetRootLayer().Save()
    return path


@pytest.fixture
def scene_file(tmp_path):
    """small_scene in tmp_path; call with mutate to break it."""
    def make(mutate=None, name="scene.usda"):
        return small_scene(tmp_path / name, mutate)
    return make


def run_cli(argv, capsys):
    """granular in-process: (exit status, stdout, stderr)."""
    rc = cli_main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return rc, out, err


def run_script(argv, **kw):
    """The installed `granular` console script as a subprocess."""
    exe = [str(GRANULAR)] if GRANULAR.exists() else [sys.executable, "-m", "granular.cli"]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "python"), str(BUILD / "python")])
    return subprocess.run(exe + [str(a) for a in argv], capture_output=True, text=True, env=env, **kw)
