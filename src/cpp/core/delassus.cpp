#include "stiction/delassus.hpp"

#include <cmath>
#include <stdexcept>

namespace stiction {

DenseDelassus::DenseDelassus(Eigen::MatrixXd A) : A_(std::move(A)) {
  if (A_.rows() != A_.cols())
    throw std::invalid_argument("Delassus matrix A must be square, got " + std::to_string(A_.rows()) +
                                "x" + std::to_string(A_.cols()));
}

void DenseDelassus::multiply(const Eigen::Ref<const Eigen::VectorXd>& x,
                             Eigen::Ref<Eigen::VectorXd> y) const {
  y.noalias() = A_ * x;
}

void DenseDelassus::absMultiply(const Eigen::Ref<const Eigen::VectorXd>& x,
                                Eigen::Ref<Eigen::VectorXd> y) const {
  y.setZero();
  for (Eigen::Index j = 0; j < A_.cols(); ++j) y += A_.col(j).cwiseAbs() * std::abs(x[j]);  // no |A| copy
}

void DenseDelassus::addColumnBlockTimes(Eigen::Index offset, Eigen::Index size,
                                        const Eigen::Ref<const Eigen::VectorXd>& dx,
                                        Eigen::Ref<Eigen::VectorXd> y) const {
  y.noalias() += A_.middleCols(offset, size) * dx;
}

Eigen::MatrixXd DenseDelassus::diagonalBlock(Eigen::Index offset, Eigen::Index size) const {
  return A_.block(offset, offset, size, size);
}

double DenseDelassus::relativeAsymmetry() const {
  if (A_.size() == 0) return 0.0;  // an empty problem (no active contact) is symmetric
  const double scale = A_.cwiseAbs().maxCoeff();
  if (!(scale > 0.0)) return 0.0;
  return (A_ - A_.transpose()).cwiseAbs().maxCoeff() / scale;
}

}  // namespace stiction
