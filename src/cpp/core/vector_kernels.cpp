#include "stiction/vector_kernels.hpp"

#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>

namespace stiction {

#ifdef STICTION_X86_KERNELS
bool vectorKernels() {
  static const bool use = [] {
    const char* env = std::getenv("STICTION_VECTOR_KERNELS");
    if (env != nullptr && std::strcmp(env, "0") == 0) return false;
    if (env != nullptr && std::strcmp(env, "1") != 0 && env[0] != '\0')
      throw std::invalid_argument(std::string("STICTION_VECTOR_KERNELS must be 0 or 1, got '") + env + "'");
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
  }();
  return use;
}
#else
bool vectorKernels() { return false; }
#endif

}  // namespace stiction
