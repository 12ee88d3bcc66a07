// Stage 2, detection: which candidates touch, how deep, and with how many rows.
// Spheres (or points) against half-spaces analytically; general shapes through coal.
#include <array>
#include <cmath>
#include <limits>

#include <pinocchio/algorithm/geometry.hpp>
#include <pinocchio/collision/collision.hpp>
#include <coal/collision.h>
#include <coal/contact_patch.h>

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

// Up to `wanted` of the patch's vertices, spread out: the farthest from the centroid first,
// then each time the vertex farthest from those chosen (a square's corners out of an octagon).
int spreadVertices(const coal::ContactPatch& patch, int wanted, std::array<int, 64>& chosen) {
  const int size = std::min<int>(static_cast<int>(patch.size()), 64);
  if (size <= wanted) {
    for (int k = 0; k < size; ++k) chosen[k] = k;
    return size;
  }
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (int k = 0; k < size; ++k) centroid += patch.getPoint(static_cast<size_t>(k));
  centroid /= size;
  std::array<double, 64> nearest;  // distance of each vertex to the nearest chosen one
  int first = 0;
  for (int k = 1; k < size; ++k)
    if ((patch.getPoint(k) - centroid).squaredNorm() > (patch.getPoint(first) - centroid).squaredNorm()) first = k;
  chosen[0] = first;
  for (int k = 0; k < size; ++k) nearest[k] = (patch.getPoint(k) - patch.getPoint(first)).squaredNorm();
  for (int c = 1; c < wanted; ++c) {
    int next = 0;
    for (int k = 1; k < size; ++k)
      if (nearest[k] > nearest[next]) next = k;
    chosen[c] = next;
    for (int k = 0; k < size; ++k)
      nearest[k] = std::min(nearest[k], (patch.getPoint(k) - patch.getPoint(next)).squaredNorm());
  }
  return wanted;
}

}  // namespace

