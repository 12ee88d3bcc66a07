// A small dense LU for Newton's systems (newton.hpp).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "stiction/thresholds.hpp"

namespace stiction {

/// Dense LU with partial pivoting for Newton systems of up to a few dozen contacts: unblocked
/// and allocation-free once sized, where Eigen's blocked PartialPivLU spends more on its set-up
/// than on the arithmetic (measured: ~50k instructions for a 27 x 27 matrix, against ~12k).
class SmallDenseLU {
 public:
  /// Up to this many rows (thresholds.hpp: measured against Eigen's LU in whole Newton solves).
  static constexpr Eigen::Index kMaxRows = kSmallDenseLuRows;
  /// Factor `a` in place (P a = L U); `a` must outlive the solves.
  void compute(Eigen::MatrixXd& a);
  /// x <- a^{-1} x.
  void solve(Eigen::VectorXd& x) const;

 private:
  std::vector<int> pivots_;
  const Eigen::MatrixXd* factor_ = nullptr;
};

}  // namespace stiction
