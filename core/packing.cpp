// packing.cpp — Lubachevsky–Stillinger growth of hard spheres in a periodic cube.
//
// Event-driven MD after Skoge, Donev, Stillinger, Torquato 2006 (PRE 74, 041127): spheres fly
// ballistically, all diameters grow as D(t) = d0 + g*t, and the next event is either a pair
// collision or a sphere leaving its cell of a grid whose cells are at least one final diameter
// wide. Each sphere keeps one scheduled event (its earliest); an event is stale when its owner
// was rescheduled (version) or its partner changed velocity (collision count). Every pair's true
// contact time is then never earlier than the earlier of the two spheres' scheduled events,
// so popping the queue in order never misses a collision.
// The growth is chaotic: a single rounding changed anywhere gives another tile. So the
// neighbour search, nearly all of the time, is made fast without changing one operation
// or its order: the spheres' motion lives in their cells' slots (a search reads a few
// contiguous runs), the neighbours are gathered and their quadratics computed with no
// data-dependent branch, and only then are the survivors taken in the original order
// (tests/core/test_packing.cpp holds checksums of tiles packed before the change).
#include "packing.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <queue>
#include <stdexcept>

#include "cache.h"
#include "error.h"
#include "rng.h"

namespace granular {

namespace {

constexpr double kInfD = std::numeric_limits<double>::infinity();
constexpr double kMaxPackingRate = 0.64;
constexpr int kMaxSpheres = 100000;

// Growth rates (TileGrowth) are of the diameter in units of (final diameter) x (thermal speed
// sqrt(kT/m) = 1): Skoge's dimensionless compression rate gamma with the final diameter as
// unit length. Faster growth jams at lower densities; the default final rate, 0.1, reaches
// 0.63 reliably (see the tests). Its fast stage (1.0) stops at f <= 0.5, far below where
// fast growth jams (growth at 1.0 throughout still reaches 0.6).
// On jamming, retry from the same initial state with slower growth (denser jammed states).
constexpr double kSlowdown = 4.0;
constexpr int kAttempts = 3;
// Reduced pressure p = PV/(NkT) above which the packing counts as jammed: near jamming
// p ~ 3 / (1 - f/f_J), so this means f is within ~3e-5 of its jamming density.
constexpr double kJamPressure = 1e5;
// Guard against endless loops (bugs): events per attempt, per sphere.
constexpr uint64_t kEventsPerSphere = 200000;

double packingRateOf(int n, double r) { return n * (4.0 / 3.0) * kPiD * r * r * r; }

// Largest change of a minimum-image distance when both centres in [0,1] are rounded to float:
// each coordinate moves by at most 2^-25, a difference by 2^-24, a length by sqrt(3) 2^-24.
constexpr double kFloatRoundingGap = 1.7320508075688772 * 0x1p-24;

// A sphere's motion: position x at time t, velocity v, and its relative diameter a (the
// pair terms need it). Kept in its cell's slots (LsSystem), so that a neighbour search
// reads the 27 cells' spheres from a few contiguous runs instead of chasing indices.
struct Body {
  double x[3];
  double v[3];
  double t;
  double a;
};
static_assert(sizeof(Body) == 64, "a body is a cache line's worth");

struct Event {
  double t;
  int i;         // owner
  int j;         // collision partner, or -1 for a cell crossing
  uint32_t version;           // owner's version when scheduled
  uint32_t partnerCollisions; // partner's collision count when scheduled
  int8_t axis, dir;           // cell crossing: axis and direction (+1 / -1)
};

struct LaterFirst {
  bool operator()(const Event& a, const Event& b) const { return a.t > b.t; }
};

// The coefficients of |dx + dv tau|^2 - (D + g tau)^2 = A tau^2 + 2B tau + C.
struct Quadratic {
  double A, B, C;
};

Quadratic contactQuadratic(const double dx[3], const double dv[3], double D, double g) {
  return {dv[0] * dv[0] + dv[1] * dv[1] + dv[2] * dv[2] - g * g, dx[0] * dv[0] + dx[1] * dv[1] + dx[2] * dv[2] - D * g,
          dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2] - D * D};
}

// Earliest tau >= 0 at which |dx + dv tau| = D + g tau (spheres touching, diameters growing),
// or +inf. Roots of A tau^2 + 2B tau + C, written in the cancellation-free form.
double contactTime(const Quadratic& q) {
  const double A = q.A, B = q.B, C = q.C;
  if (C <= 0) {  // touching (or overlapping by rounding)
    if (B < 0) return 0;
    if (A >= 0) return kInfD;
    double disc = B * B - A * C;  // <= B^2 here
    return disc >= 0 ? (B + std::sqrt(disc)) / -A : 0.0;
  }
  if (A < 0) {  // the growth outruns the relative speed: contact is certain
    double disc = B * B - A * C;
    return B <= 0 ? C / (-B + std::sqrt(disc)) : (-B - std::sqrt(disc)) / A;
  }
  if (B >= 0) return kInfD;
  double disc = B * B - A * C;
  if (disc < 0) return kInfD;
  return C / (-B + std::sqrt(disc));
}

class LsSystem {
 public:
  // dStop: diameter at which growth stops; gamma: dimensionless growth rate.
  // a: each sphere's diameter relative to the largest (empty: all 1); a pair touches when
  // its centres are (a_i + a_j)/2 · D apart, D the largest diameter.
  LsSystem(int n, double dStop, double gamma, uint64_t seed, const std::vector<double>& a = {})
      : n_(n), dStop_(dStop), equal_(a.empty()) {
    g_ = gamma * dStop;
    // Cells at least one final diameter wide (with a margin for rounding), and not many more
    // cells than spheres (tiny targets would otherwise ask for huge grids).
    int nc = int(std::floor(1.0 / (dStop * (1.0 + 1e-9))));
    int ncCap = std::max(1, int(std::cbrt(2.0 * n)));
    nc_ = std::max(1, std::min(nc, ncCap));
    const size_t cells = size_t(nc_) * nc_ * nc_;
    count_.assign(cells, 0);
    bodies_.resize(cells * size_t(capacity_));
    ids_.resize(bodies_.size());
    cell_.resize(size_t(n));
    home_.resize(size_t(n));
    slot_.resize(size_t(n));
    version_.assign(size_t(n), 0);
    collisions_.assign(size_t(n), 0);

    Rng rng(hashInts(seed, 0x4c53u /* "LS" */), 0x70616b);
    std::vector<Body> init(static_cast<size_t>(n));
    double mean[3] = {0, 0, 0};
    for (int i = 0; i < n; ++i) {
      Body& b = init[size_t(i)];
      b.t = 0;
      b.a = a.empty() ? 1.0 : a[size_t(i)];
      for (int k = 0; k < 3; ++k) {
        b.x[k] = rng.nextDouble();
        cell_[size_t(i)].c[k] = std::min(nc_ - 1, int(b.x[k] * nc_));
      }
      // Gaussian velocities (Box–Muller), kT/m = 1 per component.
      for (int k = 0; k < 3; ++k) {
        double u1 = 1.0 - rng.nextDouble(), u2 = rng.nextDouble();
        b.v[k] = std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPiD * u2);
        mean[k] += b.v[k] / n;
      }
    }
    for (Body& b : init)
      for (int k = 0; k < 3; ++k) b.v[k] -= mean[k];  // zero momentum: no drift of the tile
    for (int i = 0; i < n; ++i) insert(i, init[size_t(i)]);
    normaliseKineticEnergy();
  }

