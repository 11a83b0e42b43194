"""Coarse density export: the VDB read back through the bindings holds sigma_t inside
the aggregate's boundary and 0 outside, in world space; export-vdb uses the
teleportation-transport sigma_t when core has it and fails clearly when not."""
import json

import numpy as np
import pytest
from conftest import EXAMPLES, run_cli

import granular_core as core
from granular.usd_reader import read_stage


def test_density_of_an_example_aggregate_reads_back(tmp_path):
    scene = read_stage(str(EXAMPLES / "sandcastle.usda"), surfaces=False, need_camera=False)
    base = [a for a in scene.aggregates if a["prim"] == "/World/Castle/Base"][0]
    out = tmp_path / "base.vdb"
    r = core.write_density_vdb(str(out), base["world_boundary"], 42.0, 0.02, "/World/Castle/Base",
                               vec3_metadata={"granular:sigmaT": (41.0, 42.0, 43.0)})
    assert r["voxel_size"] == pytest.approx(0.02)
    grids = core.read_vdb_grids(str(out))
    assert [g["name"] for g in grids] == ["density"]
    g = grids[0]
    assert g["value_type"] == "float" and g["grid_class"] == "fog volume"
    assert g["metadata"]["granular:object"] == "/World/Castle/Base"
    assert g["metadata"]["granular:sigmaT"] == "[41, 42, 43]"
    # The base is the box [-0.8, 0.8] x [0, 0.3] x [-0.8, 0.8] in world space.
    inside = np.array([[0, 0.15, 0], [0.7, 0.05, -0.7], [-0.5, 0.25, 0.3]], dtype=np.float32)
    outside = np.array([[0, 0.4, 0], [0.9, 0.15, 0], [0, -0.1, 0], [3, 3, 3]], dtype=np.float32)
    assert core.sample_vdb_grid(str(out), "density", inside) == pytest.approx([42.0] * 3)
    assert core.sample_vdb_grid(str(out), "density", outside) == pytest.approx([0.0] * 4)
    # The voxel centres in the closed box: its faces fall on voxel centres here, so
    # between those strictly inside and those inside or on a face.
    assert 79 * 14 * 79 <= g["active_voxels"] <= 81 * 16 * 81


def test_export_vdb_command_writes_the_tt_sigma_t(tmp_path, capsys):
    from granular.cli import main
    out = tmp_path / "snow.vdb"
    rc = main(["export-vdb", str(EXAMPLES / "snowslab.usda"), "--prim", "/World/Snow", "-o", str(out),
               "--voxel-size", "0.05", "--quiet"])
    assert rc == 0, capsys.readouterr().err
    # sigma_t as the teleportation-transport model derives it for this aggregate.
    scene = read_stage(str(EXAMPLES / "snowslab.usda"), surfaces=False, need_camera=False)
    medium = core.Scene.build(scene.desc).media()[0]
    sigma = medium["sigma_t"]
    assert min(sigma) > 0
    g = core.read_vdb_grids(str(out))[0]
    assert g["name"] == "density" and g["voxel_size"] == pytest.approx((0.05, 0.05, 0.05))
    assert json.loads(g["metadata"]["granular:sigmaT"]) == pytest.approx(list(sigma), rel=1e-5)  # printed to 6 digits
    # The slab is the box [-0.9, 0.9] x [0, 0.3] x [-0.55, 0.55].
    inside = core.sample_vdb_grid(str(out), "density", np.array([[0, 0.15, 0], [0.8, 0.1, -0.45]], dtype=np.float32))
    assert inside == pytest.approx([sum(sigma) / 3] * 2, rel=1e-6)
    outside = core.sample_vdb_grid(str(out), "density", np.array([[0, 0.4, 0], [1.0, 0.1, 0]], dtype=np.float32))
    assert list(outside) == [0.0, 0.0]


def test_export_vdb_leaves_nothing_on_error(tmp_path, capsys):
    from granular.cli import main
    out = tmp_path / "snow.vdb"
    rc = main(["export-vdb", str(EXAMPLES / "snowslab.usda"), "--prim", "/World/Snow", "-o", str(out),
               "--voxel-size", "0.00001"])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert err.startswith("error: command line.--voxel-size: 1e-05 is too small for the boundary's extent")
    assert not out.exists() and not list(tmp_path.iterdir())


def test_export_vdb_of_a_prim_that_is_not_an_aggregate(tmp_path, capsys):
    from granular.cli import main
    rc = main(["export-vdb", str(EXAMPLES / "snowslab.usda"), "--prim", "/World/Ground", "-o",
               str(tmp_path / "g.vdb")])
    assert rc == 2
    assert capsys.readouterr().err.strip() == "error: /World/Ground: is not a visible Mesh with GranularAggregateAPI"
