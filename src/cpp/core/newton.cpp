#include "stiction/newton.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <utility>

#include "stiction/clock.hpp"
#include "stiction/admm.hpp"
#include "stiction/cone.hpp"
#include "stiction/proxqp_warm_start.hpp"
#include "stiction/vector_kernels.hpp"
#ifdef STICTION_X86_KERNELS
#include <immintrin.h>
#endif

namespace stiction {

namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

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

// Every block of x strictly inside its cone: a unilateral row pushing, a friction block's
// tangential part below mu times a positive normal part (bilateral rows: any value), by a relative
// margin: a block at the edge of slipping (statically indeterminate friction left at mu |lambda_n|
// by an earlier solve, as in a grid of resting cubes) would most likely leave the cone in the
// all-stick solution, and the factorization would be wasted. With de_saxce, the normal part is
// first shifted by De Saxce's term, x_n - mu |x_t| (see stickingAtZero).
constexpr double kInsideMargin = 1e-6;

bool strictlyInsideCones(const ContactProblem& problem, const Eigen::VectorXd& x, bool de_saxce = false) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const double shift = de_saxce ? 1.0 : 0.0;
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    const double mu = cons[i].mu;
    switch (cons[i].kind) {
      case ConstraintKind::kBilateral: break;
      case ConstraintKind::kUnilateral:
        if (!(x[o] > 0.0)) return false;
        break;
      case ConstraintKind::kPlanarFriction: {
        const double t = std::abs(x[o]);
        if (!(t < (1.0 - kInsideMargin) * mu * (x[o + 1] - shift * mu * t))) return false;
        break;
      }
      case ConstraintKind::kSpatialFriction: {
        const double t = norm2(x[o], x[o + 1]);
        if (!(t < (1.0 - kInsideMargin) * mu * (x[o + 2] - shift * mu * t))) return false;
        break;
      }
    }
  }
  return true;
}

// At lambda = 0 the natural map of eq. 65 puts every block in its sticking regime when its
// argument there, -kappa (u + mu |u_t| e_n) with u = -b, is strictly inside the cone: b inside the
// cones once shifted by De Saxce's term (|b_t| < mu (b_n - mu |b_t|); unilateral rows b_n > 0).
// Newton's first step from zero then aims at the all-stick solution, but regularised (its shift is
// largest there, ~1 % of the scaled Jacobian: CubesH8-27 took 4 steps, 0.019, 3e-4, 9e-8, 8e-15);
// one factorization of A reaches it. Only a prediction: the sticking step's stopping test decides,
// and Newton follows if it fails.
bool stickingAtZero(const ContactProblem& problem) {
  return strictlyInsideCones(problem, problem.b(), /*de_saxce=*/true);
}

// Entries A stores (a dense A: its nonzeros).
Eigen::Index storedEntries(const ContactProblem& problem) {
  if (const Eigen::SparseMatrix<double>* S = problem.delassus().sparse()) return S->nonZeros();
  const Eigen::MatrixXd& A = problem.delassus().dense();
  return static_cast<Eigen::Index>((A.array() != 0.0).count());
}

// The LU's update of the columns right of pivots k and k + 1 in one pass over each (half the
// loads and stores of one pass per pivot): c_j[k+1] -= l0[k+1] c_j[k], then
// c_j[k+2:] -= l0[k+2:] c_j[k] + l1[k+2:] c_j[k+1] (l0, l1 = columns k and k + 1).
void eliminateTwoPortable(double* d, Eigen::Index m, Eigen::Index k) {
  const double* __restrict l0 = d + k * m;
  const double* __restrict l1 = d + (k + 1) * m;
  for (Eigen::Index j = k + 2; j < m; ++j) {
    double* __restrict cj = d + j * m;
    const double f0 = cj[k];
    const double f1 = cj[k + 1] - l0[k + 1] * f0;
    cj[k + 1] = f1;
    if (f0 == 0.0 && f1 == 0.0) continue;
    for (Eigen::Index i = k + 2; i < m; ++i) cj[i] = (cj[i] - l0[i] * f0) - l1[i] * f1;
  }
}

#ifdef STICTION_X86_KERNELS
// The same with four rows per instruction (CubesH8's 27 x 27 Newton system: its LU was most
// of the solve). Raw pointers and intrinsics only (docs/development.md).
__attribute__((target("avx2,fma"))) void eliminateTwoAvx2(double* d, Eigen::Index m, Eigen::Index k) {
  const double* l0 = d + k * m;
  const double* l1 = d + (k + 1) * m;
  for (Eigen::Index j = k + 2; j < m; ++j) {
    double* cj = d + j * m;
    const double f0 = cj[k];
    const double f1 = cj[k + 1] - l0[k + 1] * f0;
    cj[k + 1] = f1;
    if (f0 == 0.0 && f1 == 0.0) continue;
    const __m256d v0 = _mm256_set1_pd(f0), v1 = _mm256_set1_pd(f1);
    Eigen::Index i = k + 2;
    for (; i + 4 <= m; i += 4) {
      const __m256d c = _mm256_fnmadd_pd(_mm256_loadu_pd(l0 + i), v0, _mm256_loadu_pd(cj + i));
      _mm256_storeu_pd(cj + i, _mm256_fnmadd_pd(_mm256_loadu_pd(l1 + i), v1, c));
    }
    for (; i < m; ++i) cj[i] = (cj[i] - l0[i] * f0) - l1[i] * f1;
  }
}
#endif

