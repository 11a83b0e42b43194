// output_file.h — writing a user's output file whole, safely, beside other writers.
//
// Contract: an OutputFile creates a new temporary file next to the output, exclusively
// (".NAME.XXXXXX", O_EXCL: a link or file planted there is never followed or overwritten),
// for the caller to write; commit() renames it into place, so the output is always either
// the old file or the complete new one, and two processes writing one path never write
// into one file. Destroyed uncommitted, it removes the temporary. The rename happens under
// an exclusive lock on the folder, together with the check of claimOutput(): commit()
// returns true when the output was claimed and another process has replaced it since
// (this process's file is the one that stays; the caller says so). Errors throw
// std::runtime_error naming the output.
#pragma once

#include <cstdio>
#include <string>

namespace granular {

// Records what the file at path is now (or that there is none), for commit() to compare.
void claimOutput(const std::string& path);

class OutputFile {
 public:
  explicit OutputFile(const std::string& path);
  ~OutputFile();
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;

  const std::string& path() const { return path_; }
  const std::string& temporaryPath() const { return tmp_; }
  // The temporary, open for writing (owned here; closed by close() or commit()).
  FILE* stream() const { return file_; }
  // Closes the stream, for a writer that reopens the temporary by its name (a name only
  // this process knows).
  void close();
  bool commit();

 private:
  std::string path_, tmp_;
  FILE* file_ = nullptr;
  bool committed_ = false;
};

}  // namespace granular
