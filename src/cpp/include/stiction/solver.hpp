// Solver interface: every algorithm resolves the same ContactProblem and every
// result carries the same residual (the natural map of the De Saxce problem).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "stiction/contact_problem.hpp"

namespace stiction {

enum class WarmStart {
  kNone = 0,    ///< start from lambda = 0
  kGiven = 1,   ///< start from a lambda_0 given by the caller (e.g. the previous step)
  kProxQP = 2,  ///< start from ProxQP's solution of the facetized-cone QP
};

struct SolverSettings {
  double tolerance = 1e-10;   ///< on SolverResult::relative_residual (hence also on residual)
  int max_iterations = 2000;  ///< sweeps (NSGS) / iterations (ADMM, Newton)
  WarmStart warm_start = WarmStart::kNone;
  int proxqp_facets = 8;       ///< edges of the pyramid that replaces each spatial cone
  double proxqp_tolerance = 1e-8;
  double admm_rho = 0.0;       ///< 0: chosen from the spectrum of A
  double time_limit = 0.0;     ///< seconds, 0 = none; exceeding it returns converged = false
};

/// Natural-map residual ||lambda - P_C(lambda - (u + E s(u)))|| with u = A lambda - b,
/// unnormalised. Bilateral rows contribute u, unilateral rows min-map.
double naturalMapNorm(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                      const Eigen::Ref<const Eigen::VectorXd>& u);

/// The residual every result reports: naturalMapNorm / (1 + ||b||).
double residual(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam);

/// ||b||, or 1 when b = 0: the scale of relative_residual (Siconos divides by ||q|| = ||b||).
/// Solvers stop on naturalMapNorm <= tolerance * stoppingScale, which is the stricter of
/// the two measures, so a problem scaled down (tiny b and lambda) is still solved to
/// relative accuracy instead of passing on an absolute test.
double stoppingScale(const ContactProblem& problem);

struct SolverResult {
  Eigen::VectorXd lam;  ///< the impulse / force lambda (numRows)
  Eigen::VectorXd u;    ///< A lambda - b (numRows)
  std::vector<ContactState> states;  ///< one per block
  int iterations = 0;
  bool converged = false;
  double residual = 0.0;          ///< naturalMapNorm / (1 + ||b||)
  double relative_residual = 0.0; ///< naturalMapNorm / ||b|| (Siconos' measure; >= residual)
  double seconds = 0.0;           ///< wall time of the whole solve, warm start included
  double warm_start_seconds = 0.0;
  int warm_start_iterations = 0;  ///< ProxQP iterations when warm_start == kProxQP
  std::string solver;
  std::string message;            ///< why it stopped

  void resize(Eigen::Index rows, std::size_t blocks);
};

/// One algorithm. Owns its workspace (reused across solves of the same size).
class ContactSolver {
 public:
  virtual ~ContactSolver() = default;
  virtual std::string name() const = 0;

  /// Iterate from result.lam (already sized and set to the initial guess) until
  /// the residual is below settings.tolerance or the budget is spent. Must
  /// leave result.lam, result.iterations and result.message set; the driver
  /// computes u, the residual, the states and the converged flag itself.
  virtual void iterate(const ContactProblem& problem, const SolverSettings& settings,
                       SolverResult& result) = 0;
};

/// "nsgs", "admm", "newton" or "default" (NSGS, then Newton if NSGS stalls).
std::unique_ptr<ContactSolver> makeSolver(const std::string& name);
std::vector<std::string> solverNames();

/// The driver: warm start, iterate, then the common verdict (u, residual, states,
/// converged, seconds). `guess` is used when settings.warm_start == kGiven.
void solve(const ContactProblem& problem, ContactSolver& solver, const SolverSettings& settings,
           SolverResult& result, const Eigen::VectorXd* guess = nullptr);

/// Classify every block from (lambda, u): open / stick / slip / closed.
void classifyStates(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                    const Eigen::Ref<const Eigen::VectorXd>& u, std::vector<ContactState>& states);

}  // namespace stiction
