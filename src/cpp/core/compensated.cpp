// Compensated residuals (compensated.hpp). Compiled with -ffp-contract=off (CMakeLists.txt).
#include "stiction/compensated.hpp"

#include <cmath>

#include "stiction/vector_kernels.hpp"

#ifdef STICTION_X86_KERNELS
#include <immintrin.h>
#endif

namespace stiction {

namespace {

#define STICTION_INLINE inline __attribute__((always_inline))

// s + e = a + b exactly (Knuth's TwoSum: no condition on the magnitudes)
STICTION_INLINE void twoSum(double a, double b, double& s, double& e) {
  s = a + b;
  const double z = s - a;
  e = (a - (s - z)) + (b - z);
}

// p + e = a * b exactly, with a fused multiply-add: inlined into a target("fma") kernel, std::fma
// is one instruction there.
struct FusedProduct {
  static STICTION_INLINE void run(double a, double b, double& p, double& e) {
    p = a * b;
    e = std::fma(a, b, -p);
  }
};

// The same without FMA: Dekker's product of Veltkamp's halves (exact unless a product overflows).
struct SplitProduct {
  static STICTION_INLINE void split(double a, double& hi, double& lo) {
    const double c = 134217729.0 * a;  // 2^27 + 1
    hi = c - (c - a);
    lo = a - hi;
  }
  static STICTION_INLINE void run(double a, double b, double& p, double& e) {
    p = a * b;
    double ah, al, bh, bl;
    split(a, ah, al);
    split(b, bh, bl);
    e = al * bl - (((p - ah * bh) - al * bh) - ah * bl);
  }
};

// Two independent chains of (sum, error) per dot product: one chain waits on each TwoSum's latency.
template <typename Product>
STICTION_INLINE void gather(Eigen::Index n, const int* outer, const int* inner, const double* value,
                            const double* x, const double* b, double* y) {
  for (Eigen::Index j = 0; j < n; ++j) {
    double s0 = -b[j], s1 = 0.0, c0 = 0.0, c1 = 0.0;
    int k = outer[j];
    const int end = outer[j + 1];
    for (; k + 2 <= end; k += 2) {
      double p0, e0, p1, e1, t0, t1;
      Product::run(value[k], x[inner[k]], p0, e0);
      Product::run(value[k + 1], x[inner[k + 1]], p1, e1);
      twoSum(s0, p0, s0, t0);
      twoSum(s1, p1, s1, t1);
      c0 += t0 + e0;
      c1 += t1 + e1;
    }
    for (; k < end; ++k) {
      double p, e, t;
      Product::run(value[k], x[inner[k]], p, e);
      twoSum(s0, p, s0, t);
      c0 += t + e;
    }
    double s, t;
    twoSum(s0, s1, s, t);  // the two chains joined without loss
    y[j] = s + (t + (c0 + c1));
  }
}

template <typename Product>
STICTION_INLINE void scatter(Eigen::Index n, const int* outer, const int* inner, const double* value,
                             const double* x, const double* b, double* y, double* lo) {
  for (Eigen::Index i = 0; i < n; ++i) {
    y[i] = -b[i];
    lo[i] = 0.0;
  }
  for (Eigen::Index j = 0; j < n; ++j) {
    const double xj = x[j];
    for (int k = outer[j]; k < outer[j + 1]; ++k) {
      const int i = inner[k];
      double p, e, t;
      Product::run(value[k], xj, p, e);
      twoSum(y[i], p, y[i], t);
      lo[i] += t + e;
    }
  }
  for (Eigen::Index i = 0; i < n; ++i) y[i] += lo[i];
}

// Column by column: each row's (sum, error) pair updated by a column's entry (vectorises over rows).
template <typename Product>
STICTION_INLINE void dense(const double* A, Eigen::Index m, const double* x, const double* b, double* __restrict y,
                           double* __restrict lo) {
  for (Eigen::Index i = 0; i < m; ++i) {
    y[i] = -b[i];
    lo[i] = 0.0;
  }
  for (Eigen::Index j = 0; j < m; ++j) {
    const double xj = x[j];
    const double* __restrict col = A + j * m;
    for (Eigen::Index i = 0; i < m; ++i) {
      double p, e, s, t;
      Product::run(col[i], xj, p, e);
      twoSum(y[i], p, s, t);
      y[i] = s;
      lo[i] += t + e;
    }
  }
  for (Eigen::Index i = 0; i < m; ++i) y[i] += lo[i];
}

#ifdef STICTION_X86_KERNELS
// gather's sums in four lanes of (sum, error), four entries a step (x gathered by index): the
// scalar chains waited on TwoSum's latency. The lanes are joined by TwoSum at the end.
__attribute__((target("avx2,fma"))) void gatherFma(Eigen::Index n, const int* outer, const int* inner,
                                                   const double* value, const double* x, const double* b, double* y) {
  alignas(32) double lanes_s[4], lanes_c[4];
  for (Eigen::Index j = 0; j < n; ++j) {
    int k = outer[j];
    const int end = outer[j + 1];
    __m256d s = _mm256_set_pd(0.0, 0.0, 0.0, -b[j]);
    __m256d c = _mm256_setzero_pd();
    for (; k + 4 <= end; k += 4) {
      const __m256d a = _mm256_loadu_pd(value + k);
      const __m256d xi = _mm256_i32gather_pd(x, _mm_loadu_si128(reinterpret_cast<const __m128i*>(inner + k)), 8);
      const __m256d p = _mm256_mul_pd(a, xi);
      const __m256d e = _mm256_fmsub_pd(a, xi, p);  // a xi - p, exactly
      const __m256d sum = _mm256_add_pd(s, p);      // TwoSum(s, p)
      const __m256d z = _mm256_sub_pd(sum, s);
      const __m256d t = _mm256_add_pd(_mm256_sub_pd(s, _mm256_sub_pd(sum, z)), _mm256_sub_pd(p, z));
      s = sum;
      c = _mm256_add_pd(c, _mm256_add_pd(t, e));
    }
    _mm256_store_pd(lanes_s, s);
    _mm256_store_pd(lanes_c, c);
    double hi = lanes_s[0], lo = (lanes_c[0] + lanes_c[1]) + (lanes_c[2] + lanes_c[3]);
    for (int l = 1; l < 4; ++l) {
      double t;
      twoSum(hi, lanes_s[l], hi, t);
      lo += t;
    }
    for (; k < end; ++k) {
      double p, e, t;
      FusedProduct::run(value[k], x[inner[k]], p, e);
      twoSum(hi, p, hi, t);
      lo += t + e;
    }
    y[j] = hi + lo;
  }
}
__attribute__((target("avx2,fma"))) void scatterFma(Eigen::Index n, const int* outer, const int* inner,
                                                    const double* value, const double* x, const double* b, double* y,
                                                    double* lo) {
  scatter<FusedProduct>(n, outer, inner, value, x, b, y, lo);
}
__attribute__((target("avx2,fma"))) void denseFma(const double* A, Eigen::Index m, const double* x, const double* b,
                                                  double* y, double* lo) {
  dense<FusedProduct>(A, m, x, b, y, lo);
}
#endif

// Without the kernels: a hardware FMA where the build targets one (then std::fma is an
// instruction), Dekker's split otherwise (std::fma would be a slow library call).
#ifdef FP_FAST_FMA
using PortableProduct = FusedProduct;
#else
using PortableProduct = SplitProduct;
#endif

}  // namespace

void compensatedDenseResidual(const double* A, Eigen::Index m, const double* x, const double* b, double* y,
                              double* lo) {
#ifdef STICTION_X86_KERNELS
  if (vectorKernels()) return denseFma(A, m, x, b, y, lo);
#endif
  dense<PortableProduct>(A, m, x, b, y, lo);
}

void compensatedGatherResidual(Eigen::Index n, const int* outer, const int* inner, const double* value,
                               const double* x, const double* b, double* y) {
#ifdef STICTION_X86_KERNELS
  if (vectorKernels()) return gatherFma(n, outer, inner, value, x, b, y);
#endif
  gather<PortableProduct>(n, outer, inner, value, x, b, y);
}

void compensatedScatterResidual(Eigen::Index n, const int* outer, const int* inner, const double* value,
                                const double* x, const double* b, double* y, double* lo) {
#ifdef STICTION_X86_KERNELS
  if (vectorKernels()) return scatterFma(n, outer, inner, value, x, b, y, lo);
#endif
  scatter<PortableProduct>(n, outer, inner, value, x, b, y, lo);
}

double compensatedGammaSquared(double terms) {
  constexpr double eps = 0x1p-53;  // the unit roundoff
  const double g = terms * eps / (1.0 - terms * eps);
  return g * g;
}

}  // namespace stiction
