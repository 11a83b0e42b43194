// cryptomatte.h — Cryptomatte ids, manifests and ranked coverage (Psyop's Cryptomatte
// specification), for the film (film.h) and the front ends' image headers.
//
// Contract. A name (a prim path) is hashed with MurmurHash3_x86_32, seed 0, over its UTF-8
// bytes; its id is that hash as a float32 bit pattern with the exponent clamped to
// [1, 254] (the spec's "uint32_to_float32": no zero, denormal, Inf or NaN ids), the sign
// and mantissa kept. Ids are handled as those bits (uint32) until written as floats. A
// type ("CryptoObject", "CryptoMaterial") is written as kCryptomatteLayers RGBA layers
// <type>00, <type>01, ...: layer k holds (id, coverage) of ranks 2k and 2k+1, ranks by
// coverage, largest first (equal coverage: smaller id first); empty ranks are (0, 0).
// Coverage is the fraction of the pixel's samples whose first hit carried the id.
// The header of a file holding a type carries, under cryptomatte/<key>/ (key: the first 7
// hex digits of the hash of the type's name): name, hash ("MurmurHash3_32"), conversion
// ("uint32_to_float32") and manifest (JSON {name: 8 hex digits of the id}).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

namespace granular {

// MurmurHash3, 32-bit x86 variant (Austin Appleby's public-domain algorithm).
uint32_t murmurHash3_x86_32(const void* data, size_t length, uint32_t seed);
inline uint32_t murmurHash3_x86_32(const std::string& s, uint32_t seed = 0) {
  return murmurHash3_x86_32(s.data(), s.size(), seed);
}

// The spec's uint32_to_float32: the hash's bits with the exponent clamped to [1, 254].
uint32_t cryptomatteIdBits(uint32_t hash);
float cryptomatteIdFloat(uint32_t idBits);
// A name's id bits: cryptomatteIdBits(murmurHash3_x86_32(name, 0)).
uint32_t cryptomatteId(const std::string& name);

enum class CryptomatteType : int { Object = 0, Material = 1 };
constexpr int kCryptomatteTypes = 2;
// Layers per type written (two ranks each): the spec's suggested 6 ranks.
constexpr int kCryptomatteLayers = 3;
constexpr int kCryptomatteRanks = 2 * kCryptomatteLayers;
// Distinct ids a pixel keeps per type while sampling (film.h): an id first seen when the
// table is full is not counted, so that pixel's coverages sum to less than its alpha.
constexpr int kCryptomatteEntries = 8;

const char* cryptomatteTypeName(CryptomatteType type);  // "CryptoObject", "CryptoMaterial"
// "<type>00", "<type>01", ...: the layers of a type, and their channels <layer>.R/G/B/A.
std::string cryptomatteLayerName(CryptomatteType type, int layer);
// The type a layer name ("CryptoObject", "CryptoObject01") belongs to; false for others.
bool cryptomatteTypeOfLayer(const std::string& layer, CryptomatteType& type);
// First 7 hex digits of the hash of the type's name: the header's key.
std::string cryptomatteKey(CryptomatteType type);
// JSON object {name: "%08x" of its id}, names sorted, each once.
std::string cryptomatteManifest(const std::vector<std::string>& names);
// The header attributes of a type: cryptomatte/<key>/name, hash, conversion, manifest.
std::vector<std::pair<std::string, std::string>> cryptomatteMetadata(CryptomatteType type,
                                                                     const std::vector<std::string>& names);

// One pixel's table for one type: (id bits, samples) in first-seen order; count 0: free.
struct CryptomatteEntry {
  uint32_t id = 0;
  uint32_t count = 0;
};
// Counts one sample of id in a pixel's table of kCryptomatteEntries (see above).
void cryptomatteCount(CryptomatteEntry* table, uint32_t id);
// The ranked layers of a table of a pixel of n samples: kCryptomatteLayers × RGBA floats
// (id as float, coverage count / n).
void cryptomatteRanked(const CryptomatteEntry* table, long n, float* out);

}  // namespace granular
