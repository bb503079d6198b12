/// @file cmd_codec.cpp
/// @brief `crpgs info`: what a bitstream is made of.
#include <chrono>
#include <cmath>
#include <filesystem>
#include <map>
#include <optional>

#include <ATen/Parallel.h>

#include "cli_common.h"
#include "core/size_text.h"
#include "crpgs/atomic_file.h"
#include "crpgs/codec.h"
#include "crpgs/coding/bitstream.h"
#include "crpgs/experiments/sweep.h"
#include "crpgs/hashing.h"
#include "crpgs/trainer.h"

namespace crpgs::cli {
namespace fs = std::filesystem;

namespace {

void print_link_rate_report(const LinkRateReport& r, uint64_t side_bytes) {
  auto per = [](double bits, int64_t n) { return n > 0 ? bits / double(n) : 0.0; };
  std::printf(
      "\nCOHS (estimated FEAT bits per anchor): roots %.1f, free %.1f, leaves %.1f "
      "(%.1f with the base model's mean)\n",
      per(r.root_bits, r.counts.roots), per(r.free_bits, r.counts.free),
      per(r.leaf_bits, r.counts.leaves), per(r.leaf_bits_base, r.counts.leaves));
  const double saved = (r.leaf_bits_base - r.leaf_bits) / 8.0;
  std::printf(
      "leaf model saves %.0f B of leaf features (%.1f%%); side information costs %llu B: "
      "file %+.0f B\nleaf-root cosine similarity of coded features: %.3f\n",
      saved, r.leaf_bits_base > 0 ? 100.0 * saved * 8.0 / r.leaf_bits_base : 0.0,
      static_cast<unsigned long long>(side_bytes), double(side_bytes) - saved,
      r.mean_leaf_root_cosine);
}

}  // namespace

void print_bitstream_report(const BitstreamReport& r) {
  char scale[48] = "";
  if (r.rate_scale != 1.0) std::snprintf(scale, sizeof scale, ", rate scale %.6g", r.rate_scale);
  std::printf("bitstream: %s, %llu bytes (%.4f MiB) — encode %.2f s, decode %.2f s%s\n",
              r.path.c_str(), static_cast<unsigned long long>(r.file_bytes),
              double(r.file_bytes) / 1048576.0, r.encode_seconds, r.decode_seconds, scale);
  std::vector<std::vector<std::string>> rows = {{"SECTION", "CATEGORY", "BYTES", "%"}};
  char pct[32];
  for (const auto& s : r.sections) {
    std::snprintf(pct, sizeof pct, "%.2f", 100.0 * double(s.bytes) / double(r.file_bytes));
    rows.push_back({s.id, section_category(s.id), std::to_string(s.bytes), pct});
  }
  print_table(rows);
  for (const auto& [id, ec] : r.estimated_vs_coded_bits)
    std::printf("%s: training-time estimate %.0f bits, coded %.0f bits (%+.2f%%)\n", id.c_str(),
                ec.first, ec.second, ec.first > 0 ? 100.0 * (ec.second / ec.first - 1) : 0.0);
  std::printf("test PSNR: quantised model %.3f dB, decoded from the file %.3f dB\n",
              r.quantized_psnr, r.decoded_psnr);
  if (r.links_built >= 0)
    std::printf(
        "links: %lld at the end of training, %lld coded (the others had a masked leaf or root, "
        "or, with rate.prune_links, saved fewer feature bits than the link costs)\n",
        static_cast<long long>(r.links_built), static_cast<long long>(r.links_coded));
  if (r.link_rate) print_link_rate_report(*r.link_rate, r.link_side_bytes);
}

namespace {

int info(const GlobalOptions& g, const std::string& path, bool verbose) {
  auto ct = coding::ContainerReader::read_file(path);
  if (!ct.ok()) return report_error(ct.status());
  const double total = double(ct->file_size);
  // The model's format (what decides how a file decodes) is the version of its HEAD section.
  const coding::Section* head = ct->find("HEAD");
  const std::string format = head ? std::to_string(head->component_major) + "." +
                                        std::to_string(head->component_minor) + ", "
                                  : std::string();
  std::printf(
      "%s: %llu bytes (%.4f MiB), format %scontainer %u.%u, config hash %s, %zu sections\n\n",
      path.c_str(), static_cast<unsigned long long>(ct->file_size), total / 1048576.0,
      format.c_str(), ct->header.major, ct->header.minor, hex64(ct->header.config_hash).c_str(),
      ct->sections.size());
  std::vector<std::vector<std::string>> rows = {
      {"SECTION", "CATEGORY", "COMPONENT", "VERSION", "BYTES", "%"}};
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
  if (const coding::Section* ls = ct->find("LINK")) {
    // COHS side information (docs/method.md §6.4): the link vector (and the paper's active-anchor
    // mask).
    const coding::Section* as = ct->find("AMSK");
    const uint64_t side = ls->file_size + (as ? as->file_size : 0);
    auto links = link_vector_of(*ls);
    if (!links.ok()) return report_error(links.status());
    const auto lc =
        count_links(torch::from_blob(links->data(), {int64_t(links->size())}, torch::kInt).clone());
    if (as)
      std::printf("\nCOHS side information (paper coding): mask %llu B + link vector %llu B",
                  static_cast<unsigned long long>(as->file_size),
                  static_cast<unsigned long long>(ls->file_size));
    else
      std::printf("\nCOHS side information (compact coding): link vector");
    std::printf(" = %llu B (%.2f%% of the file)\nanchors: %lld roots, %lld leaves, %lld free\n",
                static_cast<unsigned long long>(side), 100.0 * double(side) / total,
                static_cast<long long>(lc.roots), static_cast<long long>(lc.leaves),
                static_cast<long long>(lc.free));
  }
  if (verbose) {
    // Decoding checks every section and rebuilds the components from the stored config.
    ComponentRegistry r = load_registry(g);
    auto bytes = read_file_bytes(path);
    if (!bytes.ok()) return report_error(bytes.status());
    auto dec = decode_model(bytes.value(), r);
    if (!dec.ok())
      return report_error(Status(dec.status().code(), path + ": " + dec.status().message()));
    const auto& m = dec->model;
    std::printf(
        "\nDecoded: %lld anchors, %lld offsets per anchor (%lld active), feature width %lld, "
        "voxel %.6g\n",
        static_cast<long long>(m.voxels.size(0)), static_cast<long long>(m.offset_masks.size(1)),
        static_cast<long long>(m.offset_masks.to(torch::kLong).sum().item().toLong()),
        static_cast<long long>(m.feature_sym.size(1)), m.voxel_size);
    // What the training-time rate estimate predicted for each stream against its coded size.
    const auto est = estimated_stream_bits(m, dec->params, *dec->components.entropy);
    for (const auto& s : ct->sections) {
      auto it = est.find(s.id);
      if (it == est.end()) continue;
      const double coded = 8.0 * double(s.payload.size());
      std::printf("%s: estimated %.0f bits, coded %.0f bits (%+.2f%%)\n", s.id.c_str(), it->second,
                  coded, it->second > 0 ? 100.0 * (coded / it->second - 1) : 0.0);
    }
    if (m.links.defined()) {
      auto lr =
          link_rate_report(m, dec->params, *dec->components.context, *dec->components.entropy);
      if (!lr.ok()) return report_error(lr.status());
      print_link_rate_report(lr.value(), ct->find("LINK")->file_size +
                                             (ct->find("AMSK") ? ct->find("AMSK")->file_size : 0));
    }
  }
  return 0;
}

int encode_run(const GlobalOptions& g, const std::string& run_dir, const std::string& out,
               double rate_scale, const std::string& target_size) {
  ComponentRegistry r = load_registry(g);
  if (Status st = check_output_is_not_input(out, run_dir, "scene.crpgs"); !st.ok())
    return report_error(st);
  auto run = open_finished_run(r, run_dir, g.sets);
  if (!run.ok()) return report_error(run.status());
  print_dataset_warnings(run->trainer->dataset());
  Config& cfg = run->config;
  auto& trainer = run->trainer;
  uint64_t target = 0;
  if (!target_size.empty()) {
    auto parsed = parse_byte_size(target_size);
    if (!parsed.ok()) return report_error(parsed.status());
    target = parsed.value();
    auto scale = scale_for_target_size(*trainer, cfg, target);
    if (!scale.ok()) return report_error(scale.status());
    rate_scale = scale.value();
  }
  auto rep = write_and_check_bitstream(*trainer, cfg, r, out, "", rate_scale);
  if (!rep.ok()) return report_error(rep.status());
  print_bitstream_report(rep.value());
  if (target > 0)
    std::printf("target %s: %llu bytes written (%.2f %% under it) at rate scale %.4f\n",
                target_size.c_str(), static_cast<unsigned long long>(rep->file_bytes),
                100.0 * (1.0 - double(rep->file_bytes) / double(target)), rate_scale);
  return 0;
}

/// `crpgs encode RUN --rate-scales 1,2,3`: the finished run's model re-encoded at each scale into
/// RUN/rates/scale-<s>/ (scene.crpgs, metrics.json): a "one model, many rates" curve, which
/// `crpgs report` draws beside the per-λ curves. A scale whose metrics.json exists is kept.
int encode_rates(const GlobalOptions& g, const std::string& run_dir,
                 const std::vector<double>& scales) {
  ComponentRegistry r = load_registry(g);
  auto base = experiments::read_run_metrics(run_dir + "/metrics.json");
  if (!base.ok())
    return report_error(Status(base.status().code(), "--rate-scales re-encodes a finished run: " +
                                                         base.status().message()));
  if (!std::isnan(base->rate_scale))
    return report_error(Status(StatusCode::kInvalidArgument,
                               run_dir + " is itself a re-encoded file, not a training run"));
  std::optional<FinishedRun> run;
  for (double s : scales) {
    const fs::path dir = experiments::rate_scale_dir(run_dir, s);
    if (experiments::read_run_metrics((dir / "metrics.json").string()).ok()) {
      std::printf("rate scale %g: done before (%s), kept\n", s, dir.c_str());
      continue;
    }
    if (!run) {  // loaded once, and only when a scale needs it
      auto opened = open_finished_run(r, run_dir, g.sets);
      if (!opened.ok()) return report_error(opened.status());
      run = std::move(opened).value();
      print_dataset_warnings(run->trainer->dataset());
    }
    Config& cfg = run->config;
    Trainer& trainer = *run->trainer;
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec) return report_error(Status(StatusCode::kIoError, "cannot create " + dir.string()));
    auto rep = write_and_check_bitstream(trainer, cfg, r, (dir / "scene.crpgs").string(), "", s);
    if (!rep.ok()) return report_error(rep.status());
    experiments::RunMetrics m = bitstream_metrics(rep.value(), cfg);
    m.method = base->method + " (one model)";
    m.base_method = base->method;
    m.rate_scale = s;
    m.dataset = base->dataset;
    m.config_hash = base->config_hash;
    m.train_seconds = base->train_seconds;  // the one training all the scales share
    m.peak_memory_bytes = experiments::peak_rss_bytes();
    m.provenance =
        experiments::this_process_provenance(base->provenance.seed, at::get_num_threads(), "cpu");
    if (Status st = experiments::write_run_metrics((dir / "metrics.json").string(), m); !st.ok())
      return report_error(st);
    std::printf("rate scale %g: %llu bytes (%.4f MiB), decoded %.3f dB (quantised %.3f dB): %s\n",
                s, static_cast<unsigned long long>(rep->file_bytes),
                double(rep->file_bytes) / 1048576.0, rep->decoded_psnr, rep->quantized_psnr,
                dir.c_str());
  }
  return 0;
}

}  // namespace

