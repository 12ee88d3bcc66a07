#include "stiction/rollout.hpp"

#include <algorithm>
#include <atomic>
#include <exception>
#include <limits>
#include <new>
#include <stdexcept>
#include <thread>

namespace stiction {

std::size_t Recording::size(const SimulatorModel& sim, int n_steps, int every) {
  const auto n = static_cast<std::size_t>(n_steps / every + 1);
  const auto nc = static_cast<std::size_t>(sim.numCandidates());
  // t, q, v, lam, contact_velocity, gaps, states, rows, anchor_lam, residual, iterations,
  // converged, dt, timings
  const std::size_t per_record = 1 + static_cast<std::size_t>(sim.model.nq + sim.model.nv) + 9 * nc +
                                 3 * sim.anchors.size() + 4 + 5;
  return n * per_record;
}

void Recording::allocate(const SimulatorModel& sim, int n_steps, int every, double* storage) {
  const Eigen::Index n = n_steps / every + 1;
  const Eigen::Index nc = sim.numCandidates(), na = static_cast<Eigen::Index>(sim.anchors.size());
  const std::size_t total = size(sim, n_steps, every);
  if (storage == nullptr) {
    own_.resize(total);
    storage = own_.data();
  } else {
    own_.clear();
  }
  // NaN until recorded; and the block's fresh pages are faulted in here, not by the loop's first
  // writes (the operating system clearing a page in the middle of the steps evicted their working
  // set: measured +0.9 us a Solo-12 step)
  std::fill(storage, storage + total, std::numeric_limits<double>::quiet_NaN());
  double* at = storage;  // (in the order of size() and fields())
  const auto vector = [&](Eigen::Map<Eigen::VectorXd>& x) {
    new (&x) Eigen::Map<Eigen::VectorXd>(at, n);
    at += n;
  };
  const auto matrix = [&](Eigen::Map<Rows>& x, Eigen::Index cols) {
    new (&x) Eigen::Map<Rows>(at, n, cols);
    at += n * cols;
  };
  vector(t);
  matrix(q, sim.model.nq);
  matrix(v, sim.model.nv);
  matrix(lam, 3 * nc);
  matrix(contact_velocity, 3 * nc);
  matrix(gaps, nc);
  matrix(states, nc);
  matrix(rows, nc);
  matrix(anchor_lam, 3 * na);
  vector(residual);
  vector(iterations);
  vector(converged);
  vector(dt);
  matrix(timings, 5);
  records = 0;
  error.clear();
}

bool Recording::fits(const SimulatorModel& sim, int n_steps, int every) const {
  return t.data() != nullptr && t.size() == n_steps / every + 1 && q.cols() == sim.model.nq &&
         v.cols() == sim.model.nv && gaps.cols() == sim.numCandidates() &&
         anchor_lam.cols() == 3 * static_cast<Eigen::Index>(sim.anchors.size());
}

std::vector<Recording::Field> Recording::fields() const {
  const double* base = t.data();
  const auto offset = [&](const double* p) { return static_cast<std::size_t>(p - base); };
  return {{"t", 0, -1},
          {"q", offset(q.data()), q.cols()},
          {"v", offset(v.data()), v.cols()},
          {"lam", offset(lam.data()), lam.cols()},
          {"contact_velocity", offset(contact_velocity.data()), contact_velocity.cols()},
          {"gaps", offset(gaps.data()), gaps.cols()},
          {"states", offset(states.data()), states.cols()},
          {"rows", offset(rows.data()), rows.cols()},
          {"anchor_lam", offset(anchor_lam.data()), anchor_lam.cols()},
          {"residual", offset(residual.data()), -1},
          {"iterations", offset(iterations.data()), -1},
          {"converged", offset(converged.data()), -1},
          {"dt", offset(dt.data()), -1},
          {"timings", offset(timings.data()), timings.cols()}};
}

void Recording::record(const SimulatorModel& sim, const SimulatorData& d) {
  const int r = records++;
  const int nc = sim.numCandidates();
  t[r] = d.t;
  q.row(r) = d.q.transpose();
  v.row(r) = d.v.transpose();
  for (int i = 0; i < nc; ++i) {
    lam.block<1, 3>(r, 3 * i) = d.candidate_lambda.col(i).transpose();
    contact_velocity.block<1, 3>(r, 3 * i) = d.candidate_velocity.col(i).transpose();
    states(r, i) = static_cast<int>(d.candidate_states[i]);
    rows(r, i) = d.candidate_rows[i];
  }
  gaps.row(r) = d.gaps.transpose();
  for (std::size_t a = 0; a < sim.anchors.size(); ++a)
    anchor_lam.block<1, 3>(r, 3 * a) = d.anchor_lambda.col(a).transpose();
  residual[r] = d.max_residual_step;
  iterations[r] = d.iterations_step;
  converged[r] = d.all_converged_step ? 1.0 : 0.0;
  dt[r] = d.last_dt;
  timings.row(r) << d.timings.kinematics, d.timings.delassus, d.timings.solve, d.timings.integrate,
      d.timings.total;
}

namespace {

void checkCounts(int n_steps, int every) {
  if (n_steps < 0) throw std::invalid_argument("rollout: n_steps must be >= 0");
  if (every < 1) throw std::invalid_argument("rollout: record_every must be >= 1");
}

void run(const SimulatorModel& sim, SimulatorData& d, int n_steps, int every, Recording& out) {
  out.record(sim, d);
  for (int k = 1; k <= n_steps; ++k) {
    step(sim, d);
    if (k % every == 0) out.record(sim, d);
  }
}

}  // namespace

void rollout(const SimulatorModel& sim, SimulatorData& d, int n_steps, int every, Recording& out) {
  checkCounts(n_steps, every);
  if (!out.fits(sim, n_steps, every)) out.allocate(sim, n_steps, every);
  run(sim, d, n_steps, every, out);
}

void batchRollout(const std::vector<BatchItem>& items, int n_steps, int every, int threads,
                  std::vector<Recording>& out) {
  checkCounts(n_steps, every);
  for (std::size_t i = 0; i < items.size(); ++i) {
    if (items[i].sim == nullptr || items[i].data == nullptr)
      throw std::invalid_argument("batch rollout: item " + std::to_string(i) + " has no model or data");
    for (std::size_t j = 0; j < i; ++j)
      if (items[j].data == items[i].data)
        throw std::invalid_argument("batch rollout: items " + std::to_string(j) + " and " + std::to_string(i) +
                                    " share one SimulatorData (each simulation needs its own)");
  }
  out.resize(items.size());
  for (std::size_t i = 0; i < items.size(); ++i) out[i].allocate(*items[i].sim, n_steps, every);
  if (threads <= 0) threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const int workers = static_cast<int>(std::min<std::size_t>(static_cast<std::size_t>(threads), items.size()));
  std::atomic<std::size_t> next{0};
  auto work = [&]() {
    for (std::size_t i = next++; i < items.size(); i = next++) {
      try {
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
