#include "output_file.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <stdexcept>

#include "cache.h"
#include "error.h"

namespace granular {

namespace {

std::mutex gMutex;
std::map<std::string, FileVersion>& claims() {
  static std::map<std::string, FileVersion> c;
  return c;
}

std::string absolutePath(const std::string& path) {
  std::error_code ec;
  const std::filesystem::path a = std::filesystem::absolute(path, ec);
  return ec ? path : a.lexically_normal().string();
}

// The process's file-creation mask, read without changing it (umask() is read by setting
// it, which would race with other threads creating files).
mode_t processUmask() {
  static const mode_t mask = [] {
    if (FILE* f = std::fopen("/proc/self/status", "r")) {
      char line[256];
      unsigned m = 022;
      bool found = false;
      while (!found && std::fgets(line, sizeof line, f)) found = std::sscanf(line, "Umask: %o", &m) == 1;
      std::fclose(f);
      if (found) return mode_t(m);
    }
    return mode_t(022);
  }();
  return mask;
}

std::string failure(const std::string& path, const std::string& why) { return "cannot write " + path + ": " + why; }

// flock on the folder itself: no lock file is left behind.
class FolderLock {
 public:
  explicit FolderLock(const std::string& folder) : fd_(open(folder.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC)) {
    if (fd_ >= 0)
      while (flock(fd_, LOCK_EX) != 0 && errno == EINTR) {
      }
  }
  ~FolderLock() {
    if (fd_ >= 0) ::close(fd_);  // releases the lock
  }
  FolderLock(const FolderLock&) = delete;
  FolderLock& operator=(const FolderLock&) = delete;

 private:
  int fd_;
};

std::string folderOf(const std::string& path) {
  const std::filesystem::path p(path);
  return p.has_parent_path() ? p.parent_path().string() : std::string(".");
}

}  // namespace

void claimOutput(const std::string& path) {
  std::lock_guard<std::mutex> guard(gMutex);
  claims()[absolutePath(path)] = fileVersion(path);
}

OutputFile::OutputFile(const std::string& path) : path_(path) {
  const std::filesystem::path p(path);
  tmp_ = (p.has_parent_path() ? (p.parent_path() / "").string() : std::string()) + "." + p.filename().string() +
         ".XXXXXX";
  const int fd = mkostemp(tmp_.data(), O_CLOEXEC);
  if (fd < 0)
    throw std::runtime_error(failure(path, str("cannot create a temporary file in ", folderOf(path), ": ",
                                               std::strerror(errno))));
  fchmod(fd, 0666 & ~processUmask());  // mkostemp makes it 0600; an output is as readable as any new file
  file_ = fdopen(fd, "wb");
  if (!file_) {
    const int err = errno;
    ::close(fd);
    std::remove(tmp_.c_str());
    throw std::runtime_error(failure(path, str("cannot open ", tmp_, ": ", std::strerror(err))));
  }
}

OutputFile::~OutputFile() {
  if (file_) std::fclose(file_);
  if (!committed_) std::remove(tmp_.c_str());
}

void OutputFile::close() {
  if (!file_) return;
  const bool ok = std::fclose(file_) == 0;
  file_ = nullptr;
  if (!ok) throw std::runtime_error(failure(path_, str("cannot finish ", tmp_, ": ", std::strerror(errno))));
}

bool OutputFile::commit() {
  close();
  FolderLock lock(folderOf(path_));
  const std::string key = absolutePath(path_);
  bool replacedOther = false;
  {
    std::lock_guard<std::mutex> guard(gMutex);
    auto it = claims().find(key);
    replacedOther = it != claims().end() && it->second != fileVersion(path_);
  }
  if (std::rename(tmp_.c_str(), path_.c_str()) != 0)
    throw std::runtime_error(failure(path_, str("rename from ", tmp_, " failed: ", std::strerror(errno))));
  committed_ = true;
  std::lock_guard<std::mutex> guard(gMutex);
  auto it = claims().find(key);
  if (it != claims().end()) it->second = fileVersion(path_);  // this process's own file now
  return replacedOther;
}

}  // namespace granular
