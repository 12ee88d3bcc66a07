// Islands (islands.hpp): the block graph's connected components, each solved as its own problem,
// the assembled lambda judged by the whole problem's verdict.
#include "stiction/islands.hpp"

#include <chrono>
#include <cmath>
#include <numeric>
#include <utility>

#include <Eigen/SparseCore>

#include "stiction/clock.hpp"
#include "stiction/delassus.hpp"
#include "stiction/thresholds.hpp"

namespace stiction {

namespace {

int findRoot(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];  // (path halving)
    i = parent[i];
  }
  return i;
}

// The whole problem's verdict at a lambda already found: iterate() leaves the given lambda as it
// is, so solve() (the driver) only judges it (u, residual, rounding bound, states).
class GivenLambda final : public ContactSolver {
 public:
  std::string name() const override { return "islands"; }
  void iterate(const ContactProblem&, const SolverSettings&, SolverResult& result) override {
    result.iterations = iterations;
    result.message = message;
    for (const StageReport& s : *stages) result.stages.push_back(s);
  }
  int iterations = 0;
  std::string message;
  const std::vector<StageReport>* stages = nullptr;
};

}  // namespace

std::vector<int> blockIslands(const ContactProblem& problem, int& islands) {
  const std::size_t blocks = problem.numBlocks();
  const auto& offsets = problem.offsets();
  std::vector<int> block_of_row(static_cast<std::size_t>(problem.numRows()));
  for (std::size_t k = 0; k < blocks; ++k)
    for (Eigen::Index r = offsets[k]; r < offsets[k + 1]; ++r) block_of_row[static_cast<std::size_t>(r)] = static_cast<int>(k);
  std::vector<int> parent(blocks);
  std::iota(parent.begin(), parent.end(), 0);
  const auto join = [&](Eigen::Index r, Eigen::Index c) {
    const int a = findRoot(parent, block_of_row[static_cast<std::size_t>(r)]);
    const int b = findRoot(parent, block_of_row[static_cast<std::size_t>(c)]);
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  };
  if (const Eigen::SparseMatrix<double>* S = problem.delassus().sparse()) {
    for (Eigen::Index c = 0; c < S->outerSize(); ++c)
      for (Eigen::SparseMatrix<double>::InnerIterator it(*S, c); it; ++it)
        if (it.value() != 0.0) join(it.row(), it.col());
  } else {
    const Eigen::MatrixXd& A = problem.delassus().dense();
    for (Eigen::Index c = 0; c < A.cols(); ++c)
      for (Eigen::Index r = 0; r < A.rows(); ++r)
        if (A(r, c) != 0.0) join(r, c);
  }
  std::vector<int> island(blocks);
  islands = 0;
  for (std::size_t k = 0; k < blocks; ++k) {  // (roots are each island's first block: numbered in order)
    const int root = findRoot(parent, static_cast<int>(k));
    island[k] = root == static_cast<int>(k) ? islands++ : island[static_cast<std::size_t>(root)];
  }
  return island;
}

IslandSolver::IslandSolver(std::string solver_name)
    : solver_name_(std::move(solver_name)), checker_(std::make_unique<GivenLambda>()) {
  makeSolver(solver_name_);  // (an unknown name fails here, loudly, not at the first split)
}

