// Stage 1 for a robot part, fused: one pass over its joints gives what Pinocchio's
// forwardKinematics + computeJointJacobians gave (placements oMi, the world-frame joint Jacobian
// J) and, in world coordinates, each body's spatial velocity ov and bias acceleration oa (at zero
// joint acceleration: the classical accelerations they give are J' v), its inertia oY and the
// force of rnea's forward pass, of = oY (oa - g) + ov x* (oY ov). Stage 4's backward pass
// (compositeBackwardPass) sums those into M and nle = C(q, v) v + g(q) without a second pass
// over the joints' kinematics.
//
// Measured on Solo-12 (18 coordinates, 13 joints): Pinocchio's forwardKinematics and
// computeJointJacobians cost 1.6 us of a 7.8 us step (its generic joint visitors, local-frame
// velocities transformed joint by joint, Data written through Eigen::Ref); the joints here are
// the kinds robots are made of (revolute and prismatic about x, y, z or any axis, free flyer),
// each in fixed-size code. A part with any other joint keeps Pinocchio's pass (treeOf returns
// an empty description), followed by worldFrameTerms.
#include <cmath>

#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/multibody/joint/joints.hpp>

#include "stages.hpp"

namespace stiction {

std::vector<TreeJoint> treeOf(const pinocchio::Model& model) {
  std::vector<TreeJoint> tree(static_cast<std::size_t>(model.njoints));
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j) {
    TreeJoint& t = tree[j];
    const std::string kind = model.joints[j].shortname();
    const auto& joint = model.joints[j].toVariant();
    if (kind == "JointModelFreeFlyer") {
      t.kind = TreeJoint::Kind::kFreeFlyer;
    } else if (kind == "JointModelRX" || kind == "JointModelRY" || kind == "JointModelRZ") {
      t.kind = TreeJoint::Kind::kRevolute;
      t.axis = kind.back() - 'X';
    } else if (kind == "JointModelPX" || kind == "JointModelPY" || kind == "JointModelPZ") {
      t.kind = TreeJoint::Kind::kPrismatic;
      t.axis = kind.back() - 'X';
    } else if (kind == "JointModelRevoluteUnaligned") {
      t.kind = TreeJoint::Kind::kRevolute;
      t.direction = boost::get<pinocchio::JointModelRevoluteUnaligned>(joint).axis;
    } else if (kind == "JointModelPrismaticUnaligned") {
      t.kind = TreeJoint::Kind::kPrismatic;
      t.direction = boost::get<pinocchio::JointModelPrismaticUnaligned>(joint).axis;
    } else {
      return {};  // (planar, spherical, unbounded revolute, ...: Pinocchio's pass)
    }
    if (t.axis >= 0) t.direction = Eigen::Vector3d::Unit(t.axis);
    t.parent = static_cast<int>(model.parents[j]);
    t.idx_q = model.idx_qs[j];
    t.idx_v = model.idx_vs[j];
    t.rotation = model.jointPlacements[j].rotation();
    t.translation = model.jointPlacements[j].translation();
    t.rotation_identity = t.rotation == Eigen::Matrix3d::Identity();
  }
  return tree;
}

