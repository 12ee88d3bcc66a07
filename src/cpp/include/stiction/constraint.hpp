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
  /// 1 row, lower <= lambda <= upper (lower <= 0 <= upper): a joint's dry friction (|lambda| <= h tau_c)
  /// or an actuator's effort limit. C is the interval, so eq. 65 reads u in -N_[lower, upper](lambda):
  /// u = 0 strictly inside, u <= 0 at `upper`, u >= 0 at `lower` (box complementarity).
  kBox = 4,
};

/// Per-block state after a solve.
enum class ContactState {
  kOpen = 0,    ///< lambda = 0, the contact separates
  kStick = 1,   ///< u = 0 with lambda inside the friction cone (box rows: strictly inside the interval)
  kSlip = 2,    ///< lambda on the cone boundary, opposite to the tangential velocity (box rows: at a bound)
  kClosed = 3,  ///< bilateral rows, or a frictionless unilateral row that pushes
};

const char* toString(ConstraintKind kind);
const char* toString(ContactState state);

/// One block of rows of the problem.
struct Constraint {
  ConstraintKind kind = ConstraintKind::kSpatialFriction;
  int size = 3;    ///< number of rows: k, 1, 2 or 3
  double mu = 0.;  ///< friction coefficient (friction kinds only)
  double lower = 0., upper = 0.;  ///< the interval of a box row (kBox only)

  static Constraint bilateral(int rows);
  static Constraint unilateral();
  static Constraint planarFriction(double mu);
  static Constraint spatialFriction(double mu);
  /// Throws std::invalid_argument unless lower <= 0 <= upper, both finite.
  static Constraint box(double lower, double upper);

  bool hasFriction() const {
    return kind == ConstraintKind::kPlanarFriction || kind == ConstraintKind::kSpatialFriction;
  }
  std::string describe() const;
};

}  // namespace stiction
