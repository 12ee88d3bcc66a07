// The semismooth Newton solver (newton.hpp): the natural map and its generalized Jacobian, the
// step by a dense, block-diagonal or sparse factorization, a non-monotone line search.
#include "stiction/newton.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "stiction/admm.hpp"
#include "stiction/cone.hpp"

namespace stiction {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// The filtered Newton step (box rows) is taken when the part of F it leaves is below this share of
// the stopping test's threshold.
constexpr double kFilteredShare = 0.5;
// With box rows, a line search without descent also tries the first few points where a box or
// unilateral row's natural-map argument crosses a bound, this far (relative) past each.
constexpr int kBreakpointTrials = 8;
constexpr double kPastBreakpoint = 1e-9;

// Jacobian of the projection onto {||x_t|| <= mu x_n} (k = 2 or 3, normal last).
template <int K>
Eigen::Matrix<double, K, K> coneProjectionJacobian(const Eigen::Matrix<double, K, 1>& z, double mu) {
  using Mat = Eigen::Matrix<double, K, K>;
  using Vt = Eigen::Matrix<double, K - 1, 1>;
  const Vt zt = z.template head<K - 1>();
  const double zn = z[K - 1];
  const double rho = zt.norm();
  if (zn >= 0.0 && rho <= mu * zn) return Mat::Identity();
  if (mu * rho <= -zn) return Mat::Zero();
  const double d = 1.0 + mu * mu;
  const double a = (zn + mu * rho) / d;
  Mat J = Mat::Zero();
  if (!(rho > 0.0)) {  // mu = 0 corner: only the normal survives
    J(K - 1, K - 1) = 1.0 / d;
    return J;
  }
  const Vt e = zt / rho;
  J.template topLeftCorner<K - 1, K - 1>() =
      mu * (mu / d) * e * e.transpose() +
      mu * a / rho * (Eigen::Matrix<double, K - 1, K - 1>::Identity() - e * e.transpose());
  J.template topRightCorner<K - 1, 1>() = mu / d * e;
  J.template bottomLeftCorner<1, K - 1>() = mu / d * e.transpose();
  J(K - 1, K - 1) = 1.0 / d;
  return J;
}

// No entry of the dense A outside the square diagonal blocks of its constraints.
bool blocksUncoupled(const ContactProblem& problem) {
  const Eigen::MatrixXd& A = problem.delassus().dense();
  const Eigen::Index m = A.rows();
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index begin = off[i], end = off[i] + cons[i].size;
    for (Eigen::Index j = begin; j < end; ++j) {
      const double* column = A.data() + j * m;
      for (Eigen::Index r = 0; r < begin; ++r)
        if (column[r] != 0.0) return false;
      for (Eigen::Index r = end; r < m; ++r)
        if (column[r] != 0.0) return false;
    }
  }
  return true;
}

}  // namespace

// x = -a^-1 f for one k x k block (k <= 3, column-major a, eps added to its diagonal) by Gaussian
// elimination with partial pivoting, in registers (Eigen's fixed-size PartialPivLU spent ~360
// instructions on a 3 x 3). False, x unset, when a pivot is below `pivot_floor` times the block's
// largest entry (0: never; a zero pivot then gives non-finite values, as the whole system's LU).
template <int K>
bool negatedBlockSolve(const double* a, Eigen::Index stride, double eps, const double* f, double* x,
                       double pivot_floor) {
  double m[K][K], r[K], big = 0.0;
  for (int i = 0; i < K; ++i) {
    for (int j = 0; j < K; ++j) {
      m[i][j] = a[i + j * stride];
      big = std::max(big, std::abs(m[i][j]));
    }
    m[i][i] += eps;
    r[i] = -f[i];
  }
  for (int k = 0; k < K; ++k) {
    int p = k;
    for (int i = k + 1; i < K; ++i)
      if (std::abs(m[i][k]) > std::abs(m[p][k])) p = i;
    if (p != k) {
      for (int j = 0; j < K; ++j) std::swap(m[k][j], m[p][j]);
      std::swap(r[k], r[p]);
    }
    if (!(std::abs(m[k][k]) > pivot_floor * big) && pivot_floor > 0.0) return false;
    for (int i = k + 1; i < K; ++i) {
      const double l = m[i][k] / m[k][k];
      for (int j = k + 1; j < K; ++j) m[i][j] -= l * m[k][j];
      r[i] -= l * r[k];
    }
  }
  for (int k = K - 1; k >= 0; --k) {
    double v = r[k];
    for (int j = k + 1; j < K; ++j) v -= m[k][j] * x[j];
    x[k] = v / m[k][k];
  }
  return true;
}

