#include "stiction/verdict.hpp"

#include <type_traits>

#include <cmath>
#include <cstring>
#include <limits>

#include "stiction/compensated.hpp"
#include "stiction/cone.hpp"

namespace stiction {

namespace {

constexpr double kEps = kUnitRoundoff;
constexpr double kInf = std::numeric_limits<double>::infinity();

// Extended precision for the verdict: long double (64-bit mantissa on x86-64; where
// it is plain double, its epsilon below makes the bound say so).
using Extended = long double;
template <typename T>
constexpr T unitRoundoff() {
  return std::numeric_limits<T>::epsilon() / 2;
}

// One friction block (K = 2 or 3 rows, normal last) in scalar type T: adds its
// squared natural map to `sq` and returns its rounding bound (0 when du is null).
// du: the bound on the error of each row of u (gamma (|A||lambda| + |b|)).
template <int K, typename T>
T frictionBlock(const T* lam, const T* u, const double* du, T mu, T& sq) {
  using V = Eigen::Matrix<T, K, 1>;
  using std::abs;
  using std::sqrt;
  const Eigen::Map<const V> l(lam), uu(u);
  const T ut = uu.template head<K - 1>().norm();
  V w = uu;
  w[K - 1] += mu * ut;  // De Saxce: u + E s(u), eq. 76-77
  const V z = l - w;
  const T zt = z.template head<K - 1>().norm(), zn = z[K - 1];
  const bool inside = zn >= 0 && zt <= mu * zn;  // stick: r = w (Moreau), no cancellation
  const bool polar = !inside && mu * zt <= -zn;  // open: P_C = 0, r = lambda
  if (inside) {
    sq += w.squaredNorm();
  } else if (polar) {
    sq += l.squaredNorm();
  } else {  // onto the boundary ray (cone.hpp)
    const T a = (zn + mu * zt) / (1 + mu * mu);
    V p = z;
    p.template head<K - 1>() *= zt > 0 ? mu * a / zt : T(0);
    p[K - 1] = a;
    sq += (l - p).squaredNorm();
  }
  if (du == nullptr) return T(0);
  const Eigen::Map<const Eigen::Matrix<double, K, 1>> eu(du);
  V ew = eu.template cast<T>();  // |w - w_exact| per row
  const T eps = unitRoundoff<T>();
  ew[K - 1] += mu * ew.template head<K - 1>().norm() + 3 * eps * (abs(uu[K - 1]) + mu * ut);
  const T delta_w = ew.norm();
  const T delta_z = (ew + eps * z.cwiseAbs()).norm();  // + the subtraction lambda - w
  const T root = sqrt(1 + mu * mu);
  // Well inside a region the exact point is in the same region: its closed form holds.
  if (inside && (mu * zn - zt) / root > delta_z) return delta_w;
  if (polar && (-zn - mu * zt) / root > delta_z) return T(0);
  return delta_z + 4 * eps * (l.norm() + z.norm());
}

// A unilateral row: C = R+, r = u (z > 0), lambda (z < 0), else lambda - max(0, z).
template <typename T>
T unilateralRow(T lam, T u, const double* du, T& sq) {
  using std::abs;
  const T z = lam - u;
  const T r = z > 0 ? u : (z < 0 ? lam : lam - std::max(T(0), z));
  sq += r * r;
  if (du == nullptr) return T(0);
  const T eps = unitRoundoff<T>();
  const T delta_z = T(*du) + eps * abs(z);
  if (z > delta_z) return T(*du);
  if (-z > delta_z) return T(0);
  return delta_z + 2 * eps * (abs(lam) + abs(z));
}

// A box row (C = [lo, hi], lo <= 0 <= hi): z = lambda - u; r = u strictly inside (no cancellation),
// lambda - hi above, lambda - lo below (the clamp), each evaluated as written. The bound as for a
// unilateral row, whose two regions became three: well inside a region (by delta_z) the exact z
// is in the same one and its closed form holds; near a bound the clamp is 1-Lipschitz, so r moves
// by at most delta_z, plus the subtractions' own rounding.
template <typename T>
T boxRow(T lam, T u, const double* du, T lo, T hi, T& sq) {
  using std::abs;
  const T z = lam - u;
  const T r = z >= hi ? lam - hi : (z <= lo ? lam - lo : u);
  sq += r * r;
  if (du == nullptr) return T(0);
  const T eps = unitRoundoff<T>();
  const T delta_z = T(*du) + eps * abs(z);
  if (z - lo > delta_z && hi - z > delta_z) return T(*du);
  if (z - hi > delta_z) return eps * abs(lam - hi);
  if (lo - z > delta_z) return eps * abs(lam - lo);
  return delta_z + T(*du) + 2 * eps * (abs(lam) + abs(z) + std::max(abs(lo), abs(hi)));
}

// The natural map in scalar type T; with du, also the rounding bound of each block
// into block_bound (T = double).
template <typename T>
T evaluate(const ContactProblem& problem, const T* lam, const T* u, const double* du,
           std::vector<double>* block_bound) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  T sq = 0;
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    const double* dui = du == nullptr ? nullptr : du + o;
    const T mu = static_cast<T>(cons[i].mu);
    T err = 0;
    switch (cons[i].kind) {
      case ConstraintKind::kBilateral: {  // P_C = identity on R^k: r = u
        for (int k = 0; k < cons[i].size; ++k) sq += u[o + k] * u[o + k];
        if (dui != nullptr) err = static_cast<T>(Eigen::Map<const Eigen::VectorXd>(dui, cons[i].size).norm());
        break;
      }
      case ConstraintKind::kUnilateral: err = unilateralRow<T>(lam[o], u[o], dui, sq); break;
      case ConstraintKind::kPlanarFriction: err = frictionBlock<2, T>(lam + o, u + o, dui, mu, sq); break;
      case ConstraintKind::kSpatialFriction: err = frictionBlock<3, T>(lam + o, u + o, dui, mu, sq); break;
      case ConstraintKind::kBox:
        err = boxRow<T>(lam[o], u[o], dui, static_cast<T>(cons[i].lower), static_cast<T>(cons[i].upper), sq);
        break;
    }
    if (block_bound != nullptr) (*block_bound)[i] = static_cast<double>(err);
  }
  using std::sqrt;
  return sqrt(sq);
}

