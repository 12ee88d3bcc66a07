// The registry of formulations (formulation.hpp): one line per formulation.
#include "stiction/formulation.hpp"

#include <cmath>
#include <functional>
#include <stdexcept>

#include "formulations.hpp"

namespace stiction {
namespace {

struct Entry {
  FormulationInfo info;
  std::function<std::unique_ptr<Formulation>()> make;  // empty: the exact solvers
};

const std::vector<Entry>& registry() {
  static const std::vector<Entry> entries = {
      {{"exact", "65, 73-77",
        "the singular-metric inclusion = De Saxce's exact Coulomb NCP (the package's default)",
        {"solver = default: default | nsgs | admm | newton"}},
       {}},
      {{"ccp", "78-79", "Anitescu-Tasora cone complementarity: E s(u) dropped, a convex QP (ADMM)", {}},
       makeCcpFormulation},
      {{"nakaoka", "80-81",
        "A dropped from the metric: per-contact singular-metric projection, Gauss-Seidel (Nakaoka et al.)", {}},
       makeNakaokaFormulation},
      {{"pyramid", "§4.5 ([8, 50])",
        "N-facet pyramid cones: the Stewart-Trinkle / Anitescu-Potra LCP as ProxQP QPs with a fixed point on "
        "the pyramid's De Saxce term",
        {"pyramid_facets = 4: facets per cone (3 .. 1024)",
         "pyramid_inscribed = false: corners on the cone (true) or facets tangent to it (false)",
         "pyramid_max_fixed_point = 100: QP solves on the pyramid's De Saxce term at most (>= 1)"}},
       makePyramidFormulation},
      {{"penalty", "83-84",
        "spring-damper normal and friction, implicit Euler (Kikuuwe-Fujimoto); time stepping only",
        {"penalty_stiffness = 1e5: K [N/m] per contact", "penalty_damping = 1e-3: beta [s], damping K beta"}},
       makePenaltyFormulation},
      {{"pinocchio-admm", "73-77", "Pinocchio 4.1's ADMMConstraintSolver, NCP setting (solve_ncp)", {}},
       [] { return makePinocchioFormulation("admm", true); }},
      {{"pinocchio-pgs", "73-77", "Pinocchio 4.1's PGSConstraintSolver, NCP setting (solve_ncp)", {}},
       [] { return makePinocchioFormulation("pgs", true); }},
      // (Pinocchio 4.1's PGS has no CCP setting: its iteration is the NCP whatever solve_ncp says)
      {{"pinocchio-admm-ccp", "78-79", "Pinocchio 4.1's ADMMConstraintSolver, CCP setting", {}},
       [] { return makePinocchioFormulation("admm", false); }},
  };
  return entries;
}

}  // namespace

void checkFormulationSettings(const FormulationSettings& s) {
  // (The sizes that allocate: facets, bounded; pyramid_max_fixed_point counts QP solves and sizes
  // nothing, so it has no upper bound: time_limit bounds its cost.)
  if (s.pyramid_facets < 3 || s.pyramid_facets > kMaxFacets)
    throw std::invalid_argument("pyramid_facets must be between 3 and " + std::to_string(kMaxFacets) + ", got " +
                                std::to_string(s.pyramid_facets) + kMaxFacetsReason);
  if (s.pyramid_max_fixed_point < 1)
    throw std::invalid_argument("pyramid_max_fixed_point must be >= 1, got " +
                                std::to_string(s.pyramid_max_fixed_point));
  {
    bool known = false;
    for (const auto& n : solverNames()) known = known || n == s.exact_solver;
    if (!known) makeSolver(s.exact_solver);  // throws, naming the known ones
  }
  if (!(s.penalty_stiffness > 0.0) || !std::isfinite(s.penalty_stiffness))
    throw std::invalid_argument("penalty_stiffness (K) must be a positive finite number of N/m");
  if (!(s.penalty_damping >= 0.0) || !std::isfinite(s.penalty_damping))
    throw std::invalid_argument("penalty_damping (beta) must be a finite number of seconds >= 0");
}

std::unique_ptr<ContactSolver> makeFormulation(const std::string& name, const FormulationSettings& settings) {
  checkFormulationSettings(settings);
  for (const Entry& e : registry()) {
    if (e.info.name != name) continue;
    if (!e.make) return makeSolver(settings.exact_solver);
    std::unique_ptr<Formulation> f = e.make();
    f->setSettings(settings);
    return f;
  }
  std::string known;
  for (const Entry& e : registry()) known += (known.empty() ? "" : ", ") + e.info.name;
  throw std::invalid_argument("unknown formulation '" + name + "' (known: " + known + ")");
}

std::vector<FormulationInfo> formulationInfos() {
  std::vector<FormulationInfo> out;
  for (const Entry& e : registry()) out.push_back(e.info);
  return out;
}

std::vector<std::string> formulationNames() {
  std::vector<std::string> out;
  for (const Entry& e : registry()) out.push_back(e.info.name);
  return out;
}

void setFormulationContext(ContactSolver& solver, const StepContext& context) {
  if (auto* f = dynamic_cast<Formulation*>(&solver)) f->setContext(context);
}

}  // namespace stiction
