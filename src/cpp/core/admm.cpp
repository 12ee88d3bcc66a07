#include "stiction/admm.hpp"

#include <cmath>
#include <limits>
#include <vector>

#include "stiction/cone.hpp"
#include "stiction/thresholds.hpp"
#include "stiction/verdict.hpp"

namespace stiction {

double largestEigenvalue(const ContactProblem& problem, int iterations) {
  const Eigen::Index m = problem.numRows();
  if (m == 0) return 0.0;
  Eigen::VectorXd x = Eigen::VectorXd::Ones(m) / std::sqrt(double(m)), y(m), yt(m);
  const DelassusOperator& A = problem.delassus();
  double L = 0.0;
  for (int i = 0; i < iterations; ++i) {
    A.multiply(x, y);
    if (!problem.isSymmetric()) {
      A.multiplyTransposed(x, yt);
      y = 0.5 * (y + yt);
    }
    L = x.dot(y);
    const double n = y.norm();
    if (!(n > 0.0)) break;
    x = y / n;
  }
  return std::max(L, A.diagonal().maxCoeff());
}

void projectOntoConstraints(const ContactProblem& problem, Eigen::Ref<Eigen::VectorXd> x) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  for (std::size_t i = 0; i < cons.size(); ++i) {
    auto xi = x.segment(off[i], cons[i].size);
    switch (cons[i].kind) {
      case ConstraintKind::kBilateral: break;
      case ConstraintKind::kUnilateral: xi[0] = std::max(0.0, xi[0]); break;
      case ConstraintKind::kPlanarFriction: projectPlanarCone(xi, cons[i].mu); break;
      case ConstraintKind::kSpatialFriction: projectSpatialCone(xi, cons[i].mu); break;
      case ConstraintKind::kBox: xi[0] = clampToBox(xi[0], cons[i].lower, cons[i].upper); break;
    }
  }
}

double coneNaturalMap(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                      const Eigen::Ref<const Eigen::VectorXd>& u, Eigen::VectorXd& work) {
  work = lam - u;
  projectOntoConstraints(problem, work);
  return (lam - work).norm();
}

namespace {

// Above kAdmmLargeRows rows (thresholds.hpp) a factorization costs more than many iterations:
// the stopping test (a product with A) runs every kCheckEvery iterations, and rho changes less
// often.
constexpr int kCheckEvery = 4;
// Residual balancing: rho moves when ADMM's primal and dual residuals differ by more than a
// threshold (10), by the square root of their ratio (at most kMaxRhoStep either way); on a
// large problem each reversal of direction doubles the threshold. Measured on the Capsules
// FCLib problems: the fixed x5 / /5 steps of before oscillated between two values around the
// balanced rho (10 of 14 refactorizations on i122, each a dense Cholesky of 888 rows, cost
// more than its 834 iterations); now 5-7 (i122: 7 for 1056 iterations). On small problems
// refactorizing is cheap and the growing threshold only slows convergence (the CCP on a
// two-cube stack, 24 rows: 3258 iterations with it, 1405 without, 1471 before).
// The stall test looks at the best residual over kStallWindow iterations.
constexpr double kMaxRhoStep = 25.0;
constexpr double kImbalance = 10.0;
constexpr int kStallWindow = 400;

// v += sign * E s(u): the De Saxce shift mu ||u_t|| on each normal row (eq. 76-77).
void addDesaxce(const ContactProblem& problem, const Eigen::VectorXd& u, double sign, Eigen::VectorXd& v) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    if (cons[i].kind == ConstraintKind::kSpatialFriction)
      v[o + 2] += sign * cons[i].mu * norm2(u[o], u[o + 1]);
    else if (cons[i].kind == ConstraintKind::kPlanarFriction)
      v[o + 1] += sign * cons[i].mu * std::abs(u[o]);
  }
}

}  // namespace

bool sparseEnough(const ContactProblem& problem, double density) {
  if (problem.delassus().sparse() != nullptr) return true;  // held sparse: always
  const Eigen::MatrixXd& A = problem.delassus().dense();
  const Eigen::Index m = A.rows();
  return m > kDenseFactorRows && double((A.array() != 0.0).count()) <= density * double(m) * double(m);
}

