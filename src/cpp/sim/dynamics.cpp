// Stage 4, the Delassus stage: the mass matrix and its factor, the free acceleration,
// then the contact problem's A = J M^-1 J^T (eq. 22) and b (eq. 27).
#include <stdexcept>
#include <string>

#include <pinocchio/algorithm/cholesky.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>

#include "stages.hpp"

namespace stiction {

void computeControl(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                    const Eigen::VectorXd& v) {
  const JointControl& c = sd.control;
  const int nv = sim.model.nv;
  if (c.kp.size() != nv || c.kd.size() != nv || c.v_target.size() != nv || c.tau_ff.size() != nv ||
      c.q_target.size() != sim.model.nq)
    throw std::invalid_argument("control: kp, kd, v_target, tau_ff need nv = " + std::to_string(nv) +
                                " entries and q_target nq = " + std::to_string(sim.model.nq));
  pinocchio::difference(sim.model, q, c.q_target, sd.dv);  // q_target (-) q, on the manifold
  sd.tau = c.kp.cwiseProduct(sd.dv) + c.kd.cwiseProduct(c.v_target - v) + c.tau_ff;
}

namespace stages {

namespace {

// nle = C(q, v) v + g(q) (Pinocchio's rnea at zero acceleration) from the forward
// kinematics already in `data` (placements, velocities, accelerations at q'' = 0)
// and the world-frame joint Jacobian: the backward pass of rnea, in world
// coordinates, without repeating the forward pass (saves ~1 us on Solo-12).
void nonLinearEffectsFromKinematics(const pinocchio::Model& model, pinocchio::Data& data,
                                    std::vector<pinocchio::Force>& forces, Eigen::VectorXd& nle) {
  const int n = model.njoints;
  forces.resize(n);
  const Eigen::Vector3d minus_g = -model.gravity.linear();
  for (int i = 1; i < n; ++i) {
    const pinocchio::SE3& oMi = data.oMi[i];
    // a_gf = a + gravity seen as an upward acceleration of the base, in frame i
    const pinocchio::Motion a_gf(data.a[i].linear() + oMi.rotation().transpose() * minus_g, data.a[i].angular());
    const pinocchio::Inertia& Y = model.inertias[i];
    const pinocchio::Force f_local = Y * a_gf + data.v[i].cross(Y * data.v[i]);
    forces[i] = oMi.act(f_local);
  }
  for (int i = n - 1; i >= 1; --i) {
    const int nv_i = model.nvs[i], iv = model.idx_vs[i];
    for (int k = iv; k < iv + nv_i; ++k)
      nle[k] = data.J.col(k).head<3>().dot(forces[i].linear()) + data.J.col(k).tail<3>().dot(forces[i].angular());
    const auto parent = model.parents[i];
    if (parent > 0) forces[parent] += forces[i];
  }
}

}  // namespace

void freeDynamics(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                  const Eigen::VectorXd& v, double implicit_pd_step) {
  const pinocchio::Model& model = sim.model;
  pinocchio::Data& data = sd.data;
  // q as Eigen::Ref: the instantiation libpinocchio ships (extern template), not a fresh one
  // here (a VectorXd argument made this file take 55 s to compile instead of 14 s).
  pinocchio::crba(model, data, Eigen::Ref<const Eigen::VectorXd>(q), pinocchio::Convention::LOCAL);
  if (implicit_pd_step > 0.0) {
    // Implicit joint PD over a step h: tau(q+, v+) ~ kp (q_t - q - h v+) + kd (v_t - v+)
    // moves h kd + h^2 kp onto M's diagonal (stable for any gains; MuJoCo's implicitfast
    // does the damping part). The -h kp v part of tau is added below.
    const double h = implicit_pd_step;
    data.M.diagonal() += h * sd.control.kd + h * h * sd.control.kp;
  }
  // M = U D U^T by Pinocchio's tree-sparse Cholesky (cheaper than a dense LLT).
  pinocchio::cholesky::decompose(model, data);
  if (model.nv > 0 && !(data.D.minCoeff() > 0.0))
    throw std::runtime_error("the mass matrix is not positive definite at this configuration");
  nonLinearEffectsFromKinematics(model, data, sd.forces, sd.nle);
  computeControl(sim, sd, q, v);
  if (implicit_pd_step > 0.0) sd.tau -= implicit_pd_step * sd.control.kp.cwiseProduct(v);
  sd.v_free = sd.tau - sd.nle;
  pinocchio::cholesky::solve(model, data, sd.v_free);  // M^-1 (tau - nle): the free acceleration
}

void delassusOperator(SimulatorData& sd) {
  // A = (D^-1/2 U^-1 J^T)^T (D^-1/2 U^-1 J^T): symmetric by construction.
  // (dense triangular solve: cheaper than Pinocchio's per-column Uiv at these sizes)
  const Eigen::Index rows = sd.J.rows();
  sd.W = sd.J.transpose();
  sd.data.U.triangularView<Eigen::UnitUpper>().solveInPlace(sd.W);
  sd.W = sd.data.Dinv.cwiseSqrt().asDiagonal() * sd.W;
  sd.A.resize(rows, rows);
  sd.A.setZero();
  sd.A.selfadjointView<Eigen::Lower>().rankUpdate(sd.W.transpose());
  sd.A.triangularView<Eigen::StrictlyUpper>() = sd.A.transpose();
}

void rightHandSide(SimulatorData& sd, const Eigen::VectorXd& v, double delta, double zeta, bool tangential_drift) {
  // eq. 27 with Phi = nle - tau: b = J M^-1 Phi - J' v - (2 zeta / delta) J v - Psi / delta^2
  sd.b.noalias() = -sd.J * sd.v_free;
  sd.b -= sd.drift;
  sd.b.noalias() -= (2.0 * zeta / delta) * (sd.J * v);
  sd.b -= sd.position_error / (delta * delta);
  // Time stepping drops the J' v term on the tangential rows (the paper allows it, §3.3):
  // a sticking contact then ends the step with exactly zero slip velocity, J_t v+ = 0,
  // instead of -h J_t' v. Normal rows keep it: it predicts the gap. (It is added back
  // rather than left out, as it always was: b's rounding is part of the trajectories.)
  if (!tangential_drift) sd.b += sd.drift.cwiseProduct(sd.tangent_row);
}

}  // namespace stages
}  // namespace stiction
