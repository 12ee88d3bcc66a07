// Analytic derivatives of one time step (issue 26): the implicit function theorem at the converged
// impulse of eq. 65, mode by mode (src/cpp/sim/derivatives.cpp, docs/simulator.md).
#pragma once

#include <stdexcept>
#include <vector>

#include <Eigen/Core>

#include "stiction/simulator.hpp"

namespace stiction {

/// What a step's derivatives do not cover yet (the bindings raise NotImplementedError).
class DerivativesNotImplemented : public std::logic_error {
 public:
  using std::logic_error::logic_error;
};

/// The Jacobians of one time step (eq. 70) (q, v, tau, mu) -> (q+, v+), Pinocchio's tangent
/// conventions (q+ read as q+ (-) q+_0, an nv-vector). mu: one column per candidate contact.
struct StepDerivativesOutput {
  Eigen::MatrixXd dq_dq, dq_dv, dq_dtau, dv_dq, dv_dv, dv_dtau;  ///< nv x nv
  Eigen::MatrixXd dq_dmu, dv_dmu;                                 ///< nv x candidates
  bool has_q = false;      ///< dq_dq, dv_dq computed (else NaN)
  /// Per candidate: -1 not in the problem, 0 open, 1 stick, 2 slide (the mode differentiated).
  std::vector<int> modes;
  std::vector<char> boundary;  ///< per candidate: on a mode boundary (a one-sided derivative)
  /// Per candidate: in a statically indeterminate set (the kernel of the modes' equations touches its
  /// rows: a cube's four coplanar corners), so its normal impulse, hence its own mu column, depends on
  /// the solver's split of the load; the sum of the set's mu columns (a set-wide mu) does not.
  std::vector<char> mu_indeterminate;
  /// The modes' equations had no exact solution (redundant contacts at a change of mode): every
  /// contact in contact flagged in `boundary`, the least-squares answer returned.
  bool inconsistent = false;
  /// The step's velocity is not unique (a statically indeterminate set whose sharing of the load moves
  /// v+): the minimum-norm branch returned, the contacts involved flagged in `boundary`.
  bool indeterminate = false;
  Eigen::VectorXd q_next, v_next;  ///< the step's result from the current state (the scratch step's)
};

/// The derivatives of the step from sd's state (q, v, t) and control. The step is run on `scratch`
/// (a SimulatorData of the same model: its state is overwritten, sd is not touched). Time stepping
/// and the exact formulation only (std::invalid_argument otherwise); a step with joint rows throws
/// DerivativesNotImplemented.
/// wrt_q: also dq_dq, dv_dq (sphere and point contacts on half-spaces fixed in the world, and anchors;
/// DerivativesNotImplemented for the others).
void stepDerivatives(const SimulatorModel& sim, const SimulatorData& sd, SimulatorData& scratch,
                     StepDerivativesOutput& out, bool wrt_q = true);

}  // namespace stiction
