"""What a stage means is decided once, in core (core/usd_*.h); usd_reader.py only reads.
These check core's USD rules against usd-core's own where USD defines the behaviour."""
import pytest
from pxr import UsdLux

import granular_core as core


@pytest.mark.parametrize("kelvin", [1000, 1500, 2000, 2700, 3000, 4000, 5000, 6500, 8000, 10000, 20000])
def test_blackbody_matches_usdlux_within_its_table_interpolation(kelvin):
    """core integrates Planck's law against the CIE observer; UsdLux interpolates a table
    of the same in 500 K steps. They agree to 2% of the largest component."""
    ours = core.blackbody_rgb(kelvin)
    usd = UsdLux.BlackbodyTemperatureAsRgb(kelvin)
    scale = max(usd)
    for a, b in zip(ours, usd):
        assert abs(a - b) <= 0.02 * scale, (kelvin, tuple(ours), tuple(usd))


def test_light_attribute_names_are_usdlux_attributes():
    """Every attribute core reads exists on some UsdLux light schema (a typo would read nothing)."""
    from pxr import Usd
    stage = Usd.Stage.CreateInMemory()
    prims = [UsdLux.DistantLight.Define(stage, "/D"), UsdLux.DomeLight.Define(stage, "/Dome"),
             UsdLux.RectLight.Define(stage, "/R"), UsdLux.SphereLight.Define(stage, "/S"),
             UsdLux.DiskLight.Define(stage, "/Disk"), UsdLux.CylinderLight.Define(stage, "/C")]
    UsdLux.ShapingAPI.Apply(prims[3].GetPrim())
    UsdLux.ShadowAPI.Apply(prims[3].GetPrim())
    names = set()
    for p in prims:
        names |= {a.GetName() for a in p.GetPrim().GetAttributes()}
    missing = [n for n in core.usd_light_attribute_names() if n not in names]
    assert not missing
    cam = stage.DefinePrim("/Cam", "Camera")
    assert not [n for n in core.usd_camera_attribute_names() if not cam.GetAttribute(n)]