// Below this relative pivot a block's Newton system counts as singular: it gets the shift.
constexpr double kUncoupledPivotFloor = 1e-8;

// One block's Newton step: unshifted when well-pivoted, else with the shift eps.
template <int K>
void blockNewtonStep(const double* a, Eigen::Index stride, double eps, const double* f, double* x) {
  if (!negatedBlockSolve<K>(a, stride, 0.0, f, x, kUncoupledPivotFloor)) negatedBlockSolve<K>(a, stride, eps, f, x, 0.0);
}

void NewtonSolver::solveUncoupled(const ContactProblem& problem, double eps) {
  // Each block's square of dF on its own (the LU of the whole 9 x 9 system of Toy FC3D_Example1
  // was a quarter of its solve). Unshifted where the block is well-conditioned: the shift eps is
  // there for rank-deficient systems (a tower's), and capped at 1e-2 it made the first step from
  // lambda = 0 1 % off, two more steps to repair (Toy FC3D_Example1: 3 steps, now 1). A block
  // with a small pivot gets the shift, as the whole system would.
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const Eigen::Index m = F_.size();
  step_.resize(m);
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    const double* a = J_.data() + o + o * m;
    const double* f = F_.data() + o;
    double* x = step_.data() + o;
    switch (cons[i].size) {
      case 1: blockNewtonStep<1>(a, m, eps, f, x); break;
      case 2: blockNewtonStep<2>(a, m, eps, f, x); break;
      case 3: blockNewtonStep<3>(a, m, eps, f, x); break;
      default: {  // (a bilateral block of another size)
        const int k = cons[i].size;
        Eigen::MatrixXd block = J_.block(o, o, k, k);
        block.diagonal().array() += eps;
        step_.segment(o, k) = -block.partialPivLu().solve(F_.segment(o, k));
      }
    }
  }
}

