// Stages 1 and 3: forward kinematics of every part of the world, then the rows of the active
// contacts and anchors (J by columns of parts, the drift J' v, the position error Psi).
#include <array>
#include <stdexcept>
#include <string>

#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>

#include "stages.hpp"

namespace stiction {
namespace stages {

void forwardKinematics(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                       const Eigen::VectorXd& v) {
  // Kinematics with zero acceleration: the classical accelerations it leaves are J' v.
  // (computeAllTerms does it all in one pass but is slower here: it also computes
  // the centre of mass and its Jacobian.)
  for (std::size_t s = 0; s < sim.systems.size(); ++s) {
    const SystemModel& part = sim.systems[s];
    SystemWork& w = sd.work->parts[s];
    gatherQ(part, q, w.q);
    gatherV(part, v, w.v);
    if (part.free_body) {
      freeBodyKinematics(part.model, w);
      continue;
    }
    if (!part.tree.empty()) {
      treeKinematics(part, w);
      continue;
    }
    pinocchio::forwardKinematics(part.model, w.data, w.q, w.v, w.zero);
    pinocchio::computeJointJacobians(part.model, w.data);
    worldFrameTerms(part.model, w.data);
  }
}

void freeBodyKinematics(const pinocchio::Model& model, SystemWork& w) {
  // What Pinocchio's forward kinematics computes for one free flyer (q = position and unit
  // quaternion x y z w, v in its own frame), in the same operations: oMi = its joint placement
  // times M(q); v its velocity; at zero acceleration a = v x v = 0. Its joint Jacobian is not
  // needed: the rows and nle of a free body use R and v directly (writeRows, freeDynamics).
  // (Pinocchio's generic passes over a one-joint model were ~8 % of a 256-box tower's step.)
  const Eigen::Map<const Eigen::Quaterniond> quaternion(w.q.data() + 3);
  const pinocchio::SE3 joint_motion(quaternion.matrix(), w.q.head<3>());
  w.data.oMi[1] = model.jointPlacements[1] * joint_motion;
  w.data.v[1] = pinocchio::Motion(w.v.head<3>(), w.v.segment<3>(3));
  w.data.a[1].setZero();
}

namespace {

// The two bodies of a block of rows: the rows measure the velocity of a point of `plus`
// relative to a point of `minus` (joint 0: the world, which does not move).
struct BlockBodies {
  pinocchio::JointIndex plus = 0, minus = 0;
};

BlockBodies contactBodies(const SimulatorModel& sim, const SimulatorData& sd, int i) {
  if (sim.slot_pair[i] >= 0) {  // coal: geometry 2's material point w.r.t. geometry 1's
    const GeometryPairContact& g = sim.pairs[sim.slot_pair[i]];
    if (g.dynamic) {  // the pair the broad phase gave this entry
      const auto& held = sd.work->broad.geoms[static_cast<std::size_t>(sim.slot_pair[i])];
      return {sim.geometry.geometryObjects[held[1]].parentJoint, sim.geometry.geometryObjects[held[0]].parentJoint};
    }
    const pinocchio::CollisionPair& cp = sim.geometry.collisionPairs[g.pair];
    return {sim.geometry.geometryObjects[cp.second].parentJoint, sim.geometry.geometryObjects[cp.first].parentJoint};
  }
  const SphereContact& c = sim.contacts[i];
  const HalfSpace& h = sim.halfspaces[c.halfspace];
  return {sim.model.frames[c.frame].parentJoint, h.frame != 0 ? sim.model.frames[h.frame].parentJoint : 0};
}

BlockBodies anchorBodies(const SimulatorModel& sim, const PointAnchor& a) {
  return {sim.model.frames[a.frame].parentJoint, a.frame2 != 0 ? sim.model.frames[a.frame2].parentJoint : 0};
}

int partOf(const SimulatorModel& sim, pinocchio::JointIndex j) { return j == 0 ? -1 : sim.joint_system[j]; }

// The parts a block touches: its plus body's, then its minus body's when another (-1: none).
std::array<int, 2> blockParts(const SimulatorModel& sim, const BlockBodies& b) {
  const int s1 = partOf(sim, b.plus), s2 = partOf(sim, b.minus);
  return {s1, s2 != s1 ? s2 : -1};
}

// Jrel += sign [R, -[R r]x R]: the world velocity of the material point r (joint frame) of a free
// flyer whose velocity is (v, omega) in its own frame.
inline void addFreeBodyPointJacobian(const Eigen::Matrix3d& R, const Eigen::Vector3d& r, double sign,
                                     Eigen::Matrix<double, 3, 6>& Jrel) {
  const Eigen::Vector3d rw = R * r;
  Eigen::Matrix3d skew;
  skew << 0.0, -rw.z(), rw.y(), rw.z(), 0.0, -rw.x(), -rw.y(), rw.x(), 0.0;
  Jrel.leftCols<3>() += sign * R;
  Jrel.rightCols<3>().noalias() -= sign * (skew * R);
}

// Rows [lr, lr + k) of a robot part's J += sign T (rows 0..k-1) times the world velocity Jacobian of
// the material point r (in joint j's frame): from the world-frame joint Jacobian of stage 1, a
// column (v_o, omega) moves the point p = oMi r at v_o + omega x p. Only the columns of j and its
// ancestors (Pinocchio's parents_fromRow) are nonzero. Written into J entry by entry (a 3 x nv
// point Jacobian first and T times it after, as before, read that Jacobian's columns back two
// values at a time right after writing them, loads spanning two stores, and multiplied its zero
// columns too).
void addPointRows(const SystemModel& part, SystemWork& w, pinocchio::JointIndex j, const Eigen::Vector3d& r,
                  const Eigen::Matrix3d& T, int k, int lr, double sign) {
  const pinocchio::Model& m = part.model;
  const Eigen::Vector3d p = w.data.oMi[j].act(r);
  const double px = p.x(), py = p.y(), pz = p.z();
  const Eigen::Index n = w.J.rows();
  double* J = w.J.data();
  const int deepest = m.idx_vs[j] + m.nvs[j] - 1;  // (its ancestors: the joint's and the root path's)
  for (auto a = part.ancestors.begin() + part.ancestors_start[static_cast<std::size_t>(deepest)];
       a != part.ancestors.begin() + part.ancestors_start[static_cast<std::size_t>(deepest) + 1]; ++a) {
    const int c = *a;
    const double* col = w.data.J.col(c).data();  // (v_o, omega)
    const double ux = col[0] + col[4] * pz - col[5] * py;
    const double uy = col[1] + col[5] * px - col[3] * pz;
    const double uz = col[2] + col[3] * py - col[4] * px;
    for (int q = 0; q < k; ++q) J[c * n + lr + q] += sign * (T(q, 0) * ux + T(q, 1) * uy + T(q, 2) * uz);
  }
}

// Rows [row, row + k) of the problem belong to the parts the block touches.
void reserveRows(const SimulatorModel& sim, SimulatorData& sd, const BlockBodies& b, Eigen::Index row, int k) {
  const std::array<int, 2> parts = blockParts(sim, b);
  if (parts[0] >= 0 && parts[1] >= 0) sd.work->parts_share_rows = true;
  for (int s : parts)
    if (s >= 0)
      for (int r = 0; r < k; ++r) sd.work->parts[s].rows.push_back(static_cast<int>(row + r));
}

// The block's next k rows in each part it touches: T (rows 0..k-1) times the relative point
// Jacobian, the plus body's point `at_plus` (in its joint's frame) minus the minus body's
// `at_minus`. `local_rows` receives each part's first local row.
void writeRows(const SimulatorModel& sim, SimulatorData& sd, const BlockBodies& b, const Eigen::Vector3d& at_plus,
               const Eigen::Vector3d& at_minus, const Eigen::Matrix3d& T, int k, std::array<int, 2>& local_rows) {
  const std::array<int, 2> parts = blockParts(sim, b);
  for (int p = 0; p < 2; ++p) {
    const int s = parts[p];
    local_rows[p] = -1;
    if (s < 0) continue;
    const pinocchio::Model& m = sim.systems[s].model;
    SystemWork& w = sd.work->parts[s];
    if (sim.systems[s].free_body) {
      // One free flyer (v = (v, omega) in its own frame): a material point r (joint frame) moves at
      // R (v + omega x r) = R v - [R r]x R omega. (Pinocchio's frame Jacobian, 6 x 6 from the joint
      // Jacobian, was half of a tower's kinematics.) Fixed sizes throughout.
      const Eigen::Matrix3d& R = w.data.oMi[1].rotation();
      Eigen::Matrix<double, 3, 6> Jrel = Eigen::Matrix<double, 3, 6>::Zero();
      if (partOf(sim, b.plus) == s) addFreeBodyPointJacobian(R, at_plus, 1.0, Jrel);
      if (partOf(sim, b.minus) == s) addFreeBodyPointJacobian(R, at_minus, -1.0, Jrel);
      const int lr = sd.work->part_fill[s];
      sd.work->part_fill[s] += k;
      for (int r = 0; r < k; ++r) w.J.row(lr + r) = T.row(r) * Jrel;  // (T's rows past k unset)
      local_rows[p] = lr;
      continue;
    }
    const int lr = sd.work->part_fill[s];
    sd.work->part_fill[s] += k;
    for (int r = 0; r < k; ++r) w.J.row(lr + r).setZero();
    if (partOf(sim, b.plus) == s) addPointRows(sim.systems[s], w, sim.joint_local[b.plus], at_plus, T, k, lr, 1.0);
    if (partOf(sim, b.minus) == s) addPointRows(sim.systems[s], w, sim.joint_local[b.minus], at_minus, T, k, lr, -1.0);
    local_rows[p] = lr;
  }
}

// The classical acceleration J' v of the point `at` (in joint j's frame), in world axes; 0 for
// the world.
Eigen::Vector3d pointAcceleration(const SimulatorModel& sim, SimulatorData& sd, pinocchio::JointIndex j,
                                  const Eigen::Vector3d& at) {
  if (j == 0) return Eigen::Vector3d::Zero();
  const int s = sim.joint_system[j];
  if (sim.systems[s].free_body) {
    // a free flyer at zero acceleration: R (omega x (v + omega x r)), its velocity in its own frame
    const pinocchio::Motion& vj = sd.work->parts[s].data.v[1];
    const Eigen::Vector3d v_point = vj.linear() + vj.angular().cross(at);
    return sd.work->parts[s].data.oMi[1].rotation() * vj.angular().cross(v_point);
  }
  // a robot body: from its world-frame velocity (v_o, omega) and bias acceleration (a_o, alpha)
  // (stage 1), the material point p moves at v_o + omega x p and accelerates at
  // a_o + alpha x p + omega x (v_o + omega x p)
  const pinocchio::Data& data = sd.work->parts[s].data;
  const pinocchio::JointIndex local = sim.joint_local[j];
  const Eigen::Vector3d p = data.oMi[local].act(at);
  const pinocchio::Motion &ov = data.ov[local], &oa = data.oa[local];
  const Eigen::Vector3d v_point = ov.linear() + ov.angular().cross(p);
  return oa.linear() + oa.angular().cross(p) + ov.angular().cross(v_point);
}

// Row `local_row` of part s's J times the part's entries of the world vector x.
double partRowDot(const SimulatorModel& sim, const SimulatorData& sd, int s, int local_row, const Eigen::VectorXd& x) {
  const SystemModel& part = sim.systems[s];
  const SystemWork& w = sd.work->parts[s];
  if (part.v_start >= 0) return w.J.row(local_row).dot(x.segment(part.v_start, w.J.cols()));
  double sum = 0.0;
  for (Eigen::Index k = 0; k < w.J.cols(); ++k) sum += w.J(local_row, k) * x[part.v_index[k]];
  return sum;
}

}  // namespace

void contactJacobians(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v) {
  const pinocchio::Model& model = sim.model;
  // Which rows each part holds (a contact between two parts: both), then the parts' J.
  for (SystemWork& w : sd.work->parts) w.rows.clear();
  sd.work->parts_share_rows = false;
  Eigen::Index rows = 0;
  for (int i : sd.out.active) {
    reserveRows(sim, sd, contactBodies(sim, sd, i), rows, sd.out.candidate_rows[i]);
    rows += sd.out.candidate_rows[i];
  }
  for (const PointAnchor& a : sim.anchors) {
    reserveRows(sim, sd, anchorBodies(sim, a), rows, 3);
    rows += 3;
  }
  for (const JointRow& r : sd.out.joint_rows) {  // one row in the part of its coordinate
    sd.work->parts[static_cast<std::size_t>(sim.dof_part[static_cast<std::size_t>(r.dof)])].rows.push_back(static_cast<int>(rows));
    rows += 1;
  }
  sd.out.rows = rows;
  for (std::size_t s = 0; s < sd.work->parts.size(); ++s) {
    SystemWork& w = sd.work->parts[s];
    const auto n = static_cast<Eigen::Index>(w.rows.size());
    if (w.J.rows() != n) w.J.resize(n, sim.systems[s].model.nv);  // allocation only when the active set changes
    sd.work->part_fill[s] = 0;
  }
  if (sd.out.b.size() != rows) {
    sd.out.b.resize(rows);
    sd.out.drift.resize(rows);
    sd.out.position_error.resize(rows);
    sd.out.tangent_row.resize(rows);
  }
  sd.out.position_error.setZero();
  sd.out.tangent_row.setZero();

  // Contact frames, Jacobians J (rows t1, t2, n), drifts J' v and gaps Psi.
  sd.work->frame_turn.setZero(model.nv);
  for (pinocchio::JointIndex j : sim.free_flyers) {
    const int iv = model.idx_vs[j];
    sd.work->frame_turn.segment<3>(iv) = v.segment<3>(iv + 3).cross(v.segment<3>(iv));
  }
  Eigen::Matrix3d T;
  std::array<int, 2> local_rows;
  Eigen::Index row = 0;
  sd.work->blocks.clear();
  auto keep_block = [&](const BlockBodies& bodies, Eigen::Index first, int k, const Eigen::Vector3d& point) {
    SimulatorWorkspace::ContactBlock block;
    block.plus = bodies.plus;
    block.minus = bodies.minus;
    block.row = first;
    block.k = k;
    block.T = T;
    block.point = point;
    sd.work->blocks.push_back(block);
  };
  for (int i : sd.out.active) {
    const BlockBodies bodies = contactBodies(sim, sd, i);
    const int k = sd.out.candidate_rows[i];
    if (sim.slot_pair[i] >= 0) {
      // coal contact: relative velocity of geometry 2's material point w.r.t. geometry 1's
      const Eigen::Vector3d p = sd.out.slot_point.col(i), n = sd.out.slot_normal.col(i);
      const Eigen::Vector3d at_plus = jointPlacement(sim, sd, bodies.plus).actInv(p);
      const Eigen::Vector3d at_minus = jointPlacement(sim, sd, bodies.minus).actInv(p);
      if (k == 3) {  // else frictionless (or mu = 0): the normal row only
        T.row(0) = sd.out.slot_t1.col(i).transpose();
        T.row(1) = sd.out.slot_t2.col(i).transpose();
      }
      T.row(k - 1) = n.transpose();
      writeRows(sim, sd, bodies, at_plus, at_minus, T, k, local_rows);
      keep_block(bodies, row, k, p);
      // The drift of a coal row is that of a motion whose free-flyer origins keep
      // their world velocity (J c, c = omega x v on each free flyer's linear rows):
      // the material points' accelerations are not the gap's (a rolling sphere's
      // contact point accelerates towards its centre while the gap stays 0), and for
      // general shapes the gap's curvature terms are not available; the position
      // term Psi / delta^2 keeps the constraint.
      const std::array<int, 2> parts = blockParts(sim, bodies);
      for (int r = 0; r < k; ++r) {
        double drift = 0.0;
        for (int p = 0; p < 2; ++p)
          if (parts[p] >= 0) drift += partRowDot(sim, sd, parts[p], local_rows[p] + r, sd.work->frame_turn);
        sd.out.drift[row + r] = drift;
        sd.out.tangent_row[row + r] = r + 1 < k ? 1.0 : 0.0;
      }
      sd.out.position_error[row + k - 1] = sd.out.gaps[i];
      row += k;
      continue;
    }
    const SphereContact& c = sim.contacts[i];
    const pinocchio::Frame& f = model.frames[c.frame];
    const Eigen::Vector3d n = sd.work->plane_normal.col(c.halfspace);
    const Eigen::Vector3d t1 = sd.work->plane_t1.col(c.halfspace), t2 = sd.work->plane_t2.col(c.halfspace);
    const pinocchio::SE3& oMj = jointPlacement(sim, sd, bodies.plus);
    const Eigen::Vector3d center_j = f.placement.act(c.offset);
    const Eigen::Vector3d point_w = oMj.act(center_j) - c.radius * n;
    const Eigen::Vector3d at_point = oMj.actInv(point_w);
    // A body's face (minus != 0): velocities relative to the face's material point at the
    // contact. (The face's rotation adds terms of order |omega| |v_rel| to the drift that
    // are left out; the position term corrects what they would.)
    const Eigen::Vector3d plane_at_point = jointPlacement(sim, sd, bodies.minus).actInv(point_w);
    int r = 0;
    if (k >= 2) T.row(r++) = t1.transpose();  // planar and spatial: t1 (planar scenes: the in-plane tangent)
    if (k == 3) T.row(r++) = t2.transpose();
    T.row(r) = n.transpose();
    writeRows(sim, sd, bodies, at_point, plane_at_point, T, k, local_rows);
    keep_block(bodies, row, k, point_w);
    // Tangential rows: the material point at the contact (slip velocity); normal
    // row: the sphere's centre, whose normal motion is exactly the gap's.
    const Eigen::Vector3d acc_plane = pointAcceleration(sim, sd, bodies.minus, plane_at_point);
    const Eigen::Vector3d acc_point = pointAcceleration(sim, sd, bodies.plus, at_point) - acc_plane;
    // (a point contact, radius 0: the centre is the point, up to the rounding of the round trip
    // through world coordinates; its acceleration is then computed once)
    const Eigen::Vector3d acc_center = c.radius == 0.0 && at_point == center_j
                                           ? acc_point
                                           : pointAcceleration(sim, sd, bodies.plus, center_j) - acc_plane;
    r = 0;
    if (k >= 2) {
      sd.out.drift[row + r] = t1.dot(acc_point);
      sd.out.tangent_row[row + r++] = 1.0;
    }
    if (k == 3) {
      sd.out.drift[row + r] = t2.dot(acc_point);
      sd.out.tangent_row[row + r++] = 1.0;
    }
    sd.out.drift[row + r] = n.dot(acc_center);
    sd.out.position_error[row + r] = sd.out.gaps[i];
    row += k;
  }
  for (const PointAnchor& a : sim.anchors) {
    // point 1 (frame, offset) against point 2: the world point `target`, or with
    // frame2 != 0 the point (frame2, offset2) of another body: a closed loop.
    const BlockBodies bodies = anchorBodies(sim, a);
    const Eigen::Vector3d point_j = model.frames[a.frame].placement.act(a.offset);
    const Eigen::Vector3d& at_point = point_j;
    Eigen::Vector3d other = a.target;
    Eigen::Vector3d at_point2 = Eigen::Vector3d::Zero();
    if (a.frame2 != 0) {
      const Eigen::Vector3d point2_j = model.frames[a.frame2].placement.act(a.offset2);
      other = jointPlacement(sim, sd, bodies.minus).act(point2_j);
      at_point2 = point2_j;
    }
    writeRows(sim, sd, bodies, at_point, at_point2, Eigen::Matrix3d::Identity(), 3, local_rows);
    sd.out.drift.segment<3>(row) = pointAcceleration(sim, sd, bodies.plus, at_point) -
                               (a.frame2 != 0 ? pointAcceleration(sim, sd, bodies.minus, at_point2)
                                              : Eigen::Vector3d::Zero());
    sd.out.position_error.segment<3>(row) = jointPlacement(sim, sd, bodies.plus).act(point_j) - other;
    row += 3;
  }
  // The joints' rows (joint_rows.cpp): J = +-e_dof, no drift; a limit's gap as the position error.
  for (const JointRow& r : sd.out.joint_rows) {
    const auto s = static_cast<std::size_t>(sim.dof_part[static_cast<std::size_t>(r.dof)]);
    SystemWork& w = sd.work->parts[s];
    const int lr = sd.work->part_fill[s]++;
    w.J.row(lr).setZero();
    const bool upper = r.kind == JointRowKind::kUpperLimit;
    w.J(lr, sim.dof_local[static_cast<std::size_t>(r.dof)]) = upper ? -1.0 : 1.0;
    sd.out.drift[row] = 0.0;
    sd.out.position_error[row] = r.gap;
    row += 1;
  }
}

}  // namespace stages

namespace {

// Placements of every part at configurations given one at a time: a Data per part (no world
// Data), forward kinematics only.
class PartPlacements {
 public:
  PartPlacements(const SimulatorModel& sim, const Eigen::MatrixXd& Q, const char* fn) : sim_(sim) {
    if (Q.cols() != sim.model.nq)
      throw std::invalid_argument(std::string(fn) + ": configurations need nq = " + std::to_string(sim.model.nq) +
                                  " columns, got " + std::to_string(Q.cols()));
    for (const SystemModel& part : sim.systems) {
      datas_.emplace_back(part.model);
      zeros_.push_back(Eigen::VectorXd::Zero(part.model.nv));
    }
  }
  void update(const Eigen::VectorXd& q) {
    for (std::size_t s = 0; s < sim_.systems.size(); ++s) {
      stages::gatherQ(sim_.systems[s], q, q_s_);
      pinocchio::forwardKinematics(sim_.systems[s].model, datas_[s], q_s_, zeros_[s], zeros_[s]);
    }
  }
  /// The world placement of world joint j at the last update (the identity for the universe).
  pinocchio::SE3 joint(pinocchio::JointIndex j) const {
    return j == 0 ? pinocchio::SE3::Identity() : datas_[sim_.joint_system[j]].oMi[sim_.joint_local[j]];
  }