  // Runs until the diameter reaches dUntil (<= dStop; true) or the packing jams first (false).
  bool run(double dUntil) {
    dUntil_ = dUntil;
    tStop_ = (dUntil_ - d0_) / g_;
    scheduleAll();
    const uint64_t budget = kEventsPerSphere * uint64_t(n_) + 10000000ull;
    uint64_t events = 0;
    const uint64_t epochLength = std::max<uint64_t>(4 * uint64_t(n_), 1000);
    while (!queue_.empty() && queue_.top().t < tStop_) {
      Event e = queue_.top();
      queue_.pop();
      if (++events > budget)
        throw std::runtime_error(str("tile: Lubachevsky-Stillinger growth of ", n_, " spheres exceeded its budget of ",
                                     budget, " events at f=", packingRateOf(n_, 0.5 * diameter()), " (a bug)"));
      if (e.version != version_[size_t(e.i)]) continue;  // superseded
      now_ = e.t;
      if (e.j < 0) {
        cross(e.i, e.axis, e.dir);
        schedule(e.i);
        continue;
      }
      if (collisions_[size_t(e.j)] != e.partnerCollisions) {  // partner changed course: look again
        schedule(e.i);
        continue;
      }
      collide(e.i, e.j);
      schedule(e.i);
      schedule(e.j);
      if (++epochCollisions_ >= epochLength && !endEpoch()) return false;
    }
    advanceAll(tStop_);
    now_ = tStop_;
    return true;
  }

  // Growth at another rate from now on (between two run()s): the clock restarts at 0 as at
  // an epoch's end, and a new epoch begins, its pressure from collisions at the new rate.
  void setRate(double gamma) {
    advanceAll(now_);
    d0_ = diameter();
    now_ = 0;
    forEachBody([](Body& a) { a.t = 0; });
    g_ = gamma * dStop_;
    virial_ = 0;
    epochCollisions_ = 0;
    normaliseKineticEnergy();
  }

  double diameter() const { return d0_ + g_ * now_; }
  // Sphere i's centre (advanced to the end by run()), not wrapped into [0, 1).
  const double* position(int i) const { return body(i).x; }

 private:
  struct Cell {
    int c[3];
  };

  int cellIndex(const int c[3]) const { return (c[2] * nc_ + c[1]) * nc_ + c[0]; }
  double bound(int c) const { return double(c) / double(nc_); }  // exact 0 and 1 at the ends
  Body& body(int i) { return bodies_[size_t(home_[size_t(i)]) * capacity_ + size_t(slot_[size_t(i)])]; }
  const Body& body(int i) const { return bodies_[size_t(home_[size_t(i)]) * capacity_ + size_t(slot_[size_t(i)])]; }

