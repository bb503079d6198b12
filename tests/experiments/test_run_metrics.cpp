// metrics.json round trip and validation.
#include <gtest/gtest.h>

#include <filesystem>

#include "crpgs/experiments/run_metrics.h"

namespace crpgs::experiments {
namespace {

TEST(RunMetrics, RoundTripsThroughJson) {
  RunMetrics m;
  m.method = "crpgs \"quoted\"";
  m.dataset = "fern";
  m.lambda = 1e-3;
  m.config_hash = "00ff00ff00ff00ff";
  m.size_bytes = 1234567;
  m.breakdown[static_cast<int>(BitstreamCategory::kGeometry)] = 1000;
  m.breakdown[static_cast<int>(BitstreamCategory::kMlps)] = 234567;
  m.anchors = 68123;
  m.gaussians = 512345;
  m.views = {{"view_000", 25.5, 0.81, 0.012}, {"view_008", 26.5, 0.83, 0.014}};
  m.train_seconds = 1800.25;
  m.encode_seconds = 3.5;
  m.trace = {{10.5, 100, 18.25}, {20.0, 200, 21.0}};
  m.trace_views = {"view_000", "view_008"};
  m.phases = {{"raw", 3000, 512.5}, {"fixed_noise", 7000, 1400.25}, {"rate", 30000, 15000}};
  m.peak_memory_bytes = peak_rss_bytes();
  EXPECT_GT(m.peak_memory_bytes, 0);
  m.rate_scale = 2.5;
  m.base_method = "crpgs schedule=fast";
  m.provenance = this_process_provenance(7, 2, "cpu");
  EXPECT_FALSE(m.provenance.version.empty());
  EXPECT_FALSE(m.provenance.commit.empty());
  EXPECT_GT(m.provenance.cpus, 0);

  const std::string dir = std::string(CRPGS_TEST_TMP_DIR) + "/experiments/metrics";
  std::filesystem::create_directories(dir);
  ASSERT_TRUE(write_run_metrics(dir + "/metrics.json", m).ok());
  auto back = read_run_metrics(dir + "/metrics.json");
  ASSERT_TRUE(back.ok()) << back.status().message();
  const RunMetrics& r = back.value();
  EXPECT_EQ(r.method, m.method);
  EXPECT_EQ(r.dataset, "fern");
  EXPECT_DOUBLE_EQ(r.lambda, 1e-3);
  EXPECT_EQ(r.size_bytes, 1234567u);
  EXPECT_EQ(r.breakdown, m.breakdown);
  EXPECT_EQ(r.anchors, 68123);
  EXPECT_EQ(r.gaussians, 512345);
  ASSERT_EQ(r.views.size(), 2u);
  EXPECT_EQ(r.views[1].name, "view_008");
  EXPECT_DOUBLE_EQ(r.psnr_mean, 26.0);  // filled from the views
  EXPECT_DOUBLE_EQ(r.ssim_mean, 0.82);
  EXPECT_DOUBLE_EQ(r.render_seconds_per_view, 0.013);
  EXPECT_DOUBLE_EQ(r.train_seconds, 1800.25);
  EXPECT_TRUE(std::isnan(r.decode_seconds));  // not measured stays NaN (null in JSON)
  ASSERT_EQ(r.trace.size(), 2u);
  EXPECT_EQ(r.trace[1].iteration, 200);
  EXPECT_DOUBLE_EQ(r.trace[0].seconds, 10.5);
  EXPECT_EQ(r.trace_views, m.trace_views);
  ASSERT_EQ(r.phases.size(), 3u);
  EXPECT_EQ(r.phases[1].name, "fixed_noise");
  EXPECT_EQ(r.phases[1].iterations, 7000);
  EXPECT_DOUBLE_EQ(r.phases[1].seconds, 1400.25);
  EXPECT_EQ(r.phases[2].iterations, 30000);
  EXPECT_EQ(r.peak_memory_bytes, m.peak_memory_bytes);
  EXPECT_EQ(r.rate_scale, 2.5);
  EXPECT_EQ(r.base_method, m.base_method);
  const Provenance &p = r.provenance, &q = m.provenance;
  EXPECT_EQ(p.version, q.version);
  EXPECT_EQ(p.commit, q.commit);
  EXPECT_EQ(p.libtorch, q.libtorch);
  EXPECT_EQ(p.cpu, q.cpu);
  EXPECT_EQ(p.cpus, q.cpus);
  EXPECT_EQ(p.threads, 2);
  EXPECT_EQ(p.device, "cpu");
  EXPECT_EQ(p.seed, 7);

  // A run's own file records neither; a scale must be positive.
  RunMetrics plain;
  plain.size_bytes = 1;
  plain.psnr_mean = 20;
  const std::string text = to_json(plain);
  EXPECT_EQ(text.find("rate_scale"), std::string::npos);
  EXPECT_EQ(text.find("provenance"), std::string::npos);
  auto back_plain = run_metrics_from_json(text);
  ASSERT_TRUE(back_plain.ok());
  EXPECT_TRUE(std::isnan(back_plain->rate_scale));
  EXPECT_EQ(back_plain->provenance.seed, -1);
  std::string zero = to_json(m);
  zero.replace(zero.find("\"rate_scale\": 2.5"), 17, "\"rate_scale\": 0.0");
  EXPECT_FALSE(run_metrics_from_json(zero).ok());
}

TEST(RunMetrics, CountsAreUnknownInOlderFilesAndRefusedWhenNotWholeNumbers) {
  const std::string head =
      "{\"format\": \"crpgs.run_metrics/1\", \"size_bytes\": 10, "
      "\"views\": [{\"name\": \"a\", \"psnr\": 30}]";
  auto old = run_metrics_from_json(head + "}");
  ASSERT_TRUE(old.ok()) << old.status().message();
  EXPECT_EQ(old->anchors, -1);
  EXPECT_EQ(old->gaussians, -1);
  auto bad = run_metrics_from_json(head + ", \"gaussians\": -3}");
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("\"gaussians\" must be a whole number"), std::string::npos)
      << bad.status().message();
}

TEST(RunMetrics, ATraceWithoutItsViewsIsOfTheFirstTestView) {
  // What builds before trace_views wrote: the trace measured the first test view alone.
  const std::string head =
      "{\"format\": \"crpgs.run_metrics/1\", \"size_bytes\": 10, "
      "\"views\": [{\"name\": \"a\", \"psnr\": 30}, "
      "{\"name\": \"b\", \"psnr\": 31}]";
  auto legacy = run_metrics_from_json(head + ", \"trace\": [[1, 100, 29]]}");
  ASSERT_TRUE(legacy.ok()) << legacy.status().message();
  EXPECT_EQ(legacy->trace_views, std::vector<std::string>{"a"});
  auto no_trace = run_metrics_from_json(head + "}");
  ASSERT_TRUE(no_trace.ok());
  EXPECT_TRUE(no_trace->trace_views.empty());
  EXPECT_FALSE(run_metrics_from_json(head + ", \"trace_views\": [3]}").ok());
}

TEST(RunMetrics, RejectsIncompleteDocuments) {
  EXPECT_FALSE(run_metrics_from_json("{\"size_bytes\": 10, \"psnr_mean\": 30}").ok());  // no format
  EXPECT_FALSE(
      run_metrics_from_json("{\"format\": \"crpgs.run_metrics/1\", \"psnr_mean\": 30}").ok());
  EXPECT_FALSE(
      run_metrics_from_json("{\"format\": \"crpgs.run_metrics/1\", \"size_bytes\": 10}").ok());
  EXPECT_FALSE(run_metrics_from_json("{\"format\": \"crpgs.run_metrics/1\", \"size_bytes\": 10, "
                                     "\"psnr_mean\": 30, \"trace\": [[1, 2]]}")
                   .ok());
  EXPECT_FALSE(run_metrics_from_json("{\"format\": \"crpgs.run_metrics/1\", \"size_bytes\": 10, "
                                     "\"psnr_mean\": 30, \"phases\": [{\"name\": \"rate\", "
                                     "\"iterations\": -1, \"seconds\": 2}]}")
                   .ok());
  EXPECT_FALSE(run_metrics_from_json("{\"format\": \"crpgs.run_metrics/1\", ").ok());  // truncated
  EXPECT_TRUE(run_metrics_from_json("{\"format\": \"crpgs.run_metrics/1\", \"size_bytes\": 10, "
                                    "\"psnr_mean\": 30}")
                  .ok());
}

TEST(RunMetrics, CountsMustBeWholeNumbersInRange) {
  // Byte counts and iterations are cast to integers: anything a cast would mangle is refused.
  auto doc = [](const std::string& fields) {
    return run_metrics_from_json("{\"format\": \"crpgs.run_metrics/1\", \"psnr_mean\": 30, " +
                                 fields + "}");
  };
  for (const char* bad :
       {"\"size_bytes\": -1", "\"size_bytes\": 1.5", "\"size_bytes\": 1e300",
        "\"size_bytes\": \"10\"", "\"size_bytes\": 10, \"bitstream\": {\"features\": -3}",
        "\"size_bytes\": 10, \"peak_memory_bytes\": 1e30",
        "\"size_bytes\": 10, \"trace\": [[1, -2, 20]]",
        "\"size_bytes\": 10, \"trace\": [[1, 1e12, 20]]"}) {
    auto m = doc(bad);
    EXPECT_FALSE(m.ok()) << bad;
  }
  auto m = doc("\"size_bytes\": 9007199254740992, \"bitstream\": {\"features\": 7}");
  ASSERT_TRUE(m.ok()) << m.status().message();
  EXPECT_EQ(m->size_bytes, uint64_t(1) << 53);
}

}  // namespace
}  // namespace crpgs::experiments