void detectContacts(const SimulatorModel& sim, SimulatorData& sd) {
  const pinocchio::Model& model = sim.model;
  sd.out.active.clear();
  std::fill(sd.out.candidate_rows.begin(), sd.out.candidate_rows.end(), 0);
  // Half-spaces in world coordinates (a body's face moves with its frame).
  sd.work->plane_normal.resize(3, sim.halfspaces.size());
  sd.work->plane_t1.resize(3, sim.halfspaces.size());
  sd.work->plane_t2.resize(3, sim.halfspaces.size());
  sd.work->plane_offset.resize(sim.halfspaces.size());
  for (std::size_t k = 0; k < sim.halfspaces.size(); ++k) {
    const HalfSpace& h = sim.halfspaces[k];
    if (h.frame == 0) {
      sd.work->plane_normal.col(k) = h.normal;
      sd.work->plane_t1.col(k) = h.tangent1;
      sd.work->plane_t2.col(k) = h.tangent2;
      sd.work->plane_offset[k] = h.offset;
    } else {
      const pinocchio::Frame& f = model.frames[h.frame];
      const pinocchio::SE3 oMf = jointPlacement(sim, sd, f.parentJoint) * f.placement;
      sd.work->plane_normal.col(k) = oMf.rotation() * h.normal;
      sd.work->plane_t1.col(k) = oMf.rotation() * h.tangent1;
      sd.work->plane_t2.col(k) = oMf.rotation() * h.tangent2;
      sd.work->plane_offset[k] = h.offset + sd.work->plane_normal.col(k).dot(oMf.translation());
    }
  }
  // Sphere (or point) against half-space, analytic.
  for (std::size_t i = 0; i < sim.contacts.size(); ++i) {
    const SphereContact& c = sim.contacts[i];
    const HalfSpace& h = sim.halfspaces[c.halfspace];
    const pinocchio::Frame& f = model.frames[c.frame];
    const pinocchio::SE3& oMj = jointPlacement(sim, sd, f.parentJoint);
    if (h.frame != 0) {
      // A body's face: the centre in the face's frame, from the difference of the two joints'
      // positions first. World coordinates would round each corner's gap to the positions'
      // magnitude (9e-16 m at 6 m up a tower), corner by corner, and no motion fits such gaps:
      // through Psi / delta^2 they left up to 2e-10 m/s of b outside A's range, above the
      // tolerance. Neighbouring bodies' positions subtract exactly, so this gap rounds to the
      // bodies' size (~1e-17 m).
      const pinocchio::Frame& face = model.frames[h.frame];
      const pinocchio::SE3& oMface_joint = jointPlacement(sim, sd, face.parentJoint);
      const Eigen::Vector3d relative =
          (oMj.translation() - oMface_joint.translation()) + oMj.rotation() * f.placement.act(c.offset);
      const Eigen::Vector3d in_face = face.placement.actInv(Eigen::Vector3d(oMface_joint.rotation().transpose() * relative));
      sd.out.gaps[i] = h.normal.dot(in_face) - h.offset - c.radius;
    } else {
      const Eigen::Vector3d center = oMj.act(f.placement.act(c.offset));
      sd.out.gaps[i] = sd.work->plane_normal.col(c.halfspace).dot(center) - sd.work->plane_offset[c.halfspace] - c.radius;
    }
    if (sd.out.gaps[i] <= sim.settings.activation_distance) {
      sd.out.active.push_back(static_cast<int>(i));
      sd.out.candidate_rows[i] = candidateRows(sim, static_cast<int>(i));
    }
  }
  // coal pairs: each reported point (signed distance below the activation
  // distance) fills the pair's next slot.
  if (sim.pairs.empty()) return;
  // Geometry placements (pinocchio::updateGeometryPlacements, from the parts' placements).
  for (std::size_t g = 0; g < sim.geometry.geometryObjects.size(); ++g) {
    const pinocchio::GeometryObject& object = sim.geometry.geometryObjects[g];
    sd.work->geometry_data.oMg[g] = jointPlacement(sim, sd, object.parentJoint) * object.placement;
  }
  if (!sim.dynamic_pairs.empty()) assignDynamicPairs(sim, sd);  // the pool's pairs (broad_phase.cpp)
  int slot = static_cast<int>(sim.contacts.size());
  std::array<int, 64> chosen;
  for (std::size_t p = 0; p < sim.pairs.size(); ++p) {
    const GeometryPairContact& g = sim.pairs[p];
    const coal::CollisionResult* result = nullptr;
    const coal::ContactPatch* patch = nullptr;
    int found = 0;
    if (g.dynamic) {  // the pair its entry holds (none: every slot empty); the broad phase's boxes overlap
      BroadPhaseState& bp = sd.work->broad;
      const auto held = bp.geoms[p];
      coal::CollisionResult& res = bp.result[p];
      res.clear();
      result = &res;
      if (held[0] >= 0) {
        const pinocchio::GeometryObject& first = sim.geometry.geometryObjects[static_cast<std::size_t>(held[0])];
        const pinocchio::GeometryObject& second = sim.geometry.geometryObjects[static_cast<std::size_t>(held[1])];
        const pinocchio::SE3& oM1 = sd.work->geometry_data.oMg[static_cast<std::size_t>(held[0])];
        const pinocchio::SE3& oM2 = sd.work->geometry_data.oMg[static_cast<std::size_t>(held[1])];
        const coal::Transform3s tf1(oM1.rotation(), oM1.translation()), tf2(oM2.rotation(), oM2.translation());
        coal::collide(first.geometry.get(), tf1, second.geometry.get(), tf2, bp.request[p], res);
        found = std::min<int>(static_cast<int>(res.numContacts()), g.max_contacts);
        if (g.patch && found > 0) {
          coal::ContactPatchResult& patches = bp.patches[p];
          patches.clear();
          coal::computeContactPatch(first.geometry.get(), tf1, second.geometry.get(), tf2, res, bp.patch_request,
                                    patches);
          if (patches.numContactPatches() > 0 && patches.getContactPatch(0).size() > 0) {
            patch = &patches.getContactPatch(0);
            found = spreadVertices(*patch, g.max_contacts, chosen);
          }
        }
      }
    } else {
      const pinocchio::CollisionPair& cp = sim.geometry.collisionPairs[g.pair];
      coal::CollisionResult& res = sd.work->geometry_data.collisionResults[g.pair];
      res.clear();
      result = &res;
      // broad phase: bounding spheres farther apart than the activation distance cannot touch
      const double reach = sim.geometry_radius[cp.first] + sim.geometry_radius[cp.second] +
                           sim.settings.activation_distance;
      if (!std::isfinite(reach) ||
          (sd.work->geometry_data.oMg[cp.first].act(sim.geometry_center[cp.first]) -
           sd.work->geometry_data.oMg[cp.second].act(sim.geometry_center[cp.second])).norm() <= reach) {
        pinocchio::computeCollision(sim.geometry, sd.work->geometry_data, g.pair);
        found = std::min<int>(static_cast<int>(res.numContacts()), g.max_contacts);
      }
      if (g.patch && found > 0) {
        pinocchio::computeContactPatch(sim.geometry, sd.work->geometry_data, g.pair);
        const coal::ContactPatchResult& patches = sd.work->geometry_data.contactPatchResults[g.pair];
        if (patches.numContactPatches() > 0 && patches.getContactPatch(0).size() > 0) {
          patch = &patches.getContactPatch(0);
          found = spreadVertices(*patch, g.max_contacts, chosen);
        }
      }
    }
    const coal::CollisionResult& res = *result;
    for (int k = 0; k < g.max_contacts; ++k, ++slot) {
      if (k >= found) {
        sd.out.gaps[slot] = std::numeric_limits<double>::infinity();
        continue;
      }
      Eigen::Vector3d n;
      if (patch != nullptr) {  // one normal and depth for the patch (coal 3: signed, < 0 overlapping)
        sd.out.gaps[slot] = patch->penetration_depth;
        n = patch->getNormal().normalized();
        sd.out.slot_point.col(slot) = patch->getPoint(static_cast<size_t>(chosen[k]));
      } else {
        const coal::Contact& c = res.getContact(static_cast<size_t>(k));
        sd.out.gaps[slot] = c.penetration_depth;  // signed distance (coal 3: < 0 overlapping)
        n = c.normal.normalized();  // from the pair's first geometry to its second
        sd.out.slot_point.col(slot) = c.pos;
      }
      sd.out.slot_normal.col(slot) = n;
      Eigen::Vector3d t1, t2;
      tangentsOf(n, t1, t2);
      sd.out.slot_t1.col(slot) = t1;
      sd.out.slot_t2.col(slot) = t2;
      if (sd.out.gaps[slot] <= sim.settings.activation_distance) {
        sd.out.active.push_back(slot);
        sd.out.candidate_rows[slot] = candidateRows(sim, slot);
      }
    }
  }
}

}  // namespace stages
}  // namespace stiction
