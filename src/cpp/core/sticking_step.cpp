// The sticking step (sticking_step.hpp): the all-stick solution by a proximal factorization of A
// (dense, sparse, or in 3 x 3 blocks), refined, with the factor held between calls while A stays.
#include "stiction/sticking_step.hpp"

#include <algorithm>
#include <cmath>

#include "stiction/cone.hpp"
#include "stiction/verdict.hpp"

namespace stiction {

// Every block of x strictly inside its cone: a unilateral row pushing, a friction block's
// tangential part below mu times a positive normal part, a box row inside its interval (bilateral
// rows: any value), by a relative
// margin: a block at the edge of slipping (statically indeterminate friction left at mu |lambda_n|
// by an earlier solve, as in a grid of resting cubes) would most likely leave the cone in the
// all-stick solution, and the factorization would be wasted. With de_saxce, the normal part is
// first shifted by De Saxce's term, x_n - mu |x_t| (see stickingAtZero).
constexpr double kInsideMargin = 1e-6;

namespace {

// A_oo (one entry of A's diagonal).
double diagonalEntry(const ContactProblem& problem, Eigen::Index o) {
  double a_oo = 0.0;
  Eigen::Map<Eigen::MatrixXd> entry(&a_oo, 1, 1);
  problem.delassus().diagonalBlock(o, 1, entry);
  return a_oo;
}

// Block i of x strictly inside its cone (strictlyInsideCones, one block).
bool blockStrictlyInside(const ContactProblem& problem, std::size_t i, const Eigen::VectorXd& x, bool de_saxce) {
  const Constraint& c = problem.constraints()[i];
  const Eigen::Index o = problem.offsets()[i];
  const double mu = c.mu;
  const double shift = de_saxce ? 1.0 : 0.0;
  switch (c.kind) {
    case ConstraintKind::kBilateral: return true;
    case ConstraintKind::kUnilateral: return x[o] > 0.0;
    case ConstraintKind::kPlanarFriction: {
      const double t = std::abs(x[o]);
      return t < (1.0 - kInsideMargin) * mu * (x[o + 1] - shift * mu * t);
    }
    case ConstraintKind::kSpatialFriction: {
      const double t = norm2(x[o], x[o + 1]);
      return t < (1.0 - kInsideMargin) * mu * (x[o + 2] - shift * mu * t);
    }
    case ConstraintKind::kBox: {
      // strictly inside the interval, by the margin; de_saxce (x = b, lambda = 0): the natural map's
      // argument there, b / A_oo (Newton's kappa = 1 / A_oo; a row that moves nothing: b = 0)
      double v = x[o];
      if (de_saxce) {
        const double a_oo = diagonalEntry(problem, o);
        if (!(a_oo > 0.0)) {
          if (x[o] != 0.0) return false;
        } else {
          v = x[o] / a_oo;
        }
      }
      const double margin = kInsideMargin * (c.upper - c.lower);
      return v > c.lower + margin && v < c.upper - margin;
    }
  }
  return false;
}

}  // namespace

bool strictlyInsideCones(const ContactProblem& problem, const Eigen::VectorXd& x, bool de_saxce) {
  for (std::size_t i = 0; i < problem.numBlocks(); ++i)
    if (!blockStrictlyInside(problem, i, x, de_saxce)) return false;
  return true;
}

namespace {

// Rows can be held on a bound (pinned) in the dense factor: a dense A of up to kDenseFactorRows
// rows, with box rows (contact-only problems keep their all-stick test).
bool canPin(const ContactProblem& problem) {
  return problem.hasBoxRows() && problem.delassus().sparse() == nullptr && problem.numRows() <= kDenseFactorRows;
}

}  // namespace

bool restingOnBounds(const ContactProblem& problem, const Eigen::VectorXd& lam) {
  if (!problem.hasBoxRows()) return false;
  const bool pin = canPin(problem);
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  // A box row within the margin of a bound: -1 lower, +1 upper; 0 strictly inside (or not a box row)
  auto side = [&](std::size_t i) -> int {
    const Constraint& c = cons[i];
    if (c.kind != ConstraintKind::kBox) return 0;
    const double v = lam[off[i]], margin = kInsideMargin * (c.upper - c.lower);
    if (v > c.lower + margin && v < c.upper - margin) return 0;
    return std::abs(v - c.lower) <= margin ? -1 : std::abs(v - c.upper) <= margin ? 1 : 2;
  };
  bool on_bound = false, box_on_bound = false;
  for (std::size_t i = 0; i < cons.size(); ++i) {
    if (blockStrictlyInside(problem, i, lam, false)) continue;
    if (pin && cons[i].kind == ConstraintKind::kUnilateral && lam[off[i]] == 0.0) {
      on_bound = true;  // (held open by the sticking step when u lets it, else closed by it)
      continue;
    }
    const int s = side(i);
    if (s != -1 && s != 1) return false;
    on_bound = box_on_bound = true;
  }
  if (!box_on_bound) return on_bound;  // (unilateral rows at 0 only: no product)
  // Each row on a bound: the natural map's argument z = lambda - u / A_oo at the guess
  // (u = A lambda - b) within the margin of the interval: u does not push it off its bound.
  thread_local Eigen::VectorXd u;
  u.resize(problem.numRows());
  problem.delassus().multiply(lam, u);
  u -= problem.b();
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const int s = side(i);
    if (s == 0) continue;
    const Eigen::Index o = off[i];
    const double a_oo = diagonalEntry(problem, o);
    if (!(a_oo > 0.0)) return false;  // (a row that moves nothing: its u = -b whatever lambda)
    const double push = (s > 0 ? -u[o] : u[o]) / a_oo;  // how far past the bound z lies
    if (!(push <= kInsideMargin * (cons[i].upper - cons[i].lower))) return false;
  }
  return true;
}

