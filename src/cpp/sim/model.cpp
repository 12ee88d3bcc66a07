// SimulatorModel and SimulatorData: construction and validation of the model (every index,
// radius, friction coefficient and setting checked before anything runs), and the workspace
// sized once for it.
#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>

#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/multibody/joint/joints.hpp>

#include "stiction/rk4_stability.hpp"
#include "stiction/simulator.hpp"
#include "workspace.hpp"

namespace stiction {

namespace {

void completeTangents(HalfSpace& h) {
  const double n = h.normal.norm();
  if (!(n > 0.0) || !h.normal.allFinite())
    throw std::invalid_argument("half-space '" + h.name + "': normal must be a finite non-zero vector");
  h.normal /= n;
  // t1: the world x axis projected on the plane (y if x is along the normal).
  Eigen::Vector3d e = std::abs(h.normal.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  h.tangent1 = (e - h.normal * h.normal.dot(e)).normalized();
  h.tangent2 = h.normal.cross(h.tangent1);  // (t1, t2, n) right-handed
}

// "robot 'name' (part 'root joint')": where a joint or a part is in the world, for messages.
std::string whereInWorld(const pinocchio::Model& world, pinocchio::JointIndex j) {
  while (j > 0 && world.parents[j] != 0) j = world.parents[j];
  std::string where = world.name.empty() ? "the model" : "robot '" + world.name + "'";
  if (j > 0) where += " (part '" + world.names[j] + "')";
  return where;
}

// The axis of a joint "about any axis" (revolute, unbounded revolute, prismatic, helical), else
// nullptr.
const Eigen::Vector3d* unalignedAxis(const pinocchio::JointModel& joint) {
  const auto& variant = joint.toVariant();
  if (const auto* r = boost::get<pinocchio::JointModelRevoluteUnaligned>(&variant)) return &r->axis;
  if (const auto* u = boost::get<pinocchio::JointModelRevoluteUnboundedUnaligned>(&variant)) return &u->axis;
  if (const auto* p = boost::get<pinocchio::JointModelPrismaticUnaligned>(&variant)) return &p->axis;
  if (const auto* h = boost::get<pinocchio::JointModelHelicalUnaligned>(&variant)) return &h->axis;
  return nullptr;
}

// A joint about any axis needs a unit axis. Pinocchio uses the axis as given (its URDF parser
// normalises it, a joint built in code is not): with |axis| != 1 its revolute "rotation" is not a
// rotation (axis (0, 1, 1), q = 0.7: det 1.75) and a prismatic coordinate is not in metres, so
// its own crba, rnea and Jacobians describe no rigid body. Refused rather than normalised: a
// normalised model would then disagree with Pinocchio's results for the same pinocchio.Model.
void checkJointAxes(const pinocchio::Model& world) {
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(world.njoints); ++j) {
    const Eigen::Vector3d* axis = unalignedAxis(world.joints[j]);
    if (axis == nullptr) continue;
    const double norm = axis->norm();
    if (std::isfinite(norm) && std::abs(norm - 1.0) <= 1e-12) continue;
    std::ostringstream os;
    os.precision(17);
    os << "joint '" << world.names[j] << "' (" << world.joints[j].shortname() << ") of " << whereInWorld(world, j)
       << ": axis (" << axis->x() << ", " << axis->y() << ", " << axis->z() << ") has norm " << norm
       << ", not 1. Pinocchio uses a joint's axis as given (a revolute joint then turns by a matrix that is no "
          "rotation, a prismatic joint's coordinate is not in metres), so the simulator refuses it: build the "
          "joint with axis / |axis| (Pinocchio's URDF parser normalises the axis)";
    throw std::invalid_argument(os.str());
  }
}

// The joints among `joint` (a composite: its sub-joints) whose Lie group does not commute, as
// pinocchio::integrate treats them: q (+) v = q exp(v) on SE(3), SE(2) and SO(3). Every other
// kind integrates on R^n or SO(2) (revolute, prismatic, unbounded revolute, spherical ZYX,
// translation, ...), whose bracket is zero.
void collectNonAbelian(const pinocchio::JointModel& joint, std::vector<SimulatorModel::LieAlgebraJoint>& out) {
  using Group = SimulatorModel::LieAlgebraJoint::Group;
  const std::string kind = joint.shortname();
  const int iv = joint.idx_v();
  if (kind == "JointModelFreeFlyer") {
    out.push_back({Group::kSE3, iv});
  } else if (kind == "JointModelPlanar") {
    out.push_back({Group::kSE2, iv});
  } else if (kind == "JointModelSpherical") {
    out.push_back({Group::kSO3, iv});
  } else if (kind == "JointModelComposite") {
    for (const pinocchio::JointModelVariant& sub : boost::get<pinocchio::JointModelComposite>(joint.toVariant()).joints)
      collectNonAbelian(pinocchio::JointModel(sub), out);
  }
}

// The world's subtrees (children of the universe) as separate models: joints copied in
// order (a parent before its children), with their placements, inertias and armature. With
// `fused`, robots get treeOf's description and single free flyers the free-body path; else
// every part takes Pinocchio's passes.
void splitIntoSystems(const pinocchio::Model& world, bool fused, std::vector<SystemModel>& systems,
                      std::vector<int>& joint_system, std::vector<pinocchio::JointIndex>& joint_local) {
  const auto njoints = static_cast<pinocchio::JointIndex>(world.njoints);
  joint_system.assign(njoints, -1);
  joint_local.assign(njoints, 0);
  for (pinocchio::JointIndex j = 1; j < njoints; ++j) {
    if (world.joints[j].shortname() == "JointModelMimic")
      throw std::invalid_argument("joint '" + world.names[j] + "': mimic joints are not supported by the simulator");
    const pinocchio::JointIndex parent = world.parents[j];
    if (parent == 0) {
      joint_system[j] = static_cast<int>(systems.size());
      systems.emplace_back();
      systems.back().model.name = world.names[j];
      systems.back().model.gravity = world.gravity;
    } else {
      joint_system[j] = joint_system[parent];
    }
    SystemModel& part = systems[joint_system[j]];
    const pinocchio::JointIndex local = part.model.addJoint(parent == 0 ? 0 : joint_local[parent], world.joints[j],
                                                            world.jointPlacements[j], world.names[j]);
    part.model.appendBodyToJoint(local, world.inertias[j], pinocchio::SE3::Identity());
    joint_local[j] = local;
    const int nv_j = world.nvs[j];
    part.model.armature.segment(part.model.idx_vs[local], nv_j) = world.armature.segment(world.idx_vs[j], nv_j);
    for (int k = 0; k < world.nqs[j]; ++k) part.q_index.push_back(world.idx_qs[j] + k);
    for (int k = 0; k < nv_j; ++k) part.v_index.push_back(world.idx_vs[j] + k);
  }
  const auto contiguousStart = [](const std::vector<int>& index) {
    for (std::size_t k = 1; k < index.size(); ++k)
      if (index[k] != index[0] + static_cast<int>(k)) return -1;
    return index.empty() ? -1 : index[0];
  };
  for (SystemModel& part : systems) {
    part.q_start = contiguousStart(part.q_index);
    part.v_start = contiguousStart(part.v_index);
    part.pinocchio_passes = !fused;
    part.free_body = fused && part.model.njoints == 2 && part.model.joints[1].shortname() == "JointModelFreeFlyer";
    if (fused && !part.free_body) part.tree = treeOf(part.model);
    // each coordinate's root path from Pinocchio's own parents_fromRow (a Data of the part)
    const pinocchio::Data data(part.model);
    part.ancestors_start.assign(1, 0);
    part.ancestors.clear();
    for (int k = 0; k < part.model.nv; ++k) {
      for (int c = k; c >= 0; c = data.parents_fromRow[static_cast<std::size_t>(c)]) part.ancestors.push_back(c);
      part.ancestors_start.push_back(static_cast<int>(part.ancestors.size()));
    }
  }
}


// The joints' rows (docs/joint-rows.md) from the model's limits, friction, effort limits and
// damping, as the settings switch them on; each value checked (a NaN or a negative friction is an
// error naming the joint, never a silent default).
void deriveJointRows(const pinocchio::Model& model, const SimulatorSettings& s, std::vector<JointLimit>& limits,
                     Eigen::VectorXd& friction, Eigen::VectorXd& effort, Eigen::VectorXd& damping,
                     std::vector<int>& friction_dofs, std::vector<int>& effort_dofs) {
  if (!(s.joint_limit_margin >= 0.0) || !std::isfinite(s.joint_limit_margin))
    throw std::invalid_argument("joint_limit_margin must be finite and >= 0");
  const int nv = model.nv;
  friction = Eigen::VectorXd::Zero(nv);
  effort = Eigen::VectorXd::Zero(nv);
  damping = Eigen::VectorXd::Zero(nv);
  const auto fail = [&](pinocchio::JointIndex j, const std::string& what, double value) {
    std::ostringstream os;
    os.precision(17);
    os << "joint '" << model.names[j] << "': " << what << " = " << value;
    throw std::invalid_argument(os.str());
  };
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j) {
    const int iv = model.idx_vs[j], iq = model.idx_qs[j];
    for (int k = 0; k < model.nvs[j]; ++k) {
      const double f = model.friction[iv + k], d = model.damping[iv + k], e = model.effortLimit[iv + k];
      if (!(f >= 0.0) || !std::isfinite(f)) fail(j, "friction (model.friction, URDF <dynamics friction>) must be finite and >= 0, got", f);
      if (!(d >= 0.0) || !std::isfinite(d)) fail(j, "damping (model.damping, URDF <dynamics damping>) must be finite and >= 0, got", d);
      if (!(e >= 0.0)) fail(j, "effort limit (model.effortLimit, URDF <limit effort>) must be >= 0 (0 or inf: none), got", e);
      if (s.joint_friction && f > 0.0) {
        friction[iv + k] = f;
        friction_dofs.push_back(iv + k);
      }
      if (s.joint_damping) damping[iv + k] = d;
      // (0, inf and Pinocchio's "unbounded" max double, a free flyer's: no limit)
      if (s.effort_limits && e > 0.0 && e < std::numeric_limits<double>::max()) {
        effort[iv + k] = e;
        effort_dofs.push_back(iv + k);
      }
    }
    if (!s.joint_limits || model.nqs[j] != 1 || model.nvs[j] != 1) continue;  // 1-dof joints (revolute, prismatic)
    const double lo = model.lowerPositionLimit[iq], hi = model.upperPositionLimit[iq];
    if (std::isnan(lo) || std::isnan(hi) || lo > hi) {
      std::ostringstream os;
      os.precision(17);
      os << "joint '" << model.names[j] << "': position limits [" << lo << ", " << hi
         << "] (model.lowerPositionLimit, upperPositionLimit): need lower <= upper, not NaN";
      throw std::invalid_argument(os.str());
    }
    if (!std::isfinite(lo) && !std::isfinite(hi)) continue;
    limits.push_back({j, iq, iv, lo, hi});
  }
}
}  // namespace

