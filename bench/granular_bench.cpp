// granular-bench — measurements behind bench/*.py (a tool, not a test).
//
//   granular-bench throughput [--grain-radius R] [--seconds S] [--raw-seconds S]
//     EPT ray casts per second through an aggregate against Embree's raw rtcIntersect1
//     rate on the same prototype mesh (and rtcIntersect16 on the same kind of rays in
//     packets of 16), single thread, in the same run: random rays, and rays recorded from
//     paths through clear glass grains cast with and without the grain they start at.
//     One JSON line.
//     --raw-seconds (default: --seconds) shortens the raw part, e.g. to profile the
//     aggregate alone (perf record ... --raw-seconds 0.01).
//   granular-bench setup --grains N
//     Set-up time and memory of an aggregate of about N grains. One JSON line.
//   granular-bench visits [--seconds S] [--absorption A]
//     The cost of a grain visit, explicit against proxy (proxy.h, ppt.h), single thread,
//     inside a ball of rock grains (R = 0.01, f = 0.6, IOR 1.5, absorption A per radius):
//     random walks from the ball's inner half, each visit the next grain met and the way
//     out of it — explicitly (Aggregate::intersect with the hints EPT gives, Material::sample
//     at each interface) or as a proxy (intersectProxy, hit(b), a table sample and its exit
//     point), the proxy also with one shadow ray (proxyTransmittance) per visit, as
//     next-event estimation casts near the surface. One JSON line.
//   granular-bench bulk [--rays N] [--absorption A] [--ior N]
//     The equivalent medium's transport deep inside, with no surface, against proxies and
//     explicit grains: N walks from the centre of a ball of 100 grain radii (rock grains,
//     f = 0.6, IOR N, absorption A per radius), each in one direction drawn for all three:
//     the medium (aggregateMedium, vpt.h's flights and phase), proxies (ppt.h's walk) and
//     explicit grains (Aggregate::intersect, Material::sample, Beer–Lambert inside); and the
//     exits model's medium (vpt.h), on random numbers of its own. The energy each brings to
//     its first passage through spheres of radius 2, 4, ..., 64 R about the start, with
//     standard errors. One JSON line.
//   granular-bench exits [--rays N] [--absorption A] [--ior N]
//     Where a grain lets light out, by the angle it turns it: N rays into the bounding
//     sphere of the walks' rock grain (IOR N, absorption A per radius), traced as TT
//     traces them (tt.h); per bin of the exit's cosine μ from the entering direction, the
//     energy share and the mean move from where the ray entered the sphere to where its
//     exit line leaves it, along the entering direction and across toward the exit's side,
//     in grain radii; beside TT's λ_s (which the medium adds to every flight). One JSON line.
//   granular-bench flights [--rays N] [--absorption A] [--ior N]
//     The flight after a grain, explicitly: N walks through the ball of bulk's rock grains
//     (IOR N, absorption A per radius) from its inner half, each grain's exit (reflected at
//     its surface or refracted out) followed to the next grain met, within 50 R of the
//     centre; per bin of the turn μ (from the direction the light met the grain in to the
//     one it leaves in), the exits, the mean flight from where the exit line leaves the
//     grain's sphere to where it enters the sphere of the next grain met (what the exits
//     model's flights stand for) and its standard error, and the mean of the flight that
//     brought the light to the grain; beside TT's λ_β, and over all exits the mean flight and
//     the mean of the exponential flight of the same mean square; the same two for walks
//     among the ball's proxies (each grain met scattering by its table, the flight to the
//     next grain met the packing's, Aggregate::flightToGrain). One JSON line.
//   granular-bench instanced --grains N [--density 1]
//     Explicit grains from a simulation (instanced_grains.h): N grains on a jittered cubic
//     lattice (icosphere and rock prototypes, random rotations and scales, bounding spheres
//     never touching), generated here so that 10^8 fit; the grid's build time and the
//     overlap check's, its bytes, and the process's peak RSS with the input arrays alone
//     and after the build. With --density 1 also the packing-rate grid the hybrid's medium
//     samples (grain_density.h: kernel 3 mean radii, voxels as wide, no fractions, as
//     Scene builds it): its time, bytes and working bytes, and the peak after it. CPU
//     seconds (all threads) beside each wall clock. One JSON line.
//   granular-bench tt [--rays N]
//     Teleportation-transport parameters (tt.h) of a few prototypes and materials, the
//     medium they give at R = 0.01, f = 0.6, and the (uncached) estimation time. One
//     JSON line per prototype and material.
//   granular-bench peaks [--rays N]
//     How peaked the proxies' grain scattering is (proxy.h), per b bin of a few prototypes
//     and materials: the hit chance and albedo, the table's largest density f (a cell's
//     mean over the channels, per steradian) and its ratio to an isotropic grain's,
//     albedo / 4π — what next-event estimation toward a point-like sun reads at worst —,
//     and the share of the energy a grain met sends straight on (the table's straight lobe:
//     within kStraightOnDegrees). One JSON line per prototype.
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <string>
#include <vector>

#include <random>

#include "core/aggregate.h"
#include "core/error.h"
#include "core/grain_density.h"
#include "core/instanced_grains.h"
#include "core/material.h"
#include "core/medium.h"
#include "core/proxy.h"
#include "core/shapes.h"
#include "core/tt.h"
#include "core/vpt.h"

using namespace granular;
using Clock = std::chrono::steady_clock;

namespace {

double seconds(Clock::time_point a) { return std::chrono::duration<double>(Clock::now() - a).count(); }
// This thread's CPU time: the walk comparisons run one thread, and time the scheduler
// gives to other processes on a shared machine is not theirs.
double threadSeconds() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) + 1e-9 * double(ts.tv_nsec);
}

long maxRssKiB() {
  struct rusage ru;
  getrusage(RUSAGE_SELF, &ru);
  return ru.ru_maxrss;
}

AggregateDesc sphereAggregate(float boundaryRadius, float R, int tileSpheres) {
  AggregateDesc a;
  a.name = "bench";
  a.boundary = makeIcosphere(4);
  a.xf = Transform::scale(Vec3(boundaryRadius));
  a.grainRadius = R;
  a.packingRate = 0.6f;
  a.seed = 1;
  a.tileSpheres = tileSpheres;
  a.prototypes = {GrainPrototypeDesc{"rock", makeRock(2, 0.2f, 1), 0}};
  a.weights = {1.0f};
  return a;
}

