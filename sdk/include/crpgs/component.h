/// @file component.h
/// @brief The base of every swappable component and the four family interfaces' common part.
#pragma once

#include <string>
#include <vector>

#include <torch/types.h>
#include <yaml-cpp/yaml.h>

namespace crpgs {

class Component {
 public:
  virtual ~Component() = default;
  /// The YAML `type:` this object was built from.
  virtual std::string type_name() const = 0;
  /// The resolved configuration, written from the object's own members (not a stored copy), so
  /// building a new component from it gives an identical object.
  virtual YAML::Node hyperparams() const = 0;
  /// Trainable tensors (may be empty).
  virtual std::vector<torch::Tensor> parameters() { return {}; }
};

}  // namespace crpgs
