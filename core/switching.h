// switching.h — how long a path's low orders stay among proxies before the medium takes
// them, measured per aggregate instead of set by a rule.
//
// Why: the equivalent medium is memoryless, so it misses the shadowing between
// neighbouring grains of a dense packing (Müller et al. 2016, §1); light that meets the
// packing's surface layer in the medium is absorbed in the wrong amount. Proxies keep that
// shadowing (proxy.h, ppt.h). The bias of handing a path to the medium after k proxy visits
// falls with k, how fast depends on the grains' absorption and index, their packing, and
// the object's thickness — so it is measured.
//
// Contract: measureSwitch() takes a built aggregate (its proxies prepared) with its proxy
// tables and its equivalent medium. Paths enter its boundary at points uniform in area,
// with directions cosine-distributed about the inward normal (the light of a uniform dome),
// and walk among the proxies (the first grain met is a proxy too, standing for the
// renderer's explicit first grain), scoring the energy that leaves the aggregate. After
// visit k + 1 (k in kSwitchVisits) the path forks a walk in the medium (vpt.h: the same
// flight and phase sampling; the boundary an index-matched interface) from the proxy's
// exit point and direction, in the exits model taking the path over at a grain as the
// renderer does (vpt.h: enterMedia; the packing's first flight): S_k = what left
// before the fork + what the fork carries out, an estimate of the aggregate's albedo to a
// dome when the medium takes over after k visits. The reference is S_K of the last candidate K (the proxy walk ends with its fork):
//     bias_k = mean(S_k − S_K) / mean(S_K)   per channel,
// with its standard error from the spread of S_k − S_K, which holds the noise of the walks
// after fork k only (they share every random number before it). Against S_K rather than
// the proxies to the end: what visits beyond K would change is not the switch's to fix —
// in nearly clear grains both levels walk for hundreds of visits, and a small difference
// between the medium's and the tables' albedo then shows at every k alike.
// The chosen visits: the least k whose |bias_k| ≤ tolerance with s.e._k ≤ precision ·
// tolerance in every channel (K when none is): an estimate within the tolerance, measured
// well enough to tell. (A bound |bias_k| + 2 s.e. would be decided by noise in nearly
// clear grains, whose long walks leave a standard error near the tolerance.) A candidate
// whose bias lies within a standard error of the tolerance is taken or passed over as the
// noise falls, so the chosen one may leave up to about twice the tolerance; tighter rules
// cost bright and clear grains visits they do not need (bench/README.md, "The dome's
// choice and its noise, measured"). Paths are
// traced in batches (512, 512, 1024, then 2048 paths). After each, a candidate beyond the
// tolerance by more than 3 standard errors in some channel is decided (it fails the choice
// whatever more paths say): it forks no more and keeps the estimate of the paths that
// forked it (candidatePaths; the reference K forks in every path). Batches go on until
// every candidate before the chosen one is beyond the tolerance by more than its standard
// error (3 of them before 2048 paths) or out of reach — its standard error, scaled as 1/√n
// to the most paths the measurement may still trace (the budget left at the last batch's
// steps per path, and one batch more; options.paths), above 1.25 · precision · tolerance
// in some channel, so that it could not pass —, options.paths are traced, or the walks
// have taken options.eventBudget steps. The reference always passes (its bias is 0 by
// construction), so where no earlier candidate is measured to the precision asked the
// choice is K. A candidate taken for decided or out of reach by chance is passed over: the
// error is towards more visits (less bias, a slower render).
// Walks end by Russian roulette (unbiased) or after a cap of events (leaks).
// Deterministic for a seed, whatever the number of threads. With a cacheKey (everything
// the aggregate and its medium depend on; 0: no cache; the tables' own key, ProxyTables::
// key, is added to it here, so new tables are measured anew) the measurement is
// cached on disk (cache.h) and read back instead; the choice is made from it anew (the
// tolerance is not part of the key). InputError for options out of range.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "aggregate.h"
#include "light.h"
#include "math.h"
#include "proxy.h"
#include "vpt.h"