void IslandSolver::split(const ContactProblem& problem) {
  const Eigen::SparseMatrix<double>& S = *problem.delassus().sparse();
  const auto& offsets = problem.offsets();
  int count = 0;
  island_of_ = blockIslands(problem, count);
  // Small islands (a box resting alone, a pair) solved one by one would cost more in set-up and
  // verdicts than they save (a grid of 256 lone cubes: 2x the whole problem's solve, where one
  // sticking step takes them all): they go together into one problem, the large ones alone.
  std::vector<Eigen::Index> island_rows(static_cast<std::size_t>(count), 0);
  for (std::size_t k = 0; k < island_of_.size(); ++k)
    island_rows[static_cast<std::size_t>(island_of_[k])] += offsets[k + 1] - offsets[k];
  // The small ones fill groups of at most kIslandGroupRows rows: one group of them all grows with
  // the pile and crosses the default's size classes (pile-1000 at step 266: 343 islands of <= 36
  // rows made one problem of 4458 rows and 50.7k entries, past sparse Newton's 50k, and ADMM
  // missed at every step), where each group's plan should be chosen by what its islands are.
  std::vector<int> group(static_cast<std::size_t>(count), -1);
  int groups = 0, small_group = -1;
  Eigen::Index small_rows = 0;
  for (int i = 0; i < count; ++i) {
    const Eigen::Index rows = island_rows[static_cast<std::size_t>(i)];
    if (rows >= kIslandAloneRows) {
      group[static_cast<std::size_t>(i)] = groups++;
    } else {
      if (small_group < 0 || small_rows + rows > kIslandGroupRows) {
        small_group = groups++;
        small_rows = 0;
      }
      small_rows += rows;
      group[static_cast<std::size_t>(i)] = small_group;
    }
  }
  for (int& i : island_of_) i = group[static_cast<std::size_t>(i)];
  islands_.clear();
  islands_.resize(static_cast<std::size_t>(groups));
  const auto& cons = problem.constraints();
  for (std::size_t k = 0; k < island_of_.size(); ++k) {
    Island& isl = islands_[static_cast<std::size_t>(island_of_[k])];
    isl.blocks.push_back(static_cast<int>(k));
    for (Eigen::Index r = offsets[k]; r < offsets[k + 1]; ++r) isl.rows.push_back(r);
  }
  local_row_.assign(static_cast<std::size_t>(problem.numRows()), -1);
  for (Island& isl : islands_) {
    const Eigen::Index rows = static_cast<Eigen::Index>(isl.rows.size());
    for (Eigen::Index i = 0; i < rows; ++i) local_row_[static_cast<std::size_t>(isl.rows[static_cast<std::size_t>(i)])] = static_cast<int>(i);
    std::vector<Constraint> sub_cons;
    for (int k : isl.blocks) sub_cons.push_back(cons[static_cast<std::size_t>(k)]);
    // The island's A: its columns' entries (every one in the island: A couples nothing outside it).
    std::shared_ptr<const DelassusOperator> op;
    if (rows <= kSparseDelassusRows) {  // (the simulator's rule: small problems dense)
      Eigen::MatrixXd D = Eigen::MatrixXd::Zero(rows, rows);
      for (Eigen::Index j = 0; j < rows; ++j) {
        const Eigen::Index c = isl.rows[static_cast<std::size_t>(j)];
        for (int p = S.outerIndexPtr()[c]; p < S.outerIndexPtr()[c + 1]; ++p) {
          const Eigen::Index i = local_row_[static_cast<std::size_t>(S.innerIndexPtr()[p])];
          D(i, j) = S.valuePtr()[p];
          isl.source.push_back(p);
          isl.target.push_back(static_cast<int>(i + j * rows));
        }
      }
      isl.dense = std::make_shared<DenseDelassus>(std::move(D));
      op = isl.dense;
    } else {
      // (columns in order, rows in each column in order: the whole A's rows of one island keep
      // their order, so its compressed pattern comes out sorted)
      Eigen::SparseMatrix<double>& sub = isl.staging;
      sub.resize(rows, rows);
      Eigen::VectorXi per_column(rows);
      for (Eigen::Index j = 0; j < rows; ++j) per_column[j] = static_cast<int>(S.col(isl.rows[static_cast<std::size_t>(j)]).nonZeros());
      sub.reserve(per_column);
      for (Eigen::Index j = 0; j < rows; ++j) {
        const Eigen::Index c = isl.rows[static_cast<std::size_t>(j)];
        for (int p = S.outerIndexPtr()[c]; p < S.outerIndexPtr()[c + 1]; ++p) {
          sub.insert(local_row_[static_cast<std::size_t>(S.innerIndexPtr()[p])], j) = S.valuePtr()[p];
          isl.source.push_back(p);
        }
      }
      sub.makeCompressed();
      isl.sparse = std::make_shared<SparseDelassus>(sub, problem.isSymmetric());
      op = isl.sparse;
    }
    isl.b.resize(rows);
    for (Eigen::Index i = 0; i < rows; ++i) isl.b[i] = problem.b()[isl.rows[static_cast<std::size_t>(i)]];
    isl.problem = std::make_unique<ContactProblem>(op, isl.b, std::move(sub_cons), 1e-6, false);
  }
}

