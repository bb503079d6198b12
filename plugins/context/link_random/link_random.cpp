/// @file link_random.cpp
/// @brief Context plugin `link_random`: the ablation "COHS replaced by a random link". A
/// uniformly random one-to-one pairing of the active anchors, reproducible from
/// LinkInputs::seed; same one-to-one, one-hop link form as `link_cohs`.
#include <stdexcept>

#include <torch/types.h>

#include "crpgs/context_model.h"
#include "crpgs/links.h"
#include "crpgs/plugin.h"

namespace crpgs {
namespace {

constexpr const char* kSchema = R"yaml(
- {key: leaf_fraction, type: float, default: 0.5, min: 0, max: 0.5, doc: "leaves as a fraction of the active anchors (0.5: every active anchor paired, the COHS upper bound)"}
)yaml";

class LinkRandom final : public ContextModel {
 public:
  LinkRandom(const YAML::Node& c, const crpgs_create_args&)
      : leaf_fraction_(c["leaf_fraction"].as<double>()) {}
  std::string type_name() const override { return "link_random"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    n["leaf_fraction"] = leaf_fraction_;
    return n;
  }
  torch::Tensor build_links(const LinkInputs& in) override {
    auto active =
        in.active.defined() ? in.active : torch::ones({in.features.size(0)}, torch::kBool);
    auto links = random_links(active, in.seed, leaf_fraction_);
    if (!links.ok()) throw std::invalid_argument(links.status().to_string());
    return links.value();
  }

 private:
  double leaf_fraction_;
};

}  // namespace
}  // namespace crpgs

CRPGS_PLUGIN(CRPGS_KIND_CONTEXT, crpgs::ContextModel, crpgs::LinkRandom,
             "org.crpgs.context.link_random", "link_random", 1, 0, crpgs::kSchema)
