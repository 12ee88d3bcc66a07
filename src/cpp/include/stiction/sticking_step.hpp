// The default solver's first stage (default_solver.hpp): the all-stick solution by one proximal
// factorization of A, tried when the guess says every contact sticks.
#pragma once

#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>

#include "stiction/block_cholesky.hpp"
#include "stiction/contact_problem.hpp"
#include "stiction/thresholds.hpp"

namespace stiction {

/// Every block of x strictly inside its cone, by a relative margin (a unilateral row pushing, a
/// friction block's tangential part below mu times a positive normal part, a box row inside its
/// interval: it holds, u = 0, like a sticking contact; bilateral rows: any value). With de_saxce
/// (x = b, lambda = 0), the normal part is first shifted by De Saxce's term, x_n - mu |x_t|, and a
/// box row is judged at b / A_oo.
bool strictlyInsideCones(const ContactProblem& problem, const Eigen::VectorXd& x, bool de_saxce = false);

/// At lambda = 0 the natural map of eq. 65 puts every block in its sticking regime: b inside the
/// cones once shifted by De Saxce's term (sticking_step.cpp).
bool stickingAtZero(const ContactProblem& problem);

/// Every block of lam strictly inside its cone but some box rows (a joint's dry friction, effort
/// limit) within the margin of a bound that rest there: at lam the natural map's argument
/// z = lam_o - u_o / A_oo (u = A lam - b) lies within the margin of the interval, the sticking
/// regime. A joint held by exactly its friction limit (a standing robot's joints once they slipped
/// to rest; ProxQP's solution, a vertex of the box) rests; a slipping joint, whose velocity puts z
/// past its bound, does not (anymal-stand: z inside at rest, 1e3-1e7 margins past while slipping).
/// In a dense A of up to kDenseFactorRows rows, unilateral rows at 0 too (a joint limit touched
/// with no force): the sticking step holds those that u keeps open there (pinned at 0) and closes
/// the others (TALOS's grippers rest on their limits, some open by 2e-14 rad: an all-stick answer
/// would pull on them, twice the tolerance). False without box rows (no product then).
bool restingOnBounds(const ContactProblem& problem, const Eigen::VectorXd& lam);

/// The guess `lam` predicts the all-stick solution: strictly inside every cone (a warm start where
/// every contact was closed and sticking: a robot standing, a box at rest, a tower), or zero with
/// every block sticking there (a cold problem at rest: CubesH8), or inside but for box rows resting on
/// their bounds (restingOnBounds).
bool stickingGuess(const ContactProblem& problem, const Eigen::VectorXd& lam);

/// The all-stick solution near lam: from x = lam, steps d = R^-1 A R^-1 (b - A x) with
/// R = A + rho I, refined. The correction lies in A's range, so where A is rank-deficient (the
/// four corners of a sole: 12 rows of rank 6; a tower's interfaces) the forces keep the guess's
/// share of the non-unique part, and one factorization replaces Newton's regularised steps (2.3
/// a step on TALOS, each an LU). The factor of the previous call is tried first while A's
/// diagonal is close to its matrix's (heldFactorFits) and it last did the work in one step.
class StickingStep {
 public:
  /// The sticking step's proximal shift, relative to A's largest diagonal entry, and how many
  /// refinement solves it takes at most.
  static constexpr double kStickShift = 1e-10;
  static constexpr int kStickSolves = 4;
  /// Up to this many rows the dense factor's solves are plain substitutions (solveShifted).
  static constexpr Eigen::Index kStickSmallRows = 48;
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
  /// A row held on a bound (pinned) gets this shift on its diagonal, relative to A's largest entry.
  static constexpr double kPinShift = 1e8;

  /// True (lam replaced) when StoppingTest says converged; else lam is unchanged. `solves`: the
  /// refinement steps done (two solves each).
  bool run(const ContactProblem& problem, Eigen::VectorXd& lam, double tolerance, int& solves);
  /// The last run converged with the factor held from an earlier call.
  bool usedHeldFactor() const { return stick_used_held_; }

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
  // Rows held on a bound (restingOnBounds; unilateral rows open at 0, box rows pressed on a bound):
  // this call's with their values, and the held factor's, with the pin shift M on its diagonal
  // (R = A + rho I + M P)
  std::vector<Eigen::Index> stick_pinned_, stick_factor_pinned_;
  std::vector<double> stick_pinned_value_;
  double stick_factor_pin_shift_ = 0.0;
  // The held small dense factor's step matrix G = R^-1 - rho R^-2 (= R^-1 A_f R^-1), made on the
  // factor's first reuse: a robot standing reuses one factor for hundreds of steps, where the four
  // triangular solves of a step (their divisions in a chain) cost 4x the product.
  enum class StepMatrix { kNone, kReady, kRefused };
  StepMatrix stick_step_state_ = StepMatrix::kNone;
  Eigen::MatrixXd stick_step_matrix_, stick_step_work_;
};

}  // namespace stiction
