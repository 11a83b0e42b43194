#!/usr/bin/env python3
"""Writes a simulation-like heap of explicit grains: a UsdGeomPointInstancer with
GranularInstancedAggregateAPI, as a grain solver exports one (positions, orientations,
scales, protoIndices, velocities, angularVelocities), over a few frames:

    .venv/bin/python examples/make_grain_heap.py OUT.usdc [--grains N] [--frames K] [--seed S] [--shutter OPEN CLOSE]
                                                 [--no-motion] [--slabs] [--material NAME] [--slab-depth D]
                                                 [--gradient G] [--sun E] [--sun-angle DEG]

The heap is a cone at the angle of repose of dry sand (about 31 degrees) on a ground card,
with a camera and a sun. Grains are placed one per cell of a cubic grid (cells whose centre
lies in the cone), each jittered inside its cell and of a random size, so that no two
bounding spheres can touch: the nearest centres are 2.1 largest radii apart. Two
prototypes (a round grain and a rock, both inside the unit sphere, with GranularGrainAPI)
are chosen 70/30. Frames 1..K move every grain by a small settling drift (at most 2% of the
largest radius per frame, toward the heap's foot) and spin it slowly; velocities and
angular velocities are the matching rates. Deterministic given the arguments. The default
(~100k grains, 3 frames) is about 11 MB of .usdc: write it, do not commit it.

For very large heaps (10^8 grains: bench/README.md, "Explicit grains from a simulation"):
--no-motion writes one frame without velocities and angular velocities (36 bytes a grain:
positions, half-float orientations, scales, protoIndices), and --slabs generates the grains
layer by layer of the grid, each layer from its own random stream, in memory proportional
to the grains' arrays alone (a different heap from the default's, as deterministic).

--material ice makes the grains ice (granular.materials: IOR 1.31, nearly clear) instead of
quartz sand. --slab-depth D writes a flat square slab D grid cells deep (D * 2.3 largest radii)
instead of the cone, as wide as the grains allow, seen from above at 45 degrees: a deep,
wide medium for the diffusion approximation (bench/README.md, "DA in simulated grains' media").
--gradient G thins the slab's grains with depth so that its packing rate rises G times from
bottom to top: a medium of varying density.

The sun is a normalised UsdLuxDistantLight of irradiance --sun (default 3) and angular
diameter --sun-angle (default 0.53°, the physical sun's) at 50° elevation; the sky a dome of
radiance 0.3. --sun 0 leaves the sun's prim at zero intensity: the heap is lit by the sky
alone, as the benchmarks that compare explicit grains (which cannot find a 0.53° sun)
render it.
"""
import argparse
import math
import sys

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, Vt

import granular  # noqa: F401  (registers the schema)
import granular_core as core
from granular import schema
from granular.materials import QUARTZ_SAND

RADIUS = 0.01          # largest bounding radius of a grain, metres
SPACING = 2.3          # grid cell edge, in largest radii
JITTER = 0.1           # each way, in largest radii: centres stay 2.1 radii apart
TAN_REPOSE = math.tan(math.radians(31.0))
FPS = 24.0
SUN_IRRADIANCE = 3.0   # normalised; on flat ground 2.3 at 50° elevation, the sky 0.94 (0.3 π)
SUN_ANGLE = 0.53       # degrees, the physical sun


def _unit_ball(tri):
    """The mesh scaled into the unit ball about its origin (a grain of scale s then has a
    bounding radius of at most s)."""
    pts = np.asarray(tri.points, dtype=np.float64)
    return (pts / np.linalg.norm(pts, axis=1).max()).astype(np.float32), np.asarray(tri.indices, dtype=np.int32)


