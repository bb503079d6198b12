/// @file trainer.cpp
/// @brief The training loop (HAC train.py order: lr update, render, loss, backward, statistics,
/// growing/pruning, Adam), checkpoints, evaluation, and the wiring from a resolved config.
#include "crpgs/trainer.h"
#include "crpgs/lpips.h"

#include <torch/torch.h>

#include <ATen/CPUGeneratorImpl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <numeric>
#include <optional>
#include <random>
#include <sstream>

#include "core/shuffle.h"
#include "core/text_list.h"
#include "crpgs/atomic_file.h"
#include "crpgs/components.h"
#include "crpgs/hashing.h"
#include "crpgs/metrics.h"
#include "crpgs/runtime.h"
#include "crpgs/scene_generator.h"

namespace crpgs {

torch::Tensor image_to_tensor(const Image& im) {
  return torch::from_blob(const_cast<float*>(im.pixels.data()), {im.height, im.width, im.channels},
                          torch::kFloat)
      .clone();
}

Image tensor_to_image(const torch::Tensor& t) {
  auto c = t.detach().to(torch::kCPU, torch::kFloat).clamp(0, 1).contiguous();
  Image im;
  im.height = int(c.size(0));
  im.width = int(c.size(1));
  im.channels = int(c.size(2));
  im.pixels.assign(c.data_ptr<float>(), c.data_ptr<float>() + c.numel());
  return im;
}

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t) {
  return std::chrono::duration<double>(Clock::now() - t).count();
}

// Keys in a torch archive cannot contain dots.
std::string archive_key(const std::string& k) {
  std::string s;
  for (char c : k) s += c == '.' ? std::string("__") : std::string(1, c);
  return s;
}

Schedule scale_schedule(Schedule s, double f) {
  auto sc = [&](int v) { return int(std::lround(v * f)); };
  s.iterations = std::max(1, sc(s.iterations));
  s.start_stat = sc(s.start_stat);
  s.update_from = sc(s.update_from);
  s.update_interval = std::max(1, sc(s.update_interval));
  s.update_until = sc(s.update_until);
  s.pause_from = sc(s.pause_from);
  s.pause_until = sc(s.pause_until);
  s.quant_start = sc(s.quant_start);
  s.rate_start = sc(s.rate_start);
  s.lr_steps = std::max(1, sc(s.lr_steps));
  for (int& b : s.link_builds) b = sc(b);
  return s;
}

}  // namespace

Schedule Schedule::full() {
  return Schedule{};
}
Schedule Schedule::scaled(double factor) {
  return scale_schedule(full(), factor);
}
Schedule Schedule::scaled_by(double factor) const {
  return scale_schedule(*this, factor);
}

double tensor_psnr(const torch::Tensor& a, const torch::Tensor& b) {
  const double mse = (a.detach() - b.detach().to(a.device())).pow(2).mean().item<double>();
  return mse > 0 ? -10.0 * std::log10(mse) : std::numeric_limits<double>::infinity();
}

// ---------------------------------------------------------------------------------------------
// Trainer

Trainer::Trainer(TrainOptions options, Dataset dataset, std::shared_ptr<Rasterizer> rasterizer,
                 std::unique_ptr<AnchorModel> model, torch::Generator gen)
    : options_(std::move(options)),
      dataset_(std::move(dataset)),
      rasterizer_(std::move(rasterizer)),
      model_(std::move(model)),
      gen_(std::move(gen)) {
  for (const auto& v : dataset_.train)
    train_images_.push_back(image_to_tensor(v.image).to(model_->device()));
  trace_view_count_ = int(std::min<size_t>(kMaxTraceViews, dataset_.test.size()));
  model_->set_generator(gen_);  // noise and rate subsets: checkpointed with the trainer's RNG
}

Trainer::~Trainer() = default;

std::vector<const View*> Trainer::trace_view_ptrs() const {
  // Evenly spaced, from the first: a count of 1 is the first test view (the older trace).
  const size_t n = std::min<size_t>(size_t(trace_view_count_), dataset_.test.size());
  std::vector<const View*> views;
  for (size_t i = 0; i < n; ++i) views.push_back(&dataset_.test[i * dataset_.test.size() / n]);
  return views;
}

std::vector<std::string> Trainer::trace_views() const {
  std::vector<std::string> names;
  for (const View* v : trace_view_ptrs()) names.push_back(v->camera.name);
  return names;
}

int Trainer::view_for_iteration(int iteration) const {
  // Deterministic from (seed, iteration) alone, so a resumed run sees the same views.
  const int n = int(dataset_.train.size());
  const int epoch = (iteration - 1) / n, pos = (iteration - 1) % n;
  return seeded_permutation(n, options_.seed * 0x9E3779B97F4A7C15ull + uint64_t(epoch) +
                                   replay_salt_ * 0xD1B54A32D192ED03ull)[size_t(pos)];
}

