// The simulator: a Pinocchio model with frictional unilateral contacts and
// bilateral anchors, stepped with the paper's two integration modes.
//
//   M(q) q'' + Phi(q, q', t) = J^T lambda                        (eq. 39)
//   J q'' + J' q' + (2 zeta / delta) J q' + Psi / delta^2
//        in -lim N_C^{U_eps}(lambda)                              (eq. 64)
//
// 1. Time stepping (eq. 70: delta = h, zeta = 1/2): the impulse h lambda
//    solves A (h lambda) - h b in -N(...), then v+ = v_free + M^-1 J^T h lambda
//    and q+ = integrate(q, h v+) (symplectic Euler on the configuration manifold).
// 2. The relaxed DAI as an ODE (eq. 39 + 64): lambda(q, q') from eq. 65 at every
//    right-hand-side evaluation, integrated by RK4 or by an embedded
//    Bogacki-Shampine 3(2) pair with error control; delta, zeta are free.
//
// Model/Data split as in Pinocchio: SimulatorModel is the immutable
// description, SimulatorData the state (q, v, t, control), the last step's
// outputs (SimulatorOutputs) and a private workspace (src/cpp/sim/workspace.hpp),
// sized once: a step allocates only when the number of active contacts changes.
#pragma once

#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/SparseCore>
#include <pinocchio/multibody/geometry.hpp>
#include <pinocchio/multibody/model.hpp>

#include "stiction/contact_problem.hpp"
#include "stiction/formulation.hpp"
#include "stiction/solver.hpp"

