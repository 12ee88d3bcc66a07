#include "stiction/admm.hpp"

#include <chrono>
#include <cmath>

#include "stiction/cone.hpp"
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

void AdmmSolver::factorize(const ContactProblem& problem, double shift) {
  if (const Eigen::SparseMatrix<double>* S = problem.delassus().sparse()) {
    // Sparse A: a sparse Cholesky (fill-reducing ordering) of the symmetric part + shift.
    sparse_ = true;
    Eigen::SparseMatrix<double> H = 0.5 * (*S + Eigen::SparseMatrix<double>(S->transpose()));
    Eigen::SparseMatrix<double> I(H.rows(), H.cols());
    I.setIdentity();
    H += shift * I;
    sparse_llt_.compute(H);
    if (sparse_llt_.info() == Eigen::Success) return;
    sparse_ = false;  // not quite SPD: the dense LU below
  } else {
    sparse_ = false;
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

void AdmmSolver::solveShifted(Eigen::VectorXd& x) const {
  if (sparse_)
    x = sparse_llt_.solve(x);
  else if (symmetric_)
    llt_.solveInPlace(x);
  else
    x = lu_.solve(x);
}

int AdmmSolver::run(const ContactProblem& problem, Eigen::VectorXd& lam, int max_iterations,
                    double tolerance, double time_limit, double initial_rho, bool resume,
                    std::string& message) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const Eigen::Index m = problem.numRows();
  const DelassusOperator& A = problem.delassus();
  const double scale = stoppingScale(problem);
  StoppingTest test(problem, tolerance);
  if (!resume || primal_.size() != m) {
    symmetric_ = problem.isSymmetric();
    L_ = largestEigenvalue(problem);
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
      A.multiply(z_, u_);
      u_ -= problem.b();
      y_ = -u_;
      if (desaxce_) addDesaxce(problem, u_, -1.0, y_);
    }
    primal_ = z_;
    since_rho_change_ = 0;
  }
  message = "iteration limit reached";
  int it = 0;
  for (; it < max_iterations; ++it) {
    // primal update: (A + (rho + prox) I) x = b - E s + rho z - y + prox x.
    // s comes from the unconstrained iterate x, not from z: measured on
    // sliding stacks, s(z) makes the iteration cycle (mass ratio 1e2 already),
    // s(x) converges.
    A.multiply(primal_, ulam_);
    ulam_ -= problem.b();
    rhs_ = problem.b() + rho_ * z_ - y_ + prox_ * primal_;
    if (desaxce_) addDesaxce(problem, ulam_, -1.0, rhs_);
    primal_ = rhs_;
    solveShifted(primal_);
    // z-update (projection onto C) and dual ascent
    z_prev_ = z_;
    z_ = primal_ + y_ / rho_;
    projectOntoConstraints(problem, z_);
    y_ += rho_ * (primal_ - z_);
    A.multiply(z_, u_);
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
    if (!std::isfinite(r)) {
      message = "diverged (non-finite residual)";
      ++it;
      break;
    }
    // Residual balancing: primal ||x - z|| against dual rho ||z - z_prev||.
    const double primal_res = (primal_ - z_).lpNorm<Eigen::Infinity>();
    const double dual_res = rho_ * (z_ - z_prev_).lpNorm<Eigen::Infinity>();
    if (++since_rho_change_ >= 5) {
      double factor = 1.0;
      if (primal_res > 10.0 * dual_res) factor = 5.0;
      else if (dual_res > 10.0 * primal_res) factor = 0.2;
      const double new_rho = rho_ * factor;
      if (factor != 1.0 && new_rho > 1e-8 * L_ && new_rho < 1e4 * L_) {
        rho_ = new_rho;
        factorize(problem, rho_ + prox_);
        since_rho_change_ = 0;
      }
    }
    if (time_limit > 0.0 && std::chrono::duration<double>(Clock::now() - start).count() > time_limit) {
      message = "time limit reached";
      ++it;
      break;
    }
  }
  lam = z_;  // the feasible iterate
  return it;
}

void AdmmSolver::iterate(const ContactProblem& problem, const SolverSettings& settings,
                         SolverResult& result) {
  result.iterations = run(problem, result.lam, settings.max_iterations, settings.tolerance,
                          settings.time_limit, settings.admm_rho, false, result.message);
}

}  // namespace stiction