StatusOr<double> Trainer::step() {
  if (model_->num_anchors() == 0)  // nothing could grow back, and the rate would divide by 0
    return Status(StatusCode::kInternal,
                  "iteration " + std::to_string(iteration_) +
                      ": no anchors left (pruning removed every one: all were transparent); "
                      "check the dataset's images and poses, or lower model.min_opacity");
  const auto t_begin = Clock::now();
  const int it = iteration_ + 1;
  const Schedule& sc = options_.schedule;
  const int v = view_for_iteration(it);
  const View& view = dataset_.train[size_t(v)];
  RenderSettings settings;
  settings.background = model_->options().effects.background;
  model_->update_learning_rates(it);
  const QuantPhase phase = it <= sc.quant_start  ? QuantPhase::kRaw
                           : it <= sc.rate_start ? QuantPhase::kFixedNoise
                                                 : QuantPhase::kAdaptiveNoise;
  const bool rate_path = model_->has_rate();
  if (rate_path) {  // docs/method.md §2.3
    if (it == sc.rate_start && model_->rate_options().recompute_bounds) model_->recompute_bounds();
    const bool build =
        model_->has_links() &&
        std::find(sc.link_builds.begin(), sc.link_builds.end(), it) != sc.link_builds.end();
    if (build) CRPGS_RETURN_IF_ERROR(model_->rebuild_links(options_.seed + uint64_t(it)).status());
    model_->set_quant_phase(phase);
  }

  auto t0 = Clock::now();
  NeuralGaussians ng = model_->generate(view.camera, v, *rasterizer_, settings, true);
  auto t1 = Clock::now();
  RenderOutput out = rasterizer_->render(ng.batch, view.camera, settings);
  auto t2 = Clock::now();
  const auto& gt = train_images_[size_t(v)];
  auto l1 = (out.image - gt).abs().mean();
  auto ssim = tensor_ssim(out.image, gt);
  auto loss = (1.0 - options_.lambda_dssim) * l1 + options_.lambda_dssim * (1.0 - ssim);
  if (ng.batch.scales.size(0) > 0)
    loss = loss + options_.lambda_scaling * ng.batch.scales.prod(1).mean();
  last_rate_ = RateReport();
  // What this iteration reports, read back in one copy: on a GPU each .item() waits for the
  // device, and the rate phase had seven of them per iteration.
  std::vector<torch::Tensor> reported;
  if (ng.bits_per_param.defined()) {  // rate phase (docs/method.md §2.5, §2.6)
    const RateOptions& ro = model_->rate_options();
    const double denom = double(model_->num_anchors()) *
                         double(model_->features().size(1) + 6 + 3 * model_->n_offsets());
    // Every coded grid's bits: the context's and the feature model's (SFA's shared grid).
    auto hash_bits =
        (model_->context()->parameter_bits() + model_->feature_model()->parameter_bits())
            .to(torch::kFloat);
    auto rate = ng.bits_per_param + hash_bits / denom;
    // Without offset masks nothing reads the mask logits: no term to train them.
    auto mask_loss = model_->options().use_offset_mask ? model_->mask_loss() : torch::zeros({});
    loss = loss + ro.lambda * rate + ro.mask_lambda * mask_loss;
    last_rate_.on = true;
    last_rate_.subset = ng.rate_subset;
    reported = {ng.bits_per_param,
                hash_bits,
                rate,
                mask_loss,
                model_->active_anchors().to(torch::kDouble).mean(),
                model_->links().defined() ? (model_->links() >= 0).sum() : torch::zeros({})};
  }
  reported.insert(reported.begin(), {loss, l1});
  for (auto& r : reported) r = r.detach().to(loss.device(), torch::kDouble).reshape({});
  const auto host = torch::stack(reported).cpu();
  const double* h = host.data_ptr<double>();
  auto t3 = Clock::now();
  const double loss_value = h[0];
  if (last_rate_.on) {
    last_rate_.bits_per_param = h[2];
    last_rate_.hash_bits = h[3];
    last_rate_.rate = h[4];
    last_rate_.mask_loss = h[5];
    last_rate_.active_fraction = h[6];
    last_rate_.leaves = int64_t(h[7]);
  }
  // Growing/pruning on schedule (statistics of this iteration first when it has valid ones): a
  // discarded iteration keeps the schedule of an undisturbed run, without its own statistics.
  auto densify = [&](bool with_statistics) {
    torch::NoGradGuard no_grad;
    if (it < sc.update_until && it > sc.start_stat) {
      if (with_statistics) model_->accumulate_statistics(ng, out, view.camera);
      if (sc.adjusts_at(it)) model_->adjust_anchors(sc.update_interval, gen_);
    } else if (it == sc.update_until) {
      model_->reset_statistics();
    }
  };
  auto discard = [&](const std::string& what) {
    model_->zero_grad();
    densify(false);
    iteration_ = it;
    return Status(StatusCode::kNonFinite, "iteration " + std::to_string(it) + " (view '" +
                                              view.camera.name + "'): " + what);
  };
  if (!std::isfinite(loss_value)) return discard("the loss is " + std::to_string(loss_value));
  if (loss.requires_grad()) loss.backward();
  {
    // One reduction per group and one sync: a NaN/Inf anywhere makes its group's sum non-finite.
    torch::NoGradGuard no_grad;
    const auto params = model_->named_parameters();
    std::vector<size_t> with_grad;
    std::vector<torch::Tensor> sums;
    for (size_t i = 0; i < params.size(); ++i)
      if (params[i].second.grad().defined()) {
        with_grad.push_back(i);
        sums.push_back(params[i].second.grad().sum().to(torch::kDouble));
      }
    if (!sums.empty()) {
      auto finite = torch::isfinite(torch::stack(sums));
      if (!finite.all().item<bool>()) {
        const auto bad = size_t(finite.logical_not().nonzero()[0][0].item<int64_t>());
        return discard("non-finite gradient in parameter group '" + params[with_grad[bad]].first +
                       "'");
      }
    }
  }
  auto t4 = Clock::now();
  densify(true);
  {
    torch::NoGradGuard no_grad;
    model_->optimizer_step();
  }
  auto t5 = Clock::now();
  auto dt = [](Clock::time_point a, Clock::time_point b) {
    return std::chrono::duration<double>(b - a).count();
  };
  times_.generate += dt(t0, t1);
  times_.render += dt(t1, t2);
  times_.loss += dt(t2, t3);
  times_.backward += dt(t3, t4);
  times_.optimizer += dt(t4, t5);
  times_.iterations += 1;
  times_.phase_seconds[size_t(phase)] += dt(t_begin, t5);
  times_.phase_iterations[size_t(phase)] += 1;
  last_gaussians_ = ng.batch.means.size(0);
  last_l1_ = h[1];
  iteration_ = it;
  return loss_value;
}

std::string Trainer::checkpoint_path() const {
  if (options_.output_dir.empty()) return "";
  return (std::filesystem::path(options_.output_dir) / "checkpoint.pt").string();
}

namespace {
// Short texts (ids, hashes) in a torch archive, which stores tensors only.
torch::Tensor text_tensor(const std::string& s) {
  return torch::tensor(std::vector<int64_t>(s.begin(), s.end()), torch::kLong);
}
std::string tensor_text(const torch::Tensor& t) {
  const auto c = t.to(torch::kLong).contiguous();
  return std::string(c.data_ptr<int64_t>(), c.data_ptr<int64_t>() + c.numel());
}
}  // namespace

StatusOr<std::string> Trainer::serialize_state() const {
  try {
    torch::serialize::OutputArchive ar;
    // CPU tensors: a checkpoint loads on any machine, and resumes on either device.
    for (const auto& kv : model_->state_dict())
      ar.write(archive_key("model." + kv.first), kv.second.to(torch::kCPU));
    ar.write("iteration", torch::tensor(int64_t(iteration_), torch::kLong));
    ar.write("anchors", torch::tensor(model_->num_anchors(), torch::kLong));
    ar.write("rng", gen_.get_state());
    ar.write("replay_salt", torch::tensor(int64_t(replay_salt_), torch::kLong));
    ar.write("elapsed_seconds", torch::tensor(elapsed_, torch::kDouble));
    ar.write("phase_seconds", torch::tensor(std::vector<double>(times_.phase_seconds.begin(),
                                                                times_.phase_seconds.end()),
                                            torch::kDouble));
    ar.write("phase_iterations", torch::tensor(std::vector<int64_t>(times_.phase_iterations.begin(),
                                                                    times_.phase_iterations.end()),
                                               torch::kLong));
    ar.write("build_id", text_tensor(code_build_id()));
    ar.write("config_hash", text_tensor(options_.config_hash));
    ar.write("execution", text_tensor(execution()));
    ar.write("prefix_key", text_tensor(options_.prefix_key));
    ar.write("origin", text_tensor(origin_));
    ar.write("mixed_config", torch::tensor(int64_t(mixed_config_), torch::kLong));
    std::vector<double> trace;  // [M, 3]: seconds, iteration, PSNR
    for (const auto& p : psnr_trace_)
      trace.insert(trace.end(), {p.seconds, double(p.iteration), p.psnr});
    ar.write("psnr_trace", torch::tensor(trace, torch::kDouble).view({-1, 3}));
    ar.write("trace_views", torch::tensor(int64_t(trace_view_count_), torch::kLong));
    std::ostringstream os;
    ar.save_to(os);
    return os.str();
  } catch (const std::exception& e) {
    return Status(StatusCode::kInternal,
                  std::string("serializing the training state: ") + e.what());
  }
}

