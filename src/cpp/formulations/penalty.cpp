// penalty: a spring-damper in series with each constraint (paper eq. 83-84), integrated by
// implicit Euler as Kikuuwe and Fujimoto [30], so that each contact's force has a closed
// form through relation (4) (a projection).
//
//     lambda = K (e + beta e'),   [J_v q' + e_v' ; Psi_p + e_p] ∈ -lim N_C^{U_eps}(lambda)
//
// With the step's end velocity v+ (u = A P - b = J v+ + Psi/h on normal and anchor rows,
// eq. 70; P = h lambda the impulse) and g = Psi the gap at the step's start:
//
//   normal        lambda_n = max(0, -K (g + (h + beta) v_n+))      (the spring follows the
//                 penetration g + h v_n+ while it pushes, relaxes when the contact opens)
//   friction      lambda_t = proj_{||.|| <= mu lambda_n}(K e_t - K (h + beta) v_t+)
//                 e_t+ = (lambda_t / K + (beta / h) e_t) / (1 + beta / h)
//                 (the tangential spring e_t is state: it carries a sticking contact's load,
//                 so the contact creeps by lambda_t / K before it holds)
//   anchors       lambda = -K (Psi + (h + beta) v+)
//
// K [N/m] and beta [s] (damping K beta) are the parameters. The force never depends on M or
// A (paper §4.6: the solution is always unique), but v+ does, through A, so the contacts
// are coupled: resolved by block Gauss-Seidel, each block's law solved exactly (normal: 1-D
// closed form; tangential: the disc-constrained 2-D QP of relation (4)).
//
// The constraint is never satisfied exactly: at rest the normal spring carries the weight at
// a penetration m g / (n K), and a sticking contact under a tangential load F_t stands
// F_t / K off its first position. Own stopping test: ||P - h F(u(P))|| <= tol ||P||.
#include <chrono>
#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

#include "stiction/cone.hpp"
#include "formulations.hpp"

namespace stiction {
namespace {

// argmin 1/2 x'Mx - z'x over ||x|| <= r, M 2x2 SPD: relation (4) with the metric M.
Eigen::Vector2d discQp(const Eigen::Matrix2d& M, const Eigen::Vector2d& z, double r) {
  if (r <= 0.0) return Eigen::Vector2d::Zero();
  Eigen::Vector2d x = M.ldlt().solve(z);
  if (x.norm() <= r) return x;
  // x(nu) = (M + nu I)^-1 z with ||x(nu)|| = r, nu > 0: in M's eigenbasis ||x||^2 =
  // sum c_k^2 / (m_k + nu)^2, decreasing in nu; Newton on 1/||x|| - 1/r (convex, monotone).
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> eig(M);
  const Eigen::Vector2d c = eig.eigenvectors().transpose() * z;
  const Eigen::Vector2d ev = eig.eigenvalues();
  double nu = 0.0;
  for (int it = 0; it < 100; ++it) {
    const double d0 = ev[0] + nu, d1 = ev[1] + nu;
    const double n2 = c[0] * c[0] / (d0 * d0) + c[1] * c[1] / (d1 * d1);
    const double n = std::sqrt(n2);
    const double dn2 = -2.0 * (c[0] * c[0] / (d0 * d0 * d0) + c[1] * c[1] / (d1 * d1 * d1));
    const double f = 1.0 / n - 1.0 / r;
    const double df = -0.5 * dn2 / (n2 * n);
    const double step = f / df;
    nu = std::max(0.0, nu - step);
    if (std::abs(step) <= 1e-15 * (nu + ev.maxCoeff())) break;
  }
  x = eig.eigenvectors() * Eigen::Vector2d(c[0] / (ev[0] + nu), c[1] / (ev[1] + nu));
  const double n = x.norm();
  return n > r ? Eigen::Vector2d(x * (r / n)) : x;  // rounding: stay in the disc
}

class PenaltyFormulation final : public Formulation {
 public:
  std::string name() const override { return "penalty"; }
  std::string equations() const override { return "83-84"; }
  // K [N/m], beta [s], h and the gaps carry units: the problem scaled by powers of two would be
  // another physical system, so it is solved as given (its verdict still judged at any scale).
  bool rescalable() const override { return false; }

  void iterate(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result) override {
    refuseBoxRows(problem, name());  // (a spring per contact: no law for an interval of joint forces)
    const auto& cons = problem.constraints();
    const auto& off = problem.offsets();
    const Eigen::Index m = problem.numRows();
    const Eigen::MatrixXd& A = problem.delassus().dense();
    const double K = settings_.penalty_stiffness, beta = settings_.penalty_damping;
    const double h = context_.h;
    const double c = h * K * (h + beta);  // impulse per unit of end velocity
    result.own_law = "implicit spring-damper law (eq. 83-84): ||P - h F(u(P))|| / ||P||";
    psi_.setZero(m);
    if (context_.position_error != nullptr) {
      if (context_.position_error->size() != m)
        throw std::invalid_argument("penalty: the position error has " +
                                    std::to_string(context_.position_error->size()) + " rows, the problem " +
                                    std::to_string(m));
      psi_ = *context_.position_error;
    }
    spring_.setZero(m);
    if (context_.state != nullptr && context_.state->size() == m) spring_ = *context_.state;
    // offset_: the impulse at u = 0: alpha = h (-K (Psi - (h + beta) Psi / h)) = K beta Psi
    // on normal and anchor rows, h K e_t on tangential rows.
    offset_ = K * beta * psi_;
    for (std::size_t i = 0; i < cons.size(); ++i)
      if (cons[i].hasFriction())
        for (int r = 0; r + 1 < cons[i].size; ++r) offset_[off[i] + r] = h * K * spring_[off[i] + r];

    Eigen::VectorXd& P = result.lam;
    u_.resize(m);
    sweepUntilConverged(
        settings, result,
        [&]() {
          for (std::size_t i = 0; i < cons.size(); ++i) localSolve(problem, A, c, static_cast<int>(i), P);
        },
        [&]() { return lawResidual(problem, A, c, P); }, "diverged (non-finite impulse)");
    // The step is taken: the tangential springs move (implicit Euler of eq. 83).
    if (context_.state != nullptr) {
      Eigen::VectorXd& e = *context_.state;
      e.setZero(m);
      for (std::size_t i = 0; i < cons.size(); ++i)
        if (cons[i].hasFriction())
          for (int r = 0; r + 1 < cons[i].size; ++r) {
            const Eigen::Index k = off[i] + r;
            e[k] = (P[k] / (h * K) + (beta / h) * spring_[k]) / (1.0 + beta / h);
          }
    }
  }