int throughput(float R, double budget, double rawBudget) {
  EmbreeDevice dev = makeEmbreeDevice();
  Aggregate agg;
  agg.build(sphereAggregate(1.0f, R, 512), dev, {0});
  const GrainPrototype& proto = agg.prototypes()[0];
  Rng rng(1);

  // Raw Embree: rays from a sphere of radius 2 towards random points of the unit ball.
  long raw = 0, rawHits = 0;
  auto t0 = Clock::now();
  while (seconds(t0) < rawBudget) {
    for (int i = 0; i < 4096; ++i) {
      Vec3 o = sampleUniformSphere(rng.next1D(), rng.next1D()) * 2.0f;
      Vec3 target = sampleUniformSphere(rng.next1D(), rng.next1D()) * std::cbrt(rng.next1D());
      RTCIntersectContext ctx;
      rtcInitIntersectContext(&ctx);
      RTCRayHit rh = makeRayHit(o, normalize(target - o), 0.0f, kInf);
      rtcIntersect1(proto.bvh.get(), &ctx, &rh);
      rawHits += rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
    }
    raw += 4096;
  }
  double rawRate = raw / seconds(t0);

  // The same rays as packets of 16 (rtcIntersect16): what the hybrid's bundles could gain
  // from Embree's packet API where their rays are alike (here: random, incoherent).
  long packet = 0;
  t0 = Clock::now();
  while (seconds(t0) < rawBudget) {
    for (int i = 0; i < 4096; i += 16) {
      RTCRayHit16 rh;
      alignas(64) int valid[16];
      for (int k = 0; k < 16; ++k) {
        Vec3 o = sampleUniformSphere(rng.next1D(), rng.next1D()) * 2.0f;
        Vec3 target = sampleUniformSphere(rng.next1D(), rng.next1D()) * std::cbrt(rng.next1D());
        Vec3 d = normalize(target - o);
        rh.ray.org_x[k] = o.x; rh.ray.org_y[k] = o.y; rh.ray.org_z[k] = o.z;
        rh.ray.dir_x[k] = d.x; rh.ray.dir_y[k] = d.y; rh.ray.dir_z[k] = d.z;
        rh.ray.tnear[k] = 0.0f; rh.ray.tfar[k] = kInf; rh.ray.time[k] = 0.0f;
        rh.ray.mask[k] = ~0u; rh.ray.id[k] = 0; rh.ray.flags[k] = 0;
        rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
        valid[k] = -1;
      }
      RTCIntersectContext ctx;
      rtcInitIntersectContext(&ctx);
      rtcIntersect16(valid, proto.bvh.get(), &ctx, &rh);
    }
    packet += 4096;
  }
  double packetRate = packet / seconds(t0);

  // Aggregate: the rays a path tracer casts — half from outside towards the object,
  // half from random points inside in random directions (scattered paths).
  long ept = 0, eptHits = 0;
  t0 = Clock::now();
  while (seconds(t0) < budget) {
    for (int i = 0; i < 4096; ++i) {
      Vec3 target = sampleUniformSphere(rng.next1D(), rng.next1D()) * std::cbrt(rng.next1D()) * 0.95f;
      Vec3 dir = sampleUniformSphere(rng.next1D(), rng.next1D());
      Vec3 o = (i & 1) ? target - dir * 3.0f : target;
      GrainHit h;
      eptHits += agg.intersect(o, dir, 0.0f, kInf, h);
    }
    ept += 4096;
  }
  double eptRate = ept / seconds(t0);

  // Path rays: the rays EPT casts through clear glass grains (IOR 1.5), recorded from
  // paths that enter from outside and scatter by the dielectric's Fresnel choice until
  // they leave (at most 256 bounces); each ray with the grain it starts at, the hint
  // Aggregate::intersect takes (inside it, or leaving it). Timed with and without hints.
  struct PathRay { Vec3 o, d; GrainHit from; bool hasFrom, inside; };
  std::vector<PathRay> rays;
  Material glass;
  glass.type = MaterialType::Dielectric;
  glass.ior = 1.5f;
  while (rays.size() < (1u << 18)) {
    Vec3 target = sampleUniformSphere(rng.next1D(), rng.next1D()) * std::cbrt(rng.next1D()) * 0.95f;
    Vec3 dir = sampleUniformSphere(rng.next1D(), rng.next1D());
    PathRay r{target - dir * 3.0f, dir, GrainHit(), false, false};
    for (int bounce = 0; bounce < 256; ++bounce) {
      rays.push_back(r);
      GrainHit h;
      if (!agg.intersect(r.o, r.d, 0.0f, kInf, h, r.hasFrom ? &r.from : nullptr, r.inside)) break;
      const Vec3 p = r.o + r.d * h.t;
      Frame frame(h.ng);
      BsdfSample bs;
      if (!glass.sample(frame.toLocal(-r.d), rng.next1D(), rng.next1D(), rng.next1D(), bs)) break;
      const Vec3 wi = frame.toWorld(bs.wi);
      r.inside = dot(wi, h.ng) < 0;
      r.o = offsetRayOrigin(p, h.ng, wi, kGrainEps * h.radius);
      r.d = wi;
      r.from = h;
      r.hasFrom = true;
    }
  }
  auto timePathRays = [&](bool hints, long& hits) {
    long n = 0;
    hits = 0;
    auto t = Clock::now();
    while (seconds(t) < budget) {
      for (const PathRay& r : rays) {
        GrainHit h;
        hits += agg.intersect(r.o, r.d, 0.0f, kInf, h, hints && r.hasFrom ? &r.from : nullptr, r.inside);
      }
      n += long(rays.size());
    }
    return n / seconds(t);
  };
  long hintedHits = 0, plainHits = 0;
  const double pathRate = timePathRays(true, hintedHits), plainPathRate = timePathRays(false, plainHits);
  long insideRays = 0;
  for (const PathRay& r : rays) insideRays += r.hasFrom && r.inside;
  std::printf(
      "{\"grain_radius\": %g, \"grains\": %.4g, \"embree_rays_per_s\": %.4g, \"embree_packet16_rays_per_s\": %.4g, "
      "\"embree_hit_fraction\": %.3f, "
      "\"aggregate_rays_per_s\": %.4g, \"aggregate_hit_fraction\": %.3f, \"ratio\": %.3f, "
      "\"path_rays_per_s\": %.4g, \"path_rays_no_hint_per_s\": %.4g, \"path_inside_fraction\": %.3f, "
      "\"path_ratio\": %.3f}\n",
      R, agg.stats().approxGrains, rawRate, packetRate, double(rawHits) / raw, eptRate, double(eptHits) / ept,
      eptRate / rawRate, pathRate, plainPathRate, double(insideRays) / double(rays.size()), pathRate / rawRate);
  return 0;
}

