#include "stiction/solver.hpp"

#include <chrono>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "stiction/clock.hpp"
#include "stiction/admm.hpp"
#include "stiction/cone.hpp"
#include "stiction/default_solver.hpp"
#include "stiction/newton.hpp"
#include "stiction/nsgs.hpp"
#include "stiction/proxqp_warm_start.hpp"

namespace stiction {

void SolverResult::resize(Eigen::Index rows, std::size_t blocks) {
  lam.resize(rows);
  u.resize(rows);
  states.resize(blocks);
}

double residual(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam) {
  if (lam.size() != problem.numRows())
    throw std::invalid_argument("residual: lambda has " + std::to_string(lam.size()) +
                                " entries, the problem has " + std::to_string(problem.numRows()) +
                                " rows");
  Eigen::VectorXd u(lam.size());
  problem.delassus().multiply(lam, u);
  u -= problem.b();
  return naturalMapNorm(problem, lam, u) / (1.0 + problem.bNorm());
}

void classifyStates(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                    const Eigen::Ref<const Eigen::VectorXd>& u, std::vector<ContactState>& states) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  thread_local Eigen::VectorXd diag;  // (no allocation per solve once sized)
  diag.resize(problem.numRows());
  problem.delassus().diagonal(diag);
  states.resize(cons.size());
  // Tangential speeds below this are solver noise, not sliding.
  const double speed_floor = 1.5e-8 * std::max(problem.b().lpNorm<Eigen::Infinity>(), 1e-300);
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    const int k = cons[i].size;
    if (cons[i].kind == ConstraintKind::kBilateral) {
      states[i] = ContactState::kClosed;
      continue;
    }
    // Compare what the force does (A_nn lambda_n) with the separation velocity u_n.
    const Eigen::Index n = o + k - 1;
    const double a_nn = diag[n];
    const bool pushing = a_nn > 0.0 ? a_nn * lam[n] > u[n] : lam[n] > 0.0;
    if (!pushing || lam[n] <= 0.0) {
      states[i] = ContactState::kOpen;
      continue;
    }
    if (cons[i].kind == ConstraintKind::kUnilateral) {
      states[i] = ContactState::kClosed;
      continue;
    }
    // Slip when the tangential velocity outweighs what the unused friction could cancel.
    double lt, ut, a_tt;
    if (k == 3) {
      lt = norm2(lam[o], lam[o + 1]);
      ut = norm2(u[o], u[o + 1]);
      a_tt = 0.5 * (diag[o] + diag[o + 1]);
    } else {
      lt = std::abs(lam[o]);
      ut = std::abs(u[o]);
      a_tt = diag[o];
    }
    const double margin = std::max(0.0, cons[i].mu * lam[n] - lt);
    states[i] = ut > a_tt * margin && ut > speed_floor ? ContactState::kSlip : ContactState::kStick;
  }
}

std::unique_ptr<ContactSolver> makeSolver(const std::string& name) {
  if (name == "nsgs") return std::make_unique<NsgsSolver>();
  if (name == "admm") return std::make_unique<AdmmSolver>();
  if (name == "newton") return std::make_unique<NewtonSolver>();
  if (name == "default") return std::make_unique<DefaultSolver>();
  std::string known;
  for (const auto& n : solverNames()) known += (known.empty() ? "" : ", ") + n;
  throw std::invalid_argument("unknown solver '" + name + "' (known: " + known + ")");
}

std::vector<std::string> solverNames() { return {"default", "nsgs", "admm", "newton"}; }

namespace {

std::string fmt(double x) {
  std::ostringstream os;
  os.precision(3);
  os << x;
  return os.str();
}

std::string blockList(const ContactProblem& problem, const std::vector<int>& blocks) {
  std::string out;
  for (std::size_t k = 0; k < blocks.size() && k < 8; ++k)
    out += (k ? ", " : "") + std::to_string(blocks[k]) + " (" + problem.constraints()[blocks[k]].describe() + ")";
  if (blocks.size() > 8) out += ", ...";
  return out;
}

bool startsWith(const std::string& s, const char* prefix) { return s.rfind(prefix, 0) == 0; }

}  // namespace