// Normal row of a block with one (friction, unilateral), -1 otherwise (bilateral, box: a box row's
// u may take either sign at a solution, and its force is bounded: it certifies nothing).
Eigen::Index normalRow(const ContactProblem& problem, std::size_t i) {
  const Constraint& c = problem.constraints()[i];
  if (c.kind == ConstraintKind::kBilateral || c.kind == ConstraintKind::kBox) return -1;
  return problem.offsets()[i] + c.size - 1;
}

// What rounding lambda to double can move the natural map by, per block and in all:
// |d lambda| <= eps |lambda|, |A d lambda| <= eps |A||lambda|, carried through w (1 + mu).
double floorOf(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
               const Eigen::VectorXd& abs_product, std::vector<double>& block_floor) {
  const auto& cons = problem.constraints();
  const auto& off = problem.offsets();
  block_floor.resize(cons.size());
  double sq = 0.0;
  for (std::size_t i = 0; i < cons.size(); ++i) {
    const Eigen::Index o = off[i];
    const int k = cons[i].size;
    const double f = kEps * (lam.segment(o, k).norm() + (1.0 + cons[i].mu) * abs_product.segment(o, k).norm());
    block_floor[i] = f;
    sq += f * f;
  }
  return std::sqrt(sq);
}

}  // namespace

const char* toString(SolveStatus status) {
  switch (status) {
    case SolveStatus::kConverged: return "converged";
    case SolveStatus::kNotConverged: return "not_converged";
    case SolveStatus::kInfeasible: return "infeasible";
    case SolveStatus::kUnresolvable: return "unresolvable";
  }
  return "unknown";
}

double naturalMapNorm(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                      const Eigen::Ref<const Eigen::VectorXd>& u) {
  return evaluate<double>(problem, lam.data(), u.data(), nullptr, nullptr);
}