int eval_bitstream_file(const GlobalOptions& g, const std::string& path, const std::string& png_dir,
                        const Lpips* lpips) {
  ComponentRegistry r = load_registry(g);
  // The dataset (and rasterizer) as the config that trained this model set them up.
  auto src = load_model_source(g, r, path, 0);
  if (!src.ok()) return report_error(src.status());
  auto ev = evaluate_views(src->model(), src->setup->rasterizer(), src->setup->dataset().test,
                           png_dir, lpips);
  if (!ev.ok()) return report_error(ev.status());
  if (src->kind == "bitstream")
    std::printf("%s: %llu bytes, %lld anchors, decoded in %.2f s\n", path.c_str(),
                static_cast<unsigned long long>(src->file_bytes),
                static_cast<long long>(src->model().num_anchors()), src->load_seconds);
  else
    std::printf("%s: decode directory, %lld anchors, loaded in %.2f s\n", path.c_str(),
                static_cast<long long>(src->model().num_anchors()), src->load_seconds);
  print_eval(ev.value());
  return 0;
}

void add_codec_commands(CLI::App& app, GlobalOptions& g) {
  static std::string path, run_dir, out, target_size;
  static double rate_scale = 1.0;
  static std::vector<double> rate_scales;
  static bool verbose = false;
  auto* enc = app.add_subcommand("encode",
                                 "Write the bitstream of a trained run (HAC/CRP-GS "
                                 "configs), decode it back and check it");
  enc->add_option("RUN_DIR", run_dir, "directory written by `crpgs train`")->required();
  auto* output = enc->add_option("-o,--output", out, "bitstream file");
  enc->add_option("--set", g.sets,
                  "override a key of the run's config (e.g. dataset.path=DIR when the dataset "
                  "has moved)");
  enc->add_option("--rate-scale", rate_scale,
                  "multiply every quantisation step by this (> 1: a smaller file of coarser "
                  "values from the same trained model; stored in the file, decoding needs nothing "
                  "else)")
      ->check(CLI::PositiveNumber);
  enc->add_option("--target-size", target_size,
                  "the best-quality file at or under this size (e.g. 1.5MiB, 800KB, 2000000; "
                  "KiB/MiB are 2^10/2^20 bytes, KB/MB 10^3/10^6): the rate scale is searched")
      ->excludes("--rate-scale");
  enc->add_option("--rate-scales", rate_scales,
                  "a \"one model, many rates\" curve: re-encode the finished run at each of "
                  "these scales (e.g. 1,1.5,2,3) into RUN_DIR/rates/scale-S/ with its "
                  "metrics.json, which `crpgs report` draws beside the per-λ curves")
      ->delimiter(',')
      ->check(CLI::PositiveNumber)
      ->excludes(output)
      ->excludes("--rate-scale")
      ->excludes("--target-size");
  enc->callback([&g] {
    if (!rate_scales.empty()) throw CLI::RuntimeError(encode_rates(g, run_dir, rate_scales));
    if (out.empty()) throw CLI::RequiredError("-o,--output (or --rate-scales)");
    throw CLI::RuntimeError(encode_run(g, run_dir, out, rate_scale, target_size));
  });

  auto* cmd = app.add_subcommand("info",
                                 "Show what a .crpgs bitstream is made of: every section "
                                 "with its size in bytes and % of the file, by category");
  cmd->add_option("FILE", path, "bitstream")->required();
  cmd->add_flag("-v,--verbose", verbose,
                "also decode it fully (checks every section) and compare "
                "each stream's training-time rate estimate with its coded size");
  cmd->callback([&g] { throw CLI::RuntimeError(info(g, path, verbose)); });
}

}  // namespace crpgs::cli
