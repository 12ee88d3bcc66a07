// Stage 5, the solve: eq. 65 for the Delassus stage's A and b, by the model's formulation
// (the exact law with its solver, or ccp, nakaoka, pyramid, penalty, pinocchio-*), warm-started
// from the previous step; then per-candidate forces and states. Eigen and the solver core only.
#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <string>

#include "stages.hpp"

namespace stiction {
namespace stages {

namespace {

// Forces whose own rounding moves the residual by more than kLooseTolerance (relative
// to ||b||) diverged, whatever the tolerance (verdict.hpp).
constexpr double kDivergedFloor = kLooseTolerance;

// A sticking contact's friction within this fraction of mu lambda_n is on the cone's boundary.
constexpr double kBoundaryMargin = 1e-3;

// The name of block `blk` of the current problem: a candidate contact, then the anchors.
std::string blockName(const SimulatorModel& sim, const SimulatorData& sd, int blk) {
  if (blk < static_cast<int>(sd.active.size())) {
    const int i = sd.active[blk];
    if (sim.slot_pair[i] < 0) return "contact '" + sim.contacts[i].name + "'";
    const int first_slot = static_cast<int>(sim.contacts.size());
    int slot = i - first_slot;
    for (int p = 0; p < sim.slot_pair[i]; ++p) slot -= sim.pairs[p].max_contacts;
    return "contact '" + sim.pairs[sim.slot_pair[i]].name + "#" + std::to_string(slot) + "'";
  }
  return "anchor '" + sim.anchors[blk - sd.active.size()].name + "'";
}

// Why a step cannot go on: the contact problem has no solution, or none double
// precision can resolve; names the contacts involved and t.
std::string unsolvableMessage(const SimulatorModel& sim, const SimulatorData& sd) {
  std::ostringstream os;
  const SolverResult& r = sd.result;
  if (r.status == SolveStatus::kInfeasible)
    os << "the contact problem at t = " << sd.t << " has no solution";
  else if (r.status == SolveStatus::kUnresolvable)
    os << "the contact forces at t = " << sd.t << " diverged beyond what double precision can resolve";
  else
    os << "the contact solve returned non-finite forces at t = " << sd.t;
  std::vector<int> blocks = r.implicated_blocks;
  if (blocks.empty()) {  // the largest forces
    double worst = 0.0;
    for (std::size_t k = 0; k + 1 < sd.problem->offsets().size(); ++k)
      worst = std::max(worst, r.lam.segment(sd.problem->offsets()[k], sd.problem->constraints()[k].size).norm());
    for (std::size_t k = 0; k + 1 < sd.problem->offsets().size(); ++k)
      if (r.lam.segment(sd.problem->offsets()[k], sd.problem->constraints()[k].size).norm() >= 0.1 * worst)
        blocks.push_back(static_cast<int>(k));
  }
  os << " (";
  for (std::size_t k = 0; k < blocks.size(); ++k) os << (k ? ", " : "") << blockName(sim, sd, blocks[k]);
  os << "): " << r.message;
  if (r.status == SolveStatus::kInfeasible)
    os << ". A contact on a body that cannot move (the world, a fixed joint) and starts penetrating, "
          "or a body squeezed between contacts it cannot escape, makes the forces grow without bound.";
  return os.str();
}

}  // namespace

void solveContacts(const SimulatorModel& sim, SimulatorData& sd, double scale) {
  const Eigen::Index rows = sd.rows;
  // (x * 0 sums to 0 exactly unless some x is inf or NaN: a vectorised pass, where allFinite()
  // tested entry by entry, 3 % of a 256-contact tower's step)
  const auto all_finite = [](const double* x, Eigen::Index n) {
    return !std::isnan((Eigen::Map<const Eigen::ArrayXd>(x, n) * 0.0).sum());
  };
  const bool finite_A = sd.sparse ? sd.a_known_finite || all_finite(sd.A_sparse.valuePtr(), sd.A_sparse.nonZeros())
                                  : all_finite(sd.A.data(), sd.A.size());
  if (!finite_A || !sd.b.allFinite())
    throw std::runtime_error("simulation diverged: non-finite Delassus operator or right-hand side at t = " +
                             std::to_string(sd.t));
  const auto constraints = [&] {
    std::vector<Constraint> cons;
    for (int i : sd.active)
      switch (sd.candidate_rows[i]) {
        case 1: cons.push_back(Constraint::unilateral()); break;
        case 2: cons.push_back(Constraint::planarFriction(candidateMu(sim, i))); break;
        default: cons.push_back(Constraint::spatialFriction(candidateMu(sim, i)));
      }
    for (std::size_t a = 0; a < sim.anchors.size(); ++a) cons.push_back(Constraint::bilateral(3));
    return cons;
  };
  const bool same_blocks = sd.problem && sd.active == sd.problem_active;
  if (sd.sparse && same_blocks && sd.sparse_delassus && sd.operator_pattern_version == sd.pattern_version &&
      sd.sparse_delassus->swapValues(sd.A_sparse)) {
    // the pattern the operator was built with (A assembled by its plan since): the new values
    // change places with the old, no copy (denseDelassus reads them from the operator)
    sd.a_in_operator = true;
    sd.b_scaled = scale * sd.b;
    sd.problem->setB(sd.b_scaled);
  } else if (sd.sparse && same_blocks && sd.sparse_delassus && sd.sparse_delassus->assignValues(sd.A_sparse)) {
    sd.b_scaled = scale * sd.b;  // same contacts, same pattern: new values in place, no allocation
    sd.problem->setB(sd.b_scaled);
  } else if (sd.sparse) {  // a new pattern: the contacts changed
    sd.delassus.reset();
    sd.sparse_delassus = std::make_shared<SparseDelassus>(sd.A_sparse, /*symmetric=*/true);
    sd.operator_pattern_version = sd.pattern_version;
    sd.problem = std::make_unique<ContactProblem>(sd.sparse_delassus, scale * sd.b, constraints(), 1e-6, false);
    sd.problem_active = sd.active;
  } else if (!same_blocks || !sd.delassus) {
    sd.sparse_delassus.reset();
    sd.delassus = std::make_shared<DenseDelassus>(sd.A);
    sd.problem = std::make_unique<ContactProblem>(sd.delassus, scale * sd.b, constraints(), 1e-6, false);
    sd.problem_active = sd.active;
  } else {
    sd.delassus->matrix() = sd.A;
    sd.b_scaled = scale * sd.b;
    sd.problem->setB(sd.b_scaled);
  }
  SolverSettings settings = sim.settings.solver_settings;
  // (the exact-law measures of a step's answer when its result is read: get_result, Python)
  settings.measure_exact_law = false;
  const bool exact = sd.solver->exactLaw();
  sd.guess.resize(rows);
  bool any = false;
  Eigen::Index row = 0;
  for (int i : sd.active) {
    const int k = sd.candidate_rows[i];
    if (sd.have_candidate_lambda[i]) {
      any = true;
      fromSlots(scale * sd.candidate_lambda.col(i), k, sd.guess.data() + row);
      // A contact that stuck with its friction on the cone's boundary holds forces its body does not
      // need (a resting cube's corners squeezing the ground at mu lambda_n, as Gauss-Seidel leaves
      // them: they lie in A's null space). Its guess starts without them, inside the cone, so the
      // solver's sticking step applies (docs/solvers.md); the part of the friction the body needs is
      // in A's range and comes back with the first step.
      // (The exact law's cone only: the other formulations keep their guess as it was.)
      if (exact && k > 1 && sd.candidate_states[i] == ContactState::kStick) {
        const auto tangent = sd.guess.segment(row, k - 1);
        if (tangent.norm() >= (1.0 - kBoundaryMargin) * candidateMu(sim, i) * sd.guess[row + k - 1])
          sd.guess.segment(row, k - 1).setZero();
      }
    } else {
      sd.guess.segment(row, k).setZero();
    }
    row += k;
  }
  for (std::size_t a = 0; a < sim.anchors.size(); ++a, row += 3) {
    sd.guess.segment<3>(row) = scale * sd.anchor_lambda.col(a);
    any = any || sd.anchor_lambda.col(a).squaredNorm() > 0.0;
  }
  settings.warm_start = sim.settings.warm_start && any ? WarmStart::kGiven : WarmStart::kNone;
  if (!exact) {  // what the other formulations may know of the step (formulation.hpp)
    StepContext context;
    context.h = scale;
    context.position_error = &sd.position_error;
    sd.spring_rows.setZero(rows);
    row = 0;
    for (int i : sd.active) {
      const int k = sd.candidate_rows[i];
      if (k > 1) fromSlots(sd.candidate_spring.col(i), k, sd.spring_rows.data() + row);
      sd.spring_rows[row + k - 1] = 0.0;
      row += k;
    }
    context.state = &sd.spring_rows;
    setFormulationContext(*sd.solver, context);
  }
  solve(*sd.problem, *sd.solver, settings, sd.result, &sd.guess);
  int solve_iterations = sd.result.iterations;
  // A retry's verdict replaces the first when it converged, or missed by less.
  const auto better = [&](const SolverResult& retry) {
    return retry.converged || (retry.status == SolveStatus::kNotConverged && retry.residual < sd.result.residual);
  };
  if (exact && settings.warm_start == WarmStart::kGiven && sd.result.status == SolveStatus::kNotConverged) {
    // The previous step's impulses can lead the pipeline into a stall (measured: a 1e6 : 1 stack at
    // dt = 0.1 ms, Newton stalls from the warm start and ADMM runs out of budget on 58 of 5000 steps);
    // the same problem from zero converges. Keep whichever verdict is better. Where every step misses
    // (1e-10 on that stack) the retry doubles the cost of a missed step but keeps the residual at 1e-12
    // where the warm-started best iterate reached 0.13.
    settings.warm_start = WarmStart::kNone;
    solve(*sd.problem, *sd.solver, settings, sd.cold_result, nullptr);
    solve_iterations += sd.cold_result.iterations;
    if (better(sd.cold_result)) std::swap(sd.result, sd.cold_result);
  }
  if (exact && sd.result.status == SolveStatus::kNotConverged) {
    // b may ask what no lambda can give: contacts between the same two bodies beyond their 6
    // relative degrees of freedom, whose normal drift and gap terms do not fit one rigid motion
    // (pile-24: a tilted box's 4 corners, 4e-9 ||b|| out of J's range). That part removed, solve
    // again from this answer; keep whichever verdict is better.
    sd.b_before_projection = sd.b;
    projectRedundantSets(sim, sd);
    if (sd.inconsistent_groups > 0) {
      sd.b_scaled = scale * sd.b;
      sd.problem->setB(sd.b_scaled);
      settings.warm_start = WarmStart::kGiven;
      sd.guess = sd.result.lam;
      solve(*sd.problem, *sd.solver, settings, sd.cold_result, &sd.guess);
      solve_iterations += sd.cold_result.iterations;
      if (better(sd.cold_result)) {
        std::swap(sd.result, sd.cold_result);
      } else {  // the answer kept is the original problem's: so is b
        sd.b = sd.b_before_projection;
        sd.b_scaled = scale * sd.b;
        sd.problem->setB(sd.b_scaled);
        sd.inconsistent_groups = 0;
      }
    }
  }
  // Infeasible, or forces so large that not even a loose 1e-6 could be verified: the
  // step cannot go on. (An unreachable tolerance such as 1e-300 is also "unresolvable",
  // with a tiny floor: that step is only recorded as unconverged.)
  // Other formulations are only measured by the exact law: they stop on non-finite impulses.
  if (sd.result.status == SolveStatus::kInfeasible || !sd.result.lam.allFinite() ||
      (exact && sd.result.status == SolveStatus::kUnresolvable && sd.result.precision_floor > kDivergedFloor))
    throw std::runtime_error(unsolvableMessage(sim, sd));
  // Per-candidate forces (lambda / scale) and states.
  sd.lambda = sd.result.lam / scale;
  for (int i = 0; i < sim.numCandidates(); ++i) {
    sd.candidate_lambda.col(i).setZero();
    sd.candidate_spring.col(i).setZero();
    sd.have_candidate_lambda[i] = false;
    sd.candidate_states[i] = ContactState::kOpen;
  }
  row = 0;
  for (std::size_t blk = 0; blk < sd.active.size(); ++blk) {
    const int i = sd.active[blk];
    const int k = sd.candidate_rows[i];
    if (!exact && k > 1) sd.candidate_spring.col(i) = toSlots(sd.spring_rows.data() + row, k);
    sd.candidate_lambda.col(i) = toSlots(sd.lambda.data() + row, k);
    sd.have_candidate_lambda[i] = true;
    sd.candidate_states[i] = sd.result.states[blk];
    row += k;
  }
  for (std::size_t a = 0; a < sim.anchors.size(); ++a, row += 3)
    sd.anchor_lambda.col(a) = sd.lambda.segment<3>(row);
  ++sd.solves;
  sd.max_residual_step = std::max(sd.max_residual_step, sd.result.residual);
  sd.all_converged_step = sd.all_converged_step && sd.result.own_converged;
  sd.iterations_step += solve_iterations;
}

}  // namespace stages
}  // namespace stiction