SimulatorModel::SimulatorModel(const pinocchio::Model& model_, std::vector<HalfSpace> halfspaces_,
                               std::vector<SphereContact> contacts_, std::vector<PointAnchor> anchors_,
                               SimulatorSettings settings_, const pinocchio::GeometryModel& geometry_,
                               std::vector<GeometryPairContact> pairs_)
    : model(model_),
      halfspaces(std::move(halfspaces_)),
      contacts(std::move(contacts_)),
      anchors(std::move(anchors_)),
      settings(std::move(settings_)),
      geometry(geometry_),
      pairs(std::move(pairs_)) {
  for (HalfSpace& h : halfspaces) completeTangents(h);
  const auto nframes = static_cast<pinocchio::FrameIndex>(model.nframes);
  for (const HalfSpace& h : halfspaces)
    if (h.frame >= nframes)
      throw std::invalid_argument("half-space '" + h.name + "': frame index " + std::to_string(h.frame) +
                                  " does not exist");
  for (const SphereContact& c : contacts) {
    if (c.frame >= nframes)
      throw std::invalid_argument("contact '" + c.name + "': frame index " + std::to_string(c.frame) +
                                  " does not exist (model has " + std::to_string(nframes) + " frames)");
    if (c.halfspace < 0 || c.halfspace >= static_cast<int>(halfspaces.size()))
      throw std::invalid_argument("contact '" + c.name + "': half-space index " +
                                  std::to_string(c.halfspace) + " does not exist");
    if (!(c.radius >= 0.0) || !std::isfinite(c.radius))
      throw std::invalid_argument("contact '" + c.name + "': radius must be finite and >= 0");
    if (!(c.mu >= 0.0) || !std::isfinite(c.mu))
      throw std::invalid_argument("contact '" + c.name + "': friction coefficient mu must be finite and >= 0");
    if (!c.offset.allFinite()) throw std::invalid_argument("contact '" + c.name + "': offset is not finite");
  }
  for (const PointAnchor& a : anchors) {
    if (a.frame >= nframes || a.frame2 >= nframes)
      throw std::invalid_argument("anchor '" + a.name + "': frame index " +
                                  std::to_string(std::max(a.frame, a.frame2)) + " does not exist");
    if (!a.offset2.allFinite()) throw std::invalid_argument("anchor '" + a.name + "': offset2 is not finite");
    if (!a.offset.allFinite() || !a.target.allFinite())
      throw std::invalid_argument("anchor '" + a.name + "': offset and target must be finite");
  }
  const SimulatorSettings& s = settings;
  if (!(s.dt > 0.0) || !std::isfinite(s.dt)) throw std::invalid_argument("dt must be positive and finite");
  if (s.delta < 0.0 || !std::isfinite(s.delta)) throw std::invalid_argument("delta must be >= 0 (0: dt)");
  if (!(s.zeta > 0.0) || !std::isfinite(s.zeta)) throw std::invalid_argument("zeta must be positive");
  if (!(s.ode_tolerance > 0.0)) throw std::invalid_argument("ode_tolerance must be positive");
  if (!(s.activation_distance >= 0.0)) throw std::invalid_argument("activation_distance must be >= 0");
  if (!(s.min_dt > 0.0)) throw std::invalid_argument("min_dt must be positive");
  if (s.mode == IntegrationMode::kRK4) {
    // Explicit RK4 on eq. 64 is stable only for dt below ~2.6 delta (zeta = 1/2): beyond,
    // a cube at rest on a slope leaves at 173 m/s. Refuse rather than blow up.
    const double delta = s.delta > 0.0 ? s.delta : s.dt;
    const double limit = rk4StableStep(delta, s.zeta);
    if (s.dt > limit) {
      std::ostringstream os;
      os << "rk4: dt = " << s.dt << " is too large for the contact relaxation (eq. 64) with delta = " << delta
         << ", zeta = " << s.zeta << ": RK4 is stable up to " << rk4StabilityLimit(delta, s.zeta)
         << " s; the largest stable dt accepted is " << limit << " s (" << limit / delta
         << " delta). Use dt <= " << limit << ", a larger delta, or mode 'adaptive' (which controls its step)";
      throw std::invalid_argument(os.str());
    }
  }
  makeSolver(s.solver);  // throws on an unknown name
  makeFormulation(s.formulation, s.formulation_settings);  // unknown name or bad parameter
  if (s.formulation == "penalty" && s.mode != IntegrationMode::kTimeStepping)
    throw std::invalid_argument(
        "the penalty formulation integrates its springs by implicit Euler over the time step (Kikuuwe-Fujimoto, "
        "eq. 83-84): it needs mode 'timestep', not an ODE mode");
  if (s.rigid_body_passes != "fused" && s.rigid_body_passes != "pinocchio")
    throw std::invalid_argument("rigid_body_passes must be 'fused' or 'pinocchio', got '" + s.rigid_body_passes + "'");
  const bool fused = s.rigid_body_passes == "fused";
  checkJointAxes(model);
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j) {
    const std::string kind = model.joints[j].shortname();
    if (kind == "JointModelFreeFlyer") free_flyers.push_back(j);
    if (kind == "JointModelFreeFlyer" || kind == "JointModelSpherical")
      quaternions.emplace_back(j, model.idx_qs[j] + (kind == "JointModelFreeFlyer" ? 3 : 0));
    collectNonAbelian(model.joints[j], non_abelian_joints);
  }
  if (fused) tree = treeOf(model);  // (else empty: Pinocchio's integrate and difference)
  splitIntoSystems(model, fused, systems, joint_system, joint_local);
  slot_pair.assign(contacts.size(), -1);
  for (std::size_t p = 0; p < pairs.size(); ++p) {
    const GeometryPairContact& g = pairs[p];
    if (!g.dynamic && g.pair >= geometry.collisionPairs.size())
      throw std::invalid_argument("pair '" + g.name + "': collision pair index " + std::to_string(g.pair) +
                                  " does not exist (the geometry model has " +
                                  std::to_string(geometry.collisionPairs.size()) + " pairs)");
    if (!(g.mu >= 0.0) || !std::isfinite(g.mu))
      throw std::invalid_argument("pair '" + g.name + "': friction coefficient mu must be finite and >= 0");
    if (g.max_contacts < 1 || g.max_contacts > 64)
      throw std::invalid_argument("pair '" + g.name + "': max_contacts must be in 1..64");
    if (g.model == ContactModel::kPlanar)
      throw std::invalid_argument("pair '" + g.name + "': the planar contact model applies to sphere contacts only "
                                  "(a coal pair is spatial or frictionless)");
    if (g.dynamic && g.patch) {
      for (const pinocchio::GeometryObject& object : geometry.geometryObjects)
        if (object.geometry->getObjectType() == coal::OT_BVH)
          throw std::invalid_argument("pair '" + g.name + "': a dynamic pair with contact patches meets every "
                                      "shape; '" + object.name + "' is a mesh (set patch = false)");
    } else if (g.patch)
      for (pinocchio::GeomIndex gi : {geometry.collisionPairs[g.pair].first, geometry.collisionPairs[g.pair].second})
        if (geometry.geometryObjects[gi].geometry->getObjectType() == coal::OT_BVH)
          throw std::invalid_argument("pair '" + g.name + "': contact patches need convex shapes or half-spaces; '" +
                                      geometry.geometryObjects[gi].name + "' is a mesh (set patch = false)");
    pair_first_slot.push_back(static_cast<int>(slot_pair.size()));
    if (g.dynamic) dynamic_pairs.push_back(static_cast<int>(p));
    for (int k = 0; k < g.max_contacts; ++k) slot_pair.push_back(static_cast<int>(p));
  }
  if (!dynamic_pairs.empty())  // the broad phase boxes each shape from its local AABB
    for (const pinocchio::GeometryObject& object : geometry.geometryObjects) object.geometry->computeLocalAABB();
  num_candidates = static_cast<int>(slot_pair.size());
  deriveJointRows(model, settings, joint_limits, joint_friction, effort_limit, joint_damping, friction_dofs, effort_dofs);
  // Box rows have no law in the penalty formulation (a spring per contact) or in Pinocchio's solvers
  // (cones only; formulations.hpp, refuseBoxRows). Dry friction has its rows at every step: said here.
  // (An actuator's effort row appears only near saturation: the formulation refuses that step.)
  if (!friction_dofs.empty() && (settings.formulation == "penalty" || settings.formulation.rfind("pinocchio-", 0) == 0))
    throw std::invalid_argument("formulation '" + settings.formulation + "' does not handle box rows, and the model '" +
                                model.name + "' has dry joint friction: use the exact formulation, or switch it off "
                                "(joint_friction = false)");
  dof_part.assign(static_cast<std::size_t>(model.nv), -1);
  dof_local.assign(static_cast<std::size_t>(model.nv), -1);
  dof_joint.assign(static_cast<std::size_t>(model.nv), 0);
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j)
    for (int k = 0; k < model.nvs[j]; ++k) {
      const int s_j = joint_system[j];
      dof_part[static_cast<std::size_t>(model.idx_vs[j] + k)] = s_j;
      dof_local[static_cast<std::size_t>(model.idx_vs[j] + k)] = systems[s_j].model.idx_vs[joint_local[j]] + k;
      dof_joint[static_cast<std::size_t>(model.idx_vs[j] + k)] = j;
    }
  for (const pinocchio::GeometryObject& object : geometry.geometryObjects) {
    const coal::NODE_TYPE type = object.geometry->getNodeType();
    if (type == coal::GEOM_HALFSPACE || type == coal::GEOM_PLANE) {
      geometry_center.push_back(Eigen::Vector3d::Zero());
      geometry_radius.push_back(std::numeric_limits<double>::infinity());
      continue;
    }
    object.geometry->computeLocalAABB();
    geometry_center.push_back(object.placement.act(Eigen::Vector3d(object.geometry->aabb_center)));
    geometry_radius.push_back(object.geometry->aabb_radius);
  }
}