double stoppingScale(const ContactProblem& problem) {
  const double nb = problem.bNorm();
  return nb > 0.0 ? nb : 1.0;
}

namespace {

// The measures, computed (measureVerdict adds a cache in front).
void measureVerdictUncached(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                            VerdictMeasures& out, double decisive, bool per_block, const Eigen::VectorXd* fresh_u,
                            const Eigen::VectorXd* fresh_abs, Eigen::VectorXd& ud) {
  using VectorExt = Eigen::Matrix<Extended, Eigen::Dynamic, 1>;
  // Workspace reused across calls (a verdict per simulator step: no allocation once sized).
  thread_local Eigen::VectorXd abs_product, du;
  thread_local VectorExt l, u;
  thread_local std::vector<double> block_bound, block_floor;
  const Eigen::Index m = problem.numRows();
  block_bound.resize(problem.numBlocks());
  // |A||lambda| (in double, inflated by its own rounding: it is only a bound)
  if (fresh_u != nullptr && fresh_abs != nullptr && fresh_abs->size() == m) {
    abs_product = *fresh_abs;
  } else {
    abs_product.resize(m);
    problem.delassus().absMultiply(lam, abs_product);
  }
  // A row of A lambda sums at most `terms` products (a sparse A: its fullest row, not m), through a
  // chain of at most `chain` roundings in the operator's own products (fewer where its kernel sums
  // in lanes): the worst-case rounding bounds gamma_chain of stage 1, gamma_terms of stages 2-3.
  const double terms = static_cast<double>(problem.delassus().maxRowEntries());
  const double chain = static_cast<double>(problem.delassus().productRoundingTerms());
  abs_product *= 1.0 + (chain + 2.0) * kEps;
  out.floor = floorOf(problem, lam, abs_product, per_block ? out.block_floor : block_floor);
  const double underflow = std::sqrt(2.0 * static_cast<double>(m) * std::numeric_limits<double>::min());
  auto finish = [&](double map, double unit) {
    out.natural_map = map;
    double sq = 0.0;
    for (double e : block_bound) sq += e * e;
    // + the norm's own accumulation, + squares that underflowed (each loses < DBL_MIN of the sum)
    out.bound = std::sqrt(sq) + (static_cast<double>(m) + 2.0) * unit * map + underflow;
  };
  // 1. In double (vectorised; enough for a well-scaled problem): decisive when even
  //    its worst-case bound keeps it on one side of `decisive`.
  double gamma = (chain + 2.0) * kEps;
  if (fresh_u != nullptr) {
    ud = *fresh_u;
  } else {  // (by multiply, as every other residual of this lambda: the same rounding)
    ud.resize(m);
    problem.delassus().multiply(lam, ud);
    ud -= problem.b();
  }
  du = gamma * (abs_product + problem.b().cwiseAbs());
  finish(evaluate<double>(problem, lam.data(), ud.data(), du.data(), &block_bound), kEps);
  if (out.natural_map + out.bound <= decisive || out.natural_map - out.bound > decisive) return;
  // 2. Compensated, still in double (compensated.hpp): u as if computed in twice double precision
  //    and rounded once, off by eps |u| + gamma^2 (|A||lambda| + |b|) per row where stage 1 is off
  //    by gamma (|A||lambda| + |b|). Decides where |A||lambda| dwarfs the residual's scale (a
  //    256-box tower at rest: 1e3 times), at a fraction of stage 3's long double cost. (The
  //    constants: two chains joined and b make terms + 3 sums, doubled for margin; the bound's own
  //    rounding; an absolute term for products that underflow.)
  problem.delassus().compensatedResidual(lam, problem.b(), ud);
  {
    const double g2 = 2.0 * compensatedGammaSquared(terms + 3.0);
    const double tiny = 4.0 * (terms + 3.0) * std::numeric_limits<double>::denorm_min();
    du = ((kEps * ud.cwiseAbs() + g2 * (abs_product + problem.b().cwiseAbs())) * (1.0 + 16.0 * kEps)).array() + tiny;
  }
  finish(evaluate<double>(problem, lam.data(), ud.data(), du.data(), &block_bound), kEps);
  if (out.natural_map + out.bound <= decisive || out.natural_map - out.bound > decisive) return;
  // 3. In extended precision: u = A lambda - b and every block, with its (smaller) bound.
  static_assert(std::is_same<Extended, long double>::value, "DelassusOperator::multiplyExtended is long double");
  l = lam.cast<Extended>();
  problem.delassus().multiplyExtended(l, u);
  u -= problem.b().cast<Extended>();
  gamma = static_cast<double>((static_cast<Extended>(terms) + 2) * unitRoundoff<Extended>());
  du = gamma * (abs_product + problem.b().cwiseAbs());
  finish(static_cast<double>(evaluate<Extended>(problem, l.data(), u.data(), du.data(), &block_bound)),
         static_cast<double>(unitRoundoff<Extended>()));
}

// The last verdict measured in this solve: the algorithm's stopping test and the
// driver often judge the same lambda (forgetVerdicts() at the start of every solve,
// since A and b may change between solves; not within one).
struct VerdictCache {
  const ContactProblem* problem = nullptr;
  Eigen::VectorXd lam;
  Eigen::VectorXd u;  // A lambda - b in double
  double decisive = 0.0;
  VerdictMeasures out;
};
thread_local VerdictCache last_verdict;

// The cached lambda is this one, bit for bit (one memcmp where Eigen's == compares entry by entry; a
// -0 against a 0 only misses the cache, and a NaN's own bits give its own measures).
bool sameLambda(const Eigen::VectorXd& cached, const Eigen::Ref<const Eigen::VectorXd>& lam) {
  return cached.size() == lam.size() &&
         std::memcmp(cached.data(), lam.data(), static_cast<std::size_t>(lam.size()) * sizeof(double)) == 0;
}
}  // namespace

