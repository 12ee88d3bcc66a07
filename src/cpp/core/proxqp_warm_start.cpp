#include "stiction/proxqp_warm_start.hpp"

#include <cmath>
#include <stdexcept>

#include <proxsuite/proxqp/dense/dense.hpp>

namespace stiction {

int proxqpWarmStart(const ContactProblem& problem, const SolverSettings& settings, Eigen::VectorXd& lam) {
  namespace pq = proxsuite::proxqp;
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const Eigen::Index m = problem.numRows();
  if (m == 0) {
    lam.resize(0);
    return 0;
  }
  const int facets = std::max(3, settings.proxqp_facets);
  Eigen::Index n_in = 0;
  for (const Constraint& c : cons) {
    if (c.kind == ConstraintKind::kUnilateral) n_in += 1;
    if (c.kind == ConstraintKind::kPlanarFriction) n_in += 2;
    if (c.kind == ConstraintKind::kSpatialFriction) n_in += facets;
  }
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(n_in, m);
  Eigen::Index row = 0;
  const double shrink = std::cos(M_PI / facets);  // inscribed pyramid
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    const double mu = cons[i].mu;
    switch (cons[i].kind) {
      case ConstraintKind::kBilateral: break;
      case ConstraintKind::kUnilateral: C(row++, o) = -1.0; break;  // -l_n <= 0
      case ConstraintKind::kPlanarFriction:
        for (double s : {1.0, -1.0}) {
          C(row, o) = s;
          C(row++, o + 1) = -mu;
        }
        break;
      case ConstraintKind::kSpatialFriction:
        for (int f = 0; f < facets; ++f) {  // d_f . l_t - mu cos(pi/F) l_n <= 0
          const double phi = 2.0 * M_PI * f / facets;
          C(row, o) = std::cos(phi);
          C(row, o + 1) = std::sin(phi);
          C(row++, o + 2) = -mu * shrink;
        }
        break;
    }
  }
  const Eigen::MatrixXd& A = problem.delassus().dense();
  Eigen::MatrixXd H = 0.5 * (A + A.transpose());
  // A is only positive semi-definite; a tiny shift keeps ProxQP's KKT solves honest.
  H.diagonal().array() += 1e-12 * std::max(H.diagonal().maxCoeff(), 1e-300);
  const Eigen::VectorXd g = -problem.b();
  const Eigen::VectorXd lower = Eigen::VectorXd::Constant(n_in, -1e20);
  const Eigen::VectorXd upper = Eigen::VectorXd::Zero(n_in);

  pq::dense::QP<double> qp(m, 0, n_in);
  qp.settings.eps_abs = settings.proxqp_tolerance;
  qp.settings.eps_rel = 0.0;
  qp.settings.eps_primal_inf = 1e-12;  // avoids spurious PRIMAL_INFEASIBLE on rank-deficient A
  qp.settings.max_iter = 10000;
  qp.settings.verbose = false;
  qp.init(H, g, proxsuite::nullopt, proxsuite::nullopt, C, lower, upper);
  qp.solve();
  const auto status = qp.results.info.status;
  if (status != pq::QPSolverOutput::PROXQP_SOLVED &&
      status != pq::QPSolverOutput::PROXQP_MAX_ITER_REACHED)
    throw std::runtime_error("ProxQP warm start failed (status " + std::to_string(int(status)) + ")");
  lam = qp.results.x;
  if (!lam.allFinite()) lam.setZero();
  return static_cast<int>(qp.results.info.iter);
}

}  // namespace stiction