SystemWork::SystemWork(const SystemModel& s)
    : data(s.model),
      v_index(s.v_index),
      q(pinocchio::neutral(s.model)),
      v(Eigen::VectorXd::Zero(s.model.nv)),
      zero(Eigen::VectorXd::Zero(s.model.nv)),
      tau(Eigen::VectorXd::Zero(s.model.nv)),
      nle(Eigen::VectorXd::Zero(s.model.nv)),
      v_free(Eigen::VectorXd::Zero(s.model.nv)),
      x(Eigen::VectorXd::Zero(s.model.nv)) {
  const auto revolute = s.tree.empty() ? 0 : std::count_if(s.tree.begin() + 1, s.tree.end(), [](const TreeJoint& t) {
    return t.kind == TreeJoint::Kind::kRevolute;
  });
  trig.assign(3 * static_cast<std::size_t>((revolute + 3) / 4 * 4), 0.0);
}

SimulatorWorkspace::SimulatorWorkspace(const SimulatorModel& sim)
    : geometry_data(sim.geometry),
      solver(makeSolver(sim.settings.solver)) {
  parts.reserve(sim.systems.size());
  for (const SystemModel& s : sim.systems) parts.emplace_back(s);
  part_fill.assign(sim.systems.size(), 0);
  FormulationSettings fs = sim.settings.formulation_settings;
  fs.exact_solver = sim.settings.solver;
  solver = makeFormulation(sim.settings.formulation, fs);
  for (const GeometryPairContact& g : sim.pairs) {
    if (g.dynamic) continue;  // (its request is the broad phase's, per entry)
    coal::CollisionRequest& req = geometry_data.collisionRequests[g.pair];
    req.num_max_contacts = static_cast<size_t>(g.max_contacts);
    req.security_margin = sim.settings.activation_distance;
    req.enable_contact = true;
  }
  const int nv = sim.model.nv;
  zero_nv = Eigen::VectorXd::Zero(nv);
  v_free.resize(nv);
  dv.resize(nv);
  effort_row.assign(static_cast<std::size_t>(nv), 0);
  forced_effort.assign(static_cast<std::size_t>(nv), 0);
  forced_limit.assign(sim.joint_limits.size(), 0);
  limit_rows.assign(sim.joint_limits.size(), 0);
  effort_c = Eigen::VectorXd::Zero(nv);
  effort_k = Eigen::VectorXd::Zero(nv);
}

