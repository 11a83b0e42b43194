// The aggregate build cache (core/build_cache.h): a build from the cache has every
// product of the first build, and renders bit for bit the same; damaged entries are
// caught (one warning) and rebuilt; racing writers both succeed; changed inputs miss;
// the size limit evicts the least recently used entries.
#include <gtest/gtest.h>

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <vector>

#include "core/aggregate.h"
#include "core/build_cache.h"
#include "core/cache.h"
#include "core/grain.h"
#include "core/packing.h"
#include "core/render.h"
#include "core/rng.h"
#include "core/sampling.h"
#include "core/scene.h"
#include "core/shapes.h"
#include "test_helpers.h"

using namespace granular;
using granular::testing::sameImage;

namespace {

// A fresh, empty cache folder for one test (GRANULAR_CACHE_DIR), and a size limit;
// both restored and the folder removed afterwards.
class ScopedCache {
 public:
  explicit ScopedCache(const char* maxMb = nullptr) {
    char tmpl[] = "/tmp/granular-build-cache-XXXXXX";
    dir_ = mkdtemp(tmpl);
    save("GRANULAR_CACHE_DIR", oldDir_, hadDir_);
    save("GRANULAR_CACHE_MAX_MB", oldMax_, hadMax_);
    setenv("GRANULAR_CACHE_DIR", dir_.c_str(), 1);
    setMaxMb(maxMb);
  }
  ~ScopedCache() {
    restore("GRANULAR_CACHE_DIR", oldDir_, hadDir_);
    restore("GRANULAR_CACHE_MAX_MB", oldMax_, hadMax_);
    std::system(("rm -rf '" + dir_ + "'").c_str());
  }
  void setMaxMb(const char* maxMb) {
    if (maxMb)
      setenv("GRANULAR_CACHE_MAX_MB", maxMb, 1);
    else
      unsetenv("GRANULAR_CACHE_MAX_MB");
  }
  const std::string& dir() const { return dir_; }

