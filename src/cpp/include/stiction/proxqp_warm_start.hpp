// Warm start from proxsuite's ProxQP: the facetized-cone QP
//     min 1/2 l'A l - b'l   s.t.  l in C_F
// where C_F replaces each spatial cone by its inscribed pyramid with F edges
// (the LCP-style approximation of paper §4.5; it lacks the De Saxce term, so it
// is only a starting point for the exact solvers).
#pragma once

#include <Eigen/Core>

#include "stiction/solver.hpp"

namespace stiction {

/// Writes the QP solution into lam; returns ProxQP's iteration count.
/// Throws std::runtime_error if ProxQP reports a failure status.
int proxqpWarmStart(const ContactProblem& problem, const SolverSettings& settings, Eigen::VectorXd& lam);

}  // namespace stiction
