// The convergence verdict: is lambda a solution of the De Saxce NCP (eq. 73-77)
// to the tolerance, can double precision tell, and if not, why not.
//
// The measure is the natural map
//     r(lambda) = lambda - P_C(lambda - w),   w = u + E s(u),   u = A lambda - b,
// evaluated block by block in a form that does not cancel. By Moreau's
// decomposition r = w - P_C*(w - lambda), so where lambda - w lies inside C
// (stick) r = w exactly, and where it lies in the polar cone (open) r = lambda;
// only blocks on the boundary (slip) need the subtraction lambda - P_C(.).
// Evaluated the usual way, a sticking block with lambda = 1e12 and w = 1e-4
// gives r = 0: w is below lambda's rounding step. A box row (C = [lower, upper], no De Saxce
// term: w = u) is r = u strictly inside, lambda - upper or lambda - lower beyond its bounds.
//
// The verdict evaluates it at the returned (double) lambda, in double first; when that
// is not decisive, in double again from a compensated u (compensated.hpp: off by
// eps |u| + gamma^2 (|A||lambda| + |b|)); then in extended precision (long double: a
// 64-bit mantissa on x86-64). Each stage bounds its rounding error: in the first,
// the product u = A lambda - b is off by at most
// gamma (|A||lambda| + |b|) per row (gamma = (k + 2) eps, the worst case of
// a dot product whose sum goes through k roundings, k =
// DelassusOperator::productRoundingTerms(): m dense, the fullest row sparse, a
// quarter of it where a vector kernel sums in four lanes), which carries over to w and r; a block whose
// lambda - w is within that error of a region boundary, or slips, adds
// eps (|lambda_i| + |lambda_i - w_i|) for the subtraction. Then
//
//     converged  <=>  ||r|| + bound <= tolerance * ||b||
//
// and the exact natural map at the returned lambda is certainly within the
// tolerance. (The double evaluation's worst-case bound is 2000x larger than the
// extended one's and already exceeds 1e-10 ||b|| on a 1e4:1 mass-ratio stack whose
// true residual is 1e-13: then the extended evaluation decides. Where long double is
// double, the bound says so and is that large.)
//
// Resolution. Rounding lambda itself to double moves u by up to eps |A||lambda|
// and r by up to eps (|lambda| + (1 + mu) |A||lambda|) per block: the "floor", a
// worst case (a 1e4:1 stack converges to 1e-13 with a floor of 3e-13). A result
// above the tolerance whose floor exceeds kFloorMargin * tolerance * ||b|| is
// "unresolvable": the tolerance is far below what double precision can show near
// this lambda (the 1e12 example: floor 7e-4 ||b|| against 1e-10).
//
// Infeasibility. Every solution has u_n >= 0 on normal rows and u = 0 on
// bilateral rows (w in C* <=> u_n >= 0 for a friction block). So for d >= 0 on
// normal rows (any sign on bilateral rows, 0 on tangential and box rows, whose u may
// take either sign at a solution),
// d'(A lambda - b) >= 0, hence ||A^T d|| ||lambda|| >= b'd: no solution has
// ||lambda|| < b'd / ||A^T d||. A normal row with A_nn = 0 (a contact on something
// that cannot move) and b_n > 0 gives d = e_n and no solution at all. The
// problem is declared infeasible when this bound exceeds what double
// precision can resolve even loosely at the problem's scale, ||lambda|| eps max diag A > 1e-6 ||b||.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "stiction/contact_problem.hpp"

