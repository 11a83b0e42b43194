// usd_implicit.h — UsdGeom's implicit surfaces on a plain record (usd_values.h),
// tessellated alike for both USD front ends.
//
// Types and UsdGeom's fallbacks: Cube (size 2), Sphere (radius 1), Cylinder and Cone
// (height 2, radius 1, axis "Z"; a cone's apex on +axis), Capsule (height 1 of its
// cylinder, radius 0.5 of its hemispherical ends, axis "Z"). Sizes must be finite and > 0.
// Round shapes get 64 segments around (and 32 rings on a sphere).
#pragma once

#include <string>
#include <vector>

#include "mesh.h"
#include "usd_values.h"

namespace granular {

bool isUsdImplicitSurface(const std::string& typeName);

// The attributes implicitSurfaceFromUsd reads: size, radius, height, axis.
const std::vector<std::string>& usdImplicitAttributeNames();

// The closed surface in its own space. InputError naming prim.size, .radius, .height or
// .axis on a bad value.
TriangleMesh implicitSurfaceFromUsd(const UsdPrimRecord& shape);

}  // namespace granular
