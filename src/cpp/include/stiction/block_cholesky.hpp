// Sparse Cholesky factor of a Delassus operator held in 3 x 3 blocks (one per spatial contact).
//
// The sticking step (sticking_step.hpp) solves with R = A + rho I twice per refinement step. Where A is
// sparse (many bodies: a grid, a tower) Eigen's simplicial factor walks L one scalar at a time,
// each entry an index load and a multiply-add chained on the last: on a 256-contact tower its
// four triangular solves were a third of the solve phase. A spatial contact's three rows share
// their pattern, so L is factored and applied in 3 x 3 blocks: one index per nine entries, three
// independent multiply-adds per row, the same arithmetic.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

namespace stiction {

/// L L^T = P (S + shift I) P^T for a symmetric positive definite S whose rows come in threes,
/// factored by rows of 3 x 3 blocks (the up-looking sparse Cholesky, block by block). P is the
/// approximate minimum degree ordering of S's block graph, or the natural order when that fills
/// L no more than 10 % beyond it (contacts listed body by body are ordered well already, and
/// the natural order reads the vectors in sequence).
class BlockCholesky3 {
 public:
  using Sparse = Eigen::SparseMatrix<double>;  // column-major, both triangles stored

  /// The ordering and L's block pattern from S's pattern. False (nothing analysed) when S is not
  /// compressed, square, with a multiple of 3 rows.
  bool analyze(const Sparse& S);
  /// The numeric factor of S + shift I; S has the pattern analysed. False when that matrix is not
  /// positive definite (a pivot block's Cholesky failed).
  bool factorize(const Sparse& S, double shift);
  /// x = (S + shift I)^-1 rhs with the last factor (x and rhs may not alias).
  void solve(const Eigen::VectorXd& rhs, Eigen::VectorXd& x) const;

  Eigen::Index rows() const { return 3 * static_cast<Eigen::Index>(blocks_); }

 private:
  // One entry of S's upper triangle (permuted), placed into the factorization's column workspace.
  struct Gather {
    int source;  // index into S's values
    int block;   // its block row (permuted), <= the column being factored
    int entry;   // row + 3 * column within the 3 x 3 block (column-major)
  };
  // The fill of L's block pattern for ordering `order` (new -> old); row lists kept when `keep`.
  Eigen::Index symbolic(const std::vector<int>& order, bool keep);

  int blocks_ = 0;
  bool natural_ = true;
  std::vector<std::vector<int>> adjacency_;  // S's block graph (old numbering), sorted, no self
  std::vector<int> order_, position_;        // order_[new] = old block, position_[old] = new
  std::vector<int> column_start_;            // L's block columns: diagonal block first, then rows ascending
  std::vector<int> column_rows_;
  std::vector<int> row_start_, row_columns_, row_slots_;  // L's block rows k: columns j < k in the
                                                          // order they are computed, and their slots
  std::vector<int> gather_start_;
  std::vector<Gather> gathers_;
  std::vector<Eigen::Matrix3d> factor_;        // L's blocks, by column_start_ slots
  std::vector<Eigen::Matrix3d> pivot_inverse_;  // L_kk^-1 (lower triangular)
  std::vector<Eigen::Matrix3d> work_;           // the factorization's column workspace
  mutable Eigen::VectorXd y_;
  mutable std::vector<double> y4_;  // y in four slots per block (the vector kernel's layout)
};

}  // namespace stiction
