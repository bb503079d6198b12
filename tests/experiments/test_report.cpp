// `crpgs report` from fixture metrics: tables, BD rows, plots and the self-contained HTML page.
#include <gtest/gtest.h>

#include <cmath>
#include <regex>

#include "crpgs/experiments/report.h"
#include "crpgs/experiments/run_metrics.h"
#include "experiments/exp_test_util.h"

namespace crpgs::experiments {
namespace {
namespace fs = std::filesystem;
using test::fresh_dir;
using test::read_text;
using test::write_text;

/// A fixture runs directory: on "fern", "hac" and "crpgs" (crpgs at 70% of hac's size for the
/// same PSNR) with 4 points each, plus "far" whose PSNR range overlaps neither; one unfinished
/// run.
std::string make_fixture(const std::string& name) {
  const std::string runs = fresh_dir(name) + "/runs";
  const double lambdas[4] = {4e-3, 2e-3, 1e-3, 5e-4};
  int index = 0;
  for (const std::string method : {"hac", "crpgs", "far"})
    for (int i = 0; i < 4; ++i) {
      RunMetrics m;
      m.method = method;
      m.dataset = "fern";
      m.lambda = lambdas[i];
      const double hac_size = 5e6 * std::pow(1.6, i);
      m.size_bytes = static_cast<uint64_t>(method == "crpgs" ? 0.7 * hac_size
                                           : method == "far" ? 100 * hac_size
                                                             : hac_size);
      const double psnr = (method == "far" ? 40.0 : 24.0) + 0.6 * i + 0.05 * i * i;
      m.views = {{"v0", psnr - 0.1, 0.80, 0.020}, {"v8", psnr + 0.1, 0.82, 0.024}};
      m.train_seconds = 600 + 100 * i;
      m.provenance.version = "0.test";
      m.provenance.device = method == "hac" && i == 3 ? "cuda" : "cpu";  // a GPU machine's run
      m.encode_seconds = 2 + 0.5 * i;
      m.decode_seconds = 1 + 0.25 * i;
      for (int t = 1; t <= 10; ++t)
        m.trace.push_back({m.train_seconds * t / 10, 3000 * t, psnr - 8.0 / t});
      m.trace_views = {"v0", "v8"};
      m.peak_memory_bytes = int64_t(2) << 30;
      const uint64_t s = m.size_bytes;
      m.breakdown = {s / 10, s / 3,  s / 12, s / 8, s / 40, method == "crpgs" ? s / 50 : 0,
                     s / 9,  s / 30, 0};
      uint64_t sum = 0;
      for (auto v : m.breakdown) sum += v;
      m.breakdown[8] = s - sum;
      const std::string dir = runs + "/fern/" + method + "/lambda-" + std::to_string(i);
      fs::create_directories(dir);
      EXPECT_TRUE(write_run_metrics(dir + "/metrics.json", m).ok());
      write_text(dir + "/run.json",
                 "{\"id\": \"fern/" + method + "/lambda-" + std::to_string(i) +
                     "\", \"index\": " + std::to_string(index++) + ", \"method\": \"" + method +
                     "\", \"dataset\": \"fern\", \"rate\": " + std::to_string(lambdas[i]) + "}\n");
    }
  fs::create_directories(runs + "/fern/crpgs/unfinished");
  write_text(runs + "/fern/crpgs/unfinished/run.json", "{\"id\": \"fern/crpgs/unfinished\"}\n");
  write_text(runs + "/fern/crpgs/unfinished/.running", "started\n");
  return runs;
}

TEST(Report, CollectsFinishedRunsInSweepOrder) {
  const std::string runs = make_fixture("collect");
  auto c = collect_runs({runs});
  ASSERT_TRUE(c.ok()) << c.status().message();
  ASSERT_EQ(c->runs.size(), 12u);
  EXPECT_EQ(c->runs[0].method, "hac");
  EXPECT_EQ(c->runs[4].method, "crpgs");
  EXPECT_DOUBLE_EQ(c->runs[1].rate, 2e-3);
  ASSERT_EQ(c->unfinished.size(), 1u);
  EXPECT_EQ(c->unfinished[0], "fern/crpgs/unfinished");
  EXPECT_FALSE(collect_runs({runs + "/nope"}).ok());
}

TEST(Report, TablesHaveRdPointsAndBdRows) {
  const std::string runs = make_fixture("tables");
  ReportOptions opt;
  opt.plots = false;
  auto out = write_report({runs}, opt);
  ASSERT_TRUE(out.ok()) << out.status().message();
  EXPECT_EQ(out->markdown, runs + "/report/report.md");
  const std::string md = read_text(out->markdown);
  EXPECT_NE(md.find("12 finished runs, 1 unfinished (fern/crpgs/unfinished)"), std::string::npos)
      << md;
  EXPECT_NE(md.find("## fern"), std::string::npos);
  // crpgs is the same curve at 0.7x the size: BD-rate exactly -30%.
  EXPECT_NE(md.find("| hac | crpgs | -30.00 |"), std::string::npos) << md;
  // Each row names the fronts it compared; "far" sits 16 dB above the others, so "—".
  EXPECT_NE(md.find("| 4 points, 24.000–26.250 dB | 4 points, 40.000–42.250 dB |"),
            std::string::npos)
      << md;
  // "far" never overlaps: no result either way.
  EXPECT_NE(md.find("| hac | far | — | — | — | — |"), std::string::npos) << md;
  EXPECT_NE(md.find("| crpgs | far | — | — | — | — |"), std::string::npos) << md;
  // The BD row says what it integrates: the common PSNR interval (BD-rate) and size interval
  // (BD-PSNR, in MiB: hac spans 5e6..20.48e6 B, crpgs 0.7x that).
  EXPECT_NE(md.find("| hac | crpgs | -30.00 | 24.000–26.250 | "), std::string::npos) << md;
  EXPECT_NE(md.find(" | 4.7684–13.6719 | 4 points,"), std::string::npos) << md;
  // One RD row per run, with λ and size in bytes and MiB (2^20 bytes, the field's "MB").
  EXPECT_NE(md.find("| hac | 0.004 | 5000000 | 4.7684 |"), std::string::npos) << md;
  EXPECT_EQ(std::count(md.begin(), md.end(), '\n') > 20, true);
  // hac from 5e6 B / 24.00 dB to 8e6 B / 24.65 dB, train 600 -> 700 s: per +0.1 dB 450.7 KiB,
  // 15.4 s.
  EXPECT_NE(md.find("| hac | 0.004 | 0.002 | +0.650 | +450.7 | +15.4 |"), std::string::npos) << md;
  // A run trained on a GPU says so, and its time is not set against a CPU run's.
  EXPECT_NE(md.find("| 900.0 (cuda) |"), std::string::npos) << md;
  EXPECT_NE(md.find("| 800.0 |"), std::string::npos) << md;
  EXPECT_NE(md.find("| hac | 0.001 | 0.0005 | +0.850 | +882.4 | — (cpu vs cuda) |"),
            std::string::npos)
      << md;
  // Ablation view at equal λ: crpgs is 30% smaller than hac at the same PSNR; "far" is 100x.
  EXPECT_NE(md.find("| crpgs | 0.004 | 3.3379 | -30.00 | 24.000 | +0.000 |"), std::string::npos)
      << md;
  EXPECT_NE(md.find("| far | 0.002 | 762.9395 | +9900.00 | 40.650 | +16.000 |"), std::string::npos)
      << md;
  EXPECT_EQ(md.find("![rd_"), std::string::npos);  // no plots asked for
  const std::string html = read_text(out->html);
  EXPECT_NE(html.find("<td>-30.00</td>"), std::string::npos);
}

TEST(Report, ABdRowWithoutResultShowsTheShortFront) {
  const std::string runs = make_fixture("short_front");
  for (int i = 1; i < 4; ++i) fs::remove_all(runs + "/fern/hac/lambda-" + std::to_string(i));
  ReportOptions opt;
  opt.plots = false;
  auto out = write_report({runs}, opt);
  ASSERT_TRUE(out.ok()) << out.status().message();
  const std::string md = read_text(out->markdown);
  EXPECT_NE(md.find("| hac | crpgs | — | — | — | — | 1 point, 24.000 dB | 4 points, 24.000–26.250 "
                    "dB |"),
            std::string::npos)
      << md;
}

// Several scenes: the summary table (the paper's layout) with each scene's BD figures against
// its first method and their mean, and one CSV per scene in the compression survey's layout.
TEST(Report, SummaryOverScenesAndSurveyCsvPerScene) {
  const std::string runs = make_fixture("summary");
  // flower: the same runs, crpgs at 0.8x hac's size instead of 0.7x, and Gaussian counts.
  for (const std::string method : {"hac", "crpgs"})
    for (int i = 0; i < 4; ++i) {
      const std::string from = runs + "/fern/" + method + "/lambda-" + std::to_string(i);
      const std::string to = runs + "/flower/" + method + "/lambda-" + std::to_string(i);
      auto m = read_run_metrics(from + "/metrics.json");
      ASSERT_TRUE(m.ok());
      m->dataset = "flower";
      if (method == "crpgs") m->size_bytes = uint64_t(double(m->size_bytes) / 0.7 * 0.8);
      m->anchors = 1000 + i;
      m->gaussians = 9000 + i;
      fs::create_directories(to);
      ASSERT_TRUE(write_run_metrics(to + "/metrics.json", *m).ok());
      std::string info = read_text(from + "/run.json");
      info = std::regex_replace(info, std::regex("fern"), "flower");
      write_text(to + "/run.json", info);
    }
  ReportOptions opt;
  opt.plots = false;
  auto out = write_report({runs}, opt);
  ASSERT_TRUE(out.ok()) << out.status().message();
  const std::string md = read_text(out->markdown);
  const size_t summary = md.find("## Summary over scenes");
  ASSERT_NE(summary, std::string::npos) << md;
  EXPECT_LT(summary, md.find("## fern"));  // first, before the scenes' sections
  // fern's crpgs is hac's curve at 0.7x the size, flower's at 0.8x: -30 % and -20 %; their
  // low-rate points are 3.5e6 and 4e6 bytes at 24.000 dB, the high-rate ones 14.336e6 and
  // 16.384e6 bytes at 26.250 dB.
  EXPECT_NE(
      md.find("| fern | hac | 4.7684 | 24.000 | 0.8100 | 19.5312 | 26.250 | 0.8100 | anchor |"),
      std::string::npos)
      << md;
  EXPECT_NE(md.find("| fern | crpgs | 3.3379 | 24.000 | 0.8100 | 13.6719 | 26.250 | 0.8100 | "
                    "-30.00 | "),
            std::string::npos)
      << md;
  EXPECT_NE(md.find("| flower | crpgs | 3.8147 | 24.000 | 0.8100 | 15.6250 | 26.250 | 0.8100 | "
                    "-20.00 | "),
            std::string::npos)
      << md;
  EXPECT_NE(md.find("| 4/4 points, 24.000–26.250 dB |"), std::string::npos) << md;
  // "far" is on fern only and overlaps nothing: no figure, and its mean covers no scene.
  EXPECT_NE(md.find("| mean | crpgs |  |  |  |  |  |  | -25.00 | "), std::string::npos) << md;
  EXPECT_NE(md.find("| mean | far |  |  |  |  |  |  | — | — | 0 scenes |"), std::string::npos)
      << md;

  ASSERT_EQ(out->csvs.size(), 2u);
  EXPECT_EQ(out->csvs[0], runs + "/report/scene_fern.csv");
  const std::string fern = read_text(out->csvs[0]);
  const std::string flower = read_text(out->csvs[1]);
  EXPECT_EQ(fern.substr(0, fern.find('\n')), "Submethod,PSNR,SSIM,LPIPS,Size [Bytes],#Gaussians");
  EXPECT_EQ(std::count(fern.begin(), fern.end(), '\n'), 13);  // header + 12 runs
  // LPIPS not computed: empty; #Gaussians empty where the run did not record it.
  EXPECT_NE(fern.find("\ncrpgs lambda=0.004,24.000,0.8100,,3500000,\n"), std::string::npos) << fern;
  EXPECT_NE(flower.find("\ncrpgs lambda=0.004,24.000,0.8100,,4000000,9000\n"), std::string::npos)
      << flower;
  EXPECT_NE(md.find("[scene_flower.csv](scene_flower.csv)"), std::string::npos);
}

// A one-model curve (files re-encoded from crpgs's λ 1e-3 run at scaled steps, in its rates/):
// its own method after the sweep's, BD against crpgs (its training method, not the scene's
// first), points labelled by their scale, and left out of the same-λ table.
TEST(Report, AOneModelCurveIsComparedWithItsOwnMethod) {
  const std::string runs = make_fixture("one_model");
  const std::string base = runs + "/fern/crpgs/lambda-2";  // λ 1e-3
  auto trained = read_run_metrics(base + "/metrics.json");
  ASSERT_TRUE(trained.ok());
  for (double scale : {1.0, 2.0, 4.0}) {
    RunMetrics m = trained.value();
    m.method = "crpgs (one model)";
    m.base_method = "crpgs";
    m.rate_scale = scale;
    // 1.5x smaller and 1 dB lower per doubling of the scale: worse than training per λ,
    // whose curve loses 0.6-0.7 dB per 1.6x.
    m.size_bytes = uint64_t(double(trained->size_bytes) / std::pow(1.5, std::log2(scale)));
    for (auto& v : m.views) v.psnr -= std::log2(scale);
    m.psnr_mean = NAN;
    const std::string dir = base + "/rates/scale-" + std::to_string(int(scale));
    fs::create_directories(dir);
    ASSERT_TRUE(write_run_metrics(dir + "/metrics.json", m).ok());
  }
  auto collected = collect_runs({runs});
  ASSERT_TRUE(collected.ok());
  EXPECT_EQ(collected->runs.front().method, "hac");  // still the first method: the BD anchor
  EXPECT_EQ(collected->runs.back().method, "crpgs (one model)");
  ReportOptions opt;
  opt.plots = false;
  auto out = write_report({runs}, opt);
  ASSERT_TRUE(out.ok()) << out.status().message();
  const std::string md = read_text(out->markdown);
  EXPECT_NE(md.find("| crpgs (one model) | 0.001 ×2 |"), std::string::npos) << md;
  EXPECT_NE(md.find("| crpgs | crpgs (one model) | +"), std::string::npos) << md;  // costs size
  const size_t summary = md.find("## Summary over scenes");
  const size_t row = md.find("| fern | crpgs (one model) |", summary);
  ASSERT_NE(row, std::string::npos) << md;
  const std::string line = md.substr(row, md.find('\n', row) - row);
  EXPECT_NE(line.find(" | +"), std::string::npos) << line;  // larger than crpgs's curve
  EXPECT_NE(line.find("(against crpgs)"), std::string::npos) << line;
  const size_t same = md.find("### Against hac at the same λ");
  ASSERT_NE(same, std::string::npos) << md;
  EXPECT_EQ(md.substr(same, md.find("###", same + 4) - same).find("one model"), std::string::npos)
      << md;
}

// Runs from several directories (sweeps): the first directory's methods come first, whatever
// their runs' indices in their own sweeps, so its first method anchors the BD figures.
TEST(Report, TheFirstDirectorysMethodsComeFirst) {
  const std::string runs = make_fixture("order");
  const std::string other = fresh_dir("order_other") + "/runs";
  auto m = read_run_metrics(runs + "/fern/hac/lambda-0/metrics.json");
  ASSERT_TRUE(m.ok());
  m->method = "ablation";
  fs::create_directories(other + "/fern/ablation/lambda-0");
  ASSERT_TRUE(write_run_metrics(other + "/fern/ablation/lambda-0/metrics.json", *m).ok());
  write_text(other + "/fern/ablation/lambda-0/run.json",
             "{\"id\": \"fern/ablation/lambda-0\", \"index\": 0, \"method\": \"ablation\", "
             "\"dataset\": \"fern\", \"rate\": 0.004}\n");
  auto c = collect_runs({runs, other});
  ASSERT_TRUE(c.ok()) << c.status().message();
  ASSERT_EQ(c->runs.size(), 13u);
  EXPECT_EQ(c->runs.front().method, "hac");
  EXPECT_EQ(c->runs.back().method, "ablation");
  auto reversed = collect_runs({other, runs});
  ASSERT_TRUE(reversed.ok());
  EXPECT_EQ(reversed->runs.front().method, "ablation");
}

bool is_png(const std::string& bytes) {
  return bytes.rfind("\x89PNG\r\n\x1a\n", 0) == 0;
}

TEST(Report, RendersAllPlotsAndEmbedsThemInTheHtml) {
  if (!gnuplot_available()) GTEST_SKIP() << "gnuplot not installed (Debian: gnuplot-nox)";
  const std::string runs = make_fixture("plots");
  ReportOptions opt;
  opt.out_dir = fresh_dir("plots_out");
  auto out = write_report({runs}, opt);
  ASSERT_TRUE(out.ok()) << out.status().message();
  std::set<std::string> names;
  for (const auto& p : out->pngs) names.insert(fs::path(p).filename().string());
  const std::set<std::string> expected = {"rd_fern.png",
                                          "time_fern.png",
                                          "cost_fern.png",
                                          "breakdown_fern_hac.png",
                                          "breakdown_fern_crpgs.png",
                                          "breakdown_fern_far.png"};
  EXPECT_EQ(names, expected);
  const std::string html = read_text(out->html);
  const std::string md = read_text(out->markdown);
  for (const auto& p : out->pngs) {
    const std::string bytes = read_text(p);
    EXPECT_TRUE(is_png(bytes)) << p;
    EXPECT_GT(bytes.size(), 8000u) << p << " looks empty";
    // Embedded verbatim as a data URI, and linked from the Markdown.
    EXPECT_NE(html.find("data:image/png;base64," + base64_encode(bytes) + "\""), std::string::npos)
        << p;
    EXPECT_NE(md.find("](" + fs::path(p).filename().string() + ")"), std::string::npos);
  }
  EXPECT_EQ(html.find("src=\"rd_"), std::string::npos) << "the page must not link files";
  // No temporary files left next to the outputs.
  for (const auto& e : fs::directory_iterator(opt.out_dir))
    EXPECT_TRUE(e.path().extension() == ".png" || e.path().extension() == ".md" ||
                e.path().extension() == ".html" || e.path().extension() == ".csv" ||
                e.path().filename() == "runs")
        << e.path();
}

// The report's records rebuild the same report; a later directory's run replaces an earlier
// one with the same id, an unfinished one included; a report's own output is never an input.
TEST(Report, RecordsRebuildTheReportAndNewerRunsReplaceOlderOnes) {
  const std::string runs = make_fixture("records");
  ReportOptions opt;
  opt.plots = false;
  auto first = write_report({runs}, opt);  // into runs/report, inside the runs directory
  ASSERT_TRUE(first.ok()) << first.status().message();
  EXPECT_EQ(first->records, runs + "/report/runs");
  EXPECT_TRUE(fs::exists(runs + "/report/runs/fern/crpgs/lambda-2/metrics.json"));
  EXPECT_TRUE(fs::exists(runs + "/report/runs/fern/crpgs/lambda-2/run.json"));
  EXPECT_FALSE(fs::exists(runs + "/report/runs/fern/crpgs/unfinished"));
  auto again = collect_runs({runs}, runs + "/report");
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->runs.size(), 12u);  // not 24: the records under runs/report are skipped
  auto other = collect_runs({runs});   // read for another output: still not taken for runs
  ASSERT_TRUE(other.ok());
  EXPECT_EQ(other->runs.size(), 12u);
  for (const auto& r : other->runs) EXPECT_EQ(r.dir.find("/report/"), std::string::npos) << r.dir;

