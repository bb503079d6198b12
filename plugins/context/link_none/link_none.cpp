/// @file link_none.cpp
/// @brief The null link strategy: no anchor is conditioned on another (every link is −1), so
/// every anchor uses the base entropy model. The ablation "COHS replaced by no link".
#include <torch/types.h>

#include "crpgs/context_model.h"
#include "crpgs/plugin.h"

namespace crpgs {
namespace {

class LinkNone final : public ContextModel {
 public:
  LinkNone(const YAML::Node&, const crpgs_create_args&) {}
  std::string type_name() const override { return "link_none"; }
  YAML::Node hyperparams() const override {
    YAML::Node n;
    n["type"] = type_name();
    return n;
  }
  torch::Tensor build_links(const LinkInputs& in) override {
    return torch::full({in.features.size(0)}, -1, torch::kLong);
  }
};

}  // namespace
}  // namespace crpgs

CRPGS_PLUGIN(CRPGS_KIND_CONTEXT, crpgs::ContextModel, crpgs::LinkNone,
             "org.crpgs.context.link_none", "link_none", 1, 0, "[]")
