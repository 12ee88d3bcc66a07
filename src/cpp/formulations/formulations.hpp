// Internal: the factories of the formulations, one per file of this folder; the registry
// (formulation.cpp) maps names to them.
#pragma once

#include <memory>
#include <string>

#include "stiction/formulation.hpp"

namespace stiction {

std::unique_ptr<Formulation> makeCcpFormulation();       // ccp.cpp
std::unique_ptr<Formulation> makeNakaokaFormulation();   // nakaoka.cpp
std::unique_ptr<Formulation> makePyramidFormulation();   // pyramid.cpp
std::unique_ptr<Formulation> makePenaltyFormulation();   // penalty.cpp
/// method "admm" or "pgs"; ncp: with De Saxce's correction (Pinocchio's solve_ncp), else its CCP.
std::unique_ptr<Formulation> makePinocchioFormulation(const std::string& method, bool ncp);  // pinocchio_solvers.cpp

}  // namespace stiction