// Pivot k: the largest entry of column k from the diagonal down (its row swapped with row k
// across the matrix), the column below it divided by it. Column k must hold every earlier
// pivot's update.
void choosePivot(double* d, Eigen::Index m, Eigen::Index k, std::vector<int>& pivots) {
  double* ck = d + k * m;
  Eigen::Index p = k;
  double big = std::abs(ck[k]);
  for (Eigen::Index i = k + 1; i < m; ++i)
    if (std::abs(ck[i]) > big) {
      big = std::abs(ck[i]);
      p = i;
    }
  pivots[static_cast<std::size_t>(k)] = static_cast<int>(p);
  if (p != k)
    for (Eigen::Index j = 0; j < m; ++j) std::swap(d[j * m + k], d[j * m + p]);
  const double pivot = ck[k];
  if (pivot != 0.0) {
    const double inv = 1.0 / pivot;
    for (Eigen::Index i = k + 1; i < m; ++i) ck[i] *= inv;
  }
}

}  // namespace

void SmallDenseLU::compute(Eigen::MatrixXd& a) {
  // Right-looking elimination with partial pivoting, in place, two pivots at a time: pivot k,
  // its update of column k + 1 alone, pivot k + 1 (its row swap commutes with pivot k's update
  // still pending on the columns right of it: both rows move in l0 too), then both updates in
  // one pass over the remaining columns. The inner loops run down contiguous columns. A zero
  // pivot is left in place (its column below is zero, so it updates nothing): the solve then
  // gives non-finite values, which run() reports as a singular Newton system, as Eigen's LU did.
  const Eigen::Index m = a.rows();
  pivots_.resize(m);
  double* d = a.data();
  const bool vector = vectorKernels();
  for (Eigen::Index k = 0; k < m; k += 2) {
    choosePivot(d, m, k, pivots_);
    if (k + 1 == m) break;
    const double* l0 = d + k * m;
    double* c1 = d + (k + 1) * m;
    const double f = c1[k];
    if (f != 0.0)
      for (Eigen::Index i = k + 1; i < m; ++i) c1[i] -= l0[i] * f;
    choosePivot(d, m, k + 1, pivots_);
#ifdef STICTION_X86_KERNELS
    if (vector) {
      eliminateTwoAvx2(d, m, k);
      continue;
    }
#endif
    eliminateTwoPortable(d, m, k);
  }
  factor_ = &a;
}

void SmallDenseLU::solve(Eigen::VectorXd& x) const {
  const Eigen::MatrixXd& a = *factor_;
  const Eigen::Index m = a.rows();
  const double* d = a.data();
  double* __restrict v = x.data();
  for (Eigen::Index k = 0; k < m; ++k)
    if (pivots_[k] != k) std::swap(v[k], v[pivots_[k]]);
  for (Eigen::Index k = 0; k < m; ++k) {  // L y = P x, unit diagonal
    const double vk = v[k];
    if (vk == 0.0) continue;
    const double* __restrict ck = d + k * m;
    for (Eigen::Index i = k + 1; i < m; ++i) v[i] -= ck[i] * vk;
  }
  for (Eigen::Index k = m - 1; k >= 0; --k) {  // U x = y
    const double* __restrict ck = d + k * m;
    v[k] /= ck[k];
    const double vk = v[k];
    for (Eigen::Index i = 0; i < k; ++i) v[i] -= ck[i] * vk;
  }
}