Status Trainer::save_checkpoint(const std::string& path) const {
  auto bytes = serialize_state();
  if (!bytes.ok()) return bytes.status();
  return write_checkpoint(path, bytes.value());
}

Status Trainer::write_checkpoint(const std::string& path, std::string_view bytes) {
  std::error_code ec;
  const auto parent = std::filesystem::path(path).parent_path();
  if (!parent.empty()) std::filesystem::create_directories(parent, ec);
  if (ec)
    return Status(StatusCode::kIoError, "cannot create " + parent.string() + ": " + ec.message());
  return write_file_atomic(path, bytes);
}

Status Trainer::load_checkpoint(const std::string& path) {
  auto bytes = read_file_bytes(path);
  if (!bytes.ok()) return bytes.status();
  return restore_state(bytes.value(), path, false);
}

Status Trainer::restore_state(const std::vector<uint8_t>& bytes, const std::string& origin,
                              bool rollback) {
  try {
    torch::serialize::InputArchive ar;
    ar.load_from(reinterpret_cast<const char*>(bytes.data()), bytes.size());
    std::map<std::string, torch::Tensor> state;
    const auto& optional = AnchorModel::optional_state_keys();
    for (const auto& kv : model_->state_dict()) {
      // The model may hold links the state predates (a roll-back to before a link build).
      if (std::find(optional.begin(), optional.end(), kv.first) != optional.end()) continue;
      torch::Tensor t;
      if (!ar.try_read(archive_key("model." + kv.first), t))
        return Status(StatusCode::kCorruptBitstream,
                      origin + ": checkpoint lacks '" + kv.first +
                          "' (written by a different model configuration?)");
      state[kv.first] = t;
    }
    // A fresh model has no links yet; a checkpoint written after a link build has them.
    for (const auto& key : optional) {
      torch::Tensor t;
      if (ar.try_read(archive_key("model." + key), t)) state[key] = t;
    }
    // The trainer's own fields are read and checked before the model takes its state (which is
    // all or nothing), so a refused state leaves the trainer as it was.
    torch::Tensor it, rng;  // read() into a defined tensor would resize it in place
    ar.read("iteration", it);
    ar.read("rng", rng);
    if (it.numel() != 1 || it.item<int64_t>() < 0 || it.item<int64_t>() > INT32_MAX)
      return Status(StatusCode::kCorruptBitstream, origin + ": bad iteration in the checkpoint");
    gen_.clone().set_state(rng);  // throws on a malformed state
    // Older checkpoints have none of these; a roll-back keeps the clock (that time was spent).
    torch::Tensor elapsed, trace, build, config, salt, mixed, execution, origin_text, key,
        trace_count, phase_s, phase_it;
    const uint64_t replay_salt =
        ar.try_read("replay_salt", salt) ? uint64_t(salt.item<int64_t>()) : 0;
    std::string build_id = ar.try_read("build_id", build) ? tensor_text(build) : "";
    std::string config_hash = ar.try_read("config_hash", config) ? tensor_text(config) : "";
    std::string exec = ar.try_read("execution", execution) ? tensor_text(execution) : "";
    // A roll-back restores our own snapshot; any other state trained under a config of another
    // prefix key (or under one that had been mixed) makes this run's state mixed from here on.
    // Checkpoints from before the key was recorded compare the whole config.
    const std::string prefix_key = ar.try_read("prefix_key", key) ? tensor_text(key) : "";
    const bool other_key = !prefix_key.empty() && !options_.prefix_key.empty()
                               ? prefix_key != options_.prefix_key
                               : !config_hash.empty() && config_hash != options_.config_hash;
    const bool mixed_config = (ar.try_read("mixed_config", mixed) && mixed.item<int64_t>() != 0) ||
                              (!rollback && other_key);
    const double elapsed_seconds =
        ar.try_read("elapsed_seconds", elapsed) ? elapsed.item<double>() : 0;
    std::array<double, 3> phase_seconds{};
    std::array<int, 3> phase_iterations{};
    if (ar.try_read("phase_seconds", phase_s) && ar.try_read("phase_iterations", phase_it)) {
      if (phase_s.numel() != 3 || phase_it.numel() != 3)
        return Status(StatusCode::kCorruptBitstream,
                      origin + ": bad phase times in the checkpoint");
      for (int64_t p = 0; p < 3; ++p) {
        phase_seconds[size_t(p)] = phase_s[p].item<double>();
        const int64_t n = phase_it[p].item<int64_t>();
        if (!(phase_seconds[size_t(p)] >= 0) || n < 0 || n > INT32_MAX)
          return Status(StatusCode::kCorruptBitstream,
                        origin + ": bad phase times in the checkpoint");
        phase_iterations[size_t(p)] = int(n);
      }
    }
    std::vector<PsnrPoint> psnr_trace;
    if (ar.try_read("psnr_trace", trace) && trace.dim() == 2 && trace.size(1) == 3) {
      auto acc = trace.to(torch::kDouble).contiguous();
      for (int64_t i = 0; i < acc.size(0); ++i)
        psnr_trace.push_back(
            {acc[i][0].item<double>(), int(acc[i][1].item<double>()), acc[i][2].item<double>()});
    }
    // A trace from before the count was recorded is of the first test view alone.
    int trace_view_count = trace_view_count_;
    if (ar.try_read("trace_views", trace_count)) {
      if (trace_count.numel() != 1 || trace_count.item<int64_t>() < 0 ||
          trace_count.item<int64_t>() > kMaxTraceViews)
        return Status(StatusCode::kCorruptBitstream,
                      origin + ": bad trace view count in the checkpoint");
      if (!psnr_trace.empty()) trace_view_count = int(trace_count.item<int64_t>());
    } else if (!psnr_trace.empty()) {
      trace_view_count = 1;
    }
    if (Status st = model_->load_state_dict(state); !st.ok())
      return Status(st.code(), origin + ": " + st.message());
    iteration_ = int(it.item<int64_t>());
    gen_.set_state(rng);
    replay_salt_ = replay_salt;
    if (!rollback) {  // a roll-back returns to a state of this process: same origin
      // The history names each difference once (another build again), also where a build
      // before 4fa15cd had written one twice.
      std::vector<std::string> history =
          split(ar.try_read("origin", origin_text) ? tensor_text(origin_text) : "", "; ");
      for (const std::string& d : differences_from(build_id, exec)) history.push_back(d);
      std::vector<std::string> once;
      for (std::string& d : history)
        if (std::find(once.begin(), once.end(), d) == once.end()) once.push_back(std::move(d));
      origin_ = join(once, "; ");
      state_build_id_ = std::move(build_id);
      state_config_hash_ = std::move(config_hash);
      state_execution_ = std::move(exec);
    }
    mixed_config_ = mixed_config;
    // Another state: train() snapshots it anew, even when its own snapshot has this iteration.
    if (!rollback) last_good_iteration_ = -1;
    if (!rollback) {
      elapsed_ = elapsed_seconds;
      times_.phase_seconds = phase_seconds;
      times_.phase_iterations = phase_iterations;
    }
    psnr_trace_ = std::move(psnr_trace);
    trace_view_count_ = trace_view_count;
  } catch (const std::exception& e) {
    return Status(StatusCode::kCorruptBitstream, "reading checkpoint " + origin + ": " + e.what());
  }
  return OkStatus();
}

