#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include "convert.hpp"
#include "expose.hpp"
#include "stiction/solver.hpp"

namespace bp = boost::python;

namespace stiction {
namespace python {

template <>
WarmStart fromPython<WarmStart>(const bp::object& x, const std::string& name) {
  return toEnum<WarmStart>(x, name, "stiction.WarmStart");
}

namespace {

/// Python handle on one algorithm and its reusable workspace.
struct Solver {
  explicit Solver(const std::string& name) : impl(makeSolver(name)) {}
  std::unique_ptr<ContactSolver> impl;

  SolverResult solveWith(const bp::object& problem, const bp::object& settings, const bp::object& guess) {
    const ContactProblem& p = toObject<ContactProblem>(problem, "Solver.solve: problem", "stiction.ContactProblem");
    const SolverSettings& s = toObject<SolverSettings>(settings, "Solver.solve: settings", "stiction.SolverSettings");
    SolverResult result;
    if (guess.is_none()) {
      stiction::solve(p, *impl, s, result, nullptr);
    } else {
      const Eigen::VectorXd v = toVector(guess, "Solver.solve: guess (initial lambda)");
      stiction::solve(p, *impl, s, result, &v);
    }
    return result;
  }
  std::string name() const { return impl->name(); }
};

std::shared_ptr<Solver> makeSolverObject(const bp::object& name) {
  return std::make_shared<Solver>(toStringArg(name, "Solver: name"));
}

Eigen::VectorXd lamOf(const SolverResult& r) { return r.lam; }
Eigen::VectorXd uOf(const SolverResult& r) { return r.u; }
bp::list statesOf(const SolverResult& r) {
  bp::list out;
  for (ContactState s : r.states) out.append(s);
  return out;
}
bp::list stagesOf(const SolverResult& r) {
  bp::list out;
  for (const StageReport& s : r.stages) out.append(s);
  return out;
}
bp::list blocksOf(const SolverResult& r) {
  bp::list out;
  for (int i : r.implicated_blocks) out.append(i);
  return out;
}
std::string stageRepr(const StageReport& s) {
  return "StageReport(" + s.name + ": " + std::to_string(s.iterations) + " iterations, " +
         std::to_string(s.seconds * 1e3) + " ms, " + s.outcome + ")";
}
bp::list names() {
  bp::list out;
  for (const auto& n : solverNames()) out.append(n);
  return out;
}
double residualOf(const bp::object& problem, const bp::object& lam) {
  const ContactProblem& p = toObject<ContactProblem>(problem, "residual: problem", "stiction.ContactProblem");
  return residual(p, toVector(lam, "residual: lam", p.numRows()));
}

}  // namespace

void exposeSolver() {
  bp::enum_<WarmStart>("WarmStart")
      .value("none", WarmStart::kNone)
      .value("given", WarmStart::kGiven)
      .value("proxqp", WarmStart::kProxQP);
  bp::enum_<SolveStatus>("SolveStatus")
      .value("converged", SolveStatus::kConverged)
      .value("not_converged", SolveStatus::kNotConverged)
      .value("infeasible", SolveStatus::kInfeasible)
      .value("unresolvable", SolveStatus::kUnresolvable);

  bp::class_<SolverSettings> settings("SolverSettings", "Stopping rules, budgets and warm start of a solve.");
  checkedMember(settings, "tolerance", &SolverSettings::tolerance,
                "converged means relative_residual + residual_bound <= tolerance");
  checkedMember(settings, "max_iterations", &SolverSettings::max_iterations);
  checkedMember(settings, "warm_start", &SolverSettings::warm_start);
  checkedMember(settings, "proxqp_facets", &SolverSettings::proxqp_facets);
  checkedMember(settings, "proxqp_tolerance", &SolverSettings::proxqp_tolerance, "relative");
  checkedMember(settings, "proxqp_max_iterations", &SolverSettings::proxqp_max_iterations,
                "ProxQP inner iterations per ProxQP run");
  checkedMember(settings, "admm_rho", &SolverSettings::admm_rho, "0: chosen from the spectrum of A");
  checkedMember(settings, "time_limit", &SolverSettings::time_limit, "seconds, 0 = none; covers every stage");

  bp::class_<StageReport>("StageReport", "One stage of a solve: its name, iterations, seconds and outcome.",
                          bp::no_init)
      .def_readonly("name", &StageReport::name)
      .def_readonly("iterations", &StageReport::iterations)
      .def_readonly("seconds", &StageReport::seconds)
      .def_readonly("outcome", &StageReport::outcome)
      .def("__repr__", &stageRepr);

  bp::class_<SolverResult>("SolverResult", "Outcome of a solve; every solver reports the same residual.")
      .add_property("lam", &lamOf, "lambda (num_rows)")
      .add_property("u", &uOf, "A lambda - b (num_rows)")
      .add_property("states", &statesOf, "ContactState per block")
      .def_readonly("iterations", &SolverResult::iterations)
      .def_readonly("converged", &SolverResult::converged, "status == SolveStatus.converged")
      .def_readonly("status", &SolverResult::status,
                    "converged, not_converged (budget/stall), infeasible (no solution), "
                    "unresolvable (the tolerance cannot be verified in double precision)")
      .def_readonly("residual", &SolverResult::residual, "natural map / (1 + ||b||)")
      .def_readonly("relative_residual", &SolverResult::relative_residual,
                    "natural map / ||b|| (Siconos' measure)")
      .def_readonly("residual_bound", &SolverResult::residual_bound,
                    "rounding bound of relative_residual; converged means their sum <= tolerance")
      .def_readonly("precision_floor", &SolverResult::precision_floor,
                    "what rounding lambda to double alone can move relative_residual by; "
                    "unresolvable means this exceeds the tolerance")
      .def_readonly("lambda_norm", &SolverResult::lambda_norm)
      .def_readonly("min_solution_norm", &SolverResult::min_solution_norm,
                    "from an infeasibility certificate: every solution has ||lambda|| >= this (0: none)")
      .add_property("implicated_blocks", &blocksOf, "infeasible / unresolvable: the blocks responsible")
      .add_property("stages", &stagesOf, "StageReport of every stage run, in order")
      .def_readonly("seconds", &SolverResult::seconds)
      .def_readonly("warm_start_seconds", &SolverResult::warm_start_seconds, "ProxQP's time, wherever it ran")
      .def_readonly("warm_start_iterations", &SolverResult::warm_start_iterations)
      .def_readonly("solver", &SolverResult::solver)
      .def_readonly("message", &SolverResult::message);

  bp::class_<Solver, std::shared_ptr<Solver>, boost::noncopyable>(
      "Solver", "One algorithm with its reusable workspace: 'default', 'nsgs', 'admm' or 'newton'.", bp::no_init)
      .def("__init__", bp::make_constructor(&makeSolverObject, bp::default_call_policies(), (bp::arg("name"))))
      .add_property("name", &Solver::name)
      .def("solve", &Solver::solveWith,
           (bp::arg("problem"), bp::arg("settings"), bp::arg("guess") = bp::object()));

  bp::def("solver_names", &names);
  bp::def("residual", &residualOf, (bp::arg("problem"), bp::arg("lam")),
          "natural-map residual of the De Saxce problem / (1 + ||b||)");
}

}  // namespace python
}  // namespace stiction
