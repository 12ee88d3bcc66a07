// Non-smooth block Gauss-Seidel (NSGS) with exact local solves.
//
// Sweeps the blocks in order; each block is solved exactly against the current
// values of the others (local_solve.hpp), and u = A lambda - b is updated by the
// changed columns only, so one sweep costs one product with A.
#pragma once

#include <vector>

#include "stiction/iteration_monitor.hpp"
#include "stiction/solver.hpp"

namespace stiction {

class NsgsSolver final : public ContactSolver {
 public:
  std::string name() const override { return "nsgs"; }
  void iterate(const ContactProblem& problem, const SolverSettings& settings,
               SolverResult& result) override;

  /// Sweep at most `max_sweeps` times, or until the relative residual is below
  /// `tolerance`, or (if switch_after > 0) until the convergence rate of the last
  /// 10 sweeps predicts more than `switch_after` further sweeps to reach the
  /// tolerance, or the predicted finishing sweep has moved 1.5x later than its earliest
  /// value (a decelerating rate), or (if finish_by > 0) the predicted finishing sweep
  /// (sweeps done + still needed) is past `finish_by`: the caller's budget will not suffice
  /// (message "stalled": time for another method). Returns the sweeps done.
  int sweep(const ContactProblem& problem, Eigen::VectorXd& lam, int max_sweeps, double tolerance,
            double switch_after, double time_limit, std::string& message, int finish_by = 0);

 private:
  void prepare(const ContactProblem& problem);

  std::vector<double> blocks_;       // packed diagonal blocks G_i, column-major
  std::vector<double> inverses_;     // packed G_i^-1
  std::vector<Eigen::Index> packed_offsets_;
  Eigen::VectorXd u_, delta_, local_;
  IterationMonitor monitor_;  // time limit, rate and stall
};

}  // namespace stiction
