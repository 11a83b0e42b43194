#include "embree_util.h"

#include <stdexcept>
#include <string>

namespace granular {

EmbreeDevice makeEmbreeDevice() {
  RTCDevice d = rtcNewDevice(nullptr);
  if (!d) throw std::runtime_error("Embree: cannot create a device (error " + std::to_string(int(rtcGetDeviceError(nullptr))) + ")");
  return EmbreeDevice(d, [](RTCDevice x) { rtcReleaseDevice(x); });
}

EmbreeScene makeEmbreeScene(const EmbreeDevice& device) {
  RTCScene s = rtcNewScene(device.get());
  rtcSetSceneFlags(s, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_HIGH);
  return EmbreeScene(s, [](RTCScene x) { rtcReleaseScene(x); });
}

unsigned attachTriangleMesh(RTCDevice device, RTCScene scene, const TriangleMesh& mesh, RTCFilterFunctionN filter,
                            void* filterData, const TriangleMesh* atClose) {
  RTCGeometry g = rtcNewGeometry(device, RTC_GEOMETRY_TYPE_TRIANGLE);
  if (atClose) rtcSetGeometryTimeStepCount(g, 2);
  for (unsigned slot = 0; slot < (atClose ? 2u : 1u); ++slot) {
    const TriangleMesh& m = slot == 0 ? mesh : *atClose;
    auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, slot, RTC_FORMAT_FLOAT3,
                                                          3 * sizeof(float), m.points.size()));
    for (size_t i = 0; i < m.points.size(); ++i) {
      v[3 * i] = m.points[i].x; v[3 * i + 1] = m.points[i].y; v[3 * i + 2] = m.points[i].z;
    }
  }
  auto* idx = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                             3 * sizeof(unsigned), mesh.numTriangles()));
  std::copy(mesh.indices.begin(), mesh.indices.end(), idx);
  if (filter) {
    rtcSetGeometryUserData(g, filterData);
    rtcSetGeometryIntersectFilterFunction(g, filter);
    rtcSetGeometryOccludedFilterFunction(g, filter);
  }
  rtcCommitGeometry(g);
  unsigned id = rtcAttachGeometry(scene, g);
  rtcReleaseGeometry(g);
  return id;
}

EmbreeScene buildTriangleScene(const EmbreeDevice& device, const TriangleMesh& mesh) {
  EmbreeScene s = makeEmbreeScene(device);
  attachTriangleMesh(device.get(), s.get(), mesh);
  rtcCommitScene(s.get());
  return s;
}

}  // namespace granular
