#include "ies.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>
#include <sstream>

#include <sys/stat.h>

#include "error.h"
#include "math.h"

namespace granular {

namespace {

constexpr double kDegree = kPiD / 180.0;
constexpr double kAngleTolerance = 1e-3;  // degrees: "90" written as 89.9995 is 90
constexpr size_t kMaxValues = size_t(1) << 22;  // candela values: real files hold ~10^4

bool near(double a, double b) { return std::fabs(a - b) <= kAngleTolerance; }

// The numbers after the TILT= line, split by blanks, commas or line breaks.
class Numbers {
 public:
  explicit Numbers(std::string text) {
    std::replace(text.begin(), text.end(), ',', ' ');
    std::istringstream in(text);
    for (std::string t; in >> t;) tokens_.push_back(std::move(t));
  }

  double next(const std::string& what) {
    return value([&] { return what; });
  }

  // The next number; what() names it, called only for an error's message (a file holds
  // ~10^4 numbers).
  template <typename What>
  double value(const What& what) {
    if (at_ >= tokens_.size()) throw InputError("", "", str("ends before its ", what()));
    const std::string& t = tokens_[at_++];
    char* end = nullptr;
    const double v = std::strtod(t.c_str(), &end);
    if (end == t.c_str() || *end != '\0') throw InputError("", "", str(what(), " is not a number: \"", printableToken(t), "\""));
    if (!std::isfinite(v)) throw InputError("", "", str(what(), " is not a finite number: \"", printableToken(t), "\""));
    if (std::fabs(v) > 3.0e38) throw InputError("", "", str(what(), " is ", v, ", beyond a 32-bit float"));
    return v;
  }

  int count(const std::string& what, int lo, int hi) {
    const double v = next(what);
    if (v != std::floor(v) || v < lo || v > hi)
      throw InputError("", "", str(what, " is ", v, ", expected a whole number in [", lo, ", ", hi, "]"));
    return int(v);
  }

