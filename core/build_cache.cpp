#include "build_cache.h"

#include <dirent.h>
#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <iostream>
#include <ostream>
#include <streambuf>

#include <embree3/rtcore_config.h>
#include <openvdb/version.h>
#include <tbb/parallel_for.h>

#include "cache.h"
#include "error.h"
#include "rng.h"

namespace granular {

namespace {

constexpr char kMagic[8] = {'G', 'R', 'B', 'U', 'I', 'L', 'D', '\0'};
constexpr size_t kHeaderBytes = 48;  // magic, version, header size, key, payload size and sum, header sum
constexpr uint64_t kDefaultLimitMiB = 4096;

// A checksum of the payload: 1 MiB chunks hashed (in parallel when reading: an entry of
// a paper-scale aggregate is tens of MiB), their sums folded in order.
constexpr size_t kChunk = size_t(1) << 20;

uint64_t chunkSum(size_t index, const char* data, size_t size) { return hashBytes(mix64(index + 1), data, size); }

uint64_t foldSums(const std::vector<uint64_t>& sums, uint64_t size) {
  uint64_t h = mix64(size);
  for (uint64_t s : sums) h = hashCombine(h, s);
  return h;
}

uint64_t payloadChecksum(const char* data, size_t size) {
  const size_t chunks = (size + kChunk - 1) / kChunk;
  std::vector<uint64_t> sums(chunks);
  tbb::parallel_for(size_t(0), chunks,
                    [&](size_t c) { sums[c] = chunkSum(c, data + c * kChunk, std::min(kChunk, size - c * kChunk)); });
  return foldSums(sums, size);
}

uint64_t headerChecksum(const char* header) { return hashBytes(0x4752425549ULL, header, kHeaderBytes - 8); }

std::vector<char> makeHeader(uint64_t key, uint64_t payloadBytes, uint64_t payloadSum) {
  std::vector<char> h(kMagic, kMagic + sizeof kMagic);
  appendBytes(h, kBuildFormatVersion);
  appendBytes(h, uint32_t(kHeaderBytes));
  appendBytes(h, key);
  appendBytes(h, payloadBytes);
  appendBytes(h, payloadSum);
  appendBytes(h, headerChecksum(h.data()));
  return h;
}

// The payload's way to its file: written in chunks, each summed on the way (the entry is
// never held whole in memory; the distance field streams straight in).
class PayloadSink : public std::streambuf {
 public:
  explicit PayloadSink(int fd) : fd_(fd), buf_(kChunk) { setp(buf_.data(), buf_.data() + buf_.size()); }
  // Flushes the last chunk: false if any write failed.
  bool finish() {
    flushChunk();
    return ok_;
  }
  uint64_t size() const { return size_; }
  uint64_t checksum() const { return foldSums(sums_, size_); }

 protected:
  int_type overflow(int_type c) override {
    flushChunk();
    if (!traits_type::eq_int_type(c, traits_type::eof())) {
      *pptr() = traits_type::to_char_type(c);
      pbump(1);
    }
    return ok_ ? traits_type::not_eof(c) : traits_type::eof();
  }

