// Exact solution of the one-block problem, the inner step of block Gauss-Seidel:
//
//     u = G lambda + c,    C* ∋ u + E s(u) ⟂ lambda ∈ C      (eq. 73-77 with one block)
//
// G is the block's diagonal of A (symmetric or not), c collects b and the other
// blocks. The three cases are tried in order: open (c_n >= 0), stick
// (lambda = -G^-1 c inside the cone), slip (lambda on the cone boundary with
// u_n = 0 and u_t opposite to lambda_t), the last solved exactly: for a spatial
// block the slip angle is a root of a quartic (the paper's remark after eq. 82),
// for a planar block one of two linear equations.
#pragma once

#include <Eigen/Core>

#include "stiction/constraint.hpp"

namespace stiction {

/// Spatial block (t1, t2, n). `G_inv` is G^-1. On entry `lam` is the current
/// value (used to choose between several exact solutions); on exit the solution.
ContactState solveSpatialBlock(const Eigen::Matrix3d& G, const Eigen::Matrix3d& G_inv,
                               const Eigen::Vector3d& c, double mu, Eigen::Vector3d& lam);

/// Planar block (t, n).
ContactState solvePlanarBlock(const Eigen::Matrix2d& G, const Eigen::Matrix2d& G_inv,
                              const Eigen::Vector2d& c, double mu, Eigen::Vector2d& lam);

/// Natural-map residual of one spatial block (for choosing among candidates).
double spatialBlockResidual(const Eigen::Matrix3d& G, const Eigen::Vector3d& c, double mu,
                            const Eigen::Vector3d& lam);

}  // namespace stiction