std::string Trainer::execution() const {
  const YAML::Node r = rasterizer_->hyperparams();
  std::string s = "train.threads " + std::to_string(resolve_threads(options_.threads));
  if (r.IsMap() && r["threads"])
    s += ", rasterizer.threads " + std::to_string(resolve_threads(r["threads"].as<int>()));
  return s + ", " + blas_kernels();
}

std::vector<std::string> Trainer::differences_from(const std::string& build_id,
                                                   const std::string& execution_text) const {
  std::vector<std::string> out;
  if (build_id != code_build_id())
    out.push_back(build_id.empty() ? "written by a build that did not record its id"
                                   : "written by another build");
  const std::string ours = execution();
  if (execution_text != ours)
    out.push_back(execution_text.empty()
                      ? "its thread counts and BLAS kernels not recorded"
                      : "trained with " + execution_text + ", continued with " + ours);
  return out;
}

Status Trainer::start_from_prefix(const std::string& path) {
  auto bytes = read_file_bytes(path);
  if (!bytes.ok()) return bytes.status();
  auto fresh = serialize_state();
  if (!fresh.ok()) return fresh.status();
  const std::vector<uint8_t> fresh_bytes(fresh->begin(), fresh->end());
  Status st = restore_state(bytes.value(), path, false);
  if (st.ok() && iteration_ != options_.schedule.rate_start)
    st = Status(StatusCode::kInvalidArgument,
                path + " holds iteration " + std::to_string(iteration_) + ", not rate_start (" +
                    std::to_string(options_.schedule.rate_start) + ")");
  if (st.ok()) return st;
  if (Status back = restore_state(fresh_bytes, "the fresh state", false); !back.ok())
    return Status(StatusCode::kInternal,
                  st.message() + "; the fresh state could not be restored: " + back.message());
  return st.code() == StatusCode::kInternal ? Status(StatusCode::kInvalidArgument, st.message())
                                            : st;
}

void Trainer::publish_prefix(ProgressCallback* progress) const {
  const std::string& path = options_.prefix_path;
  std::error_code ec;
  if (path.empty() || std::filesystem::exists(path, ec)) return;
  if (mixed_config_) {
    if (progress)
      progress->on_note(iteration_,
                        "shared prefix not written: part of this state was trained under "
                        "a config of another prefix key (resumed after a config change)");
    return;
  }
  Status st = nonfinite_parameter_group().empty()
                  ? OkStatus()
                  : Status(StatusCode::kNonFinite, "a parameter is non-finite");
  if (st.ok()) st = save_checkpoint(path);
  if (!progress) return;
  if (st.ok())
    progress->on_note(
        iteration_,
        "shared prefix written: " + path +
            " (runs that differ only in the rate weights or thread counts start there)");
  else
    progress->on_warning(iteration_, "shared prefix not written: " + st.message());
}

std::vector<std::string> Trainer::setting_warnings() const {
  std::vector<std::string> out;
  const std::shared_ptr<FeatureModel> f = model_->feature_model();
  if (model_->has_rate() && f && f->coded_dim() < f->feature_dim() &&
      model_->rate_options().recompute_bounds && iteration_ < options_.schedule.rate_start)
    out.push_back("rate.recompute_bounds is true with a shared feature (features: " +
                  f->type_name() + "): every anchor's shared-feature lookup moves at rate_start (" +
                  std::to_string(options_.schedule.rate_start) +
                  "); docs/method.md §7.4 keeps the bounds, as configs/crpgs.yaml does "
                  "(rate: {recompute_bounds: false})");
  return out;
}

std::string Trainer::nonfinite_parameter_group() const {
  torch::NoGradGuard no_grad;
  for (const auto& [name, param] : model_->named_parameters())
    if (!torch::isfinite(param).all().item<bool>()) return name;
  return "";
}

Status Trainer::checkpoint(ProgressCallback* progress) {
  const std::string bad = nonfinite_parameter_group();
  if (!bad.empty())
    return Status(StatusCode::kNonFinite, "iteration " + std::to_string(iteration_) +
                                              ": parameter group '" + bad + "' is non-finite");
  auto bytes = serialize_state();
  if (!bytes.ok()) return bytes.status();
  last_good_.assign(bytes->begin(), bytes->end());
  last_good_iteration_ = iteration_;
  const std::string path = checkpoint_path();
  if (path.empty()) return OkStatus();
  CRPGS_RETURN_IF_ERROR(write_checkpoint(path, bytes.value()));  // serialized once
  if (progress) progress->on_checkpoint(iteration_, path);
  return OkStatus();
}

namespace {
// Renders with HAC's test-time quantised attributes while alive (rate path only).
class QuantizedScope {
 public:
  explicit QuantizedScope(AnchorModel& m) : m_(m) {
    if (m.has_rate() && !m.is_quantized()) {
      m.set_quantized(m.quantize());
      active_ = true;
    }
  }
  ~QuantizedScope() {
    if (active_) m_.clear_quantized();
  }
  QuantizedScope(const QuantizedScope&) = delete;
  QuantizedScope& operator=(const QuantizedScope&) = delete;

 private:
  AnchorModel& m_;
  bool active_ = false;
};
}  // namespace

double Trainer::view_psnr(const View& view) {
  torch::NoGradGuard no_grad;
  QuantizedScope quantized(*model_);
  RenderSettings settings;
  settings.background = model_->options().effects.background;
  NeuralGaussians ng = model_->generate(view.camera, -1, *rasterizer_, settings, false);
  auto img = rasterizer_->render(ng.batch, view.camera, settings).image.clamp(0, 1);
  auto q = [](const torch::Tensor& t) { return torch::round(t.clamp(0, 1) * 255) / 255; };
  return tensor_psnr(q(img), q(image_to_tensor(view.image)));
}