SimulatorData::SimulatorData(const SimulatorModel& sim)
    : q(pinocchio::neutral(sim.model)),
      v(Eigen::VectorXd::Zero(sim.model.nv)),
      work(std::make_unique<SimulatorWorkspace>(sim)) {
  const int nv = sim.model.nv;
  control.kp = Eigen::VectorXd::Zero(nv);
  control.kd = Eigen::VectorXd::Zero(nv);
  control.q_target = q;
  control.v_target = Eigen::VectorXd::Zero(nv);
  control.tau_ff = Eigen::VectorXd::Zero(nv);
  const int nc = sim.numCandidates();
  out.gaps = Eigen::VectorXd::Zero(nc);
  out.slot_point = out.slot_normal = out.slot_t1 = out.slot_t2 = Eigen::Matrix3Xd::Zero(3, nc);
  out.tau.resize(nv);
  out.nle.resize(nv);
  out.candidate_lambda = Eigen::MatrixXd::Zero(3, nc);
  out.contact_force = Eigen::Matrix3Xd::Zero(3, nc);
  out.have_candidate_lambda.assign(nc, false);
  out.anchor_lambda = Eigen::MatrixXd::Zero(3, sim.anchors.size());
  out.candidate_spring = Eigen::MatrixXd::Zero(3, nc);
  out.candidate_velocity = Eigen::MatrixXd::Zero(3, nc);
  out.candidate_states.assign(nc, ContactState::kOpen);
  out.candidate_rows.assign(nc, 0);
  out.actuator_torque = Eigen::VectorXd::Zero(nv);
  out.friction_torque = Eigen::VectorXd::Zero(nv);
  out.limit_torque = Eigen::VectorXd::Zero(nv);
}