namespace granular {

// The proxy visits a measurement tries, in increasing order.
// Each is a fork of a walk in the medium per path: their number is most of the cost.
constexpr int kSwitchVisits[] = {0, 1, 2, 4, 8, 16, 32};
constexpr int kSwitchCandidates = int(sizeof(kSwitchVisits) / sizeof(kSwitchVisits[0]));

// Exit bins: where the energy a path carries out leaves to, in the frame of its entry
// point (outward normal n; back = the entry direction reversed, in the tangent plane).
// Polar bins by the exit direction's cosine μ from n, edges kSwitchExitCos (falling: the
// first bin is μ ≥ 0.8, the last μ < 0.4, past 66° from the normal), each split into back
// (toward where the path came in from) and forward. A camera and a sun see an aggregate
// from given directions; an albedo averages over them, and the medium's error can hide
// there (the shadow hiding toward the back, at grazing angles). Reported, not used in the
// choice: at the paths a measurement traces, a bin's standard error is 2–4 times the
// albedo's (bench/README.md, "Exit bins").
constexpr float kSwitchExitCos[] = {0.8f, 0.4f};
constexpr int kSwitchExitPolar = int(sizeof(kSwitchExitCos) / sizeof(kSwitchExitCos[0])) + 1;
constexpr int kSwitchExitBins = 2 * kSwitchExitPolar;
// The bin of an exit direction of cosine mu from the entry's normal, on the back side or not.
constexpr int switchExitBin(float mu, bool back) {
  int k = 0;
  while (k + 1 < kSwitchExitPolar && mu < kSwitchExitCos[k]) ++k;
  return 2 * k + (back ? 0 : 1);
}
// Bin j's cosines [lo, hi) from the entry's normal (hi 1 inclusive) and its side.
struct SwitchExitBinRange {
  float lo, hi;
  bool back;
};
constexpr SwitchExitBinRange switchExitBinRange(int j) {
  const int k = j / 2;
  return {k + 1 < kSwitchExitPolar ? kSwitchExitCos[k] : 0.0f, k == 0 ? 1.0f : kSwitchExitCos[k - 1], j % 2 == 0};
}

struct SwitchOptions {
  int64_t paths = 1 << 16;
  uint64_t seed = 1;
  float tolerance = 0.005f;  // relative bias allowed in each channel
  float precision = 1.0f;    // the standard error a choice needs, in tolerances
  // Standard errors added to |bias_k| in the choice (|bias_k| + margin · s.e._k ≤ tolerance),
  // and a candidate whose estimate would fail so at the standard error the paths left could
  // reach is out of reach. 0 for the dome: nearly clear grains' long walks leave a standard
  // error near the tolerance (above). The view measurement's (viewSwitchOptions) is 1.
  float margin = 0.0f;
  // Walk steps (proxy spheres entered, medium events) after which no batch starts: nearly
  // clear grains walk hundreds of steps per path. Enough for paths of up to 128 steps to
  // reach `paths`: a measurement cut short leaves its least candidate at the edge of the
  // precision asked, and the choice then errs toward more visits, which cost a render
  // time and variance (bench/README.md, "Hybrid speed-up").
  int64_t eventBudget = int64_t(1) << 23;
  // Paths traced before the measurement may stop for being settled or decide a candidate
  // (the budget still ends it): where single paths carry rare large contributions, the
  // standard error of a few thousand is too small more often than a normal estimate's
  // (sunSwitchOptions).
  int64_t minPaths = 0;
  // The first candidate (an index of kSwitchVisits) that forks: those before it are not
  // measured (candidatePaths 0, bias and biasSE 0), never chosen, shown or waited for. For
  // a caller that takes at least kSwitchVisits[firstCandidate] visits whatever they would
  // show (Scene's sun measurement, which adds to the dome's choice). A fork draws its own
  // random numbers, so the others' estimates are those of a measurement of every candidate
  // over the same paths.
  int firstCandidate = 0;
  // False (reports): every candidate forks in every path and all `paths` are traced, the
  // budget and the decisions notwithstanding.
  bool stopEarly = true;
};

struct SwitchMeasure {
  Vec3 albedo, albedoSE;      // mean(S_K) and its standard error
  std::vector<Vec3> bias;     // per candidate of kSwitchVisits: mean(S_k − S_K) / mean(S_K)
  std::vector<Vec3> biasSE;   // its standard error
  // Per candidate and exit bin (index c · kSwitchExitBins + j): S_kj, what leaves in bin j,
  // as bias and biasSE are of S_k; exitReference[j] = mean(S_Kj) (they sum to albedo).
  std::vector<Vec3> exitBias, exitBiasSE, exitReference;
  int64_t paths = 0;          // traced (at most SwitchOptions::paths; fewer once settled)
  std::vector<int64_t> candidatePaths;  // per candidate: the paths that forked it (≤ paths; 0: not measured)
  // Candidate c was measured (SwitchOptions::firstCandidate); a measurement made by hand,
  // without candidatePaths, measured them all.
  bool measured(int c) const { return size_t(c) >= candidatePaths.size() || candidatePaths[size_t(c)] > 0; }
  int64_t events = 0;         // walk steps taken
  int visits = kSwitchVisits[kSwitchCandidates - 1];  // the chosen k
  double seconds = 0;
  bool fromCache = false;
};

// The name of a measurement's entry in cacheDirectory().
std::string switchCacheName(uint64_t cacheKey, const ProxyTables& tables, const SwitchOptions& options);

// Chooses the visits from bias and biasSE as the contract says.
int chooseSwitchVisits(const SwitchMeasure& m, const SwitchOptions& o);

// The visits a measurement shows to be needed: the candidate after the last one with a
// channel beyond the tolerance by more than three standard errors (0 when none is, K when
// K is): the bias falls with visits, so a noisy early estimate does not undo what a later
// one shows; and three, whatever the margin, because all the candidates' channels are
// looked at (at one, a few of eighteen would show a bias by chance). Where
// chooseSwitchVisits asks a choice to be measured within the tolerance, and errs toward K
// when it is not, this errs toward fewer visits: what a noisy measurement (radiance toward
// one direction) adds to another's choice is only what it resolves.
int switchVisitsShownNeeded(const SwitchMeasure& m, const SwitchOptions& o);

SwitchMeasure measureSwitch(const Aggregate& aggregate, const ProxyTables& tables, const HomogeneousMedium& medium,
                            const SwitchOptions& options = SwitchOptions(), uint64_t cacheKey = 0);

// The view measurement: the same forks and choice, for what a camera sees of the aggregate
// under the scene's lights. A dome albedo averages over the directions light leaves in;
// the medium's error hides toward the light at grazing views (shadow hiding), where a
// camera with the sun behind it looks (bench/README.md, "Exit bins"). Paths enter where
// the camera's rays meet the aggregate's boundary, along them, and gather the radiance
// they bring back: next-event estimation toward the distant lights that reach the entry
// point (at a grain among proxies: its table toward the light and the other proxies'
// chance of letting it through; at a scattering in the medium: the phase function and
// exp(−σ_t ℓ) to the boundary), and the domes' radiance where a path leaves; a fork
// leaves to the medium what its grain's estimate found through straight lobes (ppt.h). So
// bias_k is the medium's bias in the aggregate's pixels, in the frame of the aggregate (a
// static one: its render space). Area lights are left out. With a cacheKey (as
// measureSwitch's) it is cached on disk under that key, the tables', the entries' and the
// lights' (their light at a few probe directions). InputError without entries or lights, or with more
// than 32 lights.
struct SwitchView {
  struct Entry {
    Vec3 p, n, d;      // on the boundary, its outward normal, the camera ray's direction
    uint32_t lit = 0;  // bit i: (*lights)[i], a distant light, reaches p
  };
  std::vector<Entry> entries;  // each the same share of the camera's view of the aggregate
  const std::vector<Light>* lights = nullptr;
};

// Its options: a view is measured against radiance toward one direction, noisier than a
// dome's albedo (bench/README.md, "The switch for a view"), so more paths and steps; and
// the choice wants its estimate within the tolerance by a standard error (margin 1): the
// renders at a view's choice read about its estimate and its standard error again. The
// paths stop at 2^17: where a choice needs more, a visit more costs the render less than
// the paths would cost the measurement, so it errs toward the largest candidate.
SwitchOptions viewSwitchOptions();

// The sun measurement's (Scene::sunSwitchMeasure): the view's, read by
// switchVisitsShownNeeded, at least 2^14 paths before it may stop or decide a candidate,
// and a budget of 2^26 steps for them. Radiance scattered back toward a narrow sun is
// heavy-tailed (the grains' forward lobe met by next-event estimation), and a few thousand
// paths that miss its rare large values show a bias that is not there (bench/README.md,
// "The sun's rule").
SwitchOptions sunSwitchOptions();

SwitchMeasure measureViewSwitch(const Aggregate& aggregate, const ProxyTables& tables, const HomogeneousMedium& medium,
                                const SwitchView& view, const SwitchOptions& options = viewSwitchOptions(),
                                uint64_t cacheKey = 0);

}  // namespace granular