Status Trainer::train(ProgressCallback* progress, TrainControl* control) {
  // This trainer's thread counts, whatever another trainer of the process set since its setup
  // (0: the process's, as setup_training set them).
  std::optional<ScopedComputeThreads> threads;
  if (options_.threads > 0) threads.emplace(options_.threads);
  const Schedule& sc = options_.schedule;
  const auto start = Clock::now();
  const int first = iteration_;
  auto last_report = Clock::now();
  int last_report_it = iteration_;
  auto last_checkpoint = Clock::now();
  double rate = 0;
  // The PSNR trace is of held-out views: none without test views (a train view would flatter).
  const std::vector<const View*> held_out = trace_view_ptrs();
  // The state to roll back to: the last checkpoint, or this starting point (kept in memory).
  if (last_good_iteration_ != iteration_) {
    auto bytes = serialize_state();
    if (!bytes.ok()) return bytes.status();
    last_good_.assign(bytes->begin(), bytes->end());
    last_good_iteration_ = iteration_;
  }
  int skipped_in_row = 0, rollbacks = 0;
  const double elapsed_at_start = elapsed_;
  double eval_seconds = 0;
  // A non-finite iteration: skip it, or roll back when that is not enough (see train()'s doc).
  auto recover = [&](const Status& why) -> Status {
    if (why.code() != StatusCode::kNonFinite) return why;
    const std::string bad = nonfinite_parameter_group();
    if (bad.empty() && ++skipped_in_row < options_.max_skipped_steps) {
      if (progress) progress->on_warning(iteration_, why.message() + "; update discarded");
      return OkStatus();
    }
    const std::string what =
        why.message() + (bad.empty() ? "" : " (parameter group '" + bad + "' is non-finite)");
    if (rollbacks >= options_.max_rollbacks || last_good_.empty())
      return Status(StatusCode::kNonFinite,
                    "training diverged: " + what + " after " + std::to_string(rollbacks) +
                        " roll-back(s); the last good state is iteration " +
                        std::to_string(last_good_iteration_) +
                        (checkpoint_path().empty() ? std::string()
                                                   : " (checkpoint " + checkpoint_path() + ")"));
    ++rollbacks;
    skipped_in_row = 0;
    CRPGS_RETURN_IF_ERROR(restore_state(last_good_, "the last good state", true));
    // The first replay is exact (a one-off fault then costs nothing). A failure that came back
    // is in the draws themselves: replay with other views, noise and subsets.
    const bool perturb = rollbacks > 1;
    if (perturb) {
      // The restored salt is the checkpoint's: each further replay needs its own.
      replay_salt_ += uint64_t(rollbacks - 1);
      gen_.set_current_seed(options_.seed * 0x9E3779B97F4A7C15ull +
                            replay_salt_ * 0xD1B54A32D192ED03ull + uint64_t(iteration_));
    }
    if (progress)
      progress->on_warning(
          iteration_, what + "; rolled back to iteration " + std::to_string(last_good_iteration_) +
                          (perturb ? " (the failure came back: replaying with other views "
                                     "and noise)"
                                   : ""));
    return OkStatus();
  };
  while (true) {
    // At the loop's top, so that every way of arriving at rate_start publishes: a step, a step
    // whose update was discarded, a roll-back's replay, a resume (publish_prefix writes once).
    if (iteration_ == sc.rate_start) publish_prefix(progress);
    if (iteration_ >= sc.iterations) {
      Status st = checkpoint(progress);
      if (st.code() != StatusCode::kNonFinite) return st;
      CRPGS_RETURN_IF_ERROR(recover(st));
      continue;
    }
    const int64_t anchors_before = model_->num_anchors();
    auto loss = step();
    if (!loss.ok()) {
      CRPGS_RETURN_IF_ERROR(recover(loss.status()));
      continue;
    }
    skipped_in_row = 0;
    const int it = iteration_;
    elapsed_ = elapsed_at_start + seconds_since(start) - eval_seconds;
    bool has_psnr = false;
    double psnr = 0;
    if (!held_out.empty() && options_.eval_interval > 0 &&
        (it % options_.eval_interval == 0 || it == sc.iterations)) {
      const auto te = Clock::now();
      for (const View* v : held_out) psnr += view_psnr(*v) / double(held_out.size());
      has_psnr = true;
      eval_seconds += seconds_since(te);  // the training clock leaves evaluation out
      psnr_trace_.push_back({elapsed_, it, psnr});
    }
    if (progress) {
      TrainingProgress p;
      p.iteration = it;
      p.total_iterations = sc.iterations;
      p.loss = loss.value();
      p.l1 = last_l1_;
      p.anchors = model_->num_anchors();
      p.gaussians = last_gaussians_;
      const double since = seconds_since(last_report);
      if (since > 0.5 || it == first + 1) {
        rate = since > 0 ? (it - last_report_it) / since : 0;
        last_report = Clock::now();
        last_report_it = it;
      }
      p.iterations_per_second = rate;
      p.elapsed_seconds = elapsed_;
      p.eta_seconds = rate > 0 ? (sc.iterations - it) / rate : 0;
      p.has_rate = last_rate_.on;
      p.bits_per_param = last_rate_.rate;
      p.has_test_psnr = has_psnr;
      p.test_psnr = psnr;
      if (p.anchors != anchors_before || sc.adjusts_at(it))
        progress->on_adjust(it, std::max<int64_t>(0, p.anchors - anchors_before),
                            std::max<int64_t>(0, anchors_before - p.anchors), p.anchors);
      progress->on_iteration(p);
    }
    // A multiple of the interval passed since the last good state (that multiple's own update
    // may have been discarded, which skips this block).
    const bool due_by_count =
        options_.checkpoint_interval > 0 && it < sc.iterations &&
        it / options_.checkpoint_interval > last_good_iteration_ / options_.checkpoint_interval;
    const bool due_by_time = options_.checkpoint_minutes > 0 && !checkpoint_path().empty() &&
                             it < sc.iterations &&
                             seconds_since(last_checkpoint) >= 60 * options_.checkpoint_minutes;
    const bool asked = control && control->save.exchange(false);  // cleared whatever else
    if (due_by_count || due_by_time || asked) {
      Status st = checkpoint(progress);
      if (!st.ok()) {
        CRPGS_RETURN_IF_ERROR(recover(st));
        continue;
      }
      last_checkpoint = Clock::now();
      rollbacks = 0;  // a new good state: the roll-back budget is per stretch between them
    }
    if (control && control->stop.load()) {
      CRPGS_RETURN_IF_ERROR(checkpoint(progress));
      return Status(
          StatusCode::kCancelled,
          "training stopped at iteration " + std::to_string(it) +
              (checkpoint_path().empty() ? std::string() : "; checkpoint " + checkpoint_path()));
    }
  }
}

StatusOr<EvalResult> Trainer::evaluate(const std::string& png_dir, const Lpips* lpips) {
  return evaluate_views(*model_, *rasterizer_, dataset_.test, png_dir, lpips);
}

