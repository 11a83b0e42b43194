// cache.h — the on-disk cache for derived data (tiles, transport parameters, proxy tables).
//
// Contract: cacheDirectory() is $GRANULAR_CACHE_DIR, else $XDG_CACHE_HOME/hdgranular,
// else ~/.cache/hdgranular, created on first use; it returns "" when none can be
// created, and callers then simply recompute. Entries are written to a temporary
// name and renamed, so concurrent renders never read half a file. Aggregate builds,
// larger and size-limited, have their own entries (build_cache.h).
#pragma once

#include <cstdint>
#include <cstring>
#include <iterator>
#include <string>
#include <type_traits>
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

// A cache record, the format of tiles, TT parameters and proxy tables: an 8-byte magic,
// then scalars and arrays back to back with no padding in the machine's byte order
// (little-endian wherever this builds; a cache is per machine), then a 64-bit checksum of
// every byte before it. Fields are positional: a reader gets them in the order the writer
// put them, and the format version is the record's first field after the magic.
using RecordMagic = char[8];
using RecordChecksum = uint64_t (*)(const char* data, size_t size);
// hashBytes of the bytes, seeded by their count: every record's checksum but the tile's.
uint64_t recordChecksum(const char* data, size_t size);

class RecordWriter {
 public:
  explicit RecordWriter(const RecordMagic& magic, RecordChecksum checksum = recordChecksum);
  void putU8(uint8_t v) { appendBytes(bytes_, v); }
  void putI32(int32_t v) { appendBytes(bytes_, v); }
  void putU32(uint32_t v) { appendBytes(bytes_, v); }
  void putI64(int64_t v) { appendBytes(bytes_, v); }
  void putU64(uint64_t v) { appendBytes(bytes_, v); }
  void putF32(float v) { appendBytes(bytes_, v); }
  void putF64(double v) { appendBytes(bytes_, v); }
  // The format version and the entry's key: the first fields of a keyed record.
  void putHeader(uint32_t version, uint64_t key) {
    putU32(version);
    putU64(key);
  }
  // The elements of a vector or std::array, as their bytes (no count: the reader knows it).
  template <typename Container>
  void putArray(const Container& c) {
    static_assert(std::is_trivially_copyable_v<std::decay_t<decltype(*std::data(c))>>);
    const char* p = reinterpret_cast<const char*>(std::data(c));
    bytes_.insert(bytes_.end(), p, p + std::size(c) * sizeof *std::data(c));
  }
  // Appends the checksum and hands the record over (the writer is spent).
  std::vector<char> finish();

 private:
  std::vector<char> bytes_;
  RecordChecksum checksum_;
};

// Reads a record back. The magic and the checksum are checked up front: a record failing
// either reads as empty, so every get fails. A get that would run past the checksum
// fails and leaves its target alone; later gets fail too. bytes must outlive the reader.
class RecordReader {
 public:
  RecordReader(const std::vector<char>& bytes, const RecordMagic& magic, RecordChecksum checksum = recordChecksum);
  bool getU8(uint8_t& v) { return get(v); }
  bool getI32(int32_t& v) { return get(v); }
  bool getU32(uint32_t& v) { return get(v); }
  bool getI64(int64_t& v) { return get(v); }
  bool getU64(uint64_t& v) { return get(v); }
  bool getF32(float& v) { return get(v); }
  bool getF64(double& v) { return get(v); }
  // Reads putHeader's fields: true when they are the version and key expected.
  bool getHeader(uint32_t version, uint64_t key) {
    uint32_t v = 0;
    uint64_t k = 0;
    return getU32(v) && v == version && getU64(k) && k == key;
  }
  // Fills the vector's or std::array's present elements.
  template <typename Container>
  bool getArray(Container& c) {
    static_assert(std::is_trivially_copyable_v<std::decay_t<decltype(*std::data(c))>>);
    const size_t n = std::size(c) * sizeof *std::data(c);
    if (!ok_ || end_ - pos_ < n) return ok_ = false;
    if (n > 0) std::memcpy(static_cast<void*>(std::data(c)), bytes_.data() + pos_, n);
    pos_ += n;
    return true;
  }
  // Payload bytes not yet read (0 once a get failed): lets a reader check a length read
  // from the record before it allocates for it.
  size_t remaining() const { return ok_ ? end_ - pos_ : 0; }
  // The magic and checksum matched, every get succeeded and the payload was read to its
  // last byte: the record is exactly what the gets describe.
  bool finish() const { return ok_ && pos_ == end_; }

 private:
  template <typename T>
  bool get(T& v) {
    if (!ok_ || end_ - pos_ < sizeof v) return ok_ = false;
    std::memcpy(&v, bytes_.data() + pos_, sizeof v);
    pos_ += sizeof v;
    return true;
  }
  const std::vector<char>& bytes_;
  size_t pos_ = 0, end_ = 0;  // end_: where the checksum starts
  bool ok_ = false;
};

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