bool AdmmSolver::factorsSparsely(const ContactProblem& problem) { return sparseEnough(problem, kAdmmSparseDensity); }

void AdmmSolver::prepareSparse(const ContactProblem& problem) {
  // A problem held sparse (SparseDelassus) is factorized sparsely whatever its size; a dense A
  // is copied to a sparse matrix when that pays: the FCLib problems ADMM is used on are
  // 1.6-4 % nonzero (Capsules 1.6-2 %, KaplasTower 4 %), and their Cholesky factors barely fill
  // in (AMD ordering: Capsules-i122's L has 6.7k nonzeros against 395k for a dense one;
  // KaplasTower's 150k against 1.46M).
  const Eigen::Index m = problem.numRows();
  sparse_ = false;
  if (!factorsSparsely(problem)) return;
  std::vector<Eigen::Triplet<double>> entries;
  if (const Eigen::SparseMatrix<double>* S = problem.delassus().sparse()) {
    entries.reserve(S->nonZeros() + m);
    for (Eigen::Index j = 0; j < S->outerSize(); ++j)
      for (Eigen::SparseMatrix<double>::InnerIterator it(*S, j); it; ++it)
        entries.emplace_back(it.row(), it.col(), it.value());
    for (Eigen::Index j = 0; j < m; ++j) entries.emplace_back(j, j, 0.0);  // the diagonal always
  } else {
    const Eigen::MatrixXd& A = problem.delassus().dense();
    for (Eigen::Index j = 0; j < m; ++j)
      for (Eigen::Index i = 0; i < m; ++i)
        if (A(i, j) != 0.0 || i == j) entries.emplace_back(i, j, A(i, j));  // the diagonal always
  }
  sparse_A_.resize(m, m);
  sparse_A_.setFromTriplets(entries.begin(), entries.end());  // duplicates are summed
  sparse_A_.makeCompressed();
  sparse_shifted_ = sparse_A_;
  diagonal_.resize(m);  // where each diagonal entry sits in the values array
  for (Eigen::Index j = 0; j < m; ++j)
    for (Eigen::SparseMatrix<double>::InnerIterator it(sparse_shifted_, j); it; ++it)
      if (it.row() == j) diagonal_[j] = &it.valueRef() - sparse_shifted_.valuePtr();
  sparse_ = true;
  sparse_lu_analyzed_ = false;
  if (symmetric_) sparse_llt_.analyzePattern(sparse_A_);
}

void AdmmSolver::factorize(const ContactProblem& problem, double shift) {
  if (sparse_) {
    if (symmetric_) {
      sparse_llt_.setShift(shift);  // factorizes A + shift I
      sparse_llt_.factorize(sparse_A_);
      if (sparse_llt_.info() == Eigen::Success) return;
      symmetric_ = false;  // not quite SPD: fall back to LU
    }
    const double* a = sparse_A_.valuePtr();
    double* v = sparse_shifted_.valuePtr();
    for (Eigen::Index j = 0; j < sparse_A_.cols(); ++j) v[diagonal_[j]] = a[diagonal_[j]] + shift;
    if (!sparse_lu_analyzed_) {
      sparse_lu_.analyzePattern(sparse_shifted_);
      sparse_lu_analyzed_ = true;
    }
    sparse_lu_.factorize(sparse_shifted_);
    if (sparse_lu_.info() == Eigen::Success) return;
    sparse_ = false;  // (not expected: A + shift I is nonsingular) the dense path below
  }
  const Eigen::MatrixXd& A = problem.delassus().dense();
  shifted_ = A;
  shifted_.diagonal().array() += shift;
  if (symmetric_) {
    llt_.compute(shifted_);
    if (llt_.info() != Eigen::Success) {  // not quite SPD: fall back to LU
      symmetric_ = false;
      lu_.compute(shifted_);
    }
  } else {
    lu_.compute(shifted_);
  }
}