namespace {

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
  using Clock = FastClock;  // the time-stamp counter (clock.hpp)
  const auto start = Clock::now();
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const Eigen::Index m = problem.numRows();
  StoppingTest test(problem, tolerance);
  // Above the small LU's size, a sparse A (held sparse, or dense with at most 10 % nonzero, as
  // for ADMM) gets a sparse Jacobian and a sparse LU: SpheresBox (768 rows) took 31 ms per
  // dense step.
  sparse_ = m > SmallDenseLU::kMaxRows && AdmmSolver::factorsSparsely(problem);
  if (sparse_) prepareSparse(problem);
  uncoupled_ = !sparse_ && m <= SmallDenseLU::kMaxRows && blocksUncoupled(problem);
  diagonal_.resize(m);  // (no allocation once sized: the simulator runs this every step)
  problem.delassus().diagonal(diagonal_);
  kappa_.resize(cons.size());
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const double tr = diagonal_.segment(off[i], cons[i].size).sum();
    kappa_[i] = tr > 0.0 ? cons[i].size / tr : 1.0;
  }
  message = "iteration limit reached";
  int step = 0;
  constexpr int kHistory = 4;
  double history[kHistory] = {0.0, 0.0, 0.0, 0.0};
  evaluate(problem, lam, false);  // the Jacobian only once a step is needed
  double f_norm = F_.norm();
  for (; step < max_steps; ++step) {
    const StoppingTest::Outcome outcome = test.check(lam, u_, naturalMapNorm(problem, lam, u_));
    if (outcome != StoppingTest::kContinue) {
      message = outcome == StoppingTest::kConverged ? "converged" : kUnresolvableMessage;
      break;
    }
    if (time_limit > 0.0 && std::chrono::duration<double>(Clock::now() - start).count() > time_limit) {
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
    // Non-monotone backtracking on ||F|| (against the worst of the last few
    // values): the natural map is only semismooth, a strict decrease test
    // rejects good steps across kinks.
    double reference = f_norm;
    for (double h : history) reference = std::max(reference, h);
    double t = 1.0, best_norm = kInf, best_t = 0.0;
    bool best_is_last = false;  // u_ and F_ hold the best trial's values
    trial_.resize(m);
    for (int ls = 0; ls < 20; ++ls, t *= 0.5) {
      trial_ = lam + t * step_;
      evaluate(problem, trial_, false);
      const double n = F_.norm();
      best_is_last = n < best_norm;
      if (best_is_last) {
        best_norm = n;
        best_t = t;
      }
      if (n <= (1.0 - 1e-4 * t) * reference) break;
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

bool DefaultSolver::factorShifted(const ContactProblem& problem, double shift) {
  const Eigen::Index m = problem.numRows();
  const Eigen::SparseMatrix<double>* S = problem.delassus().sparse();
  if (S == nullptr && m > kNewtonFirstRows) {
    const Eigen::MatrixXd& A = problem.delassus().dense();
    // A's values into the pattern held from the last step when its nonzeros fit in it: entries
    // that are exactly zero in one step and not in the next (a tower standing straight) would
    // otherwise change the pattern and repeat the ordering every step.
    bool fits = stick_from_dense_ && stick_sparse_.rows() == m;
    for (Eigen::Index j = 0; fits && j < m; ++j) {
      Eigen::Index placed = 0;
      for (Eigen::SparseMatrix<double>::InnerIterator it(stick_sparse_, j); it; ++it) {
        it.valueRef() = A(it.row(), j);
        placed += it.value() != 0.0;
      }
      fits = placed == (A.col(j).array() != 0.0).count();
    }
    if (fits) {
      S = &stick_sparse_;
    } else if (double((A.array() != 0.0).count()) <= kStickSparseDensity * double(m) * double(m)) {
      stick_sparse_ = A.sparseView();
      stick_sparse_.makeCompressed();
      S = &stick_sparse_;
    }
    stick_from_dense_ = S != nullptr;
  }
  stick_sparse_path_ = S != nullptr;
  if (stick_sparse_path_) {
    // The ordering (AMD) and symbolic factor are kept while A's pattern stays (the same contacts
    // from step to step).
    const auto nnz = static_cast<std::size_t>(S->nonZeros());
    const bool same = S->isCompressed() && stick_outer_.size() == static_cast<std::size_t>(m + 1) &&
                      stick_inner_.size() == nnz &&
                      std::equal(stick_outer_.begin(), stick_outer_.end(), S->outerIndexPtr()) &&
                      std::equal(stick_inner_.begin(), stick_inner_.end(), S->innerIndexPtr());
    if (!same) {
      if (!S->isCompressed()) return false;
      // spatial contacts only: factored in their 3 x 3 blocks (block_cholesky.hpp)
      const auto& offsets = problem.offsets();
      bool spatial = m % 3 == 0;
      for (std::size_t i = 0; spatial && i + 1 < offsets.size(); ++i) spatial = offsets[i + 1] - offsets[i] == 3;
      stick_blocked_ = spatial && stick_block_.analyze(*S);
      if (!stick_blocked_) {
        stick_sparse_llt_.analyzePattern(*S);
        stick_natural_llt_.analyzePattern(*S);
        // the symbolic analysis sizes L exactly: compare the fills
        stick_natural_ = stick_natural_llt_.matrixL().nestedExpression().nonZeros() <=
                         stick_sparse_llt_.matrixL().nestedExpression().nonZeros() * 11 / 10;
      }
      stick_outer_.assign(S->outerIndexPtr(), S->outerIndexPtr() + m + 1);
      stick_inner_.assign(S->innerIndexPtr(), S->innerIndexPtr() + nnz);
    }
    if (stick_blocked_) return stick_block_.factorize(*S, shift);
    if (stick_natural_) {
      stick_natural_llt_.setShift(shift);
      stick_natural_llt_.factorize(*S);
      return stick_natural_llt_.info() == Eigen::Success;
    }
    stick_sparse_llt_.setShift(shift);
    stick_sparse_llt_.factorize(*S);
    return stick_sparse_llt_.info() == Eigen::Success;
  }
  stick_shifted_ = problem.delassus().dense();
  stick_shifted_.diagonal().array() += shift;
  stick_llt_.compute(stick_shifted_);
  return stick_llt_.info() == Eigen::Success;
}

bool DefaultSolver::stickingStep(const ContactProblem& problem, Eigen::VectorXd& lam, double tolerance, int& solves) {
  solves = 0;
  stick_used_held_ = false;
  const DelassusOperator& A = problem.delassus();
  StoppingTest test(problem, tolerance);
  stick_x_ = lam;
  stick_u_.resize(lam.size());
  stick_abs_.resize(lam.size());
  stick_w_.resize(lam.size());
  A.multiplyWithAbs(stick_x_, stick_u_, stick_abs_);
  stick_u_ -= problem.b();
  const double initial_map = naturalMapNorm(problem, stick_x_, stick_u_);
  // the guess may be the answer already (a scene at rest whose A and b did not change)
  StoppingTest::Outcome outcome = test.check(stick_x_, stick_u_, initial_map, /*u_is_fresh=*/true, &stick_abs_);
  if (outcome == StoppingTest::kConverged) return true;
  stick_diagonal_.resize(lam.size());
  A.diagonal(stick_diagonal_);
  const double scale = stick_diagonal_.cwiseAbs().maxCoeff();
  if (!(scale > 0.0) || !std::isfinite(scale)) return false;
  // Refinement solves with the factor in hand: 1 converged, 0 unresolvable, -1 stalled (the
  // natural map not halved by a solve) or out of solves. first_map: the natural map after the first.
  double natural_map = initial_map, first_map = -1.0;
  auto refine = [&]() -> int {
    first_map = -1.0;
    while (solves < kStickSolves) {
      // d = R^-1 A R^-1 (A x - b), R = A + rho I: a step on the linear all-stick system filtered to
      // A's range. (The plain proximal step R^-1 (A x - b) also moves by r_0 / rho along A's null
      // space, r_0 the part of A x - b no force can cancel (b's rounding, gaps no rigid motion
      // fits): on a 64-box tower 2e-3 N s a step, until a corner's force left its cone.)
      const double previous = natural_map;
      refinementDirection(stick_u_, stick_d_);
      ++solves;
      stick_x_ -= stick_d_;
      A.multiplyWithAbs(stick_x_, stick_u_, stick_abs_);
      stick_u_ -= problem.b();
      natural_map = naturalMapNorm(problem, stick_x_, stick_u_);
      if (first_map < 0.0) first_map = natural_map;
      outcome = test.check(stick_x_, stick_u_, natural_map, /*u_is_fresh=*/true, &stick_abs_);
      if (outcome == StoppingTest::kConverged) return 1;
      // a contact that should open or slip: the all-stick point leaves the cones and the natural
      // map stops falling
      if (outcome == StoppingTest::kUnresolvable) return 0;
      if (!(natural_map < 0.5 * previous)) return -1;
    }
    return -1;
  };
  // The factor of the previous call, while its matrix is close to this A (the same contacts a step
  // later: a tower at rest, a robot standing) and its last use converged in one refinement step or
  // predicts one will do (its rate: the natural map's reduction by that first step, an upper bound
  // when the step reached the rounding floor): that step saves the factorization
  // (a 256-contact tower's sparse Cholesky, a quarter of its step). Where A moves with the joints
  // (TALOS: 3.7e-4 -> 1.3e-9 by a stale factor, 5e-14 by a fresh one) a fresh factor is cheaper
  // than a second step; the stale one is tried again every kStaleRetry calls. A small dense factor
  // with its step matrix G makes a step one product (~0.1 us at 12 rows, where a fresh factor and
  // its solves cost ~0.8 us): there up to kHeldStepsWithProduct steps are worth it (Solo-12 settling
  // on its feet: 2-3 steps, where one step's rule refactored 9 steps in 10). Whatever the factor,
  // only StoppingTest's verdict is kept.
  if (heldFactorFits(problem)) {
    // (a factor not tried since it was made may still get G: predicted at its best)
    const bool may_have_product = stick_step_state_ != StepMatrix::kRefused && !stick_sparse_path_ &&
                                  problem.numRows() <= kStickSmallRows;
    if (stale_cheap_ || std::pow(stale_rate_, may_have_product ? kHeldStepsWithProduct : 1) * initial_map <= test.threshold() ||
        ++stale_skipped_ >= kStaleRetry) {
      stale_skipped_ = 0;
      if (stick_step_state_ == StepMatrix::kNone) prepareStepMatrix();
      const int worth = stick_step_state_ == StepMatrix::kReady ? kHeldStepsWithProduct : 1;
      const int done = refine();
      stale_rate_ = first_map >= 0.0 && initial_map > 0.0 ? first_map / initial_map : 1.0;
      stale_cheap_ = done == 1 && solves <= worth;
      if (done >= 0) {
        if (done == 1) lam = stick_x_;
        stick_used_held_ = done == 1;
        return done == 1;
      }
      // stalled: a fresh factor, from the guess again
      stick_x_ = lam;
      A.multiply(stick_x_, stick_u_);
      stick_u_ -= problem.b();
      natural_map = initial_map;
    }
  }
  if (!factorShifted(problem, kStickShift * scale)) {
    stick_factor_rows_ = -1;
    return false;
  }
  stick_factor_rows_ = problem.numRows();
  stick_factor_shift_ = kStickShift * scale;
  stick_step_state_ = StepMatrix::kNone;  // (a fresh factor's own step: the solves)
  stick_factor_diagonal_ = stick_diagonal_;
  if (refine() == 1) {
    lam = stick_x_;
    return true;
  }
  return false;
}

void DefaultSolver::refinementDirection(const Eigen::VectorXd& r, Eigen::VectorXd& d) {
  if (stick_step_state_ == StepMatrix::kReady) {
    d.noalias() = stick_step_matrix_ * r;
    return;
  }
  // (A R^-1 r = r - rho R^-1 r: the filter costs a second solve, not a product)
  solveShifted(r, d);
  stick_w_ = r - stick_factor_shift_ * d;
  solveShifted(stick_w_, d);
}

void DefaultSolver::prepareStepMatrix() {
  stick_step_state_ = StepMatrix::kRefused;
  const Eigen::Index m = stick_factor_rows_;
  if (stick_sparse_path_ || m <= 0 || m > kStickSmallRows || stick_shifted_.rows() != m) return;
  // Explicit inverses are as accurate as the solves only while R is well conditioned; near a
  // rank-deficient A (a sole's four corners: R^-1 ~ 1 / rho along A's null space) R^-1 - rho R^-2
  // would cancel to nothing. The pivots bound cond(R) from below (free: TALOS's soles, 1e11, stop
  // here, before an inverse); then its 1-norm condition number, exactly, from R and R^-1.
  const auto pivots = stick_llt_.matrixLLT().diagonal().cwiseAbs();
  const double spread = pivots.maxCoeff() / pivots.minCoeff();
  if (!(spread * spread <= kStepMatrixMaxCondition)) return;
  stick_step_matrix_.setIdentity(m, m);
  stick_llt_.solveInPlace(stick_step_matrix_);  // R^-1
  const double cond = stick_shifted_.cwiseAbs().colwise().sum().maxCoeff() *
                      stick_step_matrix_.cwiseAbs().colwise().sum().maxCoeff();
  if (!(cond <= kStepMatrixMaxCondition)) return;
  stick_step_work_.noalias() = stick_step_matrix_ * stick_step_matrix_;
  stick_step_matrix_ -= stick_factor_shift_ * stick_step_work_;
  stick_step_state_ = StepMatrix::kReady;
}

void DefaultSolver::solveShifted(const Eigen::VectorXd& rhs, Eigen::VectorXd& x) const {
  if (!stick_sparse_path_ && rhs.size() <= kStickSmallRows) {
    // L L^T x = rhs by substitutions that read L across its columns (strided: one value at a time)
    // and write each x once: Eigen's blocked triangular solves cost ~700 instructions each at a
    // robot's 12 rows, and a vectorised column sweep would read x two values at a time right after
    // writing them one at a time (a load spanning two stores waits for both)
    const Eigen::MatrixXd& L = stick_llt_.matrixLLT();
    const Eigen::Index m = L.rows();
    const double* l = L.data();  // L(i, j) at j * m + i
    x = rhs;
    double* v = x.data();
    for (Eigen::Index i = 0; i < m; ++i) {  // L y = rhs, row by row
      double s = v[i];
      for (Eigen::Index j = 0; j < i; ++j) s -= l[j * m + i] * v[j];
      v[i] = s / l[i * m + i];
    }
    for (Eigen::Index j = m - 1; j >= 0; --j) {  // L^T x = y, column by column of L^T (rows of L)
      const double xj = v[j] / l[j * m + j];
      v[j] = xj;
      for (Eigen::Index i = 0; i < j; ++i) v[i] -= l[i * m + j] * xj;
    }
  } else if (!stick_sparse_path_)
    x = stick_llt_.solve(rhs);
  else if (stick_blocked_)
    stick_block_.solve(rhs, x);
  else if (stick_natural_)
    x = stick_natural_llt_.solve(rhs);
  else
    x = stick_sparse_llt_.solve(rhs);
}

bool DefaultSolver::heldFactorFits(const ContactProblem& problem) const {
  const Eigen::Index m = problem.numRows();
  if (stick_factor_rows_ != m || stick_factor_diagonal_.size() != m || stick_diagonal_.size() != m) return false;
  // the same rows (a cheap fingerprint: A's diagonal, stick_diagonal_, within kStaleDiagonalChange of
  // the factored one's)
  const double scale = stick_factor_diagonal_.cwiseAbs().maxCoeff();
  return (stick_diagonal_ - stick_factor_diagonal_).cwiseAbs().maxCoeff() <= kStaleDiagonalChange * scale;
}

void DefaultSolver::iterate(const ContactProblem& problem, const SolverSettings& settings,
                            SolverResult& result) {
  using Clock = FastClock;  // the time-stamp counter (clock.hpp)
  const auto start = settings.time_limit > 0.0 ? Clock::now() : Clock::time_point{};  // (read for a limit only)
  auto seconds_since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  // Every stage gets what is left of the time limit (0 = none).
  auto remaining = [&]() {
    if (settings.time_limit <= 0.0) return 0.0;
    return std::max(1e-9, settings.time_limit - seconds_since(start));
  };
  auto out_of_time = [&]() { return settings.time_limit > 0.0 && seconds_since(start) >= settings.time_limit; };
  Eigen::VectorXd& lam = result.lam;
  const int budget = settings.max_iterations;
  const double tol = settings.tolerance;
  std::string msg, newton_msg;
  int used = 0;

  best_ = lam;
  initial_ = lam;
  u_ws_.resize(problem.numRows());
  // The initial guess's residual is only needed once something failed (keeps the
  // usual warm-started single Newton step free of extra products).
  double best_res = std::numeric_limits<double>::infinity();
  std::string best_stage = "initial guess";  // (short: no allocation)
  bool initial_scored = false;
  // NSGS hands over when its rate predicts more sweeps than a few dense Newton steps
  // would cost. A step's LU is ~m^3/3 multiply-adds against a sweep's ~m^2, so a step is
  // ~m/3 sweeps; Newton typically needs 5-30 steps. (Before the local solve's warm slip
  // search a sweep cost ~3x more and this was m/2.) Measured on FCLib: Confeti-ex13 (321
  // rows) is predicted 160-320 more sweeps at sweep 15 and converges at 45 (1.2 ms, where
  // handing over at m/2 took 9.5 ms). PerioBox (180 rows, rank 72) hands over at sweep 30
  // instead of 23; its Newton from there took 10-27 steps in builds that differ only in
  // rounding (3.3-8.2 ms, against 4.4); with 2m, 35 steps (10.4 ms).
  const double m = static_cast<double>(problem.numRows());
  const double switch_after = std::max(50.0, m);
  auto score = [&](const Eigen::VectorXd& x) {
    problem.delassus().multiply(x, u_ws_);
    u_ws_ -= problem.b();
    return naturalMapNorm(problem, x, u_ws_);
  };
  auto keep_best = [&](const Eigen::VectorXd& x, const std::string& stage) {
    if (!initial_scored) {
      initial_scored = true;
      best_res = score(initial_);
    }
    const double r = score(x);
    if (r < best_res) {
      best_ = x;
      best_res = r;
      best_stage = stage;
    }
  };
  // Each stage's cost goes into result.stages.
  auto record = [&](const char* name, int iterations, Clock::time_point t0, const auto& outcome) {
    result.stages.push_back({name, iterations, seconds_since(t0), outcome});  // (a literal: one string made)
  };
  // Newton from `lam` for at most `steps` (within the budget); true when it converged.
  auto newton_from_here = [&](int steps, const char* name) {
    if (used >= budget) return false;  // nothing left: no empty stage in the report
    const auto t0 = Clock::now();
    const int done = newton_.run(problem, lam, std::min(steps, std::max(0, budget - used)), tol, remaining(), newton_msg);
    used += done;
    record(name, done, t0, newton_msg);
    if (newton_msg == "converged") return true;
    keep_best(lam, name);
    return false;
  };
  auto finish = [&](const std::string& how) {
    result.iterations = used;
    result.message = how;
  };
  // A stage found lambda where the tolerance cannot be verified in double
  // precision: no other stage will do better at that scale; the verdict says so.
  auto unresolvable = [&](const std::string& stage_msg) { return stage_msg == kUnresolvableMessage; };
  bool admm_started = false, use_admm = false, newton_from_initial = false;
  Eigen::VectorXd admm_state;
  // 0. A guess with every contact closed and sticking: the all-stick solution, if it is one.
  // (Or, from lambda = 0, when the natural map there says every block sticks: stickingAtZero.)
  if (budget > 0 && problem.numRows() > 0 &&
      (strictlyInsideCones(problem, lam) || (lam.isZero(0.0) && stickingAtZero(problem)))) {
    const auto t0 = Clock::now();
    int solves = 0;
    const bool done = stickingStep(problem, lam, tol, solves);
    used += solves;
    record("sticking step", solves, t0,
           !done ? "not all sticking" : stick_used_held_ ? "converged (held factor)" : "converged");
    if (done) return finish("converged (sticking step)");
  }
  if (problem.numRows() <= kNewtonFirstRows) {
    // 1a. Small problems (a robot's feet, a box's corners): a dense Newton step
    //     costs less than a few Gauss-Seidel sweeps and converges in a handful.
    if (newton_from_here(30, "newton")) return finish("converged (newton)");
    if (unresolvable(newton_msg)) return finish(newton_msg + " (newton)");
    // 1a'. Newton from ProxQP's facetized-cone QP solution: measured on stick-dominated,
    //      ill-conditioned problems (a 1e4 stack at rest), where Newton stalls from zero
    //      and converges in one step from the QP point; the QP costs ~0.1-0.3 ms at this
    //      size (docs/warm-start.md), so only after a failure and only for small problems.
    if (used < budget && !out_of_time()) {
      Eigen::VectorXd ray;
      StageReport qp = proxqpWarmStart(problem, settings, remaining(), lam, &ray);
      result.warm_start_iterations += qp.iterations;
      result.warm_start_seconds += qp.seconds;
      result.stages.push_back(qp);
      if (ray.size() == lam.size()) result.divergence_candidates.push_back(ray);
      const bool usable = qp.outcome == "solved" || qp.outcome == "iteration limit reached" ||
                          qp.outcome == "time limit reached";
      if (usable && !out_of_time()) {
        if (newton_from_here(30, "newton (from proxqp)")) return finish("converged (proxqp, newton)");
        if (unresolvable(newton_msg)) return finish(newton_msg + " (newton from proxqp)");
      }
    }
  } else {
    // ADMM from the initial guess until it converges or its best residual stops improving
    // (its stall test: no progress over 400 iterations, or a rate that needs more than 10 m
    // further ones), then a few Newton steps from the best iterate met if it is nearly there
    // (on the degenerate Capsules, Newton from a near-solution point only takes tiny steps,
    // so no more than a few). True when the solve is finished.
    auto admm_then_polish = [&](const char* converged_how, int max_iterations) {
      const auto t1 = Clock::now();
      lam = initial_;
      const int done = admm_.run(problem, lam, std::min(max_iterations, budget - used), tol, remaining(), 0.0, false,
                                 msg, kAdmmHorizonPerRow * m);
      admm_started = true;
      admm_state = lam;
      used += done;
      record("admm", done, t1, msg);
      if (msg == "converged") {
        finish(converged_how);
        return true;
      }
      if (unresolvable(msg)) {
        finish(msg + " (admm)");
        return true;
      }
      keep_best(lam, "admm");
      // Only an iterate that is nearly there (within 1000 x the tolerance) is worth a few
      // Newton steps: from SpheresBox's (relative residual ~0.2) 5 steps cost 0.17 s for
      // nothing; and from the initial guess, Newton comes next anyway.
      if (best_stage == "initial guess" || best_res > kPolishWithin * tol * stoppingScale(problem))
        return false;
      lam = best_;
      if (newton_from_here(kPolishSteps, "newton (from the best iterate)")) {
        finish("converged (admm, newton)");
        return true;
      }
      if (unresolvable(newton_msg)) {
        finish(newton_msg + " (newton)");
        return true;
      }
      return false;
    };
    const bool large = problem.numRows() > kAdmmAboveRows;
    if (large && AdmmSolver::factorsSparsely(problem)) {
      // A warm start close to the solution (the simulator's previous step) lets Gauss-Seidel
      // finish in a sweep or two, for less than ADMM's set-up (sparse copy, ordering,
      // factorization, spectrum): a resting grid of 48 cubes (576 rows), 1 sweep, where ADMM
      // took 4 iterations and 1.4x the time. At most kWarmSweeps sweeps, then ADMM.
      if (settings.warm_start != WarmStart::kNone) {
        const auto t0 = Clock::now();
        const int sweeps = nsgs_.sweep(problem, lam, std::min(budget, kWarmSweeps), tol, switch_after,
                                       remaining(), msg);
        used += sweeps;
        record("nsgs", sweeps, t0, msg);
        if (msg == "converged") return finish(msg);
        if (unresolvable(msg) || msg == "time limit reached") return finish(msg + " (nsgs)");
        keep_best(lam, "nsgs");
      }
      // 1b'. Cold large sparse problems with few stored entries: Newton from the guess, with
      //      its sparse Jacobian and LU (run()), before ADMM. Measured on FCLib to 1e-8: the
      //      Capsules 8-30 ms (ADMM 18-42), Spheres 10 ms (13), SpheresBox 80 ms (ADMM stalls
      //      after 25 ms, then the same Newton); KaplasTower (117k entries) 255 ms against
      //      ADMM's 81: the LU fills in, hence the bound on A's entries.
      //      Warm-started ones the same once the sweeps did not finish, from the guess (the
      //      previous step's answer): a tower of 36 spinning boxes (432 rows, every interface
      //      sliding) took 450-930 ADMM iterations (10-19 ms) to stall, then Newton from the
      //      guess converged in 5-34 steps (3-13 ms); within the simulator's budget of 200
      //      iterations ADMM used them all and 4 of 30 steps failed.
      if (storedEntries(problem) <= kSparseNewtonEntries) {
        newton_from_initial = true;
        lam = initial_;
        if (newton_from_here(50, "newton")) return finish("converged (newton)");
        if (unresolvable(newton_msg)) return finish(newton_msg + " (newton)");
        keep_best(lam, "newton");
        if (out_of_time()) return finish(newton_msg + " (newton)");
      }
      // 1b. Large sparse problems: ADMM alone, no Gauss-Seidel prelude. With A <= 10 %
      //     nonzero ADMM factorizes and solves sparsely (admm.cpp): on the FCLib problems of
      //     this kind (648-1710 rows, 0.6-4 % nonzero) it reaches 1e-8 in 20-130 ms where the
      //     NSGS prelude alone cost 10-100 ms and NSGS then Newton 0.15-4 s (Spheres: ADMM 20
      //     ms, NSGS 65 ms; KaplasTower: ADMM 0.08-0.13 s, NSGS 1.5 s; docs/solvers.md, "The
      //     default's rule").
      if (admm_then_polish("converged (admm)", budget)) return;
    } else {
      // 1c. Medium problems, and large dense ones: NSGS while it makes progress (a sweep
      //     costs one product with A), until its rate or its deceleration says it stalls.
      const auto t0 = Clock::now();
      const int sweeps = nsgs_.sweep(problem, lam, budget, tol, switch_after, remaining(), msg);
      used += sweeps;
      record("nsgs", sweeps, t0, msg);
      if (msg != "stalled") return finish(msg == "converged" ? msg : msg + " (nsgs)");
      keep_best(lam, "nsgs");
      if (large && used < budget && !out_of_time()) {
        // Large dense problems: ADMM, not Newton (a dense LU of > 384 rows per step; with
        // dense factorizations ADMM took 0.15-0.6 s on the Capsules, NSGS then Newton
        // 0.15-8 s). From the initial guess, not the NSGS iterate: from there ADMM took 36
        // iterations instead of 12 on KaplasTower and crawled at 2e-8 for 400 iterations
        // on Capsules-i122 and -i101 (measured).
        if (admm_then_polish("converged (nsgs, admm)", budget)) return;
      } else {
        // Medium problems warm-started from the previous step (a simulation): a few ADMM
        // iterations from that guess. A tower of 20 cubes on 4 corners each (240 rows, A of
        // rank <= 120): Newton stalled (no descent along its direction) from the NSGS iterate
        // and from the guess, 22 ms per step, where ADMM from the guess converged in 4
        // iterations, 1.5 ms (measured on box-tower-20, before the sticking step). Where ADMM
        // needs more than kWarmAdmmIterations, Newton does better (spinning towers).
        if (settings.warm_start != WarmStart::kNone && used < budget && !out_of_time() &&
            admm_then_polish("converged (nsgs, admm)", kWarmAdmmIterations))
          return;
        // Medium problems (65-384 rows): Newton from the NSGS iterate; a dense step
        // costs a few ms (BoxesStack, OneObject, PerioBox, Confeti-ex13: 0.5-18 ms in all,
        // where ADMM took 4-80 ms).
        if (admm_started) lam = best_;
        if (newton_from_here(50, "newton")) return finish("converged (nsgs, newton)");
        if (unresolvable(newton_msg)) return finish(newton_msg + " (newton)");
      }
    }
    // Newton from the initial guess: on some problems the NSGS or ADMM iterate sits in
    // a region where the line search stalls and the guess does not (SpheresBox).
    if (!out_of_time() && !newton_from_initial) {
      lam = initial_;
      if (newton_from_here(50, "newton (from the initial guess)"))
        return finish("converged (newton from the initial guess)");
      if (unresolvable(newton_msg)) return finish(newton_msg + " (newton)");
    }
  }
  // 2. Before the long fallbacks: if even the best iterate's own rounding moves the
  //    residual beyond the tolerance (lambda ~ 1e12 on a nearly singular A), no
  //    stage can verify anything at that scale: stop and let the verdict say so.
  if (initial_scored && precisionFloor(problem, best_) > kFloorMargin * tol * stoppingScale(problem)) {
    lam = best_;
    return finish(std::string(kUnresolvableMessage) + " at the best iterate (from " + best_stage + ")");
  }
  // 3. Alternate chunks of NSGS and of ADMM (never diverges, handles rank
  //    deficiency; its state carries over between its chunks), each followed by
  //    a Newton attempt from the chunk's iterate, until the budget is spent.
  use_admm = false;
  if (!admm_started) admm_state = best_;
  std::string last = result.stages.empty() ? "the start" : result.stages.back().name;
  while (used < budget && !out_of_time()) {
    const int chunk = std::min(500, budget - used);
    const auto t0 = Clock::now();
    int done;
    if (use_admm) {
      lam = admm_state;
      done = admm_.run(problem, lam, chunk, tol, remaining(), 0.0, admm_started, msg);
      admm_started = true;
      admm_state = lam;
    } else {
      lam = best_;
      done = nsgs_.sweep(problem, lam, chunk, tol, switch_after, remaining(), msg);
    }
    used += done;
    last = use_admm ? "admm" : "nsgs";
    record(use_admm ? "admm" : "nsgs", done, t0, msg);
    keep_best(lam, last);
    if (msg == "converged") return finish(use_admm ? "converged (nsgs, newton, admm)" : "converged (nsgs, newton, nsgs)");
    if (unresolvable(msg)) return finish(msg + " (" + last + ")");
    if (msg == "time limit reached" || used >= budget) break;
    trial_ = lam;
    const auto t1 = Clock::now();
    const int steps = newton_.run(problem, trial_, std::min(20, budget - used), tol, remaining(), newton_msg);
    used += steps;
    last = use_admm ? "newton (from admm)" : "newton (from nsgs)";
    record(last.c_str(), steps, t1, newton_msg);
    keep_best(trial_, last);
    if (newton_msg == "converged") {
      lam = trial_;
      return finish("converged (nsgs, newton, admm/nsgs, newton)");
    }
    if (unresolvable(newton_msg)) {
      lam = trial_;
      return finish(newton_msg + " (" + last + ")");
    }
    use_admm = !use_admm;
  }
  // An ADMM state far larger than the best iterate is a direction of divergence:
  // the verdict tests it as an infeasibility certificate.
  if (admm_started) result.divergence_candidates.push_back(admm_state);
  lam = best_;
  finish(std::string(out_of_time() ? "time limit reached" : "iteration limit reached") + " after " + last +
         "; returning the best iterate (from " + best_stage + ")");
}

}  // namespace stiction