// At lambda = 0 the natural map of eq. 65 puts every block in its sticking regime when its
// argument there, -kappa (u + mu |u_t| e_n) with u = -b, is strictly inside the cone: b inside the
// cones once shifted by De Saxce's term (|b_t| < mu (b_n - mu |b_t|); unilateral rows b_n > 0).
// Newton's first step from zero then aims at the all-stick solution, but regularised (its shift is
// largest there, ~1 % of the scaled Jacobian: CubesH8-27 took 4 steps, 0.019, 3e-4, 9e-8, 8e-15);
// one factorization of A reaches it. Only a prediction: the sticking step's stopping test decides,
// and Newton follows if it fails.
bool stickingAtZero(const ContactProblem& problem) {
  return strictlyInsideCones(problem, problem.b(), /*de_saxce=*/true);
}

bool stickingGuess(const ContactProblem& problem, const Eigen::VectorXd& lam) {
  return strictlyInsideCones(problem, lam) || (lam.isZero(0.0) && stickingAtZero(problem)) ||
         restingOnBounds(problem, lam);
}

bool StickingStep::factorShifted(const ContactProblem& problem, double shift) {
  const Eigen::Index m = problem.numRows();
  const Eigen::SparseMatrix<double>* S = problem.delassus().sparse();
  if (S == nullptr && m > kDenseFactorRows) {
    const Eigen::MatrixXd& A = problem.delassus().dense();
    // A's values into the pattern held from the last step when its nonzeros fit in it: entries
    // that are exactly zero in one step and not in the next (a tower standing straight) would
    // otherwise change the pattern and repeat the ordering every step.
    bool fits = stick_from_dense_ && stick_sparse_.rows() == m;
    for (Eigen::Index j = 0; fits && j < m; ++j) {
      Eigen::Index placed = 0;
      for (Eigen::SparseMatrix<double>::InnerIterator it(stick_sparse_, j); it; ++it) {
        it.valueRef() = A(it.row(), j);
        placed += it.value() != 0.0;
      }
      fits = placed == (A.col(j).array() != 0.0).count();
    }
    if (fits) {
      S = &stick_sparse_;
    } else if (double((A.array() != 0.0).count()) <= kStickSparseDensity * double(m) * double(m)) {
      stick_sparse_ = A.sparseView();
      stick_sparse_.makeCompressed();
      S = &stick_sparse_;
    }
    stick_from_dense_ = S != nullptr;
  }
  stick_sparse_path_ = S != nullptr;
  if (stick_sparse_path_ && !stick_pinned_.empty()) return false;  // (canPin: not reached)
  if (stick_sparse_path_) {
    // The ordering (AMD) and symbolic factor are kept while A's pattern stays (the same contacts
    // from step to step).
    const auto nnz = static_cast<std::size_t>(S->nonZeros());
    const bool same = S->isCompressed() && stick_outer_.size() == static_cast<std::size_t>(m + 1) &&
                      stick_inner_.size() == nnz &&
                      std::equal(stick_outer_.begin(), stick_outer_.end(), S->outerIndexPtr()) &&
                      std::equal(stick_inner_.begin(), stick_inner_.end(), S->innerIndexPtr());
    if (!same) {
      if (!S->isCompressed()) return false;
      // spatial contacts only: factored in their 3 x 3 blocks (block_cholesky.hpp)
      const auto& offsets = problem.offsets();
      bool spatial = m % 3 == 0;
      for (std::size_t i = 0; spatial && i + 1 < offsets.size(); ++i) spatial = offsets[i + 1] - offsets[i] == 3;
      stick_blocked_ = spatial && stick_block_.analyze(*S);
      if (!stick_blocked_) {
        stick_sparse_llt_.analyzePattern(*S);
        stick_natural_llt_.analyzePattern(*S);
        // the symbolic analysis sizes L exactly: compare the fills
        stick_natural_ = stick_natural_llt_.matrixL().nestedExpression().nonZeros() <=
                         stick_sparse_llt_.matrixL().nestedExpression().nonZeros() * 11 / 10;
      }
      stick_outer_.assign(S->outerIndexPtr(), S->outerIndexPtr() + m + 1);
      stick_inner_.assign(S->innerIndexPtr(), S->innerIndexPtr() + nnz);
    }
    if (stick_blocked_) return stick_block_.factorize(*S, shift);
    if (stick_natural_) {
      stick_natural_llt_.setShift(shift);
      stick_natural_llt_.factorize(*S);
      return stick_natural_llt_.info() == Eigen::Success;
    }
    stick_sparse_llt_.setShift(shift);
    stick_sparse_llt_.factorize(*S);
    return stick_sparse_llt_.info() == Eigen::Success;
  }
  stick_shifted_ = problem.delassus().dense();
  stick_shifted_.diagonal().array() += shift;
  // a pinned row's large shift holds it out of the system: R^-1 is (R_SS)^-1 on the others, to
  // O(1 / kPinShift), and ~0 on it
  for (Eigen::Index o : stick_pinned_) stick_shifted_(o, o) += kPinShift / kStickShift * shift;
  stick_llt_.compute(stick_shifted_);
  return stick_llt_.info() == Eigen::Success;
}

