// rng.h — counter-based hashing and a small PCG32 generator.
//
// Contract: every random decision in the renderer is a pure function of integers
// (pixel, sample index, seed; tile cell, sphere id, seed), so images do not depend on
// the thread count and no per-grain state is ever stored.
#pragma once

#include <cstdint>

namespace granular {

// SplitMix64 finaliser: a bijective 64-bit mix.
inline uint64_t mix64(uint64_t z) {
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
  return z ^ (z >> 31);
}

inline uint64_t hashCombine(uint64_t h, uint64_t v) { return mix64(h ^ (v + 0x9e3779b97f4a7c15ULL + (h << 6) + (h >> 2))); }

template <typename... Ts>
inline uint64_t hashInts(uint64_t first, Ts... rest) {
  uint64_t h = mix64(first + 0x9e3779b97f4a7c15ULL);
  ((h = hashCombine(h, uint64_t(rest))), ...);
  return h;
}

// Uniform float in [0, 1) from the top 24 bits.
inline float toUnitFloat(uint64_t bits) { return float(bits >> 40) * 0x1p-24f; }

// PCG32 (O'Neill 2014), XSH-RR variant.
class Rng {
 public:
  explicit Rng(uint64_t seed = 0, uint64_t stream = 0) { reset(seed, stream); }
  void reset(uint64_t seed, uint64_t stream) {
    state_ = 0;
    inc_ = (stream << 1u) | 1u;
    nextU32();
    state_ += seed;
    nextU32();
  }
  uint32_t nextU32() {
    uint64_t old = state_;
    state_ = old * 6364136223846793005ULL + inc_;
    uint32_t xorshifted = uint32_t(((old >> 18u) ^ old) >> 27u);
    uint32_t rot = uint32_t(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((-rot) & 31));
  }
  // Uniform in [0, 1).
  float next1D() { return float(nextU32() >> 8) * 0x1p-24f; }
  double nextDouble() { return (double(nextU32() >> 5) * 67108864.0 + double(nextU32() >> 6)) * 0x1p-53; }

 private:
  uint64_t state_ = 0, inc_ = 1;
};

}  // namespace granular
