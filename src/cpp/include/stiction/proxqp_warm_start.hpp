// Warm start from proxsuite's ProxQP: the facetized-cone QP
//     min 1/2 l'A l - b'l   s.t.  l in C_F
// where C_F replaces each spatial cone by its inscribed pyramid with F edges
// (the LCP-style approximation of paper §4.5; it lacks the De Saxce term, so it
// is only a starting point for the exact solvers). Box rows keep their interval
// (one QP row with both bounds): on a problem of box, unilateral and bilateral rows
// alone the QP is the problem itself.
//
// Budgets: tolerances are relative (eps_rel = settings.proxqp_tolerance, eps_abs
// scaled to b and lambda), so a problem with ||b|| = 1e8 costs what it costs at
// ||b|| = 1; at most settings.proxqp_max_iterations inner iterations; and, as
// proxsuite's dense QP has no clock, the solve runs in chunks of iterations sized
// from the measured cost per iteration to fit the time limit.
#pragma once

#include <Eigen/Core>

#include "stiction/solver.hpp"

namespace stiction {

/// Writes the QP solution (or ProxQP's last iterate, or 0) into lam and returns the
/// stage's report (iterations: ProxQP's inner iterations). If the QP is unbounded
/// below (b pushes along a direction of C that A does not resist: the contact
/// problem has no solution), ProxQP's ray goes into `ray` (when given). Never throws
/// on a solver failure: the report's outcome says what happened.
StageReport proxqpWarmStart(const ContactProblem& problem, const SolverSettings& settings, double time_limit,
                            Eigen::VectorXd& lam, Eigen::VectorXd* ray = nullptr);

}  // namespace stiction
