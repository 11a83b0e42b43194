// Cryptomatte (core/cryptomatte.h): MurmurHash3_x86_32 against published test vectors,
// the spec's uint32_to_float32 conversion, keys, manifests and ranked coverage tables.
#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>

#include "core/cryptomatte.h"
#include "test_helpers.h"

using namespace granular;

namespace {

using granular::testing::bitsOf;

}  // namespace

// The vectors widely published for MurmurHash3_x86_32 (the empty key under several seeds,
// every tail length under seed 0x9747b28c), and the ids of the Cryptomatte
// specification's own manifest examples ("bunny", "default", "bunny_porcelain_mat": their
// exponents need no clamping, so the id bits are the hash).
TEST(Cryptomatte, MurmurHash3MatchesThePublishedVectors) {
  EXPECT_EQ(murmurHash3_x86_32("", 0), 0u);
  EXPECT_EQ(murmurHash3_x86_32("", 1), 0x514E28B7u);
  EXPECT_EQ(murmurHash3_x86_32("", 0xffffffffu), 0x81F16F39u);
  EXPECT_EQ(murmurHash3_x86_32(std::string(4, '\0'), 0), 0x2362F9DEu);
  const uint32_t seed = 0x9747b28cu;
  EXPECT_EQ(murmurHash3_x86_32("aaaa", seed), 0x5A97808Au);
  EXPECT_EQ(murmurHash3_x86_32("aaa", seed), 0x283E0130u);
  EXPECT_EQ(murmurHash3_x86_32("aa", seed), 0x5D211726u);
  EXPECT_EQ(murmurHash3_x86_32("a", seed), 0x7FA09EA6u);
  EXPECT_EQ(murmurHash3_x86_32("abcd", seed), 0xF0478627u);
  EXPECT_EQ(murmurHash3_x86_32("abc", seed), 0xC84A62DDu);
  EXPECT_EQ(murmurHash3_x86_32("ab", seed), 0x74875592u);
  EXPECT_EQ(murmurHash3_x86_32("Hello, world!", seed), 0x24884CBAu);
  EXPECT_EQ(murmurHash3_x86_32("The quick brown fox jumps over the lazy dog", seed), 0x2FA826CDu);
  EXPECT_EQ(cryptomatteId("bunny"), 0x13851a76u);
  EXPECT_EQ(cryptomatteId("default"), 0x42c9679fu);
  EXPECT_EQ(cryptomatteId("bunny_porcelain_mat"), 0xb24b26d4u);
}

// The exponent is clamped to [1, 254]; sign and mantissa stay: no id is zero, denormal,
// infinite or NaN, and ordinary values pass unchanged.
TEST(Cryptomatte, TheFloatConversionClampsTheExponentOnly) {
  EXPECT_EQ(cryptomatteIdBits(0x00000000u), 0x00800000u);
  EXPECT_EQ(cryptomatteIdBits(0x00000001u), 0x00800001u);
  EXPECT_EQ(cryptomatteIdBits(0x80000000u), 0x80800000u);
  EXPECT_EQ(cryptomatteIdBits(0x7f800000u), 0x7f000000u);  // +inf
  EXPECT_EQ(cryptomatteIdBits(0xffffffffu), 0xff7fffffu);  // a NaN
  EXPECT_EQ(cryptomatteIdBits(0x3f800000u), 0x3f800000u);  // 1.0f
  EXPECT_EQ(cryptomatteIdBits(0x13851a76u), 0x13851a76u);
  for (uint32_t e = 0; e < 256; ++e)
    for (uint32_t low : {0u, 1u, 0x7fffffu}) {
      const uint32_t h = (e << 23) | low | (e & 1u) << 31;
      const float f = cryptomatteIdFloat(cryptomatteIdBits(h));
      EXPECT_TRUE(std::isnormal(f)) << std::hex << h;
      EXPECT_EQ(bitsOf(f) & 0x807fffffu, h & 0x807fffffu) << std::hex << h;
    }
}