void forgetVerdicts() { last_verdict.problem = nullptr; }

bool lastVerdictResidual(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                         Eigen::VectorXd& u) {
  const VerdictCache& cache = last_verdict;
  if (cache.problem != &problem || cache.lam.size() != lam.size() || cache.u.size() != lam.size() || !sameLambda(cache.lam, lam))
    return false;
  u = cache.u;
  return true;
}

void measureVerdict(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam,
                    VerdictMeasures& out, double decisive, bool per_block, const Eigen::VectorXd* fresh_u,
                    const Eigen::VectorXd* fresh_abs) {
  VerdictCache& cache = last_verdict;
  if (!per_block && cache.problem == &problem && cache.decisive == decisive && sameLambda(cache.lam, lam)) {
    out.natural_map = cache.out.natural_map;
    out.bound = cache.out.bound;
    out.floor = cache.out.floor;
    return;
  }
  measureVerdictUncached(problem, lam, out, decisive, per_block, fresh_u, fresh_abs, cache.u);
  cache.problem = &problem;
  cache.lam = lam;
  cache.decisive = decisive;
  cache.out.natural_map = out.natural_map;
  cache.out.bound = out.bound;
  cache.out.floor = out.floor;
}

double precisionFloor(const ContactProblem& problem, const Eigen::Ref<const Eigen::VectorXd>& lam) {
  thread_local Eigen::VectorXd abs_product;
  thread_local std::vector<double> blocks;
  abs_product.resize(problem.numRows());
  problem.delassus().absMultiply(lam, abs_product);
  return floorOf(problem, lam, abs_product, blocks);
}