  // A cell's bodies fill its first count_ slots in the order of arrival; a removal moves
  // the last one into the hole. That order is the neighbour search's, so it decides ties.
  void insert(int i, const Body& b) {
    const int cell = cellIndex(cell_[size_t(i)].c);
    if (count_[size_t(cell)] == capacity_) grow();
    const int slot = count_[size_t(cell)]++;
    home_[size_t(i)] = cell;
    slot_[size_t(i)] = slot;
    bodies_[size_t(cell) * capacity_ + size_t(slot)] = b;
    ids_[size_t(cell) * capacity_ + size_t(slot)] = i;
  }
  Body remove(int i) {
    const size_t base = size_t(home_[size_t(i)]) * capacity_;
    const int slot = slot_[size_t(i)], last = --count_[size_t(home_[size_t(i)])];
    const Body b = bodies_[base + size_t(slot)];
    const int moved = ids_[base + size_t(last)];
    bodies_[base + size_t(slot)] = bodies_[base + size_t(last)];
    ids_[base + size_t(slot)] = moved;
    slot_[size_t(moved)] = slot;
    return b;
  }
  // More slots per cell for a crowded cell (mostly while the spheres are still small), and
  // fewer again at the end of an epoch once the cells have thinned out: the slots of the
  // 27 cells a search reads then stay in the cache.
  void grow() { relayout(2 * capacity_); }
  void shrinkToFit() {
    int most = *std::max_element(count_.begin(), count_.end()), fit = kFastSlots;
    while (fit < most) fit *= 2;
    if (fit < capacity_) relayout(fit);
  }
  void relayout(int slots) {
    std::vector<Body> bodies(count_.size() * size_t(slots));
    std::vector<int> ids(bodies.size());
    for (size_t c = 0; c < count_.size(); ++c)
      for (int s = 0; s < count_[c]; ++s) {
        bodies[c * slots + size_t(s)] = bodies_[c * capacity_ + size_t(s)];
        ids[c * slots + size_t(s)] = ids_[c * capacity_ + size_t(s)];
      }
    bodies_.swap(bodies);
    ids_.swap(ids);
    capacity_ = slots;
  }

  static void positionAt(const Body& a, double t, double out[3]) {
    for (int k = 0; k < 3; ++k) out[k] = a.x[k] + a.v[k] * (t - a.t);
  }
  static void advance(Body& a, double t) {
    for (int k = 0; k < 3; ++k) a.x[k] += a.v[k] * (t - a.t);
    a.t = t;
  }
  // Every body, in the spheres' order (the sums below are order-dependent).
  template <typename F>
  void forEachBody(F&& f) {
    for (int i = 0; i < n_; ++i) f(body(i));
  }
  void advanceAll(double t) {
    forEachBody([t](Body& a) { advance(a, t); });
  }

  void normaliseKineticEnergy() {
    double sum = 0;
    forEachBody([&sum](Body& a) { sum += a.v[0] * a.v[0] + a.v[1] * a.v[1] + a.v[2] * a.v[2]; });
    if (!(sum > 0)) return;  // a single sphere has nothing to move for
    double scale = std::sqrt(3.0 * n_ / sum);
    forEachBody([scale](Body& a) {
      for (double& v : a.v) v *= scale;
    });
  }

