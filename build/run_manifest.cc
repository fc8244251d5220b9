#include "build/run_manifest.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "build/sort_record.h"
#include "pbgi/status.h"

namespace pbgi::internal {
namespace {

constexpr char kMagic[] = "pbgi sort runs 1";

std::string BoundsText(const Bounds& b) {
  // Hexadecimal floats: exact.
  return absl::StrFormat("%a %a %a %a %a %a", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
}

absl::Status SyncPath(const std::string& path, int flags) {
  const int fd = open(path.c_str(), flags | O_CLOEXEC);
  if (fd < 0) return absl::InternalError(absl::StrFormat("open %s: %s", path, strerror(errno)));
  const bool ok = fsync(fd) == 0;
  const int err = errno;
  close(fd);
  if (!ok) return absl::InternalError(absl::StrFormat("fsync %s: %s", path, strerror(err)));
  return absl::OkStatus();
}

}  // namespace

RunManifest ManifestFor(const BuildOptions& o, const Bounds& key_bounds, bool declared_bounds) {
  RunManifest m;
  m.input = o.resumable.input_identity;
  m.record_bytes = CompactSpill(o) ? 8 + PointRecordSize(SpillChannels(o)) : sizeof(SortRecord);
  m.key_bounds = key_bounds;
  m.declared_bounds = declared_bounds;
  m.radiance = HasRadiance(o.channels);
  m.estimate_radius = o.estimate.radius;
  m.estimate_normals = o.estimate.normals;
  m.skip_invalid = o.skip_invalid;
  return m;
}

std::string RunDirectory(const std::string& tmp_dir, const std::string& db_path) {
  const std::string abs = std::filesystem::absolute(db_path).lexically_normal().string();
  uint64_t h = 1469598103934665603ull;  // FNV-1a: stable across runs and builds
  for (unsigned char c : abs) h = (h ^ c) * 1099511628211ull;
  return absl::StrFormat("%s/pbgi-runs-%016x", tmp_dir, h);
}

absl::Status WriteManifest(const std::string& dir, const RunManifest& m) {
  std::string t = absl::StrCat(kMagic, "\n");
  absl::StrAppend(&t, "input ", m.input, "\n");
  absl::StrAppendFormat(&t, "record_bytes %d\n", m.record_bytes);
  absl::StrAppend(&t, "key_bounds ", BoundsText(m.key_bounds), "\n");
  absl::StrAppendFormat(&t, "declared_bounds %d\nradiance %d\nestimate_radius %d\n",
                        m.declared_bounds, m.radiance, m.estimate_radius);
  absl::StrAppendFormat(&t, "estimate_normals %d\nskip_invalid %d\n", m.estimate_normals,
                        m.skip_invalid);
  absl::StrAppendFormat(&t, "back_radiance %d\n", m.back_radiance);
  absl::StrAppendFormat(&t, "records %d\nskipped %d\nknown_count %d\nrun_capacity %d\n", m.records,
                        m.skipped, m.known_count, m.run_capacity);
  absl::StrAppendFormat(&t, "seconds_bounds %.6f\nseconds_sort %.6f\n", m.seconds_bounds,
                        m.seconds_sort);
  for (const KeptRun& r : m.runs) {
    absl::StrAppendFormat(&t, "run %s %d %08x %d\n", r.name, r.records, r.crc, r.bytes);
  }
  t += "end\n";
  const std::string tmp = dir + "/" + kManifestName + ".tmp";
  const std::string path = dir + "/" + kManifestName;
  std::FILE* f = std::fopen(tmp.c_str(), "wb");
  if (f == nullptr) {
    return absl::InternalError(absl::StrFormat("cannot create %s: %s", tmp, strerror(errno)));
  }
  bool ok = std::fwrite(t.data(), 1, t.size(), f) == t.size() && std::fflush(f) == 0 &&
            fsync(fileno(f)) == 0;
  ok = std::fclose(f) == 0 && ok;
  if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = strerror(errno);
    std::remove(tmp.c_str());
    return absl::InternalError(absl::StrFormat("writing %s failed: %s", path, why));
  }
  return SyncPath(dir, O_RDONLY | O_DIRECTORY);
}

absl::StatusOr<RunManifest> ReadManifest(const std::string& dir) {
  const std::string path = dir + "/" + kManifestName;
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::NotFoundError(absl::StrFormat("%s does not exist", path));
  }
  auto bad = [&](const std::string& what) {
    return absl::DataLossError(absl::StrFormat(
        "%s is not a complete manifest (%s): remove %s and build again without --resume", path,
        what, dir));
  };
  std::string line;
  if (!std::getline(in, line) || line != kMagic) return bad("no 'pbgi sort runs 1' line");
  RunManifest m;
  bool ended = false;
  auto flag = [](absl::string_view v, bool* b) {
    if (v != "0" && v != "1") return false;
    *b = v == "1";
    return true;
  };
  while (std::getline(in, line)) {
    if (line == "end") {
      ended = true;
      break;
    }
    const size_t sp = line.find(' ');
    if (sp == std::string::npos) return bad("line '" + line + "'");
    const std::string key = line.substr(0, sp);
    const absl::string_view v = absl::string_view(line).substr(sp + 1);
    bool ok = true;
    if (key == "input") {
      m.input = std::string(v);
    } else if (key == "record_bytes") {
      ok = absl::SimpleAtoi(v, &m.record_bytes);
    } else if (key == "key_bounds") {
      std::vector<std::string> f = absl::StrSplit(v, ' ');
      ok = f.size() == 6;
      float x[6];
      for (size_t i = 0; ok && i < 6; ++i) {
        char* end = nullptr;
        x[i] = std::strtof(f[i].c_str(), &end);
        ok = end != f[i].c_str() && *end == '\0';
      }
      if (ok) {
        m.key_bounds.lo = glm::vec3(x[0], x[1], x[2]);
        m.key_bounds.hi = glm::vec3(x[3], x[4], x[5]);
      }
    } else if (key == "declared_bounds") {
      ok = flag(v, &m.declared_bounds);
    } else if (key == "radiance") {
      ok = flag(v, &m.radiance);
    } else if (key == "estimate_radius") {
      ok = flag(v, &m.estimate_radius);
    } else if (key == "estimate_normals") {
      ok = flag(v, &m.estimate_normals);
    } else if (key == "skip_invalid") {
      ok = flag(v, &m.skip_invalid);
    } else if (key == "back_radiance") {
      ok = flag(v, &m.back_radiance);
    } else if (key == "records") {
      ok = absl::SimpleAtoi(v, &m.records);
    } else if (key == "skipped") {
      ok = absl::SimpleAtoi(v, &m.skipped);
    } else if (key == "known_count") {
      ok = absl::SimpleAtoi(v, &m.known_count);
    } else if (key == "run_capacity") {
      ok = absl::SimpleAtoi(v, &m.run_capacity);
    } else if (key == "seconds_bounds") {
      ok = absl::SimpleAtod(v, &m.seconds_bounds);
    } else if (key == "seconds_sort") {
      ok = absl::SimpleAtod(v, &m.seconds_sort);
    } else if (key == "run") {
      std::vector<std::string> f = absl::StrSplit(v, ' ');
      KeptRun r;
      // Manifests before compact runs have no size: raw runs, records x 48 bytes.
      ok = (f.size() == 3 || f.size() == 4) && f[0].find('/') == std::string::npos &&
           absl::SimpleAtoi(f[1], &r.records) && absl::SimpleHexAtoi(f[2], &r.crc) &&
           (f.size() == 3 || absl::SimpleAtoi(f[3], &r.bytes));
      if (ok && f.size() == 3) r.bytes = r.records * sizeof(SortRecord);
      if (ok) {
        r.name = f[0];
        m.runs.push_back(r);
      }
    } else {
      ok = false;
    }
    if (!ok) return bad("line '" + line + "'");
  }
  if (!ended) return bad("no 'end' line");
  uint64_t sum = 0;
  for (const KeptRun& r : m.runs) sum += r.records;
  if (m.runs.empty() || sum != m.records) return bad("the runs do not add up to its records");
  return m;
}

