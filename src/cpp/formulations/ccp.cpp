// ccp: Anitescu-Tasora's cone complementarity problem (paper eq. 78-79).
//
//     C* ∋ A lambda - b ⟂ lambda ∈ C,  i.e.  lambda = proj_C^A(A^-1 b)
//
// The De Saxce term E s(u) of the exact law (eq. 73) is dropped, so the problem is the
// convex QP min 1/2 l'A l - b'l over C. Solved by the package's ADMM with the De Saxce
// refresh switched off (admm.hpp), stopping on the CCP's own natural map
// ||lambda - P_C(lambda - u)|| <= tolerance ||b||.
//
// The artefact (paper §4.5, [7, Fig. 1]): at a sliding contact the complementarity
// <lambda, u> = 0 with lambda on the cone's boundary forces u_n = mu ||u_t|| > 0: the body
// separates at mu times its sliding speed, where the exact law keeps u_n = 0.
//
// Box rows (joint friction, effort limits: an interval, no De Saxce term) are projected as the
// interval they are (projectOntoConstraints): on them the CCP is the exact law.
#include "stiction/admm.hpp"
#include "stiction/verdict.hpp"
#include "formulations.hpp"

namespace stiction {
namespace {

class CcpFormulation final : public Formulation {
 public:
  std::string name() const override { return "ccp"; }
  std::string equations() const override { return "78-79"; }

  void iterate(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result) override {
    admm_.setDesaxce(false);
    result.iterations = admm_.run(problem, result.lam, settings.max_iterations, settings.tolerance,
                                  settings.time_limit, settings.admm_rho, false, result.message);
    u_.resize(problem.numRows());
    problem.delassus().multiply(result.lam, u_);
    u_ -= problem.b();
    result.own_residual = coneNaturalMap(problem, result.lam, u_, work_) / stoppingScale(problem);
    result.own_converged = result.own_residual <= settings.tolerance;
    result.own_law = "cone complementarity (eq. 79): ||lambda - P_C(lambda - u)|| / ||b||";
  }

 private:
  AdmmSolver admm_;
  Eigen::VectorXd u_, work_;
};

}  // namespace

std::unique_ptr<Formulation> makeCcpFormulation() { return std::make_unique<CcpFormulation>(); }

}  // namespace stiction
