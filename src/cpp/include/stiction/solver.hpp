// Solver interface: every algorithm resolves the same ContactProblem and every
// result carries the same residual (the natural map of the De Saxce problem).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "stiction/contact_problem.hpp"
#include "stiction/exact_law.hpp"
#include "stiction/verdict.hpp"

namespace stiction {

enum class WarmStart {
  kNone = 0,    ///< start from lambda = 0
  kGiven = 1,   ///< start from a lambda_0 given by the caller (e.g. the previous step)
  kProxQP = 2,  ///< start from ProxQP's solution of the facetized-cone QP
};

/// The most facets of a facetized cone (SolverSettings::proxqp_facets, FormulationSettings::pyramid_facets).
/// An N-facet pyramid misses the cone by 1/cos(pi/N) - 1 ~ pi^2 / (2 N^2) of mu: 4.7e-6 at 1024, finer
/// than any friction coefficient is known, so more facets buy nothing, while each costs a dense
/// inequality row per contact in ProxQP's QP (whose workspace grows as the square of the rows).
constexpr int kMaxFacets = 1024;
constexpr const char* kMaxFacetsReason =
    " (an N-facet pyramid is within pi^2/(2 N^2) of the cone: 4.7e-6 of mu at 1024; each facet is a dense QP row "
    "per contact)";

struct SolverSettings {
  double tolerance = 1e-10;   ///< on relative_residual + residual_bound (verdict.hpp)
  int max_iterations = 2000;  ///< sweeps (NSGS) / iterations (ADMM, Newton)
  WarmStart warm_start = WarmStart::kNone;
  int proxqp_facets = 8;       ///< edges of the pyramid that replaces each spatial cone (3 .. kMaxFacets)
  double proxqp_tolerance = 1e-8;  ///< relative (eps_rel), scaled to b and lambda (eps_abs)
  int proxqp_max_iterations = 20000;  ///< ProxQP's inner iterations in all, per ProxQP run
  double admm_rho = 0.0;       ///< 0: chosen from the spectrum of A
  double time_limit = 0.0;     ///< seconds, 0 = none; covers every stage (warm start included)
  /// false: result.exact_law is left unmeasured (exact_law_measured false; result.states still
  /// classified). The simulator's per-step solves: its result measures them when asked for.
  bool measure_exact_law = true;
};

/// The residual every result reports: naturalMapNorm / (1 + ||b||).
double residual(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam);

/// What one stage of a solve cost and how it ended (the default runs several).
struct StageReport {
  std::string name;        ///< "newton", "nsgs", "admm", "proxqp", "proxqp (warm start)"
  int iterations = 0;      ///< Newton steps, sweeps, ADMM or ProxQP iterations
  double seconds = 0.0;
  std::string outcome;     ///< "converged", "stalled", "time limit reached", ...
};

struct SolverResult {
  Eigen::VectorXd lam;  ///< the impulse / force lambda (numRows)
  Eigen::VectorXd u;    ///< A lambda - b (numRows)
  std::vector<ContactState> states;  ///< one per block
  int iterations = 0;             ///< Newton steps + sweeps + ADMM iterations (ProxQP's: warm_start_*)
  bool converged = false;         ///< status == kConverged
  SolveStatus status = SolveStatus::kNotConverged;
  double residual = 0.0;          ///< naturalMapNorm / (1 + ||b||)
  double relative_residual = 0.0; ///< naturalMapNorm / ||b|| (Siconos' measure; >= residual)
  double residual_bound = 0.0;    ///< rounding bound of relative_residual (verdict.hpp)
  double precision_floor = 0.0;   ///< what rounding lambda to double alone moves relative_residual by
  double lambda_norm = 0.0;       ///< ||lambda||, the scale the verdict had to resolve
  double min_solution_norm = 0.0; ///< infeasible: every solution has ||lambda|| >= this (inf: none)
  std::vector<int> implicated_blocks;  ///< infeasible / unresolvable: the blocks responsible
  double seconds = 0.0;           ///< wall time of the whole solve, warm start included
  double warm_start_seconds = 0.0;
  int warm_start_iterations = 0;  ///< ProxQP iterations, as a warm start or inside the default
  std::vector<StageReport> stages;  ///< every stage run, in order, with its cost
  std::string solver;
  std::string message;            ///< the verdict, the stage that stopped and why