  // Finds sphere i's earliest event (cell crossing or contact with a neighbour's image) from now.
  // In two passes with the same arithmetic as one: the first computes every neighbour's
  // contact quadratic and drops, without a branch, the pairs that separate faster than
  // their surfaces grow; the second takes the rest in the same order against the running
  // earliest time. Same candidates, same order, same comparisons: the same event, bit for
  // bit, at a fraction of the mispredicted branches.
  void schedule(int i) {
    const Body& a = body(i);
    const int* ca = cell_[size_t(i)].c;
    double xa[3];
    positionAt(a, now_, xa);
    Event best{kInfD, i, -1, 0, 0, 0, 0};
    for (int k = 0; k < 3; ++k) {
      double dt = kInfD;
      if (a.v[k] > 0) dt = (bound(ca[k] + 1) - xa[k]) / a.v[k];
      else if (a.v[k] < 0) dt = (bound(ca[k]) - xa[k]) / a.v[k];
      dt = std::max(dt, 0.0);
      if (now_ + dt < best.t) {
        best.t = now_ + dt;
        best.axis = int8_t(k);
        best.dir = int8_t(a.v[k] > 0 ? 1 : -1);
      }
    }
    const double Dmax = diameter();
    // The 27 neighbour cells of the infinite periodic grid; with fewer than 3 cells a side the
    // same cell appears under different shifts, i.e. as different images, as it should.
    int cc[3][3];
    double shift[3][3];
    for (int k = 0; k < 3; ++k)
      for (int o = 0; o < 3; ++o) {
        int c = ca[k] + o - 1;
        shift[k][o] = 0;
        if (c < 0) { c += nc_; shift[k][o] = -1; }
        else if (c >= nc_) { c -= nc_; shift[k][o] = 1; }
        cc[k][o] = c;
      }
    // Gather the neighbours (own images stay >= 1 apart, and D <= 1 is checked up front).
    // A cell's first kFastSlots slots are copied whether filled or not and the count
    // advanced by its bodies: a cell's count (0 to 3 mostly) then costs no mispredicted
    // loop exit.
    const Body* self = &a;
    const int home = home_[size_t(i)];
    Gathered& G = gathered_;
    G.reserve(size_t(27 * capacity_ + kFastSlots));
    size_t m = 0;
    for (int oz = 0; oz < 3; ++oz)
      for (int oy = 0; oy < 3; ++oy)
        for (int ox = 0; ox < 3; ++ox) {
          const int cell = (cc[2][oz] * nc_ + cc[1][oy]) * nc_ + cc[0][ox];
          const Body* b = &bodies_[size_t(cell) * capacity_];
          const int count = count_[size_t(cell)];
          const int image = (oz * 3 + oy) * 3 + ox;
          if (cell == home || count > kFastSlots) {
            for (int s = 0; s < count; ++s) {
              if (b + s == self) continue;
              G.body[m] = b + s;
              G.image[m++] = image;
            }
            continue;
          }
          for (int s = 0; s < kFastSlots; ++s) {
            G.body[m + size_t(s)] = b + s;
            G.image[m + size_t(s)] = image;
          }
          m += size_t(count);
        }
    // Their contact quadratics; the pairs not dropped there are taken in order against the
    // running earliest time, as one loop over the cells would.
    double shifts[27][3];
    for (int oz = 0; oz < 3; ++oz)
      for (int oy = 0; oy < 3; ++oy)
        for (int ox = 0; ox < 3; ++ox) {
          double* sh = shifts[(oz * 3 + oy) * 3 + ox];
          sh[0] = shift[0][ox];
          sh[1] = shift[1][oy];
          sh[2] = shift[2][oz];
        }
    const size_t kept = equal_ ? quadratics<true>(a, xa, Dmax, shifts, m) : quadratics<false>(a, xa, Dmax, shifts, m);
    const Body* winner = nullptr;
    for (size_t r = 0; r < kept; ++r) {
      const Quadratic& q = G.q[r];
      // For A >= 0 the contact time is at least C / (-2B): skip if that is too late.
      if (q.A >= 0 && q.C > 0 && q.C >= -2.0 * q.B * (best.t - now_)) continue;
      double t = now_ + contactTime(q);
      if (t < best.t) {
        best.t = t;
        winner = G.keep[r];
      }
    }
    if (winner) best.j = ids_[size_t(winner - bodies_.data())];
    if (best.j >= 0) best.partnerCollisions = collisions_[size_t(best.j)];
    best.version = ++version_[size_t(i)];
    if (best.t < kInfD) queue_.push(best);
  }

  // schedule()'s contact quadratics of the m gathered neighbours, as contactQuadratic
  // computes them, and the cheap rejection without a branch: the pairs separating faster
  // than their surfaces grow are dropped. Returns how many are kept (in G.q and G.keep).
  // Equal spheres: every pair's factor (a_i + a_j)/2 is exactly 1, so D and g are the
  // largest diameter and its growth as they stand.
  template <bool kEqual>
  size_t quadratics(const Body& a, const double xa[3], double Dmax, const double (*shifts)[3], size_t m) {
    Gathered& G = gathered_;
    size_t kept = 0;
    for (size_t k = 0; k < m; ++k) {
      const Body& b = *G.body[k];
      const double* sh = shifts[G.image[k]];
      const double pair = kEqual ? 1.0 : 0.5 * (a.a + b.a);
      const double D = kEqual ? Dmax : pair * Dmax, g = kEqual ? g_ : pair * g_;
      double xb[3], d[3], dv[3];
      positionAt(b, now_, xb);
      for (int e = 0; e < 3; ++e) {
        d[e] = xb[e] + sh[e] - xa[e];
        dv[e] = b.v[e] - a.v[e];
      }
      // Field by field: a copy of the whole struct went through the stack and stalled
      // (a 16-byte load of two 8-byte stores cannot be forwarded).
      const Quadratic q = contactQuadratic(d, dv, D, g);
      Quadratic& out = G.q[kept];
      out.A = q.A;
      out.B = q.B;
      out.C = q.C;
      G.keep[kept] = G.body[k];
      kept += size_t(int(!(q.B >= 0)) | int(!(q.A >= 0)));
    }
    return kept;
  }

  void scheduleAll() {
    queue_ = {};
    for (int i = 0; i < n_; ++i) schedule(i);
  }

  void cross(int i, int axis, int dir) {
    advance(body(i), now_);
    Body a = remove(i);
    int* cell = cell_[size_t(i)].c;
    // Snap onto the face so rounding never lets a sphere drift out of its cell.
    if (dir > 0) {
      a.x[axis] = bound(++cell[axis]);
      if (cell[axis] == nc_) { cell[axis] = 0; a.x[axis] -= 1.0; }
    } else {
      a.x[axis] = bound(cell[axis]--);
      if (cell[axis] < 0) { cell[axis] = nc_ - 1; a.x[axis] += 1.0; }
    }
    insert(i, a);
  }

