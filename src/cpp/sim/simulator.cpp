// The only translation unit that instantiates Pinocchio's algorithms (slow to
// compile: keep them here).
#include "stiction/simulator.hpp"

#include "stiction/rk4_stability.hpp"

#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include <pinocchio/algorithm/cholesky.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <pinocchio/algorithm/geometry.hpp>
#include <pinocchio/collision/collision.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/algorithm/rnea.hpp>

namespace stiction {

namespace {

using Clock = std::chrono::steady_clock;

double microseconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::micro>(b - a).count();
}

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

// Rows of a contact of model m and friction mu: 1 (n), 2 (t1, n) or 3 (t1, t2, n);
// mu = 0 reduces to the unilateral row.
int rowsOf(ContactModel m, double mu) {
  if (m == ContactModel::kFrictionless || mu == 0.0) return 1;
  return m == ContactModel::kPlanar ? 2 : 3;
}

// Rows and friction of candidate i (a sphere contact or a pair slot).
int candidateRows(const SimulatorModel& sim, int i) {
  if (sim.slot_pair[i] < 0) return rowsOf(sim.contacts[i].model, sim.contacts[i].mu);
  const GeometryPairContact& g = sim.pairs[sim.slot_pair[i]];
  return rowsOf(g.model, g.mu);
}
double candidateMu(const SimulatorModel& sim, int i) {
  return sim.slot_pair[i] < 0 ? sim.contacts[i].mu : sim.pairs[sim.slot_pair[i]].mu;
}

// The 3-slot (t1, t2, n) layout from k = 1, 2 or 3 rows.
Eigen::Vector3d toSlots(const double* x, int k) {
  if (k == 3) return Eigen::Vector3d(x[0], x[1], x[2]);
  if (k == 2) return Eigen::Vector3d(x[0], 0.0, x[1]);
  return Eigen::Vector3d(0.0, 0.0, x[0]);
}
void fromSlots(const Eigen::Vector3d& s, int k, double* x) {
  if (k == 3) {
    x[0] = s[0], x[1] = s[1], x[2] = s[2];
  } else if (k == 2) {
    x[0] = s[0], x[1] = s[2];
  } else {
    x[0] = s[2];
  }
}

// A right-handed (t1, t2, n) basis from a unit normal.
void tangentsOf(const Eigen::Vector3d& n, Eigen::Vector3d& t1, Eigen::Vector3d& t2) {
  const Eigen::Vector3d e = std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  t1 = (e - n * n.dot(e)).normalized();
  t2 = n.cross(t1);
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
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j)
    if (model.joints[j].shortname() == "JointModelFreeFlyer") free_flyers.push_back(j);
  slot_pair.assign(contacts.size(), -1);
  for (std::size_t p = 0; p < pairs.size(); ++p) {
    const GeometryPairContact& g = pairs[p];
    if (g.pair >= geometry.collisionPairs.size())
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
    for (int k = 0; k < g.max_contacts; ++k) slot_pair.push_back(static_cast<int>(p));
  }
  num_candidates = static_cast<int>(slot_pair.size());
}

SimulatorData::SimulatorData(const SimulatorModel& sim)
    : data(sim.model),
      geometry_data(sim.geometry),
      q(pinocchio::neutral(sim.model)),
      v(Eigen::VectorXd::Zero(sim.model.nv)),
      solver(makeSolver(sim.settings.solver)) {
  FormulationSettings fs = sim.settings.formulation_settings;
  fs.exact_solver = sim.settings.solver;
  solver = makeFormulation(sim.settings.formulation, fs);
  const int nv = sim.model.nv;
  control.kp = Eigen::VectorXd::Zero(nv);
  control.kd = Eigen::VectorXd::Zero(nv);
  control.q_target = q;
  control.v_target = Eigen::VectorXd::Zero(nv);
  control.tau_ff = Eigen::VectorXd::Zero(nv);
  const int nc = sim.numCandidates();
  gaps = Eigen::VectorXd::Zero(nc);
  slot_point = slot_normal = slot_t1 = slot_t2 = Eigen::Matrix3Xd::Zero(3, nc);
  for (const GeometryPairContact& g : sim.pairs) {
    coal::CollisionRequest& req = geometry_data.collisionRequests[g.pair];
    req.num_max_contacts = static_cast<size_t>(g.max_contacts);
    req.security_margin = sim.settings.activation_distance;
    req.enable_contact = true;
  }
  J6.resize(6, nv);
  tau.resize(nv);
  nle.resize(nv);
  zero_nv = Eigen::VectorXd::Zero(nv);
  v_free.resize(nv);
  dv.resize(nv);
  candidate_lambda = Eigen::MatrixXd::Zero(3, nc);
  have_candidate_lambda.assign(nc, false);
  anchor_lambda = Eigen::MatrixXd::Zero(3, sim.anchors.size());
  candidate_spring = Eigen::MatrixXd::Zero(3, nc);
  candidate_velocity = Eigen::MatrixXd::Zero(3, nc);
  candidate_states.assign(nc, ContactState::kOpen);
  candidate_rows.assign(nc, 0);
}

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

