#include "stiction/rollout.hpp"

#include <algorithm>
#include <atomic>
#include <exception>
#include <limits>
#include <new>
#include <stdexcept>
#include <thread>

namespace stiction {

namespace {

// The arrays of a recording in the block's order, each with its columns per record (-1: a vector,
// one value): size(), allocate() and fields() all read this one list.
struct Array {
  const char* name;
  Eigen::Map<Eigen::VectorXd> Recording::*vector;  // (one of the two set)
  Eigen::Map<Recording::Rows> Recording::*rows;
  Eigen::Index cols;
};

std::vector<Array> arrays(const SimulatorModel& sim) {
  const Eigen::Index nc = sim.numCandidates(), na = static_cast<Eigen::Index>(sim.anchors.size());
  using R = Recording;
  return {{"t", &R::t, nullptr, -1},
          {"q", nullptr, &R::q, sim.model.nq},
          {"v", nullptr, &R::v, sim.model.nv},
          {"lam", nullptr, &R::lam, 3 * nc},
          {"contact_velocity", nullptr, &R::contact_velocity, 3 * nc},
          {"gaps", nullptr, &R::gaps, nc},
          {"states", nullptr, &R::states, nc},
          {"rows", nullptr, &R::rows, nc},
          {"anchor_lam", nullptr, &R::anchor_lam, 3 * na},
          {"tau", nullptr, &R::tau, sim.model.nv},
          {"joint_friction", nullptr, &R::joint_friction, sim.model.nv},
          {"limit_torque", nullptr, &R::limit_torque, sim.model.nv},
          {"residual", &R::residual, nullptr, -1},
          {"iterations", &R::iterations, nullptr, -1},
          {"converged", &R::converged, nullptr, -1},
          {"dt", &R::dt, nullptr, -1},
          {"timings", nullptr, &R::timings, 5},
          {"contact_force", nullptr, &R::contact_force, 3 * nc},
          {"accelerometer", nullptr, &R::accelerometer, 3}};
}

}  // namespace

std::size_t Recording::size(const SimulatorModel& sim, int n_steps, int every) {
  std::size_t per_record = 0;
  for (const Array& a : arrays(sim)) per_record += static_cast<std::size_t>(a.cols < 0 ? 1 : a.cols);
  return static_cast<std::size_t>(count(n_steps, every)) * per_record;
}

void Recording::allocate(const SimulatorModel& sim, int n_steps, int every, double* storage) {
  const Eigen::Index n = count(n_steps, every);
  const std::size_t total = size(sim, n_steps, every);
  if (storage == nullptr) {
    own_.resize(total);
    storage = own_.data();
  } else {
    own_.clear();
  }
  double* at = storage;
  for (const Array& a : arrays(sim)) {
    if (a.vector != nullptr) {
      new (&(this->*a.vector)) Eigen::Map<Eigen::VectorXd>(at, n);
      at += n;
    } else {
      new (&(this->*a.rows)) Eigen::Map<Rows>(at, n, a.cols);
      at += n * a.cols;
    }
  }
  fields_ = {};
  for (const Array& a : arrays(sim)) {
    const double* p = a.vector != nullptr ? (this->*a.vector).data() : (this->*a.rows).data();
    fields_.push_back({a.name, static_cast<std::size_t>(p - storage), a.cols});
  }
  laid_out_ = total;
  clear();
}

void Recording::clear() {
  // NaN until recorded; and the block's fresh pages are faulted in here, not by the loop's first
  // writes (the operating system clearing a page in the middle of the steps evicted their working
  // set: measured +0.9 us a Solo-12 step)
  std::fill(t.data(), t.data() + laid_out_, std::numeric_limits<double>::quiet_NaN());
  records = 0;
  error.clear();
}

bool Recording::fits(const SimulatorModel& sim, int n_steps, int every) const {
  return t.data() != nullptr && t.size() == count(n_steps, every) && q.cols() == sim.model.nq &&
         v.cols() == sim.model.nv && gaps.cols() == sim.numCandidates() &&
         anchor_lam.cols() == 3 * static_cast<Eigen::Index>(sim.anchors.size());
}

void Recording::record(const SimulatorModel& sim, const SimulatorData& d, bool initial) {
  const int r = records++;
  const int nc = sim.numCandidates();
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  t[r] = d.t;
  q.row(r) = d.q.transpose();
  v.row(r) = d.v.transpose();
  for (int i = 0; i < nc; ++i) {
    contact_velocity.block<1, 3>(r, 3 * i) = d.out.candidate_velocity.col(i).transpose();
    rows(r, i) = d.out.candidate_rows[i];
    if (initial) {  // no step led here: no force, no state of a solve
      lam.block<1, 3>(r, 3 * i).setConstant(kNaN);
      states(r, i) = kNaN;
    } else {
      lam.block<1, 3>(r, 3 * i) = d.out.candidate_lambda.col(i).transpose();
      states(r, i) = static_cast<int>(d.out.candidate_states[i]);
    }
  }
  gaps.row(r) = d.out.gaps.transpose();
  for (std::size_t a = 0; a < sim.anchors.size(); ++a) {
    if (initial)
      anchor_lam.block<1, 3>(r, 3 * a).setConstant(kNaN);
    else
      anchor_lam.block<1, 3>(r, 3 * a) = d.out.anchor_lambda.col(a).transpose();
  }
  if (initial) {  // (the torques of the step that led here: none)
    tau.row(r).setConstant(kNaN);
    joint_friction.row(r).setConstant(kNaN);
    limit_torque.row(r).setConstant(kNaN);
  } else {
    tau.row(r) = d.out.actuator_torque.transpose();
    joint_friction.row(r) = d.out.friction_torque.transpose();
    limit_torque.row(r) = d.out.limit_torque.transpose();
  }
  if (initial) {  // (sensors: no step behind this record)
    contact_force.row(r).setConstant(kNaN);
    accelerometer.row(r).setConstant(kNaN);
  } else {
    contact_force.row(r) = Eigen::Map<const Eigen::RowVectorXd>(d.out.contact_force.data(), 3 * nc);
    accelerometer.row(r) = d.out.accelerometer.transpose();
  }
  residual[r] = d.out.max_residual_step;
  iterations[r] = d.out.iterations_step;
  converged[r] = d.out.all_converged_step ? 1.0 : 0.0;
  dt[r] = d.out.last_dt;
  timings.row(r) << d.out.timings.kinematics, d.out.timings.delassus, d.out.timings.solve, d.out.timings.integrate,
      d.out.timings.total;
}

namespace {

void checkCounts(int n_steps, int every) {
  if (n_steps < 0) throw std::invalid_argument("rollout: n_steps must be >= 0");
  if (every < 1) throw std::invalid_argument("rollout: record_every must be >= 1");
}

// The first record is the state the rollout starts from, with its own contacts (gaps, rows,
// J v: contactsAtState), not those of the step that led to it (or of none: zeros). The last is
// the final state even when n_steps is not a multiple of `every` (else the trajectory would end
// up to every - 1 steps early, and a summary's duration with it).
void run(const SimulatorModel& sim, SimulatorData& d, int n_steps, int every, Recording& out,
         bool initial_contacts = true, const std::function<void()>& before_step = nullptr) {
  if (initial_contacts) contactsAtState(sim, d);
  out.record(sim, d, /*initial=*/true);
  for (int k = 1; k <= n_steps; ++k) {
    if (before_step) before_step();
    step(sim, d);
    if (k % every == 0 || k == n_steps) out.record(sim, d);
  }
}

}  // namespace

void rollout(const SimulatorModel& sim, SimulatorData& d, int n_steps, int every, Recording& out,
             bool initial_contacts, const std::function<void()>& before_step) {
  checkCounts(n_steps, every);
  if (!out.fits(sim, n_steps, every))
    out.allocate(sim, n_steps, every);
  else if (out.records != 0)
    out.clear();  // (laid out for these counts but used: NaN again, from its first row)
  run(sim, d, n_steps, every, out, initial_contacts, before_step);
}

void batchRollout(const std::vector<BatchItem>& items, int n_steps, int every, int threads,
                  std::vector<Recording>& out, const std::vector<double*>& storage) {
  checkCounts(n_steps, every);
  if (!storage.empty() && storage.size() != items.size())
    throw std::invalid_argument("batch rollout: " + std::to_string(storage.size()) + " storage blocks for " +
                                std::to_string(items.size()) + " items");
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (items[i].sim == nullptr || items[i].data == nullptr)
      throw std::invalid_argument("batch rollout: item " + std::to_string(i) + " has no model or data");
    for (std::size_t j = 0; j < i; ++j)
      if (items[j].data == items[i].data)
        throw std::invalid_argument("batch rollout: items " + std::to_string(j) + " and " + std::to_string(i) +
                                    " share one SimulatorData (each simulation needs its own)");
  }
  out.clear();  // (a recording laid out before would keep its block: every one is laid out anew below)
  out.resize(items.size());
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const int workers = static_cast<int>(std::min<std::size_t>(static_cast<std::size_t>(threads), items.size()));
  std::atomic<std::size_t> next{0};
  auto work = [&]() {
    for (std::size_t i = next++; i < items.size(); i = next++) {
      try {
        // laid out here, by the thread that writes it: the NaN fill faults its pages in on this
        // thread's core, in parallel with the other threads' (doc of batchRollout)
        out[i].allocate(*items[i].sim, n_steps, every, storage.empty() ? nullptr : storage[i]);
        run(*items[i].sim, *items[i].data, n_steps, every, out[i]);
      } catch (const std::exception& e) {
        out[i].error = e.what();
      } catch (...) {
        out[i].error = "unknown error";
      }
    }
  };
  if (workers <= 1) {
    work();
    return;
  }
  std::vector<std::thread> pool;
  pool.reserve(workers - 1);
  for (int w = 1; w < workers; ++w) pool.emplace_back(work);
  work();
  for (std::thread& th : pool) th.join();
}

}  // namespace stiction
