/// @file link_cohs.cpp
/// @brief Context plugin `link_cohs`: CRP-GS's cosine one-to-one hierarchical structure (COHS,
/// docs/method.md §6.2). Top-M cosine-similar active anchors over the raw coded features, then the
/// greedy one-to-one matching of Algorithm 1 with the decaying threshold tau_max .. tau_min.
#include <stdexcept>

#include <torch/types.h>

#include "crpgs/context_model.h"
#include "crpgs/links.h"
#include "crpgs/plugin.h"

namespace crpgs {
namespace {

constexpr const char* kSchema = R"yaml(
- {key: candidates, type: int, default: 10, min: 1, max: 1024, doc: "M: cosine-similar candidates per anchor, self included (paper: 10)"}
- {key: tau_max, type: float, default: 1.0, min: -1, max: 1, doc: "first similarity threshold (paper: 1.0)"}
- {key: tau_min, type: float, default: 0.8, min: -1, max: 1, doc: "last similarity threshold, inclusive (paper: 0.8)"}
- {key: tau_step, type: float, default: 0.05, min: 0, max: 2, min_exclusive: true, doc: "threshold decrement (paper: 0.05)"}
- {key: memory_mib, type: int, default: 256, min: 1, max: 1048576, doc: "bound of the [rows, N_active] similarity block of the chunked matmul, MiB"}
)yaml";

class LinkCohs final : public ContextModel {
 public:
  LinkCohs(const YAML::Node& c, const crpgs_create_args&)
      : m_(c["candidates"].as<int64_t>()),
        tau_max_(c["tau_max"].as<double>()),
        tau_min_(c["tau_min"].as<double>()),
        tau_step_(c["tau_step"].as<double>()),
        memory_mib_(c["memory_mib"].as<int64_t>()) {
    auto t = decaying_thresholds(tau_max_, tau_min_, tau_step_);
    if (!t.ok()) throw std::invalid_argument("link_cohs: " + t.status().message());
    thresholds_ = t.value();
  }
  std::string type_name() const override { return "link_cohs"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    n["candidates"] = m_;
    n["tau_max"] = tau_max_;
    n["tau_min"] = tau_min_;
    n["tau_step"] = tau_step_;
    n["memory_mib"] = memory_mib_;
    return n;
  }
  torch::Tensor build_links(const LinkInputs& in) override {
    auto cand = cosine_candidates(in.features, in.active, m_, memory_mib_ << 20);
    if (!cand.ok()) throw std::invalid_argument(cand.status().to_string());
    auto links = greedy_links(cand.value(), thresholds_, in.active);
    if (!links.ok()) throw std::invalid_argument(links.status().to_string());
    return links.value();
  }

 private:
  int64_t m_;
  double tau_max_, tau_min_, tau_step_;
  int64_t memory_mib_;
  std::vector<double> thresholds_;
};

}  // namespace
}  // namespace crpgs

CRPGS_PLUGIN(CRPGS_KIND_CONTEXT, crpgs::ContextModel, crpgs::LinkCohs,
             "org.crpgs.context.link_cohs", "link_cohs", 1, 0, crpgs::kSchema)
