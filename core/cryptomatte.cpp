#include "cryptomatte.h"

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <map>

#include <nlohmann/json.hpp>

namespace granular {

namespace {

uint32_t rotl32(uint32_t x, int r) { return (x << r) | (x >> (32 - r)); }

// The final avalanche of MurmurHash3.
uint32_t fmix32(uint32_t h) {
  h ^= h >> 16;
  h *= 0x85ebca6bu;
  h ^= h >> 13;
  h *= 0xc2b2ae35u;
  h ^= h >> 16;
  return h;
}

constexpr uint32_t kC1 = 0xcc9e2d51u, kC2 = 0x1b873593u;

uint32_t scramble(uint32_t k) {
  k *= kC1;
  k = rotl32(k, 15);
  return k * kC2;
}

std::string hex8(uint32_t v) {
  char buf[9];
  std::snprintf(buf, sizeof buf, "%08x", v);
  return buf;
}

}  // namespace

uint32_t murmurHash3_x86_32(const void* data, size_t length, uint32_t seed) {
  const auto* bytes = static_cast<const unsigned char*>(data);
  uint32_t h = seed;
  const size_t blocks = length / 4;
  for (size_t i = 0; i < blocks; ++i) {
    // Little-endian blocks, whatever the host's byte order.
    const unsigned char* b = bytes + 4 * i;
    uint32_t k = uint32_t(b[0]) | uint32_t(b[1]) << 8 | uint32_t(b[2]) << 16 | uint32_t(b[3]) << 24;
    h ^= scramble(k);
    h = rotl32(h, 13);
    h = h * 5 + 0xe6546b64u;
  }
  const unsigned char* tail = bytes + 4 * blocks;
  uint32_t k = 0;
  switch (length & 3) {
    case 3: k ^= uint32_t(tail[2]) << 16; [[fallthrough]];
    case 2: k ^= uint32_t(tail[1]) << 8; [[fallthrough]];
    case 1:
      k ^= uint32_t(tail[0]);
      h ^= scramble(k);
  }
  h ^= uint32_t(length);
  return fmix32(h);
}

uint32_t cryptomatteIdBits(uint32_t hash) {
  const uint32_t exponent = std::clamp<uint32_t>((hash >> 23) & 0xffu, 1u, 254u);
  return (hash & 0x807fffffu) | exponent << 23;
}

float cryptomatteIdFloat(uint32_t idBits) {
  float f;
  std::memcpy(&f, &idBits, sizeof f);
  return f;
}

uint32_t cryptomatteId(const std::string& name) { return cryptomatteIdBits(murmurHash3_x86_32(name, 0)); }

const char* cryptomatteTypeName(CryptomatteType type) {
  return type == CryptomatteType::Object ? "CryptoObject" : "CryptoMaterial";
}

std::string cryptomatteLayerName(CryptomatteType type, int layer) {
  char buf[4];
  std::snprintf(buf, sizeof buf, "%02d", layer);
  return cryptomatteTypeName(type) + std::string(buf);
}

bool cryptomatteTypeOfLayer(const std::string& layer, CryptomatteType& type) {
  for (CryptomatteType t : {CryptomatteType::Object, CryptomatteType::Material}) {
    if (layer == cryptomatteTypeName(t)) {
      type = t;
      return true;
    }
    for (int k = 0; k < kCryptomatteLayers; ++k)
      if (layer == cryptomatteLayerName(t, k)) {
        type = t;
        return true;
      }
  }
  return false;
}

std::string cryptomatteKey(CryptomatteType type) {
  return hex8(murmurHash3_x86_32(std::string(cryptomatteTypeName(type)), 0)).substr(0, 7);
}

std::string cryptomatteManifest(const std::vector<std::string>& names) {
  // nlohmann's object keeps its keys sorted and escapes them as JSON requires.
  nlohmann::json manifest = nlohmann::json::object();
  for (const std::string& n : names) manifest[n] = hex8(cryptomatteId(n));
  return manifest.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
}

std::vector<std::pair<std::string, std::string>> cryptomatteMetadata(CryptomatteType type,
                                                                     const std::vector<std::string>& names) {
  const std::string prefix = "cryptomatte/" + cryptomatteKey(type) + "/";
  return {{prefix + "name", cryptomatteTypeName(type)},
          {prefix + "hash", "MurmurHash3_32"},
          {prefix + "conversion", "uint32_to_float32"},
          {prefix + "manifest", cryptomatteManifest(names)}};
}

void cryptomatteCount(CryptomatteEntry* table, uint32_t id) {
  for (int i = 0; i < kCryptomatteEntries; ++i) {
    if (table[i].count == 0) {
      table[i] = {id, 1};
      return;
    }
    if (table[i].id == id) {
      ++table[i].count;
      return;
    }
  }
}

void cryptomatteRanked(const CryptomatteEntry* table, long n, float* out) {
  CryptomatteEntry sorted[kCryptomatteEntries];
  int used = 0;
  for (int i = 0; i < kCryptomatteEntries && table[i].count; ++i) sorted[used++] = table[i];
  std::sort(sorted, sorted + used, [](const CryptomatteEntry& a, const CryptomatteEntry& b) {
    return a.count != b.count ? a.count > b.count : a.id < b.id;
  });
  for (int r = 0; r < kCryptomatteRanks; ++r) {
    const bool present = r < used && n > 0;
    out[2 * r] = present ? cryptomatteIdFloat(sorted[r].id) : 0.0f;
    out[2 * r + 1] = present ? float(double(sorted[r].count) / double(n)) : 0.0f;
  }
}

}  // namespace granular
