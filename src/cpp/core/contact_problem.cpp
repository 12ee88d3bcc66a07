#include "stiction/contact_problem.hpp"

#include <Eigen/SparseCholesky>

#include <cmath>
#include <sstream>
#include <stdexcept>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>

namespace stiction {

namespace {
/// ||b|| without its squares' under- or overflow (||b|| = 1e-200 read 0, 1e200 inf: the verdict
/// then measured against 1 or infinity); Eigen's scaled norm only where the plain one is unsafe.
double normOf(const Eigen::VectorXd& b) {
  const double n = b.norm();
  return n > 1e-150 && n < 1e150 ? n : b.stableNorm();
}

std::string fmt(double x) {
  std::ostringstream os;
  os << x;
  return os.str();
}
}  // namespace

ContactProblem::ContactProblem(std::shared_ptr<const DelassusOperator> delassus, Eigen::VectorXd b,
                               std::vector<Constraint> constraints, double asymmetry_tolerance,
                               bool check_definiteness)
    : delassus_(std::move(delassus)), b_(std::move(b)), b_norm_(normOf(b_)), constraints_(std::move(constraints)) {
  if (!delassus_) throw std::invalid_argument("ContactProblem: no Delassus operator given");
  const Eigen::Index m = delassus_->rows();
  if (b_.size() != m)
    throw std::invalid_argument("ContactProblem: b has " + std::to_string(b_.size()) +
                                " entries but A is " + std::to_string(m) + "x" + std::to_string(m));
  offsets_.clear();
  offsets_.reserve(constraints_.size() + 1);
  Eigen::Index row = 0;
  for (std::size_t i = 0; i < constraints_.size(); ++i) {
    const Constraint& c = constraints_[i];
    const int expected = c.kind == ConstraintKind::kUnilateral || c.kind == ConstraintKind::kBox ? 1
                         : c.kind == ConstraintKind::kPlanarFriction ? 2
                         : c.kind == ConstraintKind::kSpatialFriction ? 3
                                                                      : c.size;
    if (c.size != expected || c.size < 1)
      throw std::invalid_argument("ContactProblem: constraint " + std::to_string(i) + " (" +
                                  c.describe() + ") has " + std::to_string(c.size) + " rows");
    if (c.hasFriction() && !(std::isfinite(c.mu) && c.mu >= 0.0))
      throw std::invalid_argument("ContactProblem: constraint " + std::to_string(i) +
                                  " has friction coefficient mu = " + fmt(c.mu) +
                                  "; mu must be finite and >= 0");
    if (c.kind == ConstraintKind::kBox &&
        !(std::isfinite(c.lower) && std::isfinite(c.upper) && c.lower <= 0.0 && c.upper >= 0.0))
      throw std::invalid_argument("ContactProblem: constraint " + std::to_string(i) + " (" + c.describe() +
                                  ") needs finite bounds lower <= 0 <= upper");
    has_box_rows_ = has_box_rows_ || c.kind == ConstraintKind::kBox;
    offsets_.push_back(row);
    row += c.size;
  }
  offsets_.push_back(row);
  if (row != m)
    throw std::invalid_argument("ContactProblem: the constraints have " + std::to_string(row) +
                                " rows in all but A is " + std::to_string(m) + "x" + std::to_string(m));
  if (!delassus_->allFinite()) throw std::invalid_argument("ContactProblem: A has NaN or infinite entries");
  if (!b_.allFinite()) throw std::invalid_argument("ContactProblem: b has NaN or infinite entries");
  const Eigen::VectorXd diag = delassus_->diagonal();
  for (Eigen::Index i = 0; i < m; ++i)
    if (!(diag[i] >= 0.0))
      throw std::invalid_argument("ContactProblem: A[" + std::to_string(i) + "," + std::to_string(i) +
                                  "] = " + fmt(diag[i]) +
                                  " is negative; a Delassus operator is positive semi-definite");
  asymmetry_ = delassus_->relativeAsymmetry();
  if (asymmetry_ > asymmetry_tolerance)
    throw std::invalid_argument("ContactProblem: A is not symmetric (max|A - A^T| / max|A| = " +
                                fmt(asymmetry_) + " > asymmetry_tolerance = " + fmt(asymmetry_tolerance) +
                                ")");
  // (A zero diagonal leaves nothing to scale by: then A must be 0, as for a problem
  // whose contacts all sit on things that cannot move.)
  const Eigen::SparseMatrix<double>* sparse = delassus_->sparse();
  if (check_definiteness && m > 0 && diag.maxCoeff() == 0.0 &&
      (sparse ? sparse->coeffs().cwiseAbs().maxCoeff() : delassus_->dense().cwiseAbs().maxCoeff()) > 0.0)
    throw std::invalid_argument("ContactProblem: A is not positive semi-definite (zero diagonal, non-zero "
                                "off-diagonal entries); a Delassus operator J M^-1 J^T never is");
  if (check_definiteness && m > 0 && diag.maxCoeff() > 0.0 && sparse != nullptr) {
    // The same test, factorized sparsely (a dense copy of a large sparse A is what it avoids).
    const double max_diag = diag.maxCoeff();
    Eigen::SparseMatrix<double> H = 0.5 * (*sparse + Eigen::SparseMatrix<double>(sparse->transpose()));
    Eigen::SparseMatrix<double> shift(m, m);
    shift.setIdentity();
    H += (kIndefiniteTolerance * max_diag) * shift;
    Eigen::SimplicialLLT<Eigen::SparseMatrix<double>> llt(H);
    if (llt.info() != Eigen::Success)
      throw std::invalid_argument("ContactProblem: A is not positive semi-definite (the sparse Cholesky "
                                  "factorization of A + " + fmt(kIndefiniteTolerance) +
                                  " max(diag A) I fails); a Delassus operator J M^-1 J^T never is: check how A "
                                  "was assembled");
  } else if (check_definiteness && m > 0 && diag.maxCoeff() > 0.0) {
    const Eigen::MatrixXd& A = delassus_->dense();
    const double max_diag = A.diagonal().maxCoeff();
    Eigen::MatrixXd H = 0.5 * (A + A.transpose());
    H.diagonal().array() += kIndefiniteTolerance * max_diag;
    Eigen::LLT<Eigen::MatrixXd> llt(H);
    if (llt.info() != Eigen::Success) {
      std::string detail;
      if (m <= 500) {  // name the offending eigenvalue when it is cheap to
        H.diagonal().array() -= kIndefiniteTolerance * max_diag;
        const double lo = Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(H, Eigen::EigenvaluesOnly).eigenvalues()[0];
        detail = "its smallest eigenvalue is " + fmt(lo) + " = " + fmt(lo / max_diag) + " x max diag";
      } else {
        detail = "the Cholesky factorization of A + " + fmt(kIndefiniteTolerance) + " max(diag A) I fails";
      }
      throw std::invalid_argument(
          "ContactProblem: A is not positive semi-definite (" + detail +
          ", below the tolerance -" + fmt(kIndefiniteTolerance) +
          " x max diag); a Delassus operator J M^-1 J^T never is: check how A was assembled");
    }
  }
}

void ContactProblem::setB(const Eigen::Ref<const Eigen::VectorXd>& b) {
  if (b.size() != b_.size())
    throw std::invalid_argument("ContactProblem.set_b: expected " + std::to_string(b_.size()) +
                                " entries, got " + std::to_string(b.size()));
  if (!b.allFinite()) throw std::invalid_argument("ContactProblem.set_b: b has NaN or infinite entries");
  b_ = b;
  b_norm_ = normOf(b_);
}

}  // namespace stiction
