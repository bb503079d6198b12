// Anchor model: initialisation, effects that are off, growing/pruning invariants.
#include <gtest/gtest.h>
#include <torch/torch.h>

#include <ATen/CPUGeneratorImpl.h>

#include <array>
#include <functional>

#include "crpgs/anchor_model.h"
#include "crpgs/chunked_mlp.h"
#include "crpgs/components.h"
#include "crpgs/scene_generator.h"
#include "model/sorted_gather.h"
#include "raster/cpu_rasterizer.h"

namespace crpgs {
namespace {

// Gradient of sum(upstream * gather(src)) with respect to src.
torch::Tensor gather_grad(const torch::Tensor& src0, const torch::Tensor& index,
                          const torch::Tensor& upstream, bool sorted_op) {
  auto src = src0.clone().requires_grad_(true);
  auto out = sorted_op ? gather_sorted_rows(src, index) : src.index_select(0, index);
  EXPECT_TRUE(torch::equal(out, src0.index_select(0, index)));
  (out * upstream).sum().backward();
  return src.grad();
}

// Repeats, gaps, unselected rows at both ends, an empty index (no repeat: the backward's copy
// path; repeats: its sum path); 1-D to 3-D rows, float and double.
TEST(GatherSortedRows, SameValuesAndGradientsAsIndexSelectBitForBit) {
  torch::manual_seed(5);
  const std::vector<std::vector<int64_t>> indices{
      {1, 1, 1, 2, 5, 5, 9, 12, 12, 12, 12, 13},
      {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14},
      {2, 3, 7, 11},
      {14, 14},
      {}};
  for (auto dtype : {torch::kFloat, torch::kDouble})
    for (auto shape : std::vector<std::vector<int64_t>>{{15}, {15, 7}, {15, 4, 3}})
      for (const auto& iv : indices) {
        auto src = torch::randn(shape, dtype);
        auto index = torch::tensor(iv, torch::kLong);
        auto out_shape = shape;
        out_shape[0] = index.size(0);
        auto upstream = torch::randn(out_shape, dtype);
        auto g_ref = gather_grad(src, index, upstream, false);
        auto g = gather_grad(src, index, upstream, true);
        EXPECT_TRUE(torch::equal(g, g_ref)) << "index of " << iv.size() << " rows";
      }
  // No source rows; an upstream gradient that is not contiguous (a transposed view).
  auto none = torch::zeros({0, 3});
  EXPECT_EQ(gather_grad(none, torch::zeros({0}, torch::kLong), torch::zeros({0, 3}), true).numel(),
            0);
  auto src = torch::randn({6, 4});
  auto index = torch::tensor({0, 2, 2, 5}, torch::kLong);
  auto upstream = torch::randn({4, 4}).t();
  ASSERT_FALSE(upstream.is_contiguous());
  EXPECT_TRUE(torch::equal(gather_grad(src, index, upstream, true),
                           gather_grad(src, index, upstream, false)));
  // Long indices, without and with repeats, over many parallel chunks: runs of consecutive rows
  // and gaps meet the chunk borders anywhere.
  auto big = torch::randn({50000, 3});
  auto picked = (torch::rand({50000}) < 0.6).nonzero().squeeze(1);
  for (const auto& idx :
       {picked, std::get<0>(torch::sort(torch::cat({picked, picked.narrow(0, 0, 999)})))}) {
    auto up = torch::randn({idx.size(0), 3});
    EXPECT_TRUE(torch::equal(gather_grad(big, idx, up, true), gather_grad(big, idx, up, false)));
  }
}

TEST(GatherSortedRows, SameGradientWithOneAndTwoThreads) {
  auto src = torch::randn({20000, 6});
  auto index = std::get<0>(torch::randint(20000, {50000}, torch::kLong).sort());
  auto upstream = torch::randn({50000, 6});
  const int threads = at::get_num_threads();
  at::set_num_threads(1);
  auto g1 = gather_grad(src, index, upstream, true);
  at::set_num_threads(2);
  auto g2 = gather_grad(src, index, upstream, true);
  at::set_num_threads(threads);
  EXPECT_TRUE(torch::equal(g1, g2));
}

// Output and the five gradients of sum(upstream * mlp(x)), fused or as libtorch ops.
std::vector<torch::Tensor> mlp_and_grads(const std::vector<torch::Tensor>& in0,
                                         const torch::Tensor& upstream, bool chunked,
                                         bool x_grad = true) {
  std::vector<torch::Tensor> in;
  for (size_t i = 0; i < in0.size(); ++i)
    in.push_back(in0[i].clone().requires_grad_(i > 0 || x_grad));
  auto y = chunked ? chunked_mlp(in[0], in[1], in[2], in[3], in[4])
                   : torch::linear(torch::relu(torch::linear(in[0], in[1], in[2])), in[3], in[4]);
  (y * upstream).sum().backward();
  std::vector<torch::Tensor> out{y.detach()};
  for (auto& t : in) out.push_back(t.grad());
  return out;
}

std::vector<torch::Tensor> random_mlp(int64_t rows, torch::ScalarType dtype) {
  return {torch::randn({rows, 9}, dtype), torch::randn({6, 9}, dtype), torch::randn({6}, dtype),
          torch::randn({4, 6}, dtype), torch::randn({4}, dtype)};
}

TEST(ChunkedMlp, SameValuesAndGradientsAsLibtorch) {
  torch::manual_seed(8);
  // One partial chunk, exactly one chunk, several with a partial last one, none.
  for (int64_t rows : {1, 37, 1024, 2500, 0}) {
    auto in = random_mlp(rows, torch::kDouble);
    auto upstream = torch::randn({rows, 4}, torch::kDouble);
    auto ref = mlp_and_grads(in, upstream, false);
    auto got = mlp_and_grads(in, upstream, true);
    for (size_t i = 0; i < ref.size(); ++i) {
      ASSERT_TRUE(got[i].defined()) << "rows " << rows << " output " << i;
      EXPECT_EQ(got[i].sizes(), ref[i].sizes()) << "rows " << rows << " output " << i;
      EXPECT_TRUE(torch::allclose(got[i], ref[i], 1e-12, 1e-12)) << "rows " << rows << " " << i;
    }
  }
  // With an input that needs no gradient the weights' gradients are the same; without autograd
  // only the forward runs, also with parameters that require gradients and chunks on several
  // threads.
  auto in = random_mlp(5000, torch::kFloat);
  auto up = torch::randn({5000, 4});
  auto ref = mlp_and_grads(in, up, false, false), got = mlp_and_grads(in, up, true, false);
  for (size_t i = 2; i < ref.size(); ++i)
    EXPECT_TRUE(torch::allclose(got[i], ref[i], 1e-4, 1e-4)) << "tensor " << i;
  for (size_t i = 1; i < in.size(); ++i) in[i].requires_grad_(true);
  const int threads = at::get_num_threads();
  at::set_num_threads(2);
  torch::NoGradGuard no_grad;
  auto y = chunked_mlp(in[0], in[1], in[2], in[3], in[4]);
  at::set_num_threads(threads);
  EXPECT_FALSE(y.requires_grad());
  EXPECT_TRUE(torch::allclose(
      y, torch::linear(torch::relu(torch::linear(in[0], in[1], in[2])), in[3], in[4]), 1e-5, 1e-5));
}

// Degenerate matrices for the direct BLAS calls: one output (dy^T is [1, n]), one hidden unit,
// chunks of one row; values and all five gradients as libtorch's.
TEST(ChunkedMlp, OneOutputOneHiddenUnitAndOneRowChunks) {
  torch::manual_seed(11);
  for (auto [rows, hidden, outputs] : {std::array<int64_t, 3>{1025, 6, 1}, {3, 1, 4}, {1, 1, 1}}) {
    const auto d = torch::kDouble;
    std::vector<torch::Tensor> in = {torch::randn({rows, 9}, d), torch::randn({hidden, 9}, d),
                                     torch::randn({hidden}, d), torch::randn({outputs, hidden}, d),
                                     torch::randn({outputs}, d)};
    auto upstream = torch::randn({rows, outputs}, d);
    auto ref = mlp_and_grads(in, upstream, false);
    auto got = mlp_and_grads(in, upstream, true);
    for (size_t i = 0; i < ref.size(); ++i)
      EXPECT_TRUE(torch::allclose(got[i], ref[i], 1e-12, 1e-12))
          << rows << " rows, " << hidden << " hidden, " << outputs << " outputs: tensor " << i;
  }
}

// The chunks call BLAS directly with the bias written first, as at::addmm does: the forward is
// libtorch's bit for bit (so the training arithmetic did not change with that).
TEST(ChunkedMlp, ForwardIsLibtorchsBitForBit) {
  torch::manual_seed(10);
  for (int64_t rows : {1, 1024, 3000}) {
    auto in = random_mlp(rows, torch::kFloat);
    torch::NoGradGuard no_grad;
    const auto got = chunked_mlp(in[0], in[1], in[2], in[3], in[4]);
    // Row chunks of 1024, as chunked_mlp cuts them: a GEMM's rows do not change each other.
    std::vector<torch::Tensor> parts;
    for (int64_t first = 0; first < rows; first += 1024) {
      const auto x = in[0].narrow(0, first, std::min<int64_t>(1024, rows - first));
      parts.push_back(
          torch::addmm(in[4], torch::relu(torch::addmm(in[2], x, in[1].t())), in[3].t()));
    }
    EXPECT_TRUE(torch::equal(got, torch::cat(parts))) << "rows " << rows;
  }
}

TEST(ChunkedMlp, SameResultsWithOneAndTwoThreads) {
  torch::manual_seed(9);
  auto in = random_mlp(5000, torch::kFloat);
  auto upstream = torch::randn({5000, 4});
  const int threads = at::get_num_threads();
  at::set_num_threads(1);
  auto one = mlp_and_grads(in, upstream, true);
  at::set_num_threads(2);
  auto two = mlp_and_grads(in, upstream, true);
  at::set_num_threads(threads);
  for (size_t i = 0; i < one.size(); ++i) EXPECT_TRUE(torch::equal(one[i], two[i])) << i;
}

TEST(ChunkedMlp, RefusesShapesThatDoNotChain) {
  auto in = random_mlp(4, torch::kFloat);
  EXPECT_THROW(chunked_mlp(in[0], in[3], in[2], in[1], in[4]), c10::Error);
}

// sparse_mlp's output and gradients (of sum(upstream * y)), or the dense MLP's selected rows.
std::vector<torch::Tensor> sparse_and_grads(const std::vector<torch::Tensor>& in0,
                                            const torch::Tensor& row, const torch::Tensor& slot,
                                            int64_t O, const torch::Tensor& upstream, bool sparse,
                                            bool x_grad = true) {
  std::vector<torch::Tensor> in;
  for (size_t i = 0; i < in0.size(); ++i)
    in.push_back(in0[i].clone().requires_grad_(i > 0 || x_grad));
  const int64_t K = in[3].size(0) / O;
  auto y = sparse ? sparse_mlp(in[0], in[1], in[2], in[3], in[4], row, slot, O)
                  : torch::linear(torch::relu(torch::linear(in[0], in[1], in[2])), in[3], in[4])
                        .reshape({-1, O})
                        .index_select(0, row * K + slot);
  (y * upstream).sum().backward();
  std::vector<torch::Tensor> out{y.detach()};
  for (auto& t : in) out.push_back(t.grad());
  return out;
}

// `rows` anchors, K = 10 slots of O outputs; every third anchor has no Gaussian, the others a
// random subset of their slots.
struct SparseCase {
  std::vector<torch::Tensor> in;
  torch::Tensor row, slot;
  SparseCase(int64_t rows, int64_t O) {
    in = {torch::randn({rows, 9}), torch::randn({6, 9}), torch::randn({6}),
          torch::randn({10 * O, 6}), torch::randn({10 * O})};
    auto kept = torch::rand({rows, 10}) < 0.3;
    kept.index_put_({torch::arange(0, rows, 3)}, false);
    auto flat = kept.reshape({-1}).nonzero().squeeze(1);
    row = flat.div(10, "floor");
    slot = flat.remainder(10);
  }
};

TEST(SparseMlp, SameValuesAndGradientsAsTheDenseMlpsSelectedOutputs) {
  torch::manual_seed(10);
  for (int64_t O : {3, 7, 8})
    for (int64_t rows : {1, 5, 1024, 2500, 0}) {
      SparseCase c(rows, O);
      auto upstream = torch::randn({c.row.numel(), O});
      auto ref = sparse_and_grads(c.in, c.row, c.slot, O, upstream, false);
      auto got = sparse_and_grads(c.in, c.row, c.slot, O, upstream, true);
      for (size_t i = 0; i < ref.size(); ++i) {
        ASSERT_TRUE(got[i].defined()) << O << " outputs, " << rows << " rows, tensor " << i;
        EXPECT_EQ(got[i].sizes(), ref[i].sizes()) << O << " outputs, " << rows << " rows, " << i;
        EXPECT_TRUE(torch::allclose(got[i], ref[i], 1e-4, 1e-4))
            << O << " outputs, " << rows << " rows, tensor " << i << ": max diff "
            << (got[i] - ref[i]).abs().max().item<float>();
      }
    }
  // An input that needs no gradient: the same weight gradients.
  SparseCase c(3000, 7);
  auto up = torch::randn({c.row.numel(), 7});
  auto ref = sparse_and_grads(c.in, c.row, c.slot, 7, up, false, false);
  auto got = sparse_and_grads(c.in, c.row, c.slot, 7, up, true, false);
  for (size_t i = 2; i < ref.size(); ++i)
    EXPECT_TRUE(torch::allclose(got[i], ref[i], 1e-4, 1e-4)) << "tensor " << i;
  // Without autograd, on two threads, with parameters that require gradients.
  for (size_t i = 1; i < c.in.size(); ++i) c.in[i].requires_grad_(true);
  const int threads = at::get_num_threads();
  at::set_num_threads(2);
  torch::NoGradGuard no_grad;
  auto y = sparse_mlp(c.in[0], c.in[1], c.in[2], c.in[3], c.in[4], c.row, c.slot, 7);
  at::set_num_threads(threads);
  EXPECT_TRUE(torch::allclose(
      y,
      torch::linear(torch::relu(torch::linear(c.in[0], c.in[1], c.in[2])), c.in[3], c.in[4])
          .reshape({-1, 7})
          .index_select(0, c.row * 10 + c.slot),
      1e-4, 1e-4));
}

// What tensors off the CPU run (a GPU): the libtorch forms, against the CPU kernels.
TEST(MlpReference, SameValuesAndGradientsAsTheCpuKernels) {
  torch::manual_seed(12);
  SparseCase c(2500, 7);
  auto up_sparse = torch::randn({c.row.numel(), 7});
  auto mlp = random_mlp(2500, torch::kFloat);
  auto up_dense = torch::randn({2500, 4});
  auto run = [](const std::vector<torch::Tensor>& in0, const torch::Tensor& upstream,
                const std::function<torch::Tensor(const std::vector<torch::Tensor>&)>& f) {
    std::vector<torch::Tensor> in;
    for (const auto& t : in0) in.push_back(t.clone().requires_grad_(true));
    auto y = f(in);
    (y * upstream).sum().backward();
    std::vector<torch::Tensor> out{y.detach()};
    for (auto& t : in) out.push_back(t.grad());
    return out;
  };
  const auto kernel = run(
      mlp, up_dense, [](const auto& in) { return chunked_mlp(in[0], in[1], in[2], in[3], in[4]); });
  const auto ref = run(mlp, up_dense, [](const auto& in) {
    return chunked_mlp_reference(in[0], in[1], in[2], in[3], in[4]);
  });
  const auto sparse_kernel = run(c.in, up_sparse, [&](const auto& in) {
    return sparse_mlp(in[0], in[1], in[2], in[3], in[4], c.row, c.slot, 7);
  });
  const auto sparse_ref = run(c.in, up_sparse, [&](const auto& in) {
    return sparse_mlp_reference(in[0], in[1], in[2], in[3], in[4], c.row, c.slot, 7);
  });
  for (size_t i = 0; i < ref.size(); ++i) {
    EXPECT_TRUE(torch::allclose(kernel[i], ref[i], 1e-4, 1e-4)) << "dense tensor " << i;
    EXPECT_TRUE(torch::allclose(sparse_kernel[i], sparse_ref[i], 1e-4, 1e-4))
        << "sparse tensor " << i << ": max diff "
        << (sparse_kernel[i] - sparse_ref[i]).abs().max().item<float>();
  }
}

TEST(SparseMlp, SameResultsWithOneAndTwoThreads) {
  torch::manual_seed(11);
  SparseCase c(5000, 7);
  auto upstream = torch::randn({c.row.numel(), 7});
  const int threads = at::get_num_threads();
  at::set_num_threads(1);
  auto one = sparse_and_grads(c.in, c.row, c.slot, 7, upstream, true);
  at::set_num_threads(2);
  auto two = sparse_and_grads(c.in, c.row, c.slot, 7, upstream, true);
  at::set_num_threads(threads);
  for (size_t i = 0; i < one.size(); ++i) EXPECT_TRUE(torch::equal(one[i], two[i])) << i;
}

TEST(SparseMlp, RefusesRowsAndSlotsItCannotUse) {
  SparseCase c(4, 3);
  auto call = [&](std::vector<int64_t> row, std::vector<int64_t> slot, int64_t O = 3) {
    sparse_mlp(c.in[0], c.in[1], c.in[2], c.in[3], c.in[4], torch::tensor(row, torch::kLong),
               torch::tensor(slot, torch::kLong), O);
  };
  EXPECT_NO_THROW(call({0, 1, 3}, {0, 9, 2}));
  EXPECT_THROW(call({1, 0}, {0, 0}), c10::Error);      // decreasing rows
  EXPECT_THROW(call({0, 4}, {0, 0}), c10::Error);      // row out of range
  EXPECT_THROW(call({0, 1}, {0, 10}), c10::Error);     // slot out of range
  EXPECT_THROW(call({0, 1}, {0}), c10::Error);         // lengths differ
  EXPECT_THROW(call({0, 1}, {0, 0}, 10), c10::Error);  // more outputs than lanes (30 = 3 x 10)
}

TEST(GatherSortedRows, RefusesAnIndexItsBackwardCannotUse) {
  auto src = torch::randn({6, 2}).requires_grad_(true);
  for (const std::vector<int64_t>& bad :
       std::vector<std::vector<int64_t>>{{0, 3, 2}, {1, 6}, {-1, 2}}) {
    try {
      gather_sorted_rows(src, torch::tensor(bad, torch::kLong));
      ADD_FAILURE() << "accepted index " << torch::tensor(bad);
    } catch (const c10::Error& e) {
      EXPECT_NE(std::string(e.what()).find("gather_sorted_rows"), std::string::npos) << e.what();
    }
  }
}

// Anchor growing's pooled parent features: the CPU loop and the scatter_reduce that other
// devices run, with an empty cell (-inf) and repeated cells.
TEST(MaxRowsInto, LoopAndReferenceAgree) {
  torch::manual_seed(13);
  auto src = torch::randn({200, 7});
  auto cell = torch::randint(0, 40, {200}, torch::kLong);
  cell.masked_fill_(cell == 5, 6);  // cell 5 stays empty
  const auto got = max_rows_into(src, cell, 41);
  EXPECT_TRUE(torch::equal(got, max_rows_into_reference(src, cell, 41)));
  EXPECT_TRUE(torch::isinf(got[5]).all().item<bool>());
  EXPECT_TRUE(torch::isinf(got[40]).all().item<bool>());
  const auto rows6 = src.index({cell == 6});
  EXPECT_TRUE(torch::equal(got[6], std::get<0>(rows6.max(0))));
  EXPECT_THROW(max_rows_into(src, cell, 30), c10::Error);  // a cell out of range
}

struct SmallScene {
  Dataset ds;
  std::shared_ptr<Rasterizer> raster = std::make_shared<raster::CpuRasterizer>(1);
  SmallScene() {
    SyntheticSceneOptions o;
    o.width = 48;
    o.height = 36;
    o.views = 8;
    o.sfm_points = 1500;
    auto s = generate_scene(o, *raster);
    if (!s.ok()) throw StatusError(s.status());
    ds = std::move(s).value();
  }
  AnchorInit init() const {
    AnchorInit in;
    for (const auto& p : ds.points) in.points.push_back({p.x(), p.y(), p.z()});
    for (const auto& v : ds.train) in.train_cameras.push_back(v.camera);
    return in;
  }
};

AnchorModelOptions small_options() {
  AnchorModelOptions o;
  o.voxel_size = 0.1;
  return o;
}

std::unique_ptr<AnchorModel> make_model(const SmallScene& s, const AnchorModelOptions& o,
                                        uint64_t seed = 3) {
  auto m = AnchorModel::create(o, identity_feature_model(50), s.init(),
                               at::make_generator<at::CPUGeneratorImpl>(seed));
  if (!m.ok()) throw StatusError(m.status());
  return std::move(m).value();
}

// Runs `n` render/backward/statistics/Adam iterations over the training views.
void accumulate(AnchorModel& m, SmallScene& s, int n, double zoom = 1.0) {
  RenderSettings rs;
  for (int i = 0; i < n; ++i) {
    const View& v = s.ds.train[size_t(i) % s.ds.train.size()];
    Camera cam = v.camera;
    cam.fx *= zoom;  // a narrower view sees only part of the anchors
    cam.fy *= zoom;
    auto g = m.generate(cam, int(i % s.ds.train.size()), *s.raster, rs, true);
    auto out = s.raster->render(g.batch, cam, rs);
    auto gt = torch::from_blob(const_cast<float*>(v.image.pixels.data()),
                               {v.image.height, v.image.width, 3});
    (out.image - gt).abs().mean().backward();
    m.accumulate_statistics(g, out, cam);
    m.optimizer_step();
  }
}

TEST(MeanSqDist3nn, MatchesBruteForce) {
  auto pts = torch::rand({700, 3}) * torch::tensor({4.f, 2.f, 0.05f});  // nearly planar
  auto fast = mean_sq_dist_3nn(pts);
  auto d2 = (pts.unsqueeze(1) - pts.unsqueeze(0)).pow(2).sum(-1);  // exact, unlike cdist
  d2.fill_diagonal_(std::numeric_limits<float>::infinity());
  auto brute = std::get<0>(d2.topk(3, 1, /*largest=*/false)).mean(1).clamp_min(1e-7);
  EXPECT_TRUE(torch::allclose(fast, brute, 1e-4, 1e-7))
      << "max abs diff " << (fast - brute).abs().max().item<float>();
}

TEST(AnchorModel, InitVoxelisesPointsWithoutDuplicates) {
  SmallScene s;
  auto m = make_model(s, small_options());
  auto a = m->anchors();
  ASSERT_GT(a.size(0), 100);
  auto cells = torch::round(a / 0.1);
  EXPECT_TRUE(torch::allclose(cells * 0.1, a, 0, 1e-5)) << "anchors must lie on the voxel grid";
  EXPECT_EQ(std::get<0>(at::unique_dim(cells, 0)).size(0), a.size(0));
  // scaling = log(sqrt(mean sq 3-NN distance)), same in all 6 components.
  auto expect = torch::log(torch::sqrt(mean_sq_dist_3nn(a)));
  EXPECT_TRUE(torch::allclose(m->scaling_raw().select(1, 0), expect, 1e-5, 1e-6));
  EXPECT_TRUE(torch::equal(m->scaling_raw().select(1, 5), m->scaling_raw().select(1, 0)));
  EXPECT_EQ(m->offsets().sizes(), (std::vector<int64_t>{a.size(0), 10, 3}));
  EXPECT_EQ(m->mask_logits().sizes(), (std::vector<int64_t>{a.size(0), 10}));
  EXPECT_EQ(m->features().abs().sum().item<float>(), 0.f);
}

TEST(AnchorModel, RandomInitWithoutPoints) {
  SmallScene s;
  s.ds.points.clear();
  auto o = small_options();
  o.random_init_points = 500;
  auto m = make_model(s, o);
  EXPECT_GT(m->num_anchors(), 100);
  EXPECT_LE(m->num_anchors(), 500);
  // Every anchor is in front of some training camera and inside its image, give or take the
  // voxel rounding (a margin of a quarter image): an anchor no view sees could never be trained.
  const auto a = m->anchors();
  for (int64_t i = 0; i < a.size(0); ++i) {
    const Eigen::Vector3d p(a[i][0].item<double>(), a[i][1].item<double>(), a[i][2].item<double>());
    bool seen = false;
    for (const auto& v : s.ds.train) {
      const Camera& c = v.camera;
      const Eigen::Vector3d q = c.R * p + c.t;
      const double u = c.fx * q.x() / q.z() + c.cx, w = c.fy * q.y() / q.z() + c.cy;
      seen = seen || (q.z() > 0 && u > -0.25 * c.width && u < 1.25 * c.width &&
                      w > -0.25 * c.height && w < 1.25 * c.height);
    }
    ASSERT_TRUE(seen) << "anchor " << i << " at " << p.transpose() << " is seen by no view";
  }
}

// Guards against computing (and paying for) effects the scene did not ask for.
TEST(AnchorModel, EffectsThatAreOffAreNotComputed) {
  SmallScene s;
  RenderSettings rs;
  const Camera& cam = s.ds.train[0].camera;
  {
    auto m = make_model(s, small_options());  // HAC defaults: dir + dist
    EXPECT_EQ(m->mlp_input_dim(), 54);
    EXPECT_EQ(m->color_input_dim(), 54);
    for (const auto& p : m->named_parameters()) EXPECT_NE(p.first, "appearance");
    EXPECT_EQ(m->generate(cam, 0, *s.raster, rs, false).input.size(1), 54);
  }
  {
    auto o = small_options();
    o.effects.view_dependent = false;
    o.effects.distance_input = false;
    auto m = make_model(s, o);
    EXPECT_EQ(m->mlp_input_dim(), 50);
    EXPECT_EQ(m->color_input_dim(), 50);
    EXPECT_EQ(m->generate(cam, 0, *s.raster, rs, false).input.size(1), 50);
  }
  {
    auto o = small_options();
    o.effects.view_dependent = false;
    o.effects.appearance_dim = 8;
    auto m = make_model(s, o);
    EXPECT_EQ(m->mlp_input_dim(), 51);
    EXPECT_EQ(m->color_input_dim(), 59);
    bool has_app = false;
    for (const auto& p : m->named_parameters())
      if (p.first == "appearance") {
        has_app = true;
        EXPECT_EQ(p.second.sizes(), (std::vector<int64_t>{int64_t(s.ds.train.size()), 8}));
      }
    EXPECT_TRUE(has_app);
  }
}

TEST(AnchorModel, GeneratedGaussiansFollowTheFormulas) {
  SmallScene s;
  auto m = make_model(s, small_options());
  RenderSettings rs;
  auto g = m->generate(s.ds.train[0].camera, 0, *s.raster, rs, false);
  const int64_t G = g.batch.means.size(0);
  ASSERT_GT(G, 0);
  EXPECT_EQ(g.selection.sum().item<int64_t>(), G);
  EXPECT_TRUE((g.batch.opacities > 0).all().item<bool>()) << "only opacity > 0 is spawned";
  // Offsets are 0 at init, so every Gaussian sits on its anchor.
  auto anchor_of = g.source.div(10, "floor");
  EXPECT_TRUE(torch::allclose(g.batch.means, m->anchors().index_select(0, anchor_of)));
  auto base = torch::exp(m->scaling_raw().index_select(0, anchor_of).slice(1, 3, 6));
  EXPECT_TRUE((g.batch.scales <= base + 1e-6).all().item<bool>());
  EXPECT_TRUE(torch::allclose(g.batch.rotations.norm(2, 1), torch::ones({G}), 1e-5, 1e-5));
}

TEST(AnchorModel, GrowingAddsAnchorsOnFreeCellsOnly) {
  SmallScene s;
  auto o = small_options();
  o.densify_grad_threshold = 0;  // every Gaussian seen often enough is a candidate
  o.min_opacity = 0;             // no pruning
  // Cells 4v, 2v, v: with HAC's 16v the coarse cells of this small scene are all occupied.
  o.voxel_size = 0.05;
  o.update_init_factor = 4;
  o.update_hierarchy_factor = 2;
  auto m = make_model(s, o);
  accumulate(*m, s, 12);  // offsets moved by Adam, so candidates leave their anchors' cells
  const int64_t before = m->num_anchors();
  auto rep = m->adjust_anchors(/*check_interval=*/10, at::make_generator<at::CPUGeneratorImpl>(5));
  const int64_t N = m->num_anchors();
  EXPECT_GT(rep.grown, 0);
  EXPECT_EQ(rep.pruned, 0);
  EXPECT_EQ(N, before + rep.grown);
  // No two anchors share a position (new ones sit on cells that held no anchor).
  EXPECT_EQ(std::get<0>(at::unique_dim(m->anchors(), 0)).size(0), N);
  auto st = m->state_dict();
  for (const char* g : {"feature", "offset", "scaling", "mask"}) {
    EXPECT_EQ(st.at(std::string("param.") + g).size(0), N) << g;
    EXPECT_EQ(st.at(std::string("adam_m.") + g).sizes(), st.at(std::string("param.") + g).sizes());
    EXPECT_EQ(st.at(std::string("adam_v.") + g).sizes(), st.at(std::string("param.") + g).sizes());
    // New rows start with zero moments.
    EXPECT_EQ(st.at(std::string("adam_m.") + g).slice(0, before).abs().sum().item<float>(), 0.f);
  }
  EXPECT_EQ(st.at("stat.offset_denom").size(0), N * 10);
  EXPECT_EQ(st.at("stat.anchor_demon").size(0), N);
  // Statistics used by this step were reset.
  EXPECT_LE(st.at("stat.offset_denom").max().item<float>(), 10 * 0.8 * 0.5);
  EXPECT_LE(st.at("stat.anchor_demon").max().item<float>(), 10 * 0.8);
  // New anchors: offsets 0, mask logits 1, scaling = log(cell size) for a level's cell.
  EXPECT_EQ(m->offsets().slice(0, before).abs().sum().item<float>(), 0.f);
  EXPECT_TRUE(torch::equal(m->mask_logits().slice(0, before), torch::ones({N - before, 10})));
}

TEST(AnchorModel, PruningRemovesAnchorsWithAllTheirState) {
  SmallScene s;
  auto o = small_options();
  o.densify_grad_threshold = 1e9;  // no growing
  o.min_opacity = 1.0;             // every anchor seen often enough is pruned
  auto m = make_model(s, o);
  accumulate(*m, s, 10, /*zoom=*/4.0);
  auto st0 = m->state_dict();
  auto survivors = (st0.at("stat.anchor_demon") <= 10 * 0.8).nonzero().squeeze(1);
  ASSERT_GT(survivors.size(0), 0);
  ASSERT_LT(survivors.size(0), m->num_anchors());
  auto rep = m->adjust_anchors(10, at::make_generator<at::CPUGeneratorImpl>(5));
  EXPECT_EQ(rep.grown, 0);
  EXPECT_EQ(m->num_anchors(), survivors.size(0));
  auto st = m->state_dict();
  EXPECT_TRUE(torch::equal(st.at("anchor"), st0.at("anchor").index_select(0, survivors)));
  for (const char* g : {"feature", "offset", "mask"})
    for (const char* kind : {"param.", "adam_m.", "adam_v."}) {
      const std::string k = std::string(kind) + g;
      EXPECT_TRUE(torch::equal(st.at(k), st0.at(k).index_select(0, survivors))) << k;
    }
  EXPECT_TRUE(
      torch::equal(st.at("adam_m.scaling"), st0.at("adam_m.scaling").index_select(0, survivors)));
  EXPECT_TRUE(torch::equal(st.at("stat.opacity_accum"),
                           st0.at("stat.opacity_accum").index_select(0, survivors)));
  EXPECT_EQ(st.at("stat.offset_denom").size(0), survivors.size(0) * 10);
  // The HAC clamp of the base scales after pruning.
  EXPECT_LE(m->scaling_raw().slice(1, 3, 6).max().item<float>(), 0.05f);
}

TEST(AnchorModel, OptimizerStepIsTorchAdam) {
  SmallScene s;
  auto m = make_model(s, small_options());
  std::vector<torch::Tensor> mirror;
  std::vector<torch::optim::OptimizerParamGroup> groups;
  for (const auto& [name, p] : m->named_parameters()) {
    mirror.push_back(p.detach().clone().requires_grad_(true));
    groups.emplace_back(
        std::vector<torch::Tensor>{mirror.back()},
        std::make_unique<torch::optim::AdamOptions>(
            torch::optim::AdamOptions(m->learning_rate(name)).betas({0.9, 0.999}).eps(1e-15)));
  }
  torch::optim::Adam reference(groups);
  torch::manual_seed(4);
  for (int step = 0; step < 4; ++step) {  // bias corrections differ per step
    size_t i = 0;
    for (const auto& [name, p] : m->named_parameters()) {
      auto g = torch::randn(p.sizes()) * (i % 2 ? 1e-6 : 1.0);  // tiny gradients too
      p.mutable_grad() = g;
      mirror[i++].mutable_grad() = g.clone();
    }
    m->optimizer_step();
    reference.step();
    i = 0;
    for (const auto& [name, p] : m->named_parameters()) {
      EXPECT_FALSE(p.grad().defined()) << name;
      EXPECT_TRUE(torch::allclose(p, mirror[i++], 1e-5, 1e-7)) << name << " step " << step;
    }
  }
}

TEST(AnchorModel, StateDictRoundTripRestoresEverything) {
  SmallScene s;
  auto m = make_model(s, small_options());
  accumulate(*m, s, 3);
  auto st = m->state_dict();
  auto m2 = make_model(s, small_options(), /*seed=*/99);  // different MLP init
  ASSERT_TRUE(m2->load_state_dict(st).ok());
  auto st2 = m2->state_dict();
  ASSERT_EQ(st.size(), st2.size());
  for (const auto& kv : st) EXPECT_TRUE(torch::equal(kv.second, st2.at(kv.first))) << kv.first;
}

TEST(AnchorModel, RefusedStateDictLeavesTheModelUnchanged) {
  SmallScene s;
  auto m = make_model(s, small_options());
  accumulate(*m, s, 3);
  const auto good = m->state_dict();
  auto other = make_model(s, small_options(), /*seed=*/99);
  auto before = other->state_dict();  // copies: a load into the live tensors shows too
  for (auto& kv : before) kv.second = kv.second.clone();
  auto last = good.end();
  --last;  // a key a loader that commits as it reads would meet after the others
  const int64_t n = good.at("anchor").size(0);
  std::vector<std::pair<std::string, std::map<std::string, torch::Tensor>>> broken;
  auto with = [&](const std::string& what, const std::string& key, torch::Tensor t) {
    auto b = good;
    if (t.defined())
      b[key] = t;
    else
      b.erase(key);
    broken.emplace_back(what, b);
  };
  with("missing last key", last->first, {});
  with("last key reshaped", last->first, last->second.reshape({-1, 1}));
  with("feature rows != anchors", "param.feature", good.at("param.feature").slice(0, 0, n - 1));
  with("adam moment shape", "adam_m.offset", good.at("adam_m.offset").slice(0, 0, n - 1));
  with("stat rows", "stat.offset_denom", good.at("stat.offset_denom").slice(0, 1));
  with("double anchors", "anchor", good.at("anchor").to(torch::kDouble));
  with("zero voxel", "voxel_size", torch::tensor(0.0, torch::kDouble));
  with("links without a link strategy", "links", torch::full({n}, -1, torch::kLong));
  for (const auto& [what, state] : broken) {
    Status st = other->load_state_dict(state);
    EXPECT_FALSE(st.ok()) << what;
    const auto after = other->state_dict();
    ASSERT_EQ(after.size(), before.size()) << what;
    for (const auto& kv : before)
      EXPECT_TRUE(torch::equal(kv.second, after.at(kv.first))) << what << ": " << kv.first;
  }
  EXPECT_TRUE(other->load_state_dict(good).ok());
}

}  // namespace
}  // namespace crpgs
