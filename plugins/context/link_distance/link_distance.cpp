/// @file link_distance.cpp
/// @brief Context plugin `link_distance`: the ablation "COHS replaced by the nearest-anchor
/// link". Each active anchor, in index order, links to its nearest active anchor that is still
/// free (neither leaf nor root), among its M nearest; one greedy pass, no threshold. Same
/// one-to-one, one-hop link form as `link_cohs`.
#include <limits>

#include <stdexcept>

#include <torch/types.h>

#include "crpgs/context_model.h"
#include "crpgs/links.h"
#include "crpgs/plugin.h"

namespace crpgs {
namespace {

constexpr const char* kSchema = R"yaml(
- {key: candidates, type: int, default: 10, min: 1, max: 1024, doc: "M: nearest active anchors per anchor, self included"}
)yaml";

class LinkDistance final : public ContextModel {
 public:
  LinkDistance(const YAML::Node& c, const crpgs_create_args&) : m_(c["candidates"].as<int64_t>()) {}
  std::string type_name() const override { return "link_distance"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    n["candidates"] = m_;
    return n;
  }
  torch::Tensor build_links(const LinkInputs& in) override {
    auto cand = nearest_candidates(in.positions, in.active, m_);
    if (!cand.ok()) throw std::invalid_argument(cand.status().to_string());
    auto links = greedy_links(cand.value(), {-std::numeric_limits<double>::infinity()}, in.active);
    if (!links.ok()) throw std::invalid_argument(links.status().to_string());
    return links.value();
  }

 private:
  int64_t m_;
};

}  // namespace
}  // namespace crpgs

CRPGS_PLUGIN(CRPGS_KIND_CONTEXT, crpgs::ContextModel, crpgs::LinkDistance,
             "org.crpgs.context.link_distance", "link_distance", 1, 0, crpgs::kSchema)
