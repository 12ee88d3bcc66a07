// The joints' own rows of the step problem (docs/joint-rows.md): position limits (unilateral), dry
// friction (box |lambda| <= h tau_c) and actuator effort limits (box |lambda| <= h e, the implicit PD
// its compliance), after the contacts and anchors, in the same problem (eq. 65) and the same solvers.
//
// Each row measures one velocity coordinate (J = +-e_dof), so that for a 1-dof joint, whose
// configuration moves as q+ = q + h v+ in time stepping, a limit row's u = J v+ + gap / h >= 0 is
// exactly q+ within the limit, and a friction row's u = v+_dof is the joint's velocity after the step:
// zero while the joint holds (|lambda| < h tau_c), and lambda = -h tau_c sign(v+) while it slides.
#include <algorithm>
#include <cmath>
#include <string>

#include "stages.hpp"

namespace stiction {
namespace stages {

namespace {

// A limit's sides in SimulatorWorkspace::forced_limit and limit_rows (bits per joint limit).
constexpr char kLowerSide = 1, kUpperSide = 2;

}  // namespace

void selectJointRows(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q, const Eigen::VectorXd& v,
                     double implicit_pd_step) {
  computeControl(sim, sd, q, v);  // sd.out.tau = tau_ff + kp (q_t (-) q) + kd (v_t - v)
  SimulatorWorkspace& w = *sd.work;
  std::vector<JointRow>& rows = sd.out.joint_rows;
  rows.clear();
  for (int dof : sim.friction_dofs) rows.push_back({JointRowKind::kFriction, dof, -1});
  // A limit enters within the margin, or when the joint's current speed would carry it there within
  // a step (a fast joint far from its limit keeps its row out until it comes close).
  const double h = sim.settings.dt, margin = sim.settings.joint_limit_margin;
  for (std::size_t i = 0; i < sim.joint_limits.size(); ++i) {
    const JointLimit& l = sim.joint_limits[i];
    const double qj = q[l.idx_q], vj = v[l.idx_v];
    char has = 0;  // (the limit rows this problem has, for finishJointRows's check)
    if (std::isfinite(l.lower) && ((qj - l.lower) - h * std::max(0.0, -vj) < margin || (w.forced_limit[i] & kLowerSide))) {
      rows.push_back({JointRowKind::kLowerLimit, l.idx_v, static_cast<int>(i), qj - l.lower});
      has |= kLowerSide;
    }
    if (std::isfinite(l.upper) && ((l.upper - qj) - h * std::max(0.0, vj) < margin || (w.forced_limit[i] & kUpperSide))) {
      rows.push_back({JointRowKind::kUpperLimit, l.idx_v, static_cast<int>(i), l.upper - qj});
      has |= kUpperSide;
    }
    w.limit_rows[i] = has;
  }
  // Actuators: with the implicit PD, a row for those near saturation (the torque the PD would give at
  // v+ = v, or the last step's); the others' torque is checked after the step (finishJointRows).
  // An explicit PD, or a feed-forward torque alone, is clamped here.
  for (int dof : sim.effort_dofs) {
    const double e = sim.effort_limit[dof];
    const double kp = sd.control.kp[dof], kd = sd.control.kd[dof];
    const double K = kd + implicit_pd_step * kp;
    w.effort_row[static_cast<std::size_t>(dof)] = 0;
    if (implicit_pd_step > 0.0 && K > 0.0) {
      const double c = sd.out.tau[dof] + kd * v[dof];  // tau_ff + kp (q_t - q) + kd v_t
      const double predicted = c - K * v[dof];
      if (w.forced_effort[static_cast<std::size_t>(dof)] || std::abs(predicted) >= 0.5 * e ||
          std::abs(sd.out.actuator_torque[dof]) >= 0.5 * e) {
        rows.push_back({JointRowKind::kEffort, dof, -1});
        w.effort_row[static_cast<std::size_t>(dof)] = 1;
        w.effort_c[dof] = c;
        w.effort_k[dof] = K;
      }
    } else {
      sd.out.tau[dof] = std::clamp(sd.out.tau[dof], -e, e);
    }
  }
  w.control_torque = sd.out.tau;  // (freeDynamics turns sd.out.tau into the step's generalized force)
}

void addActuatorCompliance(SimulatorData& sd, double h) {
  const Eigen::Index first = sd.out.rows - static_cast<Eigen::Index>(sd.out.joint_rows.size());
  for (std::size_t k = 0; k < sd.out.joint_rows.size(); ++k) {
    const JointRow& r = sd.out.joint_rows[k];
    if (r.kind != JointRowKind::kEffort) continue;
    const Eigen::Index row = first + static_cast<Eigen::Index>(k);
    const double K = sd.work->effort_k[r.dof], c = sd.work->effort_c[r.dof];
    if (sd.out.sparse)
      sd.out.A_sparse.coeffRef(row, row) += 1.0 / (h * K);  // (the diagonal is in the pattern: no insertion)
    else
      sd.out.A(row, row) += 1.0 / (h * K);
    sd.out.b[row] += c / (h * K);
  }
}

Constraint jointRowConstraint(const SimulatorModel& sim, const SimulatorData& sd, std::size_t k, double scale) {
  const JointRow& r = sd.out.joint_rows[k];
  switch (r.kind) {
    case JointRowKind::kLowerLimit:
    case JointRowKind::kUpperLimit: return Constraint::unilateral();
    case JointRowKind::kFriction: {
      const double bound = scale * sim.joint_friction[r.dof];
      return Constraint::box(-bound, bound);
    }
    case JointRowKind::kEffort: break;
  }
  const double bound = scale * sim.effort_limit[r.dof];
  return Constraint::box(-bound, bound);
}

namespace {

// A joint on its limit with dry friction can hold a pair of torques that cancel (the limit pushing, the
// friction pulling back: their rows are +-e_dof, one null direction of A): the part of the last step's
// limit and friction torques that cancels, which the warm start leaves out (a gripper resting on its
// limit under its own PD read 0.54 N m of limit torque against 0.54 of friction, from step to step).
double cancellingTorque(const SimulatorOutputs& out, int dof) {
  const double limit = out.limit_torque[dof], friction = out.friction_torque[dof];
  if (limit * friction >= 0.0) return 0.0;
  return std::copysign(std::min(std::abs(limit), std::abs(friction)), limit);
}

}  // namespace

double jointRowGuess(const SimulatorModel& sim, const SimulatorData& sd, std::size_t k, double scale) {
  const JointRow& r = sd.out.joint_rows[k];
  const double squeeze = cancellingTorque(sd.out, r.dof);  // (limit side; the friction's is -squeeze)
  switch (r.kind) {
    case JointRowKind::kLowerLimit: return scale * std::max(0.0, sd.out.limit_torque[r.dof] - squeeze);
    case JointRowKind::kUpperLimit: return scale * std::max(0.0, -(sd.out.limit_torque[r.dof] - squeeze));
    case JointRowKind::kFriction: {
      const double bound = sim.joint_friction[r.dof];
      return scale * std::clamp(sd.out.friction_torque[r.dof] + squeeze, -bound, bound);
    }
    case JointRowKind::kEffort: break;
  }
  const double bound = sim.effort_limit[r.dof];
  return scale * std::clamp(sd.out.actuator_torque[r.dof], -bound, bound);
}

std::string jointRowName(const SimulatorModel& sim, const SimulatorData& sd, std::size_t k) {
  const JointRow& r = sd.out.joint_rows[k];
  const pinocchio::JointIndex j = r.limit >= 0 ? sim.joint_limits[static_cast<std::size_t>(r.limit)].joint
                                               : sim.dof_joint[static_cast<std::size_t>(r.dof)];
  const char* what = r.kind == JointRowKind::kLowerLimit   ? "lower limit"
                     : r.kind == JointRowKind::kUpperLimit ? "upper limit"
                     : r.kind == JointRowKind::kFriction   ? "dry friction"
                                                           : "actuator effort limit";
  return "joint '" + sim.model.names[j] + "' " + what;
}

bool finishJointRows(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v0, double h,
                     double implicit_pd_step) {
  SimulatorWorkspace& w = *sd.work;
  SimulatorOutputs& out = sd.out;
  // The actuators without a row: the control torque of selectJointRows (clamped where explicit); with
  // the implicit PD, at v+: tau_ff + kp (q_t - q - h v+) + kd (v_t - v+).
  out.actuator_torque = w.control_torque;
  if (implicit_pd_step > 0.0)
    for (Eigen::Index i = 0; i < out.actuator_torque.size(); ++i) {
      const double kp = sd.control.kp[i], kd = sd.control.kd[i];
      if (kp != 0.0 || kd != 0.0) out.actuator_torque[i] += kd * (v0[i] - sd.v[i]) - implicit_pd_step * kp * sd.v[i];
    }
  out.friction_torque.setZero();
  out.limit_torque.setZero();
  const Eigen::Index first = out.rows - static_cast<Eigen::Index>(out.joint_rows.size());
  for (std::size_t k = 0; k < out.joint_rows.size(); ++k) {
    const JointRow& r = out.joint_rows[k];
    const double force = out.lambda[first + static_cast<Eigen::Index>(k)];
    switch (r.kind) {
      case JointRowKind::kLowerLimit: out.limit_torque[r.dof] += force; break;
      case JointRowKind::kUpperLimit: out.limit_torque[r.dof] -= force; break;
      case JointRowKind::kFriction: out.friction_torque[r.dof] = force; break;
      case JointRowKind::kEffort: {
        // the impulse within [-h e, h e] divided by h: within [-e, e] up to the division's rounding
        const double e = sim.effort_limit[r.dof];
        out.actuator_torque[r.dof] = std::clamp(force, -e, e);
        break;
      }
    }
  }
  if (h <= 0.0) return true;  // (the ODE modes: no repeated pass)
  // A row the step needed and did not have: a joint past its limit, an actuator past its effort.
  bool complete = true;
  for (std::size_t i = 0; i < sim.joint_limits.size(); ++i) {
    const JointLimit& l = sim.joint_limits[i];
    const double qj = sd.q[l.idx_q];
    if (!(w.limit_rows[i] & kLowerSide) && qj < l.lower) {
      w.forced_limit[i] |= kLowerSide;
      complete = false;
    }
    if (!(w.limit_rows[i] & kUpperSide) && qj > l.upper) {
      w.forced_limit[i] |= kUpperSide;
      complete = false;
    }
  }
  for (int dof : sim.effort_dofs)
    if (!w.effort_row[static_cast<std::size_t>(dof)] && std::abs(out.actuator_torque[dof]) > sim.effort_limit[dof]) {
      w.forced_effort[static_cast<std::size_t>(dof)] = 1;
      complete = false;
    }
  return complete;
}

}  // namespace stages
}  // namespace stiction
