/// @file sections.cpp
/// @brief Schemas of the core (non-component) config sections: dataset, scene, model, train.
/// Torch-free (part of crpgs_base) so `crpgs config check` validates without building anything.
#include "crpgs/config.h"

namespace crpgs {
namespace {

ParamSpec P(const char* key, ParamType type, YAML::Node def, const char* doc) {
  ParamSpec p;
  p.key = key;
  p.type = type;
  p.default_value = def;
  p.doc = doc;
  return p;
}
ParamSpec range(ParamSpec p, std::optional<double> lo, std::optional<double> hi) {
  p.min = lo;
  p.max = hi;
  return p;
}
ParamSpec choice(ParamSpec p, std::vector<std::string> choices) {
  p.type = ParamType::kChoice;
  p.choices = std::move(choices);
  return p;
}

}  // namespace

const std::vector<CoreSection>& core_sections() {
  using T = ParamType;
  static const std::vector<CoreSection> sections = {
      {"dataset",
       Schema({
           P("path", T::kString, YAML::Node(""), "dataset root; empty = the built-in synthetic scene"),
           choice(P("format", T::kChoice, YAML::Node("auto"), "dataset format"),
                  {"auto", "colmap", "nerf_synthetic", "instant_ngp", "llff", "synthetic"}),
           P("images", T::kString, YAML::Node(""), "image folder; empty = format default"),
           range(P("downscale", T::kInt, YAML::Node(1), "integer downscale factor on load"), 1, 64),
           range(P("max_width", T::kInt, YAML::Node(0), ">0: downscale so width <= this"), 0, 1e5),
           range(P("test_every", T::kInt, YAML::Node(8), "every Nth image is a test view; 0 = none"),
                 0, 1e6),
       })},
  };
  return sections;
}

}  // namespace crpgs
