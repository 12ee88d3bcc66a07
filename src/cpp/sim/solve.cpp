// Stage 5, the solve: eq. 65 for the Delassus stage's A and b, by the model's formulation
// (the exact law with its solver, or ccp, nakaoka, pyramid, penalty, pinocchio-*), warm-started
// from the previous step; then per-candidate forces and states. Eigen and the solver core only.
#include <algorithm>
#include <cmath>
#include <cstdlib>
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
  if (blk < static_cast<int>(sd.out.active.size())) {
    const int i = sd.out.active[blk];
    if (sim.slot_pair[i] < 0) return "contact '" + sim.contacts[i].name + "'";
    const int first_slot = static_cast<int>(sim.contacts.size());
    int slot = i - first_slot;
    for (int p = 0; p < sim.slot_pair[i]; ++p) slot -= sim.pairs[p].max_contacts;
    return "contact '" + sim.pairs[sim.slot_pair[i]].name + "#" + std::to_string(slot) + "'";
  }
  const std::size_t anchor = static_cast<std::size_t>(blk) - sd.out.active.size();
  if (anchor < sim.anchors.size()) return "anchor '" + sim.anchors[anchor].name + "'";
  return jointRowName(sim, sd, anchor - sim.anchors.size());
}

// Why a step cannot go on: the contact problem has no solution, or none double
// precision can resolve; names the contacts involved and t.
std::string unsolvableMessage(const SimulatorModel& sim, const SimulatorData& sd) {
  std::ostringstream os;
  const SolverResult& r = sd.out.result;
  if (r.status == SolveStatus::kInfeasible)
    os << "the contact problem at t = " << sd.t << " has no solution";
  else if (r.status == SolveStatus::kUnresolvable)
    os << "the contact forces at t = " << sd.t << " diverged beyond what double precision can resolve";
  else
    os << "the contact solve returned non-finite forces at t = " << sd.t;
  std::vector<int> blocks = r.implicated_blocks;
  if (blocks.empty()) {  // the largest forces
    double worst = 0.0;
    for (std::size_t k = 0; k + 1 < sd.work->problem->offsets().size(); ++k)
      worst = std::max(worst, r.lam.segment(sd.work->problem->offsets()[k], sd.work->problem->constraints()[k].size).norm());
    for (std::size_t k = 0; k + 1 < sd.work->problem->offsets().size(); ++k)
      if (r.lam.segment(sd.work->problem->offsets()[k], sd.work->problem->constraints()[k].size).norm() >= 0.1 * worst)
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

// Islands on unless STICTION_ISLANDS=0 (read at each call: cheap, and A/B runs flip it in one process).
bool islandsEnabled() {
  const char* v = std::getenv("STICTION_ISLANDS");
  return v == nullptr || std::string(v) != "0";
}

}  // namespace

void setStepProblem(const SimulatorModel& sim, SimulatorData& sd, double scale) {
  // (x * 0 sums to 0 exactly unless some x is inf or NaN: a vectorised pass, where allFinite()
  // tested entry by entry, 3 % of a 256-contact tower's step)
  const auto all_finite = [](const double* x, Eigen::Index n) {
    return !std::isnan((Eigen::Map<const Eigen::ArrayXd>(x, n) * 0.0).sum());
  };
  const bool finite_A = sd.out.sparse ? sd.work->a_known_finite || all_finite(sd.out.A_sparse.valuePtr(), sd.out.A_sparse.nonZeros())
                                  : all_finite(sd.out.A.data(), sd.out.A.size());
  if (!finite_A || !sd.out.b.allFinite())
    throw std::runtime_error("simulation diverged: non-finite Delassus operator or right-hand side at t = " +
                             std::to_string(sd.t));
  const auto constraints = [&] {
    std::vector<Constraint> cons;
    appendContactConstraints(sim, sd, cons);
    for (std::size_t a = 0; a < sim.anchors.size(); ++a) cons.push_back(Constraint::bilateral(3));
    for (std::size_t k = 0; k < sd.out.joint_rows.size(); ++k) cons.push_back(jointRowConstraint(sim, sd, k, scale));
    return cons;
  };
  // (a joint row's bounds are h tau: the same while its kind, coordinate and h are; ODE modes scale 1)
  const bool same_blocks = sd.work->problem && sd.out.active == sd.work->problem_active &&
                           sd.out.joint_rows == sd.work->problem_joint_rows && sd.work->problem_scale == scale;
  if (sd.out.sparse && same_blocks && sd.work->sparse_delassus && sd.work->operator_pattern_version == sd.work->pattern_version &&
      sd.work->sparse_delassus->swapValues(sd.out.A_sparse)) {
    // the pattern the operator was built with (A assembled by its plan since): the new values
    // change places with the old, no copy (denseDelassus reads them from the operator)
    sd.work->a_in_operator = true;
    sd.work->b_scaled = scale * sd.out.b;
    sd.work->problem->setB(sd.work->b_scaled);
  } else if (sd.out.sparse && same_blocks && sd.work->sparse_delassus && sd.work->sparse_delassus->assignValues(sd.out.A_sparse)) {
    sd.work->b_scaled = scale * sd.out.b;  // same contacts, same pattern: new values in place, no allocation
    sd.work->problem->setB(sd.work->b_scaled);
  } else if (sd.out.sparse) {  // a new pattern: the contacts changed
    sd.work->delassus.reset();
    sd.work->sparse_delassus = std::make_shared<SparseDelassus>(sd.out.A_sparse, /*symmetric=*/true);
    sd.work->operator_pattern_version = sd.work->pattern_version;
    sd.work->problem = std::make_unique<ContactProblem>(sd.work->sparse_delassus, scale * sd.out.b, constraints(), 1e-6, false);
    ++sd.work->problem_version;
    sd.work->problem_active = sd.out.active;
    sd.work->problem_joint_rows = sd.out.joint_rows;
    sd.work->problem_scale = scale;
  } else if (!same_blocks || !sd.work->delassus) {
    sd.work->sparse_delassus.reset();
    sd.work->delassus = std::make_shared<DenseDelassus>(sd.out.A);
    sd.work->problem = std::make_unique<ContactProblem>(sd.work->delassus, scale * sd.out.b, constraints(), 1e-6, false);
    ++sd.work->problem_version;
    sd.work->problem_active = sd.out.active;
    sd.work->problem_joint_rows = sd.out.joint_rows;
    sd.work->problem_scale = scale;
  } else {
    sd.work->delassus->matrix() = sd.out.A;
    sd.work->b_scaled = scale * sd.out.b;
    sd.work->problem->setB(sd.work->b_scaled);
  }
}

bool stepGuess(const SimulatorModel& sim, SimulatorData& sd, double scale, bool exact) {
  const Eigen::Index rows = sd.out.rows;
  sd.work->guess.resize(rows);
  bool any = false;
  Eigen::Index row = 0;
  for (int i : sd.out.active) {
    const int k = sd.out.candidate_rows[i];
    if (sd.out.have_candidate_lambda[i]) {
      any = true;
      fromSlots(scale * sd.out.candidate_lambda.col(i), k, sd.work->guess.data() + row);
      // A contact that stuck with its friction on the cone's boundary holds forces its body does not
      // need (a resting cube's corners squeezing the ground at mu lambda_n, as Gauss-Seidel leaves
      // them: they lie in A's null space). Its guess starts without them, inside the cone, so the
      // solver's sticking step applies (docs/solvers.md); the part of the friction the body needs is
      // in A's range and comes back with the first step.
      // (The exact law's cone only: the other formulations keep their guess as it was.)
      if (exact && k > 1 && sd.out.candidate_states[i] == ContactState::kStick) {
        const auto tangent = sd.work->guess.segment(row, k - 1);
        if (tangent.norm() >= (1.0 - kBoundaryMargin) * candidateMu(sim, i) * sd.work->guess[row + k - 1])
          sd.work->guess.segment(row, k - 1).setZero();
      }
    } else {
      sd.work->guess.segment(row, k).setZero();
    }
    row += k;
  }
  for (std::size_t a = 0; a < sim.anchors.size(); ++a, row += 3) {
    sd.work->guess.segment<3>(row) = scale * sd.out.anchor_lambda.col(a);
    any = any || sd.out.anchor_lambda.col(a).squaredNorm() > 0.0;
  }
  for (std::size_t k = 0; k < sd.out.joint_rows.size(); ++k, ++row) {
    sd.work->guess[row] = jointRowGuess(sim, sd, k, scale);
    any = any || sd.work->guess[row] != 0.0;
  }
  return any;
}

void recordSolution(const SimulatorModel& sim, SimulatorData& sd, double scale, int solve_iterations) {
  const bool exact = sd.work->solver->exactLaw();
  Eigen::Index row = 0;
  // Infeasible, or forces so large that not even a loose 1e-6 could be verified: the
  // step cannot go on. (An unreachable tolerance such as 1e-300 is also "unresolvable",
  // with a tiny floor: that step is only recorded as unconverged.)
  // Other formulations are only measured by the exact law: they stop on non-finite impulses.
  if (sd.out.result.status == SolveStatus::kInfeasible || !sd.out.result.lam.allFinite() ||
      (exact && sd.out.result.status == SolveStatus::kUnresolvable && sd.out.result.precision_floor > kDivergedFloor))
    throw std::runtime_error(unsolvableMessage(sim, sd));
  // A joint's box row that slips (friction sliding, an actuator saturated) holds its bound exactly, as
  // the law says (eq. 65: u != 0 only at a bound); the solver leaves it within its tolerance of it (a
  // saturated actuator read 2.69999888 of 2.7 N m). Its impulse is set on the bound: a projection onto
  // C that moves lambda by less than the tolerance and makes the recorded torque the limit itself.
  if (!sd.out.joint_rows.empty() && sd.work->problem && !sd.work->locked.pending_full &&
      sd.out.result.states.size() == sd.work->problem->numBlocks()) {
    const std::size_t first_block = sd.out.active.size() + sim.anchors.size();
    const auto& cons = sd.work->problem->constraints();
    const auto& offsets = sd.work->problem->offsets();
    for (std::size_t blk = first_block; blk < cons.size(); ++blk) {
      if (cons[blk].kind != ConstraintKind::kBox || sd.out.result.states[blk] != ContactState::kSlip) continue;
      const Eigen::Index r = offsets[blk];
      sd.out.result.lam[r] = sd.out.result.u[r] < 0.0 ? cons[blk].upper : cons[blk].lower;
    }
  }
  // Per-candidate forces (lambda / scale) and states.
  sd.out.lambda = sd.out.result.lam / scale;
  for (int i = 0; i < sim.numCandidates(); ++i) {
    sd.out.candidate_lambda.col(i).setZero();
    sd.out.candidate_spring.col(i).setZero();
    sd.out.have_candidate_lambda[i] = false;
    sd.out.candidate_states[i] = ContactState::kOpen;
  }
  row = 0;
  for (std::size_t blk = 0; blk < sd.out.active.size(); ++blk) {
    const int i = sd.out.active[blk];
    const int k = sd.out.candidate_rows[i];
    if (!exact && k > 1) sd.out.candidate_spring.col(i) = toSlots(sd.work->spring_rows.data() + row, k);
    sd.out.candidate_lambda.col(i) = toSlots(sd.out.lambda.data() + row, k);
    sd.out.have_candidate_lambda[i] = true;
    sd.out.candidate_states[i] = sd.out.result.states[blk];
    row += k;
  }
  for (std::size_t a = 0; a < sim.anchors.size(); ++a, row += 3)
    sd.out.anchor_lambda.col(a) = sd.out.lambda.segment<3>(row);
  ++sd.out.solves;
  sd.out.max_residual_step = std::max(sd.out.max_residual_step, sd.out.result.residual);
  sd.out.all_converged_step = sd.out.all_converged_step && sd.out.result.own_converged;
  sd.out.iterations_step += solve_iterations;
  // The friction rows that are their coordinate's only row all holding: the next step tries those
  // joints locked first (locked_joints.cpp)
  const std::size_t first_joint_block = sd.out.active.size() + sim.anchors.size();
  bool held = exact && sd.out.result.states.size() == first_joint_block + sd.out.joint_rows.size();
  std::vector<int>& rows_on = sd.work->locked.rows_on;
  rows_on.assign(static_cast<std::size_t>(sim.model.nv), 0);
  for (const JointRow& r : sd.out.joint_rows) ++rows_on[static_cast<std::size_t>(r.dof)];
  bool any_lockable = false;
  for (std::size_t k = 0; held && k < sd.out.joint_rows.size(); ++k) {
    const JointRow& r = sd.out.joint_rows[k];
    if (r.kind != JointRowKind::kFriction || rows_on[static_cast<std::size_t>(r.dof)] != 1) continue;
    any_lockable = true;
    held = sd.out.result.states[first_joint_block + k] == ContactState::kStick;
  }
  held = held && any_lockable;
  sd.work->locked.held = held;
}

void solveContacts(const SimulatorModel& sim, SimulatorData& sd, double scale) {
  const Eigen::Index rows = sd.out.rows;
  setStepProblem(sim, sd, scale);
  SolverSettings settings = sim.settings.solver_settings;
  // (the exact-law measures of a step's answer when its result is read: get_result, Python)
  settings.measure_exact_law = false;
  const bool exact = sd.work->solver->exactLaw();
  bool any = stepGuess(sim, sd, scale, exact);
  Eigen::Index row = 0;
  settings.warm_start = sim.settings.warm_start && any ? WarmStart::kGiven : WarmStart::kNone;
  if (!exact) {  // what the other formulations may know of the step (formulation.hpp)
    StepContext context;
    context.h = scale;
    context.position_error = &sd.out.position_error;
    sd.work->spring_rows.setZero(rows);
    row = 0;
    for (int i : sd.out.active) {
      const int k = sd.out.candidate_rows[i];
      if (k > 1) fromSlots(sd.out.candidate_spring.col(i), k, sd.work->spring_rows.data() + row);
      sd.work->spring_rows[row + k - 1] = 0.0;
      row += k;
    }
    context.state = &sd.work->spring_rows;
    setFormulationContext(*sd.work->solver, context);
  }
  // Independent islands (bodies resting apart share no row of A) solved one by one, the whole
  // problem judged at their answer (islands.hpp); else, or where that misses, the whole problem.
  // (STICTION_ISLANDS=0: the whole problem only, for A/B timing.)
  bool by_islands = false;
  if (exact && sd.out.sparse && islandsEnabled()) {
    if (!sd.work->islands) sd.work->islands = std::make_unique<IslandSolver>(sim.settings.solver);
    by_islands = sd.work->islands->solve(*sd.work->problem, settings, sd.out.result,
                                         settings.warm_start == WarmStart::kGiven ? &sd.work->guess : nullptr,
                                         sd.work->problem_version);
  }
  if (!by_islands) solve(*sd.work->problem, *sd.work->solver, settings, sd.out.result, &sd.work->guess);
  int solve_iterations = sd.out.result.iterations;
  // A retry's verdict replaces the first when it converged, or missed by less.
  const auto better = [&](const SolverResult& retry) {
    return retry.converged || (retry.status == SolveStatus::kNotConverged && retry.residual < sd.out.result.residual);
  };
  if (exact && settings.warm_start == WarmStart::kGiven && sd.out.result.status == SolveStatus::kNotConverged) {
    // The previous step's impulses can lead the pipeline into a stall (measured: a 1e6 : 1 stack at
    // dt = 0.1 ms, Newton stalls from the warm start and ADMM runs out of budget on 58 of 5000 steps);
    // the same problem from zero converges. Keep whichever verdict is better. Where every step misses
    // (1e-10 on that stack) the retry doubles the cost of a missed step but keeps the residual at 1e-12
    // where the warm-started best iterate reached 0.13.
    settings.warm_start = WarmStart::kNone;
    solve(*sd.work->problem, *sd.work->solver, settings, sd.work->cold_result, nullptr);
    solve_iterations += sd.work->cold_result.iterations;
    if (better(sd.work->cold_result)) std::swap(sd.out.result, sd.work->cold_result);
  }
  if (exact && sd.out.result.status == SolveStatus::kNotConverged) {
    // b may ask what no lambda can give: contacts between the same two bodies beyond their 6
    // relative degrees of freedom, whose normal drift and gap terms do not fit one rigid motion
    // (pile-24: a tilted box's 4 corners, 4e-9 ||b|| out of J's range). That part removed, solve
    // again from this answer; keep whichever verdict is better.
    sd.work->b_before_projection = sd.out.b;
    projectRedundantSets(sim, sd);
    if (sd.out.inconsistent_groups > 0) {
      sd.work->b_scaled = scale * sd.out.b;
      sd.work->problem->setB(sd.work->b_scaled);
      settings.warm_start = WarmStart::kGiven;
      sd.work->guess = sd.out.result.lam;
      solve(*sd.work->problem, *sd.work->solver, settings, sd.work->cold_result, &sd.work->guess);
      solve_iterations += sd.work->cold_result.iterations;
      if (better(sd.work->cold_result)) {
        std::swap(sd.out.result, sd.work->cold_result);
      } else {  // the answer kept is the original problem's: so is b
        sd.out.b = sd.work->b_before_projection;
        sd.work->b_scaled = scale * sd.out.b;
        sd.work->problem->setB(sd.work->b_scaled);
        sd.out.inconsistent_groups = 0;
      }
    }
  }
  recordSolution(sim, sd, scale, solve_iterations);
}

}  // namespace stages
}  // namespace stiction
