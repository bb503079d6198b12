/// @file shared_prefix.cpp
#include "crpgs/shared_prefix.h"

#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <string>

#include "crpgs/hashing.h"

namespace crpgs {

std::string shared_prefix_key(const Config& resolved) {
  if (!resolved.section("context")) return "";
  // Keys added after runs were published, at their defaults, are left out: the keys of those
  // runs stay those of the builds before the keys existed, whose published prefixes and running
  // sweeps they continue.
  YAML::Node tree = YAML::Load(resolved.dump());
  for (const auto& [key, default_value] : {std::pair<const char*, const char*>{"device", "cpu"},
                                           {"feature_model_start", "start"},
                                           {"feature_model_hold_lr_scale", "0"}})
    if (tree["train"] && tree["train"][key] &&
        tree["train"][key].as<std::string>() == default_value)
      tree["train"].remove(key);
  YAML::Emitter out;
  out << tree;
  auto blanked = Config::from_string(out.c_str(), "<prefix key>");
  if (!blanked.ok()) return "";
  // Thread counts are not part of the training either (like the BLAS kernels, they change only
  // the last bits): a sweep run on other thread counts continues the same prefixes.
  for (const char* key :
       {"rate.lambda=0", "rate.mask_lambda=0", "train.threads=0", "rasterizer.threads=0"})
    if (!blanked->apply_override(key).ok()) return "";
  return hex64(blanked->hash());
}

std::string shared_prefix_path(const std::string& dir, const std::string& key) {
  return (std::filesystem::path(dir) / (key + ".pt")).string();
}

}  // namespace crpgs
