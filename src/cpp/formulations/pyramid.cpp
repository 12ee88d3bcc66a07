// pyramid: every spatial friction cone replaced by an N-facet pyramid (paper §4.5: the
// facetized cones of Stewart-Trinkle [50] and Anitescu-Potra [8]).
//
// Facets k = 0..N-1 with outward normals at phi_k = 2 pi k / N in the tangent plane:
//     cos(phi_k) l_t1 + sin(phi_k) l_t2 <= mu_f l_n,   l_n >= 0,
// mu_f = mu (circumscribed: the facets touch the cone, the corners reach mu / cos(pi/N);
// N = 4 is the box |l_t1|, |l_t2| <= mu l_n of many engines) or mu cos(pi/N) (inscribed:
// the corners on the cone). Planar (2-row) contacts are already polyhedral: unchanged.
//
// The LCP of Stewart-Trinkle / Anitescu-Potra (friction as a combination of the pyramid's
// edge directions, maximum dissipation over them, Signorini on the normal) is the cone
// complementarity problem on the pyramid P with De Saxce's term for P:
//     P ∋ lambda ⟂ u + E s_P(u) ∈ P*,    s_P(u) = max_j v_j . (-u_t)
// (v_j the pyramid's corners at unit normal force: the largest dissipation rate the
// pyramid allows). With s fixed this is the convex QP min 1/2 l'A l - (b - E s)'l over P,
// a polyhedral QP that ProxQP (proxsuite) solves; s is then refreshed from the solution's u
// and the QP re-solved, warm-started, until s stops moving: the fixed point on the De Saxce
// term that the cone-complementarity literature uses for the exact law (Cadoux; Acary et
// al.). Its first iterate (s = 0) is Anitescu's convex relaxation on the pyramid. Unlike
// Lemke's pivoting this is not guaranteed to converge for large mu; when it does not, the
// result says so (own_converged false).
//
// Box rows (an interval: already polyhedral, no De Saxce term) are one QP row with both bounds, and
// clamped in the ADMM finish: on them the pyramid LCP is the exact law.
//
// Own stopping test: the QP solved and ||E (s_P(u) - s)|| <= tol ||b||, i.e. the LCP's
// complementarity holds up to the tolerance.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

#include <proxsuite/proxqp/dense/dense.hpp>

#include "stiction/proxqp_chunks.hpp"

#include "stiction/clock.hpp"
#include "stiction/cone.hpp"
#include "stiction/verdict.hpp"

#include <Eigen/Cholesky>
#include "formulations.hpp"