 private:
  static void save(const char* name, std::string& value, bool& had) {
    const char* v = std::getenv(name);
    had = v != nullptr;
    if (v) value = v;
  }
  static void restore(const char* name, const std::string& value, bool had) {
    if (had)
      setenv(name, value.c_str(), 1);
    else
      unsetenv(name);
  }
  std::string dir_, oldDir_, oldMax_;
  bool hadDir_ = false, hadMax_ = false;
};

AggregateDesc castle(float R = 0.04f, float f = 0.55f) { return granular::testing::smallAggregate(R, f, 11, "cached_sand"); }

struct Built {
  EmbreeDevice device = makeEmbreeDevice();
  Aggregate agg;
  explicit Built(const AggregateDesc& d) { agg.build(d, device, {0, 0}); }
};

std::string entryPath(const std::string& dir, const AggregateDesc& d) {
  TriangleMesh world = d.boundary.transformed(d.xf);
  if (world.signedVolume() < 0) world.flip();
  const SizeClasses classes = sizeClassesOf(d);
  TileSizes sizes;
  sizes.classSize.assign(classes.size.begin(), classes.size.end());
  sizes.classWeight = classes.weight;
  sizes.spread = d.sizeSpread;
  const Tile tile = loadOrGenerateTile(d.tileSpheres, d.packingRate, d.seed, sizes);
  return dir + "/" + buildCacheName(buildKey(d, world, tile));
}

bool sameBits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

// Every product, and what the queries make of them, bit for bit.
void expectSameProducts(const Aggregate& a, const Aggregate& b) {
  const AggregateStats &sa = a.stats(), &sb = b.stats();
  EXPECT_EQ(sa.cells, sb.cells);
  EXPECT_EQ(sa.insideCells, sb.insideCells);
  EXPECT_EQ(sa.partialCells, sb.partialCells);
  EXPECT_EQ(sa.approxGrains, sb.approxGrains);
  EXPECT_TRUE(sameBits(sa.maxInteriorDepth, sb.maxInteriorDepth));
  EXPECT_EQ(sa.memoryBytes, sb.memoryBytes);
  ASSERT_TRUE(sameBits(a.cellSize(), b.cellSize()));
  for (int k = 0; k < 3; ++k) {
    ASSERT_TRUE(sameBits(a.bounds().lo[k], b.bounds().lo[k]));
    ASSERT_TRUE(sameBits(a.bounds().hi[k], b.bounds().hi[k]));
  }
  // Cell classes, one cell beyond the grid on each side.
  int64_t n[3];
  for (int k = 0; k < 3; ++k) n[k] = std::lround((a.bounds().hi[k] - a.bounds().lo[k]) / a.cellSize());
  ASSERT_EQ(n[0] * n[1] * n[2], sa.cells);
  int64_t differing = 0;
  for (int64_t z = -1; z <= n[2]; ++z)
    for (int64_t y = -1; y <= n[1]; ++y)
      for (int64_t x = -1; x <= n[0]; ++x) differing += a.cellClass(x, y, z) != b.cellClass(x, y, z);
  EXPECT_EQ(differing, 0);
  // The distance field: trilinear and nearest-voxel values on a lattice finer than its
  // voxels, across the band and beyond it.
  const DistanceField &fa = a.distanceField(), &fb = b.distanceField();
  EXPECT_TRUE(sameBits(fa.voxelSize(), fb.voxelSize()));
  EXPECT_TRUE(sameBits(fa.bandWidth(), fb.bandWidth()));
  DistanceField::NearestProbe pa(fa), pb(fb);
  const float step = 0.37f * fa.voxelSize();
  const Vec3 lo = a.bounds().lo - Vec3(fa.bandWidth()), hi = a.bounds().hi + Vec3(fa.bandWidth());
  int64_t samples = 0;
  differing = 0;
  for (float z = lo.z; z < hi.z; z += step)
    for (float y = lo.y; y < hi.y; y += step)
      for (float x = lo.x; x < hi.x; x += step) {
        const Vec3 p(x, y, z);
        differing += !sameBits(fa.distance(p), fb.distance(p)) || !sameBits(pa(p), pb(p));
        ++samples;
      }
  EXPECT_GT(samples, 10000);
  EXPECT_EQ(differing, 0);
  // Rays (the sub-cell lists, the classes and the field's jumps together).
  const Vec3 centre = (a.bounds().lo + a.bounds().hi) * 0.5f;
  int hits = 0;
  for (uint64_t i = 0; i < 3000; ++i) {
    const uint64_t h = mix64(i + 77);
    const Vec3 d = sampleUniformSphere(toUnitFloat(h), toUnitFloat(h << 24));
    const Vec3 o = centre - d * 2.0f + Vec3(toUnitFloat(mix64(h)) - 0.5f, toUnitFloat(mix64(h + 1)) - 0.5f, 0.0f) * 0.8f;
    GrainHit ha, hb;
    const bool ia = a.intersect(o, d, 0.0f, kInf, ha), ib = b.intersect(o, d, 0.0f, kInf, hb);
    ASSERT_EQ(ia, ib) << "ray " << i;
    EXPECT_EQ(a.occluded(o, d, 0.0f, kInf), b.occluded(o, d, 0.0f, kInf));
    if (!ia) continue;
    ++hits;
    EXPECT_TRUE(sameBits(ha.t, hb.t));
    EXPECT_EQ(ha.sphere, hb.sphere);
    EXPECT_EQ(ha.prototype, hb.prototype);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(ha.cell[k], hb.cell[k]);
      EXPECT_TRUE(sameBits(ha.ng[k], hb.ng[k]));
    }
  }
  EXPECT_GT(hits, 1000);
  std::vector<Vec3> ga, gb;
  a.forEachGrain(a.bounds(), [&](const GrainInstance& g) { ga.push_back(g.center); });
  b.forEachGrain(b.bounds(), [&](const GrainInstance& g) { gb.push_back(g.center); });
  ASSERT_EQ(ga.size(), gb.size());
  for (size_t i = 0; i < ga.size(); ++i)
    for (int k = 0; k < 3; ++k) ASSERT_TRUE(sameBits(ga[i][k], gb[i][k]));
}

std::vector<char> readFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<char>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeFile(const std::string& path, const std::vector<char>& bytes, size_t size) {
  std::ofstream(path, std::ios::binary | std::ios::trunc).write(bytes.data(), std::streamsize(size));
}

int count(const std::string& text, const std::string& word) {
  int n = 0;
  for (size_t at = text.find(word); at != std::string::npos; at = text.find(word, at + 1)) ++n;
  return n;
}

}  // namespace

TEST(BuildCache, SecondBuildComesFromTheCacheWithEveryProductIdentical) {
  ScopedCache cache;
  const AggregateDesc d = castle();
  Built first(d);
  EXPECT_FALSE(first.agg.stats().fromCache);
  const std::string path = entryPath(cache.dir(), d);
  ASSERT_TRUE(std::ifstream(path).good()) << path;
  Built second(d);
  EXPECT_TRUE(second.agg.stats().fromCache);
  expectSameProducts(first.agg, second.agg);
  // A renamed aggregate (no product depends on the name) takes the same entry.
  AggregateDesc renamed = d;
  renamed.name = "another_name";
  EXPECT_TRUE(Built(renamed).agg.stats().fromCache);
}

