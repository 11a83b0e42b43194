#include "grain.h"

namespace granular {

namespace {

// Ritter (1990) bounding sphere, then a few passes that pull the centre towards the
// farthest point: within a few percent of the minimal sphere, enough for packing.
void boundingSphere(const std::vector<Vec3>& pts, Vec3& center, float& radius) {
  auto farthest = [&](const Vec3& from) {
    size_t best = 0;
    float bd = -1;
    for (size_t i = 0; i < pts.size(); ++i) {
      float d = length2(pts[i] - from);
      if (d > bd) { bd = d; best = i; }
    }
    return best;
  };
  Vec3 a = pts[farthest(pts[0])];
  Vec3 b = pts[farthest(a)];
  center = (a + b) * 0.5f;
  radius = 0.5f * length(b - a);
  for (const Vec3& p : pts) {
    float d = length(p - center);
    if (d > radius) {
      float r = 0.5f * (radius + d);
      center += (p - center) * ((r - radius) / d);
      radius = r;
    }
  }
  // Refinement: step the centre towards the farthest point while it shrinks the radius.
  for (int it = 0; it < 64; ++it) {
    Vec3 f = pts[farthest(center)];
    Vec3 c2 = center + (f - center) * (0.5f / float(it + 2));
    float r2 = length(pts[farthest(c2)] - c2);
    if (r2 < radius) { center = c2; radius = r2; }
  }
  radius = length(pts[farthest(center)] - center);
}

}  // namespace

GrainPrototype makeGrainPrototype(const EmbreeDevice& device, const GrainPrototypeDesc& desc) {
  GrainPrototype p;
  p.name = desc.name;
  p.material = desc.material;
  boundingSphere(desc.mesh.points, p.fitCenter, p.fitRadius);
  p.mesh = desc.mesh;
  float inv = 1.0f / p.fitRadius;
  for (Vec3& q : p.mesh.points) q = (q - p.fitCenter) * inv;
  if (p.mesh.signedVolume() < 0) p.mesh.flip();
  p.bvh = buildTriangleScene(device, p.mesh);
  return p;
}

GrainSelector::GrainSelector(const std::vector<float>& weights, uint64_t seed) : weights_(weights), seed_(seed) {}

}  // namespace granular
