#include "stiction/block_cholesky.hpp"

#include "stiction/vector_kernels.hpp"

#ifdef STICTION_X86_KERNELS
#include <immintrin.h>
#endif

#include <algorithm>

#include <Eigen/Cholesky>
#include <Eigen/OrderingMethods>

namespace stiction {

namespace {

// L's pattern in rows: the columns j < k with L_kj != 0 are the nodes on the paths of the
// elimination tree from each i < k with S_ik != 0 up to k (Davis, "Direct Methods for Sparse
// Linear Systems", 4.1), listed so that each j follows the columns it depends on.
struct EliminationReach {
  std::vector<int> flag, stack, path;
  explicit EliminationReach(int n) : flag(static_cast<std::size_t>(n), -1), stack(static_cast<std::size_t>(n)),
                                     path(static_cast<std::size_t>(n)) {}
  // the reach of row k in topological order: stack[top .. n)
  template <class UpperColumn>
  int operator()(int k, const UpperColumn& upper, const std::vector<int>& parent) {
    const int n = static_cast<int>(stack.size());
    int top = n;
    flag[static_cast<std::size_t>(k)] = k;
    for (int i : upper) {
      int len = 0;
      for (; flag[static_cast<std::size_t>(i)] != k; i = parent[static_cast<std::size_t>(i)]) {
        path[static_cast<std::size_t>(len++)] = i;
        flag[static_cast<std::size_t>(i)] = k;
      }
      while (len > 0) stack[static_cast<std::size_t>(--top)] = path[static_cast<std::size_t>(--len)];
    }
    return top;
  }
};

}  // namespace

bool BlockCholesky3::analyze(const Sparse& S) {
  blocks_ = 0;
  column_start_.clear();
  if (!S.isCompressed() || S.rows() != S.cols() || S.rows() % 3 != 0) return false;
  const int n = static_cast<int>(S.rows() / 3);
  adjacency_.assign(static_cast<std::size_t>(n), {});
  for (Eigen::Index j = 0; j < S.cols(); ++j)
    for (Sparse::InnerIterator it(S, j); it; ++it) {
      const int bi = static_cast<int>(it.row() / 3), bj = static_cast<int>(j / 3);
      if (bi != bj) adjacency_[static_cast<std::size_t>(bj)].push_back(bi);
    }
  for (auto& a : adjacency_) {
    std::sort(a.begin(), a.end());
    a.erase(std::unique(a.begin(), a.end()), a.end());
  }
  blocks_ = n;
  // AMD on the block graph (Eigen's, which symmetrises the pattern it is given)
  Sparse graph(n, n);
  {
    std::vector<Eigen::Triplet<double>> entries;
    for (int j = 0; j < n; ++j) {
      entries.emplace_back(j, j, 1.0);
      for (int i : adjacency_[static_cast<std::size_t>(j)]) entries.emplace_back(i, j, 1.0);
    }
    graph.setFromTriplets(entries.begin(), entries.end());
  }
  Eigen::PermutationMatrix<Eigen::Dynamic, Eigen::Dynamic, int> inverse;
  Eigen::AMDOrdering<int>()(graph, inverse);  // inverse.indices()[new] = old
  std::vector<int> amd(inverse.indices().data(), inverse.indices().data() + n), natural(static_cast<std::size_t>(n));
  for (int k = 0; k < n; ++k) natural[static_cast<std::size_t>(k)] = k;
  const Eigen::Index amd_fill = symbolic(amd, false), natural_fill = symbolic(natural, false);
  natural_ = natural_fill * 10 <= amd_fill * 11;
  symbolic(natural_ ? natural : amd, true);

  // where each of S's upper-triangle entries (permuted) lands in the column workspace
  gather_start_.assign(static_cast<std::size_t>(n + 1), 0);
  gathers_.clear();
  for (int k = 0; k < n; ++k) {
    const int old = order_[static_cast<std::size_t>(k)];
    for (int c = 0; c < 3; ++c) {
      const Eigen::Index col = 3 * Eigen::Index(old) + c;
      for (Eigen::Index p = S.outerIndexPtr()[col]; p < S.outerIndexPtr()[col + 1]; ++p) {
        const int row = S.innerIndexPtr()[p];
        const int block = position_[static_cast<std::size_t>(row / 3)];
        if (block <= k) gathers_.push_back({static_cast<int>(p), block, row % 3 + 3 * c});
      }
    }
    gather_start_[static_cast<std::size_t>(k + 1)] = static_cast<int>(gathers_.size());
  }
  // (one block and one value of padding: the vector kernel loads a block's columns and y's
  // three-row segments four values at a time)
  factor_.assign(static_cast<std::size_t>(column_start_.back()) + 1, Eigen::Matrix3d::Zero());
  pivot_inverse_.assign(static_cast<std::size_t>(n) + 1, Eigen::Matrix3d::Zero());
  work_.assign(static_cast<std::size_t>(n), Eigen::Matrix3d::Zero());
  y_.setZero(3 * n);
  y4_.assign(static_cast<std::size_t>(4 * n), 0.0);
  return true;
}

Eigen::Index BlockCholesky3::symbolic(const std::vector<int>& order, bool keep) {
  const int n = blocks_;
  std::vector<int> position(static_cast<std::size_t>(n));
  for (int k = 0; k < n; ++k) position[static_cast<std::size_t>(order[static_cast<std::size_t>(k)])] = k;
  // the upper triangle of the permuted block graph, by columns
  std::vector<std::vector<int>> upper(static_cast<std::size_t>(n));
  for (int k = 0; k < n; ++k)
    for (int o : adjacency_[static_cast<std::size_t>(order[static_cast<std::size_t>(k)])]) {
      const int i = position[static_cast<std::size_t>(o)];
      if (i < k) upper[static_cast<std::size_t>(k)].push_back(i);
    }
  // elimination tree (Davis 4.1, with path compression through `ancestor`)
  std::vector<int> parent(static_cast<std::size_t>(n), -1), ancestor(static_cast<std::size_t>(n), -1);
  for (int k = 0; k < n; ++k)
    for (int i : upper[static_cast<std::size_t>(k)])
      for (int next; i != -1 && i < k; i = next) {
        next = ancestor[static_cast<std::size_t>(i)];
        ancestor[static_cast<std::size_t>(i)] = k;
        if (next == -1) parent[static_cast<std::size_t>(i)] = k;
      }
  EliminationReach reach(n);
  std::vector<int> count(static_cast<std::size_t>(n), 1);  // the diagonal block
  Eigen::Index fill = n;
  if (keep) {
    row_start_.assign(static_cast<std::size_t>(n + 1), 0);
    row_columns_.clear();
  }
  for (int k = 0; k < n; ++k) {
    const int top = reach(k, upper[static_cast<std::size_t>(k)], parent);
    fill += n - top;
    for (int t = top; t < n; ++t) {
      ++count[static_cast<std::size_t>(reach.stack[static_cast<std::size_t>(t)])];
      if (keep) row_columns_.push_back(reach.stack[static_cast<std::size_t>(t)]);
    }
    if (keep) row_start_[static_cast<std::size_t>(k + 1)] = static_cast<int>(row_columns_.size());
  }
  if (!keep) return fill;
  order_ = order;
  position_ = position;
  column_start_.assign(static_cast<std::size_t>(n + 1), 0);
  for (int j = 0; j < n; ++j)
    column_start_[static_cast<std::size_t>(j + 1)] = column_start_[static_cast<std::size_t>(j)] + count[static_cast<std::size_t>(j)];
  column_rows_.assign(static_cast<std::size_t>(column_start_.back()), 0);
  row_slots_.assign(row_columns_.size(), 0);
  std::vector<int> next(column_start_.begin(), column_start_.end() - 1);
  for (int j = 0; j < n; ++j) column_rows_[static_cast<std::size_t>(next[static_cast<std::size_t>(j)]++)] = j;
  for (int k = 0; k < n; ++k)  // rows in increasing k: each column's rows come out ascending
    for (int t = row_start_[static_cast<std::size_t>(k)]; t < row_start_[static_cast<std::size_t>(k + 1)]; ++t) {
      const int slot = next[static_cast<std::size_t>(row_columns_[static_cast<std::size_t>(t)])]++;
      column_rows_[static_cast<std::size_t>(slot)] = k;
      row_slots_[static_cast<std::size_t>(t)] = slot;
    }
  return fill;
}

bool BlockCholesky3::factorize(const Sparse& S, double shift) {
  if (column_start_.empty() || S.rows() != rows()) return false;
  const double* values = S.valuePtr();
  for (int k = 0; k < blocks_; ++k) {
    // S's column k (its upper triangle, permuted) into the workspace
    for (int g = gather_start_[static_cast<std::size_t>(k)]; g < gather_start_[static_cast<std::size_t>(k + 1)]; ++g) {
      const Gather& e = gathers_[static_cast<std::size_t>(g)];
      work_[static_cast<std::size_t>(e.block)].data()[e.entry] = values[e.source];
    }
    Eigen::Matrix3d pivot = work_[static_cast<std::size_t>(k)];
    work_[static_cast<std::size_t>(k)].setZero();
    pivot.diagonal().array() += shift;
    for (int t = row_start_[static_cast<std::size_t>(k)]; t < row_start_[static_cast<std::size_t>(k + 1)]; ++t) {
      const int j = row_columns_[static_cast<std::size_t>(t)];
      const int slot = row_slots_[static_cast<std::size_t>(t)];
      // L_kj^T = L_jj^-1 (S_jk - sum_i L_ji L_ki^T), the last held in work_[j]
      const Eigen::Matrix3d lkj_t = pivot_inverse_[static_cast<std::size_t>(j)] * work_[static_cast<std::size_t>(j)];
      work_[static_cast<std::size_t>(j)].setZero();
      // the rows of column j above k take their share of row k: work_[r] -= L_rj L_kj^T
      for (int p = column_start_[static_cast<std::size_t>(j)] + 1; p < slot; ++p)
        work_[static_cast<std::size_t>(column_rows_[static_cast<std::size_t>(p)])].noalias() -=
            factor_[static_cast<std::size_t>(p)] * lkj_t;
      pivot.noalias() -= lkj_t.transpose() * lkj_t;
      factor_[static_cast<std::size_t>(slot)] = lkj_t.transpose();
    }
    Eigen::LLT<Eigen::Matrix3d> llt(pivot);
    if (llt.info() != Eigen::Success || !llt.matrixLLT().diagonal().allFinite() ||
        !(llt.matrixLLT().diagonal().minCoeff() > 0.0)) {
      for (auto& w : work_) w.setZero();  // the next factorization starts from a clean workspace
      return false;
    }
    Eigen::Matrix3d lkk = llt.matrixL();
    factor_[static_cast<std::size_t>(column_start_[static_cast<std::size_t>(k)])] = lkk;
    pivot_inverse_[static_cast<std::size_t>(k)] = lkk.triangularView<Eigen::Lower>().solve(Eigen::Matrix3d::Identity());
  }
  return true;
}

namespace {

#ifdef STICTION_X86_KERNELS
// The two triangular solves of BlockCholesky3::solve with AVX2: a 3 x 3 block's columns (9 values
// column-major; the blocks padded by one) are loaded four values at a time, the fourth lane zeroed;
// y holds each block's three rows in four slots (the fourth 0), so that a segment's load never
// straddles two earlier stores (a forwarding stall: the three-slot layout was 20 % slower than
// Eigen's fixed-size code). L z = y column by column; then L^T w = z by dot products.
__attribute__((target("avx2,fma"))) void blockSolvesAvx2(int n, const double* factor, const double* pivot_inverse,
                                                         const int* column_start, const int* column_rows,
                                                         double* y) {
  const __m256d zero = _mm256_setzero_pd();
  const auto column = [zero](const double* block, int c) __attribute__((target("avx2,fma"))) {
    return _mm256_blend_pd(_mm256_loadu_pd(block + 3 * c), zero, 0x8);
  };
  // (a block times a 3-vector whose entries are broadcast: three multiply-adds)
  const auto times = [&column](const double* block, __m256d z0, __m256d z1, __m256d z2) __attribute__((target("avx2,fma"))) {
    return _mm256_fmadd_pd(column(block, 2), z2, _mm256_fmadd_pd(column(block, 1), z1, _mm256_mul_pd(column(block, 0), z0)));
  };
  for (int j = 0; j < n; ++j) {
    double* yj = y + 4 * j;
    const __m256d z = times(pivot_inverse + 9 * j, _mm256_broadcast_sd(yj), _mm256_broadcast_sd(yj + 1),
                            _mm256_broadcast_sd(yj + 2));
    _mm256_storeu_pd(yj, z);  // (its fourth lane 0: the zeroed lanes times y)
    const __m256d z0 = _mm256_permute4x64_pd(z, 0x00), z1 = _mm256_permute4x64_pd(z, 0x55),
                  z2 = _mm256_permute4x64_pd(z, 0xAA);
    for (int p = column_start[j] + 1; p < column_start[j + 1]; ++p) {
      double* yr = y + 4 * column_rows[p];
      const double* f = factor + 9 * p;
      __m256d v = _mm256_loadu_pd(yr);
      v = _mm256_fnmadd_pd(column(f, 0), z0, v);
      v = _mm256_fnmadd_pd(column(f, 1), z1, v);
      v = _mm256_fnmadd_pd(column(f, 2), z2, v);
      _mm256_storeu_pd(yr, v);
    }
  }
  alignas(32) double lanes[4];
  const auto sum = [&lanes](__m256d v) __attribute__((target("avx2,fma"))) {
    _mm256_store_pd(lanes, v);
    return (lanes[0] + lanes[1]) + lanes[2];
  };
  for (int j = n - 1; j >= 0; --j) {
    // s_i = y_j,i - sum_p column i of L_pj . y_r
    __m256d d0 = zero, d1 = zero, d2 = zero;
    for (int p = column_start[j] + 1; p < column_start[j + 1]; ++p) {
      const __m256d yr = _mm256_loadu_pd(y + 4 * column_rows[p]);
      const double* f = factor + 9 * p;
      d0 = _mm256_fmadd_pd(column(f, 0), yr, d0);
      d1 = _mm256_fmadd_pd(column(f, 1), yr, d1);
      d2 = _mm256_fmadd_pd(column(f, 2), yr, d2);
    }
    double* yj = y + 4 * j;
    const double s0 = yj[0] - sum(d0), s1 = yj[1] - sum(d1), s2 = yj[2] - sum(d2);
    // w_j = L_jj^-T s: dot products with L_jj^-1's columns
    const double* q = pivot_inverse + 9 * j;
    _mm256_storeu_pd(yj, _mm256_set_pd(0.0, q[6] * s0 + q[7] * s1 + q[8] * s2, q[3] * s0 + q[4] * s1 + q[5] * s2,
                                      q[0] * s0 + q[1] * s1 + q[2] * s2));
  }
}
#endif

}  // namespace

void BlockCholesky3::solve(const Eigen::VectorXd& rhs, Eigen::VectorXd& x) const {
  const int n = blocks_;
  x.resize(rhs.size());
#ifdef STICTION_X86_KERNELS
  if (vectorKernels()) {
    double* y4 = y4_.data();
    for (int k = 0; k < n; ++k) {
      Eigen::Map<Eigen::Vector3d>(y4 + 4 * k) = rhs.segment<3>(3 * Eigen::Index(order_[static_cast<std::size_t>(k)]));
      y4[4 * k + 3] = 0.0;
    }
    blockSolvesAvx2(n, factor_.data()->data(), pivot_inverse_.data()->data(), column_start_.data(),
                    column_rows_.data(), y4);
    for (int k = 0; k < n; ++k)
      x.segment<3>(3 * Eigen::Index(order_[static_cast<std::size_t>(k)])) = Eigen::Map<const Eigen::Vector3d>(y4 + 4 * k);
    return;
  }
#endif
  double* y = y_.data();
  for (int k = 0; k < n; ++k)
    Eigen::Map<Eigen::Vector3d>(y + 3 * k) = rhs.segment<3>(3 * Eigen::Index(order_[static_cast<std::size_t>(k)]));
  // L z = P rhs, column by column
  for (int j = 0; j < n; ++j) {
    Eigen::Map<Eigen::Vector3d> yj(y + 3 * j);
    const Eigen::Vector3d zj = pivot_inverse_[static_cast<std::size_t>(j)] * yj;
    yj = zj;
    for (int p = column_start_[static_cast<std::size_t>(j)] + 1; p < column_start_[static_cast<std::size_t>(j + 1)]; ++p)
      Eigen::Map<Eigen::Vector3d>(y + 3 * column_rows_[static_cast<std::size_t>(p)]).noalias() -=
          factor_[static_cast<std::size_t>(p)] * zj;
  }
  // L^T w = z, column by column from the last
  for (int j = n - 1; j >= 0; --j) {
    Eigen::Vector3d s = Eigen::Map<const Eigen::Vector3d>(y + 3 * j);
    for (int p = column_start_[static_cast<std::size_t>(j)] + 1; p < column_start_[static_cast<std::size_t>(j + 1)]; ++p)
      s.noalias() -= factor_[static_cast<std::size_t>(p)].transpose() *
                     Eigen::Map<const Eigen::Vector3d>(y + 3 * column_rows_[static_cast<std::size_t>(p)]);
    Eigen::Map<Eigen::Vector3d>(y + 3 * j).noalias() = pivot_inverse_[static_cast<std::size_t>(j)].transpose() * s;
  }
  for (int k = 0; k < n; ++k)
    x.segment<3>(3 * Eigen::Index(order_[static_cast<std::size_t>(k)])) = Eigen::Map<const Eigen::Vector3d>(y + 3 * k);
}

}  // namespace stiction
