// embree_util.h — ownership of Embree handles and a triangle-mesh BVH.
//
// Contract: EmbreeDevice/EmbreeScene release their handle when the last owner goes.
// buildTriangleScene() makes a static, robust BVH over one mesh (geometry id 0).
#pragma once

#include <embree3/rtcore.h>

#include <cmath>
#include <memory>

#include "mesh.h"

namespace granular {

using EmbreeDevice = std::shared_ptr<std::remove_pointer_t<RTCDevice>>;
using EmbreeScene = std::shared_ptr<std::remove_pointer_t<RTCScene>>;

EmbreeDevice makeEmbreeDevice();
EmbreeScene makeEmbreeScene(const EmbreeDevice& device);
// Adds mesh as a triangle geometry to scene (not committed); returns its geometry id.
// A filter (with its user data), if given, sees every candidate hit of intersection and
// occlusion rays and may reject it (cut-outs). atClose (same topology): the mesh moves
// linearly from `mesh` at ray time 0 to it at ray time 1 (two time steps).
unsigned attachTriangleMesh(RTCDevice device, RTCScene scene, const TriangleMesh& mesh,
                            RTCFilterFunctionN filter = nullptr, void* filterData = nullptr,
                            const TriangleMesh* atClose = nullptr);
EmbreeScene buildTriangleScene(const EmbreeDevice& device, const TriangleMesh& mesh);

// Unit outward normal of triangle prim (counter-clockwise winding seen from outside).
inline Vec3 triangleNormal(const TriangleMesh& m, unsigned prim) {
  const Vec3& a = m.points[m.indices[3 * prim]];
  const Vec3& b = m.points[m.indices[3 * prim + 1]];
  const Vec3& c = m.points[m.indices[3 * prim + 2]];
  return normalize(cross(b - a, c - a));
}

// Whether Embree may be given this ray: its own check (finite, coordinates within about
// 1.8e18, 0 <= tnear, tfar not NaN) is an assertion that aborts the process. Callers answer
// "no hit" for a ray that fails it, so no input can end a render that way.
inline bool traceable(const Vec3& o, const Vec3& d, float tnear, float tfar) {
  constexpr float kLarge = 1e18f;
  return std::fabs(o.x) <= kLarge && std::fabs(o.y) <= kLarge && std::fabs(o.z) <= kLarge && std::fabs(d.x) <= kLarge &&
         std::fabs(d.y) <= kLarge && std::fabs(d.z) <= kLarge && tnear >= 0 && tnear <= kInf && !std::isnan(tfar);
}

inline RTCRayHit makeRayHit(const Vec3& o, const Vec3& d, float tnear, float tfar) {
  RTCRayHit rh;
  rh.ray.org_x = o.x; rh.ray.org_y = o.y; rh.ray.org_z = o.z;
  rh.ray.dir_x = d.x; rh.ray.dir_y = d.y; rh.ray.dir_z = d.z;
  rh.ray.tnear = tnear; rh.ray.tfar = tfar;
  rh.ray.time = 0; rh.ray.mask = 0xffffffffu; rh.ray.id = 0; rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.primID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  return rh;
}

}  // namespace granular
