// The simulator's private workspace (internal to src/cpp/sim/ and the bindings): what a step
// reuses from step to step and no user reads. SimulatorData owns one (SimulatorData::work) for
// its whole life; the stages of a step (stages.hpp) write and read it, and nothing in it is an
// output: the last problem's inspectable results are SimulatorData::out (simulator.hpp).
#pragma once

#include <array>
#include <memory>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/QR>
#include <Eigen/SparseCore>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/geometry.hpp>

#include "broad_phase.hpp"
#include "stiction/contact_problem.hpp"
#include "stiction/delassus.hpp"
#include "stiction/formulation.hpp"
#include "stiction/islands.hpp"
#include "stiction/simulator.hpp"
#include "stiction/solver.hpp"

namespace stiction {

/// One block of the lower triangle of a sparse A shared by parts (two contacts' rows, or anchors'),
/// and where its columns and its mirror's start in the compressed storage (each column's `rows`
/// values are consecutive there): the sum over its one or two parts s of W_s's columns
/// [row, row + rows) transposed times [col, col + cols) (part -1: none; mirror -1: a diagonal block).
struct AssemblyBlock {
  int rows = 0, cols = 0;
  int position[3] = {0, 0, 0}, mirror[3] = {-1, -1, -1};
  int part[2] = {-1, -1}, row[2] = {0, 0}, col[2] = {0, 0};
  bool free_bodies = false;  ///< 3 x 3 between free bodies (W: 6 rows in each part): the fixed-size path
};

/// The target a plan of A's blocks (SimulatorWorkspace::assembly) writes: none, A_sparse's values, or A.
enum class AssemblyKind { kNone, kSparse, kDense };

/// The robot Delassus operator's workspace (src/cpp/sim/robot_delassus.cpp): the problem's blocks
/// of rows, each block's chain (the root path of its deepest coordinate) and its columns of
/// Y = D^-1/2 U^-1 J^T on that chain.
struct RobotOperatorPlan {
  struct Block {
    int row = 0, k = 0;          ///< first row, rows (1-3)
    int start = 0, length = 0;   ///< its chain: chain[start, start + length)
  };
  std::vector<Block> blocks;
  std::vector<int> chain;       ///< every block's chain (ascending coordinates), one after another
  std::vector<int> prefix;      ///< blocks x blocks (f <= g): the length of their common chain
  std::vector<double> scale;    ///< sqrt(D^-1) per coordinate
  std::vector<double> Y;        ///< 4 values per chain entry: the block's values, zero-padded
  bool valid = false;           ///< the plan holds for these active contacts, anchors and joint rows:
  std::vector<int> active;
  std::size_t anchors = 0;
  std::vector<JointRow> joint_rows;
};

/// The workspace of one part: its Pinocchio Data, its coordinates, and its columns of the
/// contact Jacobian (the rows of the contacts that touch it).
struct SystemWork {
  explicit SystemWork(const SystemModel& s);

