"""The stage the motion-blur tests of both front ends render (test_motion_blur_switches.py
through granular render; tests/hydra/usdrecord_motion_blur.py through usdrecord as well):
a floor, a box sliding 1.2 units and turning 45 degrees per frame about frame 1, a dome and
a sun, the camera's shutter open over `shutter` frames, and optionally an active render
settings prim with one product. Needs only usd-core's (or OpenUSD's) pxr and granular_core."""
from pxr import Gf, Usd, UsdGeom, UsdLux, UsdRender, Vt

import granular_core as core


def add_mesh(stage, path, tri, translate=None):
    """A UsdGeom.Mesh of core's triangle mesh `tri`, moved by `translate`."""
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, p)) for p in tri.points]))
    idx = [int(i) for i in tri.indices]
    m.CreateFaceVertexIndicesAttr(Vt.IntArray(idx))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([3] * (len(idx) // 3)))
    if translate is not None:
        UsdGeom.Xformable(m).AddTranslateOp().Set(Gf.Vec3d(*translate))
    return m


def write_stage(path, time_codes_per_second=24, shutter=(-0.5, 0.5), settings=None, product=None,
                product_name=None, resolution=None, extra=None):
    """`settings`, `product`: attributes authored on /Render/Settings and on its one product
    /Render/Main, written to `product_name` (None: no such prim). `extra(stage)` adds prims
    before the stage is saved. Returns str(path)."""
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
    UsdLux.DistantLight.Define(stage, "/World/Sun").CreateIntensityAttr(2.0)
    add_mesh(stage, "/World/Floor", core.make_box((-3, -0.1, -3), (3, 0, 3))).CreateDisplayColorAttr(
        [Gf.Vec3f(0.5, 0.5, 0.5)])
    box = add_mesh(stage, "/World/Box", core.make_box((-0.35, 0, -0.35), (0.35, 0.7, 0.35)))
    box.CreateDisplayColorAttr([Gf.Vec3f(0.9, 0.3, 0.1)])
    translate, rotate = box.AddTranslateOp(), box.AddRotateYOp()
    for t, x, angle in ((0, -1.2, 0.0), (2, 1.2, 90.0)):
        translate.Set(Gf.Vec3d(x, 0, 0), t)
        rotate.Set(angle, t)
    if extra is not None:
        extra(stage)
    if settings is not None:
        rs = UsdRender.Settings.Define(stage, "/Render/Settings")
        if resolution is not None:
            rs.CreateResolutionAttr(Gf.Vec2i(*resolution))
        rs.CreateCameraRel().SetTargets(["/World/Camera"])
        for name, value in settings.items():
            rs.GetPrim().GetAttribute(name).Set(value)
        if product is not None:
            p = UsdRender.Product.Define(stage, "/Render/Main")
            p.CreateProductNameAttr(product_name)
            var = UsdRender.Var.Define(stage, "/Render/Vars/color")
            var.CreateSourceNameAttr("color")
            var.CreateDataTypeAttr("color4f")
            p.CreateOrderedVarsRel().SetTargets([var.GetPath()])
            for name, value in product.items():
                p.GetPrim().GetAttribute(name).Set(value)
            rs.CreateProductsRel().SetTargets([p.GetPath()])
        stage.SetMetadata("renderSettingsPrimPath", "/Render/Settings")
    stage.GetRootLayer().Save()
    return str(path)
