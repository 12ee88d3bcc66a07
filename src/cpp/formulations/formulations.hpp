// Internal: the factories of the formulations, one per file of this folder; the registry
// (formulation.cpp) maps names to them.
#pragma once

#include <chrono>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string>

#include "stiction/clock.hpp"
#include "stiction/formulation.hpp"

namespace stiction {

std::unique_ptr<Formulation> makeCcpFormulation();       // ccp.cpp
std::unique_ptr<Formulation> makeNakaokaFormulation();   // nakaoka.cpp
std::unique_ptr<Formulation> makePyramidFormulation();   // pyramid.cpp
std::unique_ptr<Formulation> makePenaltyFormulation();   // penalty.cpp
/// method "admm" or "pgs"; ncp: with De Saxce's correction (Pinocchio's solve_ncp), else its CCP.
std::unique_ptr<Formulation> makePinocchioFormulation(const std::string& method, bool ncp);  // pinocchio_solvers.cpp

/// Throws std::invalid_argument (one line) when the problem has box rows: for the formulations
/// that have no law for them (penalty: a spring per contact; Pinocchio's solvers: cones only).
inline void refuseBoxRows(const ContactProblem& problem, const std::string& formulation) {
  for (const Constraint& c : problem.constraints())
    if (c.kind == ConstraintKind::kBox)
      throw std::invalid_argument("formulation '" + formulation +
                                  "' does not handle box rows (joint friction, effort limits): use the exact "
                                  "formulation, or switch them off (joint_friction = false, effort_limits = false)");
}

/// The sweep loop of the Gauss-Seidel formulations (nakaoka, penalty): sweep() once, then
/// residual() (the formulation's own measure), until it is <= settings.tolerance, non-finite, the
/// iteration budget or the time limit; sets result.iterations, message, own_residual, own_converged.
template <class Sweep, class Residual>
void sweepUntilConverged(const SolverSettings& settings, SolverResult& result, Sweep sweep, Residual residual,
                         const char* nonfinite_message) {
  using Clock = FastClock;  // the time-stamp counter (clock.hpp)
  const auto start = Clock::now();
  result.message = "iteration limit reached";
  int done = 0;
  while (done < settings.max_iterations) {
    sweep();
    ++done;
    result.own_residual = residual();
    if (!std::isfinite(result.own_residual)) {
      result.message = nonfinite_message;
      break;
    }
    if (result.own_residual <= settings.tolerance) {
      result.message = "converged";
      break;
    }
    if (settings.time_limit > 0.0 &&
        std::chrono::duration<double>(Clock::now() - start).count() > settings.time_limit) {
      result.message = "time limit reached";
      break;
    }
  }
  if (done == 0) result.own_residual = residual();
  result.iterations = done;
  result.own_converged = result.own_residual <= settings.tolerance;
}

}  // namespace stiction
