#include "cache.h"

#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <utility>

#include "rng.h"

namespace granular {

namespace {

bool makeDirs(const std::string& path) {
  std::string partial;
  for (size_t i = 0; i <= path.size(); ++i) {
    if (i == path.size() || path[i] == '/') {
      if (!partial.empty() && mkdir(partial.c_str(), 0755) != 0 && errno != EEXIST) return false;
    }
    if (i < path.size()) partial += path[i];
  }
  struct stat st;
  return stat(path.c_str(), &st) == 0 && S_ISDIR(st.st_mode) && access(path.c_str(), W_OK) == 0;
}

}  // namespace

FileVersion fileVersion(const std::string& path) {
  FileVersion v;
  struct stat st;
  if (stat(path.c_str(), &st) != 0) return v;
  v.exists = true;
  v.device = uint64_t(st.st_dev);
  v.inode = uint64_t(st.st_ino);
  v.size = uint64_t(st.st_size);
  v.mtimeNs = int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
  v.ctimeNs = int64_t(st.st_ctim.tv_sec) * 1000000000 + st.st_ctim.tv_nsec;
  return v;
}

std::string cacheDirectory() {
  std::string dir;
  if (const char* d = std::getenv("GRANULAR_CACHE_DIR"); d && *d) {
    dir = d;
  } else if (const char* x = std::getenv("XDG_CACHE_HOME"); x && *x) {
    dir = std::string(x) + "/hdgranular";
  } else if (const char* h = std::getenv("HOME"); h && *h) {
    dir = std::string(h) + "/.cache/hdgranular";
  } else {
    return "";
  }
  return makeDirs(dir) ? dir : "";
}

bool readCacheFile(const std::string& name, std::vector<char>& bytes) {
  std::string dir = cacheDirectory();
  if (dir.empty()) return false;
  std::ifstream in(dir + "/" + name, std::ios::binary);
  if (!in) return false;
  bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  return !in.bad();
}

bool writeCacheFile(const std::string& name, const std::vector<char>& bytes) {
  std::string dir = cacheDirectory();
  if (dir.empty()) return false;
  std::string final = dir + "/" + name;
  std::string tmp = final + ".tmp" + std::to_string(getpid()) + "." + std::to_string(mix64(uint64_t(&bytes)) & 0xffff);
  {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) return false;
    out.write(bytes.data(), std::streamsize(bytes.size()));
    if (!out) { std::remove(tmp.c_str()); return false; }
  }
  if (std::rename(tmp.c_str(), final.c_str()) != 0) { std::remove(tmp.c_str()); return false; }
  return true;
}

uint64_t recordChecksum(const char* data, size_t size) { return hashBytes(mix64(size), data, size); }

RecordWriter::RecordWriter(const RecordMagic& magic, RecordChecksum checksum)
    : bytes_(magic, magic + sizeof magic), checksum_(checksum) {}

std::vector<char> RecordWriter::finish() {
  appendBytes(bytes_, checksum_(bytes_.data(), bytes_.size()));
  return std::move(bytes_);
}

RecordReader::RecordReader(const std::vector<char>& bytes, const RecordMagic& magic, RecordChecksum checksum)
    : bytes_(bytes) {
  constexpr size_t kSum = sizeof(uint64_t);
  if (bytes.size() < sizeof magic + kSum || std::memcmp(bytes.data(), magic, sizeof magic) != 0) return;
  uint64_t sum;
  std::memcpy(&sum, bytes.data() + bytes.size() - kSum, kSum);
  if (sum != checksum(bytes.data(), bytes.size() - kSum)) return;
  pos_ = sizeof magic;
  end_ = bytes.size() - kSum;
  ok_ = true;
}

}  // namespace granular