void buildContactProblem(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                         const Eigen::VectorXd& v, double delta, double zeta, double implicit_pd_step) {
  const pinocchio::Model& model = sim.model;
  pinocchio::Data& data = sd.data;
  const auto t0 = Clock::now();
  // Kinematics with zero acceleration: the classical accelerations it leaves are J' v.
  // (computeAllTerms does it all in one pass but is slower here: it also computes
  // the centre of mass and its Jacobian.)
  pinocchio::forwardKinematics(model, data, q, v, sd.zero_nv);
  pinocchio::computeJointJacobians(model, data);

  // Detection: sphere (or point) against half-space, analytic.
  sd.active.clear();
  std::fill(sd.candidate_rows.begin(), sd.candidate_rows.end(), 0);
  Eigen::Index rows = 3 * static_cast<Eigen::Index>(sim.anchors.size());
  // Half-spaces in world coordinates (a body's face moves with its frame).
  sd.plane_normal.resize(3, sim.halfspaces.size());
  sd.plane_t1.resize(3, sim.halfspaces.size());
  sd.plane_t2.resize(3, sim.halfspaces.size());
  sd.plane_offset.resize(sim.halfspaces.size());
  for (std::size_t k = 0; k < sim.halfspaces.size(); ++k) {
    const HalfSpace& h = sim.halfspaces[k];
    if (h.frame == 0) {
      sd.plane_normal.col(k) = h.normal;
      sd.plane_t1.col(k) = h.tangent1;
      sd.plane_t2.col(k) = h.tangent2;
      sd.plane_offset[k] = h.offset;
    } else {
      const pinocchio::Frame& f = model.frames[h.frame];
      const pinocchio::SE3 oMf = data.oMi[f.parentJoint] * f.placement;
      sd.plane_normal.col(k) = oMf.rotation() * h.normal;
      sd.plane_t1.col(k) = oMf.rotation() * h.tangent1;
      sd.plane_t2.col(k) = oMf.rotation() * h.tangent2;
      sd.plane_offset[k] = h.offset + sd.plane_normal.col(k).dot(oMf.translation());
    }
  }
  for (std::size_t i = 0; i < sim.contacts.size(); ++i) {
    const SphereContact& c = sim.contacts[i];
    const pinocchio::Frame& f = model.frames[c.frame];
    const Eigen::Vector3d center = data.oMi[f.parentJoint].act(f.placement.act(c.offset));
    sd.gaps[i] = sd.plane_normal.col(c.halfspace).dot(center) - sd.plane_offset[c.halfspace] - c.radius;
    if (sd.gaps[i] <= sim.settings.activation_distance) {
      sd.active.push_back(static_cast<int>(i));
      sd.candidate_rows[i] = candidateRows(sim, static_cast<int>(i));
      rows += sd.candidate_rows[i];
    }
  }
  // coal pairs: each reported point (signed distance below the activation
  // distance) fills the pair's next slot.
  if (!sim.pairs.empty()) {
    pinocchio::updateGeometryPlacements(model, data, sim.geometry, sd.geometry_data);
    int slot = static_cast<int>(sim.contacts.size());
    for (const GeometryPairContact& g : sim.pairs) {
      coal::CollisionResult& res = sd.geometry_data.collisionResults[g.pair];
      res.clear();
      pinocchio::computeCollision(sim.geometry, sd.geometry_data, g.pair);
      const int found = std::min<int>(static_cast<int>(res.numContacts()), g.max_contacts);
      for (int k = 0; k < g.max_contacts; ++k, ++slot) {
        if (k >= found) {
          sd.gaps[slot] = std::numeric_limits<double>::infinity();
          continue;
        }
        const coal::Contact& c = res.getContact(static_cast<size_t>(k));
        sd.gaps[slot] = c.penetration_depth;  // signed distance (coal 3: < 0 overlapping)
        const Eigen::Vector3d n = c.normal.normalized();  // from the pair's first geometry to its second
        sd.slot_normal.col(slot) = n;
        sd.slot_point.col(slot) = c.pos;
        Eigen::Vector3d t1, t2;
        tangentsOf(n, t1, t2);
        sd.slot_t1.col(slot) = t1;
        sd.slot_t2.col(slot) = t2;
        if (sd.gaps[slot] <= sim.settings.activation_distance) {
          sd.active.push_back(slot);
          sd.candidate_rows[slot] = candidateRows(sim, slot);
          rows += sd.candidate_rows[slot];
        }
      }
    }
  }
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
  const auto t1 = Clock::now();

  // Dynamics: M (crba) and its Cholesky, nle = C v + g, tau, A = J M^-1 J^T (eq. 22).
  pinocchio::crba(model, data, q, pinocchio::Convention::LOCAL);
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
  // A = (D^-1/2 U^-1 J^T)^T (D^-1/2 U^-1 J^T): symmetric by construction.
  // (dense triangular solve: cheaper than Pinocchio's per-column Uiv at these sizes)
  sd.W = sd.J.transpose();
  data.U.triangularView<Eigen::UnitUpper>().solveInPlace(sd.W);
  sd.W = data.Dinv.cwiseSqrt().asDiagonal() * sd.W;
  sd.A.resize(rows, rows);
  sd.A.setZero();
  sd.A.selfadjointView<Eigen::Lower>().rankUpdate(sd.W.transpose());
  sd.A.triangularView<Eigen::StrictlyUpper>() = sd.A.transpose();
  // eq. 27 with Phi = nle - tau: b = J M^-1 Phi - J' v - (2 zeta / delta) J v - Psi / delta^2
  sd.b.noalias() = -sd.J * sd.v_free;
  sd.b -= sd.drift;
  sd.b.noalias() -= (2.0 * zeta / delta) * (sd.J * v);
  sd.b -= sd.position_error / (delta * delta);
  const auto t2 = Clock::now();
  sd.timings.kinematics += microseconds(t0, t1);
  sd.timings.delassus += microseconds(t1, t2);
}

