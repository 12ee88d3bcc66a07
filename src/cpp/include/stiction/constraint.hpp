// Constraint kinds of the per-step problem (paper eq. 40, 58, 59).
//
// Row convention, shared with Pinocchio and the paper: inside each block the
// normal component comes LAST, e.g. a spatial friction block is (t1, t2, n).
#pragma once

#include <string>
#include <vector>

namespace stiction {

enum class ConstraintKind {
  kBilateral = 0,        ///< k equality rows, C = R^k (eq. 14-15)
  kUnilateral = 1,       ///< 1 row, lambda_n >= 0 (eq. 43)
  kPlanarFriction = 2,   ///< 2 rows (t, n), |lambda_t| <= mu lambda_n
  kSpatialFriction = 3,  ///< 3 rows (t1, t2, n), ||lambda_t|| <= mu lambda_n (eq. 58)
};

/// Per-block state after a solve.
enum class ContactState {
  kOpen = 0,    ///< lambda = 0, the contact separates
  kStick = 1,   ///< u = 0 with lambda inside the friction cone
  kSlip = 2,    ///< lambda on the cone boundary, opposite to the tangential velocity
  kClosed = 3,  ///< bilateral rows, or a frictionless unilateral row that pushes
};

const char* toString(ConstraintKind kind);
const char* toString(ContactState state);

/// One block of rows of the problem.
struct Constraint {
  ConstraintKind kind = ConstraintKind::kSpatialFriction;
  int size = 3;    ///< number of rows: k, 1, 2 or 3
  double mu = 0.;  ///< friction coefficient (friction kinds only)

  static Constraint bilateral(int rows);
  static Constraint unilateral();
  static Constraint planarFriction(double mu);
  static Constraint spatialFriction(double mu);

  bool hasFriction() const {
    return kind == ConstraintKind::kPlanarFriction || kind == ConstraintKind::kSpatialFriction;
  }
  std::string describe() const;
};

}  // namespace stiction
