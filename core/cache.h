// cache.h — the on-disk cache for derived data (tiles, transport parameters).
//
// Contract: cacheDirectory() is $GRANULAR_CACHE_DIR, else $XDG_CACHE_HOME/hdgranular,
// else ~/.cache/hdgranular, created on first use; it returns "" when none can be
// created, and callers then simply recompute. Entries are written to a temporary
// name and renamed, so concurrent renders never read half a file. Aggregate builds,
// larger and size-limited, have their own entries (build_cache.h).
#pragma once

#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "rng.h"

namespace granular {

std::string cacheDirectory();

// What tells one content of a file from another without reading it: device, inode, size,
// and the modification and status-change times to the nanosecond (exists false: no file).
// A copy that keeps the modification time (cp -p, rsync -a) still changes the
// status-change time, which no user call can set back.
struct FileVersion {
  bool exists = false;
  uint64_t device = 0, inode = 0, size = 0;
  int64_t mtimeNs = 0, ctimeNs = 0;
  bool operator==(const FileVersion& o) const {
    return exists == o.exists && device == o.device && inode == o.inode && size == o.size && mtimeNs == o.mtimeNs &&
           ctimeNs == o.ctimeNs;
  }
  bool operator!=(const FileVersion& o) const { return !(*this == o); }
};
FileVersion fileVersion(const std::string& path);

// Reads a whole cache entry; false if it is absent or unreadable.
bool readCacheFile(const std::string& name, std::vector<char>& bytes);
// Writes a cache entry atomically; false (and no exception) on failure.
bool writeCacheFile(const std::string& name, const std::vector<char>& bytes);

// Serialisation of cache entries: appends a trivially copyable value; reads one back at
// pos (false, and nothing read, when the entry is too short: a truncated file).
template <typename T>
void appendBytes(std::vector<char>& out, const T& v) {
  const char* p = reinterpret_cast<const char*>(&v);
  out.insert(out.end(), p, p + sizeof(T));
}

template <typename T>
bool readBytes(const std::vector<char>& in, size_t& pos, T& v) {
  if (in.size() < pos || in.size() - pos < sizeof(T)) return false;
  std::memcpy(&v, in.data() + pos, sizeof(T));
  pos += sizeof(T);
  return true;
}

// Keys of cache entries: bytes and values folded into a 64-bit hash.
inline uint64_t hashBytes(uint64_t h, const void* data, size_t size) {
  const char* p = static_cast<const char*>(data);
  size_t i = 0;
  for (; i + 8 <= size; i += 8) {
    uint64_t v;
    std::memcpy(&v, p + i, 8);
    h = hashCombine(h, v);
  }
  uint64_t tail = 0;
  if (size > i) std::memcpy(&tail, p + i, size - i);
  return hashCombine(hashCombine(h, tail), size);
}

template <typename T>
uint64_t hashValue(uint64_t h, const T& v) {
  return hashBytes(h, &v, sizeof v);
}

}  // namespace granular
