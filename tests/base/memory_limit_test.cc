// ReadMemoryLimit over fake cgroup and meminfo files (issue 17: the defaults were OOM-killed
// without a word in a 128 MiB container).
#include "base/memory_limit.h"

#include <cstdlib>
#include <fstream>
#include <string>

#include "gtest/gtest.h"
#include "tests/common/scratch_dir.h"

namespace pbgi::internal {
namespace {

void Write(const std::string& file, const std::string& text) { std::ofstream(file) << text; }

class MemoryLimitTest : public ::testing::Test {
 protected:
  void SetUp() override {
    limit_ = dir_.Sub("memory.max");
    usage_ = dir_.Sub("memory.current");
    meminfo_ = dir_.Sub("meminfo");
    setenv("PBGI_CGROUP_MEMORY_LIMIT_FILE", limit_.c_str(), 1);
    setenv("PBGI_CGROUP_MEMORY_USAGE_FILE", usage_.c_str(), 1);
    setenv("PBGI_MEMINFO_FILE", meminfo_.c_str(), 1);
    Write(meminfo_, "MemTotal:       16000000 kB\nMemFree:  100 kB\nMemAvailable:    8000000 kB\n");
  }
  void TearDown() override {
    unsetenv("PBGI_CGROUP_MEMORY_LIMIT_FILE");
    unsetenv("PBGI_CGROUP_MEMORY_USAGE_FILE");
    unsetenv("PBGI_MEMINFO_FILE");
  }
  testing_common::ScratchDir dir_;
  std::string limit_, usage_, meminfo_;
};

TEST_F(MemoryLimitTest, CgroupV2LimitLessUsage) {
  Write(limit_, "134217728\n");
  Write(usage_, "33554432\n");
  const MemoryLimit m = ReadMemoryLimit();
  EXPECT_EQ(m.cgroup_limit, 134217728u);
  EXPECT_EQ(m.cgroup_usage, 33554432u);
  EXPECT_EQ(m.cgroup_file, limit_);
  EXPECT_EQ(m.available, uint64_t{8000000} * 1024);
  EXPECT_EQ(m.Headroom(), 100663296u);  // 96 MiB: the cgroup binds, not MemAvailable
}

TEST_F(MemoryLimitTest, NoLimitLeavesMemAvailable) {
  for (const char* none : {"max\n", "9223372036854771712\n", ""}) {  // v2, v1, missing
    SCOPED_TRACE(none);
    Write(limit_, none);
    const MemoryLimit m = ReadMemoryLimit();
    EXPECT_EQ(m.cgroup_limit, 0u);
    EXPECT_EQ(m.Headroom(), uint64_t{8000000} * 1024);
  }
}

TEST_F(MemoryLimitTest, MemAvailableBindsBelowALargeLimit) {
  Write(limit_, "68719476736\n");  // 64 GiB
  Write(usage_, "0\n");
  EXPECT_EQ(ReadMemoryLimit().Headroom(), uint64_t{8000000} * 1024);
}

TEST_F(MemoryLimitTest, AFullCgroupLeavesAlmostNothing) {
  Write(limit_, "1000\n");
  Write(usage_, "5000\n");
  EXPECT_EQ(ReadMemoryLimit().Headroom(), 1u);
}

TEST(MemoryLimitRealTest, ThisMachineGivesANumber) {
  // Whatever the machine: MemAvailable is there on Linux, and any limit found is positive.
  const MemoryLimit m = ReadMemoryLimit();
  EXPECT_GT(m.available, 0u);
  EXPECT_GT(m.Headroom(), 0u);
}

}  // namespace
}  // namespace pbgi::internal
