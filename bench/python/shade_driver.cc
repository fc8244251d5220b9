// The C++ side of bench/python/shade_overhead.py: ShadeBatch called directly, with the options
// that pbgi.Database.shade() passes by default, on receivers read from a raw float32 file
// (n x 6: position, normal). Prints one line per timed run, "seconds cpu_seconds checksum"
// (wall time, and the process's user + system time, which a loaded machine disturbs less), after
// one warm-up run; the checksum (sum of occlusion and irradiance) shows both sides did the same
// work. With RUNS = 0 it runs once per line read from stdin (after the warm-up, which prints
// "ready"), so that the script can alternate single runs of both sides.
//   pbgi_shade_driver DB RECEIVERS.f32 RUNS THREADS occlusion|irradiance
#include <sys/resource.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "base/stopwatch.h"
#include "pbgi/shade.h"

int main(int argc, char** argv) {
  if (argc != 6) {
    std::fprintf(stderr, "usage: %s DB RECEIVERS.f32 RUNS THREADS occlusion|irradiance\n", argv[0]);
    return 2;
  }
  const std::string mode = argv[5];
  std::ifstream in(argv[2], std::ios::binary | std::ios::ate);
  if (!in) {
    std::fprintf(stderr, "cannot read %s\n", argv[2]);
    return 1;
  }
  std::vector<float> raw(static_cast<size_t>(in.tellg()) / sizeof(float));
  in.seekg(0);
  in.read(reinterpret_cast<char*>(raw.data()), static_cast<std::streamsize>(raw.size() * 4));
  std::vector<pbgi::ShadeReceiver> receivers(raw.size() / 6);
  for (size_t i = 0; i < receivers.size(); ++i) {
    const float* r = &raw[6 * i];
    receivers[i].position = glm::vec3(r[0], r[1], r[2]);
    receivers[i].normal = glm::vec3(r[3], r[4], r[5]);
    receivers[i].reflection = receivers[i].normal;
  }
  auto db = pbgi::Database::Open(argv[1]);
  if (!db.ok()) {
    std::fprintf(stderr, "%s\n", db.status().ToString().c_str());
    return 1;
  }
  pbgi::ShadeOptions o;  // what pbgi.Database.shade() passes by default (python/pbgi/__init__.py)
  o.threads = std::atoi(argv[4]);
  o.cut.cosine_weighted = true;
  o.raster.compute_radiance = mode != "occlusion";
  std::vector<pbgi::ShadeResult> out(receivers.size());
  auto cpu_seconds = [] {
    rusage u;
    getrusage(RUSAGE_SELF, &u);
    return double(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
           1e-6 * double(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
  };
  auto run_once = [&](bool print) -> bool {
    const double cpu = cpu_seconds();
    const pbgi::internal::Stopwatch clock;
    absl::Status s = pbgi::ShadeBatch(**db, receivers, o, absl::MakeSpan(out));
    const double seconds = clock.Seconds();
    const double cpu_used = cpu_seconds() - cpu;
    if (!s.ok()) {
      std::fprintf(stderr, "%s\n", s.ToString().c_str());
      return false;
    }
    double sum = 0;
    for (const pbgi::ShadeResult& r : out) sum += r.occlusion + r.irradiance.x;
    if (print) std::printf("%.6f %.6f %.6f\n", seconds, cpu_used, sum);
    std::fflush(stdout);
    return true;
  };
  if (!run_once(false)) return 1;  // warm-up: the cache
  const int runs = std::atoi(argv[3]);
  if (runs > 0) {
    for (int run = 0; run < runs; ++run) {
      if (!run_once(true)) return 1;
    }
    return 0;
  }
  std::printf("ready\n");
  std::fflush(stdout);
  for (std::string line; std::getline(std::cin, line);) {
    if (!run_once(true)) return 1;
  }
  return 0;
}
