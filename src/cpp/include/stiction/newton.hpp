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

#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseLU>

#include "stiction/admm.hpp"
#include "stiction/block_cholesky.hpp"
#include "stiction/nsgs.hpp"
#include "stiction/solver.hpp"

namespace stiction {

/// Dense LU with partial pivoting for Newton systems of up to a few dozen contacts: unblocked
/// and allocation-free once sized, where Eigen's blocked PartialPivLU spends more on its set-up
/// than on the arithmetic (measured: ~50k instructions for a 27 x 27 matrix, against ~12k).
class SmallDenseLU {
 public:
  /// Up to this many rows. Measured on random spatial problems, whole Newton solves: 1.5x
  /// faster than with Eigen's LU at 24-63 rows, 1.2x at 96-150, even at 192-240, 0.9x at 321.
  static constexpr Eigen::Index kMaxRows = 192;
  /// Factor `a` in place (P a = L U); `a` must outlive the solves.
  void compute(Eigen::MatrixXd& a);
  /// x <- a^{-1} x.
  void solve(Eigen::VectorXd& x) const;

 private:
  std::vector<int> pivots_;
  const Eigen::MatrixXd* factor_ = nullptr;
};

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
};

/// The default: picks its stages by size and sparsity, and within those by how the stages
/// converge (measured on the 36 FCLib problems and the simulator's scenes: docs/solvers.md,
/// "The default's rule").
/// - First, when the initial guess is strictly inside every cone (a warm start where every
///   contact was closed and sticking: a robot standing, a box at rest, a tower), or when it is
///   zero and the natural map there puts every block in its sticking regime (b inside the
///   shifted cones: a cold problem at rest, CubesH8), the all-stick solution (u = A lambda - b =
///   0, eq. 65 with every block inside its cone) by one proximal factorization (stickingStep);
///   kept only if the stopping test passes.
/// - Small problems (<= kNewtonFirstRows rows: a robot's feet, a box's corners): Newton
///   first, then Newton from ProxQP's facetized-cone solution if that failed.
/// - Large sparse problems (> kAdmmAboveRows rows, <= 10 % nonzero): warm-started, at most
///   kWarmSweeps NSGS sweeps first; then, with at most kSparseNewtonEntries stored entries,
///   Newton from the guess (sparse Jacobian and LU); then ADMM (sparse factorization) until it
///   converges or its best residual stops improving, then a few Newton steps from the best
///   iterate if it is nearly there.
/// - Otherwise NSGS while its rate promises to finish within ~m sweeps and does not
///   decelerate; then Newton from the NSGS iterate (medium problems, <= kAdmmAboveRows rows;
///   warm-started, after at most kWarmAdmmIterations of ADMM from the guess) or ADMM as above
///   (large dense ones).
/// - Then Newton from the initial guess; if all that fails, alternating chunks of NSGS and
///   ADMM (500 iterations at most), each followed by a Newton attempt from its iterate.
///   Returns the best iterate met.
class DefaultSolver final : public ContactSolver {
 public:
  /// Up to this many rows a dense Newton step is cheaper than a few sweeps
  /// (measured: docs/solvers.md).
  static constexpr Eigen::Index kNewtonFirstRows = 64;
  /// Above this many rows ADMM, not Newton, follows a stalled NSGS, and a sparse A goes to
  /// ADMM directly: the FCLib problems where Newton wins have <= 321 rows, those where ADMM
  /// wins >= 648 (docs/solvers.md).
  static constexpr Eigen::Index kAdmmAboveRows = 384;
  /// ADMM's stall horizon, in iterations per row (admm.hpp: switch_after).
  static constexpr double kAdmmHorizonPerRow = 10.0;
  /// A large sparse problem whose A stores at most this many entries tries Newton (sparse
  /// Jacobian and LU) from the guess before ADMM (warm-started: after a few sweeps; measured:
  /// docs/solvers.md, "The default's rule").
  static constexpr Eigen::Index kSparseNewtonEntries = 50000;
  /// Gauss-Seidel sweeps tried before ADMM on a warm-started large sparse problem.
  static constexpr int kWarmSweeps = 10;
  /// ADMM iterations from the guess on a warm-started medium problem before Newton: where it
  /// helps (a tower at rest whose contacts are not all sticking) it converges in a few; a tower
  /// of 24 spinning boxes took 440-910 to stall (7-13 ms) before Newton converged in 5-6 steps.
  static constexpr int kWarmAdmmIterations = 50;
  /// Newton steps from the best iterate after ADMM stalls, if its residual is within
  /// kPolishWithin x the tolerance.
  static constexpr int kPolishSteps = 5;
  static constexpr double kPolishWithin = 1e3;

