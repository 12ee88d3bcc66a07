#include "stiction/iteration_monitor.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

namespace stiction {

void IterationMonitor::startClock(double limit) {
  limit_ = limit > 0.0 ? limit : 0.0;
  start_ = limit_ > 0.0 ? FastClock::now() : FastClock::time_point{};
}

double IterationMonitor::elapsed() const {
  if (!timeLimited()) return 0.0;
  return std::chrono::duration<double>(FastClock::now() - start_).count();
}

double IterationMonitor::remaining() const {
  if (!timeLimited()) return 0.0;
  return std::max(1e-9, limit_ - elapsed());
}

void IterationMonitor::resetRate(int window, Deceleration deceleration) {
  samples_.clear();
  first_ = 0;
  window_ = std::max(1, window);
  deceleration_ = deceleration;
  earliest_finish_ = std::numeric_limits<double>::infinity();
}

void IterationMonitor::record(int iteration, double residual) {
  samples_.emplace_back(iteration, residual);
  // keep one sample at or before the window's start: the shortest span >= window
  while (samples_.size() - first_ > 2 && samples_[first_ + 1].first <= iteration - window_) ++first_;
  if (first_ > 64 && 2 * first_ > samples_.size()) {  // drop the passed samples (no reallocation)
    samples_.erase(samples_.begin(), samples_.begin() + static_cast<std::ptrdiff_t>(first_));
    first_ = 0;
  }
}

bool IterationMonitor::rateReady() const {
  return samples_.size() > first_ && samples_[first_].first <= samples_.back().first - window_;
}

double IterationMonitor::rate() const {
  const auto& from = samples_[first_];
  const auto& last = samples_.back();
  const double span = double(last.first - from.first);
  return std::pow(last.second / from.second, 1.0 / span);
}

double IterationMonitor::needed(double tolerance) const {
  const double rho = rate();
  return rho < 1.0 ? std::log(tolerance / samples_.back().second) / std::log(rho)
                   : std::numeric_limits<double>::infinity();
}

bool IterationMonitor::stalled(double tolerance, double horizon) {
  if (!rateReady()) return false;
  const double more = needed(tolerance);
  const int iteration = samples_.back().first;
  const double finish = iteration + more;
  const bool decelerating = deceleration_.track_from >= 0;
  if (decelerating && iteration >= deceleration_.track_from) earliest_finish_ = std::min(earliest_finish_, finish);
  return more > horizon ||
         (decelerating && iteration >= deceleration_.judge_from && finish > deceleration_.factor * earliest_finish_);
}

}  // namespace stiction