  // Elastic collision in the frame of the growing surfaces: the normal relative velocity u
  // becomes 2g - u, so the pair separates faster than its surfaces grow (Skoge et al. 2006).
  void collide(int i, int j) {
    Body& a = body(i);
    Body& b = body(j);
    advance(a, now_);
    advance(b, now_);
    double d[3], len2 = 0;
    for (int k = 0; k < 3; ++k) {
      d[k] = b.x[k] - a.x[k];
      d[k] -= std::round(d[k]);  // minimum image: the touching image is the nearest one
      len2 += d[k] * d[k];
    }
    double len = std::sqrt(len2);
    if (!(len > 0)) return;
    double u = 0;
    for (int k = 0; k < 3; ++k) u += (b.v[k] - a.v[k]) * d[k] / len;
    // The pair's contact distance grows at g = (a_i + a_j)/2 · g_.
    const double pair = 0.5 * (a.a + b.a), g = pair * g_;
    // Never leave a pair that would touch again at once (rounding, grazing contacts): the
    // floor keeps the contact-time numerator B = |d| u' - D g clearly positive.
    double uMin = g * pair * diameter() / len + 1e-3 * g;
    double u2 = std::max(u, std::max(2.0 * g - u, uMin));
    double impulse = 0.5 * (u2 - u);
    for (int k = 0; k < 3; ++k) {
      a.v[k] -= impulse * d[k] / len;
      b.v[k] += impulse * d[k] / len;
    }
    ++collisions_[size_t(i)];
    ++collisions_[size_t(j)];
    virial_ += len * impulse;
  }

  // Every epoch of collisions: measure the reduced pressure, put back the kinetic energy that
  // the growth pumped in, and restart the clock at 0 (keeps times small and exact).
  bool endEpoch() {
    advanceAll(now_);
    double sumV2 = 0;
    forEachBody([&sumV2](Body& a) { sumV2 += a.v[0] * a.v[0] + a.v[1] * a.v[1] + a.v[2] * a.v[2]; });
    // Virial: PV = NkT + sum(r.J) / (3 dt), with NkT = sum(m v^2) / 3.
    pressure_ = now_ > 0 && sumV2 > 0 ? 1.0 + virial_ / (now_ * sumV2) : kInfD;
    virial_ = 0;
    epochCollisions_ = 0;
    normaliseKineticEnergy();
    d0_ = diameter();
    now_ = 0;
    tStop_ = (dUntil_ - d0_) / g_;
    forEachBody([](Body& a) { a.t = 0; });
    shrinkToFit();
    scheduleAll();
    return !(pressure_ > kJamPressure);
  }

  // schedule()'s neighbours: their bodies, image shifts and ids; the quadratics of those
  // kept and where they are.
  struct Gathered {
    std::vector<const Body*> body, keep;
    std::vector<int> image;  // the neighbour cell, (oz * 3 + oy) * 3 + ox
    std::vector<Quadratic> q;
    void reserve(size_t n) {
      if (body.size() >= n) return;
      body.resize(n);
      keep.resize(n);
      image.resize(n);
      q.resize(n);
    }
  };
  static constexpr int kFastSlots = 4;

  int n_;
  double dStop_;        // the final diameter: the rate's unit
  double dUntil_ = 0;   // the diameter this run() stops at
  bool equal_;         // every sphere of one size
  double g_ = 0;       // diameter growth per unit time
  double d0_ = 0;      // diameter at time 0 of the current epoch
  double now_ = 0;
  double tStop_ = 0;
  int nc_ = 1;
  int capacity_ = kFastSlots;    // slots per cell
  std::vector<Body> bodies_;     // capacity_ slots per cell
  std::vector<int> ids_;         // the sphere in each slot
  std::vector<int> count_;       // bodies per cell
  std::vector<Cell> cell_;       // per sphere: its cell's coordinates,
  std::vector<int> home_, slot_; // its cell's index and its slot there,
  std::vector<uint32_t> version_;     // bumped when its scheduled event is replaced,
  std::vector<uint32_t> collisions_;  // bumped when its velocity changes
  Gathered gathered_;
  std::priority_queue<Event, std::vector<Event>, LaterFirst> queue_;
  uint64_t epochCollisions_ = 0;
  double virial_ = 0;
  double pressure_ = 1;
};

double minImage(double d) { return d - std::round(d); }

double pairDistance(const Vec3& a, const Vec3& b) {
  double dx = minImage(double(b.x) - a.x), dy = minImage(double(b.y) - a.y), dz = minImage(double(b.z) - a.z);
  return std::sqrt(dx * dx + dy * dy + dz * dz);
}

