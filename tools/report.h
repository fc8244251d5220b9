// What the commands print about a build, as text and as JSON (nlohmann::json, typed values):
// the one place BuildStats is turned into words and numbers for `pbgi build` and its
// --stats-json, and the float formatting of every command's JSON.
#ifndef PBGI_TOOLS_REPORT_H_
#define PBGI_TOOLS_REPORT_H_

#include <cstdint>
#include <string>

#include "nlohmann/json.hpp"
#include "pbgi/build.h"
#include "pbgi/query.h"

namespace pbgi::tools {

using Json = nlohmann::ordered_json;  // keys in the order they are set

// A float as the JSON number that prints it to 9 significant digits (the float's round trip,
// without double's noise digits); JSON null when it is not finite.
Json JsonFloat(float v);
// Three floats as a JSON array.
Json JsonVec3(const glm::vec3& v);
// Pretty-printed (two-space indent), newline-terminated; bytes that are not UTF-8 are replaced
// rather than thrown on.
std::string DumpJson(const Json& j);

// Every BuildStats field, with the build's settings and derived rates (bytes per point, points
// per second). `input`, `output` and `channels` name what the build read and wrote.
Json BuildStatsJson(const BuildStats& s, const BuildOptions& o, const std::string& input,
                    const std::string& output, const std::string& channels);

// The page cache's figures that `pbgi shade` and `pbgi demo` print for a shaded batch: hit
// rates of both levels, the pages read (with their stored bytes) and, of them, the distinct
// pages (Database::DistinctPagesRead) in all and per receiver. The distinct count is the whole
// database's, the reads only the batch's shading Readers': with radiance, the root page that
// EffectiveCut reads for the mean radiance can make it one more than the reads.
std::string CacheSummary(const CacheStats& cs, uint64_t distinct_pages, uint64_t receivers);

// The build summary table of `pbgi build`.
void PrintBuildStats(const BuildStats& s, const BuildOptions& o, const std::string& input,
                     const std::string& output, const std::string& channels);

}  // namespace pbgi::tools

#endif  // PBGI_TOOLS_REPORT_H_
