// proxy.h — grains as proxies (Müller et al. 2016, §4): a grain stands in the packing as
// its bounding sphere at its true position, and scatters by a grain scattering
// distribution tabulated once per prototype.
//
// Contract. estimateProxyTable() traces rays into one prototype's unit bounding sphere as
// TT does (tt.h: sampleSphereEntry, traceGrainPassage) and tabulates, by the impact
// parameter b of the entering ray (its distance from the centre, in radii; bins equal in
// b², so each holds the same share of the entering rays):
//   hit(b)       the chance that the ray meets the grain; else it crosses unchanged;
//   f_c(b, ω)    per channel, the energy that leaves into direction ω per steradian, per
//                ray that met the grain, but for what leaves straight on;
//   pass_c(b)    per channel, the energy that leaves straight on (within
//                kStraightOnDegrees of the entering direction), per ray that met the
//                grain: a lobe of its own, a delta (∫ f_c dω + pass_c is the albedo at b);
//   offsets      where rays leave: the exit line's offset from the centre, perpendicular
//                to its direction; up to offsetsPerBin of them per (b, direction bin), in
//                the order traced (a uniform sample, not weighted by energy).
//                The straight lobe's rays keep theirs likewise, per b bin.
// Why a straight lobe: a flat grain sends much of what it meets near its middle through
// parallel faces unturned (bench/README.md, "Straight through flat grains"), light that a
// density spreads over its 5.6° first bin and that next-event estimation toward a narrow
// sun meets only where the path lines up with it.
// As a delta it keeps its direction, and a shadow ray crosses a proxy with the chance
// crossing_c(b) = 1 − hit(b) + hit(b) pass_c(b), so sunlight through clear flat grains is
// found by every shadow ray, not by chance.
// Directions are in the entry's frame (ProxyFrame): z along the entering ray, x towards
// the side of the centre where it entered, y = z × x; bins equal in the polar angle θ and
// in φ ∈ [0, π], the mirror image y → −y folded onto y ≥ 0. Equal in θ, not in μ = cos θ:
// a flat grain sends light straight on through parallel faces and straight back, peaks at
// θ = 0 and π that 32 bins equal in μ would spread over 20° cones; equal in θ, 5.6°.
//
// Why that suffices: every grain is rotated uniformly at random, so averaged over its
// rotations the sphere's response depends on the entering ray only through b, and is
// symmetric under the mirror that keeps the entry plane (up to a grain's handedness).
// Where a ray leaves the sphere matters for what it meets next — the neighbours and the
// gaps between them, which keep the packing's shadowing — and the offsets keep it,
// conditioned on the exit direction. Lost: the correlation between two visits of one
// grain (a proxy is re-rotated at each visit), and within a bin any dependence of the
// exit offset on the energy left (absorbing grains).
//
// Sampling: the straight lobe with probability P = Σ_c pass_c / Σ_c albedo_c (weight_c =
// pass_c / P), else a direction bin with probability proportional to its Σ_c f_c mass,
// then ω uniform over the bin's solid angle (μ uniform between its edges, φ uniform) and
// a mirror side with 1/2 (pdf stated per steradian):
//   pdf(ω) = Σ_c f_c(b, ω) / Σ_c albedo_c(b),   weight_c = f_c(b, ω) / pdf(ω),
// so the pdf integrates to 1 − P. eval() gives the same f_c and pdf (next-event
// estimation, MIS); it never gives the straight lobe. A table is a pure
// function of (mesh, material, options) and is cached on disk like TT's parameters.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "material.h"
#include "math.h"
#include "mesh.h"
#include "rng.h"