absl::Status CheckResumable(const RunManifest& kept, const RunManifest& want,
                            const std::string& dir) {
  auto refuse = [&](const std::string& what, const std::string& was, const std::string& is) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "cannot resume from the sort runs kept in %s: %s differs (the runs were made with %s, "
        "this build has %s); build again without --resume (it replaces them)",
        dir, what, was, is));
  };
  auto yn = [](bool b) { return std::string(b ? "yes" : "no"); };
  if (kept.input != want.input) return refuse("the input", kept.input, want.input);
  if (kept.radiance != want.radiance) {
    return refuse("radiance (--channels)", yn(kept.radiance), yn(want.radiance));
  }
  if (kept.estimate_radius != want.estimate_radius) {
    return refuse("estimated radii", yn(kept.estimate_radius), yn(want.estimate_radius));
  }
  if (kept.estimate_normals != want.estimate_normals) {
    return refuse("estimated normals", yn(kept.estimate_normals), yn(want.estimate_normals));
  }
  if (kept.skip_invalid != want.skip_invalid) {
    return refuse("--skip-invalid", yn(kept.skip_invalid), yn(want.skip_invalid));
  }
  // After the options that decide it (channels, estimates), whose names say more.
  if (kept.record_bytes != want.record_bytes) {
    return refuse("the record size", absl::StrCat(kept.record_bytes),
                  absl::StrCat(want.record_bytes));
  }
  if (kept.declared_bounds != want.declared_bounds ||
      (want.declared_bounds && BoundsText(kept.key_bounds) != BoundsText(want.key_bounds))) {
    auto text = [](const RunManifest& m) {
      return m.declared_bounds ? "declared bounds " + BoundsText(m.key_bounds)
                               : std::string("bounds from a bounds pass");
    };
    return refuse("the bounds (--bounds or the header's)", text(kept), text(want));
  }
  return absl::OkStatus();
}

}  // namespace pbgi::internal
