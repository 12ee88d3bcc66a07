// The broad phase of the dynamic pairs (broad_phase.hpp): which pairs of shapes the pool holds.
#include "broad_phase.hpp"

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "stages.hpp"

namespace stiction {
namespace stages {

namespace {

std::uint64_t keyOf(int a, int b) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(a)) << 32) | static_cast<std::uint32_t>(b);
}

void prepare(const SimulatorModel& sim, BroadPhaseState& bp) {
  const std::size_t n = sim.pairs.size();
  bp.geoms.assign(n, {-1, -1});
  bp.seen.assign(n, 0);
  bp.request.assign(n, coal::CollisionRequest());
  bp.result.assign(n, coal::CollisionResult());
  bp.patches.assign(n, coal::ContactPatchResult(bp.patch_request));
  bp.free_entries.clear();
  bp.entry_of.clear();
  for (int p : sim.dynamic_pairs) {
    coal::CollisionRequest& req = bp.request[static_cast<std::size_t>(p)];
    req.num_max_contacts = static_cast<std::size_t>(sim.pairs[p].max_contacts);
    req.security_margin = sim.settings.activation_distance;
    req.enable_contact = true;
    bp.free_entries.push_back(p);
  }
  bp.ready = true;
}

}  // namespace

void assignDynamicPairs(const SimulatorModel& sim, SimulatorData& sd) {
  BroadPhaseState& bp = sd.work->broad;
  if (!bp.ready) prepare(sim, bp);
  const auto& objects = sim.geometry.geometryObjects;
  const int ng = static_cast<int>(objects.size());
  constexpr double kInf = std::numeric_limits<double>::infinity();
  // World boxes: the local AABB's centre placed, its half extents through |R|, grown by half the
  // activation distance each (two boxes then overlap when the shapes may come that close).
  bp.lower.resize(3, ng);
  bp.upper.resize(3, ng);
  const double grow = 0.5 * sim.settings.activation_distance;
  for (int g = 0; g < ng; ++g) {
    const coal::AABB& box = objects[static_cast<std::size_t>(g)].geometry->aabb_local;
    const pinocchio::SE3& oMg = sd.work->geometry_data.oMg[static_cast<std::size_t>(g)];
    const Eigen::Vector3d centre = 0.5 * (box.min_ + box.max_), half = 0.5 * (box.max_ - box.min_);
    if (!centre.allFinite() || !half.allFinite()) {  // a half-space or a plane: everywhere
      bp.lower.col(g).setConstant(-kInf);
      bp.upper.col(g).setConstant(kInf);
      continue;
    }
    const Eigen::Vector3d at = oMg.act(centre);
    const Eigen::Vector3d reach = oMg.rotation().cwiseAbs() * half + Eigen::Vector3d::Constant(grow);
    bp.lower.col(g) = at - reach;
    bp.upper.col(g) = at + reach;
  }
  bp.found.clear();
  sweepAndPrune(bp.lower, bp.upper, bp.order, bp.found, [&](int a, int b) {
    return objects[static_cast<std::size_t>(a)].parentJoint == objects[static_cast<std::size_t>(b)].parentJoint;
  });
  for (int p : sim.dynamic_pairs) bp.seen[static_cast<std::size_t>(p)] = 0;
  std::size_t kept = 0;  // the pairs already held move to the front of `found`, the newcomers after
  for (std::size_t k = 0; k < bp.found.size(); ++k) {
    const auto it = bp.entry_of.find(keyOf(bp.found[k].first, bp.found[k].second));
    if (it != bp.entry_of.end()) {
      bp.seen[static_cast<std::size_t>(it->second)] = 1;
    } else {
      std::swap(bp.found[kept], bp.found[k]);  // (order among newcomers: the sweep's, deterministic)
      ++kept;
    }
  }
  const std::size_t newcomers = kept;
  for (int p : sim.dynamic_pairs) {  // entries whose pair no longer overlaps are free again
    auto& held = bp.geoms[static_cast<std::size_t>(p)];
    if (held[0] >= 0 && !bp.seen[static_cast<std::size_t>(p)]) {
      bp.entry_of.erase(keyOf(held[0], held[1]));
      held = {-1, -1};
      bp.free_entries.push_back(p);
    }
  }
  if (newcomers > bp.free_entries.size())
    throw std::runtime_error("broad phase: " + std::to_string(bp.entry_of.size() + newcomers) +
                             " pairs of shapes overlap at t = " + std::to_string(sd.t) + " but the pool has " +
                             std::to_string(sim.dynamic_pairs.size()) +
                             " dynamic pair entries (give the scene more: a pile's array.pairs_per_body)");
  for (std::size_t k = 0; k < newcomers; ++k) {
    const int p = bp.free_entries.front();
    bp.free_entries.pop_front();
    const auto [a, b] = bp.found[k];
    bp.geoms[static_cast<std::size_t>(p)] = {a, b};
    bp.entry_of.emplace(keyOf(a, b), p);
    bp.seen[static_cast<std::size_t>(p)] = 1;
    // a new pair: no warm start from the entry's last pair (GJK's guess nor the solve's forces)
    coal::CollisionRequest& req = bp.request[static_cast<std::size_t>(p)];
    const coal::CollisionRequest fresh;
    req.cached_gjk_guess = fresh.cached_gjk_guess;
    req.cached_support_func_guess = fresh.cached_support_func_guess;
    const int first = sim.pair_first_slot[static_cast<std::size_t>(p)];
    for (int s = first; s < first + sim.pairs[p].max_contacts; ++s) {
      sd.out.have_candidate_lambda[static_cast<std::size_t>(s)] = false;
      sd.out.candidate_lambda.col(s).setZero();
      if (sd.out.candidate_spring.cols() > s) sd.out.candidate_spring.col(s).setZero();
    }
  }
}

}  // namespace stages
}  // namespace stiction