void AdmmSolver::solveShifted(Eigen::VectorXd& x) {
  if (sparse_) {
    work_ = x;
    if (symmetric_)
      x = sparse_llt_.solve(work_);
    else
      x = sparse_lu_.solve(work_);
  } else if (symmetric_) {
    llt_.solveInPlace(x);
  } else {
    x = lu_.solve(x);
  }
}

void AdmmSolver::multiplyA(const ContactProblem& problem, const Eigen::VectorXd& x, Eigen::VectorXd& y) const {
  if (sparse_ && problem.delassus().sparse() == nullptr)  // a dense A with a sparse copy
    y.noalias() = sparse_A_ * x;
  else
    problem.delassus().multiply(x, y);
}

double AdmmSolver::largestEigenvalueEstimate(const ContactProblem& problem, int iterations) {
  if (!sparse_ || problem.delassus().sparse() != nullptr) return largestEigenvalue(problem, iterations);
  const Eigen::Index m = problem.numRows();
  Eigen::VectorXd x = Eigen::VectorXd::Ones(m) / std::sqrt(double(m)), y(m);
  double L = 0.0;
  for (int i = 0; i < iterations; ++i) {
    if (problem.isSymmetric())
      y.noalias() = sparse_A_ * x;
    else
      y.noalias() = 0.5 * (sparse_A_ * x + sparse_A_.transpose() * x);
    L = x.dot(y);
    const double n = y.norm();
    if (!(n > 0.0)) break;
    x = y / n;
  }
  return std::max(L, sparse_A_.diagonal().maxCoeff());
}

