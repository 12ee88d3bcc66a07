// The default solver: a rule that picks stages from the problem's size and structure
// (defaultPlan, a pure function), and an executor that runs them, each stage judging by how the
// previous ones converged (DefaultSolver::iterate). Measured on the 36 FCLib problems and the
// simulator's scenes: docs/solvers.md, "The default's rule".
#pragma once

#include <array>
#include <string>

#include "stiction/admm.hpp"
#include "stiction/iteration_monitor.hpp"
#include "stiction/newton.hpp"
#include "stiction/nsgs.hpp"
#include "stiction/solver.hpp"
#include "stiction/sticking_step.hpp"
#include "stiction/thresholds.hpp"

namespace stiction {

/// The stages the default can run. Each runs from the iterate its predecessor left (or the
/// initial guess, where named) and either finishes the solve (converged, unresolvable, out of
/// time) or hands over to the next one.
enum class DefaultStage {
  kStickingStep,     ///< the all-stick solution by one proximal factorization (sticking_step.hpp)
  kNewtonFirst,      ///< Newton from the guess, at most 30 steps (small problems)
  kProxqpNewton,     ///< ProxQP's facetized-cone QP solution, then Newton from it (30 steps)
  kWarmSweeps,       ///< at most DefaultSolver::kWarmSweeps NSGS sweeps from a warm start
  kSparseNewton,     ///< Newton from the initial guess with its sparse Jacobian and LU (50 steps)
  kAdmm,             ///< ADMM from the initial guess until it converges or stalls, then polish
  kNsgs,             ///< NSGS while its rate promises to finish within ~m sweeps
  kAdmmAfterNsgs,    ///< ADMM (as kAdmm) after a stalled NSGS on a large dense problem
  kWarmAdmm,         ///< at most DefaultSolver::kWarmAdmmIterations ADMM iterations from the guess
  kNewtonAfterNsgs,  ///< Newton from the NSGS iterate (or the best iterate), 50 steps
  kNewtonFromGuess,  ///< Newton from the initial guess, 50 steps
  kFallbacks,        ///< unresolvable at the best iterate? else NSGS / ADMM chunks, each with Newton
};

/// A short name for each stage ("sticking_step", "newton_first", ...).
const char* toString(DefaultStage stage);

/// What the default's rule reads: the problem's size and structure, and the solve's start.
struct DefaultRuleInput {
  Eigen::Index rows = 0;
  /// A held sparse, or more than kDenseFactorRows rows of which at most kSparseProblemDensity are
  /// nonzero (sparseEnough, admm.hpp). Read only above kAdmmAboveRows rows.
  bool sparse = false;
  /// The entries A stores (a dense A: its nonzeros). Read only for a large sparse A.
  Eigen::Index stored_entries = 0;
  bool warm_started = false;   ///< SolverSettings::warm_start is not kNone
  bool sticking_guess = false; ///< stickingGuess(problem, guess) (sticking_step.hpp)
  bool has_budget = true;      ///< SolverSettings::max_iterations > 0
};

/// The stages to run, in order (the last is always kFallbacks). No allocation.
struct DefaultPlan {
  static constexpr int kMaxStages = 6;
  std::array<DefaultStage, kMaxStages> stages{};
  int count = 0;
  const DefaultStage* begin() const { return stages.data(); }
  const DefaultStage* end() const { return stages.data() + count; }
  void add(DefaultStage stage) { stages[static_cast<std::size_t>(count++)] = stage; }
};

/// The default's rule (docs/solvers.md, "The default's rule"), from its input alone (the sizes:
/// thresholds.hpp):
/// - a sticking guess (and a budget, and rows): the sticking step first;
/// - up to kNewtonFirstRows rows: Newton, then Newton from ProxQP's solution;
/// - above kAdmmAboveRows rows with a sparse A: (warm-started: a few sweeps), then, with at most
///   kSparseNewtonEntries stored entries, sparse Newton from the guess; then ADMM, then (when
///   sparse Newton did not run) Newton from the initial guess;
/// - above kAdmmAboveRows rows with a dense A: NSGS, ADMM, Newton from the initial guess;
/// - otherwise: NSGS, (warm-started: a few ADMM iterations), Newton from the NSGS iterate, Newton
///   from the initial guess;
/// - then the fallbacks.
DefaultPlan defaultPlan(const DefaultRuleInput& input);

/// The rule's input for a solve of `problem` from `guess` with `settings`. A's sparsity and stored
/// entries are counted only where the rule reads them (O(rows^2) for a dense A).
DefaultRuleInput defaultRuleInput(const ContactProblem& problem, const Eigen::VectorXd& guess,
                                  const SolverSettings& settings);

/// The default: runs defaultPlan's stages (see there, and docs/solvers.md). Returns the best
/// iterate met when no stage converged.
class DefaultSolver final : public ContactSolver {
 public:
  /// ADMM's stall horizon, in iterations per row (admm.hpp: switch_after).
  static constexpr double kAdmmHorizonPerRow = 10.0;
  /// Gauss-Seidel sweeps tried before ADMM on a warm-started large sparse problem.
  static constexpr int kWarmSweeps = 10;
  /// ADMM iterations from the guess on a warm-started medium problem before Newton: where it
  /// helps (a tower at rest whose contacts are not all sticking) it converges in a few; a tower
  /// of 24 spinning boxes took 440-910 to stall (7-13 ms) before Newton converged in 5-6 steps.
  static constexpr int kWarmAdmmIterations = 50;
  /// Newton steps from the best iterate after ADMM stalls, if its residual is within
  /// kPolishWithin x the tolerance.
  static constexpr int kPolishSteps = 5;
  static constexpr double kPolishWithin = 1e3;

  std::string name() const override { return "default"; }
  void iterate(const ContactProblem& problem, const SolverSettings& settings,
               SolverResult& result) override;

 private:
  class Cascade;  // one solve's executor (default_solver.cpp)

  StickingStep sticking_;
  NsgsSolver nsgs_;
  NewtonSolver newton_;
  AdmmSolver admm_;
  Eigen::VectorXd best_, trial_, initial_, u_ws_;
};

}  // namespace stiction