namespace stiction {

/// The half-space {x : normal . x >= offset} is free space; its boundary is a
/// ground, a wall, or (frame != 0) a face of a body of the model, e.g. the top
/// of a cube that carries another one. normal and offset are expressed in that
/// frame. Tangents complete the normal to a right-handed frame (t1, t2, normal),
/// the row order of every contact on it.
struct HalfSpace {
  std::string name;
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();
  double offset = 0.0;
  pinocchio::FrameIndex frame = 0;  ///< 0: fixed in the world
  Eigen::Vector3d tangent1 = Eigen::Vector3d::UnitX();
  Eigen::Vector3d tangent2 = Eigen::Vector3d::UnitY();
};

/// The rows of a friction contact: spatial (t1, t2, n), planar (t1, n: planar
/// scenes, t2 the out-of-plane tangent), frictionless (n: one unilateral row).
/// A spatial or planar contact with mu = 0 is built as the frictionless row
/// (fewer rows, same physics: the tangential impulse is 0).
enum class ContactModel { kSpatial = 0, kPlanar = 1, kFrictionless = 2 };

/// A sphere of `radius` (0: a point, e.g. a box corner) fixed at `offset` in
/// frame `frame`, touching half-space `halfspace` with friction `mu`.
struct SphereContact {
  std::string name;
  pinocchio::FrameIndex frame = 0;
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();
  double radius = 0.0;
  int halfspace = 0;
  double mu = 0.5;
  ContactModel model = ContactModel::kSpatial;
};

/// A collision pair of the scene's GeometryModel handled by coal: general shapes
/// (meshes, boxes, capsules, ...). Each step coal reports up to `max_contacts`
/// points (signed distance below the activation distance); each becomes a
/// spatial friction contact with the normal coal gives (from the pair's first
/// geometry to its second). Velocities are relative between the two bodies.
struct GeometryPairContact {
  std::string name;
  pinocchio::PairIndex pair = 0;  ///< index into GeometryModel::collisionPairs
  double mu = 0.5;
  int max_contacts = 4;
  ContactModel model = ContactModel::kSpatial;  ///< spatial or frictionless (planar: spheres only)
  /// Flat faces need a manifold, not coal's one deepest point (a box on a box would rock on
  /// it): with `patch`, the points are coal's contact patch (the overlap polygon of the two
  /// support sets, computeContactPatch), reduced to the max_contacts most spread vertices.
  bool patch = false;
  /// A pool entry instead of a listed pair (`pair` is then ignored): each step the broad phase
  /// (sweep-and-prune over every geometry's AABB, broad_phase.hpp) finds the overlapping pairs of
  /// shapes of different joints, and each takes a free entry for as long as it keeps overlapping.
  /// Detection grows as N, and a scene of N bodies needs ~ a few N entries, not N^2 / 2 pairs.
  bool dynamic = false;
};

/// A point of frame `frame` (at `offset`) held at the world point `target`, or
/// (frame2 != 0) at the point `offset2` of frame `frame2`: 3 bilateral rows
/// (paper §3, eq. 24-27), e.g. a pendulum pinned to the world, or a closed loop.
struct PointAnchor {
  std::string name;
  pinocchio::FrameIndex frame = 0;
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();
  Eigen::Vector3d target = Eigen::Vector3d::Zero();
  pinocchio::FrameIndex frame2 = 0;  ///< 0: the world point `target`
  Eigen::Vector3d offset2 = Eigen::Vector3d::Zero();
};

enum class IntegrationMode { kTimeStepping = 0, kRK4 = 1, kAdaptive = 2 };

struct SimulatorSettings {
  double dt = 1e-3;               ///< time step (RK4: at most rk4StableStep(delta, zeta)), max step (adaptive)
  IntegrationMode mode = IntegrationMode::kTimeStepping;
  double delta = 0.0;             ///< ODE modes: Baumgarte time constant (eq. 64); 0 = dt
  double zeta = 0.5;              ///< ODE modes: damping ratio (eq. 64)
  double ode_tolerance = 1e-6;    ///< adaptive mode: local error per unit time
  double min_dt = 1e-7;           ///< adaptive mode: smallest step before giving up
  double activation_distance = 0.02;  ///< a candidate enters the problem when its gap is below this
  std::string solver = "default";
  SolverSettings solver_settings;  ///< tolerance, iterations (warm start is set per step)
  /// How each step's problem is resolved (formulation.hpp): "exact" (eq. 65, with `solver`),
  /// "ccp", "nakaoka", "pyramid", "penalty" (time stepping only), "pinocchio-admm", ...
  std::string formulation = "exact";
  FormulationSettings formulation_settings;  ///< pyramid facets, penalty K and beta (exact_solver: `solver`)
  bool warm_start = true;          ///< start each solve from the previous step's lambda
  bool implicit_pd = true;         ///< time stepping: the joint PD implicit in the step (stable for any gains)
  /// The rigid-body passes (placements, joint Jacobians, M, nle, M's factor and solves, the
  /// configuration update): "fused" (default: src/cpp/sim/tree.cpp's one pass per robot and the
  /// free bodies' fixed-size code, a speed choice) or "pinocchio" (Pinocchio's own
  /// forwardKinematics, computeJointJacobians, crba, nonLinearEffects, cholesky::decompose and
  /// solve, integrate and difference for every part: the reference the fused passes are checked
  /// against, docs/simulator.md).
  std::string rigid_body_passes = "fused";
  /// The joints' own rows of the step problem (docs/joint-rows.md), each from the Pinocchio model
  /// (the URDF's <limit lower upper effort> and <dynamics friction damping>):
  /// position limits of 1-dof joints as unilateral rows, beside the contacts, within
  /// `joint_limit_margin` of a limit (or about to cross it in the step);
  bool joint_limits = true;
  /// dry friction (model.friction > 0) as box rows |lambda| <= tau_c (exact stiction);
  bool joint_friction = true;
  /// viscous damping (model.damping) implicit in the step, as the PD's damping is;
  bool joint_damping = true;
  /// actuator effort limits (0 < model.effortLimit < inf): |feed-forward + PD| <= effortLimit. With the
  /// implicit PD (time stepping) the actuator's impulse is a box row of the problem with the PD as its
  /// compliance, for the joints near saturation; else the torque is clamped.
  bool effort_limits = true;
  double joint_limit_margin = 0.02;  ///< rad or m: a limit's row enters the problem within this distance
};

/// A 1-dof joint's position limits (either finite; model.lowerPositionLimit, upperPositionLimit).
struct JointLimit {
  pinocchio::JointIndex joint = 0;
  int idx_q = 0, idx_v = 0;
  double lower = 0.0, upper = 0.0;  ///< -inf / +inf: no limit on that side
};

/// The kinds of a joint's row of the step problem (after the contacts and anchors).
enum class JointRowKind {
  kLowerLimit = 0,  ///< unilateral, J = +e_dof, gap q - lower
  kUpperLimit = 1,  ///< unilateral, J = -e_dof, gap upper - q
  kFriction = 2,    ///< box |lambda| <= tau_c, J = e_dof (the joint velocity)
  kEffort = 3,      ///< box |lambda| <= effortLimit: the actuator torque, the implicit PD its compliance
};

/// One joint row of the last problem: its kind, velocity coordinate and (limits) the index into
/// SimulatorModel::joint_limits.
struct JointRow {
  JointRowKind kind = JointRowKind::kFriction;
  int dof = 0;
  int limit = -1;
  double gap = 0.0;  ///< limits: the distance to the limit at the problem's state (q - lower, upper - q)
  /// the same row (its gap aside)
  bool operator==(const JointRow& o) const { return kind == o.kind && dof == o.dof && limit == o.limit; }
};

/// Joint-space control: tau = kp (q_target - q) + kd (v_target - v) + tau_ff on
/// the actuated velocity coordinates (kp, kd = 0 elsewhere, e.g. a free base).
struct JointControl {
  Eigen::VectorXd kp, kd;     ///< nv
  Eigen::VectorXd q_target;   ///< nq (difference taken on the manifold)
  Eigen::VectorXd v_target;   ///< nv
  Eigen::VectorXd tau_ff;     ///< nv
};

/// One joint as the fused kinematics pass (src/cpp/sim/tree.cpp) and the joint-by-joint PD and
/// integration read it: revolute or prismatic about x, y, z (`axis`) or any unit `direction`, or
/// a free flyer.
struct TreeJoint {
  enum class Kind { kRevolute, kPrismatic, kFreeFlyer };
  Kind kind = Kind::kRevolute;
  int axis = -1;                                         ///< 0, 1, 2: x, y, z; -1: `direction`
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();  ///< the unit axis in the joint's frame
  int parent = 0, idx_q = 0, idx_v = 0;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  ///< jointPlacement
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  bool rotation_identity = true;
};

/// The joints of `model` for the fused pass (entry j for joint j; entry 0 unused), or empty when
/// one is of another kind (planar, spherical, unbounded, ...: Pinocchio's forward kinematics).
std::vector<TreeJoint> treeOf(const pinocchio::Model& model);

/// An independent part of the world: a subtree of the model hanging from the universe (a
/// robot, a free body), given a Model of its own so that its Data is sized by its own nv
/// (a Pinocchio Data holds nv^3 tensors: one Data for 64 free cubes in one Model is 1.9 GB).
/// Parts interact only through contacts: A = sum over parts of J_s M_s^-1 J_s^T (eq. 22),
/// block-sparse when the parts are many.
struct SystemModel {
  pinocchio::Model model;
  /// Its joints for the fused kinematics pass (treeOf); empty: Pinocchio's forwardKinematics.
  std::vector<TreeJoint> tree;
  std::vector<int> q_index, v_index;  ///< the world coordinate of each local q, v coordinate
  int q_start = -1, v_start = -1;     ///< the first world coordinate when contiguous (else -1)
  /// One free-flyer joint: its mass matrix in its own frame (Pinocchio's LOCAL convention) is
  /// constant, factored once rather than every step (unless a joint PD adds to its diagonal).
  /// (Never with rigid_body_passes "pinocchio": a free body is then a tree like any other.)
  bool free_body = false;
  /// rigid_body_passes "pinocchio": M and nle by Pinocchio's crba and nonLinearEffects, M's factor
  /// and solves by its cholesky::decompose and solve (tree empty, free_body false).
  bool pinocchio_passes = false;
  /// Each coordinate's ancestors in M's tree (itself first, then up to the root: Pinocchio's
  /// parents_fromRow followed), coordinate k's at ancestors[ancestors_start[k], ancestors_start[k + 1]).
  /// A list walked by index: following parents_fromRow chains a load per step (its latency, ~6
  /// cycles, was the backward pass's critical path).
  std::vector<int> ancestors_start, ancestors;
};

class SimulatorModel {
 public:
  SimulatorModel(const pinocchio::Model& model, std::vector<HalfSpace> halfspaces,
                 std::vector<SphereContact> contacts, std::vector<PointAnchor> anchors,
                 SimulatorSettings settings, const pinocchio::GeometryModel& geometry = {},
                 std::vector<GeometryPairContact> pairs = {});