InfeasibilityCertificate findInfeasibility(const ContactProblem& problem,
                                           const std::vector<Eigen::VectorXd>& candidates) {
  InfeasibilityCertificate best;
  const DelassusOperator& A = problem.delassus();
  const Eigen::VectorXd& b = problem.b();
  const Eigen::Index m = problem.numRows();
  if (m == 0) return best;
  thread_local Eigen::VectorXd diag;  // (every solve runs this first: no allocation once sized)
  diag.resize(m);
  A.diagonal(diag);
  const double max_diag = diag.cwiseAbs().maxCoeff();
  // 1. Rows that nothing moves (a contact on an immovable body) but b pushes closed:
  //    u_n = -b_n < 0 whatever lambda. Only nearly-zero diagonals can be that.
  for (std::size_t i = 0; i < problem.numBlocks(); ++i) {
    const Eigen::Index n = normalRow(problem, i);
    if (n < 0 || !(b[n] > 0.0) || diag[n] > 1e-8 * max_diag) continue;
    const double column = std::max(A.columnNorm(n), A.rowNorm(n));
    const double bound = column > 0.0 ? b[n] / column : kInf;
    if (bound > best.min_solution_norm) {
      best.min_solution_norm = bound;
      best.blocks.assign(1, static_cast<int>(i));
    } else if (bound == kInf) {
      best.blocks.push_back(static_cast<int>(i));
    }
  }
  if (best.min_solution_norm == kInf) return best;
  // 2. Directions along which the iterates ran away.
  if (candidates.empty()) return best;
  Eigen::VectorXd d(m), Ad(m);
  for (const Eigen::VectorXd& c : candidates) {
    if (c.size() != m || !c.allFinite()) continue;
    d.setZero();
    for (std::size_t i = 0; i < problem.numBlocks(); ++i) {
      const Constraint& con = problem.constraints()[i];
      const Eigen::Index o = problem.offsets()[i];
      if (con.kind == ConstraintKind::kBilateral)
        d.segment(o, con.size) = c.segment(o, con.size);
      else if (con.kind != ConstraintKind::kBox)  // (box rows: d = 0, their u has no sign)
        d[o + con.size - 1] = std::max(0.0, c[o + con.size - 1]);
    }
    const double scale = d.lpNorm<Eigen::Infinity>();
    if (!(scale > 0.0)) continue;
    d /= scale;
    const double push = b.dot(d);
    if (!(push > 0.0)) continue;
    A.multiplyTransposed(d, Ad);  // d' A lambda = (A^T d)' lambda
    const double resist = Ad.norm();
    const double bound = resist > 0.0 ? push / resist : kInf;
    if (bound > best.min_solution_norm) {
      best.min_solution_norm = bound;
      best.blocks.clear();
      for (std::size_t i = 0; i < problem.numBlocks(); ++i) {
        const Eigen::Index o = problem.offsets()[i];
        if (d.segment(o, problem.constraints()[i].size).lpNorm<Eigen::Infinity>() >= 1e-3)
          best.blocks.push_back(static_cast<int>(i));
      }
    }
  }
  return best;
}

bool beyondPrecision(const ContactProblem& problem, double min_solution_norm) {
  if (!(min_solution_norm > 0.0)) return false;
  if (std::isinf(min_solution_norm)) return true;
  // lambda's natural scale is ||b|| / max diag A: a bound measured against it says the same at
  // every magnitude of A (against ||b|| alone, A = 1e-50 I made every problem "infeasible").
  thread_local Eigen::VectorXd diag;
  diag.resize(problem.numRows());
  problem.delassus().diagonal(diag);
  const double max_diag = problem.numRows() > 0 ? diag.maxCoeff() : 0.0;
  return min_solution_norm * kEps * (max_diag > 0.0 ? max_diag : 1.0) > kLooseTolerance * stoppingScale(problem);
}

StoppingTest::StoppingTest(const ContactProblem& problem, double tolerance)
    : problem_(problem), threshold_(tolerance * stoppingScale(problem)) {}

StoppingTest::Outcome StoppingTest::check(const Eigen::Ref<const Eigen::VectorXd>& lam, const Eigen::VectorXd& u,
                                          double natural_map, bool u_is_fresh, const Eigen::VectorXd* abs_product) {
  if (!(natural_map <= threshold_)) return kContinue;
  measureVerdict(problem_, lam, measures_, threshold_, false, u_is_fresh ? &u : nullptr,
                 u_is_fresh ? abs_product : nullptr);
  if (measures_.natural_map + measures_.bound <= threshold_) return kConverged;
  if (measures_.floor > kFloorMargin * threshold_) return kUnresolvable;
  return kContinue;  // within reach: a little more accuracy is needed
}

}  // namespace stiction
