// Semismooth Newton on the natural map of the De Saxce problem (eq. 73-77):
//
//     F(l) = l - P_C(l - K (u + E s(u))),   u = A l - b,   K = diag(kappa_i I)
//
// with kappa_i = 1 / ||A_ii|| per block (unit-consistent). Each step solves
// (dF + eps I) d = -F with a dense LU, eps ~ ||F|| (Levenberg-Marquardt style:
// keeps the step defined where A is rank-deficient, e.g. sticking contacts with
// more rows than degrees of freedom), then backtracks on ||F||.
// Converges in a few steps where Gauss-Seidel stalls (large mass ratios).
#pragma once

#include <Eigen/LU>

#include "stiction/admm.hpp"
#include "stiction/nsgs.hpp"
#include "stiction/solver.hpp"

namespace stiction {

class NewtonSolver final : public ContactSolver {
 public:
  std::string name() const override { return "newton"; }
  void iterate(const ContactProblem& problem, const SolverSettings& settings,
               SolverResult& result) override;

  /// Newton steps from lam; returns the number of steps. Stops at `tolerance`.
  int run(const ContactProblem& problem, Eigen::VectorXd& lam, int max_steps, double tolerance,
          double time_limit, std::string& message);

 private:
  /// F(lam) into F_, and (if jacobian) its generalized Jacobian into J_.
  void evaluate(const ContactProblem& problem, const Eigen::VectorXd& lam, bool jacobian);

  Eigen::VectorXd kappa_, u_, z_, F_, trial_, step_, trial_F_;
  Eigen::MatrixXd J_;
  Eigen::RowVectorXd row_;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu_;
};

/// The default. Small problems (<= kNewtonFirstRows rows): Newton first, then
/// Newton from ProxQP's facetized-cone solution if that failed. Larger
/// ones: NSGS while its rate promises to finish sooner than ~10 Newton steps
/// (cheap sweeps, exact local solves), then Newton from the NSGS iterate and
/// from the initial guess. If Newton's line search cannot finish:
/// alternating chunks of NSGS and ADMM (500 iterations at most), each followed
/// by a Newton attempt from its iterate. Returns the best iterate met.
class DefaultSolver final : public ContactSolver {
 public:
  /// Up to this many rows a dense Newton step is cheaper than a few sweeps
  /// (measured: docs/solvers.md).
  static constexpr Eigen::Index kNewtonFirstRows = 64;

  std::string name() const override { return "default"; }
  void iterate(const ContactProblem& problem, const SolverSettings& settings,
               SolverResult& result) override;

 private:
  NsgsSolver nsgs_;
  NewtonSolver newton_;
  AdmmSolver admm_;
  Eigen::VectorXd best_, trial_, initial_, u_ws_;
};

}  // namespace stiction
