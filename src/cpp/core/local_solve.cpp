#include "stiction/local_solve.hpp"

#include <cmath>
#include <limits>

#include <Eigen/Eigenvalues>

#include "stiction/cone.hpp"

namespace stiction {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Real roots of k[4] t^4 + ... + k[0] (degree drops when leading terms vanish).
// Companion matrix eigenvalues; fixed maximum size, so no heap allocation.
int realPolynomialRoots(const double k[5], double roots[4]) {
  double scale = 0.0;
  for (int i = 0; i < 5; ++i) scale = std::max(scale, std::abs(k[i]));
  if (!(scale > 0.0)) return 0;
  int degree = 4;
  while (degree > 0 && std::abs(k[degree]) <= 1e-13 * scale) --degree;
  if (degree == 0) return 0;
  if (degree == 1) {
    roots[0] = -k[0] / k[1];
    return 1;
  }
  using Companion = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 4, 4>;
  Companion C = Companion::Zero(degree, degree);
  for (int i = 1; i < degree; ++i) C(i, i - 1) = 1.0;
  for (int i = 0; i < degree; ++i) C(i, degree - 1) = -k[i] / k[degree];
  Eigen::EigenSolver<Companion> es(C, false);
  int n = 0;
  for (int i = 0; i < degree; ++i) {
    const std::complex<double> z = es.eigenvalues()[i];
    if (std::abs(z.imag()) <= 1e-6 * (1.0 + std::abs(z.real()))) roots[n++] = z.real();
  }
  return n;
}

template <int N>
double blockResidual(const Eigen::Matrix<double, N, N>& G, const Eigen::Matrix<double, N, 1>& c,
                     double mu, const Eigen::Matrix<double, N, 1>& lam) {
  Eigen::Matrix<double, N, 1> u = G * lam + c;
  Eigen::Matrix<double, N, 1> z = lam - u;
  if constexpr (N == 3) {
    z[2] -= mu * norm2(u[0], u[1]);
    projectSpatialCone(z, mu);
  } else {
    z[1] -= mu * std::abs(u[0]);
    projectPlanarCone(z, mu);
  }
  return (lam - z).norm();
}

}  // namespace

double spatialBlockResidual(const Eigen::Matrix3d& G, const Eigen::Vector3d& c, double mu,
                            const Eigen::Vector3d& lam) {
  return blockResidual<3>(G, c, mu, lam);
}

