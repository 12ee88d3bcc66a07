// Run-time choice of the hand-written AVX2/FMA kernels (docs/development.md, "No -march=native"):
// each kernel is one function with __attribute__((target("avx2,fma"))), raw pointers and
// intrinsics only, next to a portable loop that computes the same thing.
#pragma once

#if defined(__x86_64__) && defined(__GNUC__)
#define STICTION_X86_KERNELS 1
#endif

namespace stiction {

/// True when this processor has AVX2 and FMA and STICTION_VECTOR_KERNELS is not 0 (1 or unset:
/// use them; any other value is an error, std::invalid_argument).
bool vectorKernels();

}  // namespace stiction
