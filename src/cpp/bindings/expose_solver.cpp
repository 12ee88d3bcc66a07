#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include "expose.hpp"
#include "stiction/solver.hpp"

namespace bp = boost::python;

namespace stiction {
namespace python {

namespace {

/// Python handle on one algorithm and its reusable workspace.
struct Solver {
  explicit Solver(const std::string& name) : impl(makeSolver(name)) {}
  std::unique_ptr<ContactSolver> impl;

  SolverResult solveWith(const ContactProblem& problem, const SolverSettings& settings,
                         const bp::object& guess) {
    SolverResult result;
    if (guess.is_none()) {
      stiction::solve(problem, *impl, settings, result, nullptr);
    } else {
      bp::extract<Eigen::VectorXd> g(guess);
      if (!g.check()) throw std::invalid_argument("initial lambda must be a 1-D float array");
      const Eigen::VectorXd v = g();
      stiction::solve(problem, *impl, settings, result, &v);
    }
    return result;
  }
  std::string name() const { return impl->name(); }
};

Eigen::VectorXd lamOf(const SolverResult& r) { return r.lam; }
Eigen::VectorXd uOf(const SolverResult& r) { return r.u; }
bp::list statesOf(const SolverResult& r) {
  bp::list out;
  for (ContactState s : r.states) out.append(s);
  return out;
}
bp::list names() {
  bp::list out;
  for (const auto& n : solverNames()) out.append(n);
  return out;
}
double residualOf(const ContactProblem& p, const Eigen::VectorXd& lam) { return residual(p, lam); }

}  // namespace

void exposeSolver() {
  bp::enum_<WarmStart>("WarmStart")
      .value("none", WarmStart::kNone)
      .value("given", WarmStart::kGiven)
      .value("proxqp", WarmStart::kProxQP);

  bp::class_<SolverSettings>("SolverSettings", "Stopping rules and warm start of a solve.")
      .def_readwrite("tolerance", &SolverSettings::tolerance,
                     "on relative_residual (natural map / ||b||), hence also on residual")
      .def_readwrite("max_iterations", &SolverSettings::max_iterations)
      .def_readwrite("warm_start", &SolverSettings::warm_start)
      .def_readwrite("proxqp_facets", &SolverSettings::proxqp_facets)
      .def_readwrite("proxqp_tolerance", &SolverSettings::proxqp_tolerance)
      .def_readwrite("admm_rho", &SolverSettings::admm_rho, "0: chosen from the spectrum of A")
      .def_readwrite("time_limit", &SolverSettings::time_limit, "seconds, 0 = none");

  bp::class_<SolverResult>("SolverResult", "Outcome of a solve; every solver reports the same residual.")
      .add_property("lam", &lamOf, "lambda (num_rows)")
      .add_property("u", &uOf, "A lambda - b (num_rows)")
      .add_property("states", &statesOf, "ContactState per block")
      .def_readonly("iterations", &SolverResult::iterations)
      .def_readonly("converged", &SolverResult::converged)
      .def_readonly("residual", &SolverResult::residual, "natural map / (1 + ||b||)")
      .def_readonly("relative_residual", &SolverResult::relative_residual,
                    "natural map / ||b|| (Siconos' measure); converged means this <= tolerance")
      .def_readonly("seconds", &SolverResult::seconds)
      .def_readonly("warm_start_seconds", &SolverResult::warm_start_seconds)
      .def_readonly("warm_start_iterations", &SolverResult::warm_start_iterations)
      .def_readonly("solver", &SolverResult::solver)
      .def_readonly("message", &SolverResult::message);

  bp::class_<Solver, boost::noncopyable>("Solver",
                                         "One algorithm with its reusable workspace: "
                                         "'default', 'nsgs', 'admm' or 'newton'.",
                                         bp::init<std::string>(bp::arg("name")))
      .add_property("name", &Solver::name)
      .def("solve", &Solver::solveWith,
           (bp::arg("problem"), bp::arg("settings"), bp::arg("guess") = bp::object()));

  bp::def("solver_names", &names);
  bp::def("residual", &residualOf, (bp::arg("problem"), bp::arg("lam")),
          "natural-map residual of the De Saxce problem / (1 + ||b||)");
}

}  // namespace python
}  // namespace stiction