  ReportOptions rebuilt_opt = opt;
  rebuilt_opt.out_dir = fresh_dir("records_rebuilt");
  auto rebuilt = write_report({first->records}, rebuilt_opt);
  ASSERT_TRUE(rebuilt.ok()) << rebuilt.status().message();
  auto tables = [](const std::string& md) { return md.substr(md.find("## fern")); };
  EXPECT_EQ(tables(read_text(rebuilt->markdown)), tables(read_text(first->markdown)));

  // A newer copy of one run (smaller file) and the unfinished run, now finished.
  const std::string newer = fresh_dir("records_newer");
  auto m = read_run_metrics(runs + "/fern/crpgs/lambda-2/metrics.json");
  ASSERT_TRUE(m.ok());
  m->size_bytes /= 2;
  fs::create_directories(newer + "/a");
  ASSERT_TRUE(write_run_metrics(newer + "/a/metrics.json", *m).ok());
  fs::copy_file(runs + "/fern/crpgs/lambda-2/run.json", newer + "/a/run.json");
  fs::create_directories(newer + "/b");
  ASSERT_TRUE(write_run_metrics(newer + "/b/metrics.json", *m).ok());
  write_text(newer + "/b/run.json", "{\"id\": \"fern/crpgs/unfinished\", \"method\": \"crpgs\"}\n");
  auto merged = collect_runs({first->records, runs + "/fern/crpgs/unfinished", newer});
  ASSERT_TRUE(merged.ok()) << merged.status().message();
  EXPECT_EQ(merged->runs.size(), 13u);
  EXPECT_TRUE(merged->unfinished.empty());
  const auto it = std::find_if(merged->runs.begin(), merged->runs.end(),
                               [](const ReportRun& r) { return r.id == "fern/crpgs/lambda-2"; });
  ASSERT_NE(it, merged->runs.end());
  EXPECT_EQ(it->metrics.size_bytes, m->size_bytes);
  EXPECT_EQ(std::count_if(merged->runs.begin(), merged->runs.end(),
                          [](const ReportRun& r) { return r.id == "fern/crpgs/lambda-2"; }),
            1);

