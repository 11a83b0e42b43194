"""The stage the aggregate motion-blur tests render (test_aggregate_motion.py through granular
render; tests/hydra/usdrecord_aggregate_motion_blur.py through usdrecord as well): a floor, a
box of sand grains (an aggregate) sliding 2.4 units per 2 frames about frame 1 and optionally
turning, a dome and a sun, the camera's shutter open over `shutter` frames. Needs usd-core's
(or OpenUSD's) pxr, granular_core and the granular package (the schema)."""
from pxr import Gf, Usd, UsdGeom, UsdLux

import granular_core as core
from granular import schema

from motion_blur_stage import add_mesh

SAND = "/World/Sand"


def write_stage(path, time_codes_per_second=24, shutter=(-0.5, 0.5), turn=0.0):
    """The sand box at x = -1.2 at time 0 and +1.2 at time 2 (linear in between: at frame t
    exactly -1.2 + 1.2 t), turned by `turn` degrees about +y over those two frames. Returns
    str(path)."""
    stage = Usd.Stage.CreateNew(str(path))
    stage.SetTimeCodesPerSecond(time_codes_per_second)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(1)
    UsdGeom.Xform.Define(stage, "/World")
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateHorizontalApertureAttr(36.0)
    cam.CreateVerticalApertureAttr(24.0)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.01, 100))
    cam.CreateShutterOpenAttr(shutter[0])
    cam.CreateShutterCloseAttr(shutter[1])
    cam.AddTranslateOp().Set(Gf.Vec3d(0, 1.2, 3.2))
    cam.AddRotateXOp().Set(-20.0)
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(1.0)
    sun = UsdLux.DistantLight.Define(stage, "/World/Sun")
    sun.CreateIntensityAttr(2.0)
    sun.CreateNormalizeAttr(True)  # an irradiance of 2: as bright as the sky
    sun.CreateAngleAttr(30.0)
    UsdGeom.Xformable(sun).AddRotateXOp().Set(-130.0)  # from behind the sand: its shadow falls into view
    add_mesh(stage, "/World/Floor", core.make_box((-3, -0.1, -3), (3, 0, 3))).CreateDisplayColorAttr(
        [Gf.Vec3f(0.5, 0.5, 0.5)])
    UsdGeom.Scope.Define(stage, "/World/Grains")
    rock = add_mesh(stage, "/World/Grains/Rock", core.make_rock(1, 0.2, 2))
    schema.apply_grain(rock, ior=1.5, absorption=(0.1, 0.2, 0.4))
    box = add_mesh(stage, SAND, core.make_box((-0.35, 0, -0.35), (0.35, 0.7, 0.35)))
    schema.apply_aggregate(box, [rock], grain_radius=0.03, packing_rate=0.6, seed=3, tile_spheres=64)
    translate = box.AddTranslateOp()
    rotate = box.AddRotateYOp() if turn else None
    for t, x, angle in ((0, -1.2, 0.0), (2, 1.2, turn)):
        translate.Set(Gf.Vec3d(x, 0, 0), t)
        if rotate is not None:
            rotate.Set(angle, t)
    stage.GetRootLayer().Save()
    return str(path)
