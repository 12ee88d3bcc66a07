// Stage 6, integration: time stepping's velocity and configuration update (eq. 70), or
// one step of the relaxed DAI as an ODE (eq. 39 + 64) by RK4 or Bogacki-Shampine 3(2),
// whose right-hand side runs stages 1-5 at every evaluation.
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include <pinocchio/algorithm/joint-configuration.hpp>

#include "stages.hpp"

namespace stiction {
namespace stages {

namespace {

// Free-flyer joints in time stepping. Pinocchio's free-flyer velocity is in the
// body frame; over a step of a spinning body that frame turns by h omega, which
// symplectic Euler would apply to the linear velocity too (a screw motion): a
// rolling ball's centre then leaves the ground by h^2 |omega x v| / 2 per step and
// the position term pulls it back (measured: +-1.5 cm/s normal chatter, 25 % error
// on its acceleration). Instead, within a step the linear velocity is held in the
// frame at the step's start: its derivative gains omega x v (undoing the frame's
// turn that the bias forces contain), the origin moves on the straight line
// p + h R_k v+, and v+ is re-expressed in the new frame. The constraint J(q_k) v+
// and b are unchanged (the drift's omega x v part cancels the added term).
void addFrameTurn(const SimulatorModel& sim, const Eigen::VectorXd& v, double h, Eigen::VectorXd& dv) {
  for (pinocchio::JointIndex j : sim.free_flyers) {
    const int iv = sim.model.idx_vs[j];
    dv.segment<3>(iv) += h * v.segment<3>(iv + 3).cross(v.segment<3>(iv));
  }
}

// out = q (+) h v, free flyers' origins on the straight line p + h R_k v (v is then
// re-expressed in the turned frame, see addFrameTurn).
void integrateConfiguration(const SimulatorModel& sim, const Eigen::VectorXd& q, Eigen::VectorXd& v, double h,
                            Eigen::VectorXd& out) {
  const pinocchio::Model& model = sim.model;
  out.resize(model.nq);
  if (!sim.tree.empty()) {
    // joint by joint with the Lie groups' own operations, as pinocchio::integrate's visitor calls
    // them (the same values, without its dispatch over the joint variant): q + h v, or SE(3)'s
    for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j) {
      const int iq = model.idx_qs[j], iv = model.idx_vs[j];
      if (sim.tree[j].kind != TreeJoint::Kind::kFreeFlyer) {
        for (int k = 0; k < model.nvs[j]; ++k) out[iq + k] = q[iq + k] + h * v[iv + k];
      } else {
        const Eigen::Matrix<double, 6, 1> step = h * v.segment<6>(iv);
        pinocchio::SpecialEuclideanOperationTpl<3, double>().integrate(q.segment<7>(iq), step, out.segment<7>(iq));
      }
    }
  } else {
    pinocchio::integrate(model, q, h * v, out);
  }
  for (pinocchio::JointIndex j : sim.free_flyers) {
    const int iq = model.idx_qs[j], iv = model.idx_vs[j];
    const Eigen::Quaterniond quat(q[iq + 6], q[iq + 3], q[iq + 4], q[iq + 5]);
    out.segment<3>(iq) = q.segment<3>(iq) + h * (quat.toRotationMatrix() * v.segment<3>(iv));
    // R_{k+1} = R_k exp(h omega): the same world vector in the new frame.
    const Eigen::Vector3d rot = h * v.segment<3>(iv + 3);
    const double angle = rot.norm();
    if (angle > 0.0) {
      const Eigen::AngleAxisd turn(angle, rot / angle);
      v.segment<3>(iv) = turn.toRotationMatrix().transpose() * v.segment<3>(iv);
    }
  }
}

// The acceleration of the relaxed DAI (eq. 39 with lambda from eq. 65) at (q, v):
// stages 1-5, then a = M^-1 (tau - nle + J^T lambda).
void acceleration(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                  const Eigen::VectorXd& v, Eigen::VectorXd& a) {
  const double delta = sim.settings.delta > 0.0 ? sim.settings.delta : sim.settings.dt;
  buildContactProblem(sim, sd, q, v, delta, sim.settings.zeta, 0.0);  // stages 1-4, timed
  Stopwatch watch;
  solveContacts(sim, sd, 1.0);
  watch.lap(sd.out.timings.solve);
  a = sd.work->v_free;  // M^-1 (tau - nle)
  if (sd.out.rows > 0) {
    solveJacobianTransposed(sim, sd, sd.out.lambda, sd.work->dv);  // M^-1 J^T lambda
    a += sd.work->dv;
  }
  ++sd.out.rhs_evaluations;
}

}  // namespace

void integrateTimeStep(const SimulatorModel& sim, SimulatorData& sd, double h) {
  sd.work->dv = h * sd.work->v_free;  // h M^-1 (tau - nle)
  addFrameTurn(sim, sd.v, h, sd.work->dv);
  sd.v += sd.work->dv;
  if (sd.out.rows > 0) {  // + M^-1 J^T P (the joints locked: their solve's x, locked_joints.cpp)
    if (sd.work->locked.pending_full) {
      sd.v += sd.work->locked.x;
    } else {
      solveJacobianTransposed(sim, sd, sd.out.result.lam, sd.work->dv);
      sd.v += sd.work->dv;
    }
    // contact velocities J(q_k) v+, in the frame the solve used
    multiplyJacobian(sim, sd, sd.v, sd.work->row_velocity);
  }
  integrateConfiguration(sim, sd.q, sd.v, h, sd.work->q_tmp);  // symplectic: uses v+
  sd.q = sd.work->q_tmp;
  sd.t += h;
  sd.out.last_dt = h;
}

// The classical RK4 tableau and Bogacki-Shampine 3(2) on the configuration's Lie group, as
// Runge-Kutta-Munthe-Kaas methods (H. Munthe-Kaas, "Runge-Kutta methods on Lie groups", BIT 38
// (1998) 92-111, and "High order Runge-Kutta methods on manifolds", Appl. Numer. Math. 29 (1999)
// 115-127; A. Iserles, H. Munthe-Kaas, S. Norsett, A. Zanna, "Lie-group methods", Acta Numerica 9
// (2000) 215-365, sec. 5). Every stage's configuration is q0 (+) Theta_s, Theta_s = h sum_j a_sj k_j
// an increment in the Lie algebra from the step's start q0, and a stage's rate is not its velocity
// V_s but k_s = dexp^-1_{-Theta_s}(V_s): q = q0 exp(Theta) with body velocity V = q^-1 q' gives
// Theta' = V + 1/2 [Theta, V] + 1/12 [Theta, [Theta, V]] + O(Theta^4) (the Bernoulli series with
// ad_{-Theta}, B_3 = 0; an order-p method needs the terms up to ad^(p-2), Munthe-Kaas 1999, so RK4
// all of these and the 3(2) pair the first two).
// Combining the velocities themselves (as before) is exact only where the group commutes (revolute
// and prismatic joints): on a free flyer it left an O(h^3) error per step, order 2 overall
// (observed at dt = 4, 2, 1 ms: RK4 2.0 on a tumbling rod and Solo-12 in the air, 2.1-2.4 on the
// anchored rod; Bogacki-Shampine 2.0; now 4.0 and 3.0: tests/test_ode_order.py, docs/simulator.md).

namespace {

// v x w on each block [u, v] of se(3) (pinocchio's Motion::cross: linear first), se(2) ((vx, vy,
// omega): se(3)'s with z-rotation alone) and so(3); 0 elsewhere. out must not alias u or v.
void lieBracket(const SimulatorModel& sim, const Eigen::VectorXd& u, const Eigen::VectorXd& v, Eigen::VectorXd& out) {
  using Group = SimulatorModel::LieAlgebraJoint::Group;
  out.setZero(u.size());
  for (const SimulatorModel::LieAlgebraJoint& j : sim.non_abelian_joints) {
    const int i = j.idx_v;
    switch (j.group) {
      case Group::kSE3: {
        const Eigen::Vector3d ul = u.segment<3>(i), ua = u.segment<3>(i + 3);
        const Eigen::Vector3d vl = v.segment<3>(i), va = v.segment<3>(i + 3);
        out.segment<3>(i) = ua.cross(vl) + ul.cross(va);
        out.segment<3>(i + 3) = ua.cross(va);
        break;
      }
      case Group::kSE2:
        out[i] = u[i + 1] * v[i + 2] - u[i + 2] * v[i + 1];
        out[i + 1] = u[i + 2] * v[i] - u[i] * v[i + 2];
        out[i + 2] = 0.0;
        break;
      case Group::kSO3:
        out.segment<3>(i) = u.segment<3>(i).cross(v.segment<3>(i));
        break;
    }
  }
}

// k = V + 1/2 [Theta, V] + 1/12 [Theta, [Theta, V]] (see above); k = V where the group commutes.
void configurationRate(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& theta,
                       const Eigen::VectorXd& velocity, Eigen::VectorXd& k) {
  k = velocity;
  if (sim.non_abelian_joints.empty()) return;
  lieBracket(sim, theta, velocity, sd.work->ode_bracket);  // [Theta, V]
  k += 0.5 * sd.work->ode_bracket;
  lieBracket(sim, theta, sd.work->ode_bracket, sd.work->ode_bracket2);  // [Theta, [Theta, V]]
  k += (1.0 / 12.0) * sd.work->ode_bracket2;
}

}  // namespace

void integrateRK4(const SimulatorModel& sim, SimulatorData& sd) {
  const double h = sim.settings.dt;
  auto& V = sd.work->stage_v;
  auto& Acc = sd.work->stage_a;
  auto& K = sd.work->stage_k;
  V.resize(4);
  Acc.resize(4);
  K.resize(4);
  sd.work->ode_q0 = sd.q;
  sd.work->ode_v0 = sd.v;
  sd.work->q_tmp.resize(sim.model.nq);
  static const double c[4] = {0.0, 0.5, 0.5, 1.0};  // classical RK4: a_s,s-1 = c_s, the rest 0
  for (int s = 0; s < 4; ++s) {
    if (s == 0) {
      sd.work->ode_theta.setZero(sim.model.nv);
      sd.work->q_tmp = sd.work->ode_q0;
      V[0] = sd.work->ode_v0;
    } else {
      sd.work->ode_theta = c[s] * h * K[s - 1];
      pinocchio::integrate(sim.model, sd.work->ode_q0, sd.work->ode_theta, sd.work->q_tmp);
      V[s] = sd.work->ode_v0 + c[s] * h * Acc[s - 1];
    }
    acceleration(sim, sd, sd.work->q_tmp, V[s], Acc[s]);
    configurationRate(sim, sd, sd.work->ode_theta, V[s], K[s]);
  }
  Stopwatch watch;
  sd.v = sd.work->ode_v0 + (h / 6.0) * (Acc[0] + 2.0 * Acc[1] + 2.0 * Acc[2] + Acc[3]);
  sd.work->ode_theta = (h / 6.0) * (K[0] + 2.0 * K[1] + 2.0 * K[2] + K[3]);
  pinocchio::integrate(sim.model, sd.work->ode_q0, sd.work->ode_theta, sd.q);
  sd.t += h;
  sd.out.last_dt = h;
  watch.lap(sd.out.timings.integrate);
}

// Bogacki-Shampine 3(2) with error control on (q, v), Munthe-Kaas's way as RK4 above:
// configuration increments are Lie-algebra vectors at the step's start, so the error of q is
// a difference of increments. (The integrator's own work is not timed here: only its
// right-hand sides are.)
void integrateAdaptive(const SimulatorModel& sim, SimulatorData& sd) {
  const SimulatorSettings& s = sim.settings;
  double h = sd.out.next_dt > 0.0 ? std::min(sd.out.next_dt, s.dt) : s.dt;
  auto& V = sd.work->stage_v;
  auto& Acc = sd.work->stage_a;
  auto& K = sd.work->stage_k;
  V.resize(4);
  Acc.resize(4);
  K.resize(4);
  sd.work->ode_q0 = sd.q;
  sd.work->ode_v0 = sd.v;
  sd.work->q_tmp.resize(sim.model.nq);
  sd.work->ode_q3.resize(sim.model.nq);
  const Eigen::VectorXd& q0 = sd.work->ode_q0;
  const Eigen::VectorXd& v0 = sd.work->ode_v0;
  for (int attempt = 0;; ++attempt) {
    if (h < s.min_dt)
      throw std::runtime_error("adaptive integration: step size fell below min_dt at t = " + std::to_string(sd.t));
    V[0] = v0;
    acceleration(sim, sd, q0, V[0], Acc[0]);
    K[0] = V[0];  // (Theta = 0)
    V[1] = v0 + 0.5 * h * Acc[0];
    sd.work->ode_theta = 0.5 * h * K[0];
    pinocchio::integrate(sim.model, q0, sd.work->ode_theta, sd.work->q_tmp);
    acceleration(sim, sd, sd.work->q_tmp, V[1], Acc[1]);
    configurationRate(sim, sd, sd.work->ode_theta, V[1], K[1]);
    V[2] = v0 + 0.75 * h * Acc[1];
    sd.work->ode_theta = 0.75 * h * K[1];
    pinocchio::integrate(sim.model, q0, sd.work->ode_theta, sd.work->q_tmp);
    acceleration(sim, sd, sd.work->q_tmp, V[2], Acc[2]);
    configurationRate(sim, sd, sd.work->ode_theta, V[2], K[2]);
    sd.work->ode_theta3 = h * ((2.0 / 9.0) * K[0] + (1.0 / 3.0) * K[1] + (4.0 / 9.0) * K[2]);
    sd.work->ode_v3 = v0 + h * ((2.0 / 9.0) * Acc[0] + (1.0 / 3.0) * Acc[1] + (4.0 / 9.0) * Acc[2]);
    pinocchio::integrate(sim.model, q0, sd.work->ode_theta3, sd.work->ode_q3);
    V[3] = sd.work->ode_v3;
    acceleration(sim, sd, sd.work->ode_q3, V[3], Acc[3]);
    configurationRate(sim, sd, sd.work->ode_theta3, V[3], K[3]);
    sd.work->ode_theta2 = h * ((7.0 / 24.0) * K[0] + 0.25 * K[1] + (1.0 / 3.0) * K[2] + 0.125 * K[3]);
    sd.work->ode_v2 = v0 + h * ((7.0 / 24.0) * Acc[0] + 0.25 * Acc[1] + (1.0 / 3.0) * Acc[2] + 0.125 * Acc[3]);
    // error per unit of the state, mixed absolute/relative
    const double eq = ((sd.work->ode_theta3 - sd.work->ode_theta2).array() /
                       (s.ode_tolerance * (1.0 + sd.work->ode_theta3.array().abs()))).abs().maxCoeff();
    const double ev =
        ((sd.work->ode_v3 - sd.work->ode_v2).array() / (s.ode_tolerance * (1.0 + sd.work->ode_v3.array().abs()))).abs().maxCoeff();
    const double err = std::max(eq, ev);
    const double factor = err > 0.0 ? std::clamp(0.9 * std::pow(err, -1.0 / 3.0), 0.2, 5.0) : 5.0;
    if (err <= 1.0 && std::isfinite(err)) {
      sd.q = sd.work->ode_q3;
      sd.v = sd.work->ode_v3;
      sd.t += h;
      sd.out.last_dt = h;
      sd.out.next_dt = std::min(s.dt, h * factor);
      return;
    }
    h *= std::isfinite(err) ? factor : 0.2;
  }
}

}  // namespace stages
}  // namespace stiction