namespace granular {

// What counts as straight on: an exit direction within this angle of the entering one.
// Parallel faces send rays exactly straight, so it need only be small.
constexpr double kStraightOnDegrees = 0.25;

// Crossings of proxy spheres whose grains a ray misses, per grain met, at most (a walk
// among proxies): far more than any packing puts along one ray before a grain is met (hit
// chances are ~0.5–0.9).
constexpr int kMaxProxyCrossings = 1 << 16;

struct ProxyOptions {
  int64_t rays = 1 << 20;
  int bBins = 8, muBins = 32, phiBins = 16;
  int offsetsPerBin = 16;
  int maxBounces = 4096;  // inside one grain (TTOptions::maxBounces)
  uint64_t seed = 1;
  bool useCache = true;
};

// The entry's frame of a ray of unit direction d that enters a sphere at offset v from
// its centre (in radii): b = |v − (v·d) d|.
struct ProxyFrame {
  Vec3 x, y, z;
  float b = 0;
  ProxyFrame(const Vec3& d, const Vec3& v) : z(d) {
    const Vec3 perp = v - d * dot(v, d);
    const float b2 = length2(perp);
    if (b2 > 1e-12f) {
      b = std::sqrt(b2);
      x = perp * (1.0f / b);
    } else {  // through the centre: every x is alike
      x = Frame(d).s;
    }
    b = std::min(b, 1.0f);
    y = cross(z, x);
  }
  Vec3 toLocal(const Vec3& w) const { return Vec3(dot(w, x), dot(w, y), dot(w, z)); }
  Vec3 toWorld(const Vec3& w) const { return x * w.x + y * w.y + z * w.z; }
};

// Where a ray at offset oc from a sphere's centre (unit direction d) leaves that sphere of
// radius r: the far root, at least 0 (a ray that misses it: its closest approach).
inline float sphereFarSide(const Vec3& oc, const Vec3& d, float r) {
  const float along = dot(oc, d);
  return std::max(0.0f, -along + std::sqrt(std::max(0.0f, r * r - length2(oc - d * along))));
}
// Where it enters that sphere: the near root (as a walk finds it), false where it misses.
inline bool sphereNearSide(const Vec3& oc, const Vec3& d, float r, float& t) {
  const float along = dot(oc, d), disc = r * r - length2(oc - d * along);
  t = -along - std::sqrt(std::max(0.0f, disc));
  return disc >= 0;
}

// A shadow ray's passage through proxies (Aggregate::proxyTransmittance): per channel the
// chance that light crosses the spheres on its line — the product of crossing_c(b), grains
// missed or left straight on —, and the chance that it meets no grain at all — the product
// of 1 − hit(b). The two differ by the light the straight lobe lets through, which the
// equivalent medium counts as scattered (TT: every grain met is a scattering event): next-
// event estimation among proxies takes the first only while the path goes on among proxies
// (ppt.h: PathState::pendingStraight).
struct ProxyShadow {
  Vec3 crossing{1.0f};
  float unscattered = 1.0f;
  ProxyShadow& operator*=(const ProxyShadow& o) {
    crossing *= o.crossing;
    unscattered *= o.unscattered;
    return *this;
  }
  bool blocked() const { return isBlack(crossing); }
};

// Russian roulette on a proxy shadow ray (the products above, over the spheres it
// crosses): deep inside they soon vanish, so once the crossing's largest channel m is under
// kProxyRoulette the ray goes on with probability m / kProxyRoulette, both products scaled
// by kProxyRoulette / m, else both are 0 (unbiased). The `draws`-th random number of
// `seed`; false when it ends.
constexpr float kProxyRoulette = 0.05f;
inline bool proxyRoulette(ProxyShadow& shadow, uint64_t seed, uint64_t& draws) {
  const float m = maxComponent(shadow.crossing);
  if (m >= kProxyRoulette) return true;
  if (!(m > 0) || toUnitFloat(hashInts(seed, draws++)) * kProxyRoulette >= m) {
    shadow = ProxyShadow{Vec3(0.0f), 0.0f};
    return false;
  }
  shadow.crossing *= kProxyRoulette / m;
  shadow.unscattered *= kProxyRoulette / m;
  return true;
}

// An exit direction drawn or evaluated in the entry's frame.
struct ProxyDirection {
  Vec3 w;                 // unit, local
  Vec3 f{0.0f};           // f_c(b, ω) per steradian
  float pdf = 0;          // per steradian
  int bin = -1;           // its direction bin (folded); -1: none, or the straight lobe
  bool mirrored = false;  // w.y < 0 (the folded bin's mirror image)
  bool straight = false;  // the straight lobe: w = (0, 0, 1), f = pass_c, pdf its probability
};

class ProxyTable {
 public:
  int bBin(float b) const { return std::clamp(int(b * b * float(nb_)), 0, nb_ - 1); }
  float hitProbability(int bBin) const { return hit_[size_t(bBin)]; }
  const Vec3& albedo(int bBin) const { return albedo_[size_t(bBin)]; }
  // The straight lobe's energy per ray that met the grain, per channel.
  const Vec3& pass(int bBin) const { return pass_[size_t(bBin)]; }
  // The chance per channel that light crosses the sphere on its line: the grain missed, or
  // met and left straight on (a shadow ray's factor).
  Vec3 crossing(int bBin) const {
    const float h = hit_[size_t(bBin)];
    return Vec3(1.0f - h) + pass_[size_t(bBin)] * h;
  }
  ProxyShadow shadow(int bBin) const { return ProxyShadow{crossing(bBin), 1.0f - hit_[size_t(bBin)]}; }
  // False when nothing leaves a grain met at this b (black grains): the path ends there.
  bool sample(int bBin, float uBin, float u1, float u2, float uSide, ProxyDirection& out) const;
  // f and pdf toward a local direction (both 0 in a bin no energy reaches).
  ProxyDirection eval(int bBin, const Vec3& wLocal) const;
  // Where a ray leaving in direction d crosses the unit sphere (local frame): one of the
  // bin's offsets (of the b bin's straight rays for the straight lobe), picked by u.
  Vec3 exitPoint(int bBin, const ProxyDirection& d, float u) const;

