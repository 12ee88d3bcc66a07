// The exact-law measures (exact_law.hpp, docs/exact-law.md).
#include "stiction/exact_law.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "stiction/cone.hpp"
#include "stiction/solver.hpp"   // classifyStates
#include "stiction/verdict.hpp"  // naturalMapNorm, stoppingScale

namespace stiction {

namespace {

// Distance of (x_t, x_n), x_t given by its norm, to the friction cone ||x_t|| <= mu x_n (eq. 58),
// by the closed-form projection of cone.hpp (eq. 66).
double distanceToCone(double xt_norm, double xn, double mu) {
  double scale, n;
  projectOntoConeScalars(xt_norm, xn, mu, scale, n);
  return norm2((1.0 - scale) * xt_norm, xn - n);
}

// Distance of (w_t, w_n) to the dual cone C* = {mu ||w_t|| <= w_n}: by Moreau's decomposition
// w = P_C*(w) + P_(C*)°(w) and (C*)° = -C, so dist(w, C*) = ||P_-C(w)|| = ||P_C(-w)||.
double distanceToDualCone(double wt_norm, double wn, double mu) {
  double scale, n;
  projectOntoConeScalars(wt_norm, -wn, mu, scale, n);
  return norm2(scale * wt_norm, n);
}

}  // namespace

void measureExactLaw(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                     ExactLawMeasures& out, double relative_speed_floor, const Eigen::VectorXd* u) {
  const Eigen::Index m = problem.numRows();
  if (lam.size() != m)
    throw std::invalid_argument("exact_law_measures: lambda has " + std::to_string(lam.size()) +
                                " entries, the problem has " + std::to_string(m) + " rows");
  if (!(relative_speed_floor >= 0.0) || !std::isfinite(relative_speed_floor))
    throw std::invalid_argument("exact_law_measures: relative_speed_floor must be finite and >= 0, got " +
                                std::to_string(relative_speed_floor));
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  const std::size_t nb = cons.size();
  const Eigen::Index nbi = static_cast<Eigen::Index>(nb);

  // u = A lambda - b (eq. 27), then the natural map exactly as every SolverResult reports it.
  if (u != nullptr && u->size() == m) {
    out.u = *u;
  } else {
    out.u.resize(m);
    problem.delassus().multiply(lam, out.u);
    out.u -= problem.b();
  }
  out.b_norm = problem.bNorm();
  out.lambda_norm = lam.norm();
  out.natural_map = naturalMapNorm(problem, lam, out.u);
  out.residual = out.natural_map / (1.0 + out.b_norm);
  out.relative_residual = out.natural_map / stoppingScale(problem);
  // The speed floor of "sliding", scale-aware like classifyStates: relative to ||b||_inf.
  out.speed_floor = relative_speed_floor * problem.b().lpNorm<Eigen::Infinity>();
  classifyStates(problem, lam, out.u, out.states);

  // One pass over the blocks: every per-block entry written (0 where a measure does not apply),
  // the aggregates kept as it goes (a robot's step measures 4 blocks: separate zeroing, copies
  // and reductions cost more than the measures).
  for (Eigen::VectorXd* v : {&out.primal, &out.dual, &out.complementarity, &out.signorini, &out.dissipation,
                             &out.dissipation_angle, &out.liftoff})
    v->resize(nbi);
  out.sliding.assign(nb, false);
  out.w.resize(m);
  out.num_sliding = 0;
  out.liftoff_max = 0.0;
  // (NaN wins: a measure of a non-finite lambda says so)
  const auto raise = [](double& max, double x) {
    if (x > max || std::isnan(x)) max = std::isnan(max) ? max : x;
  };
  double primal_max = 0.0, primal_sq = 0.0, dual_max = 0.0, dual_sq = 0.0, comp_max = 0.0, comp_sum = 0.0;
  double signorini_max = 0.0, dissipation_max = 0.0, angle_max = 0.0;
  bool any_sliding = false;
  const double* lp = lam.data();
  const double* up = out.u.data();
  double* wp = out.w.data();

  for (std::size_t i = 0; i < nb; ++i) {
    const Eigen::Index o = off[i];
    const int k = cons[i].size;
    const double* l = lp + o;
    const double* u = up + o;
    double* w = wp + o;
    double primal = 0.0, dual = 0.0, comp = 0.0, signorini = 0.0, dissipation = 0.0, angle = 0.0, liftoff = 0.0;
    for (int r = 0; r < k; ++r) w[r] = u[r];
    if (cons[i].kind == ConstraintKind::kBilateral) {
      // C = R^k, C* = {0} (eq. 14-15): lambda is free, w = u must vanish.
      double uu = 0.0, lu = 0.0;
      for (int r = 0; r < k; ++r) {
        uu += u[r] * u[r];
        lu += l[r] * u[r];
      }
      dual = std::sqrt(uu);
      comp = std::abs(lu);
    } else if (cons[i].kind == ConstraintKind::kUnilateral) {
      // C = C* = R+ (eq. 43): lambda_n >= 0, u_n >= 0, lambda_n u_n = 0.
      primal = std::max(0.0, -l[0]);
      dual = std::max(0.0, -u[0]);
      comp = signorini = std::abs(l[0] * u[0]);
    } else if (cons[i].kind == ConstraintKind::kBox) {
      // C = [lo, hi] (lo <= 0 <= hi), w = u (no De Saxce term): box complementarity, u = 0 inside,
      // u <= 0 at hi, u >= 0 at lo. With u = u+ - u- it is lambda - lo ⟂ u+ and hi - lambda ⟂ u-:
      // complementarity (lambda - lo) u+ + (hi - lambda) u-, zero exactly when lambda in C obeys it.
      // No dual part: every u is admissible at some point of the interval.
      const double lo = cons[i].lower, hi = cons[i].upper;
      primal = std::max(0.0, std::max(lo - l[0], l[0] - hi));
      comp = std::abs((l[0] - lo) * std::max(0.0, u[0])) + std::abs((hi - l[0]) * std::max(0.0, -u[0]));
    } else {
      // Friction block (t, n) or (t1, t2, n).
      const int n = k - 1;  // normal row last
      const double mu = cons[i].mu;
      const double ut = k == 3 ? norm2(u[0], u[1]) : std::abs(u[0]);
      const double lt = k == 3 ? norm2(l[0], l[1]) : std::abs(l[0]);
      w[n] += mu * ut;  // De Saxce: w = u + E s(u), s = mu ||u_t|| (eq. 76-77)
      primal = distanceToCone(lt, l[n], mu);
      dual = distanceToDualCone(ut, w[n], mu);  // w_t = u_t
      double lw = 0.0;
      for (int r = 0; r < k; ++r) lw += l[r] * w[r];
      comp = std::abs(lw);  // eq. 75
      signorini = std::abs(l[n] * u[n]);
      if (ut > out.speed_floor && l[n] > 0.0) {
        // Sliding: maximum dissipation wants lambda_t = -mu lambda_n u_t / ||u_t|| (eq. 58, 66).
        out.sliding[i] = true;
        ++out.num_sliding;
        const double c = mu * l[n] / ut;
        double dot, cross;  // of lambda_t with -u_t
        if (k == 3) {
          dissipation = norm2(l[0] + c * u[0], l[1] + c * u[1]);
          dot = -(l[0] * u[0] + l[1] * u[1]);
          cross = std::abs(l[0] * u[1] - l[1] * u[0]);
        } else {
          dissipation = std::abs(l[0] + c * u[0]);
          dot = -l[0] * u[0];
          cross = 0.0;
        }
        angle = lt > 0.0 ? std::atan2(cross, dot) : 0.0;  // in [0, pi]
        liftoff = u[n];  // exact: 0 (<lambda, w> = lambda_n u_n); CCP: mu ||u_t||
        out.liftoff_max = any_sliding ? std::max(out.liftoff_max, u[n]) : u[n];
        any_sliding = true;
      }
    }
    out.primal[i] = primal;
    out.dual[i] = dual;
    out.complementarity[i] = comp;
    out.signorini[i] = signorini;
    out.dissipation[i] = dissipation;
    out.dissipation_angle[i] = angle;
    out.liftoff[i] = liftoff;
    raise(primal_max, primal);
    raise(dual_max, dual);
    raise(comp_max, comp);
    raise(signorini_max, signorini);
    raise(dissipation_max, dissipation);
    raise(angle_max, angle);
    primal_sq += primal * primal;
    dual_sq += dual * dual;
    comp_sum += comp;
  }
  out.primal_max = primal_max;
  out.primal_norm = std::sqrt(primal_sq);
  out.dual_max = dual_max;
  out.dual_norm = std::sqrt(dual_sq);
  out.complementarity_max = comp_max;
  out.complementarity_sum = comp_sum;
  out.signorini_max = signorini_max;
  out.dissipation_max = dissipation_max;
  out.dissipation_angle_max = angle_max;
}

ExactLawMeasures exactLawMeasures(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                                  double relative_speed_floor) {
  ExactLawMeasures out;
  measureExactLaw(problem, lam, out, relative_speed_floor);
  return out;
}

}  // namespace stiction
