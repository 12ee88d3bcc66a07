// The clock of the step's phase timers and the solver's stage times.
#pragma once

#include <chrono>
#include <cstdint>

namespace stiction {

/// A steady clock read from the processor's time-stamp counter where it is invariant (x86-64:
/// constant rate, not stopped in sleep states; ~10 ns a read on this AMD EPYC against ~25 ns for
/// std::chrono::steady_clock's clock_gettime, read about 13 times in a robot's 6 us step), else
/// std::chrono::steady_clock itself. Ticks become nanoseconds at a rate measured once against
/// steady_clock, over 2 ms, at the first read (clock.cpp).
struct FastClock {
  using rep = std::int64_t;
  using period = std::nano;
  using duration = std::chrono::nanoseconds;
  using time_point = std::chrono::time_point<FastClock>;
  static constexpr bool is_steady = true;
  static time_point now() noexcept;
};

}  // namespace stiction