 private:
  void flushChunk() {
    const size_t n = size_t(pptr() - pbase());
    if (n == 0) return;
    sums_.push_back(chunkSum(sums_.size(), pbase(), n));
    const char* p = pbase();
    for (size_t left = n; ok_ && left > 0;) {
      const ssize_t w = ::write(fd_, p, left);
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) ok_ = false;
      else p += w, left -= size_t(w);
    }
    size_ += n;
    setp(buf_.data(), buf_.data() + buf_.size());
  }
  int fd_;
  std::vector<char> buf_;
  std::vector<uint64_t> sums_;
  uint64_t size_ = 0;
  bool ok_ = true;
};

// Bounds-checked reads from a mapped payload.
struct Cursor {
  const char* p;
  size_t left;
  template <typename T>
  bool get(T& v) {
    if (left < sizeof(T)) return false;
    std::memcpy(&v, p, sizeof(T));
    p += sizeof(T);
    left -= sizeof(T);
    return true;
  }
  template <typename T>
  bool getArray(std::vector<T>& v, uint64_t maxCount) {
    uint64_t n;
    if (!get(n) || n > maxCount || n > left / sizeof(T)) return false;
    v.resize(size_t(n));
    std::memcpy(v.data(), p, size_t(n) * sizeof(T));
    p += n * sizeof(T);
    left -= n * sizeof(T);
    return true;
  }
};

template <typename T>
void put(std::ostream& out, const T& v) {
  out.write(reinterpret_cast<const char*>(&v), sizeof v);
}

template <typename T>
void putArray(std::ostream& out, const std::vector<T>& v) {
  put(out, uint64_t(v.size()));
  out.write(reinterpret_cast<const char*>(v.data()), std::streamsize(v.size() * sizeof(T)));
}

// Cell classes as runs, (length << 2) | class: a paper-scale grid of 8·10^7 cells is a
// few hundred thousand runs (whole rows outside or inside).
constexpr uint32_t kMaxRun = (1u << 30) - 1;

void putClasses(std::ostream& out, const std::vector<CellClass>& classes) {
  std::vector<uint32_t> runs;
  for (size_t i = 0; i < classes.size();) {
    size_t j = i + 1;
    while (j < classes.size() && classes[j] == classes[i] && j - i < kMaxRun) ++j;
    runs.push_back(uint32_t(j - i) << 2 | uint32_t(classes[i]));
    i = j;
  }
  putArray(out, runs);
}

bool readClasses(Cursor& c, size_t cells, std::vector<CellClass>& classes) {
  std::vector<uint32_t> runs;
  if (!c.getArray(runs, cells)) return false;
  classes.resize(cells);
  size_t at = 0;
  for (uint32_t r : runs) {
    const size_t n = r >> 2;
    const uint32_t cls = r & 3;
    if (n == 0 || cls > uint32_t(CellClass::Inside) || n > cells - at) return false;
    std::memset(classes.data() + at, int(cls), n);
    at += n;
  }
  return at == cells;
}

bool parsePayload(const char* data, size_t size, size_t sphereCount, BuildProducts& out, std::string& why) {
  Cursor c{data, size};
  int64_t n[3] = {0, 0, 0};
  float origin[3] = {0, 0, 0}, cellSize = 0, voxelSize = 0, bandWidth = 0;
  double anchor[3] = {0, 0, 0};
  bool ok = c.get(n[0]) && c.get(n[1]) && c.get(n[2]);
  for (float& o : origin) ok = ok && c.get(o);
  ok = ok && c.get(cellSize) && c.get(voxelSize) && c.get(bandWidth);
  for (double& a : anchor) ok = ok && c.get(a);
  if (!ok) return (why = "short payload"), false;
  // Bit for bit: a build of these inputs computes exactly these.
  const auto same = [](auto a, auto b) { return std::memcmp(&a, &b, sizeof a) == 0; };
  if (n[0] != out.cells[0] || n[1] != out.cells[1] || n[2] != out.cells[2] || !same(origin[0], out.origin.x) ||
      !same(origin[1], out.origin.y) || !same(origin[2], out.origin.z) || !same(cellSize, out.cellSize) ||
      !same(voxelSize, out.voxelSize) || !same(bandWidth, out.bandWidth) || !same(anchor[0], out.anchor.x) ||
      !same(anchor[1], out.anchor.y) || !same(anchor[2], out.anchor.z))
    return (why = "made for another grid"), false;
  const size_t cells = size_t(n[0] * n[1] * n[2]);
  if (!(c.get(out.insideCells) && c.get(out.partialCells) && c.get(out.approxGrains) && c.get(out.maxInteriorDepth)))
    return (why = "short payload"), false;
  if (!readClasses(c, cells, out.classes)) return (why = "bad cell classes"), false;
  int64_t inside = 0, partial = 0;
  for (CellClass k : out.classes) {
    inside += k == CellClass::Inside;
    partial += k == CellClass::Partial;
  }
  if (inside != out.insideCells || partial != out.partialCells) return (why = "cell counts disagree"), false;
  if (!c.get(out.sub) || out.sub < 1 || out.sub > 1024) return (why = "bad sub-cell grid"), false;
  const uint64_t subCells = uint64_t(out.sub) * uint64_t(out.sub) * uint64_t(out.sub);
  if (!c.getArray(out.subStart, subCells + 1) || out.subStart.size() != subCells + 1 || out.subStart[0] != 0)
    return (why = "bad sub-cell lists"), false;
  if (!c.getArray(out.subList, c.left / sizeof(uint32_t)) || out.subStart.back() != out.subList.size() ||
      !std::is_sorted(out.subStart.begin(), out.subStart.end()) ||
      std::any_of(out.subList.begin(), out.subList.end(), [&](uint32_t s) { return s >= sphereCount; }))
    return (why = "bad sub-cell lists"), false;
  // The rest is the distance field.
  if (!out.sdf.read(c.p, c.left, out.voxelSize, out.bandWidth, out.anchor)) return (why = "bad distance field"), false;
  return true;
}

// A read-only mapping of a whole file.
struct Mapping {
  int fd = -1;
  const char* data = nullptr;
  size_t size = 0;
  ~Mapping() {
    if (data) munmap(const_cast<char*>(data), size);
    if (fd >= 0) close(fd);
  }
  // False when the file is absent or unreadable (a miss, not damage).
  bool open(const std::string& path) {
    fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    struct stat st;
    if (fd < 0 || fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) return false;
    size = size_t(st.st_size);
    if (size == 0) return true;
    void* p = mmap(nullptr, size, PROT_READ, MAP_PRIVATE, fd, 0);
    if (p == MAP_FAILED) return false;
    madvise(p, size, MADV_SEQUENTIAL);
    data = static_cast<const char*>(p);
    return true;
  }
};

// Why the mapped entry cannot be trusted ("" when it can); out gets its products.
std::string checkEntry(const Mapping& m, uint64_t key, size_t sphereCount, BuildProducts& out) {
  if (m.size < kHeaderBytes) return str("truncated: ", m.size, " bytes, shorter than its header");
  if (std::memcmp(m.data, kMagic, sizeof kMagic) != 0) return "not a build cache entry";
  uint32_t version, headerBytes;
  uint64_t storedKey, payloadBytes, payloadSum, headerSum;
  std::memcpy(&version, m.data + 8, 4);
  std::memcpy(&headerBytes, m.data + 12, 4);
  std::memcpy(&storedKey, m.data + 16, 8);
  std::memcpy(&payloadBytes, m.data + 24, 8);
  std::memcpy(&payloadSum, m.data + 32, 8);
  std::memcpy(&headerSum, m.data + 40, 8);
  if (headerSum != headerChecksum(m.data)) return "its header's checksum does not match";
  if (version != kBuildFormatVersion || headerBytes != kHeaderBytes)
    return str("format version ", version, ", expected ", kBuildFormatVersion);
  if (storedKey != key) return "made for other inputs";
  if (payloadBytes != m.size - kHeaderBytes)
    return str(m.size < kHeaderBytes + payloadBytes ? "truncated: " : "too long: ", m.size, " bytes, its header says ",
               kHeaderBytes + payloadBytes);
  if (payloadChecksum(m.data + kHeaderBytes, payloadBytes) != payloadSum) return "its payload's checksum does not match";
  std::string why;
  if (!parsePayload(m.data + kHeaderBytes, payloadBytes, sphereCount, out, why)) return why;
  return "";
}

struct EntryFile {
  std::string name;
  uint64_t size;
  int64_t mtimeNs;
};

// Removes the least recently used build entries (never `keep`) while they exceed the
// limit, and temporary files that crashed writers left over an hour ago.
void evict(const std::string& dir, const std::string& keep, uint64_t limit) {
  DIR* d = opendir(dir.c_str());
  if (!d) return;
  std::vector<EntryFile> entries;
  uint64_t total = 0;
  const std::string prefix = "build-";
  struct timespec now;
  clock_gettime(CLOCK_REALTIME, &now);
  while (const dirent* e = readdir(d)) {
    const std::string name = e->d_name;
    if (name.compare(0, prefix.size(), prefix) != 0) continue;
    struct stat st;
    const std::string path = dir + "/" + name;
    if (stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) continue;
    const bool entry = name.size() > 4 && name.compare(name.size() - 4, 4, ".bin") == 0;
    if (!entry) {
      if (name.find(".bin.tmp.") != std::string::npos && now.tv_sec - st.st_mtim.tv_sec > 3600) unlink(path.c_str());
      continue;
    }
    entries.push_back({name, uint64_t(st.st_size), int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec});
    total += uint64_t(st.st_size);
  }
  closedir(d);
  if (total <= limit) return;
  std::sort(entries.begin(), entries.end(), [](const EntryFile& a, const EntryFile& b) {
    return a.mtimeNs != b.mtimeNs ? a.mtimeNs < b.mtimeNs : a.name < b.name;
  });
  for (const EntryFile& e : entries) {
    if (total <= limit) break;
    if (e.name == keep) continue;
    // Another process may have removed it first, or a reader still maps it: its mapping
    // stays valid, and a later reader misses and rebuilds.
    if (unlink((dir + "/" + e.name).c_str()) == 0 || errno == ENOENT) total -= e.size;
  }
}

}  // namespace

