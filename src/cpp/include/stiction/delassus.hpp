// The Delassus operator A = J M^-1 J^T (paper eq. 22).
//
// Solvers touch A only through this interface, so that a sparse or
// matrix-free operator can replace the dense one without changing them.
#pragma once

#include <atomic>
#include <mutex>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

namespace stiction {

class DelassusOperator {
 public:
  virtual ~DelassusOperator() = default;

  virtual Eigen::Index rows() const = 0;

  /// y = A x
  virtual void multiply(const Eigen::Ref<const Eigen::VectorXd>& x,
                        Eigen::Ref<Eigen::VectorXd> y) const = 0;

  /// y = |A| |x|, entrywise absolute values (the rounding bound of A x, verdict.hpp)
  virtual void absMultiply(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const = 0;

  /// y = A x and y_abs = |A| |x| (a product and its rounding bound, for a verdict to follow); an
  /// operator that reads A once for both overrides it.
  virtual void multiplyWithAbs(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y,
                               Eigen::Ref<Eigen::VectorXd> y_abs) const {
    multiply(x, y);
    absMultiply(x, y_abs);
  }

  /// y += A[:, offset:offset+size] dx   (Gauss-Seidel update of u = A lambda - b)
  virtual void addColumnBlockTimes(Eigen::Index offset, Eigen::Index size,
                                   const Eigen::Ref<const Eigen::VectorXd>& dx,
                                   Eigen::Ref<Eigen::VectorXd> y) const = 0;

  /// The square diagonal block A[offset:offset+size, offset:offset+size], written into `out`
  /// (size x size; the solvers' per-step set-up, so no allocation).
  virtual void diagonalBlock(Eigen::Index offset, Eigen::Index size, Eigen::Ref<Eigen::MatrixXd> out) const = 0;
  Eigen::MatrixXd diagonalBlock(Eigen::Index offset, Eigen::Index size) const {
    Eigen::MatrixXd block(size, size);
    diagonalBlock(offset, size, block);
    return block;
  }

  /// A dense copy (for factorizations; a sparse operator would factorize sparsely instead).
  virtual const Eigen::MatrixXd& dense() const = 0;

  /// max_ij |A_ij - A_ji| / max_ij |A_ij|  (0 for an exactly symmetric A)
  virtual double relativeAsymmetry() const = 0;

  /// y = A^T x
  virtual void multiplyTransposed(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const = 0;
  /// y = A x in long double (the verdict's extended-precision stage)
  virtual void multiplyExtended(const Eigen::Matrix<long double, Eigen::Dynamic, 1>& x,
                                Eigen::Matrix<long double, Eigen::Dynamic, 1>& y) const = 0;
  /// y = A x - b, compensated (compensated.hpp: as if in twice double precision, then rounded; the
  /// verdict's middle stage). No allocation once the operator's workspace is sized.
  virtual void compensatedResidual(const Eigen::Ref<const Eigen::VectorXd>& x, const Eigen::Ref<const Eigen::VectorXd>& b,
                                   Eigen::Ref<Eigen::VectorXd> y) const = 0;
  /// A's diagonal, written into `out` (rows() entries; no allocation).
  virtual void diagonal(Eigen::Ref<Eigen::VectorXd> out) const = 0;
  Eigen::VectorXd diagonal() const {
    Eigen::VectorXd d(rows());
    diagonal(d);
    return d;
  }
  virtual double columnNorm(Eigen::Index j) const = 0;
  virtual double rowNorm(Eigen::Index i) const = 0;
  virtual bool allFinite() const = 0;
  /// The stored entries when A is held sparse (nullptr for a dense A).
  virtual const Eigen::SparseMatrix<double>* sparse() const { return nullptr; }
  /// The most entries any row of A x sums: the k of the rounding bound gamma_k = k eps of a
  /// product (verdict.hpp; a dense A: its columns; a sparse one: its fullest row).
  virtual Eigen::Index maxRowEntries() const { return rows(); }
  /// The k of the rounding bound gamma_k (|A||x|) of this operator's double products (multiply,
  /// absMultiply, multiplyWithAbs): the longest chain of roundings a row's sum goes through. At
  /// most maxRowEntries(); fewer where the terms are summed in independent lanes.
  virtual Eigen::Index productRoundingTerms() const { return maxRowEntries(); }
};

/// Dense, column-major storage.
class DenseDelassus final : public DelassusOperator {
 public:
  explicit DenseDelassus(Eigen::MatrixXd A);

  Eigen::Index rows() const override { return A_.rows(); }
  void multiply(const Eigen::Ref<const Eigen::VectorXd>& x,
                Eigen::Ref<Eigen::VectorXd> y) const override;
  void absMultiply(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const override;
  void multiplyWithAbs(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y,
                       Eigen::Ref<Eigen::VectorXd> y_abs) const override;
  void addColumnBlockTimes(Eigen::Index offset, Eigen::Index size,
                           const Eigen::Ref<const Eigen::VectorXd>& dx,
                           Eigen::Ref<Eigen::VectorXd> y) const override;
  using DelassusOperator::diagonalBlock;
  void diagonalBlock(Eigen::Index offset, Eigen::Index size, Eigen::Ref<Eigen::MatrixXd> out) const override;
  const Eigen::MatrixXd& dense() const override { return A_; }
  double relativeAsymmetry() const override;
  void multiplyTransposed(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const override;
  void multiplyExtended(const Eigen::Matrix<long double, Eigen::Dynamic, 1>& x,
                        Eigen::Matrix<long double, Eigen::Dynamic, 1>& y) const override;
  void compensatedResidual(const Eigen::Ref<const Eigen::VectorXd>& x, const Eigen::Ref<const Eigen::VectorXd>& b,
                           Eigen::Ref<Eigen::VectorXd> y) const override;
  using DelassusOperator::diagonal;
  void diagonal(Eigen::Ref<Eigen::VectorXd> out) const override { out = A_.diagonal(); }
  double columnNorm(Eigen::Index j) const override { return A_.col(j).norm(); }
  double rowNorm(Eigen::Index i) const override { return A_.row(i).norm(); }
  bool allFinite() const override { return A_.allFinite(); }
  /// Mutable access for per-step updates of the same size (the simulator's A).
  /// The caller keeps it symmetric positive semi-definite: problems built on
  /// this operator validated it once.
  Eigen::MatrixXd& matrix() { return A_; }

 private:
  Eigen::MatrixXd A_;
};

/// Sparse (compressed column) storage: the operator of many bodies, where a contact couples
/// only with the contacts of the bodies it touches (block-sparse A). Every product the solvers
/// and the verdict need costs O(entries); dense() builds a dense copy once, on first use, for
/// the algorithms that factorize densely (Newton, ProxQP, some formulations).
class SparseDelassus final : public DelassusOperator {
 public:
  using Matrix = Eigen::SparseMatrix<double>;
  /// symmetric: A is symmetric by construction (e.g. assembled as sum W_s^T W_s with mirrored
  /// entries), so relativeAsymmetry() is 0 without forming A - A^T (a third of a 1024-contact
  /// operator's set-up).
  explicit SparseDelassus(Matrix A, bool symmetric = false);

  Eigen::Index rows() const override { return A_.rows(); }
  void multiply(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const override;
  void absMultiply(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const override;
  void multiplyWithAbs(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y,
                       Eigen::Ref<Eigen::VectorXd> y_abs) const override;
  void addColumnBlockTimes(Eigen::Index offset, Eigen::Index size, const Eigen::Ref<const Eigen::VectorXd>& dx,
                           Eigen::Ref<Eigen::VectorXd> y) const override;
  using DelassusOperator::diagonalBlock;
  void diagonalBlock(Eigen::Index offset, Eigen::Index size, Eigen::Ref<Eigen::MatrixXd> out) const override;
  const Eigen::MatrixXd& dense() const override;
  double relativeAsymmetry() const override;
  void multiplyTransposed(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const override;
  void multiplyExtended(const Eigen::Matrix<long double, Eigen::Dynamic, 1>& x,
                        Eigen::Matrix<long double, Eigen::Dynamic, 1>& y) const override;
  void compensatedResidual(const Eigen::Ref<const Eigen::VectorXd>& x, const Eigen::Ref<const Eigen::VectorXd>& b,
                           Eigen::Ref<Eigen::VectorXd> y) const override;
  using DelassusOperator::diagonal;
  void diagonal(Eigen::Ref<Eigen::VectorXd> out) const override { out = diagonal_; }
  double columnNorm(Eigen::Index j) const override { return A_.col(j).norm(); }
  double rowNorm(Eigen::Index i) const override;
  bool allFinite() const override;
  const Matrix* sparse() const override { return &A_; }
  Eigen::Index maxRowEntries() const override { return max_row_entries_; }
  Eigen::Index productRoundingTerms() const override;
  Eigen::Index nonZeros() const { return A_.nonZeros(); }
  /// Take the values of `A` when it has this operator's pattern (the simulator's A from one step
  /// to the next while the same contacts are active): O(entries), no allocation. Returns false and
  /// changes nothing when the pattern differs or dense() was already built (its copy would go stale).
  bool assignValues(const Matrix& A);
  /// The same for an A whose pattern the caller knows is this operator's (the simulator's, while
  /// its plan of A holds): A and this operator's matrix swap storage, O(1); A then holds the
  /// previous values. False (nothing changed) when sizes differ or dense() was built.
  bool swapValues(Matrix& A);
  /// This operator's matrix (for reading).
  const Matrix& sparseMatrix() const { return A_; }

 private:
  Matrix A_;
  Matrix abs_;  // |A|, for the rounding bound (a non-symmetric A only)
  Eigen::VectorXd diagonal_;  // computed once (a sparse diagonal is a search per column)
  std::vector<Eigen::Index> diagonal_position_;  // where each diagonal entry is stored (-1: none)
  void updateDiagonal();
  void valuesChanged();  // |A| (non-symmetric A) and the diagonal, after new values
  Eigen::Index max_row_entries_ = 0;  // the pattern's fullest row
  bool runs_of_three_ = false;  // every column's entries in runs of 3 consecutive rows (spatial contacts)
  void productKernel(const double* x, double* y, double* y_abs) const;  // the AVX2 products (y or y_abs null)
  bool symmetric_ = false;
  mutable std::once_flag dense_once_;
  mutable std::atomic<bool> dense_built_{false};
  mutable Eigen::MatrixXd dense_;
};

}  // namespace stiction
