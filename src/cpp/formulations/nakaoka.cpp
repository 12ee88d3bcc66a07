// nakaoka: A dropped from the metric (paper eq. 80-81), per-contact projection as
// Nakaoka et al.'s projected Gauss-Seidel.
//
//     lambda = lim_{eps->0} proj_C^{U_eps}(A^-1 b)                     (eq. 80)
//
// The singular metric U_eps = diag(1, 1, 1/eps) weighs the normal infinitely, so the
// projection of y = (y_t, y_n) onto a friction cone keeps y_n and clips y_t radially to
// the disc of radius mu y_n (0 when y_n <= 0): friction and normal are settled separately,
// as in Nakaoka et al. Gauss-Seidel over contacts: each block i takes its local
// unconstrained solution y_i = lambda_i - A_ii^+ u_i (what makes u_i = 0 with the others
// fixed) and projects it. For one contact the fixed point is exactly eq. 80; with several,
// each contact sees the others only through the current lambda (A's coupling is lost from
// the metric twice over). Where A_ii is not isotropic, or contacts are coupled, the friction
// no longer opposes the sliding velocity and a sliding contact moves along its normal
// (u_n = A_nt Delta_t != 0): the exact law is violated, which is what the paper points out.
//
// Box rows (an interval, one row: no metric question) are clamped: on them the fixed point is
// box complementarity, the exact law (a problem of box rows alone: projected Gauss-Seidel on its QP).
//
// Own stopping test: the fixed point, ||lambda - P^U(lambda - D^+ u)|| <= tol ||lambda||,
// D the block diagonal of A.
#include <Eigen/Eigenvalues>

#include <chrono>
#include <cmath>

#include "stiction/cone.hpp"
#include "formulations.hpp"

namespace stiction {
namespace {

// lim_{eps->0} proj^{U_eps} onto the block's set: normal kept (clipped at 0), tangential
// clipped radially (eq. 59, 80).
void projectSingularMetric(const Constraint& c, Eigen::Ref<Eigen::VectorXd> y) {
  switch (c.kind) {
    case ConstraintKind::kBilateral: return;
    case ConstraintKind::kUnilateral: y[0] = std::max(0.0, y[0]); return;
    case ConstraintKind::kPlanarFriction: {
      const double n = std::max(0.0, y[1]);
      y[0] = std::clamp(y[0], -c.mu * n, c.mu * n);
      y[1] = n;
      return;
    }
    case ConstraintKind::kBox: y[0] = clampToBox(y[0], c.lower, c.upper); return;  // one row: any metric
    case ConstraintKind::kSpatialFriction: {
      const double n = std::max(0.0, y[2]);
      const double t = norm2(y[0], y[1]);
      const double r = c.mu * n;
      if (t > r) {
        const double s = t > 0.0 ? r / t : 0.0;
        y[0] *= s;
        y[1] *= s;
      }
      y[2] = n;
      return;
    }
  }
}

class NakaokaFormulation final : public Formulation {
 public:
  std::string name() const override { return "nakaoka"; }
  std::string equations() const override { return "80-81"; }

  void iterate(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result) override {
    const auto& cons = problem.constraints();
    const auto& off = problem.offsets();
    const Eigen::Index m = problem.numRows();
    const Eigen::MatrixXd& A = problem.delassus().dense();
    // Pseudo-inverses of the diagonal blocks (a block of a rank-deficient system, e.g. a
    // 3-row contact on a 1-DOF body, is singular: its null directions get no update).
    inverses_.resize(cons.size());
    for (std::size_t i = 0; i < cons.size(); ++i) {
      const int k = cons[i].size;
      block_ = 0.5 * (A.block(off[i], off[i], k, k) + A.block(off[i], off[i], k, k).transpose());
      eig_.compute(block_);
      const Eigen::VectorXd& ev = eig_.eigenvalues();
      const double cut = 1e-12 * std::max(ev.cwiseAbs().maxCoeff(), 1e-300);
      inv_ = ev.unaryExpr([cut](double x) { return x > cut ? 1.0 / x : 0.0; });
      inverses_[i].noalias() = eig_.eigenvectors() * inv_.asDiagonal() * eig_.eigenvectors().transpose();
    }
    Eigen::VectorXd& lam = result.lam;
    u_.resize(m);
    y_.resize(m);
    auto sweep = [&]() {
      for (std::size_t i = 0; i < cons.size(); ++i) {
        const int k = cons[i].size;
        const Eigen::Index o = off[i];
        auto li = lam.segment(o, k);
        auto ri = u_.segment(o, k);  // u_i with the current lambda
        ri.noalias() = A.middleRows(o, k) * lam;
        ri -= problem.b().segment(o, k);
        auto yi = y_.segment(o, k);  // the local unconstrained solution, then its projection
        yi = li;
        yi.noalias() -= inverses_[i] * ri;
        projectSingularMetric(cons[i], yi);
        li = yi;
      }
    };
    sweepUntilConverged(settings, result, sweep, [&]() { return fixedPointResidual(problem, A, lam); },
                        "diverged (non-finite lambda)");
    result.own_law = "Nakaoka fixed point (eq. 80, per block): ||lambda - P^U(lambda - D^+ u)|| / ||lambda||";
  }

 private:
  double fixedPointResidual(const ContactProblem& problem, const Eigen::MatrixXd& A, const Eigen::VectorXd& lam) {
    const auto& cons = problem.constraints();
    const auto& off = problem.offsets();
    u_.noalias() = A * lam;
    u_ -= problem.b();
    double num = 0.0;
    for (std::size_t i = 0; i < cons.size(); ++i) {
      const int k = cons[i].size;
      auto yi = y_.segment(off[i], k);
      yi = lam.segment(off[i], k);
      yi.noalias() -= inverses_[i] * u_.segment(off[i], k);
      projectSingularMetric(cons[i], yi);
      num += (lam.segment(off[i], k) - yi).squaredNorm();
    }
    const double scale = lam.norm();
    num = std::sqrt(num);
    return num == 0.0 ? 0.0 : num / std::max(scale, 1e-300);
  }

  std::vector<Eigen::MatrixXd> inverses_;
  Eigen::MatrixXd block_;
  Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig_;
  Eigen::VectorXd u_, y_, inv_;
};

}  // namespace

std::unique_ptr<Formulation> makeNakaokaFormulation() { return std::make_unique<NakaokaFormulation>(); }

}  // namespace stiction
