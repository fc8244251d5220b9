// `pbgi export DB -o OUT.ply`: the database's surfels back out as a PLY point file, in Morton
// order, streamed through a Reader in batches: memory stays within the cache budget plus one
// batch whatever the database's size.
#include <algorithm>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "base/proc.h"
#include "pbgi/ply.h"
#include "pbgi/query.h"
#include "pbgi/status.h"
#include "tools/args.h"
#include "tools/command.h"
#include "tools/outputs.h"
#include "tools/progress.h"

namespace pbgi::tools {
namespace {

struct Args {
  std::string db;
  std::string out;
  std::string cache = "64M";
  bool ascii = false;
};

// The meta record's provenance goes along, so that a database built from the export keeps
// its scene's fingerprint (pbgi/ply.h, PlyHeader::Provenance()).
bool CarriedOver(const std::string& k) {
  return k.rfind("scene.", 0) == 0 || k.rfind("light.", 0) == 0 || k == "radius" || k == "normals";
}

absl::Status Run(const Args& a) {
  if (!absl::EndsWith(a.out, ".ply")) {
    return absl::InvalidArgumentError(
        absl::StrFormat("-o %s: the output is a PLY point file (-o NAME.ply)", a.out));
  }
  PBGI_RETURN_IF_ERROR(CheckOutputsAreNotInputs({a.db}, {a.out}));
  PBGI_RETURN_IF_ERROR(CheckOutsideStores(a.out));
  PBGI_ASSIGN_OR_RETURN(uint64_t cache, ParseBudget(a.cache, "--cache"));
  DatabaseOptions dbo;
  dbo.cache_bytes = cache;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(a.db, dbo));
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Reader> reader, db->NewReader());
  const StoreMeta& meta = db->meta();
  PlyWriterOptions wo;
  wo.ascii = a.ascii;
  wo.radiance = HasRadiance(meta.channels);
  wo.two_sided = true;  // Surfel::two_sided, so that a rebuild from the file is the same
  for (const auto& [k, v] : meta.stats) {
    if (CarriedOver(k)) wo.comments.push_back(absl::StrFormat("pbgi %s %s", k, v));
  }
  wo.comments.push_back("pbgi source pbgi export " + a.db);
  wo.comments.push_back(std::string("pbgi tool ") + kToolVersion);
  wo.comments.push_back("pbgi date " + NowIso8601());
  const InterruptGuard interrupt;
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PlyWriter> out, PlyWriter::Create(a.out, wo));
  // A batch of point pages' worth at a time: the Reader pins what it reads within its share of
  // the cache, and one batch of surfels is the only other memory.
  constexpr uint64_t kBatch = 1 << 16;
  std::vector<Surfel> batch;
  Progress progress("export", "points", static_cast<int64_t>(meta.point_count));
  for (uint64_t first = 0; first < meta.point_count; first += kBatch) {
    PBGI_RETURN_IF_ERROR(interrupt.Check("pbgi export"));
    batch.clear();
    PBGI_RETURN_IF_ERROR(
        reader->ReadPoints(first, std::min(kBatch, meta.point_count - first), &batch));
    PBGI_RETURN_IF_ERROR(out->Write(batch));
    progress.Update(first + batch.size());
  }
  PBGI_RETURN_IF_ERROR(out->Close());
  progress.Finish(out->count());
  std::printf("%s: %llu surfels from %s (%s), peak memory %s\n", a.out.c_str(),
              static_cast<unsigned long long>(out->count()), a.db.c_str(),
              wo.radiance ? "with radiance" : "occlusion only",
              FormatBytes(internal::PeakRssBytes()).c_str());
  return absl::OkStatus();
}

CommandSetup Setup() {
  return [](CLI::App* app) -> std::function<absl::Status()> {
    auto a = std::make_shared<Args>();
    app->add_option("db", a->db, "Database directory")->required();
    app->add_option("-o,--output", a->out, "Output PLY file")->required();
    app->add_option("--cache", a->cache, "Page cache budget while reading (e.g. 64M)")
        ->check(BudgetValidator())
        ->capture_default_str();
    app->add_flag("--ascii", a->ascii, "Write ASCII PLY instead of binary");
    return [a]() { return Run(*a); };
  };
}

}  // namespace
PBGI_REGISTER_COMMAND(export, "export", "Write a database's surfels back out to a PLY point file",
                      Setup());
}  // namespace pbgi::tools
