#include "stiction/solver.hpp"

#include <chrono>
#include <cmath>
#include <limits>
#include <memory>
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
    if (cons[i].kind == ConstraintKind::kBox) {
      // As a friction block's boundary: slip when the velocity outweighs what the room left to the
      // bound it pushes against could cancel (u < 0 holds lambda at upper, u > 0 at lower).
      const double v = u[o];
      const double room = v < 0.0 ? cons[i].upper - lam[o] : lam[o] - cons[i].lower;
      states[i] = std::abs(v) > diag[o] * std::max(0.0, room) && std::abs(v) > speed_floor ? ContactState::kSlip
                                                                                            : ContactState::kStick;
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

namespace {
// Reports cleared by clearStages, their strings' buffers kept (per thread, as the solvers' workspaces).
constexpr std::size_t kStagePoolSize = 32;
thread_local std::vector<StageReport> stage_pool;

StageReport& pushStage(std::vector<StageReport>& stages) {
  if (stage_pool.empty()) {
    stages.emplace_back();
  } else {
    stages.push_back(std::move(stage_pool.back()));
    stage_pool.pop_back();
  }
  return stages.back();
}
}  // namespace

void clearStages(std::vector<StageReport>& stages) {
  if (stage_pool.capacity() < kStagePoolSize) stage_pool.reserve(kStagePoolSize);
  for (StageReport& r : stages)
    if (stage_pool.size() < kStagePoolSize) stage_pool.push_back(std::move(r));
  stages.clear();
}

void addStage(std::vector<StageReport>& stages, const char* name, int iterations, double seconds,
              const char* outcome) {
  StageReport& r = pushStage(stages);
  r.name.assign(name);
  r.iterations = iterations;
  r.seconds = seconds;
  r.outcome.assign(outcome);
}

void addStage(std::vector<StageReport>& stages, const char* name, int iterations, double seconds,
              const std::string& outcome) {
  StageReport& r = pushStage(stages);
  r.name.assign(name);
  r.iterations = iterations;
  r.seconds = seconds;
  r.outcome.assign(outcome);
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


namespace {

/// e with x = f 2^e, f in [0.5, 1) (x > 0): x / 2^e lies in [0.5, 1).
int binaryExponent(double x) {
  int e = 0;
  std::frexp(x, &e);
  return e;
}

/// v 2^e entry by entry: exact unless an entry leaves double's range (ldexp rounds it then).
void scaleByPowerOfTwo(Eigen::Ref<Eigen::VectorXd> v, int e) {
  if (e == 0) return;
  for (Eigen::Index i = 0; i < v.size(); ++i) v[i] = std::ldexp(v[i], e);
}

/// A 2^e as a new operator of the same storage (dense, or sparse with its pattern).
std::shared_ptr<const DelassusOperator> scaledOperator(const DelassusOperator& A, int e, bool symmetric) {
  auto scale = [e](double x) { return std::ldexp(x, e); };
  if (const Eigen::SparseMatrix<double>* s = A.sparse()) {
    Eigen::SparseMatrix<double> copy = *s;
    for (Eigen::Index k = 0; k < copy.nonZeros(); ++k) copy.valuePtr()[k] = scale(copy.valuePtr()[k]);
    return std::make_shared<SparseDelassus>(std::move(copy), symmetric);
  }
  return std::make_shared<DenseDelassus>(A.dense().unaryExpr(scale));
}

/// The constraints of a problem whose lambda is scaled by 2^e: box rows' bounds scale with lambda
/// (cones are scale-free). A bound beyond double's range stays the largest double (effectively none).
std::vector<Constraint> scaledConstraints(const std::vector<Constraint>& constraints, int e) {
  std::vector<Constraint> out = constraints;
  if (e == 0) return out;
  const double big = std::numeric_limits<double>::max();
  for (Constraint& c : out)
    if (c.kind == ConstraintKind::kBox) {
      c.lower = std::max(-big, std::ldexp(c.lower, e));
      c.upper = std::min(big, std::ldexp(c.upper, e));
    }
  return out;
}

/// The problems a solve works on (docs/solvers.md, "Scale"). Far from 1, the algorithms' absolute
/// constants and the verdict's squared norms under- or overflow (||b|| = 1e-200 squares to 0: the
/// relative residual of lambda = 0 read 0). Outside 2^+-kScaleWindow, the driver divides b by 2^c
/// (c: ||b||'s binary exponent) and A by 2^a (a: its largest diagonal entry's):
///   algorithm  (A 2^-a, b 2^-c): lambda' = lambda 2^(a - c), the algorithm's own problem;
///   verdict    (A, b 2^-c):      lambda 2^-c, u 2^-c, natural map 2^-c: relative_residual exactly
///              as for (A, b) (only b and lambda scale, and P_C is positively homogeneous; box rows'
///              intervals scale with lambda: P_(sC)(s x) = s P_C(x)).
/// Powers of two keep every scaling exact (short of leaving double's range).
struct Frames {
  static constexpr int kScaleWindow = 30;  // 2^30 ~ 1e9: inside, the problem is solved as given
  int a = 0;  // the algorithm's A is A 2^-a
  int c = 0;  // the algorithm's and the verdict's b are b 2^-c
  std::unique_ptr<ContactProblem> algorithm_problem, verdict_problem;
  const ContactProblem* algorithm = nullptr;
  const ContactProblem* verdict = nullptr;

  Frames(const ContactProblem& problem, bool rescalable) {
    algorithm = verdict = &problem;
    const Eigen::Index m = problem.numRows();
    if (m == 0) return;
    const double nb = problem.bNorm();
    const int eb = nb > 0.0 ? binaryExponent(nb) : 0;
    if (std::abs(eb) > kScaleWindow) c = eb;
    thread_local Eigen::VectorXd diag;  // (no allocation per solve once sized)
    diag.resize(m);
    problem.delassus().diagonal(diag);
    const double max_diag = diag.maxCoeff();
    const int ea = max_diag > 0.0 ? binaryExponent(max_diag) : 0;
    if (std::abs(ea) > kScaleWindow && rescalable) a = ea;
    if (c != 0) {
      Eigen::VectorXd b = problem.b();
      scaleByPowerOfTwo(b, -c);
      verdict_problem = std::make_unique<ContactProblem>(
          std::shared_ptr<const DelassusOperator>(&problem.delassus(), [](const DelassusOperator*) {}), std::move(b),
          scaledConstraints(problem.constraints(), -c), std::numeric_limits<double>::infinity(), false);
      verdict = verdict_problem.get();
    }
    if (a != 0) {
      Eigen::VectorXd b = problem.b();
      scaleByPowerOfTwo(b, -c);
      algorithm_problem = std::make_unique<ContactProblem>(
          scaledOperator(problem.delassus(), -a, problem.isSymmetric()), std::move(b),
          scaledConstraints(problem.constraints(), a - c), std::numeric_limits<double>::infinity(), false);
      algorithm = algorithm_problem.get();
      rescaled = true;
    } else if (rescalable && c != 0) {
      algorithm = verdict;  // (lambda 2^-c: the verdict's bounds are the algorithm's)
      rescaled = true;
    }
  }
  /// The algorithm's lambda is the caller's times 2^algorithmExponent().
  int algorithmExponent() const { return rescaled ? a - c : 0; }
  bool rescaled = false;  // the algorithm runs on (A 2^-a, b 2^-c), not on the problem given
};

/// ExactLawMeasures of (A, b 2^-c) at lambda 2^-c turned into those of (A, b) at lambda: forces,
/// velocities and distances scale by 2^c, products of two by 2^2c; relative measures and angles stay.
void scaleExactLaw(ExactLawMeasures& e, int c, double b_norm) {
  if (c == 0) return;
  auto one = [c](double& x) { x = std::ldexp(x, c); };
  auto two = [c](double& x) { x = std::ldexp(x, 2 * c); };
  e.b_norm = b_norm;
  one(e.lambda_norm);
  one(e.speed_floor);
  one(e.natural_map);
  e.residual = b_norm > 0.0 ? e.relative_residual * (b_norm / (1.0 + b_norm)) : e.natural_map;
  one(e.primal_max);
  one(e.primal_norm);
  one(e.dual_max);
  one(e.dual_norm);
  two(e.complementarity_max);
  two(e.complementarity_sum);
  two(e.signorini_max);
  one(e.dissipation_max);
  one(e.liftoff_max);
  scaleByPowerOfTwo(e.primal, c);
  scaleByPowerOfTwo(e.dual, c);
  for (Eigen::Index i = 0; i < e.complementarity.size(); ++i) two(e.complementarity[i]);
  for (Eigen::Index i = 0; i < e.signorini.size(); ++i) two(e.signorini[i]);
  scaleByPowerOfTwo(e.dissipation, c);
  scaleByPowerOfTwo(e.liftoff, c);
  scaleByPowerOfTwo(e.u, c);
  scaleByPowerOfTwo(e.w, c);
}

/// ||v|| without the squares' under- or overflow (Eigen's stableNorm where the plain one is unsafe).
double safeNorm(const Eigen::VectorXd& v) {
  const double n = v.norm();
  if (n > 1e-150 && n < 1e150) return n;
  return v.stableNorm();
}

}  // namespace

void validateSettings(const SolverSettings& settings) {
  if (!(settings.tolerance > 0.0) || !std::isfinite(settings.tolerance))
    throw std::invalid_argument("solver tolerance must be a positive finite number, got " + fmt(settings.tolerance));
  if (settings.max_iterations < 0)
    throw std::invalid_argument("max_iterations must be >= 0, got " + std::to_string(settings.max_iterations));
  if (!(settings.time_limit >= 0.0) || !std::isfinite(settings.time_limit))
    throw std::invalid_argument("time_limit must be a finite number of seconds >= 0 (0: none), got " +
                                fmt(settings.time_limit));
  if (!(settings.proxqp_tolerance > 0.0) || !std::isfinite(settings.proxqp_tolerance))
    throw std::invalid_argument("proxqp_tolerance must be a positive finite number, got " +
                                fmt(settings.proxqp_tolerance));
  if (settings.proxqp_max_iterations < 1)
    throw std::invalid_argument("proxqp_max_iterations must be >= 1, got " +
                                std::to_string(settings.proxqp_max_iterations));
  if (settings.proxqp_facets < 3 || settings.proxqp_facets > kMaxFacets)
    throw std::invalid_argument("proxqp_facets must be between 3 and " + std::to_string(kMaxFacets) + ", got " +
                                std::to_string(settings.proxqp_facets) + kMaxFacetsReason);
  if (!(settings.admm_rho >= 0.0) || !std::isfinite(settings.admm_rho))
    throw std::invalid_argument("admm_rho must be a finite number >= 0 (0: chosen from the spectrum of A), got " +
                                fmt(settings.admm_rho));
  switch (settings.warm_start) {
    case WarmStart::kNone:
    case WarmStart::kGiven:
    case WarmStart::kProxQP: break;
    default: throw std::invalid_argument("warm_start: unknown value " + std::to_string(static_cast<int>(settings.warm_start)));
  }
}

void solve(const ContactProblem& original, ContactSolver& solver, const SolverSettings& settings,
           SolverResult& result, const Eigen::VectorXd* guess) {
  using Clock = FastClock;  // the time-stamp counter (clock.hpp)
  validateSettings(settings);
  const auto start = Clock::now();
  auto elapsed = [&]() { return std::chrono::duration<double>(Clock::now() - start).count(); };
  forgetVerdicts();  // A or b may have changed in place since the last solve
  const Eigen::Index m = original.numRows();
  const bool exact = solver.exactLaw();
  // The algorithm's problem and the verdict's (Frames: the same problem unless its scale is extreme).
  const Frames frames(original, solver.rescalable());
  const ContactProblem& problem = *frames.algorithm;
  const int to_algorithm = frames.algorithmExponent();  // lambda' = lambda 2^to_algorithm
  result.resize(m, original.numBlocks());
  result.solver = solver.name();
  result.warm_start_seconds = 0.0;
  result.warm_start_iterations = 0;
  result.iterations = 0;
  clearStages(result.stages);
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
      scaleByPowerOfTwo(result.lam, to_algorithm);
      if (!result.lam.allFinite())
        throw std::invalid_argument("initial lambda is beyond double's range once scaled to the problem (||b|| / "
                                    "max diag A = 2^" + std::to_string(-to_algorithm) + ")");
      break;
    case WarmStart::kProxQP: result.lam.setZero(); break;
  }
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
      addStage(result.stages, solver.name().c_str(), result.iterations,
               std::chrono::duration<double>(Clock::now() - t0).count(), result.message);
  } else {
    result.message = "no algorithm run";
  }

  // Back to the caller's scale: the returned lambda (its entries may leave double's range: then
  // the verdict below says so).
  const bool algorithm_finite = result.lam.allFinite();
  if (exact && to_algorithm != 0) result.divergence_candidates.push_back(result.lam);  // (the algorithm's frame)
  scaleByPowerOfTwo(result.lam, -to_algorithm);
  const bool representable = !algorithm_finite || result.lam.allFinite();

  // The common verdict, whatever the algorithm (verdict.hpp), judged on (A, b 2^-c) at the returned
  // lambda times 2^-c: exactly the natural map of (A, b) at lambda, times 2^-c.
  const ContactProblem& judged = *frames.verdict;
  const int c = frames.c;
  thread_local Eigen::VectorXd lam_v;
  const Eigen::VectorXd* lam_judged = &result.lam;
  if (c != 0) {
    lam_v = result.lam;
    scaleByPowerOfTwo(lam_v, -c);
    lam_judged = &lam_v;
  }
  const Eigen::VectorXd& lam = *lam_judged;
  // (u as the stopping test's last verdict computed it when it judged this lambda.)
  if (!lastVerdictResidual(judged, lam, result.u)) {
    judged.delassus().multiply(lam, result.u);
    result.u -= judged.b();
  }
  const double scale = stoppingScale(judged);
  const double threshold = settings.tolerance * scale;
  VerdictMeasures measures;
  measureVerdict(judged, lam, measures, threshold);
  const double b_norm = original.bNorm();
  result.relative_residual = measures.natural_map / scale;
  result.residual = c == 0 ? measures.natural_map / (1.0 + b_norm) : result.relative_residual * (b_norm / (1.0 + b_norm));
  result.residual_bound = measures.bound / scale;
  result.precision_floor = measures.floor / scale;
  result.lambda_norm = safeNorm(result.lam);
  const bool finite = std::isfinite(measures.natural_map) && std::isfinite(measures.bound) && lam.allFinite();
  if (finite && measures.natural_map + measures.bound <= threshold) {
    result.status = SolveStatus::kConverged;
  } else if (!exact) {
    // Another law than the exact one: its own verdict is in own_*; say how far the exact law is,
    // and whether double precision can tell at this lambda (as below: the floor).
    const bool resolvable = finite && !(measures.floor > kFloorMargin * threshold);
    result.status = resolvable ? SolveStatus::kNotConverged : SolveStatus::kUnresolvable;
    result.message += std::string(result.message.empty() ? "" : "; ") + "exact-law residual " +
                      fmt(result.relative_residual) + " x ||b||";
    if (!resolvable)
      result.message += finite ? " (not resolvable in double precision: rounding lambda alone moves it by up to " +
                                     fmt(result.precision_floor) + " x ||b||)"
                               : " (not finite in double precision)";
  } else {
    std::string why = result.message;
    if (startsWith(why, "converged")) why = "residual above tolerance " + why.substr(std::min<std::size_t>(10, why.size()));
    // (certificates on the algorithm's problem: scaled to unit diagonal and ||b||, their directions
    // and norms are free of A's and b's magnitudes)
    if (to_algorithm == 0) result.divergence_candidates.push_back(result.lam);
    const InfeasibilityCertificate cert = findInfeasibility(problem, result.divergence_candidates);
    result.min_solution_norm = std::ldexp(cert.min_solution_norm, -to_algorithm);
    if (beyondPrecision(problem, cert.min_solution_norm)) {
      result.status = SolveStatus::kInfeasible;
      result.implicated_blocks = cert.blocks;
      result.message = std::isinf(cert.min_solution_norm)
                           ? "no solution: b pushes block(s) " + blockList(original, cert.blocks) +
                                 " closed along a direction A does not resist (a contact on something "
                                 "that cannot move, or contacts pushing against each other); lambda would "
                                 "grow without bound"
                           : "no solution of a size double precision can verify: every solution has "
                             "||lambda|| >= " + fmt(result.min_solution_norm) + " (b pushes block(s) " +
                                 blockList(original, cert.blocks) + " along a direction A barely resists)";
      result.message += " [" + why + "]";
    } else if (!finite || measures.floor > kFloorMargin * threshold) {
      result.status = SolveStatus::kUnresolvable;
      // the blocks whose lambda's rounding moves the residual most
      measureVerdict(judged, lam, measures, threshold, /*per_block=*/true);
      double worst = 0.0;
      for (double e : measures.block_floor) worst = std::max(worst, e);
      for (std::size_t i = 0; i < measures.block_floor.size(); ++i)
        if (measures.block_floor[i] >= 0.1 * worst && worst > 0.0)
          result.implicated_blocks.push_back(static_cast<int>(i));
      if (!representable) {
        result.message = "lambda is beyond double's range at this problem's scale (the algorithm solved it "
                         "scaled by powers of two: ||b|| / max diag A = 2^" + std::to_string(-to_algorithm) + ")";
      } else if (!finite) {
        result.message = algorithm_finite && result.lam.allFinite()
                             ? "residual not resolvable in double precision: the natural map mixes lambda (||lambda|| = " +
                                   fmt(result.lambda_norm) + ") and u in one norm, beyond double's range relative "
                                   "to ||b|| = " + fmt(b_norm)
                             : "diverged: non-finite lambda or residual";
      } else {
        result.message = "residual not resolvable in double precision (lambda scale ||lambda|| = " +
                         fmt(result.lambda_norm) + ": rounding lambda alone moves the residual by up to " +
                         fmt(result.precision_floor) + " x ||b||, far above the tolerance " +
                         fmt(settings.tolerance) + "; residual " + fmt(result.relative_residual) + " x ||b||)";
      }
      result.message += " [" + why + "]";
    } else {
      result.status = SolveStatus::kNotConverged;
      result.message = why;
      if (cert.min_solution_norm > 0.0)
        result.message += " (every solution has ||lambda|| >= " + fmt(result.min_solution_norm) + ")";
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
    measureExactLaw(judged, lam, result.exact_law, kRelativeSpeedFloor, &result.u);
    scaleExactLaw(result.exact_law, c, b_norm);
    result.states = result.exact_law.states;  // (classifyStates of the same lambda and u)
  } else {
    classifyStates(judged, lam, result.u, result.states);
  }
  result.exact_law_measured = settings.measure_exact_law;
  scaleByPowerOfTwo(result.u, c);
  forgetVerdicts();  // nothing of this solve outlives it (the problems in `frames` die here)
  result.seconds = elapsed();
}

}  // namespace stiction