  pinocchio::Model model;
  std::vector<HalfSpace> halfspaces;
  std::vector<SphereContact> contacts;
  std::vector<PointAnchor> anchors;
  SimulatorSettings settings;
  pinocchio::GeometryModel geometry;       ///< shapes for the coal pairs (may be empty)
  std::vector<GeometryPairContact> pairs;

  // derived
  std::vector<pinocchio::JointIndex> free_flyers;
  /// The joints whose configuration holds a unit quaternion (free flyers, spherical) and where
  /// in q it starts (x, y, z, w): checked at a trajectory's first step.
  std::vector<std::pair<pinocchio::JointIndex, int>> quaternions;
  /// A joint whose configuration space is a non-commutative Lie group, and the velocity
  /// coordinates of its Lie algebra: the ODE modes correct their configuration increments there
  /// by the dexp^-1 series (Runge-Kutta-Munthe-Kaas, integrate.cpp); every other joint's group
  /// (R^n, SO(2)) commutes and needs no correction.
  struct LieAlgebraJoint {
    enum class Group { kSE3, kSE2, kSO3 } group;  ///< free flyer, planar, spherical
    int idx_v = 0;
  };
  std::vector<LieAlgebraJoint> non_abelian_joints;
  /// The world's joints as treeOf describes them (revolute and prismatic: vector-space joints,
  /// q (+) v = q + v and q1 (-) q0 = q1 - q0 as Pinocchio's Lie groups compute them; free flyers),
  /// or empty when another kind is among them: the joint PD and the configuration update then go
  /// through Pinocchio's difference and integrate over the whole model.
  std::vector<TreeJoint> tree;
  /// The parts of the world (one per subtree of the universe), in the order of their roots.
  std::vector<SystemModel> systems;
  std::vector<int> joint_system;                   ///< world joint -> its part (-1: the universe)
  std::vector<pinocchio::JointIndex> joint_local;  ///< world joint -> its index in its part's model
  /// Candidates: the sphere contacts, then max_contacts slots per pair.
  int numCandidates() const { return num_candidates; }
  int num_candidates = 0;
  std::vector<int> slot_pair;  ///< per candidate: -1 for a sphere contact, else its pair
  std::vector<int> pair_first_slot;  ///< per pair: its first candidate
  std::vector<int> dynamic_pairs;    ///< the pairs that are pool entries (GeometryPairContact::dynamic)
  /// Broad phase: each geometry's bounding sphere (centre in its joint's frame, radius; a
  /// half-space or plane: infinite), so a pair farther apart than the activation distance
  /// skips coal.
  std::vector<Eigen::Vector3d> geometry_center;
  std::vector<double> geometry_radius;
  /// The joints' rows (settings.joint_limits, joint_friction, effort_limits; docs/joint-rows.md):
  /// the limited 1-dof joints, and per velocity coordinate its dry friction tau_c, effort limit
  /// (0: none) and viscous damping (0 when off).
  std::vector<JointLimit> joint_limits;
  Eigen::VectorXd joint_friction, effort_limit, joint_damping;
  std::vector<int> friction_dofs, effort_dofs;  ///< the coordinates with friction, with an effort limit
  std::vector<int> dof_part, dof_local;  ///< per world velocity coordinate: its part and local coordinate
  std::vector<pinocchio::JointIndex> dof_joint;  ///< per world velocity coordinate: its joint
};

/// Microseconds spent per phase in the last step (summed over RHS evaluations in ODE modes).
struct StepTimings {
  double kinematics = 0.0;  ///< forward kinematics, Jacobians, contact detection and frames
  double delassus = 0.0;    ///< M, its Cholesky, A = J M^-1 J^T, b
  double solve = 0.0;
  double integrate = 0.0;
  double total = 0.0;
};

/// The last contact problem and step, for inspection (Python's sim.data.A, .b, .candidate_lambda, ...) and
/// for the next step. Written by the stages of step() / buildContactProblem / contactsAtState
/// (src/cpp/sim/), read by the bindings, the rollout recorder and a C++ user; valid until the next
/// step overwrites it. Sized once by SimulatorData's constructor (per candidate, per anchor) or
/// per problem (per row: resized only when the number of rows changes).
struct SimulatorOutputs {
  // The last contact problem (active blocks in candidate order, then anchors).
  std::vector<int> active;           ///< candidate index of each active contact block
  /// Rows of the problem: per contact (t1, t2, n), (t1, n) or (n), then anchors. The Jacobian
  /// J (rows x nv) is held by columns of parts (the workspace's); denseJacobian() assembles it.
  Eigen::Index rows = 0;
  Eigen::MatrixXd A;                 ///< rows x rows, J M^-1 J^T (eq. 22), when dense
  /// The same when sparse (many parts, > 96 rows). After a solve it may hold the previous step's
  /// values (this step's were swapped into the workspace's Delassus operator, no copy): read A
  /// through denseDelassus(), which takes them from wherever they are.
  Eigen::SparseMatrix<double> A_sparse;
  bool sparse = false;               ///< which of A, A_sparse holds the last problem's operator
  Eigen::VectorXd b;                 ///< eq. 27 at force level
  Eigen::VectorXd drift;             ///< J' v per row
  Eigen::VectorXd position_error;    ///< Psi per row (gap on normal rows, anchor error; 0 else)
  Eigen::VectorXd tangent_row;       ///< 1 on tangential rows, 0 on normal and anchor rows
  /// nv: the joints' generalized force in the last problem's dynamics (M v_free = tau - nle): the
  /// control torque of the actuators without an effort row, minus the implicit PD's h kp v and the damping
  Eigen::VectorXd tau;
  Eigen::VectorXd nle;               ///< nv: C(q, v) v + g(q) at the last problem built
  Eigen::VectorXd gaps;              ///< signed distance per candidate contact
  Eigen::VectorXd lambda;            ///< forces per row of the last solve
  SolverResult result;               ///< the last solve
  int inconsistent_groups = 0;       ///< redundant contact sets whose b was projected this step