namespace stiction {
namespace {

// The pyramid of one spatial block at unit normal force: facet normals at 2 pi k / N, facet
// distance mu_f; corners at radius mu_f / cos(pi / N), angles (2k + 1) pi / N.
struct Pyramid {
  int N;
  double mu_f, corner_radius;
  double supportOfMinus(double u1, double u2) const {  // max over the corners v_j . (-u_t), per unit mu
    double best = -1e300;
    for (int k = 0; k < N; ++k) {
      const double a = (2.0 * k + 1.0) * M_PI / N;
      best = std::max(best, -(std::cos(a) * u1 + std::sin(a) * u2));
    }
    return corner_radius * best;
  }
  bool contains(const Eigen::Vector3d& x) const {
    if (x[2] < 0.0) return false;
    for (int k = 0; k < N; ++k)
      if (std::cos(2.0 * M_PI * k / N) * x[0] + std::sin(2.0 * M_PI * k / N) * x[1] > mu_f * x[2] * (1 + 1e-15))
        return false;
    return true;
  }
  Eigen::Vector3d edge(int j) const {
    const double a = (2.0 * j + 1.0) * M_PI / N;
    return Eigen::Vector3d(corner_radius * std::cos(a), corner_radius * std::sin(a), 1.0);
  }
  // Euclidean projection onto the polyhedral cone: the nearest of its faces (2-D cones spanned by
  // two consecutive edges), edges and apex.
  Eigen::Vector3d project(const Eigen::Vector3d& x) const {
    if (contains(x)) return x;
    Eigen::Vector3d best = Eigen::Vector3d::Zero();
    double best_d = x.squaredNorm();
    for (int j = 0; j < N; ++j) {
      const Eigen::Vector3d a = edge(j), b = edge((j + 1) % N);
      const double ta = std::max(0.0, a.dot(x) / a.squaredNorm());  // the edge ray
      const Eigen::Vector3d pe = ta * a;
      if ((x - pe).squaredNorm() < best_d) best_d = (x - pe).squaredNorm(), best = pe;
      Eigen::Matrix2d G;  // the face: x's projection on span(a, b) with non-negative weights
      G << a.dot(a), a.dot(b), a.dot(b), b.dot(b);
      const Eigen::Vector2d c = G.ldlt().solve(Eigen::Vector2d(a.dot(x), b.dot(x)));
      if (c[0] >= 0.0 && c[1] >= 0.0) {
        const Eigen::Vector3d pf = c[0] * a + c[1] * b;
        if ((x - pf).squaredNorm() < best_d) best_d = (x - pf).squaredNorm(), best = pf;
      }
    }
    return best;
  }
};

class PyramidFormulation final : public Formulation {
 public:
  std::string name() const override { return "pyramid"; }
  std::string equations() const override { return "§4.5 (LCP of [8, 50])"; }