uint64_t buildKey(const AggregateDesc& desc, const TriangleMesh& worldBoundary, const Tile& tile) {
  uint64_t h = hashInts(0x4752425549ULL /* "GRBUI" */, kBuildFormatVersion, OPENVDB_LIBRARY_VERSION_NUMBER, RTC_VERSION);
  h = hashValue(h, uint64_t(worldBoundary.points.size()));
  for (const Vec3& p : worldBoundary.points) {
    const float xyz[3] = {p.x, p.y, p.z};
    h = hashBytes(h, xyz, sizeof xyz);
  }
  h = hashBytes(h, worldBoundary.indices.data(), worldBoundary.indices.size() * sizeof(uint32_t));
  h = hashValue(h, uint64_t(desc.boundary.points.size()));
  for (const Vec3& p : desc.boundary.points) {
    const float xyz[3] = {p.x, p.y, p.z};
    h = hashBytes(h, xyz, sizeof xyz);
  }
  for (int r = 0; r < 3; ++r) h = hashBytes(h, desc.xf.m[r], 4 * sizeof(double));
  h = hashValue(h, desc.grainRadius);
  h = hashValue(h, desc.packingRate);
  h = hashValue(h, desc.seed);
  h = hashValue(h, int32_t(desc.tileSpheres));
  h = hashValue(h, desc.fineFieldBytes);  // which voxel the field takes
  h = hashValue(h, desc.sizeSpread);
  h = hashBytes(h, desc.sizes.data(), desc.sizes.size() * sizeof(float));
  h = hashBytes(h, desc.weights.data(), desc.weights.size() * sizeof(float));
  h = hashValue(h, int32_t(tile.numSpheres));
  h = hashValue(h, tile.radius);
  h = hashValue(h, tile.packingRate);
  h = hashValue(h, tile.seed);
  for (const Vec3& c : tile.centers) {
    const float xyz[3] = {c.x, c.y, c.z};
    h = hashBytes(h, xyz, sizeof xyz);
  }
  h = hashBytes(h, tile.sizes.data(), tile.sizes.size() * sizeof(float));
  return hashBytes(h, tile.classes.data(), tile.classes.size());
}