 private:
  const SimulatorModel& sim_;
  std::vector<pinocchio::Data> datas_;
  std::vector<Eigen::VectorXd> zeros_;
  Eigen::VectorXd q_s_;
};

}  // namespace

Eigen::MatrixXd contactCenters(const SimulatorModel& sim, const Eigen::MatrixXd& Q) {
  PartPlacements placements(sim, Q, "contact_centers");
  const auto nc = static_cast<Eigen::Index>(sim.contacts.size());
  Eigen::MatrixXd out(Q.rows(), 3 * nc);
  for (Eigen::Index k = 0; k < Q.rows(); ++k) {
    placements.update(Q.row(k).transpose());
    for (Eigen::Index i = 0; i < nc; ++i) {
      const SphereContact& c = sim.contacts[i];
      const pinocchio::Frame& f = sim.model.frames[c.frame];
      out.block<1, 3>(k, 3 * i) = placements.joint(f.parentJoint).act(f.placement.act(c.offset)).transpose();
    }
  }
  return out;
}

Eigen::MatrixXd jointPlacements(const SimulatorModel& sim, const Eigen::MatrixXd& Q) {
  PartPlacements placements(sim, Q, "joint_placements");
  const Eigen::Index nj = sim.model.njoints;
  Eigen::MatrixXd out(Q.rows(), 12 * nj);
  for (Eigen::Index k = 0; k < Q.rows(); ++k) {
    placements.update(Q.row(k).transpose());
    for (Eigen::Index j = 0; j < nj; ++j) {
      const pinocchio::SE3 M = placements.joint(static_cast<pinocchio::JointIndex>(j));
      for (int c = 0; c < 3; ++c)
        for (int r = 0; r < 3; ++r) out(k, 12 * j + 3 * c + r) = M.rotation()(r, c);
      for (int r = 0; r < 3; ++r) out(k, 12 * j + 9 + r) = M.translation()[r];
    }
  }
  return out;
}

}  // namespace stiction
