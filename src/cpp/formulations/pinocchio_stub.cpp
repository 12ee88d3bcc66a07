// TEMPORARY until pinocchio_solvers.cpp lands (helper): not committed.
#include <stdexcept>
#include "formulations.hpp"
namespace stiction {
std::unique_ptr<Formulation> makePinocchioFormulation(const std::string& method, bool) {
  throw std::invalid_argument("pinocchio-" + method + ": not built yet");
}
}  // namespace stiction