std::string buildCacheName(uint64_t key) {
  char hex[17];
  std::snprintf(hex, sizeof hex, "%016llx", static_cast<unsigned long long>(key));
  return str("build-v", kBuildFormatVersion, "-", hex, ".bin");
}

uint64_t buildCacheLimitBytes() {
  const char* v = std::getenv("GRANULAR_CACHE_MAX_MB");
  if (!v || !*v) return kDefaultLimitMiB << 20;
  char* end = nullptr;
  const double mib = std::strtod(v, &end);
  if (end == v || *end != '\0' || !(mib >= 0) || mib > 1e12) {
    static std::atomic<bool> warned{false};  // once per process
    if (!warned.exchange(true)) {
      std::cerr << "warning: GRANULAR_CACHE_MAX_MB=\"" << v << "\" is not a size in MiB; using " << kDefaultLimitMiB
                << "\n";
    }
    return kDefaultLimitMiB << 20;
  }
  return uint64_t(mib * 1048576.0);
}

bool loadBuild(uint64_t key, size_t sphereCount, BuildProducts& out) {
  if (buildCacheLimitBytes() == 0) return false;
  const std::string dir = cacheDirectory();
  if (dir.empty()) return false;
  const std::string path = dir + "/" + buildCacheName(key);
  Mapping m;
  if (!m.open(path)) return false;
  const std::string why = checkEntry(m, key, sphereCount, out);
  if (!why.empty()) {
    std::cerr << "warning: aggregate build cache entry " << path << " is damaged (" << why
              << "); rebuilding it\n";
    out.sdf = DistanceField();
    return false;
  }
  futimens(m.fd, nullptr);  // used now (LRU); a read-only cache stays as it is
  return true;
}

