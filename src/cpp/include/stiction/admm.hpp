// ADMM on the cone problem with the De Saxce correction (eq. 73-77).
//
// For fixed s the problem is the convex cone QP  min 1/2 l'A l - (b - E s)'l,
// l in C. ADMM splits it into a linear solve with (A + (rho + prox) I), which is
// nonsingular even for a rank-deficient A, and a projection onto C; s is
// refreshed from u = A lambda - b at every iteration, so the fixed point is the
// exact Coulomb NCP, not the CCP relaxation (eq. 79). rho follows residual
// balancing (primal against dual residual, refactorizing when it changes).
#pragma once

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/OrderingMethods>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <Eigen/SparseLU>

#include <vector>

#include "stiction/iteration_monitor.hpp"
#include "stiction/solver.hpp"

namespace stiction {

class AdmmSolver final : public ContactSolver {
 public:
  std::string name() const override { return "admm"; }
  void iterate(const ContactProblem& problem, const SolverSettings& settings,
               SolverResult& result) override;

  /// ADMM iterations from lam (or, with resume, from the state the previous call
  /// left: z, y, rho and the factorization). Writes the feasible iterate z into
  /// lam; returns the number of iterations. With switch_after > 0, stops with message
  /// "stalled" when the best residual's rate over the last 400 iterations predicts more
  /// than switch_after further iterations (or it did not improve).
  int run(const ContactProblem& problem, Eigen::VectorXd& lam, int max_iterations, double tolerance,
          double time_limit, double initial_rho, bool resume, std::string& message,
          double switch_after = 0.0);

  /// True when run() factorizes and multiplies A sparsely: A held sparse (SparseDelassus), or
  /// more than kDenseFactorRows (64) rows and at most kAdmmSparseDensity (10 %) nonzero entries
  /// (thresholds.hpp; the FCLib problems of that size ADMM is used on are 0.6-4 % nonzero).
  static bool factorsSparsely(const ContactProblem& problem);

  /// false: drop the De Saxce term, i.e. solve the convex CCP relaxation (eq. 78-79) and
  /// stop on its natural map (coneNaturalMap) instead of the exact law's.
  void setDesaxce(bool on) { desaxce_ = on; }

 private:
  void prepareSparse(const ContactProblem& problem);
  void factorize(const ContactProblem& problem, double shift);
  void solveShifted(Eigen::VectorXd& x);
  void multiplyA(const ContactProblem& problem, const Eigen::VectorXd& x, Eigen::VectorXd& y) const;
  double largestEigenvalueEstimate(const ContactProblem& problem, int iterations);

  bool desaxce_ = true;
  bool symmetric_ = true;
  double L_ = 0.0, prox_ = 0.0, rho_ = 0.0;
  int since_rho_change_ = 0;
  double imbalance_ = 10.0;    // primal/dual residual ratio that moves rho (large m: grows on reversals)
  double last_factor_ = 1.0;   // the last change of rho (its direction)
  double best_r_ = 0.0;        // best relative residual at z so far (the stall test's)
  IterationMonitor monitor_;   // time limit; best_r_'s rate over the stall window (kept on resume)
  int total_iterations_ = 0;   // over resumed runs
  Eigen::VectorXd primal_;  // the unprojected iterate x
  Eigen::MatrixXd shifted_;
  Eigen::LLT<Eigen::MatrixXd> llt_;
  Eigen::PartialPivLU<Eigen::MatrixXd> lu_;
  // A sparse A (factorsSparsely): factorized sparsely (admm.cpp).
  bool sparse_ = false, sparse_lu_analyzed_ = false;
  Eigen::SparseMatrix<double> sparse_A_, sparse_shifted_;
  std::vector<Eigen::Index> diagonal_;  // positions of the diagonal in sparse_shifted_'s values
  Eigen::SimplicialLLT<Eigen::SparseMatrix<double>, Eigen::Lower, Eigen::AMDOrdering<int>> sparse_llt_;
  Eigen::SparseLU<Eigen::SparseMatrix<double>, Eigen::COLAMDOrdering<int>> sparse_lu_;
  Eigen::VectorXd z_, z_prev_, y_, u_, ulam_, rhs_, work_;
};

/// A held sparse (SparseDelassus), or more than kDenseFactorRows rows of which at most `density`
/// are nonzero (a dense A's entries counted: O(rows^2)). thresholds.hpp says which density each
/// caller uses.
bool sparseEnough(const ContactProblem& problem, double density);

/// Largest eigenvalue of the symmetric part of A by power iteration (an estimate).
double largestEigenvalue(const ContactProblem& problem, int iterations = 30);

/// ||lambda - P_C(lambda - u)||: the natural map of the cone complementarity problem
/// C* ∋ u ⟂ lambda ∈ C (eq. 71-72, 79), i.e. without De Saxce's term.
double coneNaturalMap(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                      const Eigen::Ref<const Eigen::VectorXd>& u, Eigen::VectorXd& work);

/// In-place projection of every block of x onto its set C.
void projectOntoConstraints(const ContactProblem& problem, Eigen::Ref<Eigen::VectorXd> x);

}  // namespace stiction
