// Analytic derivatives of one time step (issue 26; docs/simulator.md, "Derivatives of a step").
//
// The step (eq. 70, time stepping, stages.hpp) from (q, v) with the impulse P of eq. 65:
//   v^ = g(q, v, tau) + M~^-1 J^T P,  g = v + h ft(v) + h M~^-1 (tau(q, v) - nle(q, v)),
//   u  = A P + c,  A = J M~^-1 J^T,  c = -h b = J g + h nrm.(drift - J ft) + Psi / h,
// where M~ is M with the implicit PD's h kd + h^2 kp and the damping's h d on its diagonal, ft the
// free flyers' frame turn (omega x v on their linear rows), nrm the normal (and anchor) rows, and the
// output is v+ = v^ with each free flyer's linear velocity re-expressed in its turned frame,
// q+ = q (+) h v^ (free flyers' origins on the straight line, integrate.cpp).
// P solves the De Saxce NCP; at the converged P each contact is in one mode, whose equations
// E(P, u, mu) = 0 hold in a neighbourhood (away from a mode boundary):
//   open:  P_c = 0;   stick: u_c = 0 (anchors too);
//   slide: u_n = 0 and P_t + mu P_n s = 0, s = u_t / |u_t| (P on the cone, opposite to the slip;
//          the De Saxce term mu |u_t| makes u_n + mu |u_t| = mu |u_t|, i.e. u_n = 0).
// The implicit function theorem: (E_P + E_u A) dP = -E_u dc - E_mu dmu, then dv^ = dg + M~^-1 J^T dP.
// The coefficient matrix is singular for redundant contacts (a box's four corners: 12 rows, 6
// coordinates): the minimum-norm dP is taken; J^T dP, hence v+, does not depend on that choice
// where the forward answer's velocity is unique.
#include "stiction/step_derivatives.hpp"

#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/LU>
#include <Eigen/QR>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/kinematics-derivatives.hpp>
#include <pinocchio/algorithm/rnea-derivatives.hpp>

#include "stages.hpp"

