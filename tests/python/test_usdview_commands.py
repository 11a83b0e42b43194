"""The usdview plugin's commands, without a GUI (usdview_plugins/granularUsdview/commands.py)."""
import sys

import pytest
from pxr import Usd

from conftest import EXAMPLES, ROOT, small_scene

sys.path.insert(0, str(ROOT / "usdview_plugins"))
from granularUsdview import commands  # noqa: E402

import granular_core as core  # noqa: E402
from granular.errors import UserError  # noqa: E402


def test_statistics_of_a_selected_aggregate_and_of_its_parent():
    stage = Usd.Stage.Open(str(EXAMPLES / "snowslab.usda"))
    text = commands.statistics_text(stage, ["/World/Snow"])
    assert text.splitlines()[0] == "/World/Snow"
    assert "grains" in text and "sigma_t" in text and "mean free path" in text
    # Selecting the parent finds the aggregate below it; the numbers are the same.
    assert commands.statistics_text(stage, ["/World"]) == text


def test_statistics_reflect_unsaved_edits_of_the_open_stage(tmp_path):
    path = tmp_path / "s.usda"
    small_scene(path)
    stage = Usd.Stage.Open(str(path))
    before = commands.statistics_text(stage, ["/World/Castle"])
    stage.GetPrimAtPath("/World/Castle").GetAttribute("primvars:granular:packingRate").Set(0.3)
    after = commands.statistics_text(stage, ["/World/Castle"])
    assert "packing rate 0.3" in after and after != before


def test_nothing_granular_selected_says_so():
    stage = Usd.Stage.Open(str(EXAMPLES / "snowslab.usda"))
    assert commands.statistics_text(stage, ["/World/Ground"]).startswith("No granular aggregate selected")


def test_light_links_list_what_each_selected_light_lights(tmp_path):
    from pxr import UsdGeom, UsdLux

    def mutate(stage):
        UsdGeom.Cube.Define(stage, "/World/Block")
        UsdLux.LightAPI(stage.GetPrimAtPath("/World/Sun")).GetLightLinkCollectionAPI().GetExcludesRel().AddTarget(
            "/World/Block")
        sky = UsdLux.DomeLight.Define(stage, "/World/Sky")
        UsdLux.LightAPI(sky).GetShadowLinkCollectionAPI().GetExcludesRel().AddTarget("/World/Castle")
        UsdLux.ShadowAPI.Apply(stage.GetPrimAtPath("/World/Sun")).CreateShadowEnableAttr(False)
    stage = Usd.Stage.Open(str(small_scene(tmp_path / "s.usda", mutate)))
    assert commands.light_links_text(stage, ["/World/Sun", "/World/Sky"]).splitlines() == [
        "/World/Sun lights 1 of 2 objects", "  lights /World/Castle", "  not /World/Block",
        "/World/Sun: no object casts its shadows (inputs:shadow:enable is off)",
        "/World/Sky lights every object (its collection:lightLink holds every prim)",
        "/World/Sky: 1 of 2 objects cast its shadows", "  casts /World/Block", "  not /World/Castle"]
    assert commands.light_links_text(stage, ["/World/Castle"]) == "No light selected (select a UsdLux light)."


def test_export_density_writes_a_vdb_with_sigma_t_inside(tmp_path):
    stage = Usd.Stage.Open(str(EXAMPLES / "snowslab.usda"))
    out = tmp_path / "snow.vdb"
    text = commands.export_density_text(stage, "/World/Snow", str(out))
    assert out.exists() and text.startswith(f"Wrote {out}")
    names = [g["name"] for g in core.read_vdb_grids(str(out))]
    assert names == ["density"]
    # Inside the slab the grid holds the medium's σ_t (as the statistics report it), 0 far outside.
    import numpy as np
    inside, outside = core.sample_vdb_grid(str(out), "density", np.array([[0, 0.15, 0], [0, 50, 0]], dtype=np.float32))
    r = commands._api().aggregate_report(stage=stage)[0]
    assert inside == pytest.approx(sum(r["rte"]["sigma_t"]) / 3, rel=1e-5) and outside == 0
    assert commands.default_vdb_name(stage, "/World/Snow") == "snowslab_World_Snow.vdb"


def test_export_of_a_bad_aggregate_names_prim_and_attribute(tmp_path):
    path = tmp_path / "s.usda"
    small_scene(path)
    stage = Usd.Stage.Open(str(path))
    stage.GetPrimAtPath("/World/Castle").GetAttribute("primvars:granular:packingRate").Set(0.9)
    with pytest.raises(UserError, match=r"/World/Castle\.primvars:granular:packingRate: 0\.9 is outside"):
        commands.export_density_text(stage, "/World/Castle", str(tmp_path / "x.vdb"))
    assert not (tmp_path / "x.vdb").exists()


def test_reference_toggle_alternates_between_ept_and_hybrid():
    assert commands.toggled_technique(None) == "ept"
    assert commands.toggled_technique("hybrid") == "ept"
    assert commands.toggled_technique("ept") == "hybrid"