bool StickingStep::run(const ContactProblem& problem, Eigen::VectorXd& lam, double tolerance, int& solves) {
  solves = 0;
  stick_used_held_ = false;
  const DelassusOperator& A = problem.delassus();
  StoppingTest test(problem, tolerance);
  stick_x_ = lam;
  stick_u_.resize(lam.size());
  stick_abs_.resize(lam.size());
  stick_w_.resize(lam.size());
  A.multiplyWithAbs(stick_x_, stick_u_, stick_abs_);
  stick_u_ -= problem.b();
  const double initial_map = naturalMapNorm(problem, stick_x_, stick_u_);
  // the guess may be the answer already (a scene at rest whose A and b did not change)
  StoppingTest::Outcome outcome = test.check(stick_x_, stick_u_, initial_map, /*u_is_fresh=*/true, &stick_abs_);
  if (outcome == StoppingTest::kConverged) return true;
  stick_diagonal_.resize(lam.size());
  A.diagonal(stick_diagonal_);
  const double scale = stick_diagonal_.cwiseAbs().maxCoeff();
  if (!(scale > 0.0) || !std::isfinite(scale)) return false;
  // Rows that rest on a bound with u not pushing them off it are pinned there (restingOnBounds):
  // unilateral rows the guess holds open (lambda = 0, u >= 0, or closing at most a millionth of b_o,
  // their velocity with no force) stay open, and a box row on a bound that u presses against stays
  // on it exactly. (A joint touching its limit with its dry friction beside it: the two rows are
  // +-e_dof, and the all-stick correction split between them pulled on the limit; TALOS's grippers.) (Left free, the all-stick answer puts such a box
  // row a rounding past its bound, within the tolerance; the simulator's next guess clamps it back,
  // and every step then took a refinement: go2-stand with 0.5 N m friction.)
  stick_pinned_.clear();
  stick_pinned_value_.clear();
  if (canPin(problem)) {
    const auto& cons = problem.constraints();
    const auto& off = problem.offsets();
    for (std::size_t i = 0; i < cons.size(); ++i) {
      const Eigen::Index o = off[i];
      const double v = stick_x_[o], u = stick_u_[o];
      if (cons[i].kind == ConstraintKind::kUnilateral && v == 0.0 && u >= -kInsideMargin * std::abs(problem.b()[o])) {
        stick_pinned_.push_back(o);
        stick_pinned_value_.push_back(0.0);
      } else if (cons[i].kind == ConstraintKind::kBox) {
        const double margin = kInsideMargin * (cons[i].upper - cons[i].lower);
        if (std::abs(v - cons[i].lower) <= margin && u >= 0.0) {
          stick_pinned_.push_back(o);
          stick_pinned_value_.push_back(cons[i].lower);
        } else if (std::abs(v - cons[i].upper) <= margin && u <= 0.0) {
          stick_pinned_.push_back(o);
          stick_pinned_value_.push_back(cons[i].upper);
        }
      }
    }
  }
  // Refinement solves with the factor in hand: 1 converged, 0 unresolvable, -1 stalled (the
  // natural map not halved by a solve) or out of solves. first_map: the natural map after the first.
  double natural_map = initial_map, first_map = -1.0;
  auto refine = [&]() -> int {
    first_map = -1.0;
    while (solves < kStickSolves) {
      // d = R^-1 A R^-1 (A x - b), R = A + rho I: a step on the linear all-stick system filtered to
      // A's range. (The plain proximal step R^-1 (A x - b) also moves by r_0 / rho along A's null
      // space, r_0 the part of A x - b no force can cancel (b's rounding, gaps no rigid motion
      // fits): on a 64-box tower 2e-3 N s a step, until a corner's force left its cone.)
      const double previous = natural_map;
      refinementDirection(stick_u_, stick_d_);
      ++solves;
      stick_x_ -= stick_d_;
      for (std::size_t k = 0; k < stick_pinned_.size(); ++k)  // (each moved by ~u_o / the pin shift)
        stick_x_[stick_pinned_[k]] = stick_pinned_value_[k];
      A.multiplyWithAbs(stick_x_, stick_u_, stick_abs_);
      stick_u_ -= problem.b();
      natural_map = naturalMapNorm(problem, stick_x_, stick_u_);
      if (first_map < 0.0) first_map = natural_map;
      outcome = test.check(stick_x_, stick_u_, natural_map, /*u_is_fresh=*/true, &stick_abs_);
      if (outcome == StoppingTest::kConverged) return 1;
      // a contact that should open or slip: the all-stick point leaves the cones and the natural
      // map stops falling
      if (outcome == StoppingTest::kUnresolvable) return 0;
      if (!(natural_map < 0.5 * previous)) return -1;
    }
    return -1;
  };
  // The factor of the previous call, while its matrix is close to this A (the same contacts a step
  // later: a tower at rest, a robot standing) and its last use converged in one refinement step or
  // predicts one will do (its rate: the natural map's reduction by that first step, an upper bound
  // when the step reached the rounding floor): that step saves the factorization
  // (a 256-contact tower's sparse Cholesky, a quarter of its step). Where A moves with the joints
  // (TALOS: 3.7e-4 -> 1.3e-9 by a stale factor, 5e-14 by a fresh one) a fresh factor is cheaper
  // than a second step; the stale one is tried again every kStaleRetry calls. A small dense factor
  // with its step matrix G makes a step one product (~0.1 us at 12 rows, where a fresh factor and
  // its solves cost ~0.8 us): there up to kHeldStepsWithProduct steps are worth it (Solo-12 settling
  // on its feet: 2-3 steps, where one step's rule refactored 9 steps in 10). Whatever the factor,
  // only StoppingTest's verdict is kept.
  if (heldFactorFits(problem)) {
    // (a factor not tried since it was made may still get G: predicted at its best)
    const bool may_have_product = stick_step_state_ != StepMatrix::kRefused && !stick_sparse_path_ &&
                                  problem.numRows() <= kStickSmallRows;
    if (stale_cheap_ || std::pow(stale_rate_, may_have_product ? kHeldStepsWithProduct : 1) * initial_map <= test.threshold() ||
        ++stale_skipped_ >= kStaleRetry) {
      stale_skipped_ = 0;
      if (stick_step_state_ == StepMatrix::kNone) prepareStepMatrix();
      const int worth = stick_step_state_ == StepMatrix::kReady ? kHeldStepsWithProduct : 1;
      const int done = refine();
      stale_rate_ = first_map >= 0.0 && initial_map > 0.0 ? first_map / initial_map : 1.0;
      stale_cheap_ = done == 1 && solves <= worth;
      if (done >= 0) {
        if (done == 1) lam = stick_x_;
        stick_used_held_ = done == 1;
        return done == 1;
      }
      // stalled: a fresh factor, from the guess again
      stick_x_ = lam;
      A.multiply(stick_x_, stick_u_);
      stick_u_ -= problem.b();
      natural_map = initial_map;
    }
  }
  if (!factorShifted(problem, kStickShift * scale)) {
    stick_factor_rows_ = -1;
    return false;
  }
  stick_factor_rows_ = problem.numRows();
  stick_factor_shift_ = kStickShift * scale;
  stick_factor_pinned_ = stick_pinned_;
  stick_factor_pin_shift_ = kPinShift * scale;
  stick_step_state_ = StepMatrix::kNone;  // (a fresh factor's own step: the solves)
  stick_factor_diagonal_ = stick_diagonal_;
  if (refine() == 1) {
    lam = stick_x_;
    return true;
  }
  return false;
}

