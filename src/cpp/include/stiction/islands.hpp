#pragma once
// Islands: the connected components of a contact problem's block graph (blocks i and j joined
// when A couples them, A_ij != 0), solved one by one. In a pile the bodies resting apart (a box
// alone on the ground, a heap of three) share no row of A: their sub-problems are independent,
// and each converges at its own rate with its own stage of the default (a lone box: the sticking
// step; a small heap: dense Newton) where the whole problem ran Gauss-Seidel until its slowest
// island converged. The assembled lambda is then judged by the whole problem's verdict (eq. 65's
// natural map, verdict.hpp): an island solved to tolerance x ||b_i|| leaves at most
// tolerance x ||b|| in all (the b_i partition b), and where rounding says otherwise the caller
// solves the whole problem as before.
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include <Eigen/SparseCore>

#include "stiction/contact_problem.hpp"
#include "stiction/delassus.hpp"
#include "stiction/solver.hpp"

namespace stiction {

/// Connected components of the block graph of `problem` (A_ij != 0 joins blocks i and j): per
/// block, its island's index, islands numbered by their first block. A dense A, and a sparse A
/// stored with explicit zeros, are read entry by entry: a stored zero joins nothing.
std::vector<int> blockIslands(const ContactProblem& problem, int& islands);

class IslandSolver {
 public:
  /// `solver_name`: each island's algorithm (makeSolver), one instance per island index so each
  /// keeps its own workspace (and the sticking step its held factor) from step to step.
  explicit IslandSolver(std::string solver_name);

  /// Solves `problem` island by island when it has at least `min_islands` islands (and a sparse
  /// A); `result` then holds the whole problem's verdict at the assembled lambda. Returns false,
  /// leaving `result` to the caller's usual solve, when the problem is one island, when an island
  /// did not converge (an infeasible or unresolvable island included: the whole problem's solve
  /// names its blocks), or when the assembled lambda misses the whole problem's tolerance.
  /// `structure`: a number the caller changes whenever the problem's blocks or A's sparsity
  /// pattern may have changed (-1: unknown, every call splits anew); while it stays, the islands,
  /// their operators and problems are kept and only A's values and b are copied in.
  bool solve(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result,
             const Eigen::VectorXd* guess, long structure = -1, int min_islands = 2);

  int lastIslands() const { return last_islands_; }  ///< islands of the last problem (0: not split)
  int lastIterations() const { return last_iterations_; }

 private:
  // One island: its blocks, its rows in the whole problem, its problem, and where each of its
  // operator's values comes from in the whole A's value array.
  struct Island {
    std::vector<int> blocks;
    std::vector<Eigen::Index> rows;
    std::shared_ptr<DenseDelassus> dense;     // (small islands: dense, as the simulator stores them)
    std::shared_ptr<SparseDelassus> sparse;
    Eigen::SparseMatrix<double> staging;      // the sparse island's next values, in its pattern
    std::vector<int> source, target;          // A's value index -> the island's (dense: column-major index)
    std::unique_ptr<ContactProblem> problem;
    Eigen::VectorXd b;
  };
  void split(const ContactProblem& problem);
  void refresh(const ContactProblem& problem);

  std::string solver_name_;
  std::vector<Island> islands_;
  long structure_ = -1;
  std::vector<std::unique_ptr<ContactSolver>> solvers_;
  std::vector<SolverResult> results_;
  std::unique_ptr<ContactSolver> checker_;
  std::vector<StageReport> stages_;
  std::vector<int> island_of_, local_row_;
  Eigen::VectorXd assembled_, sub_guess_;
  int last_islands_ = 0;
  int last_iterations_ = 0;
};

}  // namespace stiction
