#include "stiction/proxqp_warm_start.hpp"
#include "stiction/clock.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>

#include <proxsuite/proxqp/dense/dense.hpp>

#include "stiction/proxqp_chunks.hpp"

namespace stiction {

StageReport proxqpWarmStart(const ContactProblem& problem, const SolverSettings& settings, double time_limit,
                            Eigen::VectorXd& lam, Eigen::VectorXd* ray) {
  namespace pq = proxsuite::proxqp;
  using Clock = FastClock;  // the time-stamp counter (clock.hpp)
  const auto start = Clock::now();
  auto elapsed = [&]() { return std::chrono::duration<double>(Clock::now() - start).count(); };
  StageReport report;
  report.name = "proxqp";
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const Eigen::Index m = problem.numRows();
  if (m == 0) {
    lam.resize(0);
    report.outcome = "solved";
    return report;
  }
  if (settings.proxqp_facets < 3 || settings.proxqp_facets > kMaxFacets)  // (never clamped: a value that
    // cannot take effect is an error)
    throw std::invalid_argument("proxqp_facets must be between 3 and " + std::to_string(kMaxFacets) + ", got " +
                                std::to_string(settings.proxqp_facets) + kMaxFacetsReason);
  const int facets = settings.proxqp_facets;
  Eigen::Index n_in = 0;
  for (const Constraint& c : cons) {
    if (c.kind == ConstraintKind::kUnilateral) n_in += 1;
    if (c.kind == ConstraintKind::kPlanarFriction) n_in += 2;
    if (c.kind == ConstraintKind::kSpatialFriction) n_in += facets;
    if (c.kind == ConstraintKind::kBox) n_in += 1;  // lower <= l <= upper: one row, both bounds
  }
  checkDenseQpSize("ProxQP (proxqp_facets = " + std::to_string(facets) + ")", m, n_in);
  Eigen::MatrixXd C = Eigen::MatrixXd::Zero(n_in, m);
  Eigen::VectorXd lower = Eigen::VectorXd::Constant(n_in, -1e20);  // (cone rows: C l <= 0)
  Eigen::VectorXd upper = Eigen::VectorXd::Zero(n_in);
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
      case ConstraintKind::kBox:  // the interval itself: the QP's set is exact there
        lower[row] = cons[i].lower;
        upper[row] = cons[i].upper;
        C(row++, o) = 1.0;
        break;
    }
  }
  const Eigen::MatrixXd& A = problem.delassus().dense();
  Eigen::MatrixXd H = 0.5 * (A + A.transpose());
  const double max_diag = std::max(H.diagonal().maxCoeff(), 1e-300);
  // A is only positive semi-definite; a tiny shift keeps ProxQP's KKT solves honest.
  H.diagonal().array() += 1e-12 * max_diag;
  const Eigen::VectorXd g = -problem.b();

  pq::dense::QP<double> qp(m, 0, n_in);
  // Relative tolerances: eps_rel scales with ProxQP's own residual terms; the absolute
  // floor with the smaller of b's scale (dual residual) and lambda's ~ b / A (primal).
  // (An absolute 1e-8 at ||b|| = 1e8 asks for 1e-16 relative: 4.6 million iterations.)
  const double b_scale = problem.b().lpNorm<Eigen::Infinity>();
  qp.settings.eps_rel = settings.proxqp_tolerance;
  qp.settings.eps_abs = std::max(1e-300, settings.proxqp_tolerance * std::min(b_scale, b_scale / max_diag));
  qp.settings.eps_primal_inf = 1e-12;  // avoids spurious PRIMAL_INFEASIBLE on rank-deficient A
  qp.settings.verbose = false;
  qp.init(H, g, proxsuite::nullopt, proxsuite::nullopt, C, lower, upper);

  // Chunks of inner iterations (proxqp_chunks.hpp): a first guess of the cost per iteration from
  // the sizes (a few products with the m x (m + n_in) system), then measured.
  const long budget = std::max(1, settings.proxqp_max_iterations);
  const double per_iteration = 4e-9 * static_cast<double>(m) * static_cast<double>(m + n_in) + 1e-7;
  const QpChunks run = solveQpInChunks(qp, budget, time_limit, start, per_iteration);
  const long used = run.iterations;
  const auto status = qp.results.info.status;
  if (run.timed_out) {  // (the last chunk, if any, reached its iterations)
    report.outcome = "time limit reached";
  } else if (status == pq::QPSolverOutput::PROXQP_SOLVED) {
    report.outcome = "solved";
  } else if (status == pq::QPSolverOutput::PROXQP_DUAL_INFEASIBLE) {
    // The QP is unbounded below: x is a ray with A x ~ 0, x in C_F, b'x > 0.
    report.outcome = "unbounded (b pushes along a direction A does not resist)";
    if (ray != nullptr && qp.results.x.allFinite()) *ray = qp.results.x;
  } else if (status == pq::QPSolverOutput::PROXQP_MAX_ITER_REACHED || used == 0) {
    report.outcome = "iteration limit reached";
  } else {
    report.outcome = "failed (ProxQP status " + std::to_string(static_cast<int>(status)) + ")";
  }
  report.iterations = static_cast<int>(std::min<long>(used, 2147483647L));
  lam = qp.results.x;
  if (report.outcome.rfind("unbounded", 0) == 0 || !lam.allFinite()) lam.setZero();
  report.seconds = elapsed();
  return report;
}

}  // namespace stiction