void NewtonSolver::evaluate(const ContactProblem& problem, const Eigen::VectorXd& lam, bool jacobian) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  static const Eigen::MatrixXd kNone;  // the sparse path never reads a dense A (nor builds one)
  const Eigen::MatrixXd& A = sparse_ ? kNone : problem.delassus().dense();
  const Eigen::Index m = problem.numRows();
  // With the Jacobian, u_ is the one the last evaluation at this same lam left (run() asks
  // for the Jacobian only at the accepted iterate, evaluated just before).
  if (!jacobian) {
    u_.resize(m);
    problem.delassus().multiply(lam, u_);
    u_ -= problem.b();
  }
  F_.resize(m);
  const bool dense_jacobian = jacobian && !sparse_;
  const bool sparse_jacobian = jacobian && sparse_;
  if (dense_jacobian) {
    if (uncoupled_)
      J_.resize(m, m);  // (its diagonal blocks written below; nothing else read)
    else
      J_.setZero(m, m);
  }
  // Sparse: each block's rows of the Jacobian are G A_(block rows) + D on the diagonal block,
  // G and D k x k, stored here and applied to A's pattern by fillSparseJacobian.
  auto store = [&](std::size_t i, const auto& G, const auto& D) {
    const int k = cons[i].size;
    Eigen::Map<Eigen::MatrixXd>(block_G_.data() + packed_[i], k, k) = G;
    Eigen::Map<Eigen::MatrixXd>(block_D_.data() + packed_[i], k, k) = D;
  };
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    const int k = cons[i].size;
    const double kap = kappa_[i];
    const double mu = cons[i].mu;
    switch (cons[i].kind) {
      case ConstraintKind::kBilateral:
        F_.segment(o, k) = kap * u_.segment(o, k);
        if (dense_jacobian) J_.middleRows(o, k) = kap * A.middleRows(o, k);
        if (sparse_jacobian) store(i, kap * Eigen::MatrixXd::Identity(k, k), Eigen::MatrixXd::Zero(k, k));
        break;
      case ConstraintKind::kUnilateral: {
        const double z = lam[o] - kap * u_[o];
        F_[o] = lam[o] - std::max(0.0, z);
        if (dense_jacobian) {
          if (z > 0.0)
            J_.row(o) = kap * A.row(o);
          else
            J_(o, o) = 1.0;
        }
        if (sparse_jacobian)
          store(i, Eigen::Matrix<double, 1, 1>(z > 0.0 ? kap : 0.0), Eigen::Matrix<double, 1, 1>(z > 0.0 ? 0.0 : 1.0));
        break;
      }
      case ConstraintKind::kBox: {
        // F = lambda - clamp(z, lo, hi): dF = kappa A's row strictly inside, e_o at (or beyond) a bound
        const double z = lam[o] - kap * u_[o];
        const double lo = cons[i].lower, hi = cons[i].upper;
        const bool inside = z > lo && z < hi;
        F_[o] = lam[o] - clampToBox(z, lo, hi);
        if (dense_jacobian) {
          if (inside)
            J_.row(o) = kap * A.row(o);
          else
            J_(o, o) = 1.0;
        }
        if (sparse_jacobian)
          store(i, Eigen::Matrix<double, 1, 1>(inside ? kap : 0.0), Eigen::Matrix<double, 1, 1>(inside ? 0.0 : 1.0));
        break;
      }
      case ConstraintKind::kPlanarFriction: {
        const double ut = u_[o];
        Eigen::Vector2d z = lam.segment<2>(o) - kap * u_.segment<2>(o);
        z[1] -= kap * mu * std::abs(ut);
        Eigen::Vector2d p = z;
        projectPlanarCone(p, mu);
        F_.segment<2>(o) = lam.segment<2>(o) - p;
        if (jacobian) {
          const Eigen::Matrix2d JP = coneProjectionJacobian<2>(z, mu);
          const double sg = ut > 0.0 ? 1.0 : (ut < 0.0 ? -1.0 : 0.0);
          // rows of (I + D_s) A, D_s = d(E s)/du
          if (sparse_jacobian) {
            Eigen::Matrix2d G = kap * JP;
            G.col(0) += (kap * mu * sg) * JP.col(1);
            store(i, G, Eigen::Matrix2d(Eigen::Matrix2d::Identity() - JP));
          } else {
            J_.middleRows(o, 2).noalias() = kap * JP * A.middleRows(o, 2);
            if (sg != 0.0) J_.middleRows(o, 2).noalias() += (kap * mu * sg) * JP.col(1) * A.row(o);
            J_.block(o, o, 2, 2) += Eigen::Matrix2d::Identity() - JP;
          }
        }
        break;
      }
      case ConstraintKind::kSpatialFriction: {
        const double utn = norm2(u_[o], u_[o + 1]);
        Eigen::Vector3d z = lam.segment<3>(o) - kap * u_.segment<3>(o);
        z[2] -= kap * mu * utn;
        Eigen::Vector3d p = z;
        projectSpatialCone(p, mu);
        F_.segment<3>(o) = lam.segment<3>(o) - p;
        if (jacobian) {
          const Eigen::Matrix3d JP = coneProjectionJacobian<3>(z, mu);
          // rows of (I + D_s) A, D_s = d(E s)/du: the normal row gains mu u_t^T A_t / |u_t|,
          // so the three rows are G A_(rows o..o+2) with G = kap JP (I + mu e_n [u_t/|u_t|, 0]).
          Eigen::Matrix3d G = kap * JP;
          if (utn > 0.0) {
            G.col(0) += (kap * mu * u_[o] / utn) * JP.col(2);
            G.col(1) += (kap * mu * u_[o + 1] / utn) * JP.col(2);
          }
          if (sparse_jacobian) {
            store(i, G, Eigen::Matrix3d(Eigen::Matrix3d::Identity() - JP));
            break;
          }
          if (uncoupled_) {  // only the diagonal block is read (solveUncoupled)
            J_.block<3, 3>(o, o).noalias() = G * A.block<3, 3>(o, o);
            J_.block<3, 3>(o, o) += Eigen::Matrix3d::Identity() - JP;
            break;
          }
          // one pass over A's three rows (column-major: three neighbours per column)
          const double* a = A.data() + o;
          double* out = J_.data() + o;
          for (Eigen::Index j = 0; j < m; ++j, a += m, out += m) {
            const double a0 = a[0], a1 = a[1], a2 = a[2];
            out[0] = G(0, 0) * a0 + G(0, 1) * a1 + G(0, 2) * a2;
            out[1] = G(1, 0) * a0 + G(1, 1) * a1 + G(1, 2) * a2;
            out[2] = G(2, 0) * a0 + G(2, 1) * a1 + G(2, 2) * a2;
          }
          J_.block(o, o, 3, 3) += Eigen::Matrix3d::Identity() - JP;
        }
        break;
      }
    }
  }
  if (sparse_jacobian) fillSparseJacobian(problem);
}