TEST(BuildCache, PolydisperseAndUntransformedBuildsRoundTrip) {
  ScopedCache cache;
  AggregateDesc d = castle(0.05f, 0.5f);
  d.xf = Transform();
  d.sizes = {1.0f, 1.6f};
  d.sizeSpread = 0.1f;
  Built first(d);
  Built second(d);
  EXPECT_FALSE(first.agg.stats().fromCache);
  EXPECT_TRUE(second.agg.stats().fromCache);
  expectSameProducts(first.agg, second.agg);
}

TEST(BuildCache, RenderFromTheCacheIsBitIdentical) {
  ScopedCache cache;
  SceneDesc d = granular::testing::sandBallScene(Vec3(0, 0.5f, 4), 24, 0.03f, 5);
  d.settings.width = 40;
  d.settings.height = 30;
  d.settings.spp = 4;
  d.settings.technique = Technique::Ept;  // no medium: only the build is cached here
  auto render = [&](bool expectCached) {
    auto scene = Scene::build(d);
    EXPECT_EQ(scene->aggregates().at(0)->stats().fromCache, expectCached);
    Renderer r(*scene);
    EXPECT_TRUE(r.render(2));
    return r.film().toImage();
  };
  const Image cold = render(false);
  const Image warm = render(true);
  EXPECT_TRUE(sameImage(cold, warm));
  double sum = 0;
  for (float v : cold.pixels) sum += std::isfinite(v) ? v : 0;
  EXPECT_GT(sum, 0);  // grains were seen
}

TEST(BuildCache, DamagedEntriesWarnOnceAndAreRebuilt) {
  ScopedCache cache;
  const AggregateDesc d = castle();
  Built reference(d);
  const std::string path = entryPath(cache.dir(), d);
  const std::vector<char> good = readFile(path);
  ASSERT_GT(good.size(), 1000u);

  struct Damage {
    const char* what;
    std::vector<char> bytes;
    size_t size;
  };
  std::vector<Damage> damages;
  damages.push_back({"truncated mid-payload", good, good.size() - 123});
  damages.push_back({"truncated in the header", good, 20});
  damages.push_back({"empty", good, 0});
  for (size_t at : {size_t(5), size_t(18), good.size() / 3, good.size() / 2, good.size() - 1}) {
    std::vector<char> flipped = good;
    flipped[at] ^= 0x10;
    damages.push_back({"a flipped byte", flipped, flipped.size()});
  }
  std::vector<char> longer = good;
  longer.push_back('x');
  damages.push_back({"a byte appended", longer, longer.size()});

  for (const Damage& damage : damages) {
    SCOPED_TRACE(damage.what);
    writeFile(path, damage.bytes, damage.size);
    ::testing::internal::CaptureStderr();
    Built rebuilt(d);
    const std::string err = ::testing::internal::GetCapturedStderr();
    EXPECT_FALSE(rebuilt.agg.stats().fromCache);
    EXPECT_EQ(count(err, "warning:"), 1) << err;
    EXPECT_NE(err.find(path), std::string::npos) << err;
    expectSameProducts(reference.agg, rebuilt.agg);
    // Rewritten: the next build takes it, silently.
    EXPECT_EQ(readFile(path).size(), good.size());
    ::testing::internal::CaptureStderr();
    Built again(d);
    EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
    EXPECT_TRUE(again.agg.stats().fromCache);
  }
}

TEST(BuildCache, RacingBuildsOfAnEmptyCacheBothSucceed) {
  ScopedCache cache;
  const AggregateDesc d = castle(0.03f);
  for (int round = 0; round < 3; ++round) {
    std::remove(entryPath(cache.dir(), d).c_str());
    std::unique_ptr<Built> a, b;
    std::thread ta([&] { a = std::make_unique<Built>(d); });
    std::thread tb([&] { b = std::make_unique<Built>(d); });
    ta.join();
    tb.join();
    ASSERT_TRUE(a && b);
    expectSameProducts(a->agg, b->agg);
    ::testing::internal::CaptureStderr();
    Built c(d);
    EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
    EXPECT_TRUE(c.agg.stats().fromCache);
    expectSameProducts(a->agg, c.agg);
  }
  // No temporary file is left behind.
  int files = 0;
  for (const char* pattern : {"/build-*.tmp.*"}) {
    const std::string cmd = "ls " + cache.dir() + pattern + " 2>/dev/null | wc -l";
    FILE* p = popen(cmd.c_str(), "r");
    ASSERT_TRUE(p);
    ASSERT_EQ(std::fscanf(p, "%d", &files), 1);
    pclose(p);
  }
  EXPECT_EQ(files, 0);
}

