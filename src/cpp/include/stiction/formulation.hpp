// Formulations: the ways to turn one step's (A, b, constraint blocks) into impulses.
//
// The exact one is the paper's (eq. 65 = De Saxce's NCP, eq. 73-77), resolved by any of the
// solvers of solver.hpp. The others are the shortcuts the paper compares it with (§4.5-4.6):
//
//   ccp       Anitescu-Tasora's cone complementarity: E s(u) dropped (eq. 78-79)
//   nakaoka   A dropped from the metric, per-contact projection (eq. 80-81)
//   pyramid   every friction cone replaced by an N-facet pyramid: the Stewart-Trinkle /
//             Anitescu-Potra LCP (§4.5)
//   penalty   spring-damper normal and friction (eq. 83-84), implicit Euler as
//             Kikuuwe-Fujimoto (closed form per contact through relation (4))
//   pinocchio-admm, pinocchio-pgs   Pinocchio's own solvers, NCP setting (pinocchio-admm-ccp: its CCP)
//
// Every formulation is a ContactSolver (solver.hpp): solve() runs it and then judges the
// result by the exact law, the same yardstick for all (result.residual, status, states; the
// full set of measures: exact_law.hpp). The formulation itself says whether it met its own
// stopping test (result.own_converged, own_residual, own_law).
//
// Adding a formulation: one file in src/cpp/formulations/ with a class deriving from
// Formulation, and one line in the registry (formulation.cpp).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "stiction/solver.hpp"

namespace stiction {

/// Parameters of the formulations that have some (defaults = `stiction formulations`).
struct FormulationSettings {
  std::string exact_solver = "default";  ///< exact: which solver of solver.hpp
  int pyramid_facets = 4;                ///< pyramid: N facets per spatial cone (3 .. kMaxFacets, solver.hpp)
  bool pyramid_inscribed = false;        ///< pyramid: vertices on the cone (true) or facets tangent to it
  int pyramid_max_fixed_point = 100;     ///< pyramid: outer iterations on the pyramid's De Saxce term
  double penalty_stiffness = 1e5;        ///< penalty: K, N/m per contact (normal and tangential)
  double penalty_damping = 1e-3;         ///< penalty: beta, seconds (damping coefficient K beta)
};

/// What a formulation may know about the step beyond (A, b). The simulator fills it; a
/// bare algebraic problem (stiction.solve, FCLib) has h = 1 and no position error.
struct StepContext {
  double h = 1.0;  ///< step length: the problem's unknowns are impulses h lambda
  /// Psi per row (normal rows: the signed gap; anchor rows: the anchor's error; 0 elsewhere),
  /// and u = A P - b contains Psi / h on those rows (eq. 70). nullptr: all zero.
  const Eigen::VectorXd* position_error = nullptr;
  /// Internal state per row, read and updated by formulations that have one (penalty: the
  /// tangential spring elongation e_t of eq. 83 on tangential rows). nullptr: none kept.
  Eigen::VectorXd* state = nullptr;
};

class Formulation : public ContactSolver {
 public:
  /// The paper's equations this formulation implements, e.g. "78-79".
  virtual std::string equations() const = 0;
  bool exactLaw() const override { return false; }
  void setContext(const StepContext& context) { context_ = context; }
  void setSettings(const FormulationSettings& settings) { settings_ = settings; }

 protected:
  StepContext context_;
  FormulationSettings settings_;
};

struct FormulationInfo {
  std::string name;
  std::string equations;
  std::string summary;
  std::vector<std::string> parameters;  ///< "name = default: meaning"
};

/// "exact" (the solver named by settings.exact_solver), "ccp", "nakaoka", "pyramid",
/// "penalty", "pinocchio-admm", "pinocchio-pgs", "pinocchio-admm-ccp".
/// Throws std::invalid_argument naming the known ones, or a bad parameter.
std::unique_ptr<ContactSolver> makeFormulation(const std::string& name, const FormulationSettings& settings = {});
std::vector<FormulationInfo> formulationInfos();
std::vector<std::string> formulationNames();

/// The context of a formulation made by makeFormulation (no-op for exact solvers).
void setFormulationContext(ContactSolver& solver, const StepContext& context);

/// Validate the settings (throws std::invalid_argument naming the field).
void checkFormulationSettings(const FormulationSettings& settings);

}  // namespace stiction