StatusOr<EvalResult> evaluate_views(AnchorModel& model, Rasterizer& rasterizer,
                                    const std::vector<View>& views, const std::string& png_dir,
                                    const Lpips* lpips) {
  torch::NoGradGuard no_grad;
  EvalResult res;
  if (views.empty()) return Status(StatusCode::kInvalidArgument, "evaluation: no views");
  QuantizedScope quantized(model);
  const auto renders_dir = std::filesystem::path(png_dir) / "renders";
  const auto gt_dir = std::filesystem::path(png_dir) / "gt";
  if (!png_dir.empty())
    for (const auto& d : {renders_dir, gt_dir}) {
      std::error_code ec;
      std::filesystem::create_directories(d, ec);
      if (ec)
        return Status(StatusCode::kIoError, "cannot create " + d.string() + ": " + ec.message());
    }
  RenderSettings settings;
  settings.background = model.options().effects.background;
  double render_s = 0;
  for (size_t i = 0; i < views.size(); ++i) {
    const View& v = views[i];
    auto t0 = Clock::now();
    NeuralGaussians ng = model.generate(v.camera, -1, rasterizer, settings, false);
    auto img = rasterizer.render(ng.batch, v.camera, settings).image;
    render_s += seconds_since(t0);
    // The protocol measures on the 8-bit PNG round trip of both images.
    Image render = quantize_8bit(tensor_to_image(img));
    Image gt = quantize_8bit(v.image);
    auto p = psnr(render, gt);
    if (!p.ok()) return p.status();
    auto s = ssim(render, gt);
    if (!s.ok()) return s.status();
    char name[32];
    std::snprintf(name, sizeof(name), "%05zu", i);
    ViewMetrics m;
    m.name = v.camera.name.empty() ? name : v.camera.name;
    m.psnr = p.value();
    m.ssim = s.value();
    if (lpips) {
      CRPGS_ASSIGN_OR_RETURN(m.lpips, lpips->distance(render, gt));
    }
    res.views.push_back(m);
    if (!png_dir.empty()) {
      std::snprintf(name, sizeof(name), "%05zu.png", i);
      CRPGS_RETURN_IF_ERROR(save_png(render, (renders_dir / name).string()));
      CRPGS_RETURN_IF_ERROR(save_png(gt, (gt_dir / name).string()));
    }
  }
  if (lpips) res.mean_lpips = 0;
  for (const auto& m : res.views) {
    res.mean_psnr += m.psnr / double(res.views.size());
    res.mean_ssim += m.ssim / double(res.views.size());
    if (lpips) res.mean_lpips += m.lpips / double(res.views.size());
  }
  res.seconds_per_view = render_s / double(views.size());
  return res;
}

// ---------------------------------------------------------------------------------------------
// Wiring

namespace {

template <typename T>
T get(const YAML::Node& sec, const char* key, T fallback) {
  return sec && sec[key] ? sec[key].as<T>() : fallback;
}

}  // namespace

StatusOr<AnchorModelOptions> model_options_from_config(const Config& resolved) {
  AnchorModelOptions o;
  try {
    const YAML::Node m = resolved.section("model");
    o.n_offsets = get(m, "n_offsets", o.n_offsets);
    o.hidden_dim = get(m, "hidden_dim", o.hidden_dim);
    o.voxel_size = get(m, "voxel_size", o.voxel_size);
    o.update_init_factor = get(m, "update_init_factor", o.update_init_factor);
    o.update_hierarchy_factor = get(m, "update_hierarchy_factor", o.update_hierarchy_factor);
    o.update_depth = get(m, "update_depth", o.update_depth);
    o.densify_grad_threshold = get(m, "densify_grad_threshold", o.densify_grad_threshold);
    o.min_opacity = get(m, "min_opacity", o.min_opacity);
    o.success_threshold = get(m, "success_threshold", o.success_threshold);
    o.use_offset_mask = get(m, "use_offset_mask", o.use_offset_mask);
    o.mask_threshold = get(m, "mask_threshold", o.mask_threshold);
    o.random_init_points = get(m, "random_init_points", o.random_init_points);
    const YAML::Node s = resolved.section("scene");
    o.effects.view_dependent = get(s, "view_dependent", o.effects.view_dependent);
    o.effects.distance_input = get(s, "distance_input", o.effects.distance_input);
    o.effects.appearance_dim = get(s, "appearance_dim", o.effects.appearance_dim);
    if (s && s["background"]) {
      auto bg = s["background"].as<std::vector<float>>();
      if (bg.size() != 3)
        return Status(StatusCode::kInvalidConfig, "scene.background: expected 3 values [r, g, b]");
      o.effects.background = {bg[0], bg[1], bg[2]};
    }
    const YAML::Node t = resolved.section("train");
    LearningRates& lr = o.lr;
    lr.offset_init = get(t, "lr_offset", lr.offset_init);
    lr.offset_final = get(t, "lr_offset_final", lr.offset_final);
    lr.mask_init = get(t, "lr_mask", lr.mask_init);
    lr.mask_final = get(t, "lr_mask_final", lr.mask_final);
    lr.feature = get(t, "lr_feature", lr.feature);
    lr.scaling = get(t, "lr_scaling", lr.scaling);
    lr.mlp_opacity_init = get(t, "lr_mlp_opacity", lr.mlp_opacity_init);
    lr.mlp_opacity_final = get(t, "lr_mlp_opacity_final", lr.mlp_opacity_final);
    lr.mlp_cov_init = get(t, "lr_mlp_cov", lr.mlp_cov_init);
    lr.mlp_cov_final = get(t, "lr_mlp_cov_final", lr.mlp_cov_final);
    lr.mlp_color_init = get(t, "lr_mlp_color", lr.mlp_color_init);
    lr.mlp_color_final = get(t, "lr_mlp_color_final", lr.mlp_color_final);
    lr.appearance_init = get(t, "lr_appearance", lr.appearance_init);
    lr.appearance_final = get(t, "lr_appearance_final", lr.appearance_final);
    lr.feature_model_init = get(t, "lr_feature_model", lr.feature_model_init);
    lr.feature_model_final = get(t, "lr_feature_model_final", lr.feature_model_final);
    auto to = train_options_from_config(resolved);
    if (!to.ok()) return to.status();
    lr.max_steps = to->schedule.lr_steps;
    const std::string start = get<std::string>(t, "feature_model_start", "start");
    if (start == "growing_end" || start == "auto")
      lr.feature_model_start = to->schedule.update_until;
    lr.feature_model_start_auto = start == "auto";
    if (start == "rate_start") lr.feature_model_start = to->schedule.rate_start;
    lr.feature_model_hold_scale = get(t, "feature_model_hold_lr_scale", 0.0);
  } catch (const YAML::Exception& e) {
    return Status(StatusCode::kInvalidConfig, std::string("model/scene config: ") + e.what());
  }
  return o;
}

StatusOr<TrainOptions> train_options_from_config(const Config& resolved) {
  TrainOptions o;
  try {
    const YAML::Node t = resolved.section("train");
    const std::string schedule = get<std::string>(t, "schedule", "full");
    const double factor = get(t, "fast_factor", 0.1);
    Schedule full = Schedule::full();
    full.iterations = get(t, "full_iterations", full.iterations);
    if (t && t["link_builds"]) full.link_builds = t["link_builds"].as<std::vector<int>>();
    if (schedule == "fast") {
      if (!(factor > 0 && factor <= 1))
        return Status(StatusCode::kInvalidConfig, "train.fast_factor must be in (0, 1]");
      o.schedule = full.scaled_by(factor);
    } else if (schedule == "full") {
      o.schedule = full;
    } else {
      return Status(StatusCode::kInvalidConfig,
                    "train.schedule: unknown '" + schedule + "' (available: full, fast)");
    }
    const int iterations = get(t, "iterations", 0);
    if (iterations > 0) o.schedule.iterations = iterations;
    o.seed = get<uint64_t>(t, "seed", 0);
    o.lambda_dssim = get(t, "lambda_dssim", o.lambda_dssim);
    o.lambda_scaling = get(t, "lambda_scaling", o.lambda_scaling);
    o.eval_interval = get(t, "eval_interval", o.eval_interval);
    o.checkpoint_interval = get(t, "checkpoint_interval", o.checkpoint_interval);
    o.checkpoint_minutes = get(t, "checkpoint_minutes", o.checkpoint_minutes);
    o.threads = get(t, "threads", o.threads);
    o.device = get<std::string>(t, "device", o.device);
    o.config_hash = hex64(resolved.hash());
    o.prefix_key = shared_prefix_key(resolved);
  } catch (const YAML::Exception& e) {
    return Status(StatusCode::kInvalidConfig, std::string("train config: ") + e.what());
  }
  return o;
}