 private:
  // Block i's law given the other blocks: P_i = h F_i(A_ii P_i + r_i).
  void localSolve(const ContactProblem& problem, const Eigen::MatrixXd& A, double c, int i, Eigen::VectorXd& P) {
    const Constraint& con = problem.constraints()[i];
    const Eigen::Index o = problem.offsets()[i];
    const int k = con.size;
    auto r = u_.segment(o, k);  // u_i without block i's own contribution
    r.noalias() = A.middleRows(o, k) * P;
    r -= problem.b().segment(o, k);
    r.noalias() -= A.block(o, o, k, k) * P.segment(o, k);
    if (con.kind == ConstraintKind::kBilateral) {  // (I + c A_ii) P = alpha - c r
      Eigen::MatrixXd M = c * A.block(o, o, k, k);
      M.diagonal().array() += 1.0;
      P.segment(o, k) = M.ldlt().solve(offset_.segment(o, k) - c * r);
      return;
    }
    const Eigen::Index n = o + k - 1;
    const double a_nn = A(n, n);
    if (con.kind == ConstraintKind::kUnilateral) {
      P[n] = std::max(0.0, (offset_[n] - c * r[0]) / (1.0 + c * a_nn));
      return;
    }
    // friction: alternate normal (tangential fixed) and tangential (normal fixed) to a fixed point
    for (int pass = 0; pass < 50; ++pass) {
      const double old_n = P[n];
      double q = r[k - 1];
      for (int t = 0; t + 1 < k; ++t) q += A(n, o + t) * P[o + t];
      P[n] = std::max(0.0, (offset_[n] - c * q) / (1.0 + c * a_nn));
      const double radius = con.mu * P[n];
      if (k == 2) {
        const double z = offset_[o] - c * (r[0] + A(o, n) * P[n]);
        P[o] = std::clamp(z / (1.0 + c * A(o, o)), -radius, radius);
      } else {
        Eigen::Matrix2d M = c * A.block<2, 2>(o, o);
        M = 0.5 * (M + M.transpose()).eval();
        M.diagonal().array() += 1.0;
        const Eigen::Vector2d z(offset_[o] - c * (r[0] + A(o, n) * P[n]),
                                offset_[o + 1] - c * (r[1] + A(o + 1, n) * P[n]));
        P.segment<2>(o) = discQp(M, z, radius);
      }
      if (std::abs(P[n] - old_n) <= 1e-15 * std::max(std::abs(P[n]), 1e-300)) break;
    }
  }

  // ||P - h F(u(P))|| / ||P||: how far P is from the penalty law at its own end velocity.
  double lawResidual(const ContactProblem& problem, const Eigen::MatrixXd& A, double c, const Eigen::VectorXd& P) {
    const auto& cons = problem.constraints();
    const auto& off = problem.offsets();
    u_.noalias() = A * P;
    u_ -= problem.b();
    double num = 0.0;
    for (std::size_t i = 0; i < cons.size(); ++i) {
      const Eigen::Index o = off[i];
      const int k = cons[i].size;
      if (cons[i].kind == ConstraintKind::kBilateral) {
        num += (P.segment(o, k) - (offset_.segment(o, k) - c * u_.segment(o, k))).squaredNorm();
        continue;
      }
      const Eigen::Index n = o + k - 1;
      const double pn = std::max(0.0, offset_[n] - c * u_[n]);
      num += (P[n] - pn) * (P[n] - pn);
      if (k >= 2) {
        Eigen::Vector2d t = Eigen::Vector2d::Zero();
        for (int r = 0; r + 1 < k; ++r) t[r] = offset_[o + r] - c * u_[o + r];
        const double tn = t.norm(), radius = cons[i].mu * pn;
        if (tn > radius) t *= tn > 0.0 ? radius / tn : 0.0;
        for (int r = 0; r + 1 < k; ++r) num += (P[o + r] - t[r]) * (P[o + r] - t[r]);
      }
    }
    num = std::sqrt(num);
    return num == 0.0 ? 0.0 : num / std::max(P.norm(), 1e-300);
  }

  Eigen::VectorXd psi_, spring_, offset_, u_;
};

}  // namespace

std::unique_ptr<Formulation> makePenaltyFormulation() { return std::make_unique<PenaltyFormulation>(); }

}  // namespace stiction
