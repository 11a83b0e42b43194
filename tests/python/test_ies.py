"""IES profiles on UsdLux lights (core/ies.h, LightShaping in core/scene_desc.h) through
`granular render`: the asset resolved against the stage, the candela scaling the light,
normalisation dividing by the profile's mean, and a file that is not a profile refused with
the prim and the attribute named. hdGranular renders the same (tests/hydra:
AnIesProfileScalesTheLight...; tests/conformance: light_ies*)."""
import json
import subprocess

import numpy as np
from pxr import Gf, Sdf, UsdGeom, UsdLux

from conftest import BUILD, floor_world, run_cli
from noise_check import rgb_and_variance

# A downlight of 5 candela in every direction of its lower half, and a photograph.
CONSTANT = "IESNA:LM-63-2002\n[TEST] constant\nTILT=NONE\n1 -1 1 3 1 1 2 0 0 0\n1 1 10\n0 45 90\n0\n5 5 5\n"


def _floor_under_disk(path, profile=None, normalize=None):
    """A grey floor 15 below the camera under a disk light 3 above it, facing it; with
    `profile` (a path relative to the stage), its IES profile."""
    stage = floor_world(path)
    disk = UsdLux.DiskLight.Define(stage, "/World/Disk")
    disk.CreateRadiusAttr(0.5)
    disk.CreateIntensityAttr(4.0)
    UsdGeom.Xformable(disk).AddTranslateOp().Set(Gf.Vec3d(0, 0, 3))
    if profile is not None:
        shaping = UsdLux.ShapingAPI.Apply(disk.GetPrim())
        shaping.CreateShapingIesFileAttr(Sdf.AssetPath(profile))
        if normalize is not None:
            shaping.CreateShapingIesNormalizeAttr(normalize)
    stage.Save()
    return str(path)


def _render(tmp_path, name, capsys, log=None, **kw):
    out = tmp_path / f"{name}.exr"
    rc, _, err = run_cli(["render", _floor_under_disk(tmp_path / f"{name}.usda", **kw), "-o", out,
                          "--width", "8", "--height", "8", "--spp", "8"], capsys)
    assert rc == 0, err
    if log is None:
        assert "IES profiles" not in err, err
    else:
        assert f"  IES profiles: {log}" in err.splitlines(), err
    return rgb_and_variance(out)[0]


def test_a_profiles_candela_scale_the_light_and_normalisation_divides_by_their_mean(tmp_path, capsys):
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "five.ies").write_text(CONSTANT)
    plain = _render(tmp_path, "plain", capsys, profile=None)
    # ShapingAPI's cone (90° by default) leaves a downlight's floor as it is: the light is 5
    # times brighter everywhere, sample for sample (one light, the same random numbers).
    five = _render(tmp_path, "five", capsys, profile="profiles/five.ies",
                   log="/World/Disk: five.ies (3 × 1 angles, peak 5 cd, mean 5 cd)")
    assert plain.mean() > 0
    np.testing.assert_allclose(five, 5 * plain, rtol=1e-5, atol=1e-7)
    normalized = _render(tmp_path, "normalized", capsys, profile="profiles/five.ies", normalize=True,
                         log="/World/Disk: five.ies (3 × 1 angles, peak 5 cd, mean 5 cd, normalised: divided by the mean)")
    np.testing.assert_allclose(normalized, plain, rtol=1e-5, atol=1e-7)


def test_a_file_that_is_not_a_profile_names_the_light_and_its_attribute(tmp_path, capsys):
    (tmp_path / "photo.ies").write_text("a photograph\n")
    (tmp_path / "binary.ies").write_bytes(b"TILT=NONE\n1 -1 1 \xff\xfe 2 1\n")
    for name, profile, message in (
            ("bad", "photo.ies", f'"{tmp_path / "photo.ies"}" has no TILT= line'),
            ("binary", "binary.ies", f'"{tmp_path / "binary.ies"}" number of vertical angles is not a number: "??"'),
            ("missing", "none.ies", '"none.ies" cannot be found')):
        stage = _floor_under_disk(tmp_path / f"{name}.usda", profile=profile)
        rc, _, err = run_cli(["render", stage, "-o", tmp_path / f"{name}.exr"], capsys)
        assert rc == 2, err
        assert f"error: /World/Disk.inputs:shaping:ies:file: {message}" in err, err
        assert not (tmp_path / f"{name}.exr").exists()


def test_a_json_scene_names_its_profile_relative_to_the_scene_file(tmp_path):
    """`granular-render` (the C++ command line, JSON scenes): the same 5 cd profile makes the
    image 5 times the plain one, sample for sample, and the log names it."""
    (tmp_path / "profiles").mkdir()
    (tmp_path / "profiles" / "five.ies").write_text(CONSTANT)
    images = {}
    for name, shaping in (("plain", {}), ("five", {"shaping_ies_file": "profiles/five.ies"})):
        scene = {
            "render": {"width": 8, "height": 8, "spp": 8, "technique": "ept"},
            "camera": {"look_at": {"eye": [0, 15, 0], "target": [0, 0, 0], "up": [0, 0, -1]}},
            "meshes": [{"name": "floor", "shape": {"box": {"lo": [-30, -0.1, -30], "hi": [30, 0, 30]}}}],
            "lights": [{"name": "disk", "type": "disk", "radius": 0.5, "intensity": 4,
                        "transform": {"translate": [0, 3, 0], "rotate": [-90, 1, 0, 0]}, **shaping}],
        }
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(scene))
        out = tmp_path / f"{name}.exr"
        r = subprocess.run([str(BUILD / "core" / "granular-render"), str(path), "-o", str(out)],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        if shaping:
            assert "  IES profiles: disk: five.ies (3 × 1 angles, peak 5 cd, mean 5 cd)" in r.stderr.splitlines(), \
                r.stderr
        images[name] = rgb_and_variance(out)[0]
    assert images["plain"].mean() > 0
    np.testing.assert_allclose(images["five"], 5 * images["plain"], rtol=1e-5, atol=1e-7)
