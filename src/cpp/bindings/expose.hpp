// One expose function per area, all registered by module.cpp.
#pragma once

namespace stiction {
namespace python {
void exposeProblem();
void exposeSolver();
void exposeSimulator();
}  // namespace python
}  // namespace stiction
