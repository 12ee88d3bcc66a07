#include "stiction/rollout.hpp"

#include <algorithm>
#include <atomic>
#include <exception>
#include <limits>
#include <stdexcept>
#include <thread>

namespace stiction {

void Recording::allocate(const SimulatorModel& sim, int n_steps, int every) {
  const int n = n_steps / every + 1;
  const int nc = sim.numCandidates();
  const int na = static_cast<int>(sim.anchors.size());
  const double nan = std::numeric_limits<double>::quiet_NaN();
  for (Eigen::VectorXd* x : {&t, &residual, &iterations, &converged, &dt}) x->setConstant(n, nan);
  q.setConstant(n, sim.model.nq, nan);
  v.setConstant(n, sim.model.nv, nan);
  lam.setConstant(n, 3 * nc, nan);
  contact_velocity.setConstant(n, 3 * nc, nan);
  gaps.setConstant(n, nc, nan);
  states.setConstant(n, nc, nan);
  rows.setConstant(n, nc, nan);
  anchor_lam.setConstant(n, 3 * na, nan);
  timings.setConstant(n, 5, nan);
  records = 0;
  error.clear();
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
  out.allocate(sim, n_steps, every);
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