int setup(double grains, int tileSpheres) {
  const float R = 1.0f, f = 0.6f;
  float radius = R * float(std::cbrt(grains / f));  // ball volume * f / grain volume = grains
  long rss0 = maxRssKiB();
  auto t0 = Clock::now();
  EmbreeDevice dev = makeEmbreeDevice();
  Aggregate agg;
  agg.build(sphereAggregate(radius, R, tileSpheres), dev, {0});
  double t = seconds(t0);
  // Touch the aggregate once so lazy structures count.
  GrainHit h;
  agg.intersect(Vec3(-2 * radius, 0.1f, 0.2f), Vec3(1, 0, 0), 0, kInf, h);
  const AggregateStats& s = agg.stats();
  std::printf(
      "{\"requested_grains\": %.3g, \"grains\": %.4g, \"tile_spheres\": %d, \"cells\": %lld, \"setup_s\": %.3f, \"tile_s\": %.3f, "
      "\"sdf_s\": %.3f, \"aggregate_mib\": %.2f, \"peak_rss_mib\": %.1f, \"rss_growth_mib\": %.1f}\n",
      grains, s.approxGrains, tileSpheres, (long long)s.cells, t, s.tileSeconds, s.sdfSeconds, s.memoryBytes / 1048576.0,
      maxRssKiB() / 1024.0, (maxRssKiB() - rss0) / 1024.0);
  return 0;
}

std::string triple(const std::array<double, 3>& v) {
  char b[96];
  std::snprintf(b, sizeof b, "[%.6g, %.6g, %.6g]", v[0], v[1], v[2]);
  return b;
}
std::string triple(const Vec3& v) { return triple(std::array<double, 3>{v.x, v.y, v.z}); }

int ttParams(long rays) {
  EmbreeDevice dev = makeEmbreeDevice();
  struct Proto { const char* name; TriangleMesh mesh; };
  const Proto protos[] = {{"sphere", makeIcosphere(4)},
                          {"rock", makeRock(3, 0.3f, 1)},
                          {"ellipsoid", makeEllipsoid(Vec3(1.0f, 0.6f, 0.4f), 4)}};
  struct Mat { const char* name; Vec3 absorption; };
  const Mat mats[] = {{"clear", Vec3(0.0f)}, {"absorbing", Vec3(0.1f, 0.3f, 1.0f)}};
  for (const Proto& p : protos) {
    // Normalised into the unit bounding sphere exactly as an aggregate does.
    TriangleMesh unit = makeGrainPrototype(dev, GrainPrototypeDesc{p.name, p.mesh, 0}).mesh;
    for (const Mat& mm : mats) {
      Material m;
      m.type = MaterialType::Dielectric;
      m.ior = 1.5f;
      m.absorption = mm.absorption;
      TTOptions o;
      o.rays = rays;
      o.useCache = false;
      auto t0 = Clock::now();
      GrainTransport g = estimateGrainTransport(unit, m, o);
      double t = seconds(t0);
      MediumParams med = deriveMedium({g}, {1.0f}, 0.01f, 0.6f);
      std::printf(
          "{\"prototype\": \"%s\", \"material\": \"%s\", \"absorption\": %s, \"rays\": %lld, \"seconds\": %.3f, "
          "\"beta\": %.6g, \"beta_se\": %.3g, \"lambda_delta\": %.6g, \"lambda_delta_se\": %.3g, "
          "\"lambda_s\": %s, \"lambda_s_se\": %s, \"albedo\": %s, \"albedo_se\": %s, \"g\": %s, \"g_se\": %s, "
          "\"truncated\": %lld, \"sigma_t\": %s, \"mean_free_path\": %s, \"lambda_beta\": %.6g, "
          "\"albedo_reduced\": %s, \"sigma_tr\": %s}\n",
          p.name, mm.name, triple(mm.absorption).c_str(), (long long)g.rays, t, g.beta, g.betaSE, g.lambdaDelta,
          g.lambdaDeltaSE, triple(g.lambdaS).c_str(), triple(g.lambdaSSE).c_str(), triple(g.albedo).c_str(),
          triple(g.albedoSE).c_str(), triple(g.g).c_str(), triple(g.gSE).c_str(), (long long)g.truncated,
          triple(med.sigmaT).c_str(), triple(med.meanFreePath()).c_str(), med.lambdaBeta.x,
          triple(med.albedoReduced).c_str(), triple(med.sigmaTr).c_str());
      std::fflush(stdout);
    }
  }
  return 0;
}