  void iterate(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result) override {
    namespace pq = proxsuite::proxqp;
    using Clock = FastClock;  // the time-stamp counter (clock.hpp)
    const auto start = Clock::now();
    const auto& cons = problem.constraints();
    const auto& off = problem.offsets();
    const Eigen::Index m = problem.numRows();
    const int N = settings_.pyramid_facets;
    const double half = M_PI / N;
    const double facet_mu = settings_.pyramid_inscribed ? std::cos(half) : 1.0;  // times mu
    const double corner_radius = facet_mu / std::cos(half);                       // times mu
    result.own_law = "pyramid LCP (" + std::to_string(N) + " facets, " +
                     (settings_.pyramid_inscribed ? "inscribed" : "circumscribed") +
                     "): QP solved and ||E (s_P(u) - s)|| / ||b||";
    if (m == 0) {
      result.lam.resize(0);
      result.own_converged = true;
      result.message = "converged";
      return;
    }
    Eigen::Index n_in = 0;
    for (const Constraint& c : cons) {
      if (c.kind == ConstraintKind::kUnilateral) n_in += 1;
      if (c.kind == ConstraintKind::kPlanarFriction) n_in += 3;
      if (c.kind == ConstraintKind::kSpatialFriction) n_in += N + 1;
      if (c.kind == ConstraintKind::kBox) n_in += 1;
    }
    checkDenseQpSize("pyramid (pyramid_facets = " + std::to_string(N) + ")", m, n_in);
    C_.setZero(n_in, m);
    lower_.setConstant(n_in, -1e20);  // (cone rows: C l <= 0)
    upper_.setZero(n_in);
    Eigen::Index row = 0;
    for (std::size_t i = 0; i < cons.size(); ++i) {
      const Eigen::Index o = off[i];
      const double mu = cons[i].mu;
      switch (cons[i].kind) {
        case ConstraintKind::kBilateral: break;
        case ConstraintKind::kUnilateral: C_(row++, o) = -1.0; break;
        case ConstraintKind::kPlanarFriction:
          C_(row++, o + 1) = -1.0;
          for (double s : {1.0, -1.0}) {
            C_(row, o) = s;
            C_(row++, o + 1) = -mu;
          }
          break;
        case ConstraintKind::kSpatialFriction:
          C_(row++, o + 2) = -1.0;  // l_n >= 0 (implied for mu > 0, not for mu = 0)
          for (int k = 0; k < N; ++k) {
            C_(row, o) = std::cos(2.0 * M_PI * k / N);
            C_(row, o + 1) = std::sin(2.0 * M_PI * k / N);
            C_(row++, o + 2) = -mu * facet_mu;
          }
          break;
        case ConstraintKind::kBox:
          lower_[row] = cons[i].lower;
          upper_[row] = cons[i].upper;
          C_(row++, o) = 1.0;
          break;
      }
    }
    const Eigen::MatrixXd& A = problem.delassus().dense();
    H_ = 0.5 * (A + A.transpose());
    const double max_diag = std::max(H_.diagonal().maxCoeff(), 1e-300);
    H_.diagonal().array() += 1e-12 * max_diag;  // A is only semi-definite
    s_.setZero(m);  // E s: the De Saxce shift on the normal rows
    g_ = -problem.b();
    const double scale = stoppingScale(problem);
    const double b_inf = problem.b().lpNorm<Eigen::Infinity>();

    pq::dense::QP<double> qp(m, 0, n_in);
    const double own_tolerance = settings.tolerance;
    qp.settings.eps_rel = std::max(settings.tolerance, 1e-13);
    qp.settings.eps_abs = std::max(1e-300, qp.settings.eps_rel * std::min(b_inf, b_inf / max_diag));
    qp.settings.eps_primal_inf = 1e-12;
    qp.settings.verbose = false;
    // At most proxqp_max_iterations inner iterations per QP: ProxQP's own budget is
    // max_iter (outer) x max_iter_in (inner, 1500 by default) -- left as max_iter alone it
    // allowed 30 million, measured: 98 s on one 12-variable QP (8 facets). Each QP runs in chunks
    // that keep the time limit (proxqp_chunks.hpp; ProxQP has no clock of its own).
    const long budget = std::max(1, settings.proxqp_max_iterations);
    double per_iteration = 4e-9 * static_cast<double>(m) * static_cast<double>(m + n_in) + 1e-7;
    qp.init(H_, g_, proxsuite::nullopt, proxsuite::nullopt, C_, lower_, upper_);
    // (No warm start from the caller's lambda, the previous step's: without its multipliers ProxQP
    // started from it converged worse than cold, measured on a pushed cube with 8 facets.)
    QpChunks chunks = solveQpInChunks(qp, budget, settings.time_limit, start, per_iteration);
    long qp_iterations = chunks.iterations;
    result.own_converged = false;
    result.message = "fixed point on the De Saxce term did not settle";
    int outer = 1;
    u_.resize(m);
    s_new_.resize(m);
    bool out_of_time = false;
    for (;; ++outer) {
      if (chunks.timed_out) {
        out_of_time = true;
        result.message = "time limit reached";
        break;
      }
      if (qp.results.info.status != pq::QPSolverOutput::PROXQP_SOLVED) {
        result.message = qp.results.info.status == pq::QPSolverOutput::PROXQP_DUAL_INFEASIBLE
                             ? "the pyramid QP is unbounded (b pushes along a direction A does not resist)"
                             : "ProxQP did not solve the pyramid QP (status " +
                                   std::to_string(static_cast<int>(qp.results.info.status)) + ")";
        break;
      }
      // s_P(u) from the solution's velocities
      u_.noalias() = A * qp.results.x;
      u_ -= problem.b();
      s_new_.setZero();
      for (std::size_t i = 0; i < cons.size(); ++i) {
        const Eigen::Index o = off[i];
        const double mu = cons[i].mu;
        if (cons[i].kind == ConstraintKind::kPlanarFriction) {
          s_new_[o + 1] = mu * std::abs(u_[o]);
        } else if (cons[i].kind == ConstraintKind::kSpatialFriction) {
          double best = 0.0;  // max over the corners v_j . (-u_t)
          for (int k = 0; k < N; ++k) {
            const double a = 2.0 * M_PI * k / N + half;
            best = std::max(best, -(std::cos(a) * u_[o] + std::sin(a) * u_[o + 1]));
          }
          s_new_[o + 2] = mu * corner_radius * best;
        }
      }
      result.own_residual = (s_new_ - s_).norm() / scale;
      s_ = s_new_;
      if (result.own_residual <= own_tolerance) {
        result.own_converged = true;
        result.message = "converged";
        break;
      }
      if (outer >= settings_.pyramid_max_fixed_point) {
        char buf[64];
        std::snprintf(buf, sizeof buf, "%.3g", result.own_residual);
        result.message = "fixed point on the De Saxce term did not settle in " + std::to_string(outer) +
                         " QP solves (LCP residual " + buf + " x ||b||)";
        break;
      }
      if (settings.time_limit > 0.0 &&
          std::chrono::duration<double>(Clock::now() - start).count() > settings.time_limit) {
        out_of_time = true;
        result.message = "time limit reached";
        break;
      }
      g_ = s_ - problem.b();  // min 1/2 l'A l - (b - E s)'l
      qp.settings.initial_guess = pq::InitialGuessStatus::WARM_START_WITH_PREVIOUS_RESULT;
      qp.update(proxsuite::nullopt, g_, proxsuite::nullopt, proxsuite::nullopt, proxsuite::nullopt,
                proxsuite::nullopt, proxsuite::nullopt);
      chunks = solveQpInChunks(qp, budget, settings.time_limit, start, per_iteration);
      qp_iterations += chunks.iterations;
    }
    result.lam = qp.results.x;
    if (!result.lam.allFinite()) {
      result.lam.setZero(m);
      result.own_converged = false;
    }
    result.iterations = outer;
    result.stages.push_back({"proxqp (pyramid QPs)", static_cast<int>(std::min<long>(qp_iterations, 2147483647L)),
                             std::chrono::duration<double>(Clock::now() - start).count(), result.message});
    if (!result.own_converged && !out_of_time &&
        qp.results.info.status != pq::QPSolverOutput::PROXQP_DUAL_INFEASIBLE) {
      // ProxQP misses tight tolerances on some of these QPs (A only semi-definite, a degenerate
      // apex; measured: a third of a pushed cube's steps with 8 facets at 1e-10): finish with ADMM
      // on the same LCP, projecting exactly onto the pyramids, from ProxQP's iterate.
      const auto t0 = Clock::now();
      const Pyramid shape{N, facet_mu, corner_radius};
      bool timed_out = false;
      const int its = admm(problem, A, shape, settings, start, result.lam, result.own_residual, result.own_converged,
                           timed_out);
      const std::string outcome =
          result.own_converged ? "converged" : timed_out ? "time limit reached" : "iteration limit reached";
      result.message = result.own_converged ? "converged (ADMM after ProxQP)" : "ProxQP then ADMM: " + outcome;
      result.iterations += its;
      result.stages.push_back({"admm (pyramid projection)", its,
                               std::chrono::duration<double>(Clock::now() - t0).count(), outcome});
    }
  }

