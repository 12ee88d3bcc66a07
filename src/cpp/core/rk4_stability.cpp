#include "stiction/rk4_stability.hpp"

#include <algorithm>
#include <cmath>
#include <complex>

namespace stiction {

namespace {

using Complex = std::complex<double>;

double amplification(Complex z) { return std::abs(1.0 + z * (1.0 + z * (0.5 + z * (1.0 / 6.0 + z / 24.0)))); }

// Distance from 0 to the edge of RK4's stability region along direction `dir`
// (|dir| = 1, Re dir < 0): scan outwards, then bisect the first exit.
double stabilityRadius(Complex dir) {
  constexpr double kStep = 1e-3, kMax = 4.0;
  double inside = 0.0;
  for (double r = kStep; r <= kMax; r += kStep) {
    if (amplification(r * dir) > 1.0) {
      double lo = inside, hi = r;
      for (int k = 0; k < 60; ++k) {
        const double mid = 0.5 * (lo + hi);
        (amplification(mid * dir) > 1.0 ? hi : lo) = mid;
      }
      return lo;
    }
    inside = r;
  }
  return kMax;
}

}  // namespace

double rk4StabilityLimit(double delta, double zeta) {
  // The restrictive roots: the normal row's (its conjugate is symmetric; for zeta >= 1
  // the larger of its two real roots) and the tangential row's. h <= radius(arg s) / |s|.
  const Complex roots[2] = {
      zeta < 1.0 ? Complex(-zeta, std::sqrt(1.0 - zeta * zeta)) : Complex(-zeta - std::sqrt(zeta * zeta - 1.0), 0.0),
      Complex(-2.0 * zeta, 0.0)};
  double h = INFINITY;
  for (const Complex& s : roots) {
    const double mag = std::abs(s);
    if (mag > 0.0) h = std::min(h, stabilityRadius(s / mag) / mag);
  }
  return h * delta;
}

double rk4StableStep(double delta, double zeta) { return kRK4StepMargin * rk4StabilityLimit(delta, zeta); }

}  // namespace stiction