  pinocchio::Data data;
  std::vector<int> v_index;  ///< the world velocity coordinate of each local one (SystemModel's)
  Eigen::VectorXd q, v, zero, tau, nle, v_free, x;  ///< local coordinates; x: scratch
  Eigen::VectorXd row_values;                       ///< one value per row of J (scratch)
  /// The fused pass's revolute joints, in tree order: angles, then sines, then cosines (each
  /// padded to a multiple of 4: the vector kernel's lanes)
  std::vector<double> trig;
  std::vector<double> Wt;                           ///< a free body's W^T by columns, padded (the vector kernel's)
  std::vector<int> rows;  ///< the problem row of each row of J (contacts touching this part)
  Eigen::MatrixXd J;      ///< rows x nv of the part: its columns of the contact Jacobian
  Eigen::MatrixXd W;      ///< D^-1/2 U^-1 J^T (M = U D U^T)
  Eigen::MatrixXd X;      ///< J's columns under W's back substitution (scratch)
  Eigen::MatrixXd A;      ///< W^T W = J M^-1 J^T of this part (eq. 22)
  /// The coordinates the contacts can move (J's nonzero columns and their ancestors) when they
  /// are few (a humanoid's two legs and base): W, U and D restricted to them.
  std::vector<int> support;
  std::vector<char> in_support;
  Eigen::MatrixXd U_support;
  RobotOperatorPlan robot_plan;
  bool mass_factored = false;  ///< free body: data.M, U, D hold its constant mass matrix and factor
  /// A free body's D^-1/2 U^-1 (row-major, upper triangular), set with its factor: its W = S J^T.
  std::array<double, 36> free_body_scaling{};
  bool has_free_body_scaling = false;
  bool free_body_scaling_diagonal = false;  ///< S is diagonal (a box: centre of mass at its origin)
};

/// A time step solved with the joints' dry friction holding (locked_joints.cpp): the contacts' problem
/// with every friction-row coordinate locked, its operator, solver and scratch, and the prediction.
struct LockedJoints {
  bool held = false;     ///< the last step's joint rows were friction rows only, all sticking
  int skip = 0;          ///< steps left before the next try, after a try whose joints did not hold
  int backoff = 0;       ///< the last skip (doubled at each miss, up to kLockedMaxBackoff)
  bool pending_full = false;          ///< this step's full A and problem not built yet (completeLockedStep)
  const SimulatorModel* sim = nullptr;  ///< the model of that step (for completeLockedStep)
  double scale = 0.0;                 ///< that step's h
  std::vector<char> locked;           ///< per coordinate: locked (its only joint row is its dry friction)
  std::vector<int> free;              ///< the coordinates not locked
  std::vector<int> rows_on;           ///< per coordinate: its joint rows (scratch)
  std::vector<int> kept;              ///< the full problem's rows in the reduced one: contacts, unlocked joints'
  std::vector<int> sticking_rows;     ///< rebalance's: the sticking contacts' rows (scratch)
  std::vector<Eigen::Index> sticking_offsets;  ///< rebalance's: those contacts' first rows (scratch)
  std::vector<std::size_t> sticking_blocks;     ///< rebalance's: those contacts' blocks (scratch)
  // rebalance's matrices, kept so that a step that rebalances allocates only when the sizes change
  Eigen::MatrixXd rb_n, rb_g, rb_q, rb_gb, rb_h;
  Eigen::HouseholderQR<Eigen::MatrixXd> rb_qr;
  Eigen::LDLT<Eigen::MatrixXd> rb_ldlt;
  Eigen::VectorXd rb_xi, rb_d, rb_lam;
  std::vector<int> locked_rows, locked_dofs;  ///< the locked joint rows (index among the joint rows), their coordinates
  std::vector<JointRow> joint_rows;   ///< the joint rows `problem` was built for
  std::vector<JointRow> classified;   ///< the joint rows locked, kept and free were sorted for
  Eigen::Index contact_rows = -1;     ///< with this many contact rows before them
  Eigen::MatrixXd mff, z, a;          ///< M_FF = L L^T (L), J_CF L^-T, the reduced A = Z^T Z
  Eigen::VectorXd xl, y, xf, b, guess, pj;
  Eigen::VectorXd x;   ///< M^-1 J^T P of the step it solved (integrateTimeStep reads it)
  Eigen::MatrixXd msym;  ///< M, both triangles
  std::shared_ptr<DenseDelassus> delassus;
  std::unique_ptr<ContactProblem> problem;
  std::vector<int> active;            ///< the contacts `problem` was built for
  std::unique_ptr<ContactSolver> solver;  ///< its own: the sticking step's held factor stays the full problem's
  SolverResult result;
};

struct SimulatorWorkspace {
  explicit SimulatorWorkspace(const SimulatorModel& sim);

  // Parts (kinematics, Delassus): per part of the world (SimulatorModel::systems), its Data, its
  // columns of J (the output J is assembled from them, denseJacobian) and its factor of M.
  std::vector<SystemWork> parts;
  std::vector<int> part_fill;  ///< per part: rows placed so far (contactJacobians)
  bool parts_share_rows = false;  ///< a contact between two parts: its rows in both
  std::vector<int> row_part, row_local;  ///< per row: its part and local row (rows in one part each)

  // Detection: coal's geometry placements and results (its cached GJK guesses carry over), and
  // each half-space's world axes.
  pinocchio::GeometryData geometry_data;
  BroadPhaseState broad;  ///< the pool of dynamic pairs (broad_phase.hpp)
  Eigen::Matrix3Xd plane_normal, plane_t1, plane_t2;
  Eigen::VectorXd plane_offset;

  /// Each active contact block's bodies (joints of the world model: plus, minus), first row, rows,
  /// frame rows (t1, t2, n as T's first k rows, world) and world point: what the rows measure, for
  /// the consistency projection of redundant contact sets (projectRedundantSets, on a missed step).
  struct ContactBlock {
    std::size_t plus = 0, minus = 0;
    Eigen::Index row = 0;
    int k = 0;
    Eigen::Matrix3d T;
    Eigen::Vector3d point;
  };
  std::vector<ContactBlock> blocks;
  std::vector<int> block_order;  ///< scratch: blocks sorted by their pair of bodies
  Eigen::VectorXd b_before_projection;

