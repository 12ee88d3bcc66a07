// The Delassus operator A = J M^-1 J^T (paper eq. 22).
//
// Solvers touch A only through this interface, so that a sparse or
// matrix-free operator can replace the dense one without changing them.
#pragma once

#include <Eigen/Core>

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

  /// y += A[:, offset:offset+size] dx   (Gauss-Seidel update of u = A lambda - b)
  virtual void addColumnBlockTimes(Eigen::Index offset, Eigen::Index size,
                                   const Eigen::Ref<const Eigen::VectorXd>& dx,
                                   Eigen::Ref<Eigen::VectorXd> y) const = 0;

  /// The square diagonal block A[offset:offset+size, offset:offset+size].
  virtual Eigen::MatrixXd diagonalBlock(Eigen::Index offset, Eigen::Index size) const = 0;

  /// A dense copy (for factorizations; a sparse operator would factorize sparsely instead).
  virtual const Eigen::MatrixXd& dense() const = 0;

  /// max_ij |A_ij - A_ji| / max_ij |A_ij|  (0 for an exactly symmetric A)
  virtual double relativeAsymmetry() const = 0;
};

/// Dense, column-major storage.
class DenseDelassus final : public DelassusOperator {
 public:
  explicit DenseDelassus(Eigen::MatrixXd A);

  Eigen::Index rows() const override { return A_.rows(); }
  void multiply(const Eigen::Ref<const Eigen::VectorXd>& x,
                Eigen::Ref<Eigen::VectorXd> y) const override;
  void absMultiply(const Eigen::Ref<const Eigen::VectorXd>& x, Eigen::Ref<Eigen::VectorXd> y) const override;
  void addColumnBlockTimes(Eigen::Index offset, Eigen::Index size,
                           const Eigen::Ref<const Eigen::VectorXd>& dx,
                           Eigen::Ref<Eigen::VectorXd> y) const override;
  Eigen::MatrixXd diagonalBlock(Eigen::Index offset, Eigen::Index size) const override;
  const Eigen::MatrixXd& dense() const override { return A_; }
  double relativeAsymmetry() const override;
  /// Mutable access for per-step updates of the same size (the simulator's A).
  /// The caller keeps it symmetric positive semi-definite: problems built on
  /// this operator validated it once.
  Eigen::MatrixXd& matrix() { return A_; }

 private:
  Eigen::MatrixXd A_;
};

}  // namespace stiction
