// Stage 2, detection: which candidates touch, how deep, and with how many rows.
// Spheres (or points) against half-spaces analytically; general shapes through coal.
#include <limits>

#include <pinocchio/algorithm/geometry.hpp>
#include <pinocchio/collision/collision.hpp>

#include "stages.hpp"

namespace stiction {
namespace stages {

namespace {

// A right-handed (t1, t2, n) basis from a unit normal.
void tangentsOf(const Eigen::Vector3d& n, Eigen::Vector3d& t1, Eigen::Vector3d& t2) {
  const Eigen::Vector3d e = std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  t1 = (e - n * n.dot(e)).normalized();
  t2 = n.cross(t1);
}

}  // namespace

void detectContacts(const SimulatorModel& sim, SimulatorData& sd) {
  const pinocchio::Model& model = sim.model;
  sd.active.clear();
  std::fill(sd.candidate_rows.begin(), sd.candidate_rows.end(), 0);
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
      const pinocchio::SE3 oMf = jointPlacement(sim, sd, f.parentJoint) * f.placement;
      sd.plane_normal.col(k) = oMf.rotation() * h.normal;
      sd.plane_t1.col(k) = oMf.rotation() * h.tangent1;
      sd.plane_t2.col(k) = oMf.rotation() * h.tangent2;
      sd.plane_offset[k] = h.offset + sd.plane_normal.col(k).dot(oMf.translation());
    }
  }
  // Sphere (or point) against half-space, analytic.
  for (std::size_t i = 0; i < sim.contacts.size(); ++i) {
    const SphereContact& c = sim.contacts[i];
    const pinocchio::Frame& f = model.frames[c.frame];
    const Eigen::Vector3d center = jointPlacement(sim, sd, f.parentJoint).act(f.placement.act(c.offset));
    sd.gaps[i] = sd.plane_normal.col(c.halfspace).dot(center) - sd.plane_offset[c.halfspace] - c.radius;
    if (sd.gaps[i] <= sim.settings.activation_distance) {
      sd.active.push_back(static_cast<int>(i));
      sd.candidate_rows[i] = candidateRows(sim, static_cast<int>(i));
    }
  }
  // coal pairs: each reported point (signed distance below the activation
  // distance) fills the pair's next slot.
  if (sim.pairs.empty()) return;
  // Geometry placements (pinocchio::updateGeometryPlacements, from the parts' placements).
  for (std::size_t g = 0; g < sim.geometry.geometryObjects.size(); ++g) {
    const pinocchio::GeometryObject& object = sim.geometry.geometryObjects[g];
    sd.geometry_data.oMg[g] = jointPlacement(sim, sd, object.parentJoint) * object.placement;
  }
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
      }
    }
  }
}

}  // namespace stages
}  // namespace stiction
