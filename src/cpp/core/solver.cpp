#include "stiction/solver.hpp"

#include <chrono>
#include <cmath>
#include <stdexcept>

#include "stiction/admm.hpp"
#include "stiction/cone.hpp"
#include "stiction/newton.hpp"
#include "stiction/nsgs.hpp"
#include "stiction/proxqp_warm_start.hpp"

namespace stiction {

void SolverResult::resize(Eigen::Index rows, std::size_t blocks) {
  lam.resize(rows);
  u.resize(rows);
  states.resize(blocks);
}

double naturalMapNorm(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                      const Eigen::Ref<const Eigen::VectorXd>& u) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  double sq = 0.0;
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    const double mu = cons[i].mu;
    switch (cons[i].kind) {
      case ConstraintKind::kBilateral:  // P_C = identity on R^k
        sq += u.segment(o, cons[i].size).squaredNorm();
        break;
      case ConstraintKind::kUnilateral: {
        const double r = lam[o] - std::max(0.0, lam[o] - u[o]);
        sq += r * r;
        break;
      }
      case ConstraintKind::kPlanarFriction: {
        Eigen::Vector2d z(lam[o] - u[o], lam[o + 1] - u[o + 1] - mu * std::abs(u[o]));
        projectPlanarCone(z, mu);
        sq += (lam.segment<2>(o) - z).squaredNorm();
        break;
      }
      case ConstraintKind::kSpatialFriction: {
        Eigen::Vector3d z = lam.segment<3>(o) - u.segment<3>(o);
        z[2] -= mu * norm2(u[o], u[o + 1]);  // De Saxce: u + E s(u), eq. 76-77
        projectSpatialCone(z, mu);
        sq += (lam.segment<3>(o) - z).squaredNorm();
        break;
      }
    }
  }
  return std::sqrt(sq);
}

double residual(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam) {
  if (lam.size() != problem.numRows())
    throw std::invalid_argument("residual: lambda has " + std::to_string(lam.size()) +
                                " entries, the problem has " + std::to_string(problem.numRows()) +
                                " rows");
  Eigen::VectorXd u(lam.size());
  problem.delassus().multiply(lam, u);
  u -= problem.b();
  return naturalMapNorm(problem, lam, u) / (1.0 + problem.b().norm());
}

double stoppingScale(const ContactProblem& problem) {
  const double nb = problem.b().norm();
  return nb > 0.0 ? nb : 1.0;
}

void classifyStates(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                    const Eigen::Ref<const Eigen::VectorXd>& u, std::vector<ContactState>& states) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const Eigen::MatrixXd& A = problem.delassus().dense();
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
    const double a_nn = A(n, n);
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
      a_tt = 0.5 * (A(o, o) + A(o + 1, o + 1));
    } else {
      lt = std::abs(lam[o]);
      ut = std::abs(u[o]);
      a_tt = A(o, o);
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

void solve(const ContactProblem& problem, ContactSolver& solver, const SolverSettings& settings,
           SolverResult& result, const Eigen::VectorXd* guess) {
  using Clock = std::chrono::steady_clock;
  if (!(settings.tolerance > 0.0) || !std::isfinite(settings.tolerance))
    throw std::invalid_argument("solver tolerance must be a positive finite number");
  if (settings.max_iterations < 0) throw std::invalid_argument("max_iterations must be >= 0");
  const auto start = Clock::now();
  const Eigen::Index m = problem.numRows();
  result.resize(m, problem.numBlocks());
  result.solver = solver.name();
  result.warm_start_seconds = 0.0;
  result.warm_start_iterations = 0;
  result.iterations = 0;
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
    case WarmStart::kProxQP: {
      const auto t0 = Clock::now();
      result.warm_start_iterations = proxqpWarmStart(problem, settings, result.lam);
      result.warm_start_seconds = std::chrono::duration<double>(Clock::now() - t0).count();
      break;
    }
  }
  solver.iterate(problem, settings, result);
  // The common verdict, whatever the algorithm.
  problem.delassus().multiply(result.lam, result.u);
  result.u -= problem.b();
  const double map = naturalMapNorm(problem, result.lam, result.u);
  result.residual = map / (1.0 + problem.b().norm());
  result.relative_residual = map / stoppingScale(problem);
  classifyStates(problem, result.lam, result.u, result.states);
  result.converged = std::isfinite(map) && result.relative_residual <= settings.tolerance &&
                     result.lam.allFinite();
  if (!result.converged && result.message == "converged") result.message = "residual above tolerance";
  result.seconds = std::chrono::duration<double>(Clock::now() - start).count();
}

}  // namespace stiction