ContactState solveSpatialBlock(const Eigen::Matrix3d& G, const Eigen::Matrix3d& G_inv,
                               const Eigen::Vector3d& c, double mu, Eigen::Vector3d& lam) {
  // Open: with lambda = 0 the De Saxce condition reduces to u_n = c_n >= 0.
  if (c[2] >= 0.0) {
    lam.setZero();
    return ContactState::kOpen;
  }
  // Stick: u = 0.
  const Eigen::Vector3d lam_stick = -G_inv * c;
  const double stick_t = norm2(lam_stick[0], lam_stick[1]);
  if (lam_stick[2] > 0.0 && stick_t <= mu * lam_stick[2]) {
    lam = lam_stick;
    return ContactState::kStick;
  }
  if (mu == 0.0) {  // frictionless: only the normal row acts
    lam << 0.0, 0.0, -c[2] / G(2, 2);
    return ContactState::kSlip;
  }

  // Slip: lambda = lambda_n (mu cos th, mu sin th, 1), u_n = 0, u_t = -beta (cos th, sin th).
  // Work in a tangent frame rotated by th0 (the stick direction), so that the
  // solution sits near th = 0, where t = tan(th/2) is well conditioned.
  const double th0 = stick_t > 0.0 ? std::atan2(lam_stick[1], lam_stick[0])
                                   : std::atan2(-c[1], -c[0]);
  const double c0 = std::cos(th0), s0 = std::sin(th0);
  Eigen::Matrix3d Q;  // x' = Q x
  Q << c0, s0, 0.0, -s0, c0, 0.0, 0.0, 0.0, 1.0;
  const Eigen::Matrix3d Gr = Q * G * Q.transpose();
  const Eigen::Vector3d cr = Q * c;
  const double cn = cr[2];
  // v(th) = a(th) u_t(th) = p + q cos th + r sin th  (a(th) = G_n . w(th) > 0)
  double p[2], q[2], r[2];
  for (int i = 0; i < 2; ++i) {
    p[i] = -cn * Gr(i, 2) + Gr(2, 2) * cr[i];
    q[i] = mu * (-cn * Gr(i, 0) + Gr(2, 0) * cr[i]);
    r[i] = mu * (-cn * Gr(i, 1) + Gr(2, 1) * cr[i]);
  }
  // f(th) = v_0 sin th - v_1 cos th = 0  (v parallel to the direction); with
  // t = tan(th/2) and a factor (1 + t^2)^2 it becomes this quartic.
  const double qr = q[0] - r[1];
  const Eigen::Vector3d lam_prev = Q * lam;
  // f(th) = v_0 sin th - v_1 cos th and its derivative.
  auto f_and_df = [&](double th, double& f, double& df) {
    const double C = std::cos(th), S = std::sin(th);
    f = p[0] * S - p[1] * C + qr * C * S + r[0] * S * S - q[1] * C * C;
    df = p[0] * C + p[1] * S + qr * (C * C - S * S) + 2.0 * (r[0] + q[1]) * S * C;
  };
  // The slip force for direction th if it is one (a > 0 and u_t opposite to lambda_t).
  auto slipAt = [&](double th, Eigen::Vector3d& cand, bool& valid) {
    const double C = std::cos(th), S = std::sin(th);
    const Eigen::Vector3d w(mu * C, mu * S, 1.0);
    const double a = Gr.row(2).dot(w);
    if (!(a > 0.0)) return false;
    cand = (-cn / a) * w;
    const Eigen::Vector3d u = Gr * cand + cr;
    const double along = u[0] * C + u[1] * S;  // must be <= 0: u_t opposite to lambda_t
    valid = along <= 1e-9 * norm2(u[0], u[1]);
    return true;
  };
  // Fast path: Newton on f from the direction of the block's previous force, which slips
  // the same way from one Gauss-Seidel sweep to the next. A root found there with a valid
  // direction is an exact slip solution (u_n = 0 and u_t against lambda_t by construction),
  // so the quartic (an eigenvalue problem, most of a sweep's time) is only needed when this
  // fails. The residual check guards against a root that rounding made approximate.
  if (lam_prev[2] > 0.0 && norm2(lam_prev[0], lam_prev[1]) > 0.0) {
    double th = std::atan2(lam_prev[1], lam_prev[0]);
    bool converged = false;
    for (int it = 0; it < 12 && !converged; ++it) {
      double f, df;
      f_and_df(th, f, df);
      if (!(std::abs(df) > 0.0)) break;
      const double step = f / df;
      th -= step;
      converged = std::abs(step) <= 1e-12;
    }
    Eigen::Vector3d cand;
    bool valid = false;
    if (converged && std::isfinite(th) && slipAt(th, cand, valid) && valid &&
        blockResidual<3>(Gr, cr, mu, cand) <= 1e-13 * (cand.norm() * (1.0 + Gr.norm()) + cr.norm())) {
      lam = Q.transpose() * cand;
      return ContactState::kSlip;
    }
  }
  const double k[5] = {-p[1] - q[1], 2.0 * p[0] + 2.0 * qr, 4.0 * r[0] + 2.0 * q[1],
                       2.0 * p[0] - 2.0 * qr, p[1] - q[1]};
  double roots[4];
  const int n_roots = realPolynomialRoots(k, roots);
  double thetas[5];
  int n_th = 0;
  for (int i = 0; i < n_roots; ++i) thetas[n_th++] = 2.0 * std::atan(roots[i]);
  double kscale = 0.0;
  for (double ki : k) kscale = std::max(kscale, std::abs(ki));
  if (std::abs(k[4]) <= 1e-10 * kscale) thetas[n_th++] = M_PI;  // root at t = infinity

  Eigen::Vector3d best = Eigen::Vector3d::Zero();
  double best_res = kInf, best_dist = kInf;
  bool have_valid = false;
  for (int i = 0; i < n_th; ++i) {
    double th = thetas[i];
    for (int it = 0; it < 3; ++it) {  // Newton polish on the trigonometric form
      const double C = std::cos(th), S = std::sin(th);
      const double f = p[0] * S - p[1] * C + qr * C * S + r[0] * S * S - q[1] * C * C;
      const double df = p[0] * C + p[1] * S + qr * (C * C - S * S) + 2.0 * (r[0] + q[1]) * S * C;
      if (!(std::abs(df) > 0.0)) break;
      th -= f / df;
    }
    const double C = std::cos(th), S = std::sin(th);
    const Eigen::Vector3d w(mu * C, mu * S, 1.0);
    const double a = Gr.row(2).dot(w);
    if (!(a > 0.0)) continue;
    const Eigen::Vector3d cand = (-cn / a) * w;
    const Eigen::Vector3d u = Gr * cand + cr;
    const double along = u[0] * C + u[1] * S;  // must be <= 0: u_t opposite to lambda_t
    const double ut_norm = norm2(u[0], u[1]);
    const bool valid = along <= 1e-9 * ut_norm;
    const double res = blockResidual<3>(Gr, cr, mu, cand);
    const double dist = (cand - lam_prev).norm();
    if (valid && (!have_valid || res < 0.5 * best_res || (res <= 2.0 * best_res && dist < best_dist))) {
      have_valid = true;
      best = cand;
      best_res = res;
      best_dist = dist;
    } else if (!have_valid && res < best_res) {
      best = cand;
      best_res = res;
      best_dist = dist;
    }
  }
  if (!have_valid) {  // numerical corner: keep the candidate with the smallest residual
    Eigen::Vector3d projected = Q * lam_stick;
    projectSpatialCone(projected, mu);
    const double res_proj = blockResidual<3>(Gr, cr, mu, projected);
    if (res_proj < best_res) {
      best = projected;
      best_res = res_proj;
    }
    const double res_open = blockResidual<3>(Gr, cr, mu, Eigen::Vector3d::Zero());
    if (res_open < best_res) best.setZero();
  }
  lam = Q.transpose() * best;
  return ContactState::kSlip;
}