def _mesh(stage, path, tri):
    pts, idx = _unit_ball(tri)
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts))
    m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(idx))
    m.CreateFaceVertexCountsAttr(Vt.IntArray([3] * (len(idx) // 3)))
    m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    return m


def heap(grains, seed):
    """Centres, sizes, rotations (w, x, y, z) and prototype indices of about `grains`
    grains in a cone standing on y = 0."""
    rng = np.random.default_rng(seed)
    a = SPACING * RADIUS
    # Cone volume pi B^2 H / 3 with H = B tan(repose) holds `grains` cells of a^3.
    base = (3.0 * grains * a ** 3 / (math.pi * TAN_REPOSE)) ** (1.0 / 3.0)
    height = base * TAN_REPOSE
    n = int(math.ceil(base / a)) + 1
    ix, iy, iz = np.meshgrid(np.arange(-n, n + 1), np.arange(0, int(height / a) + 2), np.arange(-n, n + 1),
                             indexing="ij")
    centres = np.stack([ix.ravel(), iy.ravel(), iz.ravel()], axis=1).astype(np.float64) * a
    centres[:, 1] += 0.5 * a
    r = np.hypot(centres[:, 0], centres[:, 2])
    inside = r <= (height - centres[:, 1]) / TAN_REPOSE
    return _grains_at(rng, centres[inside]) + (height,)


def _grains_at(rng, centres):
    """Grains at the grid's cell centres: jittered centres, sizes, unit quaternions (real
    first), prototype indices (30% rock)."""
    count = len(centres)
    centres = centres + rng.uniform(-JITTER * RADIUS, JITTER * RADIUS, size=(count, 3))
    sizes = RADIUS * rng.uniform(0.75, 1.0, size=count)
    q = rng.normal(size=(count, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    protos = (rng.uniform(size=count) >= 0.7).astype(np.int32)
    return centres, sizes, q, protos


def heap_slabs(grains, seed):
    """heap()'s cone, generated one layer of the grid (constant y) at a time into float32
    arrays: centres, sizes, rotations as (i, j, k, real) half floats (USD's quath), prototype
    indices, height. Layer k draws from its own stream (seed, k)."""
    a = SPACING * RADIUS
    base = (3.0 * grains * a ** 3 / (math.pi * TAN_REPOSE)) ** (1.0 / 3.0)
    height = base * TAN_REPOSE
    n = int(math.ceil(base / a)) + 1
    axis = np.arange(-n, n + 1, dtype=np.float64) * a
    r2 = axis[:, None] ** 2 + axis[None, :] ** 2
    layers = []
    for iy in range(0, int(height / a) + 2):
        y = (iy + 0.5) * a
        inside = np.sqrt(r2) <= (height - y) / TAN_REPOSE
        layers.append((y, np.nonzero(inside.ravel())[0]))
    count = sum(len(cells) for _, cells in layers)
    centres = np.empty((count, 3), np.float32)
    sizes = np.empty(count, np.float32)
    quats = np.empty((count, 4), np.float16)
    protos = np.empty(count, np.int32)
    at = 0
    for iy, (y, cells) in enumerate(layers):
        m = len(cells)
        if m == 0:
            continue
        rng = np.random.default_rng([seed, iy])
        c = np.stack([axis[cells // len(axis)], np.full(m, y), axis[cells % len(axis)]], axis=1)
        centres[at:at + m] = c + rng.uniform(-JITTER * RADIUS, JITTER * RADIUS, size=(m, 3))
        sizes[at:at + m] = RADIUS * rng.uniform(0.75, 1.0, size=m)
        q = rng.normal(size=(m, 4))
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        quats[at:at + m] = q[:, [1, 2, 3, 0]]  # (i, j, k, real)
        protos[at:at + m] = rng.uniform(size=m) >= 0.7
        at += m
    return centres, sizes, quats, protos, height


def slab_columns(grains, depth_cells):
    """The slab's columns along each side: as many as `grains` fill at depth_cells deep."""
    return max(1, int(round(math.sqrt(grains / depth_cells))))


def slab(grains, seed, depth_cells, gradient=1.0):
    """heap()'s grains in a square slab depth_cells cells deep on y = 0 instead of the cone
    (as many columns as `grains` fill); the same arrays as heap(), height the slab's top.
    gradient G > 1 keeps a grain at height y with probability 1/G + (1 − 1/G) y / top, so
    that the packing rate rises G times from the bottom to the top (fewer grains than asked)."""
    rng = np.random.default_rng(seed)
    a = SPACING * RADIUS
    n = slab_columns(grains, depth_cells)
    ix, iy, iz = np.meshgrid(np.arange(n) - (n - 1) / 2.0, np.arange(depth_cells), np.arange(n) - (n - 1) / 2.0,
                             indexing="ij")
    centres = np.stack([ix.ravel(), iy.ravel() + 0.5, iz.ravel()], axis=1) * a
    grains_at = _grains_at(rng, centres)
    if gradient > 1.0:
        top = depth_cells * a
        keep = np.random.default_rng([seed, 1]).uniform(size=len(centres)) < \
            1.0 / gradient + (1.0 - 1.0 / gradient) * np.clip(grains_at[0][:, 1] / top, 0.0, 1.0)
        grains_at = tuple(x[keep] for x in grains_at)
    return grains_at + (depth_cells * a,)


def _write_static(stage, pi, centres, sizes, quats, protos):
    """One frame, no motion, each array handed to USD and dropped before the next."""
    pi.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(protos))
    pi.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(np.repeat(sizes[:, None], 3, axis=1)))
    pi.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy(centres))
    pi.CreateOrientationsAttr(Vt.QuathArray.FromNumpy(quats))


def write(path, grains=100000, frames=3, seed=1, shutter=None, motion=True, slabs=False, material=QUARTZ_SAND,
          slab_depth=None, gradient=1.0, sun=SUN_IRRADIANCE, sun_angle=SUN_ANGLE):
    if slab_depth:
        centres, sizes, quats, protos, height = slab(grains, seed, slab_depth, gradient)
        if not motion:
            centres, sizes = centres.astype(np.float32), sizes.astype(np.float32)
            quats = quats[:, [1, 2, 3, 0]].astype(np.float16)
    elif slabs:
        centres, sizes, quats, protos, height = heap_slabs(grains, seed)
    else:
        centres, sizes, quats, protos, height = heap(grains, seed)
        if not motion:  # as the motion path writes frame 1: float32, (i, j, k, real) halves
            centres, sizes = centres.astype(np.float32), sizes.astype(np.float32)
            quats = quats[:, [1, 2, 3, 0]].astype(np.float16)
    count = len(centres)
    # The slab's width, thinned or not.
    slab_width = slab_columns(grains, slab_depth) * SPACING * RADIUS if slab_depth else 0
    stage = Usd.Stage.CreateNew(path)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(frames)
    stage.SetTimeCodesPerSecond(FPS)
    world = UsdGeom.Xform.Define(stage, "/World")
    stage.SetDefaultPrim(world.GetPrim())

    pi = UsdGeom.PointInstancer.Define(stage, "/World/Heap")
    schema.apply_instanced_aggregate(pi)
    UsdGeom.Scope.Define(stage, "/World/Heap/Prototypes")
    round_ = _mesh(stage, "/World/Heap/Prototypes/Round", core.make_icosphere(2))
    rock = _mesh(stage, "/World/Heap/Prototypes/Rock", core.make_rock(2, 0.3, seed))
    # Absorption is per the prototype's bounding radius at scale 1 (schemas/README.md), the
    # unit ball here: the material's absorption per grain radius over RADIUS, so that grains
    # scaled to RADIUS absorb as grains of that size.
    absorption = tuple(a / RADIUS for a in material.absorption_per_radius(RADIUS))
    for m in (round_, rock):  # visible: a prototype's visibility is its instances'
        schema.apply_grain(m, ior=material.ior, absorption=absorption, invisible=False)
    pi.CreatePrototypesRel().SetTargets([round_.GetPath(), rock.GetPath()])
    if not motion:
        _write_static(stage, pi, centres, sizes, quats, protos)
        del centres, sizes, quats, protos
    else:
        _write_motion(stage, pi, centres, sizes, quats, protos, frames, seed)
    _write_rest(stage, height, shutter, slab_width=slab_width, sun=sun, sun_angle=sun_angle)
    stage.GetRootLayer().Save()
    return count


def _write_motion(stage, pi, centres, sizes, quats, protos, frames, seed):
    count = len(centres)
    rng = np.random.default_rng(seed + 1)
    pi.CreateProtoIndicesAttr(Vt.IntArray.FromNumpy(protos))
    pi.CreateScalesAttr(Vt.Vec3fArray.FromNumpy(np.repeat(sizes[:, None], 3, axis=1).astype(np.float32)))

    # Settling: a drift toward the foot of the heap (outward and down), at most 2% of the
    # largest radius per frame, and a slow spin; the rates are what a solver would export.
    out = centres * np.array([1.0, 0.0, 1.0])
    out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-9)
    drift = (out - np.array([0.0, 1.0, 0.0])) / math.sqrt(2.0)
    drift *= (0.02 * RADIUS) * rng.uniform(0.0, 1.0, size=(count, 1))
    axis = rng.normal(size=(count, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    spin = rng.uniform(0.0, 2.0, size=(count, 1))  # degrees per frame
    pi.CreateVelocitiesAttr(Vt.Vec3fArray.FromNumpy((drift * FPS).astype(np.float32)))
    pi.CreateAngularVelocitiesAttr(Vt.Vec3fArray.FromNumpy((axis * spin * FPS).astype(np.float32)))
    pos_attr = pi.CreatePositionsAttr()
    orient_attr = pi.CreateOrientationsAttr()
    for f in range(frames):
        pos_attr.Set(Vt.Vec3fArray.FromNumpy((centres + drift * f).astype(np.float32)), Usd.TimeCode(1 + f))
        half = np.radians(spin * f) / 2.0
        dq = np.concatenate([np.cos(half), axis * np.sin(half)], axis=1)  # (w, x, y, z)
        w1, v1 = dq[:, :1], dq[:, 1:]
        w2, v2 = quats[:, :1], quats[:, 1:]
        q = np.concatenate([w1 * w2 - np.sum(v1 * v2, axis=1, keepdims=True),
                            w1 * v2 + w2 * v1 + np.cross(v1, v2)], axis=1)
        # Vt takes (i, j, k, real).
        orient_attr.Set(Vt.QuathArray.FromNumpy(q[:, [1, 2, 3, 0]].astype(np.float16)), Usd.TimeCode(1 + f))


def _write_rest(stage, height, shutter, slab_width=0, sun=SUN_IRRADIANCE, sun_angle=SUN_ANGLE):
    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    g = 4.0 * max(height, slab_width) + 0.2
    ground.CreatePointsAttr([(-g, 0, -g), (g, 0, -g), (g, 0, g), (-g, 0, g)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 3, 2, 1])  # facing +y
    ground.CreateDisplayColorAttr([(0.45, 0.4, 0.35)])
    cam = UsdGeom.Camera.Define(stage, "/World/Camera")
    eye = Gf.Vec3d(0.0, 1.6 * height + 0.05, 3.5 * height + 0.1)
    target = Gf.Vec3d(0, 0.35 * height, 0)
    if slab_width:  # the slab's top from above at 45 degrees, its width filling the frame
        eye, target = Gf.Vec3d(0.0, height + 0.9 * slab_width, 0.9 * slab_width), Gf.Vec3d(0, height, 0)
    look = Gf.Matrix4d().SetLookAt(eye, target, Gf.Vec3d(0, 1, 0)).GetInverse()
    UsdGeom.Xformable(cam).AddTransformOp().Set(look)
    cam.CreateFocalLengthAttr(35.0)
    cam.CreateClippingRangeAttr(Gf.Vec2f(0.001, 100.0))
    if shutter is not None:  # motion blur from the grains' velocities and spins
        cam.CreateShutterOpenAttr(float(shutter[0]))
        cam.CreateShutterCloseAttr(float(shutter[1]))
    # Normalised: the intensity is the sun's irradiance whatever its angle (without it a
    # distant light's intensity is its radiance, and 3 over a 0.53° disk lights nothing).
    light = UsdLux.DistantLight.Define(stage, "/World/Sun")
    light.CreateIntensityAttr(float(sun))
    light.CreateAngleAttr(float(sun_angle))
    light.CreateNormalizeAttr(True)
    UsdGeom.Xformable(light).AddRotateXYZOp().Set(Gf.Vec3f(-50, 30, 0))
    UsdLux.DomeLight.Define(stage, "/World/Sky").CreateIntensityAttr(0.3)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("output", help="a .usdc (or .usda) path")
    p.add_argument("--grains", type=int, default=100000, help="about this many grains (default 100000)")
    p.add_argument("--frames", type=int, help="time samples 1..K (default 3)")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--shutter", type=float, nargs=2, metavar=("OPEN", "CLOSE"),
                   help="the camera's shutter:open and shutter:close in frames (e.g. -0.25 0.25): motion blur")
    p.add_argument("--no-motion", action="store_true",
                   help="one frame, no velocities or angular velocities (36 bytes a grain)")
    p.add_argument("--slabs", action="store_true",
                   help="generate the grid layer by layer in bounded memory (for 10^8 grains; another heap)")
    p.add_argument("--material", choices=["quartz_sand", "ice"], default="quartz_sand",
                   help="the grains' material (granular.materials; default quartz_sand)")
    p.add_argument("--slab-depth", type=int, metavar="D",
                   help="a flat square slab D grid cells deep instead of the cone")
    p.add_argument("--gradient", type=float, default=1.0, metavar="G",
                   help="with --slab-depth: the packing rate rises G times from the slab's bottom to its top")
    p.add_argument("--sun", type=float, default=SUN_IRRADIANCE, metavar="E",
                   help=f"the sun's irradiance (a normalised UsdLuxDistantLight; default {SUN_IRRADIANCE:g}; "
                        "0 leaves the sky alone)")
    p.add_argument("--sun-angle", type=float, default=SUN_ANGLE, metavar="DEG",
                   help=f"the sun's angular diameter in degrees (default {SUN_ANGLE:g}, the physical sun's)")
    a = p.parse_args(argv)
    if a.no_motion and a.frames not in (None, 1) or a.shutter and a.no_motion:
        p.error("--no-motion writes one frame without motion: no --frames or --shutter")
    a.frames = (1 if a.no_motion else 3) if a.frames is None else a.frames
    if a.grains < 1 or a.frames < 1:
        p.error("--grains and --frames must be >= 1")
    if a.slabs and not a.no_motion:
        p.error("--slabs writes a still heap: with --no-motion")
    if a.slab_depth is not None and (a.slab_depth < 1 or a.slabs):
        p.error("--slab-depth must be >= 1, and not with --slabs")
    if not a.gradient >= 1.0 or a.gradient != 1.0 and a.slab_depth is None:
        p.error("--gradient must be >= 1, and with --slab-depth")
    if not a.sun >= 0 or not 0 <= a.sun_angle < 180:
        p.error("--sun must be >= 0 and --sun-angle in [0, 180)")
    from granular.materials import MATERIALS
    n = write(a.output, a.grains, a.frames, a.seed, a.shutter, motion=not a.no_motion, slabs=a.slabs,
              material=MATERIALS[a.material], slab_depth=a.slab_depth, gradient=a.gradient, sun=a.sun,
              sun_angle=a.sun_angle)
    print(f"wrote {a.output}: {n} grains, {a.frames} frames")
    return 0


if __name__ == "__main__":
    sys.exit(main())
