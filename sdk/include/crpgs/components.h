/// @file components.h
/// @brief Typed creation of components from a registry and a resolved config.
#pragma once

#include <memory>

#include "crpgs/config.h"
#include "crpgs/context_model.h"
#include "crpgs/entropy_model.h"
#include "crpgs/feature_model.h"
#include "crpgs/rasterizer.h"
#include "crpgs/registry.h"

namespace crpgs {

template <typename T>
struct KindOf;
template <>
struct KindOf<EntropyModel> {
  static constexpr crpgs_kind value = CRPGS_KIND_ENTROPY;
};
template <>
struct KindOf<ContextModel> {
  static constexpr crpgs_kind value = CRPGS_KIND_CONTEXT;
};
template <>
struct KindOf<FeatureModel> {
  static constexpr crpgs_kind value = CRPGS_KIND_FEATURES;
};
template <>
struct KindOf<Rasterizer> {
  static constexpr crpgs_kind value = CRPGS_KIND_RASTERIZER;
};

/// Creates the component of family T from a resolved config block ({type: ..., ...}).
template <typename T>
StatusOr<std::shared_ptr<T>> create_component(const ComponentRegistry& registry,
                                              const YAML::Node& resolved_block,
                                              const crpgs_create_args& args) {
  auto raw = registry.create_raw(KindOf<T>::value, resolved_block, args);
  if (!raw.ok()) return raw.status();
  return std::static_pointer_cast<T>(std::move(raw).value());
}

/// The built-in `identity` feature model of width `feature_dim` (plain HAC: the MLPs see the
/// coded feature itself).
std::shared_ptr<FeatureModel> identity_feature_model(int feature_dim);

/// A registry holding the built-in components (cpu rasterizer, identity features, ...).
ComponentRegistry builtin_registry();

/// The default crpgs_create_args for a resolved config (feature_dim, n_offsets, device).
crpgs_create_args create_args_for(const Config& resolved);

}  // namespace crpgs