 private:
  // ADMM on the pyramid LCP: (A + rho I) x = b - E s + rho z - y, z = P_pyramid(x + y / rho),
  // y += rho (x - z), s = s_P(A x - b) refreshed from the unconstrained iterate (as the exact
  // ADMM does with the cone). Stops on ||lambda - P(lambda - w)|| <= tol ||b||, w = u + E s_P(u).
  // With settings.time_limit, stops (timed_out) once that many seconds have passed since `start`.
  int admm(const ContactProblem& problem, const Eigen::MatrixXd& A, const Pyramid& shape,
           const SolverSettings& settings, FastClock::time_point start, Eigen::VectorXd& lam, double& residual,
           bool& converged, bool& timed_out) {
    const auto& cons = problem.constraints();
    const auto& off = problem.offsets();
    const Eigen::Index m = problem.numRows();
    const double scale = stoppingScale(problem);
    auto projectAll = [&](Eigen::VectorXd& x) {
      for (std::size_t i = 0; i < cons.size(); ++i) {
        auto xi = x.segment(off[i], cons[i].size);
        switch (cons[i].kind) {
          case ConstraintKind::kBilateral: break;
          case ConstraintKind::kUnilateral: xi[0] = std::max(0.0, xi[0]); break;
          case ConstraintKind::kPlanarFriction: projectPlanarCone(xi, cons[i].mu); break;
          case ConstraintKind::kBox: xi[0] = clampToBox(xi[0], cons[i].lower, cons[i].upper); break;
          case ConstraintKind::kSpatialFriction: {
            if (cons[i].mu <= 0.0) {
              xi[0] = xi[1] = 0.0;
              xi[2] = std::max(0.0, xi[2]);
              break;
            }
            const Pyramid p{shape.N, shape.mu_f * cons[i].mu, shape.corner_radius * cons[i].mu};
            xi = p.project(Eigen::Vector3d(xi[0], xi[1], xi[2]));
            break;
          }
        }
      }
    };
    auto shift = [&](const Eigen::VectorXd& u, Eigen::VectorXd& es) {  // E s_P(u)
      es.setZero(m);
      for (std::size_t i = 0; i < cons.size(); ++i) {
        const Eigen::Index o = off[i];
        if (cons[i].kind == ConstraintKind::kPlanarFriction) es[o + 1] = cons[i].mu * std::abs(u[o]);
        if (cons[i].kind == ConstraintKind::kSpatialFriction)
          es[o + 2] = cons[i].mu * shape.supportOfMinus(u[o], u[o + 1]);
      }
    };
    const double L = std::max(A.diagonal().maxCoeff(), 1e-300);
    double rho = 0.1 * L;
    Eigen::MatrixXd K = 0.5 * (A + A.transpose());
    K.diagonal().array() += rho;
    Eigen::LLT<Eigen::MatrixXd> llt(K);
    Eigen::VectorXd z = lam, x = lam, y = Eigen::VectorXd::Zero(m), u(m), es(m), w(m), r(m), zp(m);
    projectAll(z);
    converged = false;
    int it = 0;
    for (; it < settings.max_iterations; ++it) {
      u.noalias() = A * x;
      u -= problem.b();
      shift(u, es);
      r = problem.b() - es + rho * z - y;
      x = llt.solve(r);
      zp = z;
      z = x + y / rho;
      projectAll(z);
      y += rho * (x - z);
      // the pyramid LCP's natural map at z
      u.noalias() = A * z;
      u -= problem.b();
      shift(u, es);
      w = z - (u + es);
      projectAll(w);
      residual = (z - w).norm() / scale;
      if (residual <= settings.tolerance) {
        converged = true;
        ++it;
        break;
      }
      if (settings.time_limit > 0.0 &&
          std::chrono::duration<double>(FastClock::now() - start).count() > settings.time_limit) {
        timed_out = true;
        ++it;
        break;
      }
      if ((it + 1) % 10 == 0) {  // residual balancing
        const double pr = (x - z).lpNorm<Eigen::Infinity>(), dr = rho * (z - zp).lpNorm<Eigen::Infinity>();
        const double f = pr > 10 * dr ? 5.0 : dr > 10 * pr ? 0.2 : 1.0;
        if (f != 1.0 && rho * f > 1e-8 * L && rho * f < 1e4 * L) {
          K.diagonal().array() += rho * (f - 1.0);
          rho *= f;
          llt.compute(K);
        }
      }
    }
    lam = z;
    return it;
  }

  Eigen::MatrixXd C_, H_;
  Eigen::VectorXd lower_, upper_, g_, s_, s_new_, u_;
};

}  // namespace

std::unique_ptr<Formulation> makePyramidFormulation() { return std::make_unique<PyramidFormulation>(); }

}  // namespace stiction
