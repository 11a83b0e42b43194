#include "grain.h"

#include <algorithm>

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

bool tracePrototype(const GrainPrototype& proto, const Mat3& rotation, float radius, const Vec3& oc, const Vec3& d,
                    float tmin, float tmax, float& t, unsigned& prim, Vec3& ng) {
  const float invR = 1.0f / radius;
  const Vec3 ol = rotation.transposeMul(oc) * invR, dl = rotation.transposeMul(d) * invR;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit local = makeRayHit(ol, dl, tmin, tmax);
  rtcIntersect1(proto.bvh.get(), &ctx, &local);
  if (local.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;
  t = local.ray.tfar;
  prim = local.hit.primID;
  ng = rotation * proto.normals[prim];
  return true;
}

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
  p.hullFace = hullFaces(p.mesh, 1e-5f);
  for (size_t t = 0; t < p.mesh.numTriangles(); ++t) p.normals.push_back(triangleNormal(p.mesh, unsigned(t)));
  return p;
}

std::vector<uint8_t> hullFaces(const TriangleMesh& mesh, float tolerance) {
  std::vector<uint8_t> hull(mesh.numTriangles(), 1);
  for (size_t t = 0; t < hull.size(); ++t) {
    const Vec3& a = mesh.points[mesh.indices[3 * t]];
    const Vec3 n = triangleNormal(mesh, unsigned(t));
    for (const Vec3& v : mesh.points)
      if (dot(n, v - a) > tolerance) {
        hull[t] = 0;
        break;
      }
  }
  return hull;
}

SizeClasses sizeClassesOf(const AggregateDesc& desc) {
  SizeClasses c;
  for (size_t i = 0; i < desc.weights.size(); ++i) {
    const float s = desc.sizes.empty() ? 1.0f : desc.sizes[i];
    if (!(desc.weights[i] > 0)) {
      c.classOf.push_back(-1);
      continue;
    }
    auto it = std::find(c.size.begin(), c.size.end(), s);
    if (it == c.size.end()) {
      c.size.push_back(s);
      c.weight.push_back(0.0);
      it = c.size.end() - 1;
    }
    const int k = int(it - c.size.begin());
    c.weight[size_t(k)] += desc.weights[i];
    c.classOf.push_back(k);
  }
  return c;
}

GrainSelector::GrainSelector(const std::vector<float>& weights, const SizeClasses& classes, uint64_t seed)
    : classOf_(classes.classOf), seed_(seed) {
  for (size_t k = 0; k < classes.size.size(); ++k) {
    std::vector<float> w(weights.size(), 0.0f);
    for (size_t i = 0; i < weights.size(); ++i)
      if (classes.classOf[i] == int(k)) w[i] = weights[i];
    perClass_.emplace_back(w);
  }
}

double sauterSizeOf(const AggregateDesc& desc, double* meanCube) {
  const SizeClasses classes = sizeClassesOf(desc);
  const double a2 = double(desc.sizeSpread) * desc.sizeSpread;
  double w = 0, s2 = 0, s3 = 0;
  for (size_t c = 0; c < classes.size.size(); ++c) {
    const double x = classes.size[c];
    w += classes.weight[c];
    s2 += classes.weight[c] * x * x;
    s3 += classes.weight[c] * x * x * x;
  }
  if (meanCube) *meanCube = w > 0 ? s3 / w * (1.0 + a2) : 1.0;
  if (classes.size.size() == 1) return double(classes.size[0]) * (1.0 + a2) / (1.0 + a2 / 3.0);
  return s2 > 0 ? s3 * (1.0 + a2) / (s2 * (1.0 + a2 / 3.0)) : 1.0;
}

}  // namespace granular
