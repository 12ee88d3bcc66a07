#include <cstdio>

#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include "convert.hpp"
#include "expose.hpp"
#include "stiction/exact_law.hpp"
#include "stiction/formulation.hpp"
#include "stiction/default_solver.hpp"
#include "stiction/dense_lu.hpp"
#include "stiction/solver.hpp"

namespace bp = boost::python;

namespace stiction {
namespace python {

template <>
WarmStart fromPython<WarmStart>(const bp::object& x, const std::string& name) {
  return toEnum<WarmStart>(x, name, "stiction.WarmStart");
}

template <>
FormulationSettings fromPython<FormulationSettings>(const bp::object& x, const std::string& name) {
  return toObject<FormulationSettings>(x, name, "stiction.FormulationSettings");
}

namespace {

/// Python handle on one formulation (formulation.hpp) and its reusable workspace.
struct FormulationSolver {
  FormulationSolver(const std::string& name, const FormulationSettings& settings)
      : impl(makeFormulation(name, settings)), formulation(name), settings(settings) {}
  std::unique_ptr<ContactSolver> impl;
  std::string formulation;
  FormulationSettings settings;
  Eigen::VectorXd position_error, state;

  /// A fresh formulation in place of this one: what it kept between solves (workspaces; the exact
  /// formulation's default solver: its held sticking factor) is gone, as in a new process.
  void reset() {
    InUse busy(impl.get(), "this Formulation object");
    impl = makeFormulation(formulation, settings);
    position_error.resize(0);
    state.resize(0);
  }

  SolverResult solveWith(const bp::object& problem, const bp::object& settings, const bp::object& guess,
                         const bp::object& h, const bp::object& psi) {
    const ContactProblem& p =
        toObject<ContactProblem>(problem, "Formulation.solve: problem", "stiction.ContactProblem");
    const SolverSettings& s =
        toObject<SolverSettings>(settings, "Formulation.solve: settings", "stiction.SolverSettings");
    StepContext context;
    context.h = toDouble(h, "Formulation.solve: h");
    if (!(context.h > 0.0) || !std::isfinite(context.h))
      throw std::invalid_argument("Formulation.solve: h (the step) must be a positive finite number");
    if (!psi.is_none()) {
      position_error = toVector(psi, "Formulation.solve: position_error", p.numRows());
      if (!position_error.allFinite())  // (a NaN gap would pass through the penalty springs unnoticed)
        throw std::invalid_argument("Formulation.solve: position_error has NaN or infinite entries");
      context.position_error = &position_error;
    }
    setFormulationContext(*impl, context);
    SolverResult result;
    Eigen::VectorXd v;
    if (!guess.is_none()) v = toVector(guess, "Formulation.solve: guess (initial lambda)");
    InUse busy(impl.get(), "this Formulation object");
    ReleaseGil nogil;
    stiction::solve(p, *impl, s, result, guess.is_none() ? nullptr : &v);
    return result;
  }
  std::string name() const { return formulation; }
};

std::shared_ptr<FormulationSolver> makeFormulationObject(const bp::object& name, const bp::object& settings) {
  const FormulationSettings fs = settings.is_none() ? FormulationSettings()
                                                    : fromPython<FormulationSettings>(settings, "Formulation: settings");
  return std::make_shared<FormulationSolver>(toStringArg(name, "Formulation: name"), fs);
}

bp::list formulationList() {
  bp::list out;
  for (const FormulationInfo& info : formulationInfos()) {
    bp::dict d;
    d["name"] = info.name;
    d["equations"] = info.equations;
    d["summary"] = info.summary;
    bp::list params;
    for (const auto& prm : info.parameters) params.append(prm);
    d["parameters"] = params;
    out.append(d);
  }
  return out;
}

/// Python handle on one algorithm and its reusable workspace.
struct Solver {
  explicit Solver(const std::string& name) : impl(makeSolver(name)) {}
  std::unique_ptr<ContactSolver> impl;

  /// A fresh algorithm in place of this one (see FormulationSolver::reset).
  void reset() {
    InUse busy(impl.get(), "this Solver object");
    impl = makeSolver(impl->name());
  }

