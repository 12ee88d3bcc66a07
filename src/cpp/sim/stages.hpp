// The stages of a step (internal to src/cpp/sim/), in the order step() runs them:
//
//   1. kinematics   forwardKinematics        kinematics.cpp   placements, J' v, joint Jacobians
//                   treeKinematics           tree.cpp         (a robot part: one fused pass)
//   2. detect       detectContacts           detect.cpp       gaps, the active set, its rows
//   3. Jacobians    contactJacobians         kinematics.cpp   J, drift J' v, Psi per row
//   4. Delassus     freeDynamics             dynamics.cpp     M = U D U^T, nle, tau, M^-1 (tau - nle)
//                   delassusOperator                          A = J M^-1 J^T (eq. 22)
//                   rightHandSide                             b (eq. 27)
//   5. solve        solveContacts            solve.cpp        the formulation's lambda (eq. 65)
//   6. integrate    integrateTimeStep        integrate.cpp    v+, q+ (eq. 70), or an ODE step of
//                   integrateRK4, ...                         the relaxed DAI (stages 1-5 per RHS)
//
// Timing: the stage functions do not time themselves; where they are sequenced (step(),
// buildContactProblem, the ODE right-hand side) a Stopwatch charges stages 1-3 to
// StepTimings::kinematics, 4 to `delassus`, 5 to `solve` and 6 to `integrate`. In the ODE
// modes stages 1-5 are summed over the RHS evaluations, and `integrate` is the update outside
// them (RK4: the final combination; adaptive: not timed).
// Pinocchio's algorithms cost a few seconds of compilation a file when called with the
// argument types of the instantiations libpinocchio ships (extern templates: VectorXd, or
// Eigen::Ref<const VectorXd> for crba); other argument types instantiate them anew (crba:
// +40 s). solve.cpp and step.cpp see Pinocchio's Model and Data alone.
#pragma once

#include <chrono>

#include "stiction/clock.hpp"
#include "stiction/simulator.hpp"
#include "stiction/thresholds.hpp"
#include "workspace.hpp"