StatusOr<RateOptions> rate_options_from_config(const Config& resolved) {
  RateOptions o;
  try {
    const YAML::Node r = resolved.section("rate");
    o.lambda = get(r, "lambda", o.lambda);
    o.mask_lambda = get(r, "mask_lambda", o.mask_lambda);
    o.subset = get(r, "subset", o.subset);
    o.q0.feature = get(r, "q0_feature", o.q0.feature);
    o.q0.scaling = get(r, "q0_scaling", o.q0.scaling);
    o.q0.offset = get(r, "q0_offset", o.q0.offset);
    o.recompute_bounds = get(r, "recompute_bounds", o.recompute_bounds);
    o.geometry = get<std::string>(r, "geometry", o.geometry);
    o.link_coding = get<std::string>(r, "link_coding", o.link_coding);
    o.prune_links = get(r, "prune_links", o.prune_links);
    o.lr_context_init = get(r, "lr_context", o.lr_context_init);
    o.lr_context_final = get(r, "lr_context_final", o.lr_context_final);
    o.lr_context_mlp_init = get(r, "lr_context_mlp", o.lr_context_mlp_init);
    o.lr_context_mlp_final = get(r, "lr_context_mlp_final", o.lr_context_mlp_final);
  } catch (const YAML::Exception& e) {
    return Status(StatusCode::kInvalidConfig, std::string("rate config: ") + e.what());
  }
  if (!(o.subset > 0 && o.subset <= 1))
    return Status(StatusCode::kInvalidConfig, "rate.subset must be in (0, 1]");
  return o;
}

StatusOr<LinkOptions> link_options_from_config(const Config& resolved, const Schedule& schedule) {
  LinkOptions o;
  try {
    const YAML::Node r = resolved.section("rate");
    o.leaf_hidden = get(r, "leaf_hidden", o.leaf_hidden);
    o.lr_leaf_init = get(r, "lr_leaf", o.lr_leaf_init);
    o.lr_leaf_final = get(r, "lr_leaf_final", o.lr_leaf_final);
    o.residual = get(r, "leaf_residual", o.residual);
  } catch (const YAML::Exception& e) {
    return Status(StatusCode::kInvalidConfig, std::string("rate config: ") + e.what());
  }
  if (schedule.link_builds.empty())
    return Status(StatusCode::kInvalidConfig,
                  "train.link_builds: a `links` component needs at least one build iteration");
  // Growing and pruning (before update_until) clear the links; a build after the last
  // iteration never happens. Either way the run would code no links and say nothing.
  for (int b : schedule.link_builds)
    if (b < schedule.update_until || b > schedule.iterations)
      return Status(StatusCode::kInvalidConfig,
                    "train.link_builds: a build at iteration " + std::to_string(b) +
                        " (after the schedule's scaling) is outside [" +
                        std::to_string(schedule.update_until) + ", " +
                        std::to_string(schedule.iterations) +
                        "]: the end of growing and pruning (update_until) to the last iteration" +
                        (b > schedule.iterations
                             ? std::string("; train.iterations ends the run before it without "
                                           "moving the phases: lower train.fast_factor instead "
                                           "(the whole schedule scales), or set train.link_builds "
                                           "inside the run")
                             : std::string()));
  o.lr_start = *std::min_element(schedule.link_builds.begin(), schedule.link_builds.end());
  o.lr_end = std::max(o.lr_start + 1, schedule.iterations);
  return o;
}

StatusOr<std::unique_ptr<Trainer>> make_trainer(const TrainOptions& train_options,
                                                const AnchorModelOptions& model_options,
                                                Dataset dataset,
                                                std::shared_ptr<Rasterizer> rasterizer,
                                                std::shared_ptr<FeatureModel> features,
                                                const RateSetup& rate) {
  if (!rasterizer) return Status(StatusCode::kInvalidArgument, "make_trainer: no rasterizer");
  if (dataset.train.empty())
    return Status(StatusCode::kInvalidArgument,
                  "dataset '" + dataset.name + "' has no training views");
  for (const auto* split : {&dataset.train, &dataset.test})
    for (const auto& v : *split)
      if (v.image.channels != 3 || v.image.width != v.camera.width ||
          v.image.height != v.camera.height)
        return Status(StatusCode::kInvalidArgument,
                      "view '" + v.camera.name + "': image must be RGB and match its camera size");
  auto gen = at::make_generator<at::CPUGeneratorImpl>(train_options.seed);
  AnchorInit init;
  for (const auto& p : dataset.points) init.points.push_back({p.x(), p.y(), p.z()});
  for (const auto& v : dataset.train) init.train_cameras.push_back(v.camera);
  AnchorModelOptions options = model_options;
  if (options.lr.feature_model_start_auto && !init.points.empty())
    options.lr.feature_model_start = 0;
  auto model = AnchorModel::create(options, std::move(features), init, gen);
  if (!model.ok()) return model.status();
  if (rate.context || rate.entropy)
    CRPGS_RETURN_IF_ERROR((*model)->attach_rate(rate.context, rate.entropy, rate.options));
  if (rate.links) CRPGS_RETURN_IF_ERROR((*model)->attach_links(rate.links, rate.link_options, gen));
  // Built on the CPU (the same initial values on every device), then moved.
  if (train_options.device == "cuda") {
    if (!torch::cuda::is_available())
      return Status(StatusCode::kInvalidConfig,
                    "train.device: cuda, but this libtorch sees no CUDA device (a CPU-only "
                    "build, or no GPU); use train.device: cpu");
    if (rasterizer->type_name() != "cuda")
      return Status(StatusCode::kInvalidConfig,
                    "train.device: cuda needs rasterizer.type: cuda (the '" +
                        rasterizer->type_name() + "' rasterizer takes CPU tensors)");
    (*model)->to(torch::Device(torch::kCUDA));
  } else if (train_options.device != "cpu") {
    return Status(StatusCode::kInvalidConfig,
                  "train.device: unknown '" + train_options.device + "' (available: cpu, cuda)");
  }
  return std::make_unique<Trainer>(train_options, std::move(dataset), std::move(rasterizer),
                                   std::move(model).value(), gen);
}