// One prototype's table and traced rays for `peaks`.
int peaks(long rays) {
  EmbreeDevice dev = makeEmbreeDevice();
  struct Case { const char* name; TriangleMesh mesh; float ior; Vec3 absorption; };
  const Case cases[] = {{"icosphere2-clear", makeIcosphere(2), 1.5f, Vec3(0.02f)},
                        {"rock-amber", makeRock(3, 0.3f, 5), 1.55f, Vec3(0.1f, 0.5f, 1.4f)},
                        {"box-clear", makeBox(Vec3(-0.5f, -0.35f, -0.275f), Vec3(0.5f, 0.35f, 0.275f)), 1.5f,
                         Vec3(0.02f)}};
  for (const Case& c : cases) {
    TriangleMesh unit = makeGrainPrototype(dev, GrainPrototypeDesc{c.name, c.mesh, 0}).mesh;
    Material m;
    m.type = MaterialType::Dielectric;
    m.ior = c.ior;
    m.absorption = c.absorption;
    ProxyOptions o;
    o.rays = rays;
    o.useCache = false;
    const ProxyTable t = estimateProxyTable(unit, m, o);
    const int nb = t.bBins();
    // The largest density: the table evaluated on a grid finer than its bins.
    std::vector<double> peak(size_t(nb), 0.0);
    for (int b = 0; b < nb; ++b)
      for (int i = 0; i < 1024; ++i)
        for (int j = 0; j < 128; ++j) {
          const float th = kPi * (float(i) + 0.5f) / 1024.0f, ph = kPi * (float(j) + 0.5f) / 128.0f;
          const Vec3 f = t.eval(b, Vec3(std::sin(th) * std::cos(ph), std::sin(th) * std::sin(ph), std::cos(th))).f;
          peak[size_t(b)] = std::max(peak[size_t(b)], double(f.x + f.y + f.z) / 3.0);
        }
    std::string hit, albedo, pk, ratio, share;
    for (int b = 0; b < nb; ++b) {
      const Vec3 a = t.albedo(b), pass = t.pass(b);
      const double iso = double(a.x + a.y + a.z) / 3.0 / (4.0 * kPiD);
      const char* sep = b ? ", " : "";
      hit += str(sep, t.hitProbability(b));
      albedo += str(sep, double(a.x + a.y + a.z) / 3.0);
      pk += str(sep, peak[size_t(b)]);
      ratio += str(sep, iso > 0 ? peak[size_t(b)] / iso : 0.0);
      share += str(sep, a.x + a.y + a.z > 0 ? double(pass.x + pass.y + pass.z) / double(a.x + a.y + a.z) : 0.0);
    }
    std::printf(
        "{\"prototype\": \"%s\", \"ior\": %g, \"absorption\": %s, \"rays\": %ld, \"hit\": [%s], \"albedo\": [%s], "
        "\"peak_f\": [%s], \"peak_over_isotropic\": [%s], \"straight_on_share\": [%s]}\n",
        c.name, double(c.ior), triple(c.absorption).c_str(), rays, hit.c_str(), albedo.c_str(), pk.c_str(),
        ratio.c_str(), share.c_str());
    std::fflush(stdout);
  }
  return 0;
}

// A proxy walk's next sphere entered from o along d (not the one it leaves, once started):
// the grain, its entry frame, its table and b bin. False when no sphere is ahead.
struct ProxyEntry {
  GrainHit h;
  ProxyFrame frame{Vec3(0, 0, 1), Vec3(0.0f)};
  const ProxyTable* table = nullptr;
  int b = 0;
};
// The entry of a ray along d into grain h's sphere at `at`.
ProxyEntry proxyEntry(const Aggregate& agg, const ProxyTables& tables, const GrainHit& h, const Vec3& d,
                      const Vec3& at) {
  ProxyEntry e;
  e.h = h;
  e.table = &tables.at(h.prototype, h.radius / agg.grainRadius());
  e.frame = ProxyFrame(d, (at - h.center) / h.radius);
  e.b = e.table->bBin(e.frame.b);
  return e;
}
bool enterProxy(const Aggregate& agg, const ProxyTables& tables, const Vec3& o, const Vec3& d, GrainHit& from,
                bool& started, ProxyEntry& e) {
  GrainHit h;
  if (!agg.intersectProxy(o, d, 0.0f, kInf, h, started ? &from : nullptr)) return false;
  e = proxyEntry(agg, tables, h, d, o + d * h.t);
  from = e.h;
  started = true;
  return true;
}

// A grain met at a proxy entry scatters by its table: the direction and its weight in s,
// the point it leaves from in o. False when nothing leaves the grain.
bool scatterByTable(const ProxyEntry& e, Rng& r, ProxyDirection& s, Vec3& o) {
  if (!e.table->sample(e.b, r.next1D(), r.next1D(), r.next1D(), r.next1D(), s)) return false;
  o = e.h.center + e.frame.toWorld(e.table->exitPoint(e.b, s, r.next1D())) * e.h.radius;
  return true;
}

// An explicit walk through the grains as EPT makes it: the next interface from o along d
// (with the hints EPT gives), where Material::sample turns the ray.
struct ExplicitWalk {
  Vec3 o, d;
  GrainHit from;
  bool hinted = false, inside = false;
  // One interface: h the grain met (h.t travelled, inside it where `inside` was true
  // before), at its point, bs the sample taken there; false when none is met or sampled.
  bool step(const Aggregate& agg, const Material& m, Rng& rng, GrainHit& h, Vec3& at, BsdfSample& bs) {
    if (!agg.intersect(o, d, 0.0f, kInf, h, hinted ? &from : nullptr, inside)) return false;
    at = o + d * h.t;
    const Frame frame(h.ng);
    if (!m.sample(frame.toLocal(-d), rng.next1D(), rng.next1D(), rng.next1D(), bs)) return false;
    d = normalize(frame.toWorld(bs.wi));
    inside = dot(d, h.ng) < 0;
    o = offsetRayOrigin(at, h.ng, d, kGrainEps * h.radius);
    from = h;
    hinted = true;
    return true;
  }
};

// The walks' grain material: a smooth dielectric of the given IOR and absorption per radius.
Material rockMaterial(float ior, float absorption) {
  MaterialDesc md;
  md.type = MaterialType::Dielectric;
  md.ior = ior;
  md.absorption = Vec3(absorption);
  return Material::fromDesc(md);
}

// The walks' ball: radius 1, rock grains of R = 0.01 packed at f = 0.6 (sphereAggregate), of
// rockMaterial, proxies prepared and the prototype's table.
struct RockBall {
  AggregateDesc desc = sphereAggregate(1.0f, 0.01f, 512);
  Aggregate agg;
  Material m;
  ProxyTables tables;
  RockBall(float ior, float absorption) : m(rockMaterial(ior, absorption)) {
    agg.build(desc, makeEmbreeDevice(), {0});
    agg.prepareProxies();
    tables.add(0, 1.0f, estimateProxyTable(agg.prototypes()[0].mesh, m, ProxyOptions()));
  }
};

// A start of a walk: a random point of the ball's inner half, a random direction.
void walkStart(Rng& rng, Vec3& o, Vec3& d) {
  o = sampleUniformSphere(rng.next1D(), rng.next1D()) * (0.5f * std::cbrt(rng.next1D()));
  d = sampleUniformSphere(rng.next1D(), rng.next1D());
}

