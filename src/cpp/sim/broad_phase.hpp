// Broad phase for a pool of dynamic coal pairs (internal header).
//
// A scene with dynamic pair entries (GeometryPairContact::dynamic) does not list its pairs: every
// step, sweep-and-prune over the world AABBs of all the geometries finds the pairs whose boxes
// (grown by the activation distance) overlap, and each such pair holds a pool entry for as long as
// it keeps overlapping (so its slots, and the warm start the solve stage reads by slot, follow the
// same two shapes from step to step). A pair that stops overlapping frees its entry; a new pair takes
// the entry freed longest ago. Cost per step: O(N) for the boxes, the insertion sort of the nearly
// sorted sweep order and the sweep itself (plus the overlapping pairs), not N^2 / 2 pair tests.
#pragma once

#include <array>
#include <cstdint>
#include <deque>
#include <unordered_map>
#include <utility>
#include <vector>

#include <coal/collision_data.h>
#include <Eigen/Core>

namespace stiction {

struct SimulatorModel;
struct SimulatorData;

/// Sweep-and-prune on x over axis-aligned boxes (lower, upper: 3 x n). `order` is the sweep order
/// of the last call (kept: an insertion sort of a nearly sorted order is linear). Appends each
/// overlapping pair (a < b) of boxes to `pairs`, skipping those `skip(a, b)` rejects.
template <typename Skip>
void sweepAndPrune(const Eigen::Matrix3Xd& lower, const Eigen::Matrix3Xd& upper, std::vector<int>& order,
                   std::vector<std::pair<int, int>>& pairs, Skip skip) {
  const int n = static_cast<int>(lower.cols());
  if (static_cast<int>(order.size()) != n) {
    order.resize(static_cast<std::size_t>(n));
    for (int k = 0; k < n; ++k) order[static_cast<std::size_t>(k)] = k;
  }
  for (int k = 1; k < n; ++k) {  // insertion sort by lower x
    const int item = order[static_cast<std::size_t>(k)];
    const double key = lower(0, item);
    int j = k - 1;
    while (j >= 0 && lower(0, order[static_cast<std::size_t>(j)]) > key) {
      order[static_cast<std::size_t>(j + 1)] = order[static_cast<std::size_t>(j)];
      --j;
    }
    order[static_cast<std::size_t>(j + 1)] = item;
  }
  for (int k = 0; k < n; ++k) {
    const int a = order[static_cast<std::size_t>(k)];
    for (int m = k + 1; m < n; ++m) {
      const int b = order[static_cast<std::size_t>(m)];
      if (lower(0, b) > upper(0, a)) break;  // sorted by lower x: no later box reaches a
      if (lower(1, b) > upper(1, a) || lower(1, a) > upper(1, b) || lower(2, b) > upper(2, a) ||
          lower(2, a) > upper(2, b))
        continue;
      const int lo = a < b ? a : b, hi = a < b ? b : a;
      if (!skip(lo, hi)) pairs.emplace_back(lo, hi);
    }
  }
}

/// What the broad phase keeps between steps (SimulatorWorkspace::broad).
struct BroadPhaseState {
  Eigen::Matrix3Xd lower, upper;          ///< world AABB of each geometry (grown by the activation distance / 2)
  std::vector<int> order;                 ///< the sweep order (sorted by lower x at the last step)
  std::vector<std::pair<int, int>> found; ///< this step's overlapping pairs (geometry indices)
  std::unordered_map<std::uint64_t, int> entry_of;  ///< pair (a, b) -> its entry (index into sim.pairs)
  std::vector<std::array<int, 2>> geoms;  ///< per sim.pairs entry: the geometries it holds (-1: free, or static)
  std::vector<char> seen;                 ///< per entry: found this step
  std::deque<int> free_entries;           ///< dynamic entries free, the longest free first
  std::vector<coal::CollisionRequest> request;  ///< per entry (its GJK warm start follows the pair)
  std::vector<coal::CollisionResult> result;
  std::vector<coal::ContactPatchResult> patches;
  coal::ContactPatchRequest patch_request;
  bool ready = false;
};

namespace stages {
/// The pool's pairs of this step: boxes, sweep, entries kept / freed / taken (detect.cpp calls it
/// before it fills the slots). Throws when more pairs overlap than the pool has entries.
void assignDynamicPairs(const SimulatorModel& sim, SimulatorData& sd);
}  // namespace stages

}  // namespace stiction