// Same quantity as minPeriodicGap, with a cell grid so it is cheap enough to run on every tile.
double minPeriodicGapFast(const Tile& t) {
  int n = int(t.centers.size());
  const double r = t.radius, D = 2.0 * r * t.maxSize();
  int nc = D > 0 ? int(std::floor(1.0 / (D * (1.0 + 1e-9)))) : 1;
  nc = std::min(nc, std::max(1, int(std::cbrt(2.0 * n))));
  if (nc < 3) return minPeriodicGap(t);
  std::vector<int> head(size_t(nc) * nc * nc, -1), next(n, -1);
  auto cellOf = [nc](float x) { return std::min(nc - 1, std::max(0, int(double(x) * nc))); };
  for (int i = 0; i < n; ++i) {
    const Vec3& c = t.centers[i];
    int idx = (cellOf(c.z) * nc + cellOf(c.y)) * nc + cellOf(c.x);
    next[i] = head[idx];
    head[idx] = i;
  }
  double best = 1.0 - D;  // own images
  for (int i = 0; i < n; ++i) {
    const Vec3& c = t.centers[i];
    int cx = cellOf(c.x), cy = cellOf(c.y), cz = cellOf(c.z);
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          int idx = (((cz + dz + nc) % nc) * nc + (cy + dy + nc) % nc) * nc + (cx + dx + nc) % nc;
          for (int j = head[idx]; j >= 0; j = next[j])
            if (j > i) best = std::min(best, pairDistance(c, t.centers[j]) - r * (double(t.size(i)) + t.size(j)));
        }
  }
  return best;
}

// Cache record (cache.h: RecordWriter) of a tile.
constexpr RecordMagic kMagic = {'G', 'R', 'T', 'I', 'L', 'E', '\0', '\0'};
// 2: sizes and classes of polydisperse tiles; 3: stratified sizes; 4: a fast growth stage.
constexpr uint32_t kTileFormatVersion = 4;
static_assert(sizeof(Vec3) == 3 * sizeof(float), "a centre is stored as three floats");

// The tile record's own checksum (byte by byte), older than recordChecksum: kept so that
// cached tiles stay valid.
uint64_t checksum(const char* data, size_t size) {
  uint64_t h = mix64(size);
  for (size_t i = 0; i < size; ++i) h = hashCombine(h, uint8_t(data[i]));
  return h;
}

uint64_t bitsOf(double d) {
  uint64_t b;
  std::memcpy(&b, &d, sizeof b);
  return b;
}

uint64_t sizesKey(const TileSizes& z) {
  if (z.monodisperse()) return 0;
  uint64_t h = hashInts(z.classSize.size(), bitsOf(z.spread));
  for (size_t c = 0; c < z.classSize.size(); ++c) h = hashInts(h, bitsOf(z.classSize[c]), bitsOf(z.classWeight[c]));
  return h;
}

std::string cacheName(int n, double targetF, uint64_t seed, const TileSizes& z) {
  return str("tile-v", kTileFormatVersion, "-n", n, "-f", std::hex, bitsOf(targetF), "-s", seed, "-z", sizesKey(z),
             ".bin");
}

std::vector<char> serialise(const Tile& t, double targetF) {
  RecordWriter w(kMagic, checksum);
  w.putU32(kTileFormatVersion);
  w.putI32(int32_t(t.numSpheres));
  w.putF64(targetF);
  w.putU64(t.seed);
  w.putF64(t.radius);
  w.putF64(t.packingRate);
  w.putArray(t.centers);
  w.putU32(uint32_t(t.sizes.size()));
  for (size_t k = 0; k < t.sizes.size(); ++k) {
    w.putF32(t.sizes[k]);
    w.putU8(t.classes[k]);
  }
  return w.finish();
}

bool deserialise(const std::vector<char>& in, int n, double targetF, uint64_t seed, bool poly, Tile& t) {
  RecordReader r(in, kMagic, checksum);
  uint32_t version = 0;
  int32_t count = 0;
  double f = 0;
  if (!r.getU32(version) || !r.getI32(count) || !r.getF64(f) || !r.getU64(t.seed) || !r.getF64(t.radius) ||
      !r.getF64(t.packingRate))
    return false;
  if (version != kTileFormatVersion || count != n || bitsOf(f) != bitsOf(targetF) || t.seed != seed) return false;
  if (!(t.radius > 0) || !(t.radius <= 0.5) || !(std::fabs(t.packingRate - targetF) <= 1e-6 * targetF)) return false;
  t.numSpheres = n;
  t.centers.resize(n);
  if (!r.getArray(t.centers)) return false;
  for (const Vec3& c : t.centers)
    for (int k = 0; k < 3; ++k)
      if (!(c[k] >= 0.0f && c[k] < 1.0f)) return false;
  uint32_t sized = 0;
  if (!r.getU32(sized) || sized != (poly ? uint32_t(n) : 0u)) return false;
  t.sizes.resize(sized);
  t.classes.resize(sized);
  for (size_t k = 0; k < sized; ++k) {
    if (!r.getF32(t.sizes[k]) || !r.getU8(t.classes[k])) return false;
    if (!(t.sizes[k] > 0 && t.sizes[k] < 1e3f)) return false;
  }
  return r.finish();
}