void NewtonSolver::prepareSparse(const ContactProblem& problem) {
  // The Jacobian's pattern: a block's rows are mixed by G, so row i holds an entry wherever any
  // row of its block has one in A; plus every diagonal block (D, and the eps shift).
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const Eigen::Index m = problem.numRows();
  row_block_.resize(m);
  packed_.resize(cons.size() + 1);
  Eigen::Index total = 0;
  for (std::size_t i = 0; i < cons.size(); ++i) {
    for (int r = 0; r < cons[i].size; ++r) row_block_[off[i] + r] = static_cast<int>(i);
    packed_[i] = total;
    total += static_cast<Eigen::Index>(cons[i].size) * cons[i].size;
  }
  packed_[cons.size()] = total;
  block_G_.resize(total);
  block_D_.resize(total);
  std::vector<Eigen::Triplet<double>> entries;
  std::vector<char> seen(cons.size(), 0);
  std::vector<int> touched;
  auto column = [&](Eigen::Index j, auto&& rows_of_column) {
    touched.clear();
    auto mark = [&](Eigen::Index row) {
      const int b = row_block_[row];
      if (!seen[b]) {
        seen[b] = 1;
        touched.push_back(b);
      }
    };
    rows_of_column(mark);
    mark(j);  // the diagonal block
    for (int b : touched) {
      seen[b] = 0;
      for (int r = 0; r < cons[b].size; ++r) entries.emplace_back(off[b] + r, j, 0.0);
    }
  };
  if (const Eigen::SparseMatrix<double>* S = problem.delassus().sparse()) {
    for (Eigen::Index j = 0; j < m; ++j)
      column(j, [&](auto& mark) {
        for (Eigen::SparseMatrix<double>::InnerIterator it(*S, j); it; ++it) mark(it.row());
      });
  } else {
    const Eigen::MatrixXd& A = problem.delassus().dense();
    for (Eigen::Index j = 0; j < m; ++j)
      column(j, [&](auto& mark) {
        for (Eigen::Index i = 0; i < m; ++i)
          if (A(i, j) != 0.0) mark(i);
      });
  }
  Js_.resize(m, m);
  Js_.setFromTriplets(entries.begin(), entries.end());
  Js_.makeCompressed();
  diagonal_at_.resize(m);
  for (Eigen::Index j = 0; j < m; ++j) {
    const int* rows = Js_.innerIndexPtr();
    const int* hit = std::lower_bound(rows + Js_.outerIndexPtr()[j], rows + Js_.outerIndexPtr()[j + 1], int(j));
    diagonal_at_[j] = static_cast<int>(hit - rows);
  }
  column_.setZero(m);
  sparse_lu_.analyzePattern(Js_);
}

void NewtonSolver::fillSparseJacobian(const ContactProblem& problem) {
  // Row i of block b (local row r): sum_c G_b(r, c) A(off_b + c, j), plus D_b(r, j - off_b) in
  // the diagonal block. A's column j is scattered into column_ (dense A: read in place).
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const Eigen::Index m = problem.numRows();
  const Eigen::SparseMatrix<double>* S = problem.delassus().sparse();
  const int* outer = Js_.outerIndexPtr();
  const int* inner = Js_.innerIndexPtr();
  double* values = Js_.valuePtr();
  for (Eigen::Index j = 0; j < m; ++j) {
    const double* col;
    if (S != nullptr) {
      for (Eigen::SparseMatrix<double>::InnerIterator it(*S, j); it; ++it) column_[it.row()] = it.value();
      col = column_.data();
    } else {
      col = problem.delassus().dense().data() + j * m;
    }
    const int jb = row_block_[j];
    for (int p = outer[j]; p < outer[j + 1];) {
      const int b = row_block_[inner[p]];
      const int k = cons[b].size;
      const double* G = block_G_.data() + packed_[b];  // column-major k x k
      const double* a = col + off[b];
      for (int r = 0; r < k; ++r, ++p) {
        double v = 0.0;
        for (int c = 0; c < k; ++c) v += G[c * k + r] * a[c];
        if (b == jb) v += block_D_[packed_[b] + (j - off[b]) * k + r];
        values[p] = v;
      }
    }
    if (S != nullptr)
      for (Eigen::SparseMatrix<double>::InnerIterator it(*S, j); it; ++it) column_[it.row()] = 0.0;
  }
}