  // Per candidate / anchor, after the last solve (inactive candidates: 0, open). The solve
  // stage reads candidate_lambda back as the next step's warm start and candidate_spring as
  // the penalty formulation's spring state.
  Eigen::MatrixXd candidate_lambda;  ///< 3 x candidates, force (t1, t2, n); planar: t2 = 0; 1 row: t1 = t2 = 0
  std::vector<bool> have_candidate_lambda;
  std::vector<int> candidate_rows;   ///< rows of each candidate in the last problem (0: inactive)
  std::vector<ContactState> candidate_states;
  Eigen::MatrixXd anchor_lambda;     ///< 3 x anchors
  /// The joint rows of the last problem (after the anchors, one row each; their forces in `lambda`).
  std::vector<JointRow> joint_rows;
  /// nv, after the last step: the actuator torque applied (feed-forward + PD at the step's end, after
  /// saturation; 0 where nothing acts), the joints' dry friction torque and position limits' torque (0
  /// where the joint had no such row). Time stepping: the step's impulses / h.
  Eigen::VectorXd actuator_torque, friction_torque, limit_torque;
  Eigen::MatrixXd candidate_spring;  ///< penalty: tangential spring elongation e_t per candidate (t1, t2, 0)
  Eigen::MatrixXd candidate_velocity;  ///< 3 x candidates, contact velocity J v after the step
  /// coal pairs: the contact each slot holds now (per candidate; pair slots only)
  Eigen::Matrix3Xd slot_point, slot_normal, slot_t1, slot_t2;