int visits(double budget, float absorption) {
  const RockBall ball(1.5f, absorption);
  const Aggregate& agg = ball.agg;
  const ProxyTables& tables = ball.tables;
  const float R = agg.grainRadius();
  constexpr int kVisitsPerWalk = 32;

  // Explicit: each visit traces rays until the path is out of the grain it met.
  long explicitVisits = 0, events = 0;
  Rng rng(7);
  const double t0 = threadSeconds();
  while (threadSeconds() - t0 < budget) {
    ExplicitWalk walk;
    walkStart(rng, walk.o, walk.d);
    for (int v = 0; v < kVisitsPerWalk;) {
      GrainHit h;
      Vec3 at;
      BsdfSample bs;
      if (!walk.step(agg, ball.m, rng, h, at, bs)) break;
      ++events;
      if (!walk.inside) ++v, ++explicitVisits;
    }
  }
  const double explicitSeconds = threadSeconds() - t0;

  // Proxies: a sphere entered holds a grain with the chance hit(b); a grain met scatters
  // by the table. withShadow: one shadow ray per visit towards a fixed sun.
  auto proxyWalks = [&](bool withShadow, long& visited, long& crossings) {
    Rng r(11);
    visited = crossings = 0;
    const Vec3 sun = normalize(Vec3(0.3f, 1.0f, 0.2f));
    const double start = threadSeconds();
    while (threadSeconds() - start < budget) {
      Vec3 o, d;
      walkStart(r, o, d);
      GrainHit from;
      bool started = false;
      for (int v = 0; v < kVisitsPerWalk;) {
        ProxyEntry e;
        if (!enterProxy(agg, tables, o, d, from, started, e)) break;
        ++crossings;
        const GrainHit& h = e.h;
        const ProxyTable& t = *e.table;
        const ProxyFrame& frame = e.frame;
        const int b = e.b;
        if (r.next1D() >= t.hitProbability(b)) {  // crossed: on from its far side
          o = o + d * sphereFarSide(o - h.center, d, h.radius);
          continue;
        }
        if (withShadow) {
          const ProxyDirection toSun = t.eval(b, frame.toLocal(sun));
          const Vec3 exit = h.center + frame.toWorld(t.exitPoint(b, toSun, r.next1D())) * h.radius;
          agg.proxyTransmittance(exit, sun, 0.0f, kInf, tables, &h, r.nextU32());
        }
        ProxyDirection s;
        if (!scatterByTable(e, r, s, o)) break;
        d = normalize(frame.toWorld(s.w));
        ++v, ++visited;
      }
    }
    return threadSeconds() - start;
  };
  long proxyVisits, proxyCrossings, shadowVisits, shadowCrossings;
  const double proxySeconds = proxyWalks(false, proxyVisits, proxyCrossings);
  const double shadowSeconds = proxyWalks(true, shadowVisits, shadowCrossings);
  const double explicitCost = explicitSeconds / double(explicitVisits), proxyCost = proxySeconds / double(proxyVisits),
               shadowCost = shadowSeconds / double(shadowVisits);
  std::printf("{\"absorption\": %g, \"grain_radius\": %g, \"explicit_us_per_visit\": %.4f, "
              "\"explicit_events_per_visit\": %.3f, \"proxy_us_per_visit\": %.4f, \"proxy_spheres_per_visit\": %.3f, "
              "\"proxy_with_shadow_us_per_visit\": %.4f, \"explicit_over_proxy\": %.3f, "
              "\"explicit_over_proxy_with_shadow\": %.3f}\n",
              absorption, R, 1e6 * explicitCost, double(events) / double(explicitVisits), 1e6 * proxyCost,
              double(proxyCrossings) / double(proxyVisits), 1e6 * shadowCost, explicitCost / proxyCost,
              explicitCost / shadowCost);
  return 0;
}