  // The formulation's own verdict (formulation.hpp). For the exact solvers it is the verdict
  // above; for the others, their own stopping test, while residual / status / converged
  // above always judge lambda by the exact law: "converged by its own law, exact-law residual X".
  bool own_converged = false;
  double own_residual = 0.0;      ///< the formulation's own measure, relative (own_law says which)
  std::string own_law;            ///< what own_residual measures
  /// The exact law's measures at lam, part by part (exact_law.hpp), whatever produced it:
  /// the same yardstick for every formulation, computed by the driver.
  ExactLawMeasures exact_law;
  bool exact_law_measured = false;  ///< exact_law holds this lam's measures (SolverSettings::measure_exact_law)

  /// Set by the algorithms: iterates that ran away, or ProxQP's ray of unboundedness;
  /// the verdict tests them as infeasibility certificates.
  std::vector<Eigen::VectorXd> divergence_candidates;

  void resize(Eigen::Index rows, std::size_t blocks);
};

/// One algorithm. Owns its workspace (reused across solves of the same size).
class ContactSolver {
 public:
  virtual ~ContactSolver() = default;
  virtual std::string name() const = 0;
  /// True for the solvers of the exact law (eq. 65): their result is judged by the full
  /// verdict (infeasibility certificates included). Other formulations (formulation.hpp)
  /// set result.own_converged / own_residual themselves.
  virtual bool exactLaw() const { return true; }
  /// True when the driver may run iterate() on the problem scaled by powers of two (A 2^-a,
  /// b 2^-c, lambda 2^(a-c)) where its magnitudes are extreme (docs/solvers.md, "Scale"): every
  /// algorithm whose parameters carry no units. (penalty: its stiffness K does, so no.)
  virtual bool rescalable() const { return true; }

  /// Iterate from result.lam (already sized and set to the initial guess) until
  /// the StoppingTest passes or the budget (iterations, settings.time_limit) is
  /// spent. Must leave result.lam, result.iterations and result.message set, and
  /// may append to result.stages; the driver computes u, the residual, the states
  /// and the verdict itself.
  virtual void iterate(const ContactProblem& problem, const SolverSettings& settings,
                       SolverResult& result) = 0;
};

/// "nsgs", "admm", "newton" or "default" (NSGS, then Newton if NSGS stalls).
std::unique_ptr<ContactSolver> makeSolver(const std::string& name);
std::vector<std::string> solverNames();

/// Throws std::invalid_argument naming the first setting out of its range (every field is checked;
/// max_iterations and proxqp_max_iterations size no memory, so they have no upper bound).
void validateSettings(const SolverSettings& settings);

/// The driver: infeasibility pre-check, warm start, iterate, then the common verdict
/// (u, residual and its rounding bound, states, status, seconds; verdict.hpp).
/// `guess` is used when settings.warm_start == kGiven. The time limit covers it all.
void solve(const ContactProblem& problem, ContactSolver& solver, const SolverSettings& settings,
           SolverResult& result, const Eigen::VectorXd* guess = nullptr);

/// result.stages emptied, its reports' strings kept for addStage to reuse (a solve per simulator
/// step: no allocation once they have grown).
void clearStages(std::vector<StageReport>& stages);
/// Appends {name, iterations, seconds, outcome} to `stages`, in strings clearStages kept.
void addStage(std::vector<StageReport>& stages, const char* name, int iterations, double seconds,
              const char* outcome);
void addStage(std::vector<StageReport>& stages, const char* name, int iterations, double seconds,
              const std::string& outcome);

/// Classify every block from (lambda, u): open / stick / slip / closed.
void classifyStates(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                    const Eigen::Ref<const Eigen::VectorXd>& u, std::vector<ContactState>& states);

}  // namespace stiction
