// The per-step algebraic problem of the paper:
//
//     A lambda - b  in  - lim_{eps -> 0} N_C^{U_eps}(lambda)        (eq. 65, 70)
//
// with C the product of the blocks' sets and U_eps the singular metric of eq. 59.
// For friction blocks it is De Saxce's exact Coulomb NCP (eq. 73-77):
//     C* ∋ u + E s(u)  ⟂  lambda ∈ C,    u = A lambda - b.
#pragma once

#include <memory>
#include <vector>

#include <Eigen/Core>

#include "stiction/constraint.hpp"
#include "stiction/delassus.hpp"

namespace stiction {

class ContactProblem {
 public:
  /// Validates everything and throws std::invalid_argument naming the fault:
  /// sizes, non-finite entries, mu < 0 or non-finite, an asymmetry of A above
  /// `asymmetry_tolerance` (relative, see DelassusOperator::relativeAsymmetry), and
  /// an A that is not positive semi-definite (check_definiteness; see below).
  ContactProblem(std::shared_ptr<const DelassusOperator> delassus, Eigen::VectorXd b,
                 std::vector<Constraint> constraints, double asymmetry_tolerance = 1e-9,
                 bool check_definiteness = true);

  /// A Delassus operator J M^-1 J^T is positive semi-definite; an indefinite A has no
  /// physical meaning and sends the solvers astray (a 2 s time limit once took 224 s).
  /// Rejected when the Cholesky factorization of its symmetric part shifted by
  /// kIndefiniteTolerance * max diag fails, i.e. an eigenvalue is below about
  /// -kIndefiniteTolerance * max diag. The margin admits the rounding of stored data
  /// (FCLib's Confeti files reach -9e-8 relative). Cost: one Cholesky, ~m^3/3 flops
  /// (docs/solvers.md: 0.1 s for KaplasTower's 1710 rows, a few % of its solve). The
  /// simulator skips it: its A = W^T W is semi-definite by construction.
  static constexpr double kIndefiniteTolerance = 1e-6;

  const DelassusOperator& delassus() const { return *delassus_; }
  const Eigen::VectorXd& b() const { return b_; }
  /// ||b||, kept with b (the verdict, the stopping test and the exact-law measures all scale by it)
  double bNorm() const { return b_norm_; }
  const std::vector<Constraint>& constraints() const { return constraints_; }
  /// Row offset of block i (size numBlocks()+1; the last entry is numRows()).
  const std::vector<Eigen::Index>& offsets() const { return offsets_; }

  Eigen::Index numRows() const { return b_.size(); }
  std::size_t numBlocks() const { return constraints_.size(); }
  /// Some block is a box row (a joint's dry friction or effort limit).
  bool hasBoxRows() const { return has_box_rows_; }
  double asymmetry() const { return asymmetry_; }
  bool isSymmetric() const { return asymmetry_ == 0.0; }

  /// Replace b (same size) without touching A: the cheap per-step update.
  void setB(const Eigen::Ref<const Eigen::VectorXd>& b);

 private:
  std::shared_ptr<const DelassusOperator> delassus_;
  Eigen::VectorXd b_;
  double b_norm_ = 0.0;
  std::vector<Constraint> constraints_;
  std::vector<Eigen::Index> offsets_;
  double asymmetry_ = 0.0;
  bool has_box_rows_ = false;
};

}  // namespace stiction