// The medium's transport against the proxies' deep inside, with no surface: walks from the
// centre of a ball of 100 grain radii, each direction drawn once for both, scoring the
// energy each brings to its first passage through spheres of radius 2, 4, ..., 64 R. The
// exits model's medium (vpt.h) walks too, on random numbers of its own.
int bulk(long walks, float absorption, float ior) {
  const RockBall ball(ior, absorption);
  const Aggregate& agg = ball.agg;
  const MediumParams mp = aggregateMedium({&agg.prototypes()[0].mesh}, {ball.m}, ball.desc, 1.0);
  const HomogeneousMedium med(mp), exitsMed(mp, MediumModel::Exits);
  const float R = agg.grainRadius();
  constexpr int kRadii = 6;  // spheres of 2, 4, ..., 64 R
  struct Passages {
    float R;
    double sum[kRadii] = {}, sum2[kRadii] = {};
    double walk[kRadii] = {};
    int next = 0;
    long events = 0;
    // Scores what reaches each radius x has passed (the material is grey: one channel);
    // false once past the last.
    bool reach(const Vec3& x, float w) {
      while (next < kRadii && length(x) > float(2 << next) * R) walk[next++] = w;
      return next < kRadii;
    }
    void endWalk() {
      for (int k = 0; k < kRadii; ++k) sum[k] += walk[k], sum2[k] += walk[k] * walk[k], walk[k] = 0;
      next = 0;
    }
  } viaMedium{R}, viaExits{R}, viaProxies{R}, viaGrains{R};
  auto survive = [](float& w, Rng& r) {
    const float q = std::min(1.0f, w);
    if (q <= 0 || r.next1D() >= q) return false;
    w /= q;
    return true;
  };
  // vpt.h's flights and phase sampling (in the exits model, each scattering's move too).
  auto mediumWalk = [&](const HomogeneousMedium& m, Passages& p, Vec3 d, Rng& r) {
    Vec3 o(0.0f);
    float w = 1;
    for (int e = 0; e < 1 << 16; ++e) {
      ++p.events;
      const float t = m.sampleDistance(r.next1D(), r.next1D());
      w *= (m.transmittance(t) * m.sigmaT() * m.albedo() / m.distancePdf(t))[0];
      o = o + d * t;
      if (!p.reach(o, w)) break;
      Vec3 pw;
      float pdf;
      const Vec3 wi = d;
      d = normalize(m.samplePhase(d, r.next1D(), r.next1D(), r.next1D(), pw, pdf));
      w *= pw[0];
      if (m.movesLight()) {
        o = o + m.exitMove(wi, d, r.next1D(), r.next1D());
        if (!p.reach(o, w)) break;
      }
      if (e >= 3 && !survive(w, r)) break;
    }
    p.endWalk();
  };
  for (long i = 0; i < walks; ++i) {
    Rng r(hashInts(uint64_t(i), 0xb01cULL), 0);
    const Vec3 d0 = sampleUniformSphere(r.next1D(), r.next1D());
    mediumWalk(med, viaMedium, d0, r);
    Rng re(hashInts(uint64_t(i), 0xe817ULL), 0);
    mediumWalk(exitsMed, viaExits, d0, re);
    {  // proxies: ppt.h's walk
      Vec3 o(0.0f), d = d0;
      float w = 1;
      int visits = 0;
      GrainHit from;
      bool started = false;
      for (int event = 0; event < 1 << 18; ++event) {
        ++viaProxies.events;
        ProxyEntry e;
        if (!enterProxy(agg, ball.tables, o, d, from, started, e)) break;
        const GrainHit& h = e.h;
        const ProxyTable& t = *e.table;
        const ProxyFrame& frame = e.frame;
        const int b = e.b;
        if (r.next1D() >= t.hitProbability(b)) {  // crossed: on from its far side
          o = o + d * std::max(sphereFarSide(o - h.center, d, h.radius), h.t);
          if (!viaProxies.reach(o, w)) break;
          continue;
        }
        if (!viaProxies.reach(o + d * h.t, w)) break;
        ProxyDirection s;
        if (!scatterByTable(e, r, s, o)) break;
        w *= (s.f / s.pdf)[0];
        if (!viaProxies.reach(o, w)) break;
        if (s.straight) continue;
        d = normalize(frame.toWorld(s.w));
        if (++visits >= 3 && !survive(w, r)) break;
      }
      viaProxies.endWalk();
    }
    {  // explicit grains, the reference: EPT's interfaces and Beer–Lambert inside a grain
      ExplicitWalk walk;
      walk.o = Vec3(0.0f);
      walk.d = d0;
      float w = 1;
      int visits = 0;
      for (int e = 0; e < 1 << 18; ++e) {
        ++viaGrains.events;
        const bool wasInside = walk.inside;
        GrainHit h;
        Vec3 at;
        BsdfSample bs;
        if (!walk.step(agg, ball.m, r, h, at, bs)) break;
        if (wasInside) w *= std::exp(-absorption * h.t / h.radius);
        if (!viaGrains.reach(at, w)) break;
        w *= bs.weight[0];
        if (!walk.inside && ++visits >= 3 && !survive(w, r)) break;
      }
      viaGrains.endWalk();
    }
  }
  auto list = [&](const Passages& p, bool se) {
    std::string out;
    for (int k = 0; k < kRadii; ++k) {
      const double mean = p.sum[k] / double(walks);
      const double v = std::sqrt(std::max(0.0, p.sum2[k] / double(walks) - mean * mean) / double(walks));
      out += str(k ? ", " : "", se ? v : mean);
    }
    return out;
  };
  std::printf("{\"absorption\": %g, \"ior\": %g, \"walks\": %ld, \"sigma_t_R\": %g, \"albedo\": %g, \"g\": %g, "
              "\"medium_events_per_walk\": %.2f, \"proxy_spheres_per_walk\": %.2f, \"radii_R\": [2, 4, 8, 16, 32, 64], "
              "\"medium\": [%s], \"medium_se\": [%s], \"exits\": [%s], \"exits_se\": [%s], \"proxies\": [%s], "
              "\"proxies_se\": [%s], \"grains\": [%s], \"grains_se\": [%s]}\n",
              absorption, ior, walks, mp.sigmaT[0] * R, mp.albedo[0], mp.g[0],
              double(viaMedium.events) / double(walks), double(viaProxies.events) / double(walks),
              list(viaMedium, false).c_str(), list(viaMedium, true).c_str(), list(viaExits, false).c_str(),
              list(viaExits, true).c_str(), list(viaProxies, false).c_str(),
              list(viaProxies, true).c_str(), list(viaGrains, false).c_str(), list(viaGrains, true).c_str());
  return 0;
}

