#include "stiction/nsgs.hpp"

#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/LU>

#include "stiction/cone.hpp"
#include "stiction/local_solve.hpp"
#include "stiction/verdict.hpp"

namespace stiction {

namespace {

// The stall test's rate is measured over this many sweeps; from sweep kTrackFrom on the earliest
// predicted finish is kept, and from sweep kJudgeFrom a prediction kDeceleration times later is a
// stall (see sweep()).
constexpr int kRateWindow = 10;
constexpr int kTrackFrom = 20;
constexpr int kJudgeFrom = 30;
constexpr double kDeceleration = 1.5;

// Inverse of a diagonal block; a singular block (dependent rows of one contact)
// gets the smallest diagonal shift that makes it invertible, so the local solve
// still returns a finite answer (the global verdict is made on the true residual).
template <typename Matrix>
void invertShifted(Eigen::Map<Eigen::MatrixXd> G, Eigen::Map<Eigen::MatrixXd> G_inv, double scale) {
  Matrix shifted = G;
  for (double eps = 0.0;; eps = eps == 0.0 ? 1e-12 * scale : eps * 100.0) {
    shifted.diagonal() = G.diagonal().array() + eps;
    Eigen::FullPivLU<Matrix> lu(shifted);
    lu.setThreshold(1e-13);
    if (lu.isInvertible() || eps > scale) {
      G_inv = lu.inverse();
      if (eps > 0.0) G.diagonal().array() += eps;  // keep G consistent with G_inv
      return;
    }
  }
}

void invertBlock(Eigen::Map<Eigen::MatrixXd> G, Eigen::Map<Eigen::MatrixXd> G_inv) {
  const double scale = G.diagonal().cwiseAbs().maxCoeff();
  if (!(scale > 0.0)) {  // rows that move nothing (a zero block): their force stays 0
    G_inv.setZero();
    return;
  }
  // fixed sizes for the contact blocks: no allocation (a 1024-contact problem's set-up
  // spent about 1 us per block allocating)
  if (G.rows() == 3 && G == G.transpose()) {  // exactly symmetric
    // A symmetric positive definite contact block (the usual case): a fixed-size Cholesky,
    // accepted when its smallest pivot passes FullPivLU's relative threshold.
    const Eigen::Matrix3d g = G;
    const Eigen::LLT<Eigen::Matrix3d> llt(g);
    const Eigen::Vector3d pivots = llt.matrixLLT().diagonal().cwiseAbs2();
    if (llt.info() == Eigen::Success && pivots.minCoeff() > 1e-13 * pivots.maxCoeff()) {
      G_inv = llt.solve(Eigen::Matrix3d::Identity());
      return;
    }
  }
  switch (G.rows()) {
    case 1: invertShifted<Eigen::Matrix<double, 1, 1>>(G, G_inv, scale); break;
    case 2: invertShifted<Eigen::Matrix2d>(G, G_inv, scale); break;
    case 3: invertShifted<Eigen::Matrix3d>(G, G_inv, scale); break;
    default: invertShifted<Eigen::MatrixXd>(G, G_inv, scale);
  }
}

}  // namespace

void NsgsSolver::prepare(const ContactProblem& problem) {
  const auto& cons = problem.constraints();
  packed_offsets_.resize(cons.size() + 1);
  Eigen::Index total = 0;
  for (std::size_t i = 0; i < cons.size(); ++i) {
    packed_offsets_[i] = total;
    total += static_cast<Eigen::Index>(cons[i].size) * cons[i].size;
  }
  packed_offsets_[cons.size()] = total;
  blocks_.resize(total);
  inverses_.resize(total);
  const auto& off = problem.offsets();
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const int k = cons[i].size;
    Eigen::Map<Eigen::MatrixXd> G(blocks_.data() + packed_offsets_[i], k, k);
    Eigen::Map<Eigen::MatrixXd> G_inv(inverses_.data() + packed_offsets_[i], k, k);
    problem.delassus().diagonalBlock(off[i], k, G);
    invertBlock(G, G_inv);
  }
  const Eigen::Index m = problem.numRows();
  u_.resize(m);
  delta_.resize(m);
  local_.resize(m);
}