  int bBins() const { return nb_; }
  int directionBins() const { return nmu_ * nphi_; }
  int64_t rays() const { return rays_; }
  bool fromCache() const { return fromCache_; }
  // What the table was estimated from (mesh, material, options, its format): its cache
  // key. What is measured with a table (switching.h) is cached under it too.
  uint64_t key() const { return key_; }
  // The whole table's mean albedo over entering rays that met the grain, per channel,
  // and the hit chance over all entering rays (TT's α_s and β, tt.h, from the same kind of
  // rays: a check of the table).
  Vec3 meanAlbedo() const;
  float meanHitProbability() const;

 private:
  friend ProxyTable estimateProxyTable(const TriangleMesh&, const Material&, const ProxyOptions&);
  friend std::vector<char> serialiseProxyTable(const ProxyTable&, uint64_t);
  friend bool deserialiseProxyTable(const std::vector<char>&, uint64_t, ProxyTable&);
  int directionBin(const Vec3& folded) const;
  void setValue(int bBin, ProxyDirection& d) const;  // d.f and d.pdf of d.bin
  float binSolidAngle(int muBin) const;  // both mirror sides
  int nb_ = 0, nmu_ = 0, nphi_ = 0;
  std::vector<float> hit_;              // per b bin
  std::vector<Vec3> albedo_;            // per b bin
  std::vector<Vec3> pass_;              // per b bin
  std::vector<Vec3> f_;                 // per (b, direction) bin, per steradian
  std::vector<float> cdf_;              // per b bin, nd + 1 values over its direction bins
  std::vector<float> offsets_;          // (c1, c2) pairs: the exit offset in exitFrame()
  std::vector<uint32_t> offsetStart_;   // per (b, direction) bin, then per b bin's straight lobe: its first pair (CSR)
  size_t offsetCell(int bBin, const ProxyDirection& d) const {
    return d.straight ? size_t(nb_) * size_t(nmu_ * nphi_) + size_t(bBin)
                      : size_t(bBin) * size_t(nmu_ * nphi_) + size_t(d.bin);
  }
  // Per b bin, kGuides + 1 starting points of sample()'s search (the guide table of
  // Chen & Asau 1974): guide[j] is the last direction bin whose cdf is at most j/kGuides
  // of the total. Made from cdf_ (buildSamplingTables), not stored, as is phiStart_.
  static constexpr int kGuides = 64;
  std::vector<uint32_t> guide_;
  std::vector<float> phiStart_;  // (cos, sin) of each φ bin's start, for bins up to 0.2 wide
  // μ bins: their nmu_ + 1 edges, μ_k = −cos(π k / nmu_), and per cell of kMuCells equal
  // in μ the first bin it overlaps (directionBin's start, so it needs no arccosine).
  static constexpr int kMuCells = 1024;
  std::vector<float> muEdge_;
  std::vector<uint16_t> muCell_;
  void buildMuBins();
  void buildSamplingTables();  // from cdf_ and the μ bins
  int64_t rays_ = 0;
  uint64_t key_ = 0;
  bool fromCache_ = false;
};

// An aggregate's tables: per prototype, one per grain size (in units of the aggregate's
// grain radius R: absorption is per R, so a larger grain absorbs more across); a grain
// takes the table of the nearest size (a spread of sizes: the three Gauss–Legendre nodes
// aggregateMedium traces, tt.h).
class ProxyTables {
 public:
  void add(int prototype, float size, ProxyTable table);
  const ProxyTable& at(int prototype, float size) const;
  int prototypes() const { return int(tables_.size()); }
  // The tables' keys and sizes hashed together, prototype by prototype.
  uint64_t key() const;

 private:
  std::vector<std::vector<float>> sizes_;
  std::vector<std::vector<ProxyTable>> tables_;
};

// Throws InputError for options out of range or an empty mesh. prototypeMesh: normalised
// into its unit bounding sphere (GrainPrototype); the material's absorption is per radius.
ProxyTable estimateProxyTable(const TriangleMesh& prototypeMesh, const Material& material,
                              const ProxyOptions& options = ProxyOptions());

}  // namespace granular