// Each sphere's class and size: classes by number (largest remainder, every class with a
// weight > 0 at least one sphere), sizes spread uniformly within a class — stratified (the
// midpoints of n_c equal quantiles, shuffled), so that a class of a few dozen spheres
// already has the spread's moments (random draws of 38 spheres missed E[s³]/E[s²] by 3%,
// which the medium, derived from the distribution, then missed too).
void assignSizes(int n, const TileSizes& z, uint64_t seed, Tile& t) {
  const size_t nc = z.classSize.size();
  double wsum = 0;
  for (double w : z.classWeight) wsum += w;
  std::vector<int> count(nc, 0);
  std::vector<std::pair<double, size_t>> remainders;
  int assigned = 0;
  for (size_t c = 0; c < nc; ++c) {
    double share = n * z.classWeight[c] / wsum;
    count[c] = int(std::floor(share));
    if (z.classWeight[c] > 0 && count[c] == 0) count[c] = 1;
    assigned += count[c];
    remainders.push_back({-(share - std::floor(share)), c});
  }
  std::sort(remainders.begin(), remainders.end());
  for (size_t k = 0; assigned < n; k = (k + 1) % nc)
    if (z.classWeight[remainders[k].second] > 0) ++count[remainders[k].second], ++assigned;
  for (size_t c = nc; assigned > n && c-- > 0;)  // the minimum of one made too many
    while (assigned > n && count[c] > 1) --count[c], --assigned;
  t.sizes.clear();
  t.classes.clear();
  for (size_t c = 0; c < nc; ++c) {
    std::vector<int> order(static_cast<size_t>(count[c]));
    for (int k = 0; k < count[c]; ++k) order[size_t(k)] = k;
    for (int k = count[c] - 1; k > 0; --k) {  // Fisher–Yates, seeded
      const uint64_t h = hashInts(seed, 0x53495a45u /* "SIZE" */, c, uint64_t(k));
      std::swap(order[size_t(k)], order[size_t(h % uint64_t(k + 1))]);
    }
    for (int k = 0; k < count[c]; ++k) {
      const double u = (order[size_t(k)] + 0.5) / count[c];
      t.sizes.push_back(float(z.classSize[c] * (1.0 + z.spread * (2.0 * u - 1.0))));
      t.classes.push_back(uint8_t(c));
    }
  }
}

}  // namespace

float Tile::maxSize() const {
  float m = sizes.empty() ? 1.0f : 0.0f;
  for (float x : sizes) m = std::max(m, x);
  return m;
}

double Tile::sauterSize() const {
  double s2 = 0, s3 = 0;
  for (int k = 0; k < numSpheres; ++k) {
    const double x = size(k);
    s2 += x * x;
    s3 += x * x * x;
  }
  return s2 > 0 ? s3 / s2 : 1.0;
}

TileGrowth TileGrowth::uniform(double rate) {
  TileGrowth g;
  g.rate = g.fastRate = rate;
  return g;
}

double TileGrowth::fastUntil(double targetF) const {
  if (!(fastRate > rate)) return 0;
  const double f = std::min(fastLimit, targetF - fastMargin);
  return f > 0 ? f : 0;
}

bool TileSizes::monodisperse() const {
  return classSize.empty() || (classSize.size() == 1 && classSize[0] == 1.0 && spread == 0);
}

namespace {

void checkTileInputs(int n, double targetF, const TileSizes& z) {
  if (!(targetF > 0 && targetF <= kMaxPackingRate))
    throw InputError("tile", "packingRate", str(targetF, " is outside (0, ", kMaxPackingRate, "]"));
  if (n < 1 || n > kMaxSpheres)
    throw InputError("tile", "numSpheres", str(n, " is outside [1, ", kMaxSpheres, "]"));
  if (z.monodisperse()) return;
  if (z.classWeight.size() != z.classSize.size())
    throw InputError("tile", "sizes", str(z.classWeight.size(), " weights for ", z.classSize.size(), " size classes"));
  if (int(z.classSize.size()) > std::min(n, TileSizes::kMaxClasses))
    throw InputError("tile", "sizes", str(z.classSize.size(), " size classes for ", n, " spheres (at most ",
                                          std::min(n, TileSizes::kMaxClasses), ")"));
  double wsum = 0;
  for (size_t c = 0; c < z.classSize.size(); ++c) {
    if (!(z.classSize[c] >= 0.01 && z.classSize[c] <= 100))
      throw InputError("tile", "sizes", str("size ", z.classSize[c], " is outside [0.01, 100]"));
    if (!(std::isfinite(z.classWeight[c]) && z.classWeight[c] >= 0))
      throw InputError("tile", "sizes", str("weight ", z.classWeight[c], " must be finite and >= 0"));
    wsum += z.classWeight[c];
  }
  if (!(wsum > 0)) throw InputError("tile", "sizes", "the size classes' weights are all zero");
  if (!(z.spread >= 0 && z.spread <= 0.5)) throw InputError("tile", "sizeSpread", str(z.spread, " is outside [0, 0.5]"));
}

}  // namespace

