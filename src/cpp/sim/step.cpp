// One step: the stages of stages.hpp in order, with the state checks around them.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "stages.hpp"

namespace stiction {

using namespace stages;

namespace {

// Every quaternion of q a unit one (to 1e-9: integration keeps them within rounding). The
// fused pass and Pinocchio read a quaternion as a rotation without normalising it: a zero or
// scaled one would move the bodies wrongly and without a word. Simulator.set_state normalises.
void checkQuaternions(const SimulatorModel& sim, const SimulatorData& sd) {
  for (const auto& [joint, start] : sim.quaternions) {
    const Eigen::Vector4d x = sd.q.segment<4>(start);
    const double norm = x.norm();
    if (std::abs(norm - 1.0) <= 1e-9) continue;
    std::ostringstream os;
    os.precision(17);
    os << "q: the quaternion (x, y, z, w) of joint '" << sim.model.names[joint] << "' (q[" << start << ".."
       << start + 3 << "]) = (" << x[0] << ", " << x[1] << ", " << x[2] << ", " << x[3] << ") has norm " << norm
       << ", not 1: give a unit quaternion, or set the state with Simulator.set_state (which normalises)";
    throw std::invalid_argument(os.str());
  }
}

// True when every entry of x is finite (gain: and not below 0; -0.0 is 0). On the bits, as
// integers, so that the loop vectorizes without branches (SSE2: add, and, or): x is finite when
// |x| + 2^52 (its exponent field plus one) does not carry into the sign bit, and negative when its
// sign bit is set and |x| != 0. (Comparisons of doubles accumulated into a bool took 3-4 times as
// long: ~150 ns against ~40 ns for Solo-12's nv + nq = 91 values on a loaded machine.)
bool controlValid(const Eigen::VectorXd& x, bool gain) {
  constexpr std::uint64_t kAbs = 0x7FFFFFFFFFFFFFFFull, kExponentOne = 0x0010000000000000ull;
  const std::uint64_t sign = gain ? ~kAbs : 0;
  const double* p = x.data();
  std::uint64_t bad = 0;  // (its sign bit)
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    std::uint64_t u;
    std::memcpy(&u, p + i, sizeof u);
    const std::uint64_t a = u & kAbs;
    bad |= (a + kExponentOne) | (u & sign & (a + kAbs));
  }
  return (bad >> 63) == 0;
}

// The first bad entry of x (controlValid false), named.
[[noreturn]] void throwBadControl(const Eigen::VectorXd& x, const char* name, bool gain, double t) {
  Eigen::Index i = 0;
  while (i + 1 < x.size() && std::isfinite(x[i]) && !(gain && x[i] < 0.0)) ++i;
  std::ostringstream os;
  os << "sim.data." << name << "[" << i << "] is " << x[i] << " at the step from t = " << t << ": "
     << (gain ? "a joint gain must be finite and >= 0" : "a control input must be finite")
     << " (an in-place write into the view sim.data." << name << " is checked here, at the next step)";
  throw std::invalid_argument(os.str());
}

// The control inputs are numpy views (sim.data.tau_ff, ...; docs/simulator.md): a value written in
// place reaches the step unchecked, and a NaN would otherwise surface later as an error naming no
// field ("non-finite Delassus operator", or M not positive definite for a NaN gain). Every value
// finite, and the gains kp, kd >= 0 (the scene schema's range; the implicit PD's h kd + h^2 kp on
// M's diagonal keeps M positive definite only then): nv + nq values, no allocation.
void checkControl(const SimulatorData& sd) {
  const JointControl& c = sd.control;
  if (controlValid(c.kp, true) & controlValid(c.kd, true) & controlValid(c.tau_ff, false) &
      controlValid(c.q_target, false) & controlValid(c.v_target, false))
    return;
  if (!controlValid(c.kp, true)) throwBadControl(c.kp, "kp", true, sd.t);
  if (!controlValid(c.kd, true)) throwBadControl(c.kd, "kd", true, sd.t);
  if (!controlValid(c.tau_ff, false)) throwBadControl(c.tau_ff, "tau_ff", false, sd.t);
  if (!controlValid(c.q_target, false)) throwBadControl(c.q_target, "q_target", false, sd.t);
  throwBadControl(c.v_target, "v_target", false, sd.t);
}

// Statistics to zero, the state's size and the control inputs checked, and at a trajectory's start
// (the first step, or after q, v or t were assigned) the blow-up check's reference.
bool beginStep(const SimulatorModel& sim, SimulatorData& sd) {
  sd.out.timings = StepTimings{};
  sd.out.rhs_evaluations = 0;
  sd.out.solves = 0;
  sd.out.iterations_step = 0;
  sd.out.max_residual_step = 0.0;
  sd.out.all_converged_step = true;
  if (sd.q.size() != sim.model.nq || sd.v.size() != sim.model.nv)
    throw std::invalid_argument("state size: q needs nq = " + std::to_string(sim.model.nq) +
                                " entries and v nv = " + std::to_string(sim.model.nv));
  checkControl(sd);
  const bool first = sd.reference_speed < 0.0;
  if (first) {
    checkQuaternions(sim, sd);
    sd.reference_speed = sim.model.nv > 0 ? sd.v.cwiseAbs().maxCoeff() : 0.0;
    sd.reference_time = sd.t;
    sd.reference_penetration = 0.0;
    sd.work->broad.ready = false;  // a new trajectory: the pool's entries handed out afresh (broad_phase.hpp)
  }
  return first;
}

void checkState(const SimulatorData& sd) {
  if (!sd.q.allFinite() || !sd.v.allFinite()) {
    std::ostringstream os;
    os << "simulation diverged: non-finite state at t = " << sd.t;
    throw std::runtime_error(os.str());
  }
}

// Physically absurd states, relative to the scene: a speed far above what gravity
// could have given since the start (10 (|v_0| + |g| t) + 50, m/s or rad/s), or a
// contact sinking far deeper than the activation distance and its initial depth.
// An explicit integrator past its stability bound, or forces out of control, end here.
void checkBlowUp(const SimulatorModel& sim, const SimulatorData& sd) {
  const pinocchio::Model& model = sim.model;
  const double g = model.gravity.linear().norm();
  const double speed_limit = 10.0 * (sd.reference_speed + g * std::max(0.0, sd.t - sd.reference_time)) + 50.0;
  Eigen::Index k = 0;
  const double speed = model.nv > 0 ? sd.v.cwiseAbs().maxCoeff(&k) : 0.0;
  const char* hint = sim.settings.mode == IntegrationMode::kTimeStepping
                         ? ""
                         : " (ODE mode: is dt small enough for delta? see rk4StableStep)";
  if (speed > speed_limit) {
    const std::string& joint = model.names[sim.dof_joint[static_cast<std::size_t>(k)]];
    std::ostringstream os;
    os << "simulation diverged (blow-up) at t = " << sd.t << ": velocity coordinate " << k << " (joint '" << joint
       << "') reached " << speed << ", above the bound 10 (|v0| + |g| t) + 50 = " << speed_limit << hint;
    throw std::runtime_error(os.str());
  }
  const double depth_limit =
      std::max(0.1, 10.0 * sim.settings.activation_distance) + 10.0 * sd.reference_penetration;
  for (int i : sd.out.active) {
    if (-sd.out.gaps[i] > depth_limit) {
      std::string name = sim.slot_pair[i] < 0 ? sim.contacts[i].name : sim.pairs[sim.slot_pair[i]].name;
      if (sim.slot_pair[i] >= 0 && sim.pairs[sim.slot_pair[i]].dynamic) {  // (which shapes it holds)
        const auto& held = sd.work->broad.geoms[static_cast<std::size_t>(sim.slot_pair[i])];
        name += " (" + sim.geometry.geometryObjects[held[0]].name + "|" + sim.geometry.geometryObjects[held[1]].name + ")";
      }
      std::ostringstream os;
      os << "simulation diverged (blow-up) at t = " << sd.t << ": contact '" << name << "' penetrates " << -sd.out.gaps[i]
         << " m, deeper than the bound " << depth_limit << " m" << hint;
      throw std::runtime_error(os.str());
    }
  }
}

// candidate_velocity from row_velocity (rows t1, t2, n per active candidate; 0 for the others).
void scatterRowVelocities(SimulatorData& sd) {
  sd.out.candidate_velocity.setZero();
  if (sd.out.rows == 0) return;
  Eigen::Index row = 0;
  for (int i : sd.out.active) {
    sd.out.candidate_velocity.col(i) = toSlots(sd.work->row_velocity.data() + row, sd.out.candidate_rows[i]);
    row += sd.out.candidate_rows[i];
  }
}

// The new state finite and not blown up; then the post-step contact velocities J v
// (rows t1, t2, n) per active candidate, with the last Jacobian (time stepping:
// exactly the velocity the solve imposed).
void endStep(const SimulatorModel& sim, SimulatorData& sd, bool first) {
  checkState(sd);
  if (first)
    for (int i : sd.out.active) sd.reference_penetration = std::max(sd.reference_penetration, -sd.out.gaps[i]);
  checkBlowUp(sim, sd);
  if (sd.out.rows > 0 && sim.settings.mode != IntegrationMode::kTimeStepping)
    multiplyJacobian(sim, sd, sd.v, sd.work->row_velocity);
  scatterRowVelocities(sd);
}

}  // namespace