  // An unfinished rerun of a recorded run does not displace its record.
  const std::string rerun = fresh_dir("records_rerun");
  fs::copy_file(runs + "/fern/crpgs/lambda-2/run.json", rerun + "/run.json");
  write_text(rerun + "/.running", "");
  auto kept = collect_runs({first->records, rerun});
  ASSERT_TRUE(kept.ok()) << kept.status().message();
  EXPECT_EQ(kept->runs.size(), 12u);
  EXPECT_TRUE(kept->unfinished.empty());

  // A report killed between swapping its records in left them in runs.old: the next one that
  // reads OUT/runs finds them.
  fs::rename(first->records, first->records + ".old");
  ReportOptions same_out = opt;
  same_out.out_dir = runs + "/report";
  auto resumed = write_report({first->records}, same_out);
  ASSERT_TRUE(resumed.ok()) << resumed.status().message();
  EXPECT_EQ(tables(read_text(resumed->markdown)), tables(read_text(first->markdown)));
}

/// Two runs of `method` on `dataset`; `coded`: with a bitstream and codec times, else as a
/// config without the rate path writes them (size 0, no encode/decode times).
void add_runs(const std::string& runs, const std::string& dataset, bool coded, int* index,
              const std::string& method = "base") {
  for (int i = 0; i < 2; ++i) {
    RunMetrics m;
    m.method = method;
    m.dataset = dataset;
    m.lambda = coded ? 1e-3 * (i + 1) : NAN;
    m.size_bytes = coded ? uint64_t(3e6 / (i + 1)) : 0;
    m.views = {{"v0", 25.0 - i, 0.8, 0.02}};
    m.train_seconds = 100;
    m.render_seconds_per_view = 0.02;
    if (coded) {
      m.encode_seconds = 1;
      m.decode_seconds = 0.5;
      m.breakdown[0] = m.size_bytes;
    }
    m.trace = {{10, 100, 20.0}, {100, 1000, 25.0 - i}};
    const std::string dir = runs + "/" + std::to_string(*index);
    fs::create_directories(dir);
    EXPECT_TRUE(write_run_metrics(dir + "/metrics.json", m).ok());
    write_text(dir + "/run.json",
               "{\"id\": \"" + std::to_string(*index) + "\", \"index\": " + std::to_string(*index) +
                   ", \"method\": \"" + method + "\", \"dataset\": \"" + dataset + "\"}\n");
    ++*index;
  }
}

TEST(Report, RunsWithoutBitstreamsAndLookAlikeNamesGetTheirOwnPlots) {
  if (!gnuplot_available()) GTEST_SKIP() << "gnuplot not installed (Debian: gnuplot-nox)";
  // "a b" has no bitstreams (a config without the rate path): no RD plot, a cost plot of the
  // render time only. "a_b" maps to the same file-name part and must not overwrite it.
  const std::string runs = fresh_dir("uncoded") + "/runs";
  int index = 0;
  add_runs(runs, "a b", false, &index);
  add_runs(runs, "a_b", true, &index);
  // Dataset and method names that join to the same breakdown name.
  add_runs(runs, "n", true, &index, "x_y");
  add_runs(runs, "n_x", true, &index, "y");
  ReportOptions opt;
  opt.out_dir = fresh_dir("uncoded_out");
  auto out = write_report({runs}, opt);
  ASSERT_TRUE(out.ok()) << out.status().message();
  std::set<std::string> names;
  for (const auto& p : out->pngs) {
    names.insert(fs::path(p).filename().string());
    EXPECT_GT(read_text(p).size(), 8000u) << p << " looks empty";
  }
  const std::set<std::string> expected = {
      "time_a_b.png",        "cost_a_b.png",         "rd_a_b_2.png",
      "time_a_b_2.png",      "cost_a_b_2.png",       "rd_n.png",
      "time_n.png",          "cost_n.png",           "rd_n_x.png",
      "time_n_x.png",        "cost_n_x.png",         "breakdown_a_b_base.png",
      "breakdown_n_x_y.png", "breakdown_n_x_y_2.png"};
  EXPECT_EQ(names, expected);
  ASSERT_EQ(out->notes.size(), 1u);
  EXPECT_EQ(out->notes[0], "a b: no RD plot, no run wrote a bitstream");
  EXPECT_NE(read_text(out->markdown).find("> a b: no RD plot"), std::string::npos);
}

TEST(Report, APlotGnuplotCannotDrawBecomesANoteAndTheTablesAreWritten) {
  const std::string dir = fresh_dir("bad_gnuplot");
  const std::string gnuplot = dir + "/gnuplot";
  write_text(gnuplot,
             "#!/bin/sh\n[ \"$1\" = --version ] && { echo gnuplot 5.4; exit 0; }\n"
             "echo \"line 7: all points y value undefined!\"\nexit 1\n");
  fs::permissions(gnuplot, fs::perms::owner_all);
  const std::string runs = make_fixture("bad_gnuplot_runs");
  ReportOptions opt;
  opt.gnuplot = gnuplot;
  opt.out_dir = dir + "/out";
  auto out = write_report({runs}, opt);
  ASSERT_TRUE(out.ok()) << out.status().message();
  EXPECT_TRUE(out->pngs.empty());
  ASSERT_FALSE(out->notes.empty());
  EXPECT_EQ(out->notes[0], "rd_fern.png not drawn: gnuplot: line 7: all points y value undefined!");
  const std::string md = read_text(out->markdown);
  EXPECT_NE(md.find("| hac | crpgs | -30.00 |"), std::string::npos) << md;
  EXPECT_NE(md.find("> cost_fern.png not drawn"), std::string::npos) << md;
  EXPECT_NE(read_text(out->html).find("rd_fern.png not drawn"), std::string::npos);
}

TEST(Report, TheTimePlotSaysWhatItsTracesMeasure) {
  const std::string dir = fresh_dir("trace_title");
  const std::string gnuplot = dir + "/gnuplot";
  const std::string scripts = dir + "/scripts.gp";
  write_text(gnuplot,
             "#!/bin/sh\n[ \"$1\" = --version ] && { echo gnuplot 5.4; exit 0; }\n"
             "cat \"$1\" >> '" +
                 scripts + "'\nexit 1\n");
  fs::permissions(gnuplot, fs::perms::owner_all);
  const std::string runs = make_fixture("trace_title_runs");
  ReportOptions opt;
  opt.gnuplot = gnuplot;
  opt.out_dir = dir + "/out";
  ASSERT_TRUE(write_report({runs}, opt).ok());
  EXPECT_NE(read_text(scripts).find("Held-out PSNR (mean of 2 test views) vs training time: fern"),
            std::string::npos)
      << read_text(scripts);

  // A run of an older build traced its first test view alone: the runs now measure different
  // things, and the title does not pretend otherwise.
  const std::string run = runs + "/fern/hac/lambda-0/metrics.json";
  auto m = read_run_metrics(run);
  ASSERT_TRUE(m.ok());
  m->trace_views.clear();
  ASSERT_TRUE(write_run_metrics(run, m.value()).ok());
  fs::remove(scripts);
  ASSERT_TRUE(write_report({runs}, opt).ok());
  EXPECT_NE(read_text(scripts).find("Held-out PSNR (per run: see trace_views in metrics.json)"),
            std::string::npos)
      << read_text(scripts);
  EXPECT_EQ(read_run_metrics(run)->trace_views, std::vector<std::string>{"v0"});
}

TEST(Report, ADirectoryWithoutRunsIsAnError) {
  // A path one level off (a run, or a parent of the runs directory) must not give an empty report.
  const std::string empty = fresh_dir("no_runs");
  auto out = write_report({empty}, ReportOptions{});
  ASSERT_FALSE(out.ok());
  EXPECT_NE(out.status().message().find("no runs in " + empty), std::string::npos);
  EXPECT_FALSE(fs::exists(empty + "/report"));
}

TEST(Report, Base64) {
  EXPECT_EQ(base64_encode(""), "");
  EXPECT_EQ(base64_encode("f"), "Zg==");
  EXPECT_EQ(base64_encode("fo"), "Zm8=");
  EXPECT_EQ(base64_encode("foo"), "Zm9v");
  EXPECT_EQ(base64_encode("foobar"), "Zm9vYmFy");
  EXPECT_EQ(base64_encode(std::string("\xff\x00\x80", 3)), "/wCA");
}

}  // namespace
}  // namespace crpgs::experiments
