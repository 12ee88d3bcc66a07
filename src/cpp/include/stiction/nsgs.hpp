// Non-smooth block Gauss-Seidel (NSGS) with exact local solves.
//
// Sweeps the blocks in order; each block is solved exactly against the current
// values of the others (local_solve.hpp), and u = A lambda - b is updated by the
// changed columns only, so one sweep costs one product with A.
#pragma once

#include <vector>

#include "stiction/solver.hpp"

namespace stiction {

class NsgsSolver final : public ContactSolver {
 public:
  std::string name() const override { return "nsgs"; }
  void iterate(const ContactProblem& problem, const SolverSettings& settings,
               SolverResult& result) override;

  /// Sweep at most `max_sweeps` times, or until the residual is below `tolerance`,
  /// or (if stall_ratio > 0) until 10 sweeps together reduce the residual by less
  /// than the factor stall_ratio. Returns the number of sweeps done.
  int sweep(const ContactProblem& problem, Eigen::VectorXd& lam, int max_sweeps, double tolerance,
            double stall_ratio, double time_limit, std::string& message);

 private:
  void prepare(const ContactProblem& problem);

  std::vector<double> blocks_;       // packed diagonal blocks G_i, column-major
  std::vector<double> inverses_;     // packed G_i^-1
  std::vector<Eigen::Index> packed_offsets_;
  Eigen::VectorXd u_, delta_, local_;
};

}  // namespace stiction
