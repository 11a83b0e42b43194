// shapes.h — procedural closed meshes for boundaries and grain prototypes.
//
// Contract: every function returns a closed, 2-manifold, consistently oriented mesh
// with outward-facing counter-clockwise winding (positive signedVolume()) and shared
// vertices, i.e. one that passes validateClosed(). Parameters out of range throw
// InputError(function name, parameter name, message); front ends re-label the object.
// Results are deterministic (makeRock depends only on its arguments).
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include "mesh.h"

namespace granular {

// Unit-radius icosphere: the icosahedron with each triangle split 4^subdivisions
// times, vertices projected to the sphere. subdivisions in [0, 8].
TriangleMesh makeIcosphere(int subdivisions);

// Axis-aligned box with 8 shared corners; lo < hi on every axis.
TriangleMesh makeBox(Vec3 lo, Vec3 hi);

// Unit-radius latitude/longitude sphere around +Y with pole vertices.
// segments in [3, 65536], rings in [2, 65536], at most 2^22 vertices in all.
TriangleMesh makeUVSphere(int segments, int rings);

// Surface of revolution around +Y. profile holds (radius, height) pairs from bottom
// to top; interior radii must be > 0. An end with radius 0 becomes a pole vertex, an
// end with radius > 0 is closed by a flat cap (a fan to a centre vertex).
// segments in [3, 65536], at most 2^22 vertices in all.
TriangleMesh makeLathe(const std::vector<std::pair<float, float>>& profile, int segments);

// A rounded rock: an icosphere whose radius is 1 + roughness * n(direction), with n a
// smooth sum of a few random cosine lobes scaled so that max |n| = 1 over the vertices.
// The surface stays star-shaped around the origin, hence closed and free of
// self-intersections. subdivisions in [0, 8], roughness in [0, 0.5).
TriangleMesh makeRock(int subdivisions, float roughness, uint64_t seed);

// Icosphere scaled by radii (all > 0).
TriangleMesh makeEllipsoid(Vec3 radii, int subdivisions);

}  // namespace granular