TEST(BuildCache, ChangedInputsMiss) {
  ScopedCache cache;
  const AggregateDesc d = castle();
  Built first(d);
  ASSERT_TRUE(Built(d).agg.stats().fromCache);

  AggregateDesc rate = d;
  rate.packingRate = 0.5f;
  EXPECT_FALSE(Built(rate).agg.stats().fromCache);
  AggregateDesc moved = d;
  moved.boundary.points[7] = moved.boundary.points[7] * 1.0001f;
  EXPECT_FALSE(Built(moved).agg.stats().fromCache);

  // Every input the products depend on names another entry.
  const std::string base = entryPath(cache.dir(), d);
  std::vector<AggregateDesc> changed(9, d);
  changed[0].grainRadius *= 1.001f;
  changed[1].seed += 1;
  changed[2].tileSpheres = 96;
  changed[3].xf = Transform::translate(Vec3(0.0f, 0.0f, 1e-3f)) * d.xf;
  changed[4].weights = {1.0f, 1.0f};
  changed[5].sizes = {1.0f, 1.2f};
  changed[6].sizeSpread = 0.05f;
  changed[7].boundary.indices[0] = d.boundary.indices[1], changed[7].boundary.indices[1] = d.boundary.indices[0];
  changed[8].packingRate = 0.5f;
  for (size_t i = 0; i < changed.size(); ++i) EXPECT_NE(entryPath(cache.dir(), changed[i]), base) << i;
  // Its own again: still there.
  EXPECT_TRUE(Built(d).agg.stats().fromCache);
}

TEST(BuildCache, LeastRecentlyUsedEntriesAreEvictedBeyondTheLimit) {
  ScopedCache cache;
  std::vector<AggregateDesc> ds;
  for (uint64_t seed : {21, 22, 23}) {
    AggregateDesc d = castle();
    d.seed = seed;
    ds.push_back(d);
  }
  // Sizes of the three entries, without a limit.
  std::vector<std::string> paths;
  std::vector<off_t> sizes;
  for (const AggregateDesc& d : ds) {
    Built b(d);
    paths.push_back(entryPath(cache.dir(), d));
    struct stat st;
    ASSERT_EQ(stat(paths.back().c_str(), &st), 0);
    sizes.push_back(st.st_size);
  }
  std::remove(paths[2].c_str());
  // Entry 0 older than entry 1, then used (a hit touches it): 1 is now the least recent.
  const timespec older[2] = {{1000, 0}, {1000, 0}}, newer[2] = {{2000, 0}, {2000, 0}};
  ASSERT_EQ(utimensat(AT_FDCWD, paths[0].c_str(), older, 0), 0);
  ASSERT_EQ(utimensat(AT_FDCWD, paths[1].c_str(), newer, 0), 0);
  EXPECT_TRUE(Built(ds[0]).agg.stats().fromCache);
  // Room for two of the three: writing entry 2 evicts entry 1.
  char mib[64];
  std::snprintf(mib, sizeof mib, "%.6f", double(sizes[0] + sizes[2] + sizes[1] / 2) / 1048576.0);
  cache.setMaxMb(mib);
  EXPECT_FALSE(Built(ds[2]).agg.stats().fromCache);
  EXPECT_TRUE(std::ifstream(paths[0]).good());
  EXPECT_FALSE(std::ifstream(paths[1]).good());
  EXPECT_TRUE(std::ifstream(paths[2]).good());
  // A limit below one entry: nothing is written (or evicted), the build still succeeds.
  cache.setMaxMb("0.001");
  EXPECT_FALSE(Built(ds[1]).agg.stats().fromCache);
  EXPECT_FALSE(std::ifstream(paths[1]).good());
  EXPECT_TRUE(std::ifstream(paths[0]).good());
  // 0 turns the build cache off: not even a valid entry is read.
  cache.setMaxMb("0");
  EXPECT_FALSE(Built(ds[0]).agg.stats().fromCache);
  cache.setMaxMb(nullptr);
  EXPECT_TRUE(Built(ds[0]).agg.stats().fromCache);
}
