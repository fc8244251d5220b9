// The one scratch directory of the tests: a fresh directory under $PBGI_TEST_TMPDIR (else the
// system's temporary directory), named after `name` or, by default, the running GoogleTest test
// and the process, removed with everything in it on destruction.
#ifndef PBGI_TESTS_COMMON_SCRATCH_DIR_H_
#define PBGI_TESTS_COMMON_SCRATCH_DIR_H_

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <string>
#include <system_error>

#include "gtest/gtest.h"

namespace pbgi::testing_common {

class ScratchDir {
 public:
  explicit ScratchDir(std::string name = "") {
    if (name.empty()) {
      const ::testing::TestInfo* info = ::testing::UnitTest::GetInstance()->current_test_info();
      name = info != nullptr ? std::string(info->test_suite_name()) + "_" + info->name() : "test";
    }
    for (char& c : name) {
      if (c == '/') c = '_';
    }
    const char* base = std::getenv("PBGI_TEST_TMPDIR");
    const std::filesystem::path root =
        base != nullptr ? std::filesystem::path(base) : std::filesystem::temp_directory_path();
    path_ = root / (name + "_" + std::to_string(::getpid()));
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  const std::filesystem::path& path() const { return path_; }
  std::string Sub(const std::string& name) const { return (path_ / name).string(); }

 private:
  std::filesystem::path path_;
};

}  // namespace pbgi::testing_common

#endif  // PBGI_TESTS_COMMON_SCRATCH_DIR_H_
