#include "stiction/delassus.hpp"

#include "stiction/compensated.hpp"
#include "stiction/vector_kernels.hpp"

#ifdef STICTION_X86_KERNELS
#include <immintrin.h>
#endif

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace stiction {

namespace {

#ifdef STICTION_X86_KERNELS
// A symmetric sparse A's products as dot products of its compressed columns with x, four entries a
// step (x gathered by index) in the lanes of one register: the scalar loops waited on their
// additions' latency (SparseDelassus::multiply, absMultiply, multiplyWithAbs; y or y_abs may be
// null). A row's sum goes through at most ceil(k / 4) fused multiply-adds in its lane, two lane
// sums and at most three tail terms of two roundings each (productRoundingTerms).
__attribute__((target("avx2,fma"))) double laneSum(__m256d v) {
  const __m128d half = _mm_add_pd(_mm256_castpd256_pd128(v), _mm256_extractf128_pd(v, 1));
  return _mm_cvtsd_f64(_mm_add_sd(half, _mm_unpackhi_pd(half, half)));
}

// A column's last entries (after the kernels' blocks) added to its lane sums, and the sums stored
// (y or y_abs null: not wanted).
inline void finishColumn(int p, int end, const int* inner, const double* value, const double* x, double sum,
                         double abs_sum, double* y, double* y_abs) {
  for (; p < end; ++p) {
    const double xi = x[inner[p]];
    sum += value[p] * xi;
    abs_sum += std::abs(value[p]) * std::abs(xi);
  }
  if (y != nullptr) *y = sum;
  if (y_abs != nullptr) *y_abs = abs_sum;
}

__attribute__((target("avx2,fma"))) void gatherProductAvx2(Eigen::Index n, const int* outer, const int* inner,
                                                           const double* value, const double* x, double* y,
                                                           double* y_abs) {
  const __m256d sign = _mm256_set1_pd(-0.0);
  for (Eigen::Index j = 0; j < n; ++j) {
    int p = outer[j];
    const int end = outer[j + 1];
    __m256d s = _mm256_setzero_pd(), a = _mm256_setzero_pd();
    for (; p + 4 <= end; p += 4) {
      const __m256d v = _mm256_loadu_pd(value + p);
      const __m256d xi = _mm256_i32gather_pd(x, _mm_loadu_si128(reinterpret_cast<const __m128i*>(inner + p)), 8);
      if (y != nullptr) s = _mm256_fmadd_pd(v, xi, s);
      if (y_abs != nullptr) a = _mm256_fmadd_pd(_mm256_andnot_pd(sign, v), _mm256_andnot_pd(sign, xi), a);
    }
    double sum = laneSum(s), abs_sum = laneSum(a);
    finishColumn(p, end, inner, value, x, sum, abs_sum, y != nullptr ? y + j : nullptr,
                 y_abs != nullptr ? y_abs + j : nullptr);
  }
}

// DenseDelassus::multiplyWithAbs: y = A x and y_abs = |A||x| column by column (the same order of
// additions as the portable loop: one chain of m per row), four rows a step. (Eigen's two column
// expressions spent ~9 instructions per entry: a 48-row operator's two products were a fifth of a
// 16-contact tower's step.)
__attribute__((target("avx2,fma"))) void denseProductWithAbsAvx2(const double* A, Eigen::Index m, const double* x,
                                                                double* y, double* y_abs) {
  const __m256d sign = _mm256_set1_pd(-0.0);
  for (Eigen::Index i = 0; i < m; ++i) y[i] = y_abs[i] = 0.0;
  for (Eigen::Index j = 0; j < m; ++j) {
    const double* col = A + j * m;
    const double xj = x[j], abs_xj = std::abs(xj);
    if (xj == 0.0) continue;  // exact: it would add +-0 to every row
    const __m256d vx = _mm256_set1_pd(xj), vabs = _mm256_set1_pd(abs_xj);
    Eigen::Index i = 0;
    for (; i + 4 <= m; i += 4) {
      const __m256d a = _mm256_loadu_pd(col + i);
      _mm256_storeu_pd(y + i, _mm256_fmadd_pd(a, vx, _mm256_loadu_pd(y + i)));
      _mm256_storeu_pd(y_abs + i, _mm256_fmadd_pd(_mm256_andnot_pd(sign, a), vabs, _mm256_loadu_pd(y_abs + i)));
    }
    for (; i < m; ++i) {
      y[i] += col[i] * xj;
      y_abs[i] += std::abs(col[i]) * abs_xj;
    }
  }
}

// The same for an A whose columns hold their entries in runs of three consecutive rows (a contact's
// t1, t2, n: the simulator's spatial contacts): a run's three values and x's three rows are plain
// loads, the fourth lane zeroed, where the gather fetched x entry by entry. Two accumulators (one
// chain waited on the multiply-add's latency). A row's sum: ceil(k / 6) multiply-adds per
// accumulator, and 3 lane sums (productRoundingTerms). The last run of the storage (a load past
// its end) goes through the scalar tail.
__attribute__((target("avx2,fma"))) void runsOfThreeProductAvx2(Eigen::Index n, Eigen::Index nnz, const int* outer,
                                                               const int* inner, const double* value,
                                                               const double* x, double* y, double* y_abs) {
  const __m256d sign = _mm256_set1_pd(-0.0);
  for (Eigen::Index j = 0; j < n; ++j) {
    int p = outer[j];
    const int end = outer[j + 1];
    const int vector_end = end < nnz ? end : end - 3;  // value[p + 3] exists
    __m256d s0 = _mm256_setzero_pd(), s1 = s0, a0 = s0, a1 = s0;
    bool second = false;
    for (; p + 3 <= vector_end; p += 3) {
      const int r = inner[p];
      if (r + 4 > n) break;  // x[r + 3] past the end: the scalar tail
      const __m256d v = _mm256_blend_pd(_mm256_loadu_pd(value + p), _mm256_setzero_pd(), 0x8);
      const __m256d xi = _mm256_loadu_pd(x + r);
      if (second) {
        if (y != nullptr) s1 = _mm256_fmadd_pd(v, xi, s1);
        if (y_abs != nullptr) a1 = _mm256_fmadd_pd(_mm256_andnot_pd(sign, v), _mm256_andnot_pd(sign, xi), a1);
      } else {
        if (y != nullptr) s0 = _mm256_fmadd_pd(v, xi, s0);
        if (y_abs != nullptr) a0 = _mm256_fmadd_pd(_mm256_andnot_pd(sign, v), _mm256_andnot_pd(sign, xi), a0);
      }
      second = !second;
    }
    double sum = laneSum(_mm256_add_pd(s0, s1)), abs_sum = laneSum(_mm256_add_pd(a0, a1));
    finishColumn(p, end, inner, value, x, sum, abs_sum, y != nullptr ? y + j : nullptr,
                 y_abs != nullptr ? y_abs + j : nullptr);
  }
}
#endif

}  // namespace

DenseDelassus::DenseDelassus(Eigen::MatrixXd A) : A_(std::move(A)) {
  if (A_.rows() != A_.cols())
    throw std::invalid_argument("Delassus matrix A must be square, got " + std::to_string(A_.rows()) +
                                "x" + std::to_string(A_.cols()));
}

namespace {

// Few of x's entries nonzero (NESpheres' answer: 3 of 44 contacts closed): a column loop over
// those columns only does a fraction of the general product's work. Skipping a zero x_j is exact
// (it would add +-0 to every row), so the sums equal the full column loop's.
bool mostlyZero(const Eigen::Ref<const Eigen::VectorXd>& x) {
  Eigen::Index nonzero = 0;
  for (Eigen::Index j = 0; j < x.size(); ++j) nonzero += x[j] != 0.0;
  return 2 * nonzero < x.size();
}

}  // namespace

void DenseDelassus::multiply(const Eigen::Ref<const Eigen::VectorXd>& x,
                             Eigen::Ref<Eigen::VectorXd> y) const {
  // Below 32 rows a plain column loop: Eigen's general matrix-vector product costs more to set
  // up than a 16 x 16 product (measured: ~250 instructions for 3 x 3; Newton's evaluations of
  // the Rover and Toy problems). Above, the same loop over x's nonzero entries when they are few.
  const Eigen::Index m = A_.rows();
  if (m > 32 && !mostlyZero(x)) {
    y.noalias() = A_ * x;
    return;
  }
  double* __restrict out = y.data();
  for (Eigen::Index i = 0; i < m; ++i) out[i] = 0.0;
  for (Eigen::Index j = 0; j < m; ++j) {
    const double xj = x[j];
    if (xj == 0.0) continue;
    const double* __restrict col = A_.data() + j * m;
    for (Eigen::Index i = 0; i < m; ++i) out[i] += col[i] * xj;
  }
}

void DenseDelassus::absMultiply(const Eigen::Ref<const Eigen::VectorXd>& x,
                                Eigen::Ref<Eigen::VectorXd> y) const {
  y.setZero();
  for (Eigen::Index j = 0; j < A_.cols(); ++j)
    if (x[j] != 0.0) y += A_.col(j).cwiseAbs() * std::abs(x[j]);  // no |A| copy; zero columns skipped
}

void DenseDelassus::multiplyWithAbs(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y,
                                    Eigen::Ref<Eigen::VectorXd> y_abs) const {
#ifdef STICTION_X86_KERNELS
  if (vectorKernels()) return denseProductWithAbsAvx2(A_.data(), A_.rows(), x.data(), y.data(), y_abs.data());
#endif
  y.setZero();
  y_abs.setZero();
  for (Eigen::Index j = 0; j < A_.cols(); ++j) {  // one pass over A's columns for both
    if (x[j] == 0.0) continue;
    y.noalias() += A_.col(j) * x[j];
    y_abs.noalias() += A_.col(j).cwiseAbs() * std::abs(x[j]);
  }
}

void DenseDelassus::addColumnBlockTimes(Eigen::Index offset, Eigen::Index size,
                                        const Eigen::Ref<const Eigen::VectorXd>& dx,
                                        Eigen::Ref<Eigen::VectorXd> y) const {
  // A contact's one to three columns in one pass over y: Eigen's general product costs more
  // to set up than a Gauss-Seidel update of a few hundred rows (most of NSGS's sweep).
  const Eigen::Index m = A_.rows();
  const double* a = A_.data() + offset * m;
  double* __restrict out = y.data();
  if (size == 3) {
    const double d0 = dx[0], d1 = dx[1], d2 = dx[2];
    const double* __restrict a0 = a;
    const double* __restrict a1 = a + m;
    const double* __restrict a2 = a + 2 * m;
    for (Eigen::Index i = 0; i < m; ++i) out[i] += a0[i] * d0 + a1[i] * d1 + a2[i] * d2;
  } else if (size == 1) {
    const double d0 = dx[0];
    for (Eigen::Index i = 0; i < m; ++i) out[i] += a[i] * d0;
  } else {
    y.noalias() += A_.middleCols(offset, size) * dx;
  }
}

void DenseDelassus::diagonalBlock(Eigen::Index offset, Eigen::Index size, Eigen::Ref<Eigen::MatrixXd> out) const {
  out = A_.block(offset, offset, size, size);
}

double DenseDelassus::relativeAsymmetry() const {
  if (A_.size() == 0) return 0.0;  // an empty problem (no active contact) is symmetric
  const double scale = A_.cwiseAbs().maxCoeff();
  if (!(scale > 0.0)) return 0.0;
  return (A_ - A_.transpose()).cwiseAbs().maxCoeff() / scale;
}

void DenseDelassus::multiplyTransposed(const Eigen::Ref<const Eigen::VectorXd>& x,
                                       Eigen::Ref<Eigen::VectorXd> y) const {
  y.noalias() = A_.transpose() * x;
}

void DenseDelassus::multiplyExtended(const Eigen::Matrix<long double, Eigen::Dynamic, 1>& x,
                                     Eigen::Matrix<long double, Eigen::Dynamic, 1>& y) const {
  y.setZero(A_.rows());
  for (Eigen::Index j = 0; j < A_.cols(); ++j) y += A_.col(j).cast<long double>() * x[j];
}

void DenseDelassus::compensatedResidual(const Eigen::Ref<const Eigen::VectorXd>& x,
                                        const Eigen::Ref<const Eigen::VectorXd>& b, Eigen::Ref<Eigen::VectorXd> y) const {
  thread_local Eigen::VectorXd lo;  // the rows' error sums
  lo.resize(A_.rows());
  compensatedDenseResidual(A_.data(), A_.rows(), x.data(), b.data(), y.data(), lo.data());
}

SparseDelassus::SparseDelassus(Matrix A, bool symmetric) : A_(std::move(A)), symmetric_(symmetric) {
  if (A_.rows() != A_.cols())
    throw std::invalid_argument("Delassus matrix A must be square, got " + std::to_string(A_.rows()) + "x" +
                                std::to_string(A_.cols()));
  A_.makeCompressed();
  if (!symmetric_) {  // (a symmetric A's products take |A| entry by entry: absMultiply)
    abs_ = A_;  // same pattern; |values| in place (cheaper than Eigen's generic A_.cwiseAbs())
    for (Eigen::Index k = 0; k < abs_.nonZeros(); ++k) abs_.valuePtr()[k] = std::abs(abs_.valuePtr()[k]);
  }
  diagonal_position_.assign(static_cast<std::size_t>(A_.cols()), -1);
  for (Eigen::Index j = 0; j < A_.cols(); ++j)
    for (Eigen::Index p = A_.outerIndexPtr()[j]; p < A_.outerIndexPtr()[j + 1]; ++p)
      if (A_.innerIndexPtr()[p] == j) diagonal_position_[static_cast<std::size_t>(j)] = p;
  updateDiagonal();
  std::vector<Eigen::Index> per_row(static_cast<std::size_t>(A_.rows()), 0);
  for (Eigen::Index k = 0; k < A_.nonZeros(); ++k) ++per_row[A_.innerIndexPtr()[k]];
  for (Eigen::Index c : per_row) max_row_entries_ = std::max(max_row_entries_, c);
  runs_of_three_ = A_.nonZeros() > 0;
  for (Eigen::Index j = 0; j < A_.cols() && runs_of_three_; ++j) {
    const int begin = A_.outerIndexPtr()[j], end = A_.outerIndexPtr()[j + 1];
    runs_of_three_ = (end - begin) % 3 == 0;
    for (int p = begin; p < end && runs_of_three_; p += 3)
      runs_of_three_ = A_.innerIndexPtr()[p + 1] == A_.innerIndexPtr()[p] + 1 &&
                       A_.innerIndexPtr()[p + 2] == A_.innerIndexPtr()[p] + 2;
  }
}

#ifdef STICTION_X86_KERNELS
void SparseDelassus::productKernel(const double* x, double* y, double* y_abs) const {
  if (runs_of_three_)
    runsOfThreeProductAvx2(A_.cols(), A_.nonZeros(), A_.outerIndexPtr(), A_.innerIndexPtr(), A_.valuePtr(), x, y,
                           y_abs);
  else
    gatherProductAvx2(A_.cols(), A_.outerIndexPtr(), A_.innerIndexPtr(), A_.valuePtr(), x, y, y_abs);
}
#endif

// A symmetric A is multiplied column by column as A^T x: each y_j one dot product summed in a
// register (a gather), where A x scatters into y from every column (measured: 1.6x faster on a
// 64-box tower's operator).
void SparseDelassus::multiply(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const {
  if (!symmetric_) {
    y.noalias() = A_ * x;
    return;
  }
#ifdef STICTION_X86_KERNELS
  if (vectorKernels())
    return productKernel(x.data(), y.data(), nullptr);
#endif
  const int* outer = A_.outerIndexPtr();
  const int* inner = A_.innerIndexPtr();
  const double* value = A_.valuePtr();
  for (Eigen::Index j = 0; j < A_.cols(); ++j) {
    // four partial sums: one chain of additions waited on each addition's latency
    double s0 = 0.0, s1 = 0.0, s2 = 0.0, s3 = 0.0;
    int p = outer[j];
    const int end = outer[j + 1];
    for (; p + 4 <= end; p += 4) {
      s0 += value[p] * x[inner[p]];
      s1 += value[p + 1] * x[inner[p + 1]];
      s2 += value[p + 2] * x[inner[p + 2]];
      s3 += value[p + 3] * x[inner[p + 3]];
    }
    for (; p < end; ++p) s0 += value[p] * x[inner[p]];
    y[j] = (s0 + s1) + (s2 + s3);
  }
}

void SparseDelassus::absMultiply(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const {
  if (!symmetric_) {
    y.noalias() = abs_ * x.cwiseAbs();
    return;
  }
#ifdef STICTION_X86_KERNELS
  if (vectorKernels())
    return productKernel(x.data(), nullptr, y.data());
#endif
  const int* outer = A_.outerIndexPtr();
  const int* inner = A_.innerIndexPtr();
  const double* value = A_.valuePtr();
  for (Eigen::Index j = 0; j < A_.cols(); ++j) {
    double s0 = 0.0, s1 = 0.0;  // (two partial sums, as multiply's four)
    int p = outer[j];
    const int end = outer[j + 1];
    for (; p + 2 <= end; p += 2) {
      s0 += std::abs(value[p]) * std::abs(x[inner[p]]);
      s1 += std::abs(value[p + 1]) * std::abs(x[inner[p + 1]]);
    }
    for (; p < end; ++p) s0 += std::abs(value[p]) * std::abs(x[inner[p]]);
    y[j] = s0 + s1;
  }
}

// One pass over A for both (the verdict's bound follows the product that gave u).
void SparseDelassus::multiplyWithAbs(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y,
                                     Eigen::Ref<Eigen::VectorXd> y_abs) const {
  if (!symmetric_) {
    DelassusOperator::multiplyWithAbs(x, y, y_abs);
    return;
  }
#ifdef STICTION_X86_KERNELS
  if (vectorKernels())
    return productKernel(x.data(), y.data(), y_abs.data());
#endif
  const int* outer = A_.outerIndexPtr();
  const int* inner = A_.innerIndexPtr();
  const double* value = A_.valuePtr();
  for (Eigen::Index j = 0; j < A_.cols(); ++j) {
    double s0 = 0.0, s1 = 0.0, a0 = 0.0, a1 = 0.0;  // (partial sums, as multiply's)
    int p = outer[j];
    const int end = outer[j + 1];
    for (; p + 2 <= end; p += 2) {
      const double x0 = x[inner[p]], x1 = x[inner[p + 1]];
      s0 += value[p] * x0;
      s1 += value[p + 1] * x1;
      a0 += std::abs(value[p]) * std::abs(x0);
      a1 += std::abs(value[p + 1]) * std::abs(x1);
    }
    for (; p < end; ++p) {
      const double xi = x[inner[p]];
      s0 += value[p] * xi;
      a0 += std::abs(value[p]) * std::abs(xi);
    }
    y[j] = s0 + s1;
    y_abs[j] = a0 + a1;
  }
}

Eigen::Index SparseDelassus::productRoundingTerms() const {
#ifdef STICTION_X86_KERNELS
  // the vector kernels' lanes: gatherProductAvx2 ceil(k / 4) + 2 + 6, runsOfThreeProductAvx2
  // ceil(k / 6) + 3 + 6; with a margin of 2
  if (symmetric_ && vectorKernels()) return std::min(max_row_entries_, (max_row_entries_ + 3) / 4 + 10);
#endif
  return max_row_entries_;
}

void SparseDelassus::addColumnBlockTimes(Eigen::Index offset, Eigen::Index size,
                                         const Eigen::Ref<const Eigen::VectorXd>& dx,
                                         Eigen::Ref<Eigen::VectorXd> y) const {
  for (Eigen::Index k = 0; k < size; ++k) {
    const double d = dx[k];
    if (d == 0.0) continue;
    for (Matrix::InnerIterator it(A_, offset + k); it; ++it) y[it.row()] += it.value() * d;
  }
}

void SparseDelassus::diagonalBlock(Eigen::Index offset, Eigen::Index size, Eigen::Ref<Eigen::MatrixXd> out) const {
  out.setZero();
  for (Eigen::Index k = 0; k < size; ++k)
    for (Matrix::InnerIterator it(A_, offset + k); it; ++it)
      if (it.row() >= offset && it.row() < offset + size) out(it.row() - offset, k) = it.value();
}

const Eigen::MatrixXd& SparseDelassus::dense() const {
  std::call_once(dense_once_, [this] {
    dense_ = Eigen::MatrixXd(A_);
    dense_built_ = true;
  });
  return dense_;
}

bool SparseDelassus::assignValues(const Matrix& A) {
  if (dense_built_ || !A.isCompressed() || A.rows() != A_.rows() || A.cols() != A_.cols() ||
      A.nonZeros() != A_.nonZeros())
    return false;
  const Eigen::Index n = A_.outerSize(), nnz = A_.nonZeros();
  if (!std::equal(A.outerIndexPtr(), A.outerIndexPtr() + n + 1, A_.outerIndexPtr()) ||
      !std::equal(A.innerIndexPtr(), A.innerIndexPtr() + nnz, A_.innerIndexPtr()))
    return false;
  std::copy(A.valuePtr(), A.valuePtr() + nnz, A_.valuePtr());
  valuesChanged();
  return true;
}

bool SparseDelassus::swapValues(Matrix& A) {
  if (dense_built_ || !A.isCompressed() || A.rows() != A_.rows() || A.cols() != A_.cols() ||
      A.nonZeros() != A_.nonZeros())
    return false;
  A_.swap(A);
  valuesChanged();
  return true;
}

void SparseDelassus::valuesChanged() {
  if (!symmetric_)
    for (Eigen::Index k = 0; k < A_.nonZeros(); ++k) abs_.valuePtr()[k] = std::abs(A_.valuePtr()[k]);
  updateDiagonal();
}

void SparseDelassus::updateDiagonal() {
  diagonal_.resize(A_.cols());
  for (Eigen::Index j = 0; j < A_.cols(); ++j) {
    const Eigen::Index p = diagonal_position_[static_cast<std::size_t>(j)];
    diagonal_[j] = p >= 0 ? A_.valuePtr()[p] : 0.0;
  }
}

double SparseDelassus::relativeAsymmetry() const {
  if (symmetric_ || A_.nonZeros() == 0) return 0.0;
  const double scale = abs_.coeffs().maxCoeff();
  if (!(scale > 0.0)) return 0.0;
  const Matrix diff = A_ - Matrix(A_.transpose());
  return diff.nonZeros() == 0 ? 0.0 : diff.coeffs().cwiseAbs().maxCoeff() / scale;
}

void SparseDelassus::multiplyTransposed(const Eigen::Ref<const Eigen::VectorXd>& x,
                                        Eigen::Ref<Eigen::VectorXd> y) const {
  y.noalias() = A_.transpose() * x;
}

void SparseDelassus::multiplyExtended(const Eigen::Matrix<long double, Eigen::Dynamic, 1>& x,
                                      Eigen::Matrix<long double, Eigen::Dynamic, 1>& y) const {
  y.setZero(A_.rows());
  if (symmetric_) {  // as multiply: A^T x, a gather
    for (Eigen::Index j = 0; j < A_.cols(); ++j) {
      long double sum = 0.0L;
      for (Matrix::InnerIterator it(A_, j); it; ++it) sum += static_cast<long double>(it.value()) * x[it.row()];
      y[j] = sum;
    }
    return;
  }
  for (Eigen::Index j = 0; j < A_.cols(); ++j)
    for (Matrix::InnerIterator it(A_, j); it; ++it)
      y[it.row()] += static_cast<long double>(it.value()) * x[j];
}

void SparseDelassus::compensatedResidual(const Eigen::Ref<const Eigen::VectorXd>& x,
                                         const Eigen::Ref<const Eigen::VectorXd>& b, Eigen::Ref<Eigen::VectorXd> y) const {
  if (symmetric_) {  // as multiply: A^T x, a gather
    compensatedGatherResidual(A_.cols(), A_.outerIndexPtr(), A_.innerIndexPtr(), A_.valuePtr(), x.data(), b.data(),
                              y.data());
    return;
  }
  thread_local Eigen::VectorXd lo;
  lo.resize(A_.rows());
  compensatedScatterResidual(A_.cols(), A_.outerIndexPtr(), A_.innerIndexPtr(), A_.valuePtr(), x.data(), b.data(),
                             y.data(), lo.data());
}

double SparseDelassus::rowNorm(Eigen::Index i) const {
  double sq = 0.0;
  for (Eigen::Index j = 0; j < A_.outerSize(); ++j)
    for (Matrix::InnerIterator it(A_, j); it; ++it)
      if (it.row() == i) sq += it.value() * it.value();
  return std::sqrt(sq);
}

bool SparseDelassus::allFinite() const { return A_.coeffs().allFinite(); }

}  // namespace stiction
