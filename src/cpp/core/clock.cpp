// FastClock (clock.hpp): the time-stamp counter, converted at a rate measured against steady_clock.
#include "stiction/clock.hpp"

#if defined(__x86_64__) && defined(__GNUC__)
#include <cpuid.h>
#include <x86intrin.h>
#define STICTION_TSC_CLOCK 1
#endif

namespace stiction {

namespace {

struct CounterRate {
  bool usable = false;
  double ns_per_tick = 0.0;
  std::uint64_t tick0 = 0;  // the counter at calibration (keeps the converted values small)
  std::int64_t ns0 = 0;     // steady_clock's time then, in ns: the two clocks share an epoch
};

CounterRate calibrate() {
  CounterRate rate;
#ifdef STICTION_TSC_CLOCK
  unsigned a = 0, b = 0, c = 0, d = 0;
  // CPUID 0x80000007, EDX bit 8: the invariant TSC (Linux's "nonstop_tsc")
  if (__get_cpuid(0x80000007u, &a, &b, &c, &d) == 0 || (d & (1u << 8)) == 0) return rate;
  using Steady = std::chrono::steady_clock;
  const Steady::time_point s0 = Steady::now();
  const std::uint64_t t0 = __rdtsc();
  Steady::time_point s1 = s0;
  std::uint64_t t1 = t0;
  while (s1 - s0 < std::chrono::milliseconds(2)) {
    s1 = Steady::now();
    t1 = __rdtsc();
  }
  const double ns = std::chrono::duration<double, std::nano>(s1 - s0).count();
  if (!(t1 > t0) || !(ns > 0.0)) return rate;
  rate.ns_per_tick = ns / static_cast<double>(t1 - t0);
  rate.tick0 = t1;
  rate.ns0 = std::chrono::duration_cast<std::chrono::nanoseconds>(s1.time_since_epoch()).count();
  rate.usable = true;
#endif
  return rate;
}

const CounterRate& counterRate() {
  static const CounterRate rate = calibrate();
  return rate;
}

}  // namespace

FastClock::time_point FastClock::now() noexcept {
#ifdef STICTION_TSC_CLOCK
  const CounterRate& rate = counterRate();
  if (rate.usable) {
    // (signed: a read on a core whose counter lags the calibration's by a few ticks stays valid)
    const auto ticks = static_cast<std::int64_t>(__rdtsc() - rate.tick0);
    return time_point(duration(rate.ns0 + static_cast<rep>(static_cast<double>(ticks) * rate.ns_per_tick)));
  }
#endif
  return time_point(std::chrono::duration_cast<duration>(std::chrono::steady_clock::now().time_since_epoch()));
}

}  // namespace stiction