void buildContactProblem(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                         const Eigen::VectorXd& v, double delta, double zeta, double implicit_pd_step) {
  Stopwatch watch;
  forwardKinematics(sim, sd, q, v);
  detectContacts(sim, sd);
  selectJointRows(sim, sd, q, v, implicit_pd_step);
  contactJacobians(sim, sd, v);
  watch.lap(sd.out.timings.kinematics);
  freeDynamics(sim, sd, v, implicit_pd_step);
  delassusOperator(sim, sd);
  rightHandSide(sim, sd, v, delta, zeta);
  if (implicit_pd_step > 0.0) addActuatorCompliance(sd, implicit_pd_step);  // (effort rows, as step())
  watch.lap(sd.out.timings.delassus);
}

void contactsAtState(const SimulatorModel& sim, SimulatorData& sd) {
  if (sd.q.size() != sim.model.nq || sd.v.size() != sim.model.nv)
    throw std::invalid_argument("state size: q needs nq = " + std::to_string(sim.model.nq) +
                                " entries and v nv = " + std::to_string(sim.model.nv));
  // coal warm-starts each pair's GJK from its last answer: keep the step's own history
  std::vector<std::pair<coal::Vec3s, coal::support_func_guess_t>> guesses;
  guesses.reserve(sim.pairs.size());
  const BroadPhaseState broad = sd.work->broad;  // (the pool's entries too)
  for (const GeometryPairContact& g : sim.pairs) {
    if (g.dynamic) {
      guesses.emplace_back();
      continue;
    }
    const coal::CollisionRequest& req = sd.work->geometry_data.collisionRequests[g.pair];
    guesses.emplace_back(req.cached_gjk_guess, req.cached_support_func_guess);
  }
  forwardKinematics(sim, sd, sd.q, sd.v);
  detectContacts(sim, sd);
  selectJointRows(sim, sd, sd.q, sd.v, 0.0);
  contactJacobians(sim, sd, sd.v);
  sd.work->broad = broad;
  for (std::size_t p = 0; p < sim.pairs.size(); ++p) {
    if (sim.pairs[p].dynamic) continue;
    coal::CollisionRequest& req = sd.work->geometry_data.collisionRequests[sim.pairs[p].pair];
    req.cached_gjk_guess = guesses[p].first;
    req.cached_support_func_guess = guesses[p].second;
  }
  if (sd.out.rows > 0) multiplyJacobian(sim, sd, sd.v, sd.work->row_velocity);
  scatterRowVelocities(sd);
}

