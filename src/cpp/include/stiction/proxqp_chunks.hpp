// ProxQP under a budget of iterations and a time limit. proxsuite's dense QP has no clock, so a
// solve runs in chunks of inner iterations, each sized from the cost per iteration measured so far
// to at most half the time left, warm-started from the previous chunk's result. Its workspace is
// dense in the QP's rows: checkDenseQpSize refuses what would not fit before proxsuite allocates
// (a 20,000-facet pyramid aborted the process; 1e9 facets grew to 24 GB until the kernel killed it).
//
// Include after <proxsuite/proxqp/dense/dense.hpp> (the translation units that use ProxQP).
#pragma once

#include <algorithm>
#include <chrono>
#include <string>

#include <Eigen/Core>

#include "stiction/clock.hpp"

namespace stiction {

/// The largest dense QP workspace allowed: proxsuite's KKT matrix and its factor hold about two
/// (n + n_in)^2 doubles (n variables, n_in inequality rows).
constexpr double kMaxDenseQpBytes = 1024.0 * 1024.0 * 1024.0;

/// Throws std::invalid_argument naming `what` and the sizes when ProxQP's dense workspace for n
/// variables and n_in inequality rows would exceed kMaxDenseQpBytes.
inline void checkDenseQpSize(const std::string& what, Eigen::Index n, Eigen::Index n_in) {
  const double rows = static_cast<double>(n) + static_cast<double>(n_in);
  const double bytes = 2.0 * 8.0 * rows * rows;
  if (bytes > kMaxDenseQpBytes)
    throw std::invalid_argument(what + ": ProxQP's dense QP would have " + std::to_string(n) + " variables and " +
                                std::to_string(n_in) + " inequality rows, a workspace of about " +
                                std::to_string(static_cast<long long>(bytes / 1048576.0)) +
                                " MiB (two (n + n_in)^2 matrices of doubles); refused above " +
                                std::to_string(static_cast<long long>(kMaxDenseQpBytes / 1048576.0)) +
                                " MiB: use fewer facets or fewer contacts");
}

struct QpChunks {
  long iterations = 0;     ///< inner iterations run, all chunks
  bool timed_out = false;  ///< stopped by the time limit (not solved, budget left)
};

/// qp.solve() in chunks: at most `budget` inner iterations in all; with time_limit > 0, none
/// started once `time_limit` seconds have passed since `start`, and each sized to at most half the
/// time left at the measured cost per iteration (first guess: `per_iteration` seconds). The first
/// chunk starts as qp.settings.initial_guess says, the next ones from the previous result; the
/// setting is restored at the end. Stops when ProxQP returns anything but "max iterations".
template <class Qp>
QpChunks solveQpInChunks(Qp& qp, long budget, double time_limit, FastClock::time_point start, double per_iteration) {
  namespace pq = proxsuite::proxqp;
  auto since = [&]() { return std::chrono::duration<double>(FastClock::now() - start).count(); };
  QpChunks out;
  const auto initial_guess = qp.settings.initial_guess;
  budget = std::max(1L, budget);
  for (int call = 0;; ++call) {
    long chunk = budget - out.iterations;
    if (chunk < 1) break;
    if (time_limit > 0.0) {
      const double left = time_limit - since();
      chunk = std::min<long>(chunk, static_cast<long>(0.5 * left / per_iteration));
      if (chunk < 1) {
        out.timed_out = true;
        break;
      }
    }
    qp.settings.max_iter_in = std::min<long>(chunk, 1500);
    qp.settings.max_iter = std::max<long>(1, chunk / qp.settings.max_iter_in);
    if (call > 0) qp.settings.initial_guess = pq::InitialGuessStatus::WARM_START_WITH_PREVIOUS_RESULT;
    const double t0 = since();
    qp.solve();
    const long done = std::max<long>(1, static_cast<long>(qp.results.info.iter));
    out.iterations += done;
    per_iteration = std::max(1e-9, (since() - t0) / done);  // call overheads included: they are real
    if (qp.results.info.status != pq::QPSolverOutput::PROXQP_MAX_ITER_REACHED) break;
  }
  qp.settings.initial_guess = initial_guess;
  return out;
}

}  // namespace stiction
