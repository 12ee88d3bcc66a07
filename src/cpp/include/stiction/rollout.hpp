// Rollouts without Python: n steps of one simulation recorded into plain Eigen arrays, and a
// batch of independent simulations run on a pool of threads (each its own SimulatorData; the
// SimulatorModels are only read, so several simulations may share one).
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "stiction/simulator.hpp"

namespace stiction {

/// Every `every`-th state of a rollout (and the first), row per record.
struct Recording {
  /// One row per record: a step's values are contiguous (column-major, each record's values lay
  /// a column's length apart: on a 256-contact tower's 2000-step rollout, writing them was 12 % of
  /// the rollout).
  using Rows = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  Eigen::VectorXd t, residual, iterations, converged, dt;
  Rows q, v, lam, contact_velocity, gaps, states, rows, anchor_lam, timings;
  int records = 0;       ///< rows filled (fewer than allocated when the rollout stopped early)
  std::string error;     ///< why it stopped early (the step's exception), empty when it ran to the end

  /// Sizes the arrays for n_steps / every + 1 records of `sim`, filled with NaN.
  void allocate(const SimulatorModel& sim, int n_steps, int every);
  void record(const SimulatorModel& sim, const SimulatorData& d);
};

/// n_steps of `d` from its current state, recording every `every`-th. Throws std::invalid_argument
/// for bad counts; a step that throws propagates (the recording keeps what came before it).
void rollout(const SimulatorModel& sim, SimulatorData& d, int n_steps, int every, Recording& out);

/// One simulation of a batch: its model, its data (state in, state out) and what it records.
struct BatchItem {
  const SimulatorModel* sim = nullptr;
  SimulatorData* data = nullptr;
};

/// Runs every item's rollout of n_steps on min(threads, items) threads (threads <= 0: the
/// hardware's). Items are independent; a simulation that fails (diverges, an infeasible
/// contact problem) stops there with out[i].error set and NaN in its unrecorded rows, while
/// the others go on. out is resized to the number of items.
void batchRollout(const std::vector<BatchItem>& items, int n_steps, int every, int threads,
                  std::vector<Recording>& out);

}  // namespace stiction
