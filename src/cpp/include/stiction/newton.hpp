// Semismooth Newton on the natural map of the De Saxce problem (eq. 73-77):
//
//     F(l) = l - P_C(l - K (u + E s(u))),   u = A l - b,   K = diag(kappa_i I)
//
// with kappa_i = 1 / ||A_ii|| per block (unit-consistent). Each step solves
// (dF + eps I) d = -F with a dense LU, eps ~ ||F|| (Levenberg-Marquardt style:
// keeps the step defined where A is rank-deficient, e.g. sticking contacts with
// more rows than degrees of freedom), then backtracks on ||F||. With box rows the step is
// filtered to the factor's numerical range, d = (dF + eps I)^-1 dF d0, when what that drops is
// below the tolerance (docs/solvers.md, "More rows than velocities").
// Converges in a few steps where Gauss-Seidel stalls (large mass ratios).
#pragma once

#include <vector>

#include <Eigen/LU>
#include <Eigen/SparseLU>

#include "stiction/dense_lu.hpp"
#include "stiction/iteration_monitor.hpp"
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

  /// (dF + eps I) step = -F block by block, when A couples no two blocks (uncoupled_).
  void solveUncoupled(const ContactProblem& problem, double eps);

  Eigen::VectorXd kappa_, diagonal_, u_, F_, trial_, step_;
  Eigen::VectorXd filtered_;  // eps (dF + eps I)^-1 d0, the part of the step d0 the filter removes
  Eigen::VectorXd u_start_, step_image_;  // u at the iterate and A d (box rows: the line search's breakpoints)
  std::vector<double> breakpoints_;
  Eigen::MatrixXd J_;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu_;
  SmallDenseLU small_lu_;
  /// A dense A with no entry outside its blocks' diagonal squares (FCLib's Toy FC3D_Example1:
  /// A = I; any one-contact problem): dF is block diagonal too, so the Newton system splits.
  bool uncoupled_ = false;

  // The sparse path (a sparse A above SmallDenseLU::kMaxRows rows).
  /// The Jacobian's pattern (A's, widened to whole block rows, plus the diagonal blocks).
  void prepareSparse(const ContactProblem& problem);
  /// Js_'s values from A and the blocks' G and D that evaluate() stored.
  void fillSparseJacobian(const ContactProblem& problem);
  bool sparse_ = false;
  Eigen::SparseMatrix<double> Js_;
  std::vector<int> row_block_, diagonal_at_;
  std::vector<Eigen::Index> packed_;
  std::vector<double> block_G_, block_D_;
  Eigen::VectorXd column_;
  Eigen::SparseLU<Eigen::SparseMatrix<double>, Eigen::COLAMDOrdering<int>> sparse_lu_;
  IterationMonitor monitor_;  // the time limit
};

}  // namespace stiction
