// SmallDenseLU (dense_lu.hpp): right-looking elimination two pivots at a time, with an AVX2/FMA
// kernel for the column updates chosen at run time (vector_kernels.hpp).
#include "stiction/dense_lu.hpp"

#include <cmath>
#include <utility>

#include "stiction/vector_kernels.hpp"
#ifdef STICTION_X86_KERNELS
#include <immintrin.h>
#endif

namespace stiction {

namespace {

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

}  // namespace stiction