  // Sensors of the last step (src/cpp/sim/sensors.cpp; docs/simulator.md, "Sensors"), written at its end.
  /// 3 x candidates: each candidate's force in the world frame, N: candidate_lambda (t1, t2, n) turned
  /// by the contact frame its problem was built in (time stepping: the step's start; ODE modes: the last
  /// right-hand side's). The force on the contact's own body (the sphere's; a coal pair's second
  /// geometry's); the other side (a moving half-space's body, the first geometry's) gets its opposite.
  Eigen::Matrix3Xd contact_force;
  /// The IMU at the origin of the first free flyer hanging from the universe (a robot's base), in its
  /// frame at the step's start: the proper acceleration R0^T (a - g) of the step, a = (R1 v1 - R0 v0) / h
  /// the change of the origin's world velocity (at rest +|g| up, 0 in a free fall). NaN without such
  /// a joint or before a step.
  Eigen::Vector3d accelerometer = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  double sensor_time = std::numeric_limits<double>::quiet_NaN();  ///< t when the sensors were read (NaN: no step yet)

  // Statistics of the last step (ODE modes solve once per right-hand side).
  StepTimings timings;
  int rhs_evaluations = 0;
  int solves = 0;
  int iterations_step = 0;
  double max_residual_step = 0.0;
  bool all_converged_step = true;
  double last_dt = 0.0;  ///< the step actually taken
  double next_dt = 0.0;  ///< adaptive mode: the proposal for the next step (read by it)
};

/// Everything a step reuses from step to step and nobody outside src/cpp/sim/ reads: scratch
/// vectors, the parts' Pinocchio Data and Jacobian columns, assembly plans, solver and Delassus
/// objects. Defined in src/cpp/sim/workspace.hpp (internal); owned by its SimulatorData.
struct SimulatorWorkspace;

/// Model/Data split as in Pinocchio: the state (q, v, t, control) that a user sets, the outputs
/// of the last step, and the private workspace. Sized once by the constructor; a step allocates
/// only when the number of active contacts changes. Not copyable (one workspace per data).
class SimulatorData {
 public:
  explicit SimulatorData(const SimulatorModel& sim);
  ~SimulatorData();
  SimulatorData(const SimulatorData&) = delete;
  SimulatorData& operator=(const SimulatorData&) = delete;