 private:
  std::vector<std::string> tokens_;
  size_t at_ = 0;
};

// Angles in degrees, strictly increasing within [lo, hi].
std::vector<double> readAngles(Numbers& in, int n, const char* which, double lo, double hi) {
  std::vector<double> a(n);
  for (int i = 0; i < n; ++i) {
    a[i] = in.value([&] { return str(which, " angle ", i + 1); });
    if (a[i] < lo - kAngleTolerance || a[i] > hi + kAngleTolerance)
      throw InputError("", "", str(which, " angle ", i + 1, " is ", a[i], "°, outside [", lo, ", ", hi, "]°"));
    a[i] = std::clamp(a[i], lo, hi);
    if (i > 0 && !(a[i] > a[i - 1]))
      throw InputError("", "", str(which, " angles are not increasing: ", a[i - 1], "° then ", a[i], "°"));
  }
  return a;
}

}  // namespace

IesProfile parseIes(const std::string& text) {
  // Keyword lines (or, in LM-63-1986, free text) up to the line that starts with TILT=.
  size_t tilt = std::string::npos;
  for (size_t line = 0; line < text.size();) {
    const size_t start = text.find_first_not_of(" \t", line);
    if (start != std::string::npos && text.compare(start, 5, "TILT=") == 0) {
      tilt = start + 5;
      break;
    }
    const size_t eol = text.find('\n', line);
    if (eol == std::string::npos) break;
    line = eol + 1;
  }
  if (tilt == std::string::npos) throw InputError("", "", "has no TILT= line: it is not an IES LM-63 photometric file");
  size_t eol = text.find('\n', tilt);
  if (eol == std::string::npos) eol = text.size();
  std::string tiltValue = text.substr(tilt, eol - tilt);
  tiltValue.erase(tiltValue.find_last_not_of(" \t\r") + 1);
  Numbers in(text.substr(eol));
  if (tiltValue == "INCLUDE") {
    // The lamp's output against its tilt: the luminaire is taken as photometered.
    in.next("tilt geometry");
    const int n = in.count("number of tilt angles", 0, 100000);
    for (int i = 0; i < 2 * n; ++i) in.next(i < n ? "tilt angle" : "tilt multiplier");
  }

  in.count("number of lamps", -1000000, 1000000);
  in.next("lumens per lamp");
  double factor = in.next("candela multiplier");
  const int nv = in.count("number of vertical angles", 2, 100000);
  const int nh = in.count("number of horizontal angles", 1, 100000);
  const int type = in.count("photometric type", 1, 3);
  if (type != 1)
    throw InputError("", "", str("photometric type ", type == 2 ? "B" : "A",
                                 " is not supported (type C is: the luminaire's axis vertical)"));
  if (size_t(nv) * size_t(nh) > kMaxValues)
    throw InputError("", "", str(nv, " × ", nh, " angles are more than ", kMaxValues, " candela values"));
  in.next("units type");
  in.next("width");
  in.next("length");
  in.next("height");
  factor *= in.next("ballast factor");
  factor *= in.next("ballast-lamp photometric factor");
  in.next("input watts");
  if (!(factor >= 0) || !std::isfinite(factor))
    throw InputError("", "", str("its multipliers give ", factor, ", expected a finite value ≥ 0"));

  const std::vector<double> v = readAngles(in, nv, "vertical", 0, 180);
  const std::vector<double> h = readAngles(in, nh, "horizontal", 0, 360);
  IesProfile p;
  using S = IesProfile::Symmetry;
  if (nh == 1) p.symmetry_ = S::Axial;
  else if (near(h.front(), 0) && near(h.back(), 90)) p.symmetry_ = S::Quadrant;
  else if (near(h.front(), 0) && near(h.back(), 180)) p.symmetry_ = S::Bilateral0;
  else if (near(h.front(), 0) && h.back() > 180) p.symmetry_ = S::None;
  else if (near(h.front(), 90) && near(h.back(), 270)) p.symmetry_ = S::Bilateral90;
  else
    throw InputError("", "", str("horizontal angles run from ", h.front(), "° to ", h.back(),
                                 "°: type C runs them from 0° to 90°, 180° or 360°, or from 90° to 270°"));
  for (double a : v) p.vertical_.push_back(float(a * kDegree));
  for (double a : h) p.horizontal_.push_back(float(a * kDegree));
  p.candela_.resize(size_t(nv) * nh);
  for (int j = 0; j < nh; ++j)
    for (int i = 0; i < nv; ++i) {
      auto what = [&] { return str("candela value at horizontal ", h[j], "°, vertical ", v[i], "°"); };
      const double c = in.value(what);
      if (c < 0) throw InputError("", "", str(what(), " is ", c, ", below 0"));
      const float value = float(c * factor);
      if (!std::isfinite(value))
        throw InputError("", "", str(what(), " times its multipliers overflows"));
      p.candela_[size_t(j) * nv + i] = value;
      p.max_ = std::max(p.max_, value);
    }

  // The mean for normalisation. The profile is linear in φ between rows, so ∫ I dω is
  // Σ_h W_h ∫ row_h(θ) sin θ dθ, W_h the measure of φ each row stands for: the rows'
  // blending weights summed over 0.5° steps of φ (exact for rows on half degrees, as files
  // list them: the weights bend only there), the θ integral by the midpoint rule in 0.1°
  // cells over the covered range.
  std::vector<double> weight(nh, 0.0);
  const int np = p.symmetry_ == S::Axial ? 1 : 720;
  for (int k = 0; k < np; ++k) {
    int j0 = 0, j1 = 0;
    float t = 0;
    p.phiRows(float(2 * kPiD * (k + 0.5) / np), j0, j1, t);
    weight[j0] += (1 - t) * 2 * kPiD / np;
    weight[j1] += t * 2 * kPiD / np;
  }
  const double t0 = v.front() * kDegree, t1 = v.back() * kDegree;
  const int nt = std::max(1, int(std::ceil((v.back() - v.front()) / 0.1)));
  double sum = 0;
  for (int j = 0; j < nh; ++j) {
    if (weight[j] == 0) continue;
    double ring = 0;
    for (int i = 0; i < nt; ++i) {
      const double theta = t0 + (t1 - t0) * (i + 0.5) / nt;
      ring += p.row(j, float(theta)) * std::sin(theta);
    }
    sum += weight[j] * ring * (t1 - t0) / nt;
  }
  p.mean_ = sum / ((v.back() - v.front() <= 90 + kAngleTolerance ? 2 : 4) * kPiD);
  return p;
}

float IesProfile::row(int h, float theta) const {
  const size_t nv = vertical_.size();
  if (theta < vertical_.front() - 1e-6f || theta > vertical_.back() + 1e-6f) return 0.0f;
  const size_t i = std::clamp<size_t>(size_t(std::upper_bound(vertical_.begin(), vertical_.end(), theta) - vertical_.begin()),
                                      1, nv - 1);
  const float a = vertical_[i - 1], b = vertical_[i];
  const float t = std::clamp((theta - a) / (b - a), 0.0f, 1.0f);
  const float* c = &candela_[size_t(h) * nv];
  return c[i - 1] + (c[i] - c[i - 1]) * t;
}

void IesProfile::phiRows(float phi, int& j0, int& j1, float& t) const {
  j0 = j1 = 0;
  t = 0;
  if (symmetry_ == Symmetry::Axial) return;
  const float twoPi = 2 * kPi;
  phi = std::fmod(phi, twoPi);
  if (phi < 0) phi += twoPi;
  switch (symmetry_) {
    case Symmetry::Quadrant:
      if (phi > kPi) phi = twoPi - phi;
      if (phi > 0.5f * kPi) phi = kPi - phi;
      break;
    case Symmetry::Bilateral0:
      if (phi > kPi) phi = twoPi - phi;
      break;
    case Symmetry::Bilateral90:
      if (phi < 0.5f * kPi) phi = kPi - phi;
      else if (phi > 1.5f * kPi) phi = 3 * kPi - phi;
      break;
    default: break;
  }
  const int nh = int(horizontal_.size());
  if (symmetry_ == Symmetry::None && phi > horizontal_.back()) {
    // Past the last row, back to the 0° row at 360°.
    const float span = twoPi - horizontal_.back();
    j0 = nh - 1;
    t = span > 0 ? std::clamp((phi - horizontal_.back()) / span, 0.0f, 1.0f) : 0.0f;
    return;
  }
  phi = std::clamp(phi, horizontal_.front(), horizontal_.back());
  j1 = std::clamp(int(std::upper_bound(horizontal_.begin(), horizontal_.end(), phi) - horizontal_.begin()), 1, nh - 1);
  j0 = j1 - 1;
  t = std::clamp((phi - horizontal_[j0]) / (horizontal_[j1] - horizontal_[j0]), 0.0f, 1.0f);
}

float IesProfile::intensity(float theta, float phi) const {
  int j0, j1;
  float t;
  phiRows(phi, j0, j1, t);
  const float a = row(j0, theta);
  return t > 0 ? a + (row(j1, theta) - a) * t : a;
}

std::shared_ptr<const IesProfile> readIesFile(const std::string& path) {
  // Profiles read before, while their file is unchanged: a scene's checks and its lights
  // read each one, and a Hydra host syncs a light again on every edit.
  struct Entry {
    int64_t mtime = 0, size = -1;
    std::shared_ptr<const IesProfile> profile;
  };
  static std::mutex mutex;
  static std::map<std::string, Entry> cache;
  struct stat st;
  if (stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) throw InputError(path, "", "cannot be found");
  const int64_t mtime = int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec, size = int64_t(st.st_size);
  {
    std::lock_guard<std::mutex> lock(mutex);
    auto it = cache.find(path);
    if (it != cache.end() && it->second.mtime == mtime && it->second.size == size) return it->second.profile;
  }
  if (size > (int64_t(64) << 20)) throw InputError(path, "", "is larger than 64 MiB: not a photometric file");
  std::ifstream f(path, std::ios::binary);
  if (!f) throw InputError(path, "", "cannot be read");
  std::ostringstream s;
  s << f.rdbuf();
  std::shared_ptr<const IesProfile> profile;
  try {
    profile = std::make_shared<const IesProfile>(parseIes(s.str()));
  } catch (const InputError& e) {
    throw InputError(path, "", e.detail());
  }
  std::lock_guard<std::mutex> lock(mutex);
  if (cache.size() >= 256) cache.clear();  // a bound, not a policy: scenes hold a few profiles
  cache[path] = Entry{mtime, size, profile};
  return profile;
}

}  // namespace granular
