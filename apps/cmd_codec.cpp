/// @file cmd_codec.cpp
/// @brief `crpgs info`: what a bitstream is made of.
#include <filesystem>
#include <map>

#include "cli_common.h"
#include "crpgs/atomic_file.h"
#include "crpgs/codec.h"
#include "crpgs/coding/bitstream.h"

namespace crpgs::cli {
namespace {

int info(const GlobalOptions& g, const std::string& path, bool verbose) {
  auto ct = coding::ContainerReader::read_file(path);
  if (!ct.ok()) return report_error(ct.status());
  const double total = double(ct->file_size);
  std::printf("%s: %llu bytes (%.4f MiB), container %u.%u, config hash %016llx, %zu sections\n\n",
              path.c_str(), static_cast<unsigned long long>(ct->file_size), total / 1048576.0,
              ct->header.major, ct->header.minor,
              static_cast<unsigned long long>(ct->header.config_hash), ct->sections.size());
  std::vector<std::vector<std::string>> rows = {{"SECTION", "CATEGORY", "COMPONENT", "VERSION", "BYTES", "%"}};
  std::map<std::string, uint64_t> by_category;
  char pct[32];
  for (const auto& s : ct->sections) {
    std::snprintf(pct, sizeof pct, "%.2f", 100.0 * double(s.file_size) / total);
    rows.push_back({s.id, section_category(s.id), s.component_id,
                    std::to_string(s.component_major) + "." + std::to_string(s.component_minor),
                    std::to_string(s.file_size), pct});
    by_category[section_category(s.id)] += s.file_size;
  }
  print_table(rows);
  std::printf("\nBy category:\n");
  std::vector<std::vector<std::string>> cats = {{"CATEGORY", "BYTES", "%"}};
  for (const auto& [c, b] : by_category) {
    std::snprintf(pct, sizeof pct, "%.2f", 100.0 * double(b) / total);
    cats.push_back({c, std::to_string(b), pct});
  }
  print_table(cats);
  if (verbose) {
    // Decoding checks every section and rebuilds the components from the stored config.
    ComponentRegistry r = load_registry(g);
    auto bytes = read_file_bytes(path);
    if (!bytes.ok()) return report_error(bytes.status());
    auto dec = decode_model(bytes.value(), r);
    if (!dec.ok()) return report_error(dec.status());
    const auto& m = dec->model;
    std::printf("\nDecoded: %lld anchors, %lld offsets per anchor (%lld active), feature width %lld, "
                "voxel %.6g\n",
                static_cast<long long>(m.voxels.size(0)), static_cast<long long>(m.offset_masks.size(1)),
                static_cast<long long>(m.offset_masks.to(torch::kLong).sum().item().toLong()),
                static_cast<long long>(m.feature_sym.size(1)), m.voxel_size);
  }
  return 0;
}

}  // namespace

void add_codec_commands(CLI::App& app, GlobalOptions& g) {
  static std::string path;
  static bool verbose = false;
  auto* cmd = app.add_subcommand("info", "Show what a .crpgs bitstream is made of: every section "
                                         "with its size in bytes and % of the file, by category");
  cmd->add_option("FILE", path, "bitstream")->required();
  cmd->add_flag("-v,--verbose", verbose, "also decode it fully (checks every section)");
  cmd->callback([&g] { throw CLI::RuntimeError(info(g, path, verbose)); });
}

}  // namespace crpgs::cli