Tile generateTile(int n, double targetF, uint64_t seed, const TileSizes& sizes, const TileGrowth& growth) {
  checkTileInputs(n, targetF, sizes);
  if (!(growth.rate > 0 && growth.fastRate > 0 && std::isfinite(growth.rate) && std::isfinite(growth.fastRate) &&
        std::isfinite(growth.fastMargin) && std::isfinite(growth.fastLimit)))
    throw InputError("tile", "growth", str("rates ", growth.rate, " and ", growth.fastRate, " must be finite and > 0"));
  Tile shape;  // sizes and classes, before any position
  if (!sizes.monodisperse()) assignSizes(n, sizes, seed, shape);
  double sumCubes = 0;
  for (int k = 0; k < n; ++k) sumCubes += std::pow(double(shape.size(k)), 3);
  const double sMax = shape.maxSize();
  // Reference radius r (size 1) at the target: f = (4/3)π r³ Σ s_k³.
  const double radius = std::cbrt(3.0 * targetF / (4.0 * kPiD * sumCubes));
  std::vector<double> rel;  // diameters relative to the largest
  if (!shape.sizes.empty())
    for (float x : shape.sizes) rel.push_back(double(x) / sMax);
  // Grow a hair past the largest diameter so that every gap at radius r is at least the
  // float rounding of the stored centres; the reported radius is exactly the requested one.
  const double D = 2.0 * radius * sMax;
  const double dStop = D + std::max(1e-9 * D, 2.0 * kFloatRoundingGap);
  if (dStop > 1.0)
    throw InputError("tile", "numSpheres",
                     str(n, " sphere(s) cannot reach packing rate ", targetF, ": a sphere would not fit in the tile"));
  auto rateOf = [&](double r) { return (4.0 / 3.0) * kPiD * r * r * r * sumCubes; };

  // The fast stage ends at the diameter of its packing rate (f grows as D³).
  const double fFast = growth.fastUntil(targetF);
  const double dFast = fFast > 0 ? D * std::cbrt(fFast / targetF) : 0;
  double rate = growth.rate, fastRate = growth.fastRate, jammedAt = 0;
  for (int attempt = 0; attempt < kAttempts; ++attempt, rate /= kSlowdown, fastRate /= kSlowdown) {
    LsSystem sys(n, dStop, dFast > 0 ? fastRate : rate, seed, rel);
    bool grown = true;
    if (dFast > 0) {
      grown = sys.run(dFast);
      if (grown) sys.setRate(rate);
    }
    if (!grown || !sys.run(dStop)) {
      jammedAt = std::max(jammedAt, rateOf(0.5 * sys.diameter() / sMax));
      continue;
    }
    Tile tile = shape;
    tile.numSpheres = n;
    tile.radius = radius;
    tile.seed = seed;
    tile.centers.reserve(n);
    for (int i = 0; i < n; ++i) {
      const double* p = sys.position(i);
      Vec3 c;
      for (int k = 0; k < 3; ++k) {
        double x = p[k] - std::floor(p[k]);
        float xf = float(x);
        c[k] = xf >= 1.0f ? 0.0f : xf;  // 1 - 2^-26 rounds up to 1
      }
      tile.centers.push_back(c);
    }
    // Safety net: the margin above makes this a no-op; shrink rather than hand out overlaps.
    double gap = minPeriodicGapFast(tile);
    if (gap < 0) {
      // Every pair's gap is >= gap, and its radii sum >= 2 s_min: this radius clears all.
      double sMin = shape.sizes.empty() ? 1.0 : double(*std::min_element(shape.sizes.begin(), shape.sizes.end()));
      tile.radius = std::nextafter(radius + 0.5 * gap / sMin, 0.0);
      if (!(std::fabs(rateOf(tile.radius) - targetF) <= 1e-6 * targetF))
        throw std::runtime_error(str("tile: spheres overlap by ", -gap, " after growth (a bug)"));
    }
    tile.packingRate = rateOf(tile.radius);
    return tile;
  }
  throw InputError("tile", "packingRate",
                   str(targetF, " cannot be reached with ", n, " spheres: they jam at f=", jammedAt,
                       " (random close packing is about 0.64); use a lower packing rate or more spheres"));
}

Tile loadOrGenerateTile(int n, double targetF, uint64_t seed, const TileSizes& sizes) {
  // Validate first so that bad input never touches the cache.
  checkTileInputs(n, targetF, sizes);
  const std::string name = cacheName(n, targetF, seed, sizes);
  std::vector<char> bytes;
  Tile tile;
  if (readCacheFile(name, bytes) && deserialise(bytes, n, targetF, seed, !sizes.monodisperse(), tile)) return tile;
  tile = generateTile(n, targetF, seed, sizes);
  writeCacheFile(name, serialise(tile, targetF));
  return tile;
}

double minPeriodicGap(const Tile& t) {
  size_t n = t.centers.size();
  if (n == 0) return kInfD;
  const double r = t.radius;
  double best = 1.0 - 2.0 * r * t.maxSize();  // each sphere against its own images one tile away
  for (size_t i = 0; i < n; ++i)
    for (size_t j = i + 1; j < n; ++j)
      best = std::min(best, pairDistance(t.centers[i], t.centers[j]) - r * (double(t.size(int(i))) + t.size(int(j))));
  return best;
}

}  // namespace granular
