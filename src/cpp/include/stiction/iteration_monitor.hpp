// What the iterative solvers (NSGS, ADMM, Newton, and the default's cascade of them) watch while
// they iterate: their time budget on one clock, the rate at which their residual falls, and the
// stall that rate predicts. One implementation for all: each used to keep its own.
#pragma once

#include <cstddef>
#include <utility>
#include <vector>

#include "stiction/clock.hpp"

namespace stiction {

/// IterationMonitor's deceleration rule (see there): none by default.
struct Deceleration {
  int track_from = -1;  ///< -1: no deceleration rule
  int judge_from = 0;
  double factor = 0.0;
};

class IterationMonitor {
 public:
  // ---- time budget, on FastClock (clock.hpp: the time-stamp counter, ~10 ns a read)

  /// Starts the clock for `limit` seconds (0: none). Without a limit the clock is never read:
  /// the simulator's per-step solves have none.
  void startClock(double limit);
  bool timeLimited() const { return limit_ > 0.0; }
  /// Seconds since startClock (0 without a limit).
  double elapsed() const;
  /// The limit has passed (never without one).
  bool outOfTime() const { return timeLimited() && elapsed() >= limit_; }
  /// What a stage started now may use: the rest of the limit, at least 1e-9 s so that it stays
  /// a limit (0 without one).
  double remaining() const;

  // ---- convergence rate and stall
  //
  // The caller records (iteration, residual) pairs, iterations increasing (not necessarily every
  // one: ADMM measures every 4th on large problems). Once they span the window, the rate is
  // rho = (r_last / r_first)^(1 / span) over the shortest span >= window ending at the last, and
  //
  //     needed = log(tolerance / r_last) / log(rho)      (infinite when rho is not below 1)
  //
  // the iterations that rate still needs. Stalled: needed exceeds the caller's horizon, or (with a
  // deceleration rule) the predicted finishing iteration, iteration + needed, has moved more than
  // `factor` times later than its earliest value (tracked from iteration `track_from`, judged from
  // `judge_from`): a rate that decelerates. The samples' storage is kept between runs.

  /// Forget every sample; rates over `window` iterations from now on.
  void resetRate(int window, Deceleration deceleration = {});
  /// The residual at `iteration` (not before the last one recorded).
  void record(int iteration, double residual);
  /// The samples span the window.
  bool rateReady() const;
  /// The rate per iteration over the window (rateReady() must hold).
  double rate() const;
  /// Iterations still needed at rate() to bring the last residual to `tolerance`.
  double needed(double tolerance) const;
  /// Judges the last sample (records nothing): needed(tolerance) > horizon, or the deceleration
  /// rule, whose earliest finish this call updates. False until rateReady().
  bool stalled(double tolerance, double horizon);

 private:
  double limit_ = 0.0;
  FastClock::time_point start_{};

  std::vector<std::pair<int, double>> samples_;  // [first_, end): the window and the one before
  std::size_t first_ = 0;
  int window_ = 1;
  Deceleration deceleration_;
  double earliest_finish_ = 0.0;
};

}  // namespace stiction