namespace stiction {

namespace {

using Mat = Eigen::MatrixXd;
using Vec = Eigen::VectorXd;
using namespace stages;

Eigen::Matrix3d skew(const Eigen::Vector3d& x) {
  Eigen::Matrix3d s;
  s << 0.0, -x.z(), x.y(), x.z(), 0.0, -x.x(), -x.y(), x.x(), 0.0;
  return s;
}

// SO(3)'s right Jacobian: exp(phi + d) = exp(phi) exp(Jr(phi) d) to first order (Pinocchio's Jexp3).
Eigen::Matrix3d rightJacobianSO3(const Eigen::Vector3d& phi) {
  const double t = phi.norm();
  const Eigen::Matrix3d K = skew(phi);
  if (t < 1e-6) return Eigen::Matrix3d::Identity() - 0.5 * K + K * K / 6.0;
  return Eigen::Matrix3d::Identity() - (1.0 - std::cos(t)) / (t * t) * K + (t - std::sin(t)) / (t * t * t) * K * K;
}

// Per part of the world: a Data of its own with Pinocchio's derivative passes at (q0, v0, a = 0).
struct PartPasses {
  std::vector<pinocchio::Data> data;
};

// d/dv (d/dq with wrt_q) of the classical acceleration (world axes) of the material point `at` (joint
// frame) of world joint j at zero joint acceleration, i.e. of J'(q, v) v: 3 x nv in world coordinates
// (0: the world). After computeForwardKinematicsDerivatives at (q, v, 0).
Mat pointAccelerationDv(const SimulatorModel& sim, PartPasses& passes, pinocchio::JointIndex j, const Eigen::Vector3d& at,
                        bool wrt_q = false) {
  Mat out = Mat::Zero(3, sim.model.nv);
  if (j == 0) return out;
  const int s = sim.joint_system[j];
  const SystemModel& part = sim.systems[static_cast<std::size_t>(s)];
  const Eigen::Index n = part.model.nv;
  Eigen::Matrix3Xd v_dq = Eigen::Matrix3Xd::Zero(3, n), a_dq = v_dq, a_dv = v_dq, a_da = v_dq;
  pinocchio::getPointClassicAccelerationDerivatives(part.model, passes.data[static_cast<std::size_t>(s)],
                                                    sim.joint_local[j], pinocchio::SE3(Eigen::Matrix3d::Identity(), at),
                                                    pinocchio::LOCAL_WORLD_ALIGNED, v_dq, a_dq, a_dv, a_da);
  for (Eigen::Index k = 0; k < n; ++k) out.col(part.v_index[static_cast<std::size_t>(k)]) = wrt_q ? a_dq.col(k) : a_dv.col(k);
  return out;
}

// The world velocity of the material point `at` (joint frame) of world joint j: its Jacobian (3 x nv,
// world columns; with_dq: d/dq of its velocity for the velocity of the last
// computeForwardKinematicsDerivatives instead). 0 for the world.
Mat pointVelocityJacobian(const SimulatorModel& sim, PartPasses& passes, pinocchio::JointIndex j, const Eigen::Vector3d& at,
                          bool with_dq) {
  Mat out = Mat::Zero(3, sim.model.nv);
  if (j == 0) return out;
  const int s = sim.joint_system[j];
  const SystemModel& part = sim.systems[static_cast<std::size_t>(s)];
  const Eigen::Index n = part.model.nv;
  Eigen::Matrix3Xd v_dq = Eigen::Matrix3Xd::Zero(3, n), v_dv = v_dq;
  pinocchio::getPointVelocityDerivatives(part.model, passes.data[static_cast<std::size_t>(s)], sim.joint_local[j],
                                         pinocchio::SE3(Eigen::Matrix3d::Identity(), at), pinocchio::LOCAL_WORLD_ALIGNED,
                                         v_dq, v_dv);
  for (Eigen::Index k = 0; k < n; ++k) out.col(part.v_index[static_cast<std::size_t>(k)]) = with_dq ? v_dq.col(k) : v_dv.col(k);
  return out;
}

// The world angular velocity Jacobian of world joint j (3 x nv, world columns), after
// computeJointJacobians on the part's pass data. 0 for the world.
Mat angularJacobian(const SimulatorModel& sim, PartPasses& passes, pinocchio::JointIndex j) {
  Mat out = Mat::Zero(3, sim.model.nv);
  if (j == 0) return out;
  const int s = sim.joint_system[j];
  const SystemModel& part = sim.systems[static_cast<std::size_t>(s)];
  Mat J6 = Mat::Zero(6, part.model.nv);
  pinocchio::getJointJacobian(part.model, passes.data[static_cast<std::size_t>(s)], sim.joint_local[j],
                              pinocchio::LOCAL_WORLD_ALIGNED, J6);
  for (Eigen::Index k = 0; k < part.model.nv; ++k) out.col(part.v_index[static_cast<std::size_t>(k)]) = J6.col(k).tail<3>();
  return out;
}

// Run computeForwardKinematicsDerivatives on every part at (q0, w, 0).
void kinematicsDerivativesAt(const SimulatorModel& sim, PartPasses& passes, const Vec& q0, const Vec& w) {
  for (std::size_t s = 0; s < sim.systems.size(); ++s) {
    const SystemModel& part = sim.systems[s];
    Vec qs, ws;
    gatherQ(part, q0, qs);
    gatherV(part, w, ws);
    pinocchio::computeJointJacobians(part.model, passes.data[s], qs);  // (data.J for getJointJacobian)
    pinocchio::computeForwardKinematicsDerivatives(part.model, passes.data[s], qs, ws, Vec::Zero(part.model.nv));
  }
}

// One block of rows whose derivatives with respect to q are computed: a sphere contact on a half-space
// (rows T (t1, t2, n) of the relative velocity at the contact point p = centre - r n of the material
// point `at` of joint `plus` and `at_minus` of the half-space's joint `minus`, 0 for the world; the
// half-space turns with minus: T and n do), or an anchor (3 rows, identity T, material points).
struct RowBlock {
  Eigen::Index row = 0;
  int k = 0;
  pinocchio::JointIndex plus = 0, minus = 0;
  Eigen::Vector3d at = Eigen::Vector3d::Zero(), at_minus = Eigen::Vector3d::Zero(), center = Eigen::Vector3d::Zero();
  Eigen::Vector3d n = Eigen::Vector3d::Zero();
  Eigen::Vector3d plane_origin = Eigen::Vector3d::Zero();  ///< the half-space frame's origin (minus's joint frame)
  double radius = 0.0;
  Eigen::Matrix3d T = Eigen::Matrix3d::Identity();
  bool anchor = false;
};

// d p / dq of the contact point p = centre - r n (3 x nv): the centre moves with plus, n turns with minus.
Mat contactPointDq(const SimulatorModel& sim, PartPasses& passes, const RowBlock& b) {
  Mat dp = pointVelocityJacobian(sim, passes, b.plus, b.center, false);
  if (b.minus != 0 && b.radius != 0.0) dp += b.radius * skew(b.n) * angularJacobian(sim, passes, b.minus);
  return dp;
}

// d/dq of the block's rows times the velocity w of the last kinematicsDerivativesAt (k x nv): the
// material points' velocity derivatives (Pinocchio's), the contact point's motion over the bodies
// ([omega]x (dp/dq - J_point) per body) and the frame's turn with minus (d t_i = omega_B x t_i).
Mat rowVelocityDq(const SimulatorModel& sim, PartPasses& passes, const RowBlock& b, const Vec& w) {
  Mat d = pointVelocityJacobian(sim, passes, b.plus, b.at, true);
  if (b.minus != 0) d -= pointVelocityJacobian(sim, passes, b.minus, b.at_minus, true);
  if (b.anchor) return d;
  if (b.radius == 0.0 && b.minus == 0) return b.T.topRows(b.k) * d;
  const Mat dp = contactPointDq(sim, passes, b);
  const Mat Jp = pointVelocityJacobian(sim, passes, b.plus, b.at, false);
  d += skew(angularJacobian(sim, passes, b.plus) * w) * (dp - Jp);
  Mat rows = b.T.topRows(b.k) * d;
  if (b.minus != 0) {
    const Mat Jm = pointVelocityJacobian(sim, passes, b.minus, b.at_minus, false);
    const Mat Jw = angularJacobian(sim, passes, b.minus);
    rows -= b.T.topRows(b.k) * (skew(Jw * w) * (dp - Jm));
    const Eigen::Vector3d relative = (Jp - Jm) * w;
    for (int i = 0; i < b.k; ++i) rows.row(i) += b.T.row(i).cross(relative.transpose()) * Jw;
  }
  return rows;
}

}  // namespace

void stepDerivatives(const SimulatorModel& sim, const SimulatorData& sd, SimulatorData& scratch, StepDerivativesOutput& out,
                     bool wrt_q) {
  if (sim.settings.mode != IntegrationMode::kTimeStepping)
    throw std::invalid_argument("step_derivatives: time stepping only (mode 'timestep'); the ODE modes' steps are not differentiated");
  if (sim.settings.formulation != "exact")
    throw std::invalid_argument("step_derivatives: the exact formulation only, not '" + sim.settings.formulation + "'");
  const pinocchio::Model& model = sim.model;
  const int nv = model.nv;
  const int candidates = sim.numCandidates();
  const double h = sim.settings.dt;
  const double pd_step = sim.settings.implicit_pd ? h : 0.0;

  // The step from sd's state, on the scratch data (sd is not touched).
  const Vec q0 = sd.q, v0 = sd.v;
  scratch.q = q0;
  scratch.v = v0;
  scratch.t = sd.t;
  scratch.control = sd.control;
  scratch.reference_speed = -1.0;
  step(sim, scratch);
  out.q_next = scratch.q;
  out.v_next = scratch.v;
  if (!scratch.out.joint_rows.empty())
    throw DerivativesNotImplemented("step_derivatives: the step has joint rows (" + jointRowName(sim, scratch, 0) +
                                    (scratch.out.joint_rows.size() > 1 ? ", ..." : "") +
                                    "): derivatives through joint limit, friction and effort rows are not implemented");

  const Eigen::Index m = scratch.out.rows;
  const Mat J = denseJacobian(scratch);
  const Mat M = denseMassMatrix(scratch);  // M~: the implicit PD and damping on its diagonal (factorMass)
  const Eigen::LLT<Mat> llt(M);
  const Mat MinvJt = llt.solve(J.transpose());
  const Mat A = J * MinvJt;
  const Vec P = m > 0 ? Vec(scratch.out.result.lam) : Vec();
  const Vec c = -h * scratch.out.b;
  const Vec u = A * P + c;

  // v^ (before the free flyers' re-expression) from the step's v+: v^_lin = exp(h omega) v+_lin.
  Vec v_hat = out.v_next;
  for (pinocchio::JointIndex j : sim.free_flyers) {
    const int iv = model.idx_vs[j];
    const Eigen::Vector3d rot = h * v_hat.segment<3>(iv + 3);
    const double angle = rot.norm();
    if (angle > 0.0) v_hat.segment<3>(iv) = Eigen::AngleAxisd(angle, rot / angle).toRotationMatrix() * v_hat.segment<3>(iv);
  }

  // tau(q, v)'s dependence on v and tau_ff: -kd - h kp (implicit PD) - d, and 0 for a torque held
  // at its effort limit (an explicit PD or a feed-forward torque alone, clamped: joint_rows.cpp).
  computeControl(sim, scratch, q0, v0);  // the unclamped control torque in scratch.out.tau
  Vec dtau_dv = Vec::Zero(nv), tau_gate = Vec::Ones(nv);
  for (int i = 0; i < nv; ++i)
    dtau_dv[i] = -sd.control.kd[i] - pd_step * sd.control.kp[i] - sim.joint_damping[i];
  for (int dof : sim.effort_dofs) {
    const double K = sd.control.kd[dof] + pd_step * sd.control.kp[dof];
    if ((pd_step > 0.0 && K > 0.0) || std::abs(scratch.out.tau[dof]) <= sim.effort_limit[dof]) continue;
    tau_gate[dof] = 0.0;
    dtau_dv[dof] = -sim.joint_damping[dof];
  }

  // Pinocchio's derivative passes per part at (q0, v0, a = 0): d nle / dv (rnea), and the
  // kinematics' for the drift's d (J' v) / dv.
  // the frame turn ft = omega x v_lin per free flyer
  Mat dft_dv = Mat::Zero(nv, nv);
  Vec ft = Vec::Zero(nv);
  for (pinocchio::JointIndex j : sim.free_flyers) {
    const int iv = model.idx_vs[j];
    dft_dv.block<3, 3>(iv, iv) = skew(v0.segment<3>(iv + 3));
    dft_dv.block<3, 3>(iv, iv + 3) = -skew(v0.segment<3>(iv));
    ft.segment<3>(iv) = v0.segment<3>(iv + 3).cross(v0.segment<3>(iv));
  }
  // the step's acceleration (v^ - v) / h - ft: M~ a = tau - nle + J^T P / h
  const Vec accel = (v_hat - v0) / h - ft;

  // Pinocchio's derivative passes per part at (q0, v0): rnea's at the step's acceleration (d nle / dv,
  // and d (M a + nle) / dq), and the kinematics' at a = 0 for the drift's d (J' v) / d(q, v).
  // (kept in the scratch data's workspace: a Data's construction, its kinematic Hessians zeroed, cost
  // more than the passes)
  const auto fits = [&](const PartPasses& p) {
    if (p.data.size() != sim.systems.size()) return false;
    for (std::size_t s = 0; s < p.data.size(); ++s)
      if (p.data[s].oMi.size() != static_cast<std::size_t>(sim.systems[s].model.njoints) ||
          p.data[s].dtau_dq.cols() != sim.systems[s].model.nv)
        return false;
    return true;
  };
  if (!scratch.work->derivatives || !fits(*std::static_pointer_cast<PartPasses>(scratch.work->derivatives))) {
    auto made = std::make_shared<PartPasses>();
    for (const SystemModel& part : sim.systems) made->data.emplace_back(part.model);
    scratch.work->derivatives = made;
  }
  PartPasses& passes = *std::static_pointer_cast<PartPasses>(scratch.work->derivatives);
  Mat dnle_dv = Mat::Zero(nv, nv), drnea_dq = Mat::Zero(nv, nv);
  for (std::size_t s = 0; s < sim.systems.size(); ++s) {
    const SystemModel& part = sim.systems[s];
    pinocchio::Data& data = passes.data[s];
    Vec qs, vs, as;
    gatherQ(part, q0, qs);
    gatherV(part, v0, vs);
    gatherV(part, accel, as);
    const Vec zero = Vec::Zero(part.model.nv);
    pinocchio::computeRNEADerivatives(part.model, data, qs, vs, as);
    for (Eigen::Index r = 0; r < part.model.nv; ++r)
      for (Eigen::Index k = 0; k < part.model.nv; ++k) {
        const int wr = part.v_index[static_cast<std::size_t>(r)], wk = part.v_index[static_cast<std::size_t>(k)];
        dnle_dv(wr, wk) = data.dtau_dv(r, k);
        drnea_dq(wr, wk) = data.dtau_dq(r, k);
      }
    pinocchio::computeJointJacobians(part.model, data, qs);  // (data.J for getJointJacobian)
    pinocchio::computeForwardKinematicsDerivatives(part.model, data, qs, vs, zero);
  }

  // dg/dv, dg/dtau
  Mat dtau = dtau_dv.asDiagonal();
  dtau -= dnle_dv;
  Mat dg_dv = llt.solve(dtau);
  dg_dv *= h;
  dg_dv += h * dft_dv;
  dg_dv.diagonal().array() += 1.0;
  Mat dg_dtau = llt.solve(Mat(tau_gate.asDiagonal()));
  dg_dtau *= h;

  // dc/dv = J dg/dv + h nrm.(d drift/dv - J dft/dv): sphere contacts' normal rows (their centre's
  // J' v) and the anchors; a coal row's drift is J ft (0 here), tangential rows drop theirs.
  Mat dc_dv = J * dg_dv;
  {
    Eigen::Index row = 0;
    for (int i : scratch.out.active) {
      const int k = scratch.out.candidate_rows[i];
      if (sim.slot_pair[i] < 0) {
        const SphereContact& sc = sim.contacts[i];
        const pinocchio::Frame& f = model.frames[sc.frame];
        const HalfSpace& hs = sim.halfspaces[sc.halfspace];
        const pinocchio::JointIndex plus = f.parentJoint, minus = hs.frame != 0 ? model.frames[hs.frame].parentJoint : 0;
        const Eigen::Vector3d n = scratch.work->plane_normal.col(sc.halfspace);
        const Eigen::Vector3d center_j = f.placement.act(sc.offset);
        const Eigen::Vector3d point_w = jointPlacement(sim, scratch, plus).act(center_j) - sc.radius * n;
        const Eigen::Vector3d plane_at_point = jointPlacement(sim, scratch, minus).actInv(point_w);
        const Mat acc = pointAccelerationDv(sim, passes, plus, center_j) - pointAccelerationDv(sim, passes, minus, plane_at_point);
        const Eigen::Index rn = row + k - 1;
        dc_dv.row(rn) += h * (n.transpose() * acc - J.row(rn) * dft_dv);
      }
      row += k;
    }
    for (const PointAnchor& a : sim.anchors) {
      const pinocchio::JointIndex plus = model.frames[a.frame].parentJoint;
      Mat acc = pointAccelerationDv(sim, passes, plus, model.frames[a.frame].placement.act(a.offset));
      if (a.frame2 != 0)
        acc -= pointAccelerationDv(sim, passes, model.frames[a.frame2].parentJoint, model.frames[a.frame2].placement.act(a.offset2));
      dc_dv.middleRows(row, 3) += h * (acc - J.middleRows(row, 3) * dft_dv);
      row += 3;
    }
  }
  const Mat dc_dtau = J * dg_dtau;

  // Modes at the converged P, u (scale-aware thresholds), and the mode equations' matrices.
  out.modes.assign(static_cast<std::size_t>(candidates), -1);
  out.boundary.assign(static_cast<std::size_t>(candidates), 0);
  out.mu_indeterminate.assign(static_cast<std::size_t>(candidates), 0);
  const double p_scale = m > 0 ? P.lpNorm<Eigen::Infinity>() : 0.0;
  const double u_scale = m > 0 ? std::max(u.lpNorm<Eigen::Infinity>(), c.lpNorm<Eigen::Infinity>()) : 0.0;
  const double p_zero = 1e-8 * p_scale, u_zero = 1e-8 * u_scale;  // the solve's tolerance is ~1e-10
  const double u_near = 1e-6 * u_scale, cone_near = 1e-6;          // a boundary within reach
  Mat K = Mat::Zero(m, m), Eu = Mat::Zero(m, m), Emu = Mat::Zero(m, candidates);
  {
    Eigen::Index row = 0;
    for (int i : scratch.out.active) {
      const int k = scratch.out.candidate_rows[i];
      const double mu = candidateMu(sim, i);
      const Eigen::Index rn = row + k - 1;
      const double Pn = P[rn], un = u[rn];
      const Vec Pt = P.segment(row, k - 1), ut = u.segment(row, k - 1);
      int mode;
      bool edge = false;
      if (Pn <= p_zero) {
        mode = 0;
        edge = un <= u_zero;
      } else if (k == 1 || ut.norm() <= u_zero) {
        mode = 1;
        edge = k > 1 && Pt.norm() >= (1.0 - cone_near) * mu * Pn;
      } else {
        mode = 2;
        edge = ut.norm() <= u_near;
      }
      out.modes[static_cast<std::size_t>(i)] = mode;
      out.boundary[static_cast<std::size_t>(i)] = edge ? 1 : 0;
      if (mode == 0) {
        K.block(row, row, k, k).setIdentity();
      } else if (mode == 1) {
        Eu.block(row, row, k, k).setIdentity();
      } else {
        const double speed = ut.norm();
        const Vec s = ut / speed;
        Eu(rn, rn) = 1.0;
        K.block(row, row, k - 1, k - 1).setIdentity();
        K.block(row, rn, k - 1, 1) = mu * s;
        Eu.block(row, row, k - 1, k - 1) = (mu * Pn / speed) * (Mat::Identity(k - 1, k - 1) - s * s.transpose());
        Emu.block(row, i, k - 1, 1) = Pn * s;
      }
      row += k;
    }
    for (std::size_t a = 0; a < sim.anchors.size(); ++a, row += 3) Eu.block(row, row, 3, 3).setIdentity();
  }
  K.noalias() += Eu * A;

  // dP for (v, tau, mu) at once: the minimum-norm solution (redundant contacts)
  Mat rhs(m, 2 * nv + candidates);
  rhs.leftCols(nv).noalias() = -Eu * dc_dv;
  rhs.middleCols(nv, nv).noalias() = -Eu * dc_dtau;
  rhs.rightCols(candidates) = -Emu;
  Mat dP = Mat::Zero(m, 2 * nv + candidates);
  Eigen::CompleteOrthogonalDecomposition<Mat> cod;
  // Redundant contacts whose mode equations no dP can meet (rhs outside K's range: the pinch's four
  // sticking pads turned about the box's axis) sit where the step changes mode: every contact in
  // contact is then flagged, the least-squares dP returned.
  const auto flag_inconsistent = [&](const Mat& x, const Mat& r) {
    if (m == 0) return;
    const Mat residual = K * x - r;
    // (a column whose right-hand side is rounding, 1e-10 of the largest, is not judged)
    const double largest = r.colwise().norm().maxCoeff();
    for (Eigen::Index j = 0; j < r.cols(); ++j)
      if (residual.col(j).norm() > 1e-6 * (r.col(j).norm() + K.norm() * x.col(j).norm()) &&
          residual.col(j).norm() > 1e-10 * largest) {
        for (int i : scratch.out.active)
          if (out.modes[static_cast<std::size_t>(i)] > 0) out.boundary[static_cast<std::size_t>(i)] = 1;
        out.inconsistent = true;
        return;
      }
  };
  if (m > 0) {
    cod.compute(K);
    dP = cod.solve(rhs);
    flag_inconsistent(dP, rhs);
    // A statically indeterminate set whose velocity is not unique either (a cube's four corners sliding
    // in different directions as it spins: how the weight is shared among them changes the net
    // friction): K's kernel moves v^. The minimum-norm branch is returned, the solver's may differ:
    // the contacts the kernel involves are flagged.
    if (cod.rank() < m) {
      const Mat kernel = Eigen::FullPivLU<Mat>(K).kernel();
      const Mat moved = MinvJt * kernel;
      const double tol = 1e-8 * MinvJt.norm();
      for (Eigen::Index z = 0; z < kernel.cols(); ++z) {
        // Any kernel direction changes how the load is shared: the contacts it involves have a normal
        // impulse, hence a mu column (E_mu = P_n s), that depends on the solver's split.
        {
          Eigen::Index row = 0;
          for (int i : scratch.out.active) {
            const int k = scratch.out.candidate_rows[i];
            if (kernel.col(z).segment(row, k).norm() > 1e-8 * kernel.col(z).norm())
              out.mu_indeterminate[static_cast<std::size_t>(i)] = 1;
            row += k;
          }
        }
        if (moved.col(z).norm() <= tol * kernel.col(z).norm()) continue;
        out.indeterminate = true;
        Eigen::Index row = 0;
        for (int i : scratch.out.active) {
          const int k = scratch.out.candidate_rows[i];
          if (kernel.col(z).segment(row, k).norm() > 1e-8 * kernel.col(z).norm()) out.boundary[static_cast<std::size_t>(i)] = 1;
          row += k;
        }
      }
    }
  }
  Mat dvhat(nv, 2 * nv + candidates);
  dvhat.leftCols(nv) = dg_dv;
  dvhat.middleCols(nv, nv) = dg_dtau;
  dvhat.rightCols(candidates).setZero();
  if (m > 0) dvhat.noalias() += MinvJt * dP;

  // v+ and q+ from v^: the free flyers' re-expression R^T v_lin (R = exp(h omega)) and the
  // configuration's integration (Pinocchio's dIntegrate; free flyers: p + h R0 v_lin, R0 exp(h omega)).
  Mat Rv = Mat::Identity(nv, nv);
  Mat Qv = Mat::Zero(nv, nv);  // (dIntegrate writes the joints' diagonal blocks only)
  pinocchio::dIntegrate(model, q0, Vec(h * v_hat), Qv, pinocchio::ARG1);
  Qv *= h;
  for (pinocchio::JointIndex j : sim.free_flyers) {
    const int iv = model.idx_vs[j];
    const Eigen::Vector3d phi = h * v_hat.segment<3>(iv + 3);
    const double angle = phi.norm();
    const Eigen::Matrix3d E = angle > 0.0 ? Eigen::AngleAxisd(angle, phi / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
    const Eigen::Matrix3d Jr = rightJacobianSO3(phi);
    Rv.block<3, 3>(iv, iv) = E.transpose();
    Rv.block<3, 3>(iv, iv + 3) = h * skew(E.transpose() * v_hat.segment<3>(iv)) * Jr;
    Qv.block<6, 6>(iv, iv).setZero();
    Qv.block<3, 3>(iv, iv) = h * E.transpose();
    Qv.block<3, 3>(iv + 3, iv + 3) = h * Jr;
  }
  const Mat dv_all = Rv * dvhat, dq_all = Qv * dvhat;
  out.dv_dv = dv_all.leftCols(nv);
  out.dv_dtau = dv_all.middleCols(nv, nv);
  out.dv_dmu = dv_all.rightCols(candidates);
  out.dq_dv = dq_all.leftCols(nv);
  out.dq_dtau = dq_all.middleCols(nv, nv);
  out.dq_dmu = dq_all.rightCols(candidates);
  out.has_q = false;
  out.dq_dq = Mat::Constant(nv, nv, std::nan(""));
  out.dv_dq = Mat::Constant(nv, nv, std::nan(""));
  if (!wrt_q) return;

  // ---- with respect to q (tangent: q (+) dq), at fixed v, tau, mu. The velocity equation
  // M~ (v^ - v - h ft) = h (tau(q, v) - nle(q, v)) + J(q)^T P differentiated at fixed P:
  //   M~ dv^ = -h d rnea(q, v, a)/dq + h dtau/dq + d(J^T P)/dq + J^T dP,
  // and u = J v^ + h nrm.(drift - J ft) + Psi / h:  du = J dv^ + (dJ/dq) v^ - h nrm.(dJ/dq) ft
  //   + h nrm.d drift/dq + dPsi/dq / h.
  std::vector<RowBlock> blocks;
  {
    Eigen::Index row = 0;
    for (int i : scratch.out.active) {
      const int k = scratch.out.candidate_rows[i];
      if (sim.slot_pair[i] >= 0)
        throw DerivativesNotImplemented("step_derivatives: derivatives with respect to q of a coal pair's contact ('" +
                                        sim.pairs[static_cast<std::size_t>(sim.slot_pair[i])].name +
                                        "') are not implemented (sphere and point contacts only)");
      const SphereContact& sc = sim.contacts[i];
      const HalfSpace& hs = sim.halfspaces[sc.halfspace];
      RowBlock b;
      b.row = row;
      b.k = k;
      const pinocchio::Frame& f = model.frames[sc.frame];
      b.plus = f.parentJoint;
      b.n = scratch.work->plane_normal.col(sc.halfspace);
      b.center = f.placement.act(sc.offset);
      const pinocchio::SE3& oMj = jointPlacement(sim, scratch, b.plus);
      const Eigen::Vector3d point = oMj.act(b.center) - sc.radius * b.n;
      b.at = oMj.actInv(point);
      b.radius = sc.radius;
      if (hs.frame != 0) {
        b.minus = model.frames[hs.frame].parentJoint;
        b.at_minus = jointPlacement(sim, scratch, b.minus).actInv(point);
        b.plane_origin = model.frames[hs.frame].placement.translation();
      }
      int r = 0;
      if (k >= 2) b.T.row(r++) = scratch.work->plane_t1.col(sc.halfspace).transpose();
      if (k == 3) b.T.row(r++) = scratch.work->plane_t2.col(sc.halfspace).transpose();
      b.T.row(r) = b.n.transpose();
      blocks.push_back(b);
      row += k;
    }
    for (const PointAnchor& a : sim.anchors) {
      RowBlock b;
      b.row = row;
      b.k = 3;
      b.anchor = true;
      b.plus = model.frames[a.frame].parentJoint;
      b.at = model.frames[a.frame].placement.act(a.offset);
      if (a.frame2 != 0) {
        b.minus = model.frames[a.frame2].parentJoint;
        b.at_minus = model.frames[a.frame2].placement.act(a.offset2);
      }
      blocks.push_back(b);
      row += 3;
    }
  }
  Mat U_q = Mat::Zero(m, nv);   // du/dq at fixed v^, P
  Mat JtP_q = Mat::Zero(nv, nv);  // d(J^T P)/dq at fixed P
  // the drift's and the gap's terms (kinematics derivatives at (q0, v0, 0), computed above)
  for (const RowBlock& b : blocks) {
    const Eigen::Index rn = b.row + b.k - 1;
    if (b.anchor) {
      Mat acc = pointAccelerationDv(sim, passes, b.plus, b.at, true);
      if (b.minus != 0) acc -= pointAccelerationDv(sim, passes, b.minus, b.at_minus, true);
      U_q.middleRows(b.row, 3) += h * acc + J.middleRows(b.row, 3) / h;  // Psi = p1 - p2: dPsi/dq = J
    } else {
      // gap = n . (centre - plane origin) - offset - r; drift = n . (acc_plus(centre) - acc_minus(p))
      const Mat Jc = pointVelocityJacobian(sim, passes, b.plus, b.center, false);
      Mat dacc = pointAccelerationDv(sim, passes, b.plus, b.center, true);
      Mat dgap = Jc;
      if (b.minus != 0) {
        const pinocchio::SE3& oMm = jointPlacement(sim, scratch, b.minus);
        const Mat Jw = angularJacobian(sim, passes, b.minus);
        dgap -= pointVelocityJacobian(sim, passes, b.minus, b.plane_origin, false);
        const Eigen::Vector3d center_w = jointPlacement(sim, scratch, b.plus).act(b.center);
        // the minus body's acceleration field at p, and p's motion over it
        const pinocchio::Data& data = passes.data[static_cast<std::size_t>(sim.joint_system[b.minus])];
        const pinocchio::JointIndex local = sim.joint_local[b.minus];
        const Eigen::Vector3d omega = data.ov[local].angular(), alpha = data.oa[local].angular();
        const Eigen::Vector3d p = oMm.act(b.at_minus);
        const Eigen::Vector3d acc_minus = data.oa[local].linear() + alpha.cross(p) +
                                          omega.cross(Eigen::Vector3d(data.ov[local].linear() + omega.cross(p)));
        const Eigen::Vector3d acc_plus = [&] {
          const pinocchio::Data& dp = passes.data[static_cast<std::size_t>(sim.joint_system[b.plus])];
          const pinocchio::JointIndex lp = sim.joint_local[b.plus];
          const Eigen::Vector3d wp = dp.ov[lp].angular(), c = center_w;
          return Eigen::Vector3d(dp.oa[lp].linear() + dp.oa[lp].angular().cross(c) +
                                 wp.cross(Eigen::Vector3d(dp.ov[lp].linear() + wp.cross(c))));
        }();
        const Mat dp = contactPointDq(sim, passes, b);
        const Mat Jm = pointVelocityJacobian(sim, passes, b.minus, b.at_minus, false);
        dacc -= pointAccelerationDv(sim, passes, b.minus, b.at_minus, true) +
                (skew(alpha) + skew(omega) * skew(omega)) * (dp - Jm);
        // n turns with minus: d n = omega_B(dq) x n
        U_q.row(rn) += h * b.n.cross(acc_plus - acc_minus).transpose() * Jw;
        U_q.row(rn) += b.n.cross(Eigen::Vector3d(center_w - oMm.act(b.plane_origin))).transpose() * Jw / h;
      }
      U_q.row(rn) += h * b.n.transpose() * dacc + b.n.transpose() * dgap / h;
    }
  }
  // (dJ/dq) v^ on every row, - h (dJ/dq) ft on the normal rows: the velocity derivatives at v^, v^ - h ft
  const Vec v_normal = v_hat - h * ft;
  for (int pass = 0; pass < 2; ++pass) {
    const Vec& w = pass == 0 ? v_hat : v_normal;
    kinematicsDerivativesAt(sim, passes, q0, w);
    for (const RowBlock& b : blocks) {
      const Mat d = rowVelocityDq(sim, passes, b, w);
      for (int r = 0; r < b.k; ++r) {
        const bool normal = b.anchor || r == b.k - 1;
        if (normal == (pass == 1)) U_q.row(b.row + r) += d.row(r);
      }
    }
  }
  // d(J^T P)/dq. Each block's impulse is a world force f = T^T P_c at p on plus (and -f on minus), i.e.
  // the world wrench phi = (f, p x f), and J^T P = sum over bodies J_local^T f_local, f_local = oMi^-1 * phi:
  //  (1) J_local's variation at fixed f_local: rnea's with f_local as external forces, minus its own;
  //  (2) f_local's at fixed phi (oMi -> oMi exp(nu), nu = J_local dq): -J_local^T F(f_local) J_local,
  //      F(f) nu = nu x* f;
  //  (3) the point's motion dp: phi gains (0, dp x f): -J_omega^T [f]x dp;
  //  (4) the frame's turn with minus (f = T^T P_c turns: df = omega_B x f): (J_p - J_m)^T (-[f]x J_omega,B).
  if (m > 0) {
    struct Load {  // one force on one body at one world point that moves by dp/dq
      pinocchio::JointIndex joint;
      Eigen::Vector3d f, p;
      Mat dp;
    };
    std::vector<Load> loads;
    for (const RowBlock& b : blocks) {
      const Eigen::Vector3d f = b.T.topRows(b.k).transpose() * P.segment(b.row, b.k);
      if (b.anchor) {
        const Eigen::Vector3d p1 = jointPlacement(sim, scratch, b.plus).act(b.at);
        loads.push_back({b.plus, f, p1, pointVelocityJacobian(sim, passes, b.plus, b.at, false)});
        if (b.minus != 0) {
          const Eigen::Vector3d p2 = jointPlacement(sim, scratch, b.minus).act(b.at_minus);
          loads.push_back({b.minus, Eigen::Vector3d(-f), p2, pointVelocityJacobian(sim, passes, b.minus, b.at_minus, false)});
        }
        continue;
      }
      const Eigen::Vector3d p = jointPlacement(sim, scratch, b.plus).act(b.at);
      const Mat dp = contactPointDq(sim, passes, b);
      loads.push_back({b.plus, f, p, dp});
      if (b.minus != 0) {
        loads.push_back({b.minus, Eigen::Vector3d(-f), p, dp});
        const Mat Jw = angularJacobian(sim, passes, b.minus);
        const Mat relative = pointVelocityJacobian(sim, passes, b.plus, b.at, false) -
                             pointVelocityJacobian(sim, passes, b.minus, b.at_minus, false);
        JtP_q.noalias() -= relative.transpose() * skew(f) * Jw;  // (4)
      }
    }
    for (std::size_t s = 0; s < sim.systems.size(); ++s) {
      const SystemModel& part = sim.systems[s];
      const pinocchio::Model& pm = part.model;
      pinocchio::container::aligned_vector<pinocchio::Force> fext(static_cast<std::size_t>(pm.njoints), pinocchio::Force::Zero());
      bool any = false;
      for (const Load& l : loads) {
        if (l.joint == 0 || sim.joint_system[l.joint] != static_cast<int>(s)) continue;
        const pinocchio::JointIndex local = sim.joint_local[l.joint];
        const pinocchio::Force phi(l.f, Eigen::Vector3d(l.p.cross(l.f)));
        fext[local] += passes.data[s].oMi[local].actInv(phi);
        any = true;
        // (3)
        const Mat Jw = angularJacobian(sim, passes, l.joint);
        JtP_q.noalias() -= Jw.transpose() * skew(l.f) * l.dp;
      }
      if (!any) continue;
      // (2), per joint carrying a force
      for (pinocchio::JointIndex local = 1; local < static_cast<pinocchio::JointIndex>(pm.njoints); ++local) {
        if (fext[local].toVector().isZero(0.0)) continue;
        Mat Jl = Mat::Zero(6, pm.nv);
        pinocchio::getJointJacobian(pm, passes.data[s], local, pinocchio::LOCAL, Jl);
        const Eigen::Vector3d fl = fext[local].linear(), fa = fext[local].angular();
        Eigen::Matrix<double, 6, 6> F = Eigen::Matrix<double, 6, 6>::Zero();
        F.block<3, 3>(0, 3) = -skew(fl);
        F.block<3, 3>(3, 0) = -skew(fl);
        F.block<3, 3>(3, 3) = -skew(fa);
        const Mat term = -Jl.transpose() * F * Jl;
        for (Eigen::Index r = 0; r < pm.nv; ++r)
          for (Eigen::Index k = 0; k < pm.nv; ++k)
            JtP_q(part.v_index[static_cast<std::size_t>(r)], part.v_index[static_cast<std::size_t>(k)]) += term(r, k);
      }
      // (1): rnea with and without the forces, same (q, v, a) (the last use of this part's Data)
      pinocchio::Data& with_forces = passes.data[s];
      Vec qs, vs, as;
      gatherQ(part, q0, qs);
      gatherV(part, v0, vs);
      gatherV(part, accel, as);
      pinocchio::computeRNEADerivatives(pm, with_forces, qs, vs, as, fext);
      for (Eigen::Index r = 0; r < pm.nv; ++r)
        for (Eigen::Index k = 0; k < pm.nv; ++k) {
          const int wr = part.v_index[static_cast<std::size_t>(r)], wk = part.v_index[static_cast<std::size_t>(k)];
          JtP_q(wr, wk) += drnea_dq(wr, wk) - with_forces.dtau_dq(r, k);
        }
    }
  }
  // tau's q_target (-) q (kp), where not clamped
  Mat dtau_dq = Mat::Zero(nv, nv);
  if (!sd.control.kp.isZero(0.0)) {
    Mat ddiff = Mat::Zero(nv, nv);
    pinocchio::dDifference(model, q0, sd.control.q_target, ddiff, pinocchio::ARG0);
    dtau_dq = (sd.control.kp.cwiseProduct(tau_gate)).asDiagonal() * ddiff;
  }
  Mat dg_dq = llt.solve(Mat(h * dtau_dq - h * drnea_dq + JtP_q));
  const Mat dc_dq = J * dg_dq + U_q;
  Mat dvhat_dq = dg_dq;
  if (m > 0) {
    const Mat rhs_q = -Eu * dc_dq;
    const Mat dP_q = cod.solve(rhs_q);
    flag_inconsistent(dP_q, rhs_q);
    dvhat_dq.noalias() += MinvJt * dP_q;
  }
  // q+ = q (+) h v^: the direct part (dIntegrate's first argument; free flyers: p + h R v_lin, R exp(h omega))
  Mat Q0 = Mat::Zero(nv, nv);
  pinocchio::dIntegrate(model, q0, Vec(h * v_hat), Q0, pinocchio::ARG0);
  for (pinocchio::JointIndex j : sim.free_flyers) {
    const int iv = model.idx_vs[j];
    const Eigen::Vector3d phi = h * v_hat.segment<3>(iv + 3);
    const double angle = phi.norm();
    const Eigen::Matrix3d E = angle > 0.0 ? Eigen::AngleAxisd(angle, phi / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
    Q0.block<6, 6>(iv, iv).setZero();
    Q0.block<3, 3>(iv, iv) = E.transpose();
    Q0.block<3, 3>(iv, iv + 3) = -h * E.transpose() * skew(v_hat.segment<3>(iv));
    Q0.block<3, 3>(iv + 3, iv + 3) = E.transpose();
  }
  out.dq_dq = Q0 + Qv * dvhat_dq;
  out.dv_dq = Rv * dvhat_dq;
  out.has_q = true;
}

}  // namespace stiction