void IslandSolver::refresh(const ContactProblem& problem) {
  const double* values = problem.delassus().sparse()->valuePtr();
  for (Island& isl : islands_) {
    for (std::size_t i = 0; i < isl.rows.size(); ++i) isl.b[static_cast<Eigen::Index>(i)] = problem.b()[isl.rows[i]];
    if (isl.dense) {
      double* D = isl.dense->matrix().data();
      for (std::size_t k = 0; k < isl.source.size(); ++k) D[isl.target[k]] = values[isl.source[k]];
    } else {
      double* v = isl.staging.valuePtr();
      for (std::size_t k = 0; k < isl.source.size(); ++k) v[k] = values[isl.source[k]];
      if (!isl.sparse->swapValues(isl.staging)) {  // (its dense copy was built: a new operator)
        isl.sparse = std::make_shared<SparseDelassus>(isl.staging, problem.isSymmetric());
        isl.problem = std::make_unique<ContactProblem>(isl.sparse, isl.b, isl.problem->constraints(), 1e-6, false);
        continue;
      }
      // (swapValues left the previous values in staging, in the same pattern: refilled next step)
    }
    isl.problem->setB(isl.b);
  }
}

bool IslandSolver::solve(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result,
                         const Eigen::VectorXd* guess, long structure, int min_islands) {
  last_islands_ = 0;
  last_iterations_ = 0;
  if (problem.delassus().sparse() == nullptr || problem.numBlocks() < 2) return false;
  const bool same = structure >= 0 && structure == structure_ && !islands_.empty();
  if (!same) {
    split(problem);
    structure_ = structure;
  }
  const int islands = static_cast<int>(islands_.size());
  if (islands < std::max(2, min_islands)) return false;
  if (same) refresh(problem);
  while (solvers_.size() < islands_.size()) solvers_.push_back(makeSolver(solver_name_));
  if (results_.size() < islands_.size()) results_.resize(islands_.size());
  assembled_.setZero(problem.numRows());
  stages_.clear();
  int iterations = 0;
  const auto start = FastClock::now();
  const bool given = settings.warm_start == WarmStart::kGiven && guess != nullptr;
  SolverSettings sub_settings = settings;
  sub_settings.measure_exact_law = false;
  if (!given && sub_settings.warm_start == WarmStart::kGiven) sub_settings.warm_start = WarmStart::kNone;
  for (std::size_t n = 0; n < islands_.size(); ++n) {
    Island& isl = islands_[n];
    if (given) {
      sub_guess_.resize(static_cast<Eigen::Index>(isl.rows.size()));
      for (std::size_t i = 0; i < isl.rows.size(); ++i) sub_guess_[static_cast<Eigen::Index>(i)] = (*guess)[isl.rows[i]];
    }
    SolverResult& r = results_[n];
    stiction::solve(*isl.problem, *solvers_[n], sub_settings, r, given ? &sub_guess_ : nullptr);
    iterations += r.iterations;
    if (!r.converged && given && r.status == SolveStatus::kNotConverged) {
      // The previous step's impulses can lead an island into a stall that the same island from
      // zero does not meet (the whole problem's retry, sim/solve.cpp): one cold solve of this
      // island before the whole problem (pile-1000, step 265: a group missed from its guess and
      // the whole problem, 4410 rows past sparse Newton's size, missed by ADMM at 1.9e-6).
      SolverSettings cold = sub_settings;
      cold.warm_start = WarmStart::kNone;
      stiction::solve(*isl.problem, *solvers_[n], cold, r, nullptr);
      iterations += r.iterations;
    }
    if (!r.converged) return false;  // (the whole problem's solve says why)
    for (const StageReport& s : r.stages) stages_.push_back(s);
    for (std::size_t i = 0; i < isl.rows.size(); ++i) assembled_[isl.rows[i]] = r.lam[static_cast<Eigen::Index>(i)];
  }
  // The whole verdict from the islands': the natural map is block by block, so its norm squared is
  // the sum of the islands'; each island's true norm is within its measured one plus its rounding
  // bound, hence the whole's below sqrt(sum (natural_i + bound_i)^2) <= tolerance x ||b|| when
  // every island met tolerance x ||b_i|| (the b_i partition b). An island with b_i = 0 is judged
  // on the scale 1 instead (stoppingScale): then, or where the sum misses by rounding, the whole
  // problem's verdict decides below.
  if (!settings.measure_exact_law) {
    double met = 0.0, natural = 0.0, bound = 0.0, floor = 0.0;
    bool zero_b = false;
    for (std::size_t n = 0; n < islands_.size(); ++n) {
      const SolverResult& r = results_[n];
      const double nb = islands_[n].problem->bNorm();
      zero_b = zero_b || !(nb > 0.0);
      met += std::pow((r.relative_residual + r.residual_bound) * nb, 2);
      natural += std::pow(r.relative_residual * nb, 2);
      bound += std::pow(r.residual_bound * nb, 2);
      floor += std::pow(r.precision_floor * nb, 2);
    }
    const double b_norm = problem.bNorm();
    const double threshold = settings.tolerance * b_norm;
    if (!zero_b && b_norm > 0.0 && std::isfinite(met) && met <= (1.0 - 1e-9) * threshold * threshold) {
      result.resize(problem.numRows(), problem.numBlocks());
      result.lam = assembled_;
      for (std::size_t n = 0; n < islands_.size(); ++n) {
        const Island& isl = islands_[n];
        const SolverResult& r = results_[n];
        for (std::size_t i = 0; i < isl.rows.size(); ++i) result.u[isl.rows[i]] = r.u[static_cast<Eigen::Index>(i)];
        for (std::size_t k = 0; k < isl.blocks.size(); ++k) result.states[static_cast<std::size_t>(isl.blocks[k])] = r.states[k];
      }
      result.iterations = iterations;
      result.solver = solver_name_;
      result.status = SolveStatus::kConverged;
      result.converged = true;
      result.relative_residual = std::sqrt(natural) / b_norm;
      result.residual = std::sqrt(natural) / (1.0 + b_norm);
      result.residual_bound = std::sqrt(bound) / b_norm;
      result.precision_floor = std::sqrt(floor) / b_norm;
      result.lambda_norm = result.lam.norm();
      result.min_solution_norm = 0.0;
      result.implicated_blocks.clear();
      result.divergence_candidates.clear();
      result.warm_start_seconds = 0.0;
      result.warm_start_iterations = 0;
      result.stages = stages_;
      result.message = "converged (" + std::to_string(islands) + " islands)";
      result.own_converged = true;
      result.own_residual = result.relative_residual;
      result.own_law = "exact Coulomb law (eq. 65): natural map / ||b||";
      result.exact_law_measured = false;
      result.seconds = std::chrono::duration<double>(FastClock::now() - start).count();
      last_islands_ = islands;
      last_iterations_ = iterations;
      return true;
    }
  }
  // The whole problem's verdict at the assembled lambda.
  auto& checker = static_cast<GivenLambda&>(*checker_);
  checker.iterations = iterations;
  checker.message = "converged (" + std::to_string(islands) + " islands)";
  checker.stages = &stages_;
  SolverSettings whole = settings;
  whole.warm_start = WarmStart::kGiven;
  stiction::solve(problem, checker, whole, result, &assembled_);
  last_islands_ = islands;
  last_iterations_ = iterations;
  if (!result.converged) return false;
  result.solver = solver_name_;
  return true;
}

}  // namespace stiction
