// The exact-law yardstick: how far an arbitrary lambda is from satisfying the exact
// Coulomb law of the per-step problem (Kikuuwe & Brogliato, eq. 65, 73-77), measured
// the same way whatever produced lambda (our solvers, CCP / Anitescu-Tasora, Nakaoka,
// pyramids, penalty, Pinocchio's solvers). docs/exact-law.md gives the definitions.
//
// With u = A lambda - b (eq. 27) and the De Saxce velocity
//     w = u + E s(u),   s_i = mu_i ||u_t,i||  added to the normal row (eq. 76-77),
// the exact law is  C ∋ lambda ⟂ w ∈ C*  (eq. 73-75), C the product of the blocks' sets
// (bilateral: R^k, unilateral: lambda_n >= 0, friction: ||lambda_t|| <= mu lambda_n, eq. 58)
// and C* its dual (bilateral: {0}, unilateral: w_n >= 0, friction: mu ||w_t|| <= w_n). A box row
// (C = [lower, upper], not a cone) obeys the variational form of eq. 65, u ∈ -N_C(lambda).
// Its parts, measured separately (every per-block vector has numBlocks() entries):
//
//   natural map      ||lambda - P_C(lambda - w)||  (verdict.hpp's cancellation-free naturalMapNorm)
//   primal           dist(lambda_i, C_i) = ||lambda_i - P_C(lambda_i)||       (bilateral: 0)
//   dual             dist(w_i, C_i*) = ||P_C(-w_i)|| (Moreau: C*'s polar is -C)  (bilateral: ||u_i||;
//                    box: 0)
//   complementarity  |<lambda_i, w_i>|                        (eq. 75)
//                    box rows (C = [lo, hi], w = u): |lambda - lo| u+ + |hi - lambda| u-, u = u+ - u-,
//                    the violation of box complementarity (u = 0 inside, u <= 0 at hi, u >= 0 at lo);
//                    with primal = 0 it vanishes exactly at the law (every u is admissible somewhere
//                    on the interval: no dual part)
//   Signorini        |lambda_n u_n|   (unilateral and friction blocks; eq. 43)
//   on SLIDING blocks (friction, ||u_t|| > speed floor, lambda_n > 0):
//     dissipation    ||lambda_t + mu lambda_n u_t / ||u_t||||   (maximum dissipation: the
//                    friction is on the cone boundary, opposite to the sliding, eq. 58, 66)
//     angle          the angle between lambda_t and -u_t, radians in [0, pi] (0 when lambda_t = 0:
//                    no direction; the dissipation norm above then reports mu lambda_n)
//     lift-off       u_n (signed). With lambda_t = -mu lambda_n u_t/||u_t||, <lambda, w> =
//                    lambda_n u_n (the De Saxce term cancels, eq. 77), so the exact law gives
//                    u_n = 0; CCP (Anitescu-Tasora) gives w_n's part, u_n = mu ||u_t||.
//
// Speed floor (scale-aware, as classifyStates in solver.cpp): a block slides when
// ||u_t|| > relative_speed_floor * ||b||_inf (default 1.5e-8, the noise floor of the
// states; b is the velocity scale of the problem, u = A lambda - b). Below it a
// tangential speed is solver noise, and the block is judged by the other measures only.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "stiction/constraint.hpp"
#include "stiction/contact_problem.hpp"

namespace stiction {

/// The default relative speed floor of "sliding": the same 1.5e-8 ||b||_inf as classifyStates.
constexpr double kRelativeSpeedFloor = 1.5e-8;

struct ExactLawMeasures {
  // Scales (for the caller's normalisation).
  double b_norm = 0.0;        ///< ||b||
  double lambda_norm = 0.0;   ///< ||lambda||
  double speed_floor = 0.0;   ///< relative_speed_floor * ||b||_inf: slower tangential motion is not sliding

  // Natural map of the De Saxce problem (eq. 65, 73-77).
  double natural_map = 0.0;        ///< ||lambda - P_C(lambda - w)||, absolute
  double residual = 0.0;           ///< natural_map / (1 + ||b||) (SolverResult::residual)
  double relative_residual = 0.0;  ///< natural_map / ||b|| (||b|| = 0: / 1; SolverResult::relative_residual)

  // Aggregates over blocks (absolute: forces, velocities, their products).
  double primal_max = 0.0, primal_norm = 0.0;  ///< dist(lambda_i, C_i): max, 2-norm over blocks
  double dual_max = 0.0, dual_norm = 0.0;      ///< dist(w_i, C_i*): max, 2-norm over blocks
  double complementarity_max = 0.0, complementarity_sum = 0.0;  ///< |<lambda_i, w_i>|
  double signorini_max = 0.0;                  ///< |lambda_n u_n|
  double dissipation_max = 0.0;                ///< sliding blocks: ||lambda_t + mu lambda_n u_t/||u_t||||
  double dissipation_angle_max = 0.0;          ///< sliding blocks: angle(lambda_t, -u_t), radians
  double liftoff_max = 0.0;                    ///< max u_n over sliding blocks, signed (0 when none slides)
  int num_sliding = 0;

  // Per block (numBlocks() entries; 0 where a measure does not apply).
  Eigen::VectorXd primal, dual, complementarity, signorini, dissipation, dissipation_angle, liftoff;
  std::vector<bool> sliding;             ///< friction block, ||u_t|| > speed_floor, lambda_n > 0
  std::vector<ContactState> states;      ///< classifyStates (solver.hpp)

  // Per row (numRows()).
  Eigen::VectorXd u;  ///< A lambda - b
  Eigen::VectorXd w;  ///< u + E s(u) (eq. 76-77)
};

/// All the measures at an arbitrary lambda (numRows() entries; need not be feasible nor a
/// solution). Pure; `out` is resized and overwritten, so reusing it allocates nothing once
/// sized. Throws std::invalid_argument when lambda has the wrong size or
/// relative_speed_floor < 0. u: A lambda - b when the caller has it (the solve driver's verdict).
void measureExactLaw(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                     ExactLawMeasures& out, double relative_speed_floor = kRelativeSpeedFloor,
                     const Eigen::VectorXd* u = nullptr);

/// Convenience: a fresh result.
ExactLawMeasures exactLawMeasures(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                                  double relative_speed_floor = kRelativeSpeedFloor);

}  // namespace stiction