void StickingStep::refinementDirection(const Eigen::VectorXd& r, Eigen::VectorXd& d) {
  if (stick_step_state_ == StepMatrix::kReady) {
    d.noalias() = stick_step_matrix_ * r;
    return;
  }
  // (A R^-1 r = r - rho R^-1 r: the filter costs a second solve, not a product)
  solveShifted(r, d);
  stick_w_ = r - stick_factor_shift_ * d;
  for (Eigen::Index o : stick_factor_pinned_) stick_w_[o] -= stick_factor_pin_shift_ * d[o];  // (A = R - rho I - M P)
  solveShifted(stick_w_, d);
}

void StickingStep::prepareStepMatrix() {
  stick_step_state_ = StepMatrix::kRefused;
  const Eigen::Index m = stick_factor_rows_;
  if (stick_sparse_path_ || m <= 0 || m > kStickSmallRows || stick_shifted_.rows() != m) return;
  if (!stick_factor_pinned_.empty()) return;  // (its pivots' spread refuses it anyway)
  // Explicit inverses are as accurate as the solves only while R is well conditioned; near a
  // rank-deficient A (a sole's four corners: R^-1 ~ 1 / rho along A's null space) R^-1 - rho R^-2
  // would cancel to nothing. The pivots bound cond(R) from below (free: TALOS's soles, 1e11, stop
  // here, before an inverse); then its 1-norm condition number, exactly, from R and R^-1.
  const auto pivots = stick_llt_.matrixLLT().diagonal().cwiseAbs();
  const double spread = pivots.maxCoeff() / pivots.minCoeff();
  if (!(spread * spread <= kStepMatrixMaxCondition)) return;
  stick_step_matrix_.setIdentity(m, m);
  stick_llt_.solveInPlace(stick_step_matrix_);  // R^-1
  const double cond = stick_shifted_.cwiseAbs().colwise().sum().maxCoeff() *
                      stick_step_matrix_.cwiseAbs().colwise().sum().maxCoeff();
  if (!(cond <= kStepMatrixMaxCondition)) return;
  stick_step_work_.noalias() = stick_step_matrix_ * stick_step_matrix_;
  stick_step_matrix_ -= stick_factor_shift_ * stick_step_work_;
  stick_step_state_ = StepMatrix::kReady;
}

