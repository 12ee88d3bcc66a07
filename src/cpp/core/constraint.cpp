#include "stiction/constraint.hpp"

#include <cmath>
#include <sstream>
#include <stdexcept>

namespace stiction {

const char* toString(ConstraintKind kind) {
  switch (kind) {
    case ConstraintKind::kBilateral: return "bilateral";
    case ConstraintKind::kUnilateral: return "unilateral";
    case ConstraintKind::kPlanarFriction: return "planar_friction";
    case ConstraintKind::kSpatialFriction: return "spatial_friction";
    case ConstraintKind::kBox: return "box";
  }
  return "unknown";
}

const char* toString(ContactState state) {
  switch (state) {
    case ContactState::kOpen: return "open";
    case ContactState::kStick: return "stick";
    case ContactState::kSlip: return "slip";
    case ContactState::kClosed: return "closed";
  }
  return "unknown";
}

Constraint Constraint::bilateral(int rows) {
  if (rows < 1) throw std::invalid_argument("bilateral constraint needs at least 1 row, got " + std::to_string(rows));
  return {ConstraintKind::kBilateral, rows, 0.0};
}
Constraint Constraint::unilateral() { return {ConstraintKind::kUnilateral, 1, 0.0}; }
Constraint Constraint::planarFriction(double mu) { return {ConstraintKind::kPlanarFriction, 2, mu}; }
Constraint Constraint::spatialFriction(double mu) { return {ConstraintKind::kSpatialFriction, 3, mu}; }
Constraint Constraint::box(double lower, double upper) {
  if (!(std::isfinite(lower) && std::isfinite(upper) && lower <= 0.0 && upper >= 0.0)) {
    std::ostringstream os;
    os.precision(17);
    os << "box constraint needs finite bounds lower <= 0 <= upper, got [" << lower << ", " << upper << "]";
    throw std::invalid_argument(os.str());
  }
  Constraint c{ConstraintKind::kBox, 1, 0.0};
  c.lower = lower;
  c.upper = upper;
  return c;
}

std::string Constraint::describe() const {
  std::ostringstream os;
  os << toString(kind) << "(";
  if (kind == ConstraintKind::kBilateral) os << "rows=" << size;
  if (hasFriction()) os << "mu=" << mu;
  if (kind == ConstraintKind::kBox) os << "lower=" << lower << ", upper=" << upper;
  os << ")";
  return os.str();
}

}  // namespace stiction