// Keys are the first 7 hex digits of the type name's hash (MurmurHash3 of "CryptoObject" is
// 0x3ae39a58, of "CryptoMaterial" 0xbe359d67, as the mmh3 package computes them), and the
// header holds the spec's four entries under it.
TEST(Cryptomatte, KeysAndMetadataFollowTheSpecification) {
  EXPECT_EQ(cryptomatteKey(CryptomatteType::Object), "3ae39a5");
  EXPECT_EQ(cryptomatteKey(CryptomatteType::Material), "be359d6");
  auto meta = cryptomatteMetadata(CryptomatteType::Object, {"default", "bunny"});
  ASSERT_EQ(meta.size(), 4u);
  EXPECT_EQ(meta[0].first, "cryptomatte/3ae39a5/name");
  EXPECT_EQ(meta[0].second, "CryptoObject");
  EXPECT_EQ(meta[1].first, "cryptomatte/3ae39a5/hash");
  EXPECT_EQ(meta[1].second, "MurmurHash3_32");
  EXPECT_EQ(meta[2].first, "cryptomatte/3ae39a5/conversion");
  EXPECT_EQ(meta[2].second, "uint32_to_float32");
  EXPECT_EQ(meta[3].first, "cryptomatte/3ae39a5/manifest");
  EXPECT_EQ(meta[3].second, R"({"bunny":"13851a76","default":"42c9679f"})");
  EXPECT_EQ(cryptomatteLayerName(CryptomatteType::Material, 2), "CryptoMaterial02");
  CryptomatteType t;
  EXPECT_TRUE(cryptomatteTypeOfLayer("CryptoMaterial01", t));
  EXPECT_EQ(t, CryptomatteType::Material);
  EXPECT_TRUE(cryptomatteTypeOfLayer("CryptoObject", t));
  EXPECT_EQ(t, CryptomatteType::Object);
  EXPECT_FALSE(cryptomatteTypeOfLayer("CryptoObject03", t));
  EXPECT_FALSE(cryptomatteTypeOfLayer("albedo", t));
}

TEST(Cryptomatte, ManifestNamesAreEscapedAndListedOnce) {
  EXPECT_EQ(cryptomatteManifest({}), "{}");
  const std::string quoted = "/World/a\"b";
  const std::string m = cryptomatteManifest({quoted, quoted});
  char hex[9];
  std::snprintf(hex, sizeof hex, "%08x", cryptomatteId(quoted));
  EXPECT_EQ(m, std::string(R"({"/World/a\"b":")") + hex + "\"}");
}

// Ranks by count (ties: smaller id first), coverage = count / n with the pixel's misses in
// n; ids beyond the table's kCryptomatteEntries are not counted.
TEST(Cryptomatte, RankedCoverageOfATable) {
  CryptomatteEntry table[kCryptomatteEntries];
  const uint32_t a = cryptomatteId("a"), b = cryptomatteId("b"), c = cryptomatteId("c");
  for (int i = 0; i < 10; ++i) cryptomatteCount(table, a);
  for (int i = 0; i < 5; ++i) cryptomatteCount(table, c), cryptomatteCount(table, b);
  float out[4 * kCryptomatteLayers];
  cryptomatteRanked(table, 25, out);  // 5 samples missed
  const uint32_t first = std::min(b, c), second = std::max(b, c);
  EXPECT_EQ(bitsOf(out[0]), a);
  EXPECT_FLOAT_EQ(out[1], 0.4f);
  EXPECT_EQ(bitsOf(out[2]), first);
  EXPECT_FLOAT_EQ(out[3], 0.2f);
  EXPECT_EQ(bitsOf(out[4]), second);
  EXPECT_FLOAT_EQ(out[5], 0.2f);
  for (int i = 6; i < 4 * kCryptomatteLayers; ++i) EXPECT_EQ(out[i], 0.0f) << i;

  CryptomatteEntry full[kCryptomatteEntries];
  for (int k = 0; k <= kCryptomatteEntries; ++k)
    for (int i = 0; i <= k; ++i) cryptomatteCount(full, cryptomatteId("id" + std::to_string(k)));
  int counted = 0;
  for (const CryptomatteEntry& e : full) counted += int(e.count);
  EXPECT_EQ(counted, kCryptomatteEntries * (kCryptomatteEntries + 1) / 2);  // the last id's samples are lost
  for (const CryptomatteEntry& e : full) EXPECT_NE(e.id, cryptomatteId("id" + std::to_string(kCryptomatteEntries)));
}