// The flight after a grain, by the angle the grain turned the light (the usage above).
int flights(long walks, float absorption, float ior) {
  const RockBall ball(ior, absorption);
  const Aggregate& agg = ball.agg;
  const MediumParams mp = aggregateMedium({&agg.prototypes()[0].mesh}, {ball.m}, ball.desc, 1.0);
  const float R = agg.grainRadius();
  constexpr int kBins = 8;  // μ in eighths of [−1, 1]
  double n[kBins] = {}, sum[kBins] = {}, sum2[kBins] = {}, prevN[kBins] = {}, prevSum[kBins] = {};
  for (long i = 0; i < walks; ++i) {
    Rng r(hashInts(uint64_t(i), 0xf11eULL), 0);
    ExplicitWalk walk;
    walkStart(r, walk.o, walk.d);
    Vec3 entryDir(0.0f), exitPoint(0.0f), exitDir(0.0f);
    float lastFlight = -1;   // the flight (sphere to sphere) that brought the light to the grain it is in
    int exitBin = -1;        // set while a flight from a grain's exit is under way
    for (int e = 0; e < 4096; ++e) {
      const bool wasInside = walk.inside;
      const Vec3 before = walk.d;
      GrainHit h;
      Vec3 at;
      BsdfSample bs;
      if (!walk.step(agg, ball.m, r, h, at, bs)) break;
      if (length(at) > 0.5f) break;  // deep inside only: no surface within 50 R
      if (!wasInside) {  // a grain met from outside: the flight from the last exit ends at its sphere
        float enter = 0, flight = -1;
        if (exitBin >= 0 && sphereNearSide(exitPoint - agg.grainCenter(h), exitDir, h.radius, enter)) {
          flight = std::max(0.0f, enter) / R;
          n[exitBin] += 1;
          sum[exitBin] += flight;
          sum2[exitBin] += double(flight) * flight;
          if (lastFlight >= 0) prevN[exitBin] += 1, prevSum[exitBin] += lastFlight;
        }
        lastFlight = flight;
        exitBin = -1;
        entryDir = before;
      }
      if (!walk.inside) {  // out of the grain (reflected at its surface, or refracted out): an exit
        exitPoint = walk.o + walk.d * sphereFarSide(walk.o - agg.grainCenter(h), walk.d, h.radius);
        exitDir = walk.d;
        exitBin = std::clamp(int((dot(entryDir, walk.d) + 1.0f) * 0.5f * kBins), 0, kBins - 1);
      }
    }
  }
  std::string rows;
  double all = 0, allSum = 0, allSum2 = 0;
  for (int k = 0; k < kBins; ++k) all += n[k], allSum += sum[k], allSum2 += sum2[k];
  for (int k = 0; k < kBins; ++k) {
    const double m = n[k] > 0 ? sum[k] / n[k] : 0;
    const double se = n[k] > 1 ? std::sqrt(std::max(0.0, sum2[k] / n[k] - m * m) / (n[k] - 1)) : 0;
    rows += str(k ? ", " : "", "{\"mu\": [", -1.0 + 2.0 * k / kBins, ", ", -1.0 + 2.0 * (k + 1) / kBins, "], \"exits\": ",
                int64_t(n[k]), ", \"flight_R\": ", m, ", \"flight_se\": ", se, ", \"flight_square_R2\": ",
                n[k] > 0 ? sum2[k] / n[k] : 0.0, ", \"previous_flight_R\": ",
                prevN[k] > 0 ? prevSum[k] / prevN[k] : 0.0, "}");
  }
  // The exponential flight of the same mean square: what the walk's spread depends on (tt.h,
  // exitsDiffusionMedium: 2 L² for flights of mean L).
  const double mean = all > 0 ? allSum / all : 0, rms = all > 0 ? std::sqrt(0.5 * allSum2 / all) : 0;
  // The same among proxies: each grain met scatters by its table (the straight lobe too: a
  // grain met), the flight from its exit point to the next grain met by the packing's flight
  // (Aggregate::flightToGrain, the exits model's first flight).
  double pN = 0, pSum = 0, pSum2 = 0;
  for (long i = 0; i < walks; ++i) {
    Rng r(hashInts(uint64_t(i), 0xf12eULL), 0);
    Vec3 o, d;
    walkStart(r, o, d);
    GrainFlight f = agg.flightToGrain(o, d, ball.tables, nullptr, r);
    for (int e = 0; e < 256 && f.met(); ++e) {
      const ProxyEntry entry = proxyEntry(agg, ball.tables, f.grain, d, f.entry);
      ProxyDirection s;
      if (!scatterByTable(entry, r, s, o)) break;
      if (length(o) > 0.5f) break;  // deep inside only, as above
      if (!s.straight) d = normalize(entry.frame.toWorld(s.w));
      f = agg.flightToGrain(o, d, ball.tables, &entry.h, r);
      if (!f.met()) break;
      const double t = f.t / R;
      pN += 1, pSum += t, pSum2 += t * t;
    }
  }
  const double pMean = pN > 0 ? pSum / pN : 0, pRms = pN > 0 ? std::sqrt(0.5 * pSum2 / pN) : 0;
  std::printf("{\"absorption\": %g, \"ior\": %g, \"walks\": %ld, \"lambda_beta_R\": %g, \"flight_R\": %g, "
              "\"exponential_of_the_same_mean_square_R\": %g, \"proxies_flight_R\": %g, "
              "\"proxies_exponential_of_the_same_mean_square_R\": %g, \"bins\": [%s]}\n",
              absorption, ior, walks, mp.lambdaBeta[0] / R, mean, rms, pMean, pRms, rows.c_str());
  return 0;
}

// Where a grain lets light out, by the angle it turns it (the usage above).
int exits(long rays, float absorption, float ior) {
  // The walks' grain alone (its prototype as the ball's aggregate makes it, and that
  // prototype's BVH): no packing, no proxies.
  const GrainPrototype grain = makeGrainPrototype(makeEmbreeDevice(), sphereAggregate(1.0f, 0.01f, 512).prototypes[0]);
  const TriangleMesh& mesh = grain.mesh;
  const Material m = rockMaterial(ior, absorption);
  constexpr int kBins = 16;
  double energy[kBins] = {}, along[kBins] = {}, across[kBins] = {};
  for (long i = 0; i < rays; ++i) {
    Rng rng(hashInts(uint64_t(i), 0xe715ULL), 0);
    Vec3 xi, wi;
    sampleSphereEntry(rng, xi, wi);
    const GrainPassage g = traceGrainPassage(grain.bvh.get(), mesh, m, 4096, xi, wi, rng);
    if (!g.hit || !(g.weight[0] > 0)) continue;
    const float mu = dot(wi, g.d), w = g.weight[0];
    const int k = std::clamp(int((mu + 1.0f) * 0.5f * kBins), 0, kBins - 1);
    const Vec3 move = g.o + g.d * sphereFarSide(g.o, g.d, 1.0f) - xi;
    const Vec3 side = g.d - wi * mu;
    energy[k] += w;
    along[k] += w * dot(move, wi);
    if (length2(side) > 1e-12f) across[k] += w * dot(move, normalize(side));
  }
  const GrainTransport tt = estimateGrainTransport(mesh, m);  // what aggregateMedium uses (cached)
  double total = 0, totalAlong = 0;
  for (int k = 0; k < kBins; ++k) total += energy[k], totalAlong += along[k];
  std::string bins;
  for (int k = 0; k < kBins; ++k)
    bins += str(k ? ", " : "", "{\"mu\": ", -1.0 + (k + 0.5) * 2.0 / kBins, ", \"share\": ", energy[k] / total,
                ", \"along\": ", energy[k] > 0 ? along[k] / energy[k] : 0.0, ", \"across\": ",
                energy[k] > 0 ? across[k] / energy[k] : 0.0, "}");
  std::printf("{\"ior\": %g, \"absorption\": %g, \"rays\": %ld, \"tt_lambda_s\": %.4f, \"mean_along\": %.4f, "
              "\"bins\": [%s]}\n",
              ior, absorption, rays, tt.lambdaS[0], totalAlong / total, bins.c_str());
  return 0;
}

