/// @file portable_math.h
/// @brief Arithmetic that gives the same bits on every machine, for what decides a bitstream's
/// integers (the entropy parameters): IEEE-754 basic operations in a fixed order, no fused
/// multiply-add, no BLAS (its kernels sum in an order that depends on the CPU and on
/// OPENBLAS_CORETYPE) and no libm or vectorised transcendental functions.
#pragma once

#include <torch/types.h>

namespace crpgs {

/// exp(x) from IEEE basic operations only (relative error ~1e-15).
double portable_exp(double x);

/// x w^T + b for float CPU tensors x [N, I], w [O, I], b [O]: output (n, o) is
/// b[o] + x[n,0] w[o,0] + x[n,1] w[o,1] + ..., each product and sum rounded to float, in that
/// order. Rows in parallel (the result does not depend on the thread count). No autograd.
torch::Tensor portable_linear(const torch::Tensor& x, const torch::Tensor& w,
                              const torch::Tensor& b);

/// tanh of a float CPU tensor, evaluated in double from portable_exp and rounded to float.
torch::Tensor portable_tanh(const torch::Tensor& x);

/// 1 + tanh(x) of a float CPU tensor as 2 / (1 + exp(−2x)), in double from portable_exp, rounded
/// to float: accurate (and positive down to x ≈ −51, float's smallest subnormal) where 1 + tanh(x)
/// in float cancels to 0.
torch::Tensor portable_one_plus_tanh(const torch::Tensor& x);

}  // namespace crpgs