namespace stages {

namespace {

// The spatial cross product of motions (v1, w1) x (v2, w2) = (w1 x v2 + v1 x w2, w1 x w2).
inline pinocchio::Motion cross(const pinocchio::Motion& a, const pinocchio::Motion& b) {
  return pinocchio::Motion(a.angular().cross(b.linear()) + a.linear().cross(b.angular()),
                           a.angular().cross(b.angular()));
}

}  // namespace

void treeKinematics(const SystemModel& part, SystemWork& w) {
  const pinocchio::Model& model = part.model;
  pinocchio::Data& data = w.data;
  const double* q = w.q.data();
  const double* v = w.v.data();
  data.oMi[0].setIdentity();
  data.ov[0].setZero();
  data.oa[0].setZero();
  for (int i = 1; i < model.njoints; ++i) {
    const TreeJoint& t = part.tree[static_cast<std::size_t>(i)];
    const pinocchio::SE3& parent = data.oMi[t.parent];
    pinocchio::SE3& oMi = data.oMi[i];
    // the joint's frame at q = 0 in the world: the parent's placement times jointPlacement
    Eigen::Matrix3d R0;
    if (t.rotation_identity)
      R0 = parent.rotation();
    else
      R0.noalias() = parent.rotation() * t.rotation;
    Eigen::Vector3d p = parent.translation();
    p.noalias() += parent.rotation() * t.translation;
    // S q' in the world (the joint's motion subspace times its velocity)
    pinocchio::Motion motion;
    switch (t.kind) {
      case TreeJoint::Kind::kRevolute: {
        const double c = std::cos(q[t.idx_q]), s = std::sin(q[t.idx_q]);
        Eigen::Matrix3d& R = oMi.rotation();
        if (t.axis >= 0) {
          // R0 times the rotation by q about axis k: columns k1, k2 turn in their plane
          const int k = t.axis, k1 = (k + 1) % 3, k2 = (k + 2) % 3;
          R.col(k) = R0.col(k);
          R.col(k1) = c * R0.col(k1) + s * R0.col(k2);
          R.col(k2) = c * R0.col(k2) - s * R0.col(k1);
        } else {
          // Rodrigues: c I + s [u]x + (1 - c) u u^T
          const Eigen::Vector3d& u = t.direction;
          Eigen::Matrix3d turn = (1.0 - c) * u * u.transpose();
          turn.diagonal().array() += c;
          turn(0, 1) -= s * u.z(), turn(1, 0) += s * u.z();
          turn(0, 2) += s * u.y(), turn(2, 0) -= s * u.y();
          turn(1, 2) -= s * u.x(), turn(2, 1) += s * u.x();
          R.noalias() = R0 * turn;
        }
        oMi.translation() = p;
        const Eigen::Vector3d axis = R0 * t.direction;  // (unchanged by the turn about it)
        auto column = data.J.col(t.idx_v);
        column.head<3>() = p.cross(axis);
        column.tail<3>() = axis;
        motion = pinocchio::Motion(v[t.idx_v] * column.head<3>(), v[t.idx_v] * axis);
        break;
      }
      case TreeJoint::Kind::kPrismatic: {
        const Eigen::Vector3d axis = R0 * t.direction;
        oMi.rotation() = R0;
        oMi.translation() = p + q[t.idx_q] * axis;
        auto column = data.J.col(t.idx_v);
        column.head<3>() = axis;
        column.tail<3>().setZero();
        motion = pinocchio::Motion(v[t.idx_v] * axis, Eigen::Vector3d::Zero());
        break;
      }
      case TreeJoint::Kind::kFreeFlyer: {
        // q = (x, y, z, qx, qy, qz, qw), v = (linear, angular) in the joint's own frame
        const Eigen::Map<const Eigen::Quaterniond> quaternion(q + t.idx_q + 3);
        oMi.rotation().noalias() = R0 * quaternion.matrix();
        oMi.translation() = p;
        oMi.translation().noalias() += R0 * Eigen::Map<const Eigen::Vector3d>(q + t.idx_q);
        const Eigen::Matrix3d& R = oMi.rotation();
        const Eigen::Vector3d& o = oMi.translation();
        for (int k = 0; k < 3; ++k) {  // oMi's action matrix: a local unit motion seen in the world
          auto linear = data.J.col(t.idx_v + k), angular = data.J.col(t.idx_v + 3 + k);
          linear.head<3>() = R.col(k);
          linear.tail<3>().setZero();
          angular.head<3>() = o.cross(R.col(k));
          angular.tail<3>() = R.col(k);
        }
        const Eigen::Vector3d omega = R * Eigen::Map<const Eigen::Vector3d>(v + t.idx_v + 3);
        motion = pinocchio::Motion(R * Eigen::Map<const Eigen::Vector3d>(v + t.idx_v) + o.cross(omega), omega);
        break;
      }
    }
    // velocity, and acceleration at q'' = 0: the world-frame S moves with the body (S' = ov x S)
    data.ov[i] = data.ov[t.parent] + motion;
    data.oa[i] = data.oa[t.parent] + cross(data.ov[i], motion);
  }
  worldFrameInertias(model, data);
}

void worldFrameTerms(const pinocchio::Model& model, pinocchio::Data& data) {
  for (int i = 1; i < model.njoints; ++i) {
    data.ov[i] = data.oMi[i].act(data.v[i]);
    data.oa[i] = data.oMi[i].act(data.a[i]);
  }
  worldFrameInertias(model, data);
}

void worldFrameInertias(const pinocchio::Model& model, pinocchio::Data& data) {
  // gravity as an upward acceleration of the world (rnea's a_gf = a - g)
  const pinocchio::Motion minus_g(-model.gravity.linear(), Eigen::Vector3d::Zero());
  for (int i = 1; i < model.njoints; ++i) {
    const pinocchio::Inertia& Y = data.oYcrb[i] = data.oMi[i].act(model.inertias[i]);
    data.of[i] = Y * (data.oa[i] + minus_g) + data.ov[i].cross(Y * data.ov[i]);
  }
}

void compositeBackwardPass(const pinocchio::Model& model, pinocchio::Data& data, Eigen::VectorXd& nle) {
  // Column k of M: the composite inertia of k's joint (its subtree) applied to J's column k,
  // dotted with the columns of k and its ancestors (Pinocchio's parents_fromRow); nle[k]: J's
  // column k dotted with the subtree's force. Armature on the diagonal, as crba adds it.
  for (int i = model.njoints - 1; i >= 1; --i) {
    const int iv = model.idx_vs[i], nv_i = model.nvs[i];
    const pinocchio::Force& f = data.of[i];
    for (int k = iv; k < iv + nv_i; ++k) {
      const auto column = data.J.col(k);
      const pinocchio::Force F = data.oYcrb[i] * pinocchio::Motion(column);
      for (int j = k; j >= 0; j = data.parents_fromRow[j])
        data.M(j, k) = data.J.col(j).head<3>().dot(F.linear()) + data.J.col(j).tail<3>().dot(F.angular());
      data.M(k, k) += model.armature[k];
      nle[k] = column.head<3>().dot(f.linear()) + column.tail<3>().dot(f.angular());
    }
    const int parent = static_cast<int>(model.parents[i]);
    if (parent > 0) {
      data.oYcrb[parent] += data.oYcrb[i];
      data.of[parent] += data.of[i];
    }
  }
}

}  // namespace stages
}  // namespace stiction