bool storeBuild(uint64_t key, const BuildProducts& p) {
  const uint64_t limit = buildCacheLimitBytes();
  if (limit == 0) return false;
  const std::string dir = cacheDirectory();
  if (dir.empty()) return false;
  const std::string name = buildCacheName(key), path = dir + "/" + name;
  std::string tmp = path + ".tmp.XXXXXX";
  const int fd = mkostemp(tmp.data(), O_CLOEXEC);
  if (fd < 0) return false;
  // The payload after room for the header, which follows once its length and sum are known.
  bool ok = fchmod(fd, 0644) == 0 && lseek(fd, off_t(kHeaderBytes), SEEK_SET) == off_t(kHeaderBytes);
  PayloadSink sink(fd);
  if (ok) {
    try {
      std::ostream out(&sink);
      for (int64_t n : p.cells) put(out, n);
      for (float v : {p.origin.x, p.origin.y, p.origin.z, p.cellSize, p.voxelSize, p.bandWidth}) put(out, v);
      for (double v : {p.anchor.x, p.anchor.y, p.anchor.z}) put(out, v);
      put(out, p.insideCells);
      put(out, p.partialCells);
      put(out, p.approxGrains);
      put(out, p.maxInteriorDepth);
      putClasses(out, p.classes);
      put(out, p.sub);
      putArray(out, p.subStart);
      putArray(out, p.subList);
      p.sdf.write(out);
      ok = out.good();
    } catch (const std::exception&) {
      ok = false;
    }
  }
  ok = sink.finish() && ok;
  // Beyond the limit on its own, the entry would only evict everything.
  ok = ok && kHeaderBytes + sink.size() <= limit;
  if (ok) {
    const std::vector<char> header = makeHeader(key, sink.size(), sink.checksum());
    ok = pwrite(fd, header.data(), header.size(), 0) == ssize_t(header.size());
  }
  ok = (close(fd) == 0) && ok;
  if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
    unlink(tmp.c_str());
    return false;
  }
  evict(dir, name, limit);
  return true;
}

}  // namespace granular