  SolverResult solveWith(const bp::object& problem, const bp::object& settings, const bp::object& guess) {
    const ContactProblem& p = toObject<ContactProblem>(problem, "Solver.solve: problem", "stiction.ContactProblem");
    const SolverSettings& s = toObject<SolverSettings>(settings, "Solver.solve: settings", "stiction.SolverSettings");
    SolverResult result;
    Eigen::VectorXd v;
    if (!guess.is_none()) v = toVector(guess, "Solver.solve: guess (initial lambda)");
    InUse busy(impl.get(), "this Solver object");
    ReleaseGil nogil;
    stiction::solve(p, *impl, s, result, guess.is_none() ? nullptr : &v);
    return result;
  }
  std::string name() const { return impl->name(); }
};

std::shared_ptr<Solver> makeSolverObject(const bp::object& name) {
  return std::make_shared<Solver>(toStringArg(name, "Solver: name"));
}

// Read-only: each read is a fresh copy, so a write into it would be silently lost.
NdArray lamOf(const SolverResult& r) { return readOnlyCopy(r.lam); }
NdArray uOf(const SolverResult& r) { return readOnlyCopy(r.u); }
bp::list statesOf(const SolverResult& r) {
  return pyList(r.states);
}
bp::list stagesOf(const SolverResult& r) {
  return pyList(r.stages);
}
bp::list blocksOf(const SolverResult& r) {
  return pyList(r.implicated_blocks);
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

// For the tests: Newton's small dense LU (dense_lu.hpp) on any square matrix.
Eigen::VectorXd smallDenseLuSolve(const bp::object& matrix, const bp::object& rhs) {
  Eigen::MatrixXd a = toMatrix(matrix, "_small_dense_lu_solve: matrix");
  if (a.rows() != a.cols() || a.rows() > SmallDenseLU::kMaxRows)
    throw std::invalid_argument("_small_dense_lu_solve: matrix must be square with at most " +
                                std::to_string(SmallDenseLU::kMaxRows) + " rows");
  Eigen::VectorXd x = toVector(rhs, "_small_dense_lu_solve: rhs", a.rows());
  SmallDenseLU lu;
  lu.compute(a);
  lu.solve(x);
  return x;
}

// For the tests: the default's rule (default_solver.hpp) on a stated size and structure.
bp::list defaultPlanOf(const bp::object& rows, const bp::object& sparse, const bp::object& stored_entries,
                       const bp::object& warm_started, const bp::object& sticking_guess, const bp::object& has_budget) {
  DefaultRuleInput in;
  const long r = toInteger(rows, "_default_plan: rows");
  const long e = toInteger(stored_entries, "_default_plan: stored_entries");
  if (r < 0) throw std::invalid_argument("_default_plan: rows must be >= 0, got " + std::to_string(r));
  if (e < 0) throw std::invalid_argument("_default_plan: stored_entries must be >= 0, got " + std::to_string(e));
  in.rows = r;
  in.stored_entries = e;
  in.sparse = toBool(sparse, "_default_plan: sparse");
  in.warm_started = toBool(warm_started, "_default_plan: warm_started");
  in.sticking_guess = toBool(sticking_guess, "_default_plan: sticking_guess");
  in.has_budget = toBool(has_budget, "_default_plan: has_budget");
  bp::list out;
  for (DefaultStage stage : defaultPlan(in)) out.append(std::string(toString(stage)));
  return out;
}

// For the tests: what the rule reads of a problem, its guess and a warm start (or not).
bp::dict defaultRuleInputOf(const bp::object& problem, const bp::object& guess, const bp::object& warm_started) {
  const ContactProblem& p =
      toObject<ContactProblem>(problem, "_default_rule_input: problem", "stiction.ContactProblem");
  const Eigen::VectorXd g = toVector(guess, "_default_rule_input: guess", p.numRows());
  SolverSettings settings;
  settings.warm_start = toBool(warm_started, "_default_rule_input: warm_started") ? WarmStart::kGiven : WarmStart::kNone;
  const DefaultRuleInput in = defaultRuleInput(p, g, settings);
  bp::dict d;
  d["rows"] = static_cast<long>(in.rows);
  d["sparse"] = in.sparse;
  d["stored_entries"] = static_cast<long>(in.stored_entries);
  d["warm_started"] = in.warm_started;
  d["sticking_guess"] = in.sticking_guess;
  d["has_budget"] = in.has_budget;
  return d;
}

ExactLawMeasures exactLawOf(const bp::object& problem, const bp::object& lam, const bp::object& floor) {
  const ContactProblem& p =
      toObject<ContactProblem>(problem, "exact_law_measures: problem", "stiction.ContactProblem");
  const Eigen::VectorXd l = toVector(lam, "exact_law_measures: lam", p.numRows());
  const double f = toDouble(floor, "exact_law_measures: relative_speed_floor");
  return exactLawMeasures(p, l, f);
}
template <Eigen::VectorXd ExactLawMeasures::*member>
Eigen::VectorXd vectorOf(const ExactLawMeasures& e) {
  return e.*member;
}
bp::list lawStatesOf(const ExactLawMeasures& e) {
  return pyList(e.states);
}
bp::object slidingOf(const ExactLawMeasures& e) {
  bp::list out;
  for (bool s : e.sliding) out.append(s);
  return bp::import("numpy").attr("array")(out, "bool");
}
std::string lawRepr(const ExactLawMeasures& e) {
  char buf[400];
  std::snprintf(buf, sizeof buf,
                "ExactLawMeasures(relative_residual=%.3g, primal_max=%.3g, dual_max=%.3g, "
                "complementarity_max=%.3g, dissipation_max=%.3g, dissipation_angle_max=%.3g, "
                "liftoff_max=%.3g, %d sliding of %zu blocks)",
                e.relative_residual, e.primal_max, e.dual_max, e.complementarity_max, e.dissipation_max,
                e.dissipation_angle_max, e.liftoff_max, e.num_sliding, e.sliding.size());
  return buf;
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
  checkedMember(settings, "measure_exact_law", &SolverSettings::measure_exact_law,
                "False: result.exact_law is not measured (its access raises); states are still classified");

  bp::class_<StageReport>("StageReport", "One stage of a solve: its name, iterations, seconds and outcome.",
                          bp::no_init)
      .def_readonly("name", &StageReport::name)
      .def_readonly("iterations", &StageReport::iterations)
      .def_readonly("seconds", &StageReport::seconds)
      .def_readonly("outcome", &StageReport::outcome)
      .def("__repr__", &stageRepr);

  bp::class_<SolverResult>("SolverResult", "Outcome of a solve; every solver reports the same residual.")
      .add_property("lam", &lamOf, "lambda (num_rows; a read-only copy)")
      .add_property("u", &uOf, "A lambda - b (num_rows; a read-only copy)")
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
      .def_readonly("message", &SolverResult::message)
      .def_readonly("own_converged", &SolverResult::own_converged,
                    "the formulation met its own stopping test (exact solvers: = converged)")
      .def_readonly("own_residual", &SolverResult::own_residual, "the formulation's own measure (own_law)")
      .def_readonly("own_law", &SolverResult::own_law, "what own_residual measures")
      .add_property("exact_law", +[](const SolverResult& r) {
                      if (!r.exact_law_measured)  // (SolverSettings::measure_exact_law off: never stale numbers)
                        throw std::runtime_error("exact_law: this result's measures were not taken; "
                                                 "stiction.exact_law_measures(problem, result.lam) measures them");
                      return r.exact_law;
                    },
                    "ExactLawMeasures at lam (the same yardstick for every formulation)");
  {
    bp::class_<FormulationSettings> fs("FormulationSettings",
                                       "Parameters of the formulations (stiction formulations lists them).");
    checkedMember(fs, "exact_solver", &FormulationSettings::exact_solver, "exact: default | nsgs | admm | newton");
    checkedMember(fs, "pyramid_facets", &FormulationSettings::pyramid_facets, "pyramid: facets per cone (3 .. MAX_FACETS = 1024)");
    checkedMember(fs, "pyramid_inscribed", &FormulationSettings::pyramid_inscribed,
                  "pyramid: corners on the cone (True) or facets tangent to it (False)");
    checkedMember(fs, "pyramid_max_fixed_point", &FormulationSettings::pyramid_max_fixed_point,
                  "pyramid: QP solves on the De Saxce term at most");
    checkedMember(fs, "penalty_stiffness", &FormulationSettings::penalty_stiffness, "penalty: K [N/m]");
    checkedMember(fs, "penalty_damping", &FormulationSettings::penalty_damping, "penalty: beta [s]");
  }
  bp::class_<FormulationSolver, std::shared_ptr<FormulationSolver>, boost::noncopyable>(
      "Formulation",
      "One formulation (exact, ccp, nakaoka, pyramid, penalty, pinocchio-admm, ...) with its workspace; "
      "solve() judges every result by the exact law.",
      bp::no_init)
      .def("__init__", bp::make_constructor(&makeFormulationObject, bp::default_call_policies(),
                                            (bp::arg("name"), bp::arg("settings") = bp::object())))
      .add_property("name", &FormulationSolver::name)
      .def("reset", &FormulationSolver::reset,
           "Forget what this object kept between solves (workspaces; the exact formulation's default "
           "solver: its held sticking factor): the next solve gives what a new object, or a new process, "
           "gives.")
      .def("solve", &FormulationSolver::solveWith,
           (bp::arg("problem"), bp::arg("settings"), bp::arg("guess") = bp::object(), bp::arg("h") = 1.0,
            bp::arg("position_error") = bp::object()));
  bp::def("formulation_infos", &formulationList,
          "One dict per formulation: name, equations (the paper's), summary, parameters.");

  bp::class_<Solver, std::shared_ptr<Solver>, boost::noncopyable>(
      "Solver", "One algorithm with its reusable workspace: 'default', 'nsgs', 'admm' or 'newton'.", bp::no_init)
      .def("__init__", bp::make_constructor(&makeSolverObject, bp::default_call_policies(), (bp::arg("name"))))
      .add_property("name", &Solver::name)
      .def("reset", &Solver::reset,
           "Forget what this object kept between solves (workspaces; 'default': the sticking step's held "
           "factor, tried first on the next problem whose A's diagonal is close): the next solve gives what a "
           "new Solver, or a new process, gives.")
      .def("solve", &Solver::solveWith,
           (bp::arg("problem"), bp::arg("settings"), bp::arg("guess") = bp::object()));

  bp::class_<ExactLawMeasures>(
      "ExactLawMeasures",
      "How far a lambda is from the exact Coulomb law (eq. 65, 73-77), part by part; "
      "see exact_law_measures and docs/exact-law.md. Per-block arrays have one entry per block "
      "(0 where a measure does not apply).",
      bp::no_init)
      .def_readonly("b_norm", &ExactLawMeasures::b_norm, "norm(b)")
      .def_readonly("lambda_norm", &ExactLawMeasures::lambda_norm, "norm(lambda)")
      .def_readonly("speed_floor", &ExactLawMeasures::speed_floor,
                    "relative_speed_floor * max(abs(b)): a block slides when norm(u_t) exceeds it (and lambda_n > 0)")
      .def_readonly("natural_map", &ExactLawMeasures::natural_map,
                    "norm(lambda - P_C(lambda - (u + E s(u)))), absolute")
      .def_readonly("residual", &ExactLawMeasures::residual, "natural map / (1 + norm(b))")
      .def_readonly("relative_residual", &ExactLawMeasures::relative_residual, "natural map / norm(b) (/ 1 if b = 0)")
      .def_readonly("primal_max", &ExactLawMeasures::primal_max, "max over blocks of dist(lambda_i, C_i)")
      .def_readonly("primal_norm", &ExactLawMeasures::primal_norm, "2-norm over blocks of dist(lambda_i, C_i)")
      .def_readonly("dual_max", &ExactLawMeasures::dual_max, "max over blocks of dist(w_i, C_i*), w = u + E s(u)")
      .def_readonly("dual_norm", &ExactLawMeasures::dual_norm, "2-norm over blocks of dist(w_i, C_i*)")
      .def_readonly("complementarity_max", &ExactLawMeasures::complementarity_max,
                    "max over blocks of abs(<lambda_i, w_i>)")
      .def_readonly("complementarity_sum", &ExactLawMeasures::complementarity_sum,
                    "sum over blocks of abs(<lambda_i, w_i>)")
      .def_readonly("signorini_max", &ExactLawMeasures::signorini_max, "max of abs(lambda_n u_n)")
      .def_readonly("dissipation_max", &ExactLawMeasures::dissipation_max,
                    "sliding blocks: max of norm(lambda_t + mu lambda_n u_t / norm(u_t))")
      .def_readonly("dissipation_angle_max", &ExactLawMeasures::dissipation_angle_max,
                    "sliding blocks: max angle between lambda_t and -u_t, radians")
      .def_readonly("liftoff_max", &ExactLawMeasures::liftoff_max,
                    "sliding blocks: max u_n, signed (exact law: 0; CCP: mu norm(u_t)); 0 when none slides")
      .def_readonly("num_sliding", &ExactLawMeasures::num_sliding)
      .add_property("primal", &vectorOf<&ExactLawMeasures::primal>, "per block: dist(lambda_i, C_i)")
      .add_property("dual", &vectorOf<&ExactLawMeasures::dual>,
                    "per block: dist(w_i, C_i*) (bilateral: norm(u_i))")
      .add_property("complementarity", &vectorOf<&ExactLawMeasures::complementarity>,
                    "per block: abs(<lambda_i, w_i>)")
      .add_property("signorini", &vectorOf<&ExactLawMeasures::signorini>, "per block: abs(lambda_n u_n)")
      .add_property("dissipation", &vectorOf<&ExactLawMeasures::dissipation>,
                    "per sliding block: norm(lambda_t + mu lambda_n u_t / norm(u_t))")
      .add_property("dissipation_angle", &vectorOf<&ExactLawMeasures::dissipation_angle>,
                    "per sliding block: angle(lambda_t, -u_t), radians")
      .add_property("liftoff", &vectorOf<&ExactLawMeasures::liftoff>, "per sliding block: u_n")
      .add_property("sliding", &slidingOf, "per block (bool array): norm(u_t) > speed_floor and lambda_n > 0")
      .add_property("states", &lawStatesOf, "ContactState per block (as SolverResult.states)")
      .add_property("u", &vectorOf<&ExactLawMeasures::u>, "A lambda - b (num_rows)")
      .add_property("w", &vectorOf<&ExactLawMeasures::w>, "u + E s(u) (num_rows)")
      .def("__repr__", &lawRepr);

  bp::def("exact_law_measures", &exactLawOf,
          (bp::arg("problem"), bp::arg("lam"), bp::arg("relative_speed_floor") = kRelativeSpeedFloor),
          "How far lam is from the exact Coulomb law, part by part (ExactLawMeasures): natural map, "
          "primal and dual feasibility, complementarity, Signorini, maximum dissipation and lift-off "
          "of sliding blocks.");

  // The most facets of a facetized cone (proxqp_facets, pyramid_facets; solver.hpp says why).
  bp::scope().attr("MAX_FACETS") = kMaxFacets;
  // The default's size bound for trying sparse Newton first (tests/test_default_rule.py).
  bp::scope().attr("DEFAULT_SPARSE_NEWTON_ENTRIES") = static_cast<long>(kSparseNewtonEntries);
  bp::def("_default_plan", &defaultPlanOf,
          (bp::arg("rows"), bp::arg("sparse"), bp::arg("stored_entries"), bp::arg("warm_started"),
           bp::arg("sticking_guess"), bp::arg("has_budget") = true),
          "(for tests) the default solver's stages, in order, for a problem of this size and structure");
  bp::def("_default_rule_input", &defaultRuleInputOf, (bp::arg("problem"), bp::arg("guess"), bp::arg("warm_started")),
          "(for tests) what the default's rule reads of a problem and its guess (a dict)");
  bp::def("_small_dense_lu_solve", &smallDenseLuSolve, (bp::arg("matrix"), bp::arg("rhs")),
          "(for tests) x = matrix^-1 rhs by the Newton solver's small dense LU");
  bp::def("solver_names", &names);
  bp::def("residual", &residualOf, (bp::arg("problem"), bp::arg("lam")),
          "natural-map residual of the De Saxce problem / (1 + ||b||)");
}

}  // namespace python
}  // namespace stiction