void step(const SimulatorModel& sim, SimulatorData& sd) {
  const auto start = Clock::now();
  const bool first = beginStep(sim, sd);  // statistics to zero, state size, blow-up reference
  sensorsBeforeStep(sim, sd);             // (the IMU's start state)
  switch (sim.settings.mode) {
    case IntegrationMode::kTimeStepping: {  // eq. 70: delta = h, zeta = 1/2, impulses P = h lambda
      const double h = sim.settings.dt;
      const double pd_step = sim.settings.implicit_pd ? h : 0.0;
      Stopwatch watch(start);  // (beginStep's few ns go to the kinematics)
      forwardKinematics(sim, sd, sd.q, sd.v);  // placements, J' v, joint Jacobians
      detectContacts(sim, sd);                 // gaps, the active set
      // (v0: the applied PD torque at v+ needs it; a repeated pass restarts from (q0, v0, t0))
      const bool repeatable = !sim.joint_limits.empty() || !sim.effort_dofs.empty();
      const double t0 = sd.t;
      sd.work->step_v0 = sd.v;
      if (repeatable) {
        sd.work->step_q0 = sd.q;
        std::fill(sd.work->forced_effort.begin(), sd.work->forced_effort.end(), 0);
        std::fill(sd.work->forced_limit.begin(), sd.work->forced_limit.end(), 0);
      }
      // A pass misses a row only when an actuator without one saturates or a joint without a limit
      // row crosses its limit (joint_rows.cpp): that row is added and the step repeated, at most
      // once per limit side and actuator (rows are only added).
      for (int pass = 0;; ++pass) {
        selectJointRows(sim, sd, sd.q, sd.v, pd_step);  // the control torque, the joints' rows
        contactJacobians(sim, sd, sd.v);                // J, drift J' v, Psi
        watch.lap(sd.out.timings.kinematics);
        freeDynamics(sim, sd, sd.v, pd_step);                              // M = U D U^T, M^-1 (tau - nle)
        rightHandSide(sim, sd, sd.v, h, 0.5, /*tangential_drift=*/false);  // b (eq. 27)
        // the joints' dry friction held at the last step: the contacts with those joints locked first
        if (!solveJointsLocked(sim, sd, h, watch)) {
          delassusOperator(sim, sd);                        // A = J M^-1 J^T
          if (pd_step > 0.0) addActuatorCompliance(sd, h);  // effort rows
          watch.lap(sd.out.timings.delassus);
          solveContacts(sim, sd, h);  // A P - h b in -N(P), by the formulation
          watch.lap(sd.out.timings.solve);
        }
        integrateTimeStep(sim, sd, h);  // v+, then q+
        watch.lap(sd.out.timings.integrate);
        if (finishJointRows(sim, sd, sd.work->step_v0, h, pd_step) || !repeatable) break;
        if (pass > 2 * static_cast<int>(sim.joint_limits.size() + sim.effort_dofs.size()) + 2)
          throw std::logic_error("joint rows: the repeated passes of a step did not settle");  // (cannot happen)
        sd.q = sd.work->step_q0;
        sd.v = sd.work->step_v0;
        sd.t = t0;
      }
      break;
    }
    // The relaxed DAI as an ODE: buildContactProblem and solveContacts at every RHS evaluation.
    case IntegrationMode::kRK4: integrateRK4(sim, sd); break;
    case IntegrationMode::kAdaptive: integrateAdaptive(sim, sd); break;
  }
  // ODE modes: the joints' torques of the last right-hand side (the actuators' explicit, clamped)
  if (sim.settings.mode != IntegrationMode::kTimeStepping) finishJointRows(sim, sd, sd.v, 0.0, 0.0);
  endStep(sim, sd, first);  // finite, not blown up; contact velocities J v
  sensorsAfterStep(sim, sd);  // world contact forces, IMU
  sd.out.timings.total = microseconds(start, Clock::now());
}

}  // namespace stiction