namespace {

// Forces whose own rounding moves the residual by more than kLooseTolerance (relative
// to ||b||) diverged, whatever the tolerance (verdict.hpp).
constexpr double kDivergedFloor = kLooseTolerance;

// The name of block `blk` of the current problem: a candidate contact, then the anchors.
std::string blockName(const SimulatorModel& sim, const SimulatorData& sd, int blk) {
  if (blk < static_cast<int>(sd.active.size())) {
    const int i = sd.active[blk];
    if (sim.slot_pair[i] < 0) return "contact '" + sim.contacts[i].name + "'";
    const int first_slot = static_cast<int>(sim.contacts.size());
    int slot = i - first_slot;
    for (int p = 0; p < sim.slot_pair[i]; ++p) slot -= sim.pairs[p].max_contacts;
    return "contact '" + sim.pairs[sim.slot_pair[i]].name + "#" + std::to_string(slot) + "'";
  }
  return "anchor '" + sim.anchors[blk - sd.active.size()].name + "'";
}

// Why a step cannot go on: the contact problem has no solution, or none double
// precision can resolve; names the contacts involved and t.
std::string unsolvableMessage(const SimulatorModel& sim, const SimulatorData& sd) {
  std::ostringstream os;
  const SolverResult& r = sd.result;
  if (r.status == SolveStatus::kInfeasible)
    os << "the contact problem at t = " << sd.t << " has no solution";
  else if (r.status == SolveStatus::kUnresolvable)
    os << "the contact forces at t = " << sd.t << " diverged beyond what double precision can resolve";
  else
    os << "the contact solve returned non-finite forces at t = " << sd.t;
  std::vector<int> blocks = r.implicated_blocks;
  if (blocks.empty()) {  // the largest forces
    double worst = 0.0;
    for (std::size_t k = 0; k + 1 < sd.problem->offsets().size(); ++k)
      worst = std::max(worst, r.lam.segment(sd.problem->offsets()[k], sd.problem->constraints()[k].size).norm());
    for (std::size_t k = 0; k + 1 < sd.problem->offsets().size(); ++k)
      if (r.lam.segment(sd.problem->offsets()[k], sd.problem->constraints()[k].size).norm() >= 0.1 * worst)
        blocks.push_back(static_cast<int>(k));
  }
  os << " (";
  for (std::size_t k = 0; k < blocks.size(); ++k) os << (k ? ", " : "") << blockName(sim, sd, blocks[k]);
  os << "): " << r.message;
  if (r.status == SolveStatus::kInfeasible)
    os << ". A contact on a body that cannot move (the world, a fixed joint) and starts penetrating, "
          "or a body squeezed between contacts it cannot escape, makes the forces grow without bound.";
  return os.str();
}

// Solve eq. 65 for the current sd.A, sd.b (scaled by `scale`: h for impulses),
// warm-started from the previous solution of the same candidates.
void solveContacts(const SimulatorModel& sim, SimulatorData& sd, double scale) {
  const auto t0 = Clock::now();
  const Eigen::Index rows = sd.J.rows();
  if (!sd.A.allFinite() || !sd.b.allFinite())
    throw std::runtime_error("simulation diverged: non-finite Delassus operator or right-hand side at t = " +
                             std::to_string(sd.t));
  // Rebuild the problem only when the active set changed.
  if (!sd.problem || sd.active != sd.problem_active) {
    std::vector<Constraint> cons;
    for (int i : sd.active)
      switch (sd.candidate_rows[i]) {
        case 1: cons.push_back(Constraint::unilateral()); break;
        case 2: cons.push_back(Constraint::planarFriction(candidateMu(sim, i))); break;
        default: cons.push_back(Constraint::spatialFriction(candidateMu(sim, i)));
      }
    for (std::size_t a = 0; a < sim.anchors.size(); ++a) cons.push_back(Constraint::bilateral(3));
    sd.delassus = std::make_shared<DenseDelassus>(sd.A);
    // A = W^T W is semi-definite by construction: no Cholesky check per active-set change.
    sd.problem = std::make_unique<ContactProblem>(sd.delassus, scale * sd.b, std::move(cons), 1e-6, false);
    sd.problem_active = sd.active;
  } else {
    sd.delassus->matrix() = sd.A;
    sd.b_scaled = scale * sd.b;
    sd.problem->setB(sd.b_scaled);
  }
  // Warm start: the last lambda of each candidate that is active again.
  SolverSettings settings = sim.settings.solver_settings;
  sd.guess.resize(rows);
  bool any = false;
  Eigen::Index row = 0;
  for (int i : sd.active) {
    const int k = sd.candidate_rows[i];
    if (sd.have_candidate_lambda[i]) {
      any = true;
      fromSlots(scale * sd.candidate_lambda.col(i), k, sd.guess.data() + row);
    } else {
      sd.guess.segment(row, k).setZero();
    }
    row += k;
  }
  for (std::size_t a = 0; a < sim.anchors.size(); ++a, row += 3) {
    sd.guess.segment<3>(row) = scale * sd.anchor_lambda.col(a);
    any = any || sd.anchor_lambda.col(a).squaredNorm() > 0.0;
  }
  settings.warm_start = sim.settings.warm_start && any ? WarmStart::kGiven : WarmStart::kNone;
  const bool exact = sd.solver->exactLaw();
  if (!exact) {  // what the other formulations may know of the step (formulation.hpp)
    StepContext context;
    context.h = scale;
    context.position_error = &sd.position_error;
    sd.spring_rows.setZero(rows);
    row = 0;
    for (int i : sd.active) {
      const int k = sd.candidate_rows[i];
      if (k > 1) fromSlots(sd.candidate_spring.col(i), k, sd.spring_rows.data() + row);
      sd.spring_rows[row + k - 1] = 0.0;
      row += k;
    }
    context.state = &sd.spring_rows;
    setFormulationContext(*sd.solver, context);
  }
  solve(*sd.problem, *sd.solver, settings, sd.result, &sd.guess);
  // Infeasible, or forces so large that not even a loose 1e-6 could be verified: the
  // step cannot go on. (An unreachable tolerance such as 1e-300 is also "unresolvable",
  // with a tiny floor: that step is only recorded as unconverged.)
  // Other formulations are only measured by the exact law: they stop on non-finite impulses.
  if (sd.result.status == SolveStatus::kInfeasible || !sd.result.lam.allFinite() ||
      (exact && sd.result.status == SolveStatus::kUnresolvable && sd.result.precision_floor > kDivergedFloor))
    throw std::runtime_error(unsolvableMessage(sim, sd));
  // Per-candidate forces (lambda / scale) and states.
  sd.lambda = sd.result.lam / scale;
  for (int i = 0; i < sim.numCandidates(); ++i) {
    sd.candidate_lambda.col(i).setZero();
    sd.candidate_spring.col(i).setZero();
    sd.have_candidate_lambda[i] = false;
    sd.candidate_states[i] = ContactState::kOpen;
  }
  row = 0;
  for (std::size_t blk = 0; blk < sd.active.size(); ++blk) {
    const int i = sd.active[blk];
    const int k = sd.candidate_rows[i];
    if (!exact && k > 1) sd.candidate_spring.col(i) = toSlots(sd.spring_rows.data() + row, k);
    sd.candidate_lambda.col(i) = toSlots(sd.lambda.data() + row, k);
    sd.have_candidate_lambda[i] = true;
    sd.candidate_states[i] = sd.result.states[blk];
    row += k;
  }
  for (std::size_t a = 0; a < sim.anchors.size(); ++a, row += 3)
    sd.anchor_lambda.col(a) = sd.lambda.segment<3>(row);
  sd.timings.solve += microseconds(t0, Clock::now());
  ++sd.solves;
  sd.max_residual_step = std::max(sd.max_residual_step, sd.result.residual);
  sd.all_converged_step = sd.all_converged_step && sd.result.own_converged;
  sd.iterations_step += sd.result.iterations;
}

// The acceleration of the relaxed DAI (eq. 39 with lambda from eq. 65) at (q, v).
void acceleration(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                  const Eigen::VectorXd& v, Eigen::VectorXd& a) {
  const double delta = sim.settings.delta > 0.0 ? sim.settings.delta : sim.settings.dt;
  buildContactProblem(sim, sd, q, v, delta, sim.settings.zeta, 0.0);
  solveContacts(sim, sd, 1.0);
  a = sd.v_free;  // M^-1 (tau - nle)
  if (sd.J.rows() > 0) {
    sd.dv.noalias() = sd.J.transpose() * sd.lambda;
    pinocchio::cholesky::solve(sim.model, sd.data, sd.dv);
    a += sd.dv;
  }
  ++sd.rhs_evaluations;
}

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

void integrateTimeStep(const SimulatorModel& sim, const Eigen::VectorXd& q, Eigen::VectorXd& v, double h,
                       Eigen::VectorXd& out) {
  const pinocchio::Model& model = sim.model;
  out.resize(model.nq);
  pinocchio::integrate(model, q, h * v, out);
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

void checkState(const SimulatorData& sd) {
  if (!sd.q.allFinite() || !sd.v.allFinite()) {
    std::ostringstream os;
    os << "simulation diverged: non-finite state at t = " << sd.t;
    throw std::runtime_error(os.str());
  }
}

// Physically absurd states, relative to the scene: a speed far above what gravity
// could have given since the start (10 (|v_0| + |g| t) + 50, m/s or rad/s), or a
// contact sinking far deeper than the activation distance and its initial depth.
// An explicit integrator past its stability bound, or forces out of control, end here.
void checkBlowUp(const SimulatorModel& sim, const SimulatorData& sd) {
  const pinocchio::Model& model = sim.model;
  const double g = model.gravity.linear().norm();
  const double speed_limit = 10.0 * (sd.reference_speed + g * std::max(0.0, sd.t - sd.reference_time)) + 50.0;
  Eigen::Index k = 0;
  const double speed = model.nv > 0 ? sd.v.cwiseAbs().maxCoeff(&k) : 0.0;
  const char* hint = sim.settings.mode == IntegrationMode::kTimeStepping
                         ? ""
                         : " (ODE mode: is dt small enough for delta? see rk4StableStep)";
  if (speed > speed_limit) {
    std::string joint = "?";
    for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j)
      if (k >= model.idx_vs[j] && k < model.idx_vs[j] + model.nvs[j]) joint = model.names[j];
    std::ostringstream os;
    os << "simulation diverged (blow-up) at t = " << sd.t << ": velocity coordinate " << k << " (joint '" << joint
       << "') reached " << speed << ", above the bound 10 (|v0| + |g| t) + 50 = " << speed_limit << hint;
    throw std::runtime_error(os.str());
  }
  const double depth_limit =
      std::max(0.1, 10.0 * sim.settings.activation_distance) + 10.0 * sd.reference_penetration;
  for (int i : sd.active) {
    if (-sd.gaps[i] > depth_limit) {
      const std::string name = sim.slot_pair[i] < 0 ? sim.contacts[i].name : sim.pairs[sim.slot_pair[i]].name;
      std::ostringstream os;
      os << "simulation diverged (blow-up) at t = " << sd.t << ": contact '" << name << "' penetrates " << -sd.gaps[i]
         << " m, deeper than the bound " << depth_limit << " m" << hint;
      throw std::runtime_error(os.str());
    }
  }
}

void stepTimeStepping(const SimulatorModel& sim, SimulatorData& sd) {
  const double h = sim.settings.dt;
  // eq. 70: delta = h, zeta = 1/2; impulses P = h lambda solve A P - h b in -N(P).
  buildContactProblem(sim, sd, sd.q, sd.v, h, 0.5, sim.settings.implicit_pd ? h : 0.0);
  // The J' v term is dropped on the tangential rows (the paper allows it, §3.3):
  // a sticking contact then ends the step with exactly zero slip velocity,
  // J_t v+ = 0, instead of -h J_t' v. Normal rows keep it: it predicts the gap.
  sd.b += sd.drift.cwiseProduct(sd.tangent_row);
  solveContacts(sim, sd, h);
  const auto t0 = Clock::now();
  sd.dv = h * sd.v_free;  // h M^-1 (tau - nle)
  addFrameTurn(sim, sd.v, h, sd.dv);
  sd.v += sd.dv;
  if (sd.J.rows() > 0) {  // + M^-1 J^T P
    sd.dv.noalias() = sd.J.transpose() * sd.result.lam;
    pinocchio::cholesky::solve(sim.model, sd.data, sd.dv);
    sd.v += sd.dv;
  }
  // contact velocities J(q_k) v+, in the frame the solve used
  if (sd.J.rows() > 0) sd.row_velocity.noalias() = sd.J * sd.v;
  integrateTimeStep(sim, sd.q, sd.v, h, sd.q_tmp);  // symplectic: uses v+
  sd.q = sd.q_tmp;
  sd.t += h;
  sd.last_dt = h;
  sd.timings.integrate += microseconds(t0, Clock::now());
}

void stepRK4(const SimulatorModel& sim, SimulatorData& sd) {
  const double h = sim.settings.dt;
  auto& V = sd.stage_v;
  auto& Acc = sd.stage_a;
  V.resize(4);
  Acc.resize(4);
  const Eigen::VectorXd q0 = sd.q, v0 = sd.v;
  static const double c[4] = {0.0, 0.5, 0.5, 1.0};
  for (int s = 0; s < 4; ++s) {
    if (s == 0) {
      sd.q_tmp = q0;
      V[0] = v0;
    } else {
      sd.q_tmp = pinocchio::integrate(sim.model, q0, c[s] * h * V[s - 1]);
      V[s] = v0 + c[s] * h * Acc[s - 1];
    }
    acceleration(sim, sd, sd.q_tmp, V[s], Acc[s]);
  }
  const auto t0 = Clock::now();
  sd.v = v0 + (h / 6.0) * (Acc[0] + 2.0 * Acc[1] + 2.0 * Acc[2] + Acc[3]);
  sd.q = pinocchio::integrate(sim.model, q0, (h / 6.0) * (V[0] + 2.0 * V[1] + 2.0 * V[2] + V[3]));
  sd.t += h;
  sd.last_dt = h;
  sd.timings.integrate += microseconds(t0, Clock::now());
}

// Bogacki-Shampine 3(2) with error control on (q, v); q-increments are tangent
// vectors at the step's start, so the error of q is a difference of increments.
void stepAdaptive(const SimulatorModel& sim, SimulatorData& sd) {
  const SimulatorSettings& s = sim.settings;
  double h = sd.next_dt > 0.0 ? std::min(sd.next_dt, s.dt) : s.dt;
  auto& V = sd.stage_v;
  auto& Acc = sd.stage_a;
  V.resize(4);
  Acc.resize(4);
  const Eigen::VectorXd q0 = sd.q, v0 = sd.v;
  for (int attempt = 0;; ++attempt) {
    if (h < s.min_dt)
      throw std::runtime_error("adaptive integration: step size fell below min_dt at t = " + std::to_string(sd.t));
    V[0] = v0;
    acceleration(sim, sd, q0, V[0], Acc[0]);
    V[1] = v0 + 0.5 * h * Acc[0];
    sd.q_tmp = pinocchio::integrate(sim.model, q0, 0.5 * h * V[0]);
    acceleration(sim, sd, sd.q_tmp, V[1], Acc[1]);
    V[2] = v0 + 0.75 * h * Acc[1];
    sd.q_tmp = pinocchio::integrate(sim.model, q0, 0.75 * h * V[1]);
    acceleration(sim, sd, sd.q_tmp, V[2], Acc[2]);
    const Eigen::VectorXd dq3 = h * ((2.0 / 9.0) * V[0] + (1.0 / 3.0) * V[1] + (4.0 / 9.0) * V[2]);
    const Eigen::VectorXd v3 = v0 + h * ((2.0 / 9.0) * Acc[0] + (1.0 / 3.0) * Acc[1] + (4.0 / 9.0) * Acc[2]);
    const Eigen::VectorXd q3 = pinocchio::integrate(sim.model, q0, dq3);
    V[3] = v3;
    acceleration(sim, sd, q3, V[3], Acc[3]);
    const Eigen::VectorXd dq2 =
        h * ((7.0 / 24.0) * V[0] + 0.25 * V[1] + (1.0 / 3.0) * V[2] + 0.125 * V[3]);
    const Eigen::VectorXd v2 =
        v0 + h * ((7.0 / 24.0) * Acc[0] + 0.25 * Acc[1] + (1.0 / 3.0) * Acc[2] + 0.125 * Acc[3]);
    // error per unit of the state, mixed absolute/relative
    const double eq = ((dq3 - dq2).array() / (s.ode_tolerance * (1.0 + dq3.array().abs()))).abs().maxCoeff();
    const double ev = ((v3 - v2).array() / (s.ode_tolerance * (1.0 + v3.array().abs()))).abs().maxCoeff();
    const double err = std::max(eq, ev);
    const double factor = err > 0.0 ? std::clamp(0.9 * std::pow(err, -1.0 / 3.0), 0.2, 5.0) : 5.0;
    if (err <= 1.0 && std::isfinite(err)) {
      sd.q = q3;
      sd.v = v3;
      sd.t += h;
      sd.last_dt = h;
      sd.next_dt = std::min(s.dt, h * factor);
      return;
    }
    h *= std::isfinite(err) ? factor : 0.2;
  }
}

}  // namespace

