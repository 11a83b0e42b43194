"""Explicit grains' packing rate through `granular export-vdb`: the generated heap's
instancer written as a VDB, read back through core's reader, holds at its voxels the
kernel-smoothed grain volume computed here independently, conserves the grains' volume,
and inside the heap gives the generator's packing rate within the standard error that the
grains' spread of volumes allows."""
import sys

import numpy as np
import pytest
from conftest import EXAMPLES, run_cli
from pxr import Usd

import granular_core as core

sys.path.insert(0, str(EXAMPLES))
import make_grain_heap  # noqa: E402

HEAP = "/World/Heap"


def _b3(x):
    """Cubic B-spline of knot spacing 1 on [-2, 2]."""
    x = np.abs(x)
    return np.where(x < 1, 2.0 / 3 - x ** 2 + x ** 3 / 2, np.where(x < 2, (2 - x) ** 3 / 6, 0.0))


def _volume_centroid(points, indices):
    """A closed mesh's volume and volume centroid (divergence theorem)."""
    tri = points[indices.reshape(-1, 3)].astype(np.float64)
    v = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    return v.sum(), (v[:, None] * tri.sum(axis=1) / 4.0).sum(axis=0) / v.sum()


def _rotate(q, v):
    """Rotate v by unit quaternions q (w, x, y, z), row by row."""
    w, u = q[:, :1], q[:, 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


@pytest.fixture(scope="module")
def heap(tmp_path_factory):
    """The heap's grains as authored: centroids, volumes, and the generator's packing rate."""
    path = tmp_path_factory.mktemp("density") / "heap.usdc"
    count = make_grain_heap.write(str(path), grains=5000, frames=1, seed=4)
    stage = Usd.Stage.Open(str(path))
    prim = stage.GetPrimAtPath(HEAP)
    positions = np.asarray(prim.GetAttribute("positions").Get(1), dtype=np.float64)
    scales = np.asarray(prim.GetAttribute("scales").Get(1), dtype=np.float64)[:, 0]
    quats = np.asarray(prim.GetAttribute("orientations").Get(1), dtype=np.float64)[:, [3, 0, 1, 2]]
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    protos = np.asarray(prim.GetAttribute("protoIndices").Get(1))
    vols, cents = [], []
    for target in prim.GetRelationship("prototypes").GetTargets():
        mesh = stage.GetPrimAtPath(target)
        pts = np.asarray(mesh.GetAttribute("points").Get(), dtype=np.float64)
        idx = np.asarray(mesh.GetAttribute("faceVertexIndices").Get())
        v, c = _volume_centroid(pts, idx)
        vols.append(v)
        cents.append(c)
    vols, cents = np.array(vols), np.array(cents)
    centres = positions + _rotate(quats, cents[protos] * scales[:, None])
    volumes = vols[protos] * scales ** 3
    # The generator: one grain per cell of edge SPACING R, prototype 1 with probability 0.3,
    # scale uniform in [0.75, 1] R: E[s^3] = (1 - 0.75^4) / (4 * 0.25) R^3.
    r = make_grain_heap.RADIUS
    mean_s3 = (1 - 0.75 ** 4) / (4 * 0.25) * r ** 3
    mean_s6 = (1 - 0.75 ** 7) / (7 * 0.25) * r ** 6
    p = np.array([0.7, 0.3])
    mean_v = (p * vols).sum() * mean_s3
    var_v = (p * vols ** 2).sum() * mean_s6 - mean_v ** 2
    cell = (make_grain_heap.SPACING * r) ** 3
    return {"path": str(path), "count": count, "centres": centres, "volumes": volumes,
            "packing": mean_v / cell, "var_volume": var_v, "cell": cell}


def test_export_vdb_writes_the_heaps_packing_rate(heap, tmp_path, capsys):
    out = tmp_path / "heap.vdb"
    rc, _, err = run_cli(["export-vdb", heap["path"], "--prim", HEAP, "-o", out], capsys)
    assert rc == 0, err
    assert f"{heap['count']} grains of {HEAP}" in err
    grids = {g["name"]: g for g in core.read_vdb_grids(str(out))}
    assert sorted(grids) == ["density", "fraction.0", "fraction.1"]
    g = grids["density"]
    assert g["grid_class"] == "fog volume" and g["value_type"] == "float"
    assert grids["fraction.1"]["metadata"]["granular:prototype"] == HEAP + "/Prototypes/Rock"
    dx = g["voxel_size"][0]
    assert float(g["metadata"]["granular:kernelWidth"]) == pytest.approx(2 * dx, rel=1e-5)  # (as text)
    h = 2 * dx
    # Default kernel: 3 mean bounding radii; the prototypes lie in the unit ball (a rock's
    # own bounding sphere is a little smaller) and the mean scale is 0.875 R.
    assert 0.9 * 3 * 0.875 * make_grain_heap.RADIUS < h <= 1.001 * 3 * 0.875 * make_grain_heap.RADIUS

    centres, volumes = heap["centres"], heap["volumes"]
    # Voxel centres (k dx) around the heap's axis, inside and through its surface.
    lo = np.floor((centres.min(axis=0) - 2 * h) / dx).astype(int)
    hi = np.ceil((centres.max(axis=0) + 2 * h) / dx).astype(int)
    ax = [np.arange(lo[a], hi[a] + 1) * dx for a in range(3)]
    grid = np.stack(np.meshgrid(*ax, indexing="ij"), axis=-1).reshape(-1, 3)
    f = core.sample_vdb_grid(str(out), "density", grid.astype(np.float32))
    # Every grain's volume is in the grid (float32 voxels).
    assert f.sum() * dx ** 3 == pytest.approx(volumes.sum(), rel=1e-4)
    assert (f >= 0).all()

    # A sample of voxels against the kernel sum computed here: sum_i V_i W(x - c_i).
    rng = np.random.default_rng(0)
    pick = grid[rng.choice(np.flatnonzero(f > 0), 60, replace=False)]
    w = np.prod(_b3((pick[:, None, :] - centres[None, :, :]) / h), axis=2) / h ** 3
    ref = w @ volumes
    got = core.sample_vdb_grid(str(out), "density", pick.astype(np.float32))
    assert got == pytest.approx(ref, rel=1e-4, abs=1e-6)

    # Inside the heap (the kernel's reach 2h plus a cell clear of the cone and the ground),
    # the mean packing rate of the voxels is the generator's E[V] / cell. Its standard error:
    # the mean is sum_i V_i omega_i, omega_i the grain's mean kernel weight over those voxels,
    # so Var = Var(V) sum_i omega_i^2 for independent grain volumes.
    height = centres[:, 1].max()
    tan = make_grain_heap.TAN_REPOSE
    margin = 2 * h + make_grain_heap.SPACING * make_grain_heap.RADIUS
    radial = np.hypot(grid[:, 0], grid[:, 2])
    slant = (height - grid[:, 1] - radial * tan) / np.sqrt(1 + tan ** 2)
    inside = grid[(slant > margin) & (grid[:, 1] > margin)]
    assert len(inside) >= 100
    inside = inside[rng.choice(len(inside), min(len(inside), 400), replace=False)]
    fi = core.sample_vdb_grid(str(out), "density", inside.astype(np.float32))
    omega = (np.prod(_b3((inside[:, None, :] - centres[None, :, :]) / h), axis=2) / h ** 3).mean(axis=0)
    expected = heap["packing"] * omega.sum() * heap["cell"]  # E[V] sum_i omega_i
    se = np.sqrt(heap["var_volume"] * (omega ** 2).sum())
    assert fi.mean() == pytest.approx(expected, abs=4 * se)
    # ... and the lattice fills space: sum_i omega_i is one grain per cell to the edge's reach.
    assert omega.sum() * heap["cell"] == pytest.approx(1.0, abs=0.02)

    # Fractions: sum to 1 where there are grains, about the generator's 70/30 inside.
    f0 = core.sample_vdb_grid(str(out), "fraction.0", inside.astype(np.float32))
    f1 = core.sample_vdb_grid(str(out), "fraction.1", inside.astype(np.float32))
    assert f0 + f1 == pytest.approx(np.ones(len(inside)), abs=1e-5)
    assert f1.mean() == pytest.approx(0.3, abs=0.1)


def test_export_vdb_of_an_instancer_names_a_bad_voxel_size(heap, tmp_path, capsys):
    rc, _, err = run_cli(["export-vdb", heap["path"], "--prim", HEAP, "-o", tmp_path / "x.vdb",
                          "--voxel-size", "1e-9"], capsys)
    assert rc == 2
    assert "--voxel-size" in err