  // Dynamics and the Delassus operator.
  Eigen::VectorXd v_free, dv, zero_nv;
  Eigen::VectorXd frame_turn;  ///< omega x v on each free flyer's linear rows, 0 elsewhere
  /// A came from the robot's chains (robotOperator) at the last Delassus stage: its Y (the robot
  /// plan's) is D^-1/2 U^-1 J^T for this J and M
  bool robot_chains = false;
  std::shared_ptr<DenseDelassus> delassus;  ///< dense problems: updated in place from step to step
  std::shared_ptr<SparseDelassus> sparse_delassus;  ///< sparse problems: values updated in place while the pattern holds
  std::vector<Eigen::Triplet<double>> triplets;  ///< the sparse A's entries, part by part, as last assembled
  std::vector<int> triplet_position;  ///< where each sits in A_sparse's compressed storage
  std::vector<std::vector<int>> triplet_part_rows;  ///< each part's rows when the triplets were listed
  std::vector<AssemblyBlock> assembly;  ///< the sparse A's lower triangle, block by block, from the parts' W
  AssemblyKind assembly_kind = AssemblyKind::kNone;  ///< what `assembly` was planned for
  long pattern_version = 0;             ///< counts the sparse A's pattern builds (the plan keeps it)
  long operator_pattern_version = -1;   ///< the pattern sparse_delassus was built with
  bool a_in_operator = false;           ///< this step's A_sparse values were swapped into sparse_delassus
  bool a_known_finite = false;          ///< the assembly found every value of this step's A_sparse finite
  std::vector<const double*> part_w, part_wt;  ///< each part's W, W^T (assembleFromPlan's workspace; point into parts)
  std::vector<int> part_stride;                ///< each part's rows (W^T's column length)

  // Solve: the problem handed to the formulation (kept for the exact-law measure of a result
  // read later), the formulation itself and its warm start.
  std::unique_ptr<ContactProblem> problem;
  std::vector<int> problem_active;
  std::vector<JointRow> problem_joint_rows;
  double problem_scale = 0.0;
  std::unique_ptr<ContactSolver> solver;
  SolverResult cold_result;     ///< the retry from zero after a warm-started solve missed
  std::unique_ptr<IslandSolver> islands;
  long problem_version = 0;  ///< changes with every new `problem` (its blocks or A's pattern): the islands' key  ///< the exact law's problem split into independent islands (islands.hpp)
  Eigen::VectorXd guess, b_scaled;
  Eigen::VectorXd spring_rows;  ///< penalty: the springs per row of the last problem (the formulation's state)

  // Integration. ODE modes: per stage its velocity, acceleration and configuration rate in the
  // Lie algebra (dexp^-1 of the velocity); the step's start (q, v), a stage's increment and scratch.
  Eigen::VectorXd q_tmp, row_velocity;
  std::vector<Eigen::VectorXd> stage_v, stage_a, stage_k;
  Eigen::VectorXd ode_q0, ode_v0, ode_theta, ode_bracket, ode_bracket2, ode_q3, ode_v3, ode_theta3, ode_theta2, ode_v2;

  // Joint rows (joint_rows.cpp): per coordinate, its actuator is a row of this step's problem
  // (effort_row), with the PD's c = tau_ff + kp (q_t - q) + kd v_t and K = kd + h kp (the row's
  // compliance 1 / (h K)); rows forced into the step after a pass without them saturated an actuator
  // or crossed a limit, and the state such a pass restarts from.
  std::vector<char> effort_row, forced_effort, forced_limit;
  std::vector<char> limit_rows;  ///< per joint limit: the sides with a row in the current problem
  Eigen::VectorXd effort_c, effort_k;
  Eigen::VectorXd step_q0, step_v0;
  Eigen::VectorXd control_torque;  ///< the control torque at the step's start (computeControl, clamped)

  /// Sensors (sensors.cpp): the IMU joint's (SimulatorOutputs::accelerometer) quaternion (x, y, z, w)
  /// and twist (local: linear, angular) at the step's start.
  Eigen::Vector4d imu_quaternion0 = Eigen::Vector4d::Zero();
  Eigen::Matrix<double, 6, 1> imu_twist0 = Eigen::Matrix<double, 6, 1>::Zero();

  Eigen::VectorXd row_scratch;  ///< one value per row
  Eigen::VectorXd nv_scratch;   ///< one value per velocity coordinate

  LockedJoints locked;  ///< the joints' dry friction holding: the reduced problem (locked_joints.cpp)

  /// step_derivatives' own workspace (derivatives.cpp: a Pinocchio Data per part for the derivative
  /// passes), made at the first call on this data.
  std::shared_ptr<void> derivatives;
};

}  // namespace stiction