  // ---- state: written by the user (or the bindings) and by step(), which advances it.
  Eigen::VectorXd q, v;
  double t = 0.0;
  JointControl control;
  /// Blow-up check (step()): the state when the trajectory started; set at the first step after
  /// construction or after q, v or t were assigned (reference_speed < 0: whoever assigns q, v
  /// or t sets it to -1, as the bindings do).
  double reference_speed = -1.0;        ///< ||v||_inf at the start
  double reference_time = 0.0;
  double reference_penetration = 0.0;   ///< deepest active penetration after the first step

  // ---- outputs of the last problem and step: written by the stages, read by anyone.
  SimulatorOutputs out;

  // ---- workspace: written and read by the stages only (src/cpp/sim/), lives as long as
  // this data (an opaque type outside the simulator's own sources).
  std::unique_ptr<SimulatorWorkspace> work;
};

/// The contact Jacobian J (rows x nv) of the last problem, assembled from the parts' columns.
Eigen::MatrixXd denseJacobian(const SimulatorData& sd);

/// The mass matrix M (nv x nv, symmetric) of the last step, assembled from the parts'.
Eigen::MatrixXd denseMassMatrix(const SimulatorData& sd);

/// The world position of every sphere contact's centre (a point contact: the point) at each
/// configuration, a row of Q (N x nq): N x (3 contacts), x, y, z per contact. No world Data.
Eigen::MatrixXd contactCenters(const SimulatorModel& sim, const Eigen::MatrixXd& Q);

/// The world placement of every joint of the world model (joint 0: the identity) at each
/// configuration, a row of Q: N x (12 joints), per joint the rotation (column-major) then the
/// translation. Part by part: no world Data.
Eigen::MatrixXd jointPlacements(const SimulatorModel& sim, const Eigen::MatrixXd& Q);

/// The Delassus operator A of the last problem as a dense matrix.
Eigen::MatrixXd denseDelassus(const SimulatorData& sd);

/// A step solved with its joints locked (their dry friction holding: docs/joint-rows.md) leaves its
/// full A and problem unbuilt; this builds them (sd.out.A, the problem of get_result's measures) from
/// that step's J and M. Nothing to do otherwise. denseDelassus calls it.
void completeLockedStep(const SimulatorData& sd);

/// Advance sim_data by one step (time stepping: exactly dt; ODE modes: one
/// RK4 step of dt, or one accepted adaptive step of at most dt).
/// Throws std::runtime_error naming t and the culprit when the state becomes
/// non-finite, when it blows up (a speed above 10 (|v_0| + |g| t) + 50, or a
/// contact penetrating deeper than max(0.1 m, 10 activation distances) + 10 times
/// its initial depth), or when a contact problem has no solution (SolveStatus
/// kInfeasible, e.g. a contact on something that cannot move) or forces so large
/// that double precision cannot verify even a 1e-6 tolerance (kUnresolvable with
/// precision_floor > 1e-6). A solve that merely misses the tolerance is recorded
/// (all_converged_step = false), not thrown.
void step(const SimulatorModel& sim, SimulatorData& sd);

/// The contacts of the current state (q, v) without a step, for a trajectory's first record:
/// kinematics, detection and the contact Jacobians (stages 1-3) give sd.out.gaps (every candidate's
/// signed distance), the active set with sd.out.candidate_rows, and sd.out.candidate_velocity = J v of the
/// active candidates (0 for the others, as after a step). Nothing is solved: candidate_lambda and
/// candidate_states keep the last step's. coal's cached GJK guesses are put back, so the next step
/// computes exactly what it would have without this call.
void contactsAtState(const SimulatorModel& sim, SimulatorData& sd);

/// The contact problem (eq. 65) at the current state, for inspection and tests:
/// fills sd.out.A (or A_sparse), sd.out.b (force level, eq. 27 with the given delta, zeta), sd.out.active and
/// the parts' columns of J (denseJacobian).
/// implicit_pd_step = h > 0 folds the joint PD implicitly over a step h into M (time stepping).
void buildContactProblem(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                         const Eigen::VectorXd& v, double delta, double zeta, double implicit_pd_step = 0.0);

/// tau from the joint control at (q, v).
void computeControl(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                    const Eigen::VectorXd& v);

}  // namespace stiction
