#include "stiction/admm.hpp"

#include <chrono>
#include <cmath>

#include "stiction/cone.hpp"

namespace stiction {

double largestEigenvalue(const ContactProblem& problem, int iterations) {
  const Eigen::Index m = problem.numRows();
  if (m == 0) return 0.0;
  Eigen::VectorXd x = Eigen::VectorXd::Ones(m) / std::sqrt(double(m)), y(m), yt(m);
  const Eigen::MatrixXd& A = problem.delassus().dense();
  double L = 0.0;
  for (int i = 0; i < iterations; ++i) {
    y.noalias() = A * x;
    if (!problem.isSymmetric()) {
      yt.noalias() = A.transpose() * x;
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

namespace {

// v += sign * E s(u): the De Saxce shift mu ||u_t|| on each normal row (eq. 76-77).
void addDesaxce(const ContactProblem& problem, const Eigen::VectorXd& u, double sign, Eigen::VectorXd& v) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    if (cons[i].kind == ConstraintKind::kSpatialFriction)
      v[o + 2] += sign * cons[i].mu * std::hypot(u[o], u[o + 1]);
    else if (cons[i].kind == ConstraintKind::kPlanarFriction)
      v[o + 1] += sign * cons[i].mu * std::abs(u[o]);
  }
}

}  // namespace

void AdmmSolver::factorize(const ContactProblem& problem, double shift) {
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
  if (symmetric_)
    llt_.solveInPlace(x);
  else
    x = lu_.solve(x);
}

void AdmmSolver::iterate(const ContactProblem& problem, const SolverSettings& settings,
                         SolverResult& result) {
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const Eigen::Index m = problem.numRows();
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const DelassusOperator& A = problem.delassus();
  const double scale = 1.0 + problem.b().norm();
  symmetric_ = problem.isSymmetric();

  const double L = std::max(largestEigenvalue(problem), 1e-300);
  const double prox = 1e-10 * L;  // proximal term: keeps the linear solve well posed
  double rho = settings.admm_rho > 0.0 ? settings.admm_rho : 1e-2 * L;
  factorize(problem, rho + prox);

  Eigen::VectorXd& lam = result.lam;
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
    addDesaxce(problem, u_, -1.0, y_);
  }
  lam = z_;
  result.message = "iteration limit reached";
  int it = 0;
  int last_rho_change = 0;
  for (; it < settings.max_iterations; ++it) {
    // lambda-update: (A + (rho + prox) I) lambda = b - E s + rho z - y + prox lambda.
    // s comes from the unconstrained iterate lambda, not from z: measured on
    // sliding stacks, s(z) makes the iteration cycle (mass ratio 1e2 already),
    // s(lambda) converges.
    A.multiply(lam, ulam_);
    ulam_ -= problem.b();
    rhs_ = problem.b() + rho * z_ - y_ + prox * lam;
    addDesaxce(problem, ulam_, -1.0, rhs_);
    lam = rhs_;
    solveShifted(lam);
    // z-update and dual ascent
    z_prev_ = z_;
    z_ = lam + y_ / rho;
    projectOntoConstraints(problem, z_);
    y_ += rho * (lam - z_);
    A.multiply(z_, u_);
    u_ -= problem.b();
    const double r = naturalMapNorm(problem, z_, u_) / scale;
    if (r <= settings.tolerance) {
      result.message = "converged";
      ++it;
      break;
    }
    if (!std::isfinite(r)) {
      result.message = "diverged (non-finite residual)";
      ++it;
      break;
    }
    // Residual balancing: primal ||lambda - z|| against dual rho ||z - z_prev||.
    const double primal = (lam - z_).lpNorm<Eigen::Infinity>();
    const double dual = rho * (z_ - z_prev_).lpNorm<Eigen::Infinity>();
    if (it - last_rho_change >= 5) {
      double factor = 1.0;
      if (primal > 10.0 * dual) factor = 5.0;
      else if (dual > 10.0 * primal) factor = 0.2;
      const double new_rho = rho * factor;
      if (factor != 1.0 && new_rho > 1e-8 * L && new_rho < 1e4 * L) {
        rho = new_rho;
        factorize(problem, rho + prox);
        last_rho_change = it;
      }
    }
    if (settings.time_limit > 0.0 &&
        std::chrono::duration<double>(Clock::now() - start).count() > settings.time_limit) {
      result.message = "time limit reached";
      ++it;
      break;
    }
  }
  lam = z_;  // the feasible iterate
  result.iterations = it;
}

}  // namespace stiction
