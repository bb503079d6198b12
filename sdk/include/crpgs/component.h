/// @file component.h
/// @brief The base of every swappable component and the four family interfaces' common part.
#pragma once

#include <cstdint>
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
  /// Training-time estimate of the bits this component itself adds to the bitstream (e.g. a
  /// binary hash grid's B_h, differentiable through its straight-through estimator); a scalar.
  /// Components whose state is not coded return 0.
  virtual torch::Tensor parameter_bits() { return torch::zeros({}); }
  /// The trained state as it goes into the bitstream (empty: nothing to store), and its inverse.
  /// load_state() must accept exactly what save_state() wrote and refuse anything else with a
  /// message (it is fed untrusted bytes).
  virtual std::vector<uint8_t> save_state() const { return {}; }
  virtual bool load_state(const std::vector<uint8_t>& bytes, std::string* error) {
    if (bytes.empty()) return true;
    if (error) *error = type_name() + ": this component stores no state";
    return false;
  }
};

}  // namespace crpgs