int NsgsSolver::sweep(const ContactProblem& problem, Eigen::VectorXd& lam, int max_sweeps,
                      double tolerance, double switch_after, double time_limit, std::string& message,
                      int finish_by) {
  monitor_.startClock(time_limit);
  if (switch_after > 0.0) monitor_.resetRate(kRateWindow, {kTrackFrom, kJudgeFrom, kDeceleration});
  prepare(problem);
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const DelassusOperator& A = problem.delassus();
  const double scale = stoppingScale(problem);
  StoppingTest test(problem, tolerance);

  // Start from a feasible point.
  for (std::size_t i = 0; i < cons.size(); ++i) {
    auto li = lam.segment(off[i], cons[i].size);
    switch (cons[i].kind) {
      case ConstraintKind::kUnilateral: li[0] = std::max(li[0], 0.0); break;
      case ConstraintKind::kPlanarFriction: projectPlanarCone(li, cons[i].mu); break;
      case ConstraintKind::kSpatialFriction: projectSpatialCone(li, cons[i].mu); break;
      case ConstraintKind::kBilateral: break;
      case ConstraintKind::kBox: li[0] = clampToBox(li[0], cons[i].lower, cons[i].upper); break;
    }
  }
  A.multiply(lam, u_);
  u_ -= problem.b();

  int done = 0;
  message = "iteration limit reached";
  for (int it = 0; it < max_sweeps; ++it) {
    for (std::size_t i = 0; i < cons.size(); ++i) {
      const Eigen::Index o = off[i];
      const int k = cons[i].size;
      const double* Gp = blocks_.data() + packed_offsets_[i];
      const double* Gi = inverses_.data() + packed_offsets_[i];
      auto li = lam.segment(o, k);
      auto ui = u_.segment(o, k);
      bool changed = false;
      switch (cons[i].kind) {
        case ConstraintKind::kSpatialFriction: {
          const Eigen::Map<const Eigen::Matrix3d> G(Gp), G_inv(Gi);
          const Eigen::Vector3d old = li;
          const Eigen::Vector3d c = ui - G * old;
          Eigen::Vector3d x = old;
          solveSpatialBlock(G, G_inv, c, cons[i].mu, x);
          delta_.head<3>() = x - old;
          changed = delta_.head<3>().squaredNorm() > 0.0;
          li = x;
          break;
        }
        case ConstraintKind::kPlanarFriction: {
          const Eigen::Map<const Eigen::Matrix2d> G(Gp), G_inv(Gi);
          const Eigen::Vector2d old = li;
          const Eigen::Vector2d c = ui - G * old;
          Eigen::Vector2d x = old;
          solvePlanarBlock(G, G_inv, c, cons[i].mu, x);
          delta_.head<2>() = x - old;
          changed = delta_.head<2>().squaredNorm() > 0.0;
          li = x;
          break;
        }
        case ConstraintKind::kUnilateral: {
          const double old = li[0];
          const double c = ui[0] - Gp[0] * old;
          const double x = Gp[0] > 0.0 ? std::max(0.0, -c / Gp[0]) : (c < 0.0 ? old : 0.0);
          delta_[0] = x - old;
          changed = delta_[0] != 0.0;
          li[0] = x;
          break;
        }
        case ConstraintKind::kBox: {
          // u = G lambda + c in -N_[lo, hi](lambda): lambda = clamp(-c / G); a row that moves nothing
          // (G = 0) goes to the bound its fixed velocity c pushes against (c = 0: stays)
          const double old = li[0];
          const double c = ui[0] - Gp[0] * old;
          const double lo = cons[i].lower, hi = cons[i].upper;
          const double x = Gp[0] > 0.0 ? clampToBox(-c / Gp[0], lo, hi) : (c < 0.0 ? hi : c > 0.0 ? lo : old);
          delta_[0] = x - old;
          changed = delta_[0] != 0.0;
          li[0] = x;
          break;
        }
        case ConstraintKind::kBilateral: {
          const Eigen::Map<const Eigen::MatrixXd> G(Gp, k, k), G_inv(Gi, k, k);
          local_.head(k) = ui - G * li;  // c
          delta_.head(k).noalias() = -G_inv * local_.head(k);
          delta_.head(k) -= li;
          changed = delta_.head(k).squaredNorm() > 0.0;
          li += delta_.head(k);
          break;
        }
      }
      if (changed) A.addColumnBlockTimes(o, k, delta_.head(k), u_);
    }
    done = it + 1;
    if (done % 50 == 0) {  // limit the drift of the incrementally updated u
      A.multiply(lam, u_);
      u_ -= problem.b();
    }
    double map = naturalMapNorm(problem, lam, u_);
    if (map <= test.threshold()) {  // confirm on a fresh u, with the rounding bound
      A.multiply(lam, u_);
      u_ -= problem.b();
      map = naturalMapNorm(problem, lam, u_);
      const StoppingTest::Outcome outcome = test.check(lam, u_, map);
      if (outcome == StoppingTest::kConverged) {
        message = "converged";
        break;
      }
      if (outcome == StoppingTest::kUnresolvable) {
        message = kUnresolvableMessage;
        break;
      }
    }
    const double r = map / scale;
    if (!std::isfinite(r)) {
      message = "diverged (non-finite residual)";
      break;
    }
    if (switch_after > 0.0) {
      // Linear rate over the last 10 sweeps, and the sweeps it still needs (more than
      // switch_after: stalled). A decelerating Gauss-Seidel is stalling too: the sweep at which
      // it predicts to finish (it + needed) moved more than 1.5x later than the earliest such
      // prediction (from sweep 20 on, once the first window's fast start is out of the rate).
      // Measured on FCLib: KaplasTower's prediction grows from 247 (sweep 20) to 441
      // (sweep 80) and it needs 1056 sweeps (2 s) where ADMM takes 0.5 s; Spheres' stays at
      // 231-232 and it converges at 235; the Capsules' and SpheresBox's grow from sweep 30.
      monitor_.record(it, r);
      // (finish_by: a rate that improves all along but would finish past the caller's budget is
      // as good as stalled there: pile-256's step 159, 342 rows, predicted ~300 sweeps of a
      // 200-iteration budget and ran them all to 4.5e-9, where Newton converges in 4 steps)
      if (monitor_.stalled(tolerance, switch_after) ||
          (finish_by > 0 && monitor_.rateReady() && done + monitor_.needed(tolerance) > finish_by)) {
        message = "stalled";
        break;
      }
    }
    if (monitor_.outOfTime()) {
      message = "time limit reached";
      break;
    }
  }
  return done;
}

void NsgsSolver::iterate(const ContactProblem& problem, const SolverSettings& settings,
                         SolverResult& result) {
  result.iterations = sweep(problem, result.lam, settings.max_iterations, settings.tolerance, 0.0,
                            settings.time_limit, result.message);
}

}  // namespace stiction