SimulatorData::~SimulatorData() = default;

}  // namespace stiction

namespace stiction {

Eigen::MatrixXd denseJacobian(const SimulatorData& sd) {
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(sd.out.rows, sd.v.size());
  for (const SystemWork& w : sd.work->parts)
    for (Eigen::Index r = 0; r < static_cast<Eigen::Index>(w.rows.size()); ++r)
      for (Eigen::Index k = 0; k < w.J.cols(); ++k) J(w.rows[r], w.v_index[k]) += w.J(r, k);
  return J;
}

Eigen::MatrixXd denseMassMatrix(const SimulatorData& sd) {
  Eigen::MatrixXd M = Eigen::MatrixXd::Zero(sd.v.size(), sd.v.size());
  for (const SystemWork& w : sd.work->parts) {
    // crba fills the upper triangle
    const auto n = static_cast<Eigen::Index>(w.v_index.size());
    for (Eigen::Index c = 0; c < n; ++c)
      for (Eigen::Index r = 0; r < n; ++r)
        M(w.v_index[r], w.v_index[c]) = r <= c ? w.data.M(r, c) : w.data.M(c, r);
  }
  return M;
}

Eigen::MatrixXd denseDelassus(const SimulatorData& sd) {
  completeLockedStep(sd);  // (a step with its joints locked left A to whoever asks)
  if (sd.out.sparse)
    return Eigen::MatrixXd(sd.work->a_in_operator && sd.work->sparse_delassus ? sd.work->sparse_delassus->sparseMatrix() : sd.out.A_sparse);
  return sd.out.A;
}

}  // namespace stiction