namespace stiction {
namespace stages {

// ---- stage functions

/// 1. Forward kinematics at (q, v) with zero acceleration (the classical accelerations it
/// leaves are J' v) and the world-frame joint Jacobians, per part (sd.work->parts[s].data).
void forwardKinematics(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                       const Eigen::VectorXd& v);
/// Stage 1 for a robot part whose joints treeOf describes (tree.cpp), in one pass: oMi, the
/// world-frame joint Jacobian data.J, and per body in world coordinates its velocity data.ov,
/// bias acceleration data.oa (q'' = 0), inertia data.oYcrb and rnea's forward-pass force data.of.
void treeKinematics(const SystemModel& part, SystemWork& w);
/// After Pinocchio's forwardKinematics and computeJointJacobians (a part treeOf does not
/// describe): the same world-frame ov, oa, oYcrb and of from its local v, a.
void worldFrameTerms(const pinocchio::Model& model, pinocchio::Data& data);
/// Stage 4's share of a robot part: M's upper triangle (armature included, as crba) and
/// nle = C(q, v) v + g(q) from stage 1's world-frame terms, in one backward pass.
void compositeBackwardPass(const SystemModel& part, pinocchio::Data& data, Eigen::VectorXd& nle);
/// M = U D U^T as Pinocchio's cholesky::decompose (its tree-sparse factor, the same operations),
/// written for this processor's store forwarding (tree.cpp).
void treeDecompose(const SystemModel& part, pinocchio::Data& data);
/// x = M^-1 x from treeDecompose's factor (U^-1 by columns over each coordinate's ancestors).
void treeSolve(const SystemModel& part, const pinocchio::Data& data, Eigen::VectorXd& x);

/// Stage 1 for a free body (SystemModel::free_body) from w.q, w.v: oMi, v and a of its joint, as
/// Pinocchio's forward kinematics would leave them; no joint Jacobian (data.J is not filled).
void freeBodyKinematics(const pinocchio::Model& model, SystemWork& w);

/// 2. Detection from the placements of stage 1: half-spaces in world coordinates (plane_*),
/// every candidate's signed distance (gaps; coal pairs fill their slots), and the active
/// set (active, candidate_rows) of those within the activation distance.
void detectContacts(const SimulatorModel& sim, SimulatorData& sd);

/// 2b. The joints' rows at (q, v) (joint_rows.cpp, docs/joint-rows.md), after the control torque
/// sd.out.tau at (q, v) (computeControl): every coordinate with dry friction; each 1-dof joint's limit
/// within the margin or about to cross it in a step; with the implicit PD over h > 0, the actuators
/// with an effort limit near saturation (|tau| >= half the limit now or at the last step), whose PD
/// then leaves M's diagonal for the row. Every other effort-limited actuator's torque is clamped here
/// when the PD is explicit (h = 0) or absent (kp = kd = 0). Plus the rows forced by a repeated pass.
void selectJointRows(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q, const Eigen::VectorXd& v,
                     double implicit_pd_step);

/// 4d. Time stepping with effort rows: each row's compliance 1 / (h K) on A's diagonal and c / (h K) in
/// b, so that u = v+_j + P / (h K) - c / K: the row's impulse is h (c - K v+_j), the implicit PD's,
/// strictly inside its bounds, and saturates at them (eq. 65 with C = [-h e, h e]).
void addActuatorCompliance(SimulatorData& sd, double h);

/// The constraint of joint row k of the problem (bounds scaled by `scale`: h for impulses) and its warm
/// start from the last step's torques (clamped into the bounds).
Constraint jointRowConstraint(const SimulatorModel& sim, const SimulatorData& sd, std::size_t k, double scale);
double jointRowGuess(const SimulatorModel& sim, const SimulatorData& sd, std::size_t k, double scale);
/// "joint 'name' lower limit", "... friction", "... actuator"
std::string jointRowName(const SimulatorModel& sim, const SimulatorData& sd, std::size_t k);

/// After the solve and, in time stepping (h > 0), the integration from v0 to v+ = sd.v: the applied
/// actuator, friction and limit torques (sd.out.actuator_torque, friction_torque, limit_torque; the
/// implicit PD's at v+). Time stepping: false when an actuator without a row saturated or a joint
/// without a limit row crossed its limit; that row is then forced and the step must be repeated.
bool finishJointRows(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v0, double h,
                     double implicit_pd_step);

/// 3. The rows of the active contacts, then of the anchors: J (t1, t2, n per contact),
/// drift J' v, position_error Psi (gap on normal rows, anchor error), tangent_row.
void contactJacobians(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v);

/// 4a. M and nle (a robot's from stage 1's world-frame terms, compositeBackwardPass; a free
/// body's M by crba, once), h kd + h^2 kp on M's diagonal when implicit_pd_step = h > 0, its
/// factor M = U D U^T per part, the joints' generalized force tau (from selectJointRows's control
/// torque at (q, v): the implicit PD's -h kp v, an effort row's actuator taken out, damping) and
/// v_free = M^-1 (tau - nle). Throws when M is not positive definite.
void freeDynamics(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v, double implicit_pd_step);

/// 4b. A = J M^-1 J^T (eq. 22) = sum over parts of W_s^T W_s, W_s = D_s^-1/2 U_s^-1 J_s^T:
/// symmetric by construction; dense, or sparse (sd.out.sparse) when many parts share more than
/// kSparseDelassusRows rows and at most kSparseDelassusDensity of A is nonzero (thresholds.hpp).
void delassusOperator(const SimulatorModel& sim, SimulatorData& sd);

/// 4b for a problem that is one robot's alone (robot_delassus.cpp): sd.out.A = J M^-1 J^T from the
/// chains of the tree, exactly symmetric. False (nothing done) when some block's columns are not
/// on one root path (a contact between two of the robot's limbs): the general path then.
bool robotOperator(const SimulatorModel& sim, SimulatorData& sd);

/// 4c. b of eq. 27 with Phi = nle - tau: J M^-1 Phi - J' v - (2 zeta / delta) J v - Psi / delta^2;
/// without the J' v term on tangential rows when tangential_drift is false (time stepping).
void rightHandSide(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v, double delta,
                   double zeta, bool tangential_drift = true);

/// b's part that no lambda can produce (in J's left null space over a set of contacts between the
/// same two bodies with more rows than their relative twist's 6) removed when it exceeds a tenth
/// of the solver's tolerance (solveContacts, for a step that missed it); sd.out.inconsistent_groups
/// counts the sets changed.
void projectRedundantSets(const SimulatorModel& sim, SimulatorData& sd);

/// 5. Solve eq. 65 for sd.out.A, sd.out.b (scaled by `scale`: h for impulses) with the model's
/// formulation, warm-started from the previous lambda of the same candidates; per-candidate
/// forces and states. Throws when the problem has no (resolvable) solution.
void solveContacts(const SimulatorModel& sim, SimulatorData& sd, double scale);

/// Stage 5's parts (solveContacts runs them in order): the problem handed to the formulation
/// (sd.work->problem: A, scale b, the blocks' constraints), the warm start sd.work->guess (true when
/// any entry is nonzero), and after the solve the per-candidate forces, states and statistics.
void setStepProblem(const SimulatorModel& sim, SimulatorData& sd, double scale);
bool stepGuess(const SimulatorModel& sim, SimulatorData& sd, double scale, bool exact);
void recordSolution(const SimulatorModel& sim, SimulatorData& sd, double scale, int solve_iterations);

/// 4b + 5 in time stepping while the joints' dry friction holds (locked_joints.cpp): every joint row a
/// friction row and the last step's all sticking, the contacts' problem with those coordinates locked
/// (a Schur complement of eq. 65's all-friction-stick equations, the free coordinates' M_FF only),
/// solved; its answer with the friction impulses it implies is the full problem's when each lies within
/// its bound (u = 0 on every friction row). True when that held (sd.out.result and the candidates set,
/// the full A left to completeLockedStep); false: nothing the full path needs was changed.
class Stopwatch;
bool solveJointsLocked(const SimulatorModel& sim, SimulatorData& sd, double h, Stopwatch& watch);

/// 6. Time stepping (eq. 70): v+ = v + h v_free + M^-1 J^T P (P = h lambda, free flyers'
/// frame turn), row_velocity = J v+, q+ = integrate(q, h v+); t += h.
void integrateTimeStep(const SimulatorModel& sim, SimulatorData& sd, double h);

/// 6. The relaxed DAI as an ODE: one classical RK4 step of dt (stages 1-5 per RHS evaluation).
void integrateRK4(const SimulatorModel& sim, SimulatorData& sd);

/// 6. The relaxed DAI as an ODE: one accepted Bogacki-Shampine 3(2) step of at most dt.
void integrateAdaptive(const SimulatorModel& sim, SimulatorData& sd);


/// 7. Sensors (sensors.cpp): before a step, the IMU joint's start state; after it, each candidate's
/// world force and the IMU (SimulatorOutputs::contact_force, accelerometer, sensor_time).
void sensorsBeforeStep(const SimulatorModel& sim, SimulatorData& sd);
void sensorsAfterStep(const SimulatorModel& sim, SimulatorData& sd);

// ---- the world's parts (SimulatorModel::systems, SimulatorData::parts)

/// local = the entries `index` of x (contiguous from `start` when start >= 0).
inline void gather(const std::vector<int>& index, int start, const Eigen::VectorXd& x, Eigen::VectorXd& local) {
  const auto n = static_cast<Eigen::Index>(index.size());
  if (start >= 0) {
    local = x.segment(start, n);
    return;
  }
  local.resize(n);
  for (Eigen::Index k = 0; k < n; ++k) local[k] = x[index[k]];
}

/// local = the part's entries of the world vector x (velocity coordinates).
inline void gatherV(const SystemModel& s, const Eigen::VectorXd& x, Eigen::VectorXd& local) {
  gather(s.v_index, s.v_start, x, local);
}

/// local = the part's entries of the world configuration q.
inline void gatherQ(const SystemModel& s, const Eigen::VectorXd& q, Eigen::VectorXd& local) {
  gather(s.q_index, s.q_start, q, local);
}

/// The part's entries of the world vector x = local.
inline void scatterV(const SystemModel& s, const Eigen::VectorXd& local, Eigen::VectorXd& x) {
  if (s.v_start >= 0) {
    x.segment(s.v_start, local.size()) = local;
    return;
  }
  for (Eigen::Index k = 0; k < local.size(); ++k) x[s.v_index[k]] = local[k];
}

/// True when the problem is one part's alone, its rows the problem's rows in order and its
/// coordinates the world's (a robot on the ground): the products need no gather or scatter.
inline bool wholeWorldPart(const SimulatorModel& sim, const SimulatorData& sd) {
  return sd.work->parts.size() == 1 && static_cast<Eigen::Index>(sd.work->parts[0].rows.size()) == sd.out.rows &&
         sim.systems[0].v_start == 0;
}

/// The world placement of world joint j (the identity for the universe, j = 0).
inline const pinocchio::SE3& jointPlacement(const SimulatorModel& sim, const SimulatorData& sd,
                                            pinocchio::JointIndex j) {
  static const pinocchio::SE3 kIdentity = pinocchio::SE3::Identity();
  if (j == 0) return kIdentity;
  return sd.work->parts[sim.joint_system[j]].data.oMi[sim.joint_local[j]];
}

/// y = J x: the problem's rows of a world velocity x (y sized to sd.out.rows).
void multiplyJacobian(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& x, Eigen::VectorXd& y);

/// dv = M^-1 J^T lambda in world coordinates, from each part's factor M = U D U^T.
void solveJacobianTransposed(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& lambda,
                             Eigen::VectorXd& dv);

// ---- timing

using Clock = FastClock;  // the time-stamp counter (clock.hpp)

inline double microseconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::micro>(b - a).count();
}

/// Charges the time since its start (or its last lap) to a StepTimings field at each lap:
/// one clock read per group of stages (a read costs ~10 ns, a robot's step ~5 us).
class Stopwatch {
 public:
  Stopwatch() : last_(Clock::now()) {}
  explicit Stopwatch(Clock::time_point start) : last_(start) {}
  void lap(double& field) {
    const Clock::time_point now = Clock::now();
    field += microseconds(last_, now);
    last_ = now;
  }

