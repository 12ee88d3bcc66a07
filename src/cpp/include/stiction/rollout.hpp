// Rollouts without Python: n steps of one simulation recorded into plain Eigen arrays, and a
// batch of independent simulations run on a pool of threads (each its own SimulatorData; the
// SimulatorModels are only read, so several simulations may share one).
#pragma once

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "stiction/simulator.hpp"

namespace stiction {

/// Every `every`-th state of a rollout, the first and the last (when n_steps is not a multiple of
/// `every`, the last record follows fewer than `every` steps), row per record. The arrays are views of
/// one block of doubles: its own, or one the caller lays them out in (allocate), such as the
/// memory of the arrays Python receives, so a recording is written once and never copied.
struct Recording {
  /// One row per record: a step's values are contiguous (column-major, each record's values lay
  /// a column's length apart: on a 256-contact tower's 2000-step rollout, writing them was 12 % of
  /// the rollout).
  using Rows = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  Eigen::Map<Eigen::VectorXd> t{nullptr, 0}, residual{nullptr, 0}, iterations{nullptr, 0}, converged{nullptr, 0},
      dt{nullptr, 0};
  Eigen::Map<Rows> q{nullptr, 0, 0}, v{nullptr, 0, 0}, lam{nullptr, 0, 0}, contact_velocity{nullptr, 0, 0},
      gaps{nullptr, 0, 0}, states{nullptr, 0, 0}, rows{nullptr, 0, 0}, anchor_lam{nullptr, 0, 0},
      tau{nullptr, 0, 0}, joint_friction{nullptr, 0, 0}, limit_torque{nullptr, 0, 0}, timings{nullptr, 0, 0};
  /// Sensors (SimulatorOutputs::contact_force, 3 per candidate, world; accelerometer, 3; NaN in record 0).
  Eigen::Map<Rows> contact_force{nullptr, 0, 0}, accelerometer{nullptr, 0, 0};
  int records = 0;       ///< rows filled (fewer than allocated when the rollout stopped early)
  std::string error;     ///< why it stopped early (the step's exception), empty when it ran to the end

  Recording() = default;
  Recording(Recording&&) = default;  // (the views keep pointing at the same block)
  Recording& operator=(Recording&&) = default;
  Recording(const Recording&) = delete;
  Recording& operator=(const Recording&) = delete;

  /// The records of a rollout of n_steps recording every `every`-th: the first, one per `every`
  /// steps, and the last state when n_steps is not a multiple of `every` (ceil(n_steps / every) + 1).
  static Eigen::Index count(int n_steps, int every) {
    return static_cast<Eigen::Index>(n_steps / every + 1 + (n_steps % every != 0 ? 1 : 0));
  }
  /// The doubles count() records of `sim` take, every array in one block.
  static std::size_t size(const SimulatorModel& sim, int n_steps, int every);
  /// Lays the arrays out for count() records of `sim`, filled with NaN: in `storage`
  /// (size() doubles), or when it is null in a block of its own.
  void allocate(const SimulatorModel& sim, int n_steps, int every, double* storage = nullptr);
  /// True when the arrays are laid out for these counts (allocate need not run again).
  bool fits(const SimulatorModel& sim, int n_steps, int every) const;
  /// NaN in every array again, no record (the layout kept).
  void clear();
  /// The arrays in the block's order, each with its offset (in doubles) and columns (-1: a vector).
  struct Field {
    const char* name;
    std::size_t offset;
    Eigen::Index cols;
  };
  const std::vector<Field>& fields() const { return fields_; }
  /// Appends d's state and its per-candidate values. `initial`: the rollout's first record, the
  /// state before any step (contactsAtState ran on it): lam, states and anchor_lam NaN (no solve
  /// led there); else the last step's forces and states.
  void record(const SimulatorModel& sim, const SimulatorData& d, bool initial = false);

 private:
  std::vector<double> own_;
  std::vector<Field> fields_;  // (set by allocate, from the one list of arrays in rollout.cpp)
  std::size_t laid_out_ = 0;   // doubles in the block
};

/// n_steps of `d` from its current state, recording every `every`-th and the last (into `out` as laid out by
/// allocate for these counts, else allocated here). Throws std::invalid_argument for bad counts; a
/// step that throws propagates (the recording keeps what came before it).
/// `initial_contacts` false: record 0's contact fields are left as the last step wrote them instead
/// of measured at the starting state (contactsAtState: kinematics and detection once more), for a
/// caller that drops record 0.
/// `before_step` (optional): called before each step, after the previous step's record: a
/// controller writing d.control (its writes act on that step). What it throws stops the rollout
/// and propagates, `d` left after the steps done so far and `out` with their records.
void rollout(const SimulatorModel& sim, SimulatorData& d, int n_steps, int every, Recording& out,
             bool initial_contacts = true, const std::function<void()>& before_step = nullptr);

/// One simulation of a batch: its model, its data (state in, state out) and what it records.
struct BatchItem {
  const SimulatorModel* sim = nullptr;
  SimulatorData* data = nullptr;
};

/// Runs every item's rollout of n_steps on min(threads, items) threads (threads <= 0: the
/// hardware's). Items are independent; a simulation that fails (diverges, an infeasible
/// contact problem) stops there with out[i].error set and NaN in its unrecorded rows, while
/// the others go on. out is resized to the number of items.
/// `storage` (empty, or one pointer per item, each to Recording::size() doubles, e.g. the memory of
/// the arrays Python receives): where item i's recording is laid out, so it is never copied. Each
/// recording is laid out (and its pages faulted in by the NaN fill) by the thread that runs the item,
/// not before the threads start: done serially, with the copy out afterwards, that was ~20 % of an
/// 8 x 2000-step Solo-12 batch on one thread, and what kept 2 threads at 1.5x.
void batchRollout(const std::vector<BatchItem>& items, int n_steps, int every, int threads,
                  std::vector<Recording>& out, const std::vector<double*>& storage = {});

}  // namespace stiction