// CPU seconds of this process, all threads.
double cpuSeconds() {
  struct rusage ru;
  getrusage(RUSAGE_SELF, &ru);
  return double(ru.ru_utime.tv_sec + ru.ru_stime.tv_sec) + 1e-6 * double(ru.ru_utime.tv_usec + ru.ru_stime.tv_usec);
}

int instanced(double n, bool density) {
  const long long count = (long long)n;
  const long long side = (long long)std::ceil(std::cbrt(double(count)));
  InstancedGrainsDesc d;
  d.name = "/Sim";
  d.prototypes = {GrainPrototypeDesc{"/Sim/Round", makeIcosphere(1), -1}, GrainPrototypeDesc{"/Sim/Rock", makeRock(1, 0.25f, 3), -1}};
  d.positions.resize(size_t(count));
  d.orientations.resize(size_t(count));
  d.scales.resize(size_t(count));
  d.protoIndices.resize(size_t(count));
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::normal_distribution<float> g(0.0f, 1.0f);
  for (long long i = 0; i < count; ++i) {
    const float x = float(i % side), y = float((i / side) % side), z = float(i / (side * side));
    d.positions[size_t(i)] = Vec3(x, y, z) * 2.7f + Vec3(u(rng), u(rng), u(rng)) * 0.08f;
    Quat q{g(rng), g(rng), g(rng), g(rng)};
    const float l = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
    d.orientations[size_t(i)] = Quat{q.w / l, q.x / l, q.y / l, q.z / l};
    d.scales[size_t(i)] = 0.8f + 0.2f * u(rng);
    d.protoIndices[size_t(i)] = u(rng) < 0.3f ? 1 : 0;
  }
  const long inputKb = maxRssKiB();
  InstancedGrains grains;
  const auto t0 = Clock::now();
  const double c0 = cpuSeconds();
  grains.build(std::move(d), makeEmbreeDevice(), true);  // moved: the arrays are not copied
  const double total = seconds(t0), totalCpu = cpuSeconds() - c0;
  const long builtKb = maxRssKiB();
  const InstancedGrainsStats& s = grains.stats();
  std::printf("{\"grains\": %lld, \"input_mib\": %.1f, \"grid_mib\": %.1f, \"bytes_per_grain\": %.2f, "
              "\"grid_s\": %.2f, \"overlap_check_s\": %.2f, \"build_s\": %.2f, \"build_cpu_s\": %.2f, "
              "\"peak_rss_input_mib\": %.0f, \"peak_rss_built_mib\": %.0f",
              (long long)s.grains, double(s.inputBytes) / 1048576.0, double(s.gridBytes) / 1048576.0, s.bytesPerGrain(),
              s.buildSeconds, s.overlapSeconds, total, totalCpu, double(inputKb) / 1024.0, double(builtKb) / 1024.0);
  if (density) {
    // As Scene::buildInstancedMedium: the kernel of 3 mean bounding radii, voxels as wide.
    double radii = 0;
    for (int64_t i = 0; i < s.grains; ++i) radii += grains.grain(i).radius;
    GrainDensityOptions options;
    options.kernelWidth = float(3.0 * radii / double(std::max<int64_t>(1, s.grains)));
    options.voxelSize = options.kernelWidth;
    options.fractions = false;
    const double c1 = cpuSeconds();
    const GrainDensity g = buildGrainDensity(grains.desc(), options);
    std::printf(", \"density_s\": %.2f, \"density_cpu_s\": %.2f, \"density_mib\": %.1f, \"density_build_mib\": %.1f, "
                "\"leaves\": %lld, \"peak_rss_density_mib\": %.0f",
                g.stats.seconds, cpuSeconds() - c1, double(g.stats.bytes) / 1048576.0,
                double(g.stats.buildBytes) / 1048576.0, (long long)g.stats.leaves, double(maxRssKiB()) / 1024.0);
  }
  std::printf("}\n");
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2) {
    std::fprintf(stderr,
                 "usage: granular-bench throughput [--grain-radius R] [--seconds S] [--raw-seconds S] | setup --grains N "
                 "[--tile-spheres T] | instanced --grains N [--density 1] | "
                 "tt [--rays N] | peaks [--rays N] | visits [--seconds S] [--absorption A] |\n"
                 "  bulk [--rays N] [--absorption A] [--ior N] | exits [--rays N] [--absorption A] [--ior N] |\n"
                 "  flights [--rays N] [--absorption A] [--ior N]\n");
    return 2;
  }
  std::string mode = argv[1];
  float R = 0.01f;
  double secs = 2.0, rawSecs = -1, grains = 1e6;
  long rays = 1L << 18;
  int tileSpheres = 512;
  float absorption = 0.05f, ior = 1.55f;
  bool density = false;
  for (int i = 2; i + 1 < argc; i += 2) {
    std::string a = argv[i];
    if (a == "--grain-radius") R = std::strtof(argv[i + 1], nullptr);
    else if (a == "--seconds") secs = std::strtod(argv[i + 1], nullptr);
    else if (a == "--raw-seconds") rawSecs = std::strtod(argv[i + 1], nullptr);
    else if (a == "--grains") grains = std::strtod(argv[i + 1], nullptr);
    else if (a == "--rays") rays = std::strtol(argv[i + 1], nullptr, 10);
    else if (a == "--tile-spheres") tileSpheres = int(std::strtol(argv[i + 1], nullptr, 10));
    else if (a == "--absorption") absorption = std::strtof(argv[i + 1], nullptr);
    else if (a == "--ior") ior = std::strtof(argv[i + 1], nullptr);
    else if (a == "--density") density = std::strtol(argv[i + 1], nullptr, 10) != 0;
  }
  try {
    if (mode == "throughput") return throughput(R, secs, rawSecs < 0 ? secs : rawSecs);
    if (mode == "setup") return setup(grains, tileSpheres);
    if (mode == "tt") return ttParams(rays);
    if (mode == "peaks") return peaks(rays);
    if (mode == "instanced") return instanced(grains, density);
    if (mode == "visits") return visits(secs, absorption);
    if (mode == "bulk") return bulk(rays, absorption, ior);
    if (mode == "exits") return exits(rays, absorption, ior);
    if (mode == "flights") return flights(rays, absorption, ior);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "error: %s\n", e.what());
    return 1;
  }
  return 2;
}
