// The largest step classical RK4 keeps stable on the relaxed contact dynamics
// (eq. 64). While a contact sticks, the solve of eq. 65 imposes on each row
//     normal:      g'' + (2 zeta / delta) g' + g / delta^2 = 0
//     tangential:  u' + (2 zeta / delta) u = 0
// whose roots s are -(zeta +- sqrt(zeta^2 - 1)) / delta (|s| = 1/delta at angle
// pi - acos(zeta) for zeta < 1) and -2 zeta / delta. RK4 is stable while h s lies
// in its stability region {|1 + z + z^2/2 + z^3/6 + z^4/24| <= 1}; along the
// negative axis that is 2.785, at zeta = 1/2 (angle 120 degrees) 2.623.
// Measured on cube-incline-stick (delta = 1e-4, zeta = 1/2, 0.5 s): at rest up
// to dt = 2.6 delta, drifting from 2.7 delta (docs/solvers.md).
#pragma once

namespace stiction {

/// RK4's stability limit on the contact relaxation: the largest h with every h s
/// inside the stability region (no margin).
double rk4StabilityLimit(double delta, double zeta);

/// The step the simulator accepts: kRK4StepMargin * rk4StabilityLimit (about 2 delta
/// at zeta = 1/2), leaving room for the non-smooth stick/slip switches.
constexpr double kRK4StepMargin = 0.75;
double rk4StableStep(double delta, double zeta);

}  // namespace stiction
