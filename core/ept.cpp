#include "ept.h"

namespace granular {

namespace {

// Radiance of the infinite lights along an escaping direction, MIS-weighted against
// light sampling when the previous bounce could have sampled them.
Vec3 escapedRadiance(const Scene& scene, const Vec3& p, const Vec3& dir, bool misOn, float bsdfPdf, float lightPick) {
  Vec3 L(0.0f);
  for (int li : scene.infiniteLights()) {
    const Light& light = scene.lights()[li];
    Vec3 Le = light.escapedLe(dir);
    if (isBlack(Le)) continue;
    float w = 1.0f;
    if (misOn) w = powerHeuristic(bsdfPdf, light.pdfLi(p, dir, kInf) * lightPick);
    L += Le * w;
  }
  return L;
}

}  // namespace

Vec3 tracePath(const Scene& scene, Ray ray, Rng& rng, PrimaryInfo* primary, PathStats* stats) {
  const RenderSettings& rs = scene.settings();
  const auto& lights = scene.lights();
  const float lightPick = lights.empty() ? 0.0f : 1.0f / float(lights.size());
  Vec3 L(0.0f), beta(1.0f);
  bool lastDelta = true;  // camera rays and delta bounces see emitters unweighted
  float lastPdf = 0;
  Vec3 lastP = ray.o;
  int depth = 0;
  for (; depth < rs.maxDepth; ++depth) {
    Hit hit;
    if (!scene.intersect(ray, hit)) {
      L += beta * escapedRadiance(scene, lastP, ray.d, !lastDelta, lastPdf, lightPick);
      break;
    }
    if (depth == 0 && primary) {
      primary->hit = true;
      primary->depth = scene.camera().viewDepth(hit.p);
      primary->normal = dot(hit.ng, ray.d) > 0 ? -hit.ng : hit.ng;
      primary->kind = int(hit.kind);
    }
    if (hit.kind == Hit::AreaLight) {
      const Light& light = lights[hit.light];
      float w = lastDelta ? 1.0f : powerHeuristic(lastPdf, light.pdfLi(lastP, ray.d, hit.t) * lightPick);
      L += beta * light.areaLe(ray.d) * w;
      break;
    }
    const Material& m = scene.material(hit.material);
    bool inside = dot(ray.d, hit.ng) > 0;
    if (inside && m.type == MaterialType::Dielectric && !isBlack(m.absorption)) {
      // Beer–Lambert over the segment just travelled inside (object units -> world).
      beta *= vexp(m.absorption * (-hit.t / hit.lengthScale));
    }
    if (!isBlack(m.emission) && !inside) L += beta * m.emission;

    Frame frame(hit.ng);
    Vec3 wo = frame.toLocal(-ray.d);

    if (!m.isDelta() && !lights.empty() && wo.z > 0) {
      // Next-event estimation: one light, chosen uniformly.
      int li = std::min(int(rng.next1D() * lights.size()), int(lights.size()) - 1);
      LightSample ls;
      float u1 = rng.next1D(), u2 = rng.next1D();
      if (lights[li].sampleLi(hit.p, u1, u2, ls) && !isBlack(ls.Li)) {
        Vec3 wiLocal = frame.toLocal(ls.wi);
        Vec3 f = m.eval(wo, wiLocal);
        if (!isBlack(f)) {
          Vec3 origin = offsetRayOrigin(hit.p, hit.ng, ls.wi, hit.eps);
          float dist = std::isfinite(ls.dist) ? ls.dist * (1.0f - 1e-4f) : kInf;
          if (!scene.occluded(origin, ls.wi, dist)) {
            if (ls.delta) {
              L += beta * f * ls.Li / lightPick;
            } else {
              float lp = ls.pdf * lightPick;
              float w = powerHeuristic(lp, m.pdf(wo, wiLocal));
              L += beta * f * ls.Li * (w / lp);
            }
          }
        }
      }
    }

    BsdfSample bs;
    float uLobe = rng.next1D(), u1 = rng.next1D(), u2 = rng.next1D();
    if (!m.sample(wo, uLobe, u1, u2, bs)) break;
    beta *= bs.weight;
    Vec3 wi = frame.toWorld(bs.wi);
    lastDelta = bs.delta;
    lastPdf = bs.pdf;
    lastP = hit.p;
    ray.o = offsetRayOrigin(hit.p, hit.ng, wi, hit.eps);
    ray.d = wi;
    ray.tmin = 0;
    ray.tmax = kInf;

    if (depth + 1 >= rs.rrDepth) {
      // Survive with probability min(1, max throughput): bright paths are never cut.
      float q = 1.0f - maxComponent(beta);
      if (q > 0) {
        if (rng.next1D() < q) break;
        beta /= (1.0f - q);
      }
    }
    if (!isFinite(beta) || isBlack(beta)) break;
  }
  if (stats) stats->bounces = depth;
  return isFinite(L) ? L : Vec3(0.0f);
}

}  // namespace granular
