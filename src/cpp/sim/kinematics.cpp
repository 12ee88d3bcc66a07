// Stages 1 and 3: forward kinematics, then the rows of the active contacts and anchors
// (J, the drift J' v, the position error Psi).
#include <pinocchio/algorithm/frames.hpp>
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
  pinocchio::forwardKinematics(sim.model, sd.data, q, v, sd.zero_nv);
  pinocchio::computeJointJacobians(sim.model, sd.data);
}

void contactJacobians(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v) {
  const pinocchio::Model& model = sim.model;
  pinocchio::Data& data = sd.data;
  Eigen::Index rows = 3 * static_cast<Eigen::Index>(sim.anchors.size());
  for (int i : sd.active) rows += sd.candidate_rows[i];
  const int nv = model.nv;
  if (sd.J.rows() != rows) {  // allocation only when the active set changes size
    sd.J.resize(rows, nv);
    sd.b.resize(rows);
    sd.drift.resize(rows);
    sd.position_error.resize(rows);
    sd.tangent_row.resize(rows);
  }
  sd.position_error.setZero();
  sd.tangent_row.setZero();

  // Contact frames, Jacobians J (rows t1, t2, n), drifts J' v and gaps Psi.
  sd.frame_turn.setZero(nv);
  for (pinocchio::JointIndex j : sim.free_flyers) {
    const int iv = model.idx_vs[j];
    sd.frame_turn.segment<3>(iv) = v.segment<3>(iv + 3).cross(v.segment<3>(iv));
  }
  Eigen::Index row = 0;
  for (int i : sd.active) {
    if (sim.slot_pair[i] >= 0) {
      // coal contact: relative velocity of geometry 2's material point w.r.t. geometry 1's
      const pinocchio::CollisionPair& cp = sim.geometry.collisionPairs[sim.pairs[sim.slot_pair[i]].pair];
      const pinocchio::JointIndex j1 = sim.geometry.geometryObjects[cp.first].parentJoint;
      const pinocchio::JointIndex j2 = sim.geometry.geometryObjects[cp.second].parentJoint;
      const Eigen::Vector3d p = sd.slot_point.col(i), n = sd.slot_normal.col(i);
      const Eigen::Vector3d t1 = sd.slot_t1.col(i), t2 = sd.slot_t2.col(i);
      sd.Jrel.setZero(3, nv);
      for (int side = 0; side < 2; ++side) {
        const pinocchio::JointIndex j = side == 0 ? j2 : j1;
        if (j == 0) continue;  // fixed in the world
        const double sign = side == 0 ? 1.0 : -1.0;
        const pinocchio::SE3 at(Eigen::Matrix3d::Identity(), data.oMi[j].actInv(p));
        sd.J6.setZero();
        pinocchio::getFrameJacobian(model, data, j, at, pinocchio::LOCAL_WORLD_ALIGNED, sd.J6);
        sd.Jrel += sign * sd.J6.topRows<3>();
      }
      // The drift of a coal row is that of a motion whose free-flyer origins keep
      // their world velocity (J c, c = omega x v on each free flyer's linear rows):
      // the material points' accelerations are not the gap's (a rolling sphere's
      // contact point accelerates towards its centre while the gap stays 0), and for
      // general shapes the gap's curvature terms are not available; the position
      // term Psi / delta^2 keeps the constraint.
      if (sd.candidate_rows[i] == 3) {  // else frictionless (or mu = 0): the normal row only
        sd.J.row(row) = t1.transpose() * sd.Jrel;
        sd.drift[row] = sd.J.row(row).dot(sd.frame_turn);
        sd.tangent_row[row++] = 1.0;
        sd.J.row(row) = t2.transpose() * sd.Jrel;
        sd.drift[row] = sd.J.row(row).dot(sd.frame_turn);
        sd.tangent_row[row++] = 1.0;
      }
      sd.J.row(row) = n.transpose() * sd.Jrel;
      sd.drift[row] = sd.J.row(row).dot(sd.frame_turn);
      sd.position_error[row++] = sd.gaps[i];
      continue;
    }
    const SphereContact& c = sim.contacts[i];
    const pinocchio::Frame& f = model.frames[c.frame];
    const HalfSpace& h = sim.halfspaces[c.halfspace];
    const Eigen::Vector3d n = sd.plane_normal.col(c.halfspace);
    const Eigen::Vector3d t1 = sd.plane_t1.col(c.halfspace), t2 = sd.plane_t2.col(c.halfspace);
    const pinocchio::JointIndex j = f.parentJoint;
    const Eigen::Vector3d center_j = f.placement.act(c.offset);
    const Eigen::Vector3d point_w = data.oMi[j].act(center_j) - c.radius * n;
    const pinocchio::SE3 at_point(Eigen::Matrix3d::Identity(), data.oMi[j].actInv(point_w));
    sd.J6.setZero();
    pinocchio::getFrameJacobian(model, data, j, at_point, pinocchio::LOCAL_WORLD_ALIGNED, sd.J6);
    // Tangential rows: the material point at the contact (slip velocity); normal
    // row: the sphere's centre, whose normal motion is exactly the gap's.
    Eigen::Vector3d acc_point =
        pinocchio::getFrameClassicalAcceleration(model, data, j, at_point, pinocchio::LOCAL_WORLD_ALIGNED).linear();
    const pinocchio::SE3 at_center(Eigen::Matrix3d::Identity(), center_j);
    Eigen::Vector3d acc_center =
        pinocchio::getFrameClassicalAcceleration(model, data, j, at_center, pinocchio::LOCAL_WORLD_ALIGNED).linear();
    sd.Jrel = sd.J6.topRows<3>();
    if (h.frame != 0) {
      // A body's face: velocities relative to the face's material point at the
      // contact. (The face's rotation adds terms of order |omega| |v_rel| to the
      // drift that are left out; the position term corrects what they would.)
      const pinocchio::JointIndex jp = model.frames[h.frame].parentJoint;
      const pinocchio::SE3 plane_at_point(Eigen::Matrix3d::Identity(), data.oMi[jp].actInv(point_w));
      sd.J6.setZero();
      pinocchio::getFrameJacobian(model, data, jp, plane_at_point, pinocchio::LOCAL_WORLD_ALIGNED, sd.J6);
      sd.Jrel -= sd.J6.topRows<3>();
      const Eigen::Vector3d acc_plane = pinocchio::getFrameClassicalAcceleration(
          model, data, jp, plane_at_point, pinocchio::LOCAL_WORLD_ALIGNED).linear();
      acc_point -= acc_plane;
      acc_center -= acc_plane;
    }
    const int k = sd.candidate_rows[i];
    if (k >= 2) {  // planar and spatial: t1 (planar scenes: the in-plane tangent)
      sd.J.row(row) = t1.transpose() * sd.Jrel;
      sd.drift[row] = t1.dot(acc_point);
      sd.tangent_row[row] = 1.0;
      ++row;
    }
    if (k == 3) {
      sd.J.row(row) = t2.transpose() * sd.Jrel;
      sd.drift[row] = t2.dot(acc_point);
      sd.tangent_row[row] = 1.0;
      ++row;
    }
    sd.J.row(row) = n.transpose() * sd.Jrel;
    sd.drift[row] = n.dot(acc_center);
    sd.position_error[row] = sd.gaps[i];
    ++row;
  }
  for (const PointAnchor& a : sim.anchors) {
    // point 1 (frame, offset) against point 2: the world point `target`, or with
    // frame2 != 0 the point (frame2, offset2) of another body: a closed loop.
    const pinocchio::Frame& f = model.frames[a.frame];
    const pinocchio::JointIndex j = f.parentJoint;
    const Eigen::Vector3d point_j = f.placement.act(a.offset);
    const pinocchio::SE3 at_point(Eigen::Matrix3d::Identity(), point_j);
    sd.J6.setZero();
    pinocchio::getFrameJacobian(model, data, j, at_point, pinocchio::LOCAL_WORLD_ALIGNED, sd.J6);
    sd.J.middleRows(row, 3) = sd.J6.topRows<3>();
    sd.drift.segment<3>(row) =
        pinocchio::getFrameClassicalAcceleration(model, data, j, at_point, pinocchio::LOCAL_WORLD_ALIGNED).linear();
    Eigen::Vector3d other = a.target;
    if (a.frame2 != 0) {
      const pinocchio::Frame& f2 = model.frames[a.frame2];
      const pinocchio::JointIndex j2 = f2.parentJoint;
      const Eigen::Vector3d point2_j = f2.placement.act(a.offset2);
      other = data.oMi[j2].act(point2_j);
      if (j2 != 0) {
        const pinocchio::SE3 at_point2(Eigen::Matrix3d::Identity(), point2_j);
        sd.J6.setZero();
        pinocchio::getFrameJacobian(model, data, j2, at_point2, pinocchio::LOCAL_WORLD_ALIGNED, sd.J6);
        sd.J.middleRows(row, 3) -= sd.J6.topRows<3>();
        sd.drift.segment<3>(row) -=
            pinocchio::getFrameClassicalAcceleration(model, data, j2, at_point2, pinocchio::LOCAL_WORLD_ALIGNED).linear();
      }
    }
    sd.position_error.segment<3>(row) = data.oMi[j].act(point_j) - other;
    row += 3;
  }
}

}  // namespace stages
}  // namespace stiction