ContactState solvePlanarBlock(const Eigen::Matrix2d& G, const Eigen::Matrix2d& G_inv,
                              const Eigen::Vector2d& c, double mu, Eigen::Vector2d& lam) {
  if (c[1] >= 0.0) {
    lam.setZero();
    return ContactState::kOpen;
  }
  const Eigen::Vector2d lam_stick = -G_inv * c;
  if (lam_stick[1] > 0.0 && std::abs(lam_stick[0]) <= mu * lam_stick[1]) {
    lam = lam_stick;
    return ContactState::kStick;
  }
  // Slip to either side: lambda = lambda_n (sigma mu, 1), u_n = 0, sigma u_t <= 0.
  Eigen::Vector2d best = Eigen::Vector2d::Zero();
  double best_res = kInf, best_dist = kInf;
  bool have_valid = false;
  for (double sigma : {1.0, -1.0}) {
    const Eigen::Vector2d w(sigma * mu, 1.0);
    const double a = G.row(1).dot(w);
    if (!(a > 0.0)) continue;
    const Eigen::Vector2d cand = (-c[1] / a) * w;
    const double ut = G.row(0).dot(cand) + c[0];
    const bool valid = sigma * ut <= 1e-12 * std::abs(c[0]) || mu == 0.0;
    const double res = blockResidual<2>(G, c, mu, cand);
    const double dist = (cand - lam).norm();
    if (valid && (!have_valid || dist < best_dist)) {
      have_valid = true;
      best = cand;
      best_res = res;
      best_dist = dist;
    } else if (!have_valid && res < best_res) {
      best = cand;
      best_res = res;
    }
  }
  if (!have_valid) {
    Eigen::Vector2d projected = lam_stick;
    projectPlanarCone(projected, mu);
    if (blockResidual<2>(G, c, mu, projected) < best_res) best = projected;
  }
  lam = best;
  return ContactState::kSlip;
}

}  // namespace stiction