StatusOr<std::unique_ptr<Trainer>> setup_training(const Config& resolved,
                                                  const ComponentRegistry& registry,
                                                  const SetupOptions& setup) {
  // 1. Options from the resolved config.
  CRPGS_ASSIGN_OR_RETURN(TrainOptions train_options, train_options_from_config(resolved));
  CRPGS_ASSIGN_OR_RETURN(AnchorModelOptions model_options, model_options_from_config(resolved));
  train_options.output_dir = setup.output_dir;
  if (setup.model_on_cpu) train_options.device = "cpu";
  if (!setup.prefix_dir.empty() && !train_options.prefix_key.empty())
    train_options.prefix_path = shared_prefix_path(setup.prefix_dir, train_options.prefix_key);
  // 2. Threads (libtorch starts with one here) and the allocator.
  set_compute_threads(train_options.threads);
  keep_freed_memory_in_heap();
  // 3. Components: rasterizer and feature model from the registry. They draw their initial
  // parameters (hash tables, MLPs) from libtorch's global generator: train.seed seeds it, so the
  // seed varies every random initial value, not only the anchor model's.
  torch::manual_seed(train_options.seed);
  crpgs_create_args args = create_args_for(resolved);
  auto block = [&](const char* key, const char* type) {
    YAML::Node b = resolved.section(key);
    if (!b) {
      b = YAML::Node(YAML::NodeType::Map);
      b["type"] = type;
    }
    return b;
  };
  CRPGS_ASSIGN_OR_RETURN(std::shared_ptr<Rasterizer> rasterizer,
                         create_component<Rasterizer>(registry, block("rasterizer", "cpu"), args));
  CRPGS_ASSIGN_OR_RETURN(
      std::shared_ptr<FeatureModel> features,
      create_component<FeatureModel>(registry, block("features", "identity"), args));
  // The rate path (HAC): a grid context and an entropy model, both or neither.
  RateSetup rate;
  {
    const YAML::Node c = resolved.section("context"), e = resolved.section("entropy");
    if (bool(c) != bool(e))
      return Status(StatusCode::kInvalidConfig,
                    std::string("the rate path needs both a `context` and an `entropy` section; "
                                "only `") +
                        (c ? "context" : "entropy") + "` is set");
    if (c) {
      args.coded_dim = int32_t(features->coded_dim());
      // Grid contexts and link strategies are one plugin kind; each section takes one of them.
      auto misplaced = [&](const char* section, const std::string& type, const char* is,
                           const char* belongs) {
        return Status(StatusCode::kInvalidConfig, resolved.file() + ": " + section + ".type: '" +
                                                      type + "' is " + is + "; it belongs under `" +
                                                      belongs + ":`");
      };
      CRPGS_ASSIGN_OR_RETURN(rate.context, create_component<ContextModel>(registry, c, args));
      if (rate.context->output_dim() == 0)
        return misplaced("context", rate.context->type_name(), "a link strategy", "links");
      CRPGS_ASSIGN_OR_RETURN(rate.entropy, create_component<EntropyModel>(registry, e, args));
      CRPGS_ASSIGN_OR_RETURN(rate.options, rate_options_from_config(resolved));
      if (const YAML::Node l = resolved.section("links")) {
        CRPGS_ASSIGN_OR_RETURN(rate.links, create_component<ContextModel>(registry, l, args));
        if (rate.links->output_dim() != 0)
          return misplaced("links", rate.links->type_name(), "a grid context", "context");
        CRPGS_ASSIGN_OR_RETURN(rate.link_options,
                               link_options_from_config(resolved, train_options.schedule));
      }
    } else if (resolved.section("links")) {
      return Status(StatusCode::kInvalidConfig,
                    "a `links` component needs the rate path (`context` and `entropy`)");
    }
  }
  // 4. Dataset: a real one from disk, or the built-in synthetic scene.
  const YAML::Node d = resolved.section("dataset");
  Dataset dataset;
  try {
    const std::string path = get<std::string>(d, "path", "");
    const std::string format = get<std::string>(d, "format", "auto");
    if (format == "synthetic" || path.empty()) {
      SyntheticSceneOptions so;
      so.width = get(d, "synthetic_width", so.width);
      so.height = get(d, "synthetic_height", so.height);
      so.views = get(d, "synthetic_views", so.views);
      so.sfm_points = get(d, "synthetic_points", so.sfm_points);
      so.seed = get<uint64_t>(d, "synthetic_seed", so.seed);
      so.test_every = get(d, "test_every", so.test_every);
      so.background = model_options.effects.background;
      CRPGS_ASSIGN_OR_RETURN(dataset, generate_scene(so, *rasterizer));
    } else {
      DatasetOptions o;
      o.path = path;
      o.format = format;
      o.images = get<std::string>(d, "images", "");
      o.downscale = get(d, "downscale", 1);
      o.max_width = get(d, "max_width", 0);
      o.test_every = get(d, "test_every", 8);
      o.max_images = get(d, "max_images", 0);
      o.background = model_options.effects.background;
      o.threads = resolve_threads(train_options.threads);
      CRPGS_ASSIGN_OR_RETURN(dataset, load_dataset(o));
    }
  } catch (const YAML::Exception& e) {
    return Status(StatusCode::kInvalidConfig, std::string("dataset config: ") + e.what());
  }
  // 5. Model and trainer.
  CRPGS_ASSIGN_OR_RETURN(std::unique_ptr<Trainer> trainer,
                         make_trainer(train_options, model_options, std::move(dataset),
                                      std::move(rasterizer), std::move(features), rate));
  // 6. Resume from the last checkpoint when asked and present, else from a shared prefix.
  if (setup.resume) {
    const std::string path = trainer->checkpoint_path();
    if (path.empty())
      return Status(StatusCode::kInvalidArgument, "resume needs an output directory");
    if (std::filesystem::exists(path)) CRPGS_RETURN_IF_ERROR(trainer->load_checkpoint(path));
  }
  if (!setup.start_from.empty() && trainer->iteration() == 0) {
    CRPGS_RETURN_IF_ERROR(trainer->load_checkpoint(setup.start_from));
    const int at = trainer->iteration(), end = trainer->options().schedule.iterations;
    if (at >= end)
      return Status(StatusCode::kInvalidConfig,
                    setup.start_from + " is at iteration " + std::to_string(at) +
                        ", and this run ends at train.iterations " + std::to_string(end) +
                        ": set it above (e.g. --set train.iterations=" + std::to_string(at + 400) +
                        " for a short fine-tune)");
  }
  const std::string& prefix = train_options.prefix_path;
  if (!prefix.empty() && trainer->iteration() == 0 && std::filesystem::exists(prefix)) {
    // A bad prefix costs only the time it would have saved: train from the start, and move it
    // aside so that this run publishes a good one (every run of its key would refuse it).
    const Status st = trainer->start_from_prefix(prefix);
    if (st.code() == StatusCode::kInternal) return st;
    std::string status = "started at iteration " + std::to_string(trainer->iteration()) +
                         " from the shared prefix " + prefix;
    if (const std::string d = trainer->state_origin_differences(); st.ok() && !d.empty())
      status += " (" + d + ": not bit-identical to training from the start in this process)";
    if (!st.ok()) {
      std::error_code ec;
      std::filesystem::rename(prefix, prefix + ".unusable", ec);
      status = "shared prefix not used (" +
               (ec ? "left in place" : "moved to " + prefix + ".unusable") +
               "), training from the start: " + st.message();
    }
    trainer->set_prefix_status(status);
  }
  return trainer;
}

}  // namespace crpgs