int AdmmSolver::run(const ContactProblem& problem, Eigen::VectorXd& lam, int max_iterations,
                    double tolerance, double time_limit, double initial_rho, bool resume,
                    std::string& message, double switch_after) {
  monitor_.startClock(time_limit);
  const Eigen::Index m = problem.numRows();
  const double scale = stoppingScale(problem);
  StoppingTest test(problem, tolerance);
  if (!resume || primal_.size() != m) {
    symmetric_ = problem.isSymmetric();
    prepareSparse(problem);
    L_ = largestEigenvalueEstimate(problem, 30);
    if (!(L_ > 0.0)) L_ = 1.0;  // A = 0: no spectrum to scale rho by (1e-300 sent lambda to 1e302)
    prox_ = 1e-10 * L_;  // proximal term: keeps the linear solve well posed
    rho_ = initial_rho > 0.0 ? initial_rho : 1e-2 * L_;
    factorize(problem, rho_ + prox_);
    z_ = lam;
    projectOntoConstraints(problem, z_);
    u_.resize(m);
    ulam_.resize(m);
    rhs_.resize(m);
    // Dual guess: at the solution y = -(u + E s(u)); from a cold start y = 0.
    y_.setZero(m);
    if (z_.squaredNorm() > 0.0) {
      multiplyA(problem, z_, u_);
      u_ -= problem.b();
      y_ = -u_;
      if (desaxce_) addDesaxce(problem, u_, -1.0, y_);
    }
    primal_ = z_;
    multiplyA(problem, primal_, ulam_);  // later iterations get A x from their linear solve
    ulam_ -= problem.b();
    since_rho_change_ = 0;
    imbalance_ = kImbalance;
    last_factor_ = 1.0;
    best_r_ = std::numeric_limits<double>::infinity();
    monitor_.resetRate(kStallWindow);
    monitor_.record(0, best_r_);
    total_iterations_ = 0;
  }
  message = "iteration limit reached";
  int it = 0;
  for (; it < max_iterations; ++it) {
    // primal update: (A + (rho + prox) I) x = b - E s + rho z - y + prox x.
    // s comes from the unconstrained iterate x, not from z: measured on
    // sliding stacks, s(z) makes the iteration cycle (mass ratio 1e2 already),
    // s(x) converges.
    rhs_ = problem.b() + rho_ * z_ - y_ + prox_ * primal_;
    if (desaxce_) addDesaxce(problem, ulam_, -1.0, rhs_);
    primal_ = rhs_;
    solveShifted(primal_);
    // A x - b for the next iteration's De Saxce term, from the solve itself:
    // (A + shift I) x = rhs, so A x = rhs - shift x. A backward-stable solve makes this as
    // accurate as the product (its residual is ~eps |A||x| however ill-conditioned A is; the
    // iterates on Capsules-i122 are the same to the last printed digit either way), and it
    // saves one of the two products with A per iteration.
    ulam_.noalias() = rhs_ - (rho_ + prox_) * primal_ - problem.b();
    // z-update (projection onto C) and dual ascent
    z_prev_ = z_;
    z_ = primal_ + y_ / rho_;
    projectOntoConstraints(problem, z_);
    y_ += rho_ * (primal_ - z_);
    // The stopping test needs u at z, one product with A: as much as the rest of the
    // iteration (the two triangular solves) on a large problem, so there it runs every
    // kCheckEvery iterations (at most kCheckEvery - 1 iterations late).
    if (m <= kAdmmLargeRows || (it + 1) % kCheckEvery == 0 || it + 1 == max_iterations) {
      multiplyA(problem, z_, u_);
      u_ -= problem.b();
      const double map = desaxce_ ? naturalMapNorm(problem, z_, u_) : coneNaturalMap(problem, z_, u_, rhs_);
      const StoppingTest::Outcome outcome =
          desaxce_ ? test.check(z_, u_, map)
                   : (map <= tolerance * scale ? StoppingTest::kConverged : StoppingTest::kContinue);
      if (outcome != StoppingTest::kContinue) {
        message = outcome == StoppingTest::kConverged ? "converged" : kUnresolvableMessage;
        ++it;
        break;
      }
      const double r = map / scale;
      best_r_ = std::min(best_r_, r);
      if (!std::isfinite(r)) {
        message = "diverged (non-finite residual)";
        ++it;
        break;
      }
      if (switch_after > 0.0) {
        // Stalled when the best residual so far, at its rate over the last kStallWindow
        // iterations, would need more than switch_after further iterations (or did not
        // improve at all). The best, not the last: ADMM's residual wanders (rho and the
        // active set change) and plateaus for hundreds of iterations before dropping
        // (Capsules-i122: 1.6e-7 from iteration 440 to 880, then 1e-8 at 1040).
        monitor_.record(total_iterations_ + it + 1, best_r_);  // since the start, over resumed runs
        if (monitor_.stalled(tolerance, switch_after)) {
          message = "stalled";
          ++it;
          break;
        }
      }
    }
    // Residual balancing: primal ||x - z|| against dual rho ||z - z_prev||.
    const double primal_res = (primal_ - z_).lpNorm<Eigen::Infinity>();
    const double dual_res = rho_ * (z_ - z_prev_).lpNorm<Eigen::Infinity>();
    if (++since_rho_change_ >= 5) {
      double factor = 1.0;
      if (primal_res > imbalance_ * dual_res || dual_res > imbalance_ * primal_res) {
        factor = dual_res > 0.0 ? std::sqrt(primal_res / dual_res) : kMaxRhoStep;
        factor = std::min(kMaxRhoStep, std::max(1.0 / kMaxRhoStep, factor));
        if (m > kAdmmLargeRows && last_factor_ != 1.0 && (factor > 1.0) != (last_factor_ > 1.0)) imbalance_ *= 2.0;
        last_factor_ = factor;
      }
      const double new_rho = rho_ * factor;
      if (factor != 1.0 && new_rho > 1e-8 * L_ && new_rho < 1e4 * L_) {
        rho_ = new_rho;
        factorize(problem, rho_ + prox_);
        since_rho_change_ = 0;
      }
    }
    if (monitor_.outOfTime()) {
      message = "time limit reached";
      ++it;
      break;
    }
  }
  total_iterations_ += it;
  lam = z_;  // the feasible iterate
  return it;
}

void AdmmSolver::iterate(const ContactProblem& problem, const SolverSettings& settings,
                         SolverResult& result) {
  result.iterations = run(problem, result.lam, settings.max_iterations, settings.tolerance,
                          settings.time_limit, settings.admm_rho, false, result.message);
}

}  // namespace stiction