void solve(const ContactProblem& problem, ContactSolver& solver, const SolverSettings& settings,
           SolverResult& result, const Eigen::VectorXd* guess) {
  using Clock = FastClock;  // the time-stamp counter (clock.hpp)
  if (!(settings.tolerance > 0.0) || !std::isfinite(settings.tolerance))
    throw std::invalid_argument("solver tolerance must be a positive finite number, got " + fmt(settings.tolerance));
  if (settings.max_iterations < 0)
    throw std::invalid_argument("max_iterations must be >= 0, got " + std::to_string(settings.max_iterations));
  if (!(settings.time_limit >= 0.0) || !std::isfinite(settings.time_limit))
    throw std::invalid_argument("time_limit must be a finite number of seconds >= 0 (0: none), got " +
                                fmt(settings.time_limit));
  if (!(settings.proxqp_tolerance > 0.0) || !std::isfinite(settings.proxqp_tolerance))
    throw std::invalid_argument("proxqp_tolerance must be a positive finite number");
  if (settings.proxqp_max_iterations < 1) throw std::invalid_argument("proxqp_max_iterations must be >= 1");
  const auto start = Clock::now();
  auto elapsed = [&]() { return std::chrono::duration<double>(Clock::now() - start).count(); };
  forgetVerdicts();  // A or b may have changed in place since the last solve
  const Eigen::Index m = problem.numRows();
  result.resize(m, problem.numBlocks());
  result.solver = solver.name();
  result.warm_start_seconds = 0.0;
  result.warm_start_iterations = 0;
  result.iterations = 0;
  result.stages.clear();
  result.divergence_candidates.clear();
  result.implicated_blocks.clear();
  result.min_solution_norm = 0.0;
  result.message.clear();
  switch (settings.warm_start) {
    case WarmStart::kNone: result.lam.setZero(); break;
    case WarmStart::kGiven:
      if (guess == nullptr) throw std::invalid_argument("warm start 'given' needs an initial lambda");
      if (guess->size() != m)
        throw std::invalid_argument("initial lambda has " + std::to_string(guess->size()) +
                                    " entries, the problem has " + std::to_string(m) + " rows");
      if (!guess->allFinite()) throw std::invalid_argument("initial lambda has NaN or infinite entries");
      result.lam = *guess;
      break;
    case WarmStart::kProxQP: result.lam.setZero(); break;
  }
  const bool exact = solver.exactLaw();
  result.own_converged = false;
  result.own_residual = 0.0;
  result.own_law.clear();
  // A contact that nothing can move but b pushes closed has no solution: say so
  // before spending the budget (the verdict below names it). Other formulations solve
  // problems of their own (penalty: always solvable) and are only measured by the exact law.
  const bool hopeless = exact && beyondPrecision(problem, findInfeasibility(problem, {}).min_solution_norm);
  if (!hopeless) {
    if (settings.warm_start == WarmStart::kProxQP) {
      Eigen::VectorXd ray;
      StageReport qp = proxqpWarmStart(problem, settings, settings.time_limit, result.lam, &ray);
      qp.name = "proxqp (warm start)";
      result.warm_start_iterations = qp.iterations;
      result.warm_start_seconds = qp.seconds;
      if (ray.size() == m) result.divergence_candidates.push_back(ray);
      result.stages.push_back(qp);
    }
    // The algorithm gets what is left of the time limit.
    SolverSettings local = settings;
    if (settings.time_limit > 0.0) local.time_limit = std::max(1e-9, settings.time_limit - elapsed());
    const auto t0 = Clock::now();
    const std::size_t stages_before = result.stages.size();
    solver.iterate(problem, local, result);
    if (result.stages.size() == stages_before)  // a single-stage algorithm: report it as one
      result.stages.push_back({solver.name(), result.iterations,
                               std::chrono::duration<double>(Clock::now() - t0).count(), result.message});
  } else {
    result.message = "no algorithm run";
  }

  // The common verdict, whatever the algorithm (verdict.hpp). (u as the stopping test's last
  // verdict computed it when it judged this lambda.)
  if (!lastVerdictResidual(problem, result.lam, result.u)) {
    problem.delassus().multiply(result.lam, result.u);
    result.u -= problem.b();
  }
  const double scale = stoppingScale(problem);
  const double threshold = settings.tolerance * scale;
  VerdictMeasures measures;
  measureVerdict(problem, result.lam, measures, threshold);
  result.residual = measures.natural_map / (1.0 + problem.bNorm());
  result.relative_residual = measures.natural_map / scale;
  result.residual_bound = measures.bound / scale;
  result.precision_floor = measures.floor / scale;
  result.lambda_norm = result.lam.norm();
  const bool finite = std::isfinite(measures.natural_map) && std::isfinite(measures.bound) && result.lam.allFinite();
  if (finite && measures.natural_map + measures.bound <= threshold) {
    result.status = SolveStatus::kConverged;
  } else if (!exact) {
    // Another law than the exact one: its own verdict is in own_*; say how far the exact law is.
    result.status = SolveStatus::kNotConverged;
    result.message += std::string(result.message.empty() ? "" : "; ") + "exact-law residual " +
                      fmt(result.relative_residual) + " x ||b||";
  } else {
    std::string why = result.message;
    if (startsWith(why, "converged")) why = "residual above tolerance " + why.substr(std::min<std::size_t>(10, why.size()));
    result.divergence_candidates.push_back(result.lam);
    const InfeasibilityCertificate cert = findInfeasibility(problem, result.divergence_candidates);
    result.min_solution_norm = cert.min_solution_norm;
    if (beyondPrecision(problem, cert.min_solution_norm)) {
      result.status = SolveStatus::kInfeasible;
      result.implicated_blocks = cert.blocks;
      result.message = std::isinf(cert.min_solution_norm)
                           ? "no solution: b pushes block(s) " + blockList(problem, cert.blocks) +
                                 " closed along a direction A does not resist (a contact on something "
                                 "that cannot move, or contacts pushing against each other); lambda would "
                                 "grow without bound"
                           : "no solution of a size double precision can verify: every solution has "
                             "||lambda|| >= " + fmt(cert.min_solution_norm) + " (b pushes block(s) " +
                                 blockList(problem, cert.blocks) + " along a direction A barely resists)";
      result.message += " [" + why + "]";
    } else if (!finite || measures.floor > kFloorMargin * threshold) {
      result.status = SolveStatus::kUnresolvable;
      // the blocks whose lambda's rounding moves the residual most
      measureVerdict(problem, result.lam, measures, threshold, /*per_block=*/true);
      double worst = 0.0;
      for (double e : measures.block_floor) worst = std::max(worst, e);
      for (std::size_t i = 0; i < measures.block_floor.size(); ++i)
        if (measures.block_floor[i] >= 0.1 * worst && worst > 0.0)
          result.implicated_blocks.push_back(static_cast<int>(i));
      result.message = !finite ? "diverged: non-finite lambda or residual"
                               : "residual not resolvable in double precision (lambda scale ||lambda|| = " +
                                     fmt(result.lambda_norm) + ": rounding lambda alone moves the residual by up to " +
                                     fmt(result.precision_floor) + " x ||b||, far above the tolerance " +
                                     fmt(settings.tolerance) + "; residual " + fmt(result.relative_residual) +
                                     " x ||b||)";
      result.message += " [" + why + "]";
    } else {
      result.status = SolveStatus::kNotConverged;
      result.message = why;
      if (cert.min_solution_norm > 0.0)
        result.message += " (every solution has ||lambda|| >= " + fmt(cert.min_solution_norm) + ")";
    }
  }
  result.converged = result.status == SolveStatus::kConverged;
  if (exact) {
    result.own_converged = result.converged;
    result.own_residual = result.relative_residual;
    result.own_law = "exact Coulomb law (eq. 65): natural map / ||b||";
  } else if (!result.lam.allFinite()) {
    result.own_converged = false;
  }
  result.divergence_candidates.clear();
  if (settings.measure_exact_law) {
    measureExactLaw(problem, result.lam, result.exact_law, kRelativeSpeedFloor, &result.u);
    result.states = result.exact_law.states;  // (classifyStates of the same lambda and u)
  } else {
    classifyStates(problem, result.lam, result.u, result.states);
  }
  result.exact_law_measured = settings.measure_exact_law;
  result.seconds = elapsed();
}

}  // namespace stiction