  /// The sticking step's proximal shift, relative to A's largest diagonal entry, and how many
  /// refinement solves it takes at most.
  static constexpr double kStickShift = 1e-10;
  static constexpr int kStickSolves = 4;
  /// Up to this many rows the dense factor's solves are plain substitutions (solveShifted).
  static constexpr Eigen::Index kStickSmallRows = 48;
  /// A dense A with at most this fraction of nonzeros is factored sparsely by the sticking step
  /// (a tower's A: block-tridiagonal).
  static constexpr double kStickSparseDensity = 0.25;
  /// The factor of an earlier call is tried first while A's diagonal is within this fraction (of
  /// its largest entry) of the factored one's.
  static constexpr double kStaleDiagonalChange = 1e-3;
  /// A held factor whose rate predicted a miss is tried again after this many calls.
  static constexpr int kStaleRetry = 16;
  /// A small dense factor reused from an earlier call gives its refinement step as one product
  /// with G = R^-1 A R^-1 (prepareStepMatrix) while R's 1-norm condition number is at most this.
  static constexpr double kStepMatrixMaxCondition = 1e6;
  /// Refinement steps by the product with G that are cheaper than a fresh factor and its step.
  static constexpr int kHeldStepsWithProduct = 3;

  std::string name() const override { return "default"; }
  void iterate(const ContactProblem& problem, const SolverSettings& settings,
               SolverResult& result) override;

  /// The all-stick solution near lam: from x = lam, steps d = R^-1 A R^-1 (b - A x) with
  /// R = A + rho I, refined. The correction lies in A's range, so where A is rank-deficient (the
  /// four corners of a sole: 12 rows of rank 6; a tower's interfaces) the forces keep the guess's
  /// share of the non-unique part, and one factorization replaces Newton's regularised steps (2.3
  /// a step on TALOS, each an LU). The factor of the previous call is tried first while A's
  /// diagonal is close to its matrix's (heldFactorFits) and it last did the work in one step.
  /// True (lam replaced) when StoppingTest says converged; else lam is unchanged. `solves`: the
  /// refinement steps done (two solves each).
  bool stickingStep(const ContactProblem& problem, Eigen::VectorXd& lam, double tolerance, int& solves);

 private:
  bool factorShifted(const ContactProblem& problem, double shift);
  bool heldFactorFits(const ContactProblem& problem) const;
  void solveShifted(const Eigen::VectorXd& rhs, Eigen::VectorXd& x) const;  // x = (A + rho I)^-1 rhs
  // d = R^-1 A_f R^-1 r (A_f the factored A, R = A_f + rho I): the refinement step's direction
  void refinementDirection(const Eigen::VectorXd& r, Eigen::VectorXd& d);
  void prepareStepMatrix();

  Eigen::LLT<Eigen::MatrixXd> stick_llt_;
  Eigen::MatrixXd stick_shifted_;
  Eigen::SimplicialLLT<Eigen::SparseMatrix<double>, Eigen::Lower, Eigen::AMDOrdering<int>> stick_sparse_llt_;
  // Contacts listed body by body (a tower bottom to top) are often ordered well already: the
  // natural order, when it fills no more than AMD's, saves permuting A at every factorization.
  // (Upper: with no permutation Eigen then factors the input's upper triangle in place of copying
  // a permuted one; A is stored whole and symmetric, so both triangles hold it.)
  Eigen::SimplicialLLT<Eigen::SparseMatrix<double>, Eigen::Upper, Eigen::NaturalOrdering<int>> stick_natural_llt_;
  bool stick_natural_ = false;
  BlockCholesky3 stick_block_;  // spatial contacts only: L in 3 x 3 blocks
  bool stick_blocked_ = false;
  Eigen::SparseMatrix<double> stick_sparse_;              // a dense A's entries, when sparse enough
  std::vector<int> stick_outer_, stick_inner_;            // the pattern analysed last
  bool stick_sparse_path_ = false;
  bool stick_from_dense_ = false;  // stick_sparse_ holds a dense A's pattern
  Eigen::VectorXd stick_x_, stick_u_, stick_d_, stick_w_;
  Eigen::VectorXd stick_abs_;  // |A| |stick_x_|, with stick_u_ (the verdict's bound)
  Eigen::Index stick_factor_rows_ = -1;    // the rows of the factor held (-1: none)
  Eigen::VectorXd stick_factor_diagonal_;  // its matrix's diagonal
  double stick_factor_shift_ = 0.0;        // and its shift rho
  double stale_rate_ = 0.0;   // the natural map's reduction by the held factor's first step, last try
  int stale_skipped_ = 0;     // calls since the held factor was last tried
  bool stale_cheap_ = false;  // its last try converged in the steps worth taking (1, or with G a few)
  bool stick_used_held_ = false;  // the last sticking step converged with the held factor
  Eigen::VectorXd stick_diagonal_;         // this call's A's diagonal
  // The held small dense factor's step matrix G = R^-1 - rho R^-2 (= R^-1 A_f R^-1), made on the
  // factor's first reuse: a robot standing reuses one factor for hundreds of steps, where the four
  // triangular solves of a step (their divisions in a chain) cost 4x the product.
  enum class StepMatrix { kNone, kReady, kRefused };
  StepMatrix stick_step_state_ = StepMatrix::kNone;
  Eigen::MatrixXd stick_step_matrix_, stick_step_work_;
  NsgsSolver nsgs_;
  NewtonSolver newton_;
  AdmmSolver admm_;
  Eigen::VectorXd best_, trial_, initial_, u_ws_;
};

}  // namespace stiction