void StickingStep::solveShifted(const Eigen::VectorXd& rhs, Eigen::VectorXd& x) const {
  if (!stick_sparse_path_ && rhs.size() <= kStickSmallRows) {
    // L L^T x = rhs by substitutions that read L across its columns (strided: one value at a time)
    // and write each x once: Eigen's blocked triangular solves cost ~700 instructions each at a
    // robot's 12 rows, and a vectorised column sweep would read x two values at a time right after
    // writing them one at a time (a load spanning two stores waits for both)
    const Eigen::MatrixXd& L = stick_llt_.matrixLLT();
    const Eigen::Index m = L.rows();
    const double* l = L.data();  // L(i, j) at j * m + i
    x = rhs;
    double* v = x.data();
    for (Eigen::Index i = 0; i < m; ++i) {  // L y = rhs, row by row
      double s = v[i];
      for (Eigen::Index j = 0; j < i; ++j) s -= l[j * m + i] * v[j];
      v[i] = s / l[i * m + i];
    }
    for (Eigen::Index j = m - 1; j >= 0; --j) {  // L^T x = y, column by column of L^T (rows of L)
      const double xj = v[j] / l[j * m + j];
      v[j] = xj;
      for (Eigen::Index i = 0; i < j; ++i) v[i] -= l[i * m + j] * xj;
    }
  } else if (!stick_sparse_path_)
    x = stick_llt_.solve(rhs);
  else if (stick_blocked_)
    stick_block_.solve(rhs, x);
  else if (stick_natural_)
    x = stick_natural_llt_.solve(rhs);
  else
    x = stick_sparse_llt_.solve(rhs);
}

bool StickingStep::heldFactorFits(const ContactProblem& problem) const {
  const Eigen::Index m = problem.numRows();
  if (stick_factor_rows_ != m || stick_factor_diagonal_.size() != m || stick_diagonal_.size() != m) return false;
  if (stick_pinned_ != stick_factor_pinned_) return false;
  // the same rows (a cheap fingerprint: A's diagonal, stick_diagonal_, within kStaleDiagonalChange of
  // the factored one's)
  const double scale = stick_factor_diagonal_.cwiseAbs().maxCoeff();
  return (stick_diagonal_ - stick_factor_diagonal_).cwiseAbs().maxCoeff() <= kStaleDiagonalChange * scale;
}

}  // namespace stiction