void step(const SimulatorModel& sim, SimulatorData& sd) {
  const auto t0 = Clock::now();
  sd.timings = StepTimings{};
  sd.rhs_evaluations = 0;
  sd.solves = 0;
  sd.iterations_step = 0;
  sd.max_residual_step = 0.0;
  sd.all_converged_step = true;
  if (sd.q.size() != sim.model.nq || sd.v.size() != sim.model.nv)
    throw std::invalid_argument("state size: q needs nq = " + std::to_string(sim.model.nq) +
                                " entries and v nv = " + std::to_string(sim.model.nv));
  const bool first = sd.reference_speed < 0.0;
  if (first) {
    sd.reference_speed = sim.model.nv > 0 ? sd.v.cwiseAbs().maxCoeff() : 0.0;
    sd.reference_time = sd.t;
    sd.reference_penetration = 0.0;
  }
  switch (sim.settings.mode) {
    case IntegrationMode::kTimeStepping: stepTimeStepping(sim, sd); break;
    case IntegrationMode::kRK4: stepRK4(sim, sd); break;
    case IntegrationMode::kAdaptive: stepAdaptive(sim, sd); break;
  }
  checkState(sd);
  if (first)
    for (int i : sd.active) sd.reference_penetration = std::max(sd.reference_penetration, -sd.gaps[i]);
  checkBlowUp(sim, sd);
  // Post-step contact velocities J v (rows t1, t2, n) per active candidate, with
  // the last Jacobian (time stepping: exactly the velocity the solve imposed).
  sd.candidate_velocity.setZero();
  if (sd.J.rows() > 0) {
    if (sim.settings.mode != IntegrationMode::kTimeStepping) sd.row_velocity.noalias() = sd.J * sd.v;
    Eigen::Index row = 0;
    for (int i : sd.active) {
      sd.candidate_velocity.col(i) = toSlots(sd.row_velocity.data() + row, sd.candidate_rows[i]);
      row += sd.candidate_rows[i];
    }
  }
  sd.timings.total = microseconds(t0, Clock::now());
}

}  // namespace stiction
