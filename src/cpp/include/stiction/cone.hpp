// Euclidean projections onto the blocks' sets C (eq. 58) and the De Saxce
// correction E s(u) (eq. 76-77). Normal component last in every block. A box row's C is its
// interval [lower, upper]: its projection is a clamp (clampToBox).
#pragma once

#include <algorithm>
#include <cmath>

#include <Eigen/Core>

namespace stiction {

/// sqrt(a^2 + b^2) without std::hypot's overflow guards (4x faster; the values here
/// are forces and velocities, far from overflow).
inline double norm2(double a, double b) { return std::sqrt(a * a + b * b); }

/// Projection of (x_t, x_n), x_t given by its norm `xt_norm`, onto
/// {||x_t|| <= mu x_n}. Writes the scale to apply to x_t and the new normal.
inline void projectOntoConeScalars(double xt_norm, double xn, double mu, double& t_scale,
                                   double& n_out) {
  if (xn >= 0.0 && xt_norm <= mu * xn) {  // inside (the xn >= 0 test matters for mu = 0)
    t_scale = 1.0;
    n_out = xn;
  } else if (mu * xt_norm <= -xn) {  // inside the polar cone
    t_scale = 0.0;
    n_out = 0.0;
  } else {  // onto the boundary ray
    const double a = (xn + mu * xt_norm) / (1.0 + mu * mu);
    n_out = a;
    t_scale = xt_norm > 0.0 ? mu * a / xt_norm : 0.0;
  }
}

/// In place projection of a 3-vector (t1, t2, n) onto the spatial friction cone.
template <typename Vec>
inline void projectSpatialCone(Vec&& x, double mu) {
  double s, n;
  projectOntoConeScalars(norm2(x[0], x[1]), x[2], mu, s, n);
  x[0] *= s;
  x[1] *= s;
  x[2] = n;
}

/// In place projection of a 2-vector (t, n) onto the planar friction cone.
template <typename Vec>
inline void projectPlanarCone(Vec&& x, double mu) {
  double s, n;
  projectOntoConeScalars(std::abs(x[0]), x[1], mu, s, n);
  x[0] *= s;
  x[1] = n;
}

/// Projection of x onto a box row's interval [lower, upper] (lower <= 0 <= upper): a clamp.
inline double clampToBox(double x, double lower, double upper) { return std::min(std::max(x, lower), upper); }

}  // namespace stiction