int NewtonSolver::run(const ContactProblem& problem, Eigen::VectorXd& lam, int max_steps,
                      double tolerance, double time_limit, std::string& message) {
  monitor_.startClock(time_limit);
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const Eigen::Index m = problem.numRows();
  StoppingTest test(problem, tolerance);
  // Above the small LU's size, a sparse A (held sparse, or dense with at most
  // kSparseJacobianDensity nonzero) gets a sparse Jacobian and a sparse LU: SpheresBox (768
  // rows) took 31 ms per dense step.
  sparse_ = m > SmallDenseLU::kMaxRows && sparseEnough(problem, kSparseJacobianDensity);
  if (sparse_) prepareSparse(problem);
  uncoupled_ = !sparse_ && m <= SmallDenseLU::kMaxRows && blocksUncoupled(problem);
  diagonal_.resize(m);  // (no allocation once sized: the simulator runs this every step)
  problem.delassus().diagonal(diagonal_);
  kappa_.resize(cons.size());
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const double tr = diagonal_.segment(off[i], cons[i].size).sum();
    kappa_[i] = tr > 0.0 ? cons[i].size / tr : 1.0;
  }
  // With box rows (a robot's joint friction, effort limits) the step may be filtered to J's
  // numerical range (below). A robot standing with every joint's friction row has more rows than
  // velocities (ANYmal: 12 contact + 12 joint rows, rank <= 18): at every all-stick iterate
  // dF = K A is singular, and the part of F no lambda can cancel (b's rounding out of A's range,
  // ~3 % of the tolerance there) became a plain step r_0 / eps along A's null space, as large as
  // lambda itself with eps ~ ||F||: it left the boxes and the line search found no descent
  // (anymal-stand with 0.5 N m friction: over half the steps stalled and fell back to ProxQP).
  // Contact-only problems keep the plain step (their measured paths, FCLib; the sticking step
  // covers their usual rank-deficient case, a sole's or a tower's all-stick solution).
  const bool filter_null_space = !uncoupled_ && problem.hasBoxRows();
  message = "iteration limit reached";
  int step = 0;
  constexpr int kHistory = 4;
  double history[kHistory] = {0.0, 0.0, 0.0, 0.0};
  evaluate(problem, lam, false);  // the Jacobian only once a step is needed
  double f_norm = F_.norm();
  for (; step < max_steps; ++step) {
    const double natural_map = naturalMapNorm(problem, lam, u_);
    const StoppingTest::Outcome outcome = test.check(lam, u_, natural_map);
    if (outcome != StoppingTest::kContinue) {
      message = outcome == StoppingTest::kConverged ? "converged" : kUnresolvableMessage;
      break;
    }
    if (monitor_.outOfTime()) {
      message = "time limit reached";
      break;
    }
    evaluate(problem, lam, true);
    // (dF + eps I) d = -F, eps ~ ||F|| relative to the size of lambda.
    const double eps = std::min(1e-2, std::max(1e-14, f_norm / (1.0 + lam.norm())));
    if (sparse_) {
      double* values = Js_.valuePtr();
      for (Eigen::Index j = 0; j < m; ++j) values[diagonal_at_[j]] += eps;
      sparse_lu_.factorize(Js_);
      if (sparse_lu_.info() != Eigen::Success) {
        message = "singular Newton system";
        break;
      }
      step_ = sparse_lu_.solve(F_);
      step_ = -step_;
    } else if (uncoupled_) {
      solveUncoupled(problem, eps);
    } else if (m <= SmallDenseLU::kMaxRows) {
      J_.diagonal().array() += eps;
      small_lu_.compute(J_);  // (J_ is rebuilt before its next use)
      step_ = -F_;
      small_lu_.solve(step_);
    } else {
      J_.diagonal().array() += eps;
      lu_.compute(J_);
      step_ = lu_.solve(F_);
      step_ = -step_;
    }
    if (!step_.allFinite()) {
      message = "singular Newton system";
      break;
    }
    if (filter_null_space) {
      // d = (J + eps I)^-1 J d0 = d0 - eps (J + eps I)^-1 d0: one more solve with the factor in hand
      // (iterated Tikhonov). Along a direction J nearly annihilates (sigma << eps) the step d0 is
      // -F_sigma / eps and d only sigma F_sigma / eps^2; elsewhere the two agree to O(eps / sigma).
      // By the linear model d0 leaves F + J d0 = -eps d0 and d leaves F + J d = -eps (d0 + d): the
      // part of F along those directions, which no step near this active set cancels. d is taken
      // when that part is below half the tolerance (in the natural map's units: F is K u where
      // every block sticks): rounding the answer need not cancel. Above it the part is real (a
      // UR5 pushing on a wall, whose gap term asks the joints for a slip of 1e-9 at 50 times the
      // tolerance): a box row has to reach its bound, and the plain step's long move along those
      // directions leads there (its line search tries where rows cross their bounds, below).
      filtered_ = eps * step_;
      if (sparse_) {
        filtered_ = sparse_lu_.solve(filtered_);
      } else if (m <= SmallDenseLU::kMaxRows) {
        small_lu_.solve(filtered_);
      } else {
        filtered_ = lu_.solve(filtered_);
      }
      const double left = eps * (2.0 * step_ - filtered_).norm();
      if (filtered_.allFinite() && left * natural_map <= kFilteredShare * test.threshold() * f_norm) step_ -= filtered_;
    }
    // Non-monotone backtracking on ||F|| (against the worst of the last few
    // values): the natural map is only semismooth, a strict decrease test
    // rejects good steps across kinks.
    double reference = f_norm;
    for (double h : history) reference = std::max(reference, h);
    double t = 1.0, best_norm = kInf, best_t = 0.0;
    bool best_is_last = false;  // u_ and F_ hold the best trial's values
    bool sufficient = false;
    trial_.resize(m);
    if (filter_null_space) u_start_ = u_;  // (A d from the first trial, for the breakpoints below)
    auto try_step = [&](double t_try) {
      trial_ = lam + t_try * step_;
      evaluate(problem, trial_, false);
      const double n = F_.norm();
      best_is_last = n < best_norm;
      if (best_is_last) {
        best_norm = n;
        best_t = t_try;
      }
      sufficient = n <= (1.0 - 1e-4 * t_try) * reference;
    };
    for (int ls = 0; ls < 20 && !sufficient; ++ls, t *= 0.5) {
      try_step(t);
      if (ls == 0 && filter_null_space) step_image_ = u_ - u_start_;  // A d
    }
    if (!sufficient && filter_null_space) {
      // Where a box row must reach its bound (a joint that slips, barely: the part of F no step on
      // this active set cancels is a few times the tolerance), descent lies only just past the point
      // where the row's z = lambda - kappa u crosses its bound (z is linear in t: A d is the first
      // trial's u less the iterate's): there its kappa u leaves F and lambda - bound starts from 0.
      // That window (4e-5 of the step's length on go2-stand) falls between the halvings above,
      // which then found no descent: Newton stalled, and ProxQP or ADMM took over (~60-130 us). The
      // first few crossings are tried, in order, just past each.
      breakpoints_.clear();
      for (std::size_t i = 0; i < cons.size(); ++i) {
        if (cons[i].kind != ConstraintKind::kBox && cons[i].kind != ConstraintKind::kUnilateral) continue;
        const Eigen::Index o = off[i];
        const double z0 = lam[o] - kappa_[i] * u_start_[o];
        const double dz = step_[o] - kappa_[i] * step_image_[o];
        const double lo = cons[i].kind == ConstraintKind::kBox ? cons[i].lower : 0.0;
        const double hi = cons[i].kind == ConstraintKind::kBox ? cons[i].upper : kInf;
        for (double bound : {lo, hi}) {
          const double tc = (bound - z0) / dz;
          if (tc > 0.0 && tc < 1.0) breakpoints_.push_back(tc * (1.0 + kPastBreakpoint));
        }
      }
      std::sort(breakpoints_.begin(), breakpoints_.end());
      const std::size_t tried = std::min<std::size_t>(breakpoints_.size(), kBreakpointTrials);
      for (std::size_t k = 0; k < tried && !sufficient; ++k) try_step(breakpoints_[k]);
    }
    if (!(best_norm < reference)) {
      message = "stalled (no descent along the Newton direction)";
      evaluate(problem, lam, false);  // restore u_ for the caller's verdict
      break;
    }
    history[step % kHistory] = f_norm;
    if (best_is_last) {
      lam.swap(trial_);  // u_ and F_ are already this iterate's
      f_norm = best_norm;
    } else {
      lam += best_t * step_;
      evaluate(problem, lam, false);
      f_norm = F_.norm();
    }
  }
  return step;
}

void NewtonSolver::iterate(const ContactProblem& problem, const SolverSettings& settings,
                           SolverResult& result) {
  result.iterations = run(problem, result.lam, settings.max_iterations, settings.tolerance,
                          settings.time_limit, result.message);
}

}  // namespace stiction