 private:
  Clock::time_point last_;
};

// ---- candidates: rows, friction, the 3-slot layout

/// Rows of a contact of model m and friction mu: 1 (n), 2 (t1, n) or 3 (t1, t2, n);
/// mu = 0 reduces to the unilateral row.
inline int rowsOf(ContactModel m, double mu) {
  if (m == ContactModel::kFrictionless || mu == 0.0) return 1;
  return m == ContactModel::kPlanar ? 2 : 3;
}

/// Rows of candidate i (a sphere contact or a pair slot).
inline int candidateRows(const SimulatorModel& sim, int i) {
  if (sim.slot_pair[i] < 0) return rowsOf(sim.contacts[i].model, sim.contacts[i].mu);
  const GeometryPairContact& g = sim.pairs[sim.slot_pair[i]];
  return rowsOf(g.model, g.mu);
}

/// Friction coefficient of candidate i.
inline double candidateMu(const SimulatorModel& sim, int i) {
  return sim.slot_pair[i] < 0 ? sim.contacts[i].mu : sim.pairs[sim.slot_pair[i]].mu;
}

/// The active contacts' constraints, in the problem's order: 1 row unilateral, 2 planar friction,
/// 3 spatial friction (the full problem and the locked-joints one start alike).
inline void appendContactConstraints(const SimulatorModel& sim, const SimulatorData& sd, std::vector<Constraint>& cons) {
  for (int i : sd.out.active)
    switch (sd.out.candidate_rows[i]) {
      case 1: cons.push_back(Constraint::unilateral()); break;
      case 2: cons.push_back(Constraint::planarFriction(candidateMu(sim, i))); break;
      default: cons.push_back(Constraint::spatialFriction(candidateMu(sim, i)));
    }
}

/// The 3-slot (t1, t2, n) layout from k = 1, 2 or 3 rows.
inline Eigen::Vector3d toSlots(const double* x, int k) {
  if (k == 3) return Eigen::Vector3d(x[0], x[1], x[2]);
  if (k == 2) return Eigen::Vector3d(x[0], 0.0, x[1]);
  return Eigen::Vector3d(0.0, 0.0, x[0]);
}

/// k = 1, 2 or 3 rows from the 3-slot (t1, t2, n) layout.
inline void fromSlots(const Eigen::Vector3d& s, int k, double* x) {
  if (k == 3) {
    x[0] = s[0], x[1] = s[1], x[2] = s[2];
  } else if (k == 2) {
    x[0] = s[0], x[1] = s[2];
  } else {
    x[0] = s[2];
  }
}

}  // namespace stages
}  // namespace stiction