namespace stiction {

enum class SolveStatus {
  kConverged = 0,     ///< natural map + its rounding bound <= tolerance * ||b||
  kNotConverged = 1,  ///< budget, time limit or stall: a sane iterate above the tolerance
  kInfeasible = 2,    ///< certificate: no solution of verifiable size (lambda would grow without bound)
  kUnresolvable = 3,  ///< the rounding bound alone exceeds the tolerance at this lambda
};

const char* toString(SolveStatus status);

/// Natural-map residual ||lambda - P_C(lambda - (u + E s(u)))|| with u = A lambda - b,
/// unnormalised, in the cancellation-free form above. Bilateral rows contribute u.
double naturalMapNorm(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                      const Eigen::Ref<const Eigen::VectorXd>& u);

/// ||b||, or 1 when b = 0: the scale of relative_residual (Siconos divides by ||q|| = ||b||).
/// Solvers stop on naturalMapNorm + bound <= tolerance * stoppingScale.
double stoppingScale(const ContactProblem& problem);

/// The verdict's measures at a lambda (see above); all unnormalised.
struct VerdictMeasures {
  double natural_map = 0.0;  ///< at the double lambda, by the stage that decided
  double bound = 0.0;        ///< bound on |natural_map - the exact natural map|
  double floor = 0.0;        ///< how far rounding lambda to double alone can move the natural map
  std::vector<double> block_floor;  ///< per block (names the culprits of an unresolvable result)
};

/// Evaluates them at lambda: first in double (u recomputed), whose worst-case bound is
/// decisive when it keeps natural_map on one side of `decisive` (the threshold the
/// caller tests: a well-scaled problem stops there), else from a compensated u, else in
/// extended precision. block_floor only with
/// per_block. No allocation once the (thread-local) workspace has the problem's size.
/// fresh_u: u = A lambda - b as DelassusOperator::multiply and a subtraction of b computed it (the
/// double stage then takes it rather than a product of its own; an iterate's incrementally updated u
/// is not that: its rounding is not what the bound covers). fresh_abs: |A| |lambda| from the same
/// pass (DelassusOperator::multiplyWithAbs), with fresh_u only.
void measureVerdict(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                    VerdictMeasures& out, double decisive, bool per_block = false,
                    const Eigen::VectorXd* fresh_u = nullptr, const Eigen::VectorXd* fresh_abs = nullptr);

/// u = A lambda - b for the lambda of the last verdict measured in this solve (the double
/// stage's product, or the compensated one when that stage ran): true and `u` written when lambda
/// is that one.
bool lastVerdictResidual(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                         Eigen::VectorXd& u);

/// measureVerdict remembers its last answer in a thread-local cache keyed on the problem's address
/// and lambda (the stopping test and the driver often judge the same lambda). It lives for one
/// solve: the driver forgets it at the start (A and b may have changed in place since, as the
/// simulator updates them per step) and at the end of every solve (the problems it keyed on may
/// be gone, and a new one at the same address must not meet its answers). A caller of
/// measureVerdict outside solve() calls this after changing A or b in place.
void forgetVerdicts();

/// Just the floor (one product with |A|), for algorithms deciding whether to go on.
double precisionFloor(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam);

/// A lower bound on the norm of every solution, from a direction d (see above).
struct InfeasibilityCertificate {
  double min_solution_norm = 0.0;  ///< b'd / ||A d|| (infinity when A d = 0); 0: no certificate
  std::vector<int> blocks;         ///< blocks carrying d
};

/// The strongest certificate among: every normal row with A_nn = 0 and b_n > 0, and
/// the given candidate directions (diverged iterates, ProxQP's dual-infeasibility ray),
/// each reduced to its normal (>= 0) and bilateral parts.
InfeasibilityCertificate findInfeasibility(const ContactProblem& problem,
                                           const std::vector<Eigen::VectorXd>& candidates);

/// A solution whose own rounding cannot be verified even to this relative tolerance is
/// no solution: the threshold of "infeasible" (independent of the tolerance asked for,
/// so that an unreachable 1e-300 does not make a problem infeasible).
constexpr double kLooseTolerance = 1e-6;

/// True when every solution would be too large to verify at the problem's own scale:
/// min_solution_norm * eps * max diag A > kLooseTolerance * stoppingScale (||lambda|| against
/// ||b|| / max diag A, lambda's natural size, so the test reads the same whatever A's magnitude).
bool beyondPrecision(const ContactProblem& problem, double min_solution_norm);

/// The stopping test every algorithm shares. The cheap double natural map first; the
/// verdict's measures (two more products) only once that passes. kUnresolvable: the
/// tolerance is not met and lambda's own rounding keeps it out of reach.
class StoppingTest {
 public:
  enum Outcome { kContinue, kConverged, kUnresolvable };

  StoppingTest(const ContactProblem& problem, double tolerance);
  /// u_is_fresh: u is A lambda - b just multiplied (measureVerdict's fresh_u), not an iterate's
  /// incrementally updated u.
  /// abs_product: |A| |lambda| computed with a fresh u (DelassusOperator::multiplyWithAbs), or null.
  Outcome check(const Eigen::Ref<const Eigen::VectorXd>& lam, const Eigen::VectorXd& u, double natural_map,
                bool u_is_fresh = false, const Eigen::VectorXd* abs_product = nullptr);
  double threshold() const { return threshold_; }

 private:
  const ContactProblem& problem_;
  double threshold_;  // tolerance * stoppingScale
  VerdictMeasures measures_;
};

/// Unresolvable: the floor exceeds the tolerance by this factor (the floor is a worst case).
constexpr double kFloorMargin = 100.0;

/// The message an algorithm stops with when StoppingTest says kUnresolvable.
constexpr const char* kUnresolvableMessage = "residual not resolvable in double precision";

/// The unit roundoff of double, eps = 2^-53.
constexpr double kUnitRoundoff = 1.1102230246251565e-16;

}  // namespace stiction
