// pinocchio-admm, pinocchio-pgs, pinocchio-admm-ccp: Pinocchio 4.1's own constraint solvers
// (ADMMConstraintSolverTpl, PGSConstraintSolverTpl) run on a stiction ContactProblem, the
// baselines the paper measures the exact formulation against. The C++ twin of
// src/stiction/baselines.py, with the same choices:
//
//   - Pinocchio solves  K ∋ lambda ⟂ u + Phi(u) ∈ K*,  u = G lambda + g  (Phi: De Saxce's
//     shift with solve_ncp, else 0), so stiction's u = A lambda - b is passed as G = A (a
//     DelassusOperatorDense holding a copy of A, refilled at every call) and g = -b. Rows
//     follow the same convention: normal last.
//   - The constraint models only give the solvers their sizes and cones (a dense Delassus
//     operator needs no kinematics): they are attached to a dummy model and calc() is never
//     called. Block mapping (stiction -> Pinocchio):
//       spatial friction (t1, t2, n), mu -> PointContactConstraintModel, setFriction(mu)
//       bilateral(3)                     -> PointAnchorConstraintModel (R^3, free)
//       bilateral(6)                     -> FrameAnchorConstraintModel (R^6, free)
//       bilateral(3k), k > 2             -> frame anchors (and one point anchor): the free set
//                                           R^3k is a product, so the split is exact
//       unilateral (1 row)               -> JointLimitConstraintModel with one lower limit:
//                                           Pinocchio's only 1-row cone, the non-negative
//                                           orthant (lambda >= 0 ⟂ u >= 0)
//       planar friction                  -> none (Pinocchio's friction cone is 3-D only):
//                                           std::invalid_argument, as for bilateral(k), 3 ∤ k
//   - ADMM: Lanczos size 20 for the largest Delassus eigenvalue that sets its initial rho
//     (Pinocchio's default is a full-size Lanczos); everything else at Pinocchio's defaults.
//   - PGS is refused above 1000 rows: it symmetrizes the n x n Delassus matrix in a buffer
//     on the stack (alloca in enforceSymmetry, 8 n^2 bytes), a segfault from about 1024 rows
//     on an 8 MiB stack; smaller thread stacks are checked too.
//   - settings.tolerance sets Pinocchio's four tolerances (absolute and relative feasibility
//     and complementarity), settings.max_iterations its iteration budget (Pinocchio's loop runs
//     max_iterations + 1 times; it is given max_iterations - 1). settings.time_limit: Pinocchio's
//     loop has no clock, so under a time limit it runs in chunks of iterations, each restarted from
//     the last impulses (ADMM: and its last rho), sized from the measured cost to the time left.
//   - Warm start: result.lam on entry when it is non-zero (setConstraintImpulseGuess).
//   - A non-symmetric A (some FCLib files): ADMM's Cholesky reads its lower triangle, PGS
//     works on (A + A^T) / 2 (baselines.py).
//   - result.iterations counts the iterations run: Pinocchio's `iterations` + 1 when it
//     converged (its count is then the 0-based index of the last one), 0 when ADMM's guess
//     passed its test before the loop, Pinocchio's count otherwise.
//   - result.own_residual is what Pinocchio's stopping test compared with the tolerance: the
//     smaller of its KKT measure and its step measure (own_law spells both out), so
//     own_converged (Pinocchio's claim) <=> own_residual <= tolerance, up to the scale
//     bookkeeping of its step test. PGS's KKT measure is taken per contact right after that
//     contact's update in the sweep, so it can pass while the true residual is not small
//     (cube with mu = 0: 1 sweep, exact-law residual 2e-3 ||b||).
//
// Pinocchio's PGS has no CCP mode: its solve_ncp setting only changes what it records with
// stat_record; the iteration (normal update, then the tangential projection onto the disc
// of radius mu lambda_n) is the Coulomb NCP either way. "pgs" without ncp is refused.
//
// This is the one translation unit that instantiates Pinocchio's solvers: keep it that way.
// Built best with pinocchio::pinocchio's compile definitions (PINOCCHIO_ENABLE_TEMPLATE_INSTANTIATION
// takes ADMM's solve from libpinocchio_default); without them, the Boost.MPL limits Pinocchio's
// variants need are set here, and everything is instantiated in this file.
#ifndef BOOST_MPL_LIMIT_LIST_SIZE
#define BOOST_MPL_CFG_NO_PREPROCESSED_HEADERS
#define BOOST_MPL_LIMIT_LIST_SIZE 30
#define BOOST_MPL_LIMIT_VECTOR_SIZE 30
#endif
#ifndef BOOST_FUSION_INVOKE_MAX_ARITY
#define BOOST_FUSION_INVOKE_MAX_ARITY 12
#endif

#if defined(__GNUC__) && !defined(__clang__)
// Pinocchio's ADMM leaves a union of update rules and a 1x1 vector "maybe uninitialized" in
// GCC's eyes (admm-solver.hpp, delassus-operator-base.hxx): not ours to fix.
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#endif

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <new>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#if defined(__linux__)
#include <pthread.h>
#endif

#include <pinocchio/multibody.hpp>
#include <pinocchio/constraints.hpp>
#include <pinocchio/algorithm/delassus-operator.hpp>
#include <pinocchio/algorithm/solvers/admm-solver.hpp>
#include <pinocchio/algorithm/solvers/pgs-solver.hpp>

#include "formulations.hpp"

namespace stiction {
namespace {

namespace pin = pinocchio;

constexpr int kAdmmLanczosSize = 20;       // baselines.py ADMM_LANCZOS_SIZE
constexpr Eigen::Index kPgsMaxRows = 1000;  // baselines.py PGS_MAX_ROWS

// The solvers with read access to their (protected) workspace: the previous iterates that
// their step test compared, to report the measure that stopped them.
struct AdmmSolver : pin::ADMMConstraintSolver {
  AdmmSolver() : pin::ADMMConstraintSolver(0) {}
  const ADMMSolverWorkspace& workspace() const { return m_workspace; }
};
struct PgsSolver : pin::PGSConstraintSolver {
  PgsSolver() : pin::PGSConstraintSolver(0) {}
  const PGSSolverWorkspace& workspace() const { return m_workspace; }
};

/// The dense Delassus operator G = A, refilled in place when the size repeats: rebuild()
/// reallocates its block-diagonal damping at every call. Its damping and compliance need no
/// reset: compliance stays 0, PGS never damps, and ADMM sets its damping (updateDamping) before
/// it first uses G, so what it left last time is never read.
struct DenseOperator : pin::DelassusOperatorDense {
  void refill(const Eigen::MatrixXd& A) {
    if (rows() != A.rows() || cols() != A.cols()) {
      rebuild(A);
      return;
    }
    m_delassus_matrix = A;
    m_cholesky_decomposition_dirty = true;
  }
};

/// Append x in %.3g to s (no temporary string: the message buffer is reused across steps).
void appendNumber(std::string& s, double x) {
  char buf[32];
  const int n = std::snprintf(buf, sizeof buf, "%.3g", x);
  if (n > 0) s.append(buf, static_cast<std::size_t>(std::min<int>(n, sizeof buf - 1)));
}

/// The model every constraint refers to: a free-flying body (point contacts and anchors) and
/// a revolute joint with a lower limit only (unilateral rows). Never evaluated.
struct DummyModel {
  pin::Model model;
  pin::JointIndex body = 0;
  pin::JointIndex limited = 0;
  Eigen::VectorXd lower, upper, margin;  // position limits of the joint-limit constraints
};

const DummyModel& dummyModel() {
  static const DummyModel dummy = [] {
    DummyModel d;
    const pin::Inertia inertia = pin::Inertia::FromBox(1.0, 0.1, 0.1, 0.1);
    d.body = d.model.addJoint(0, pin::JointModelFreeFlyer(), pin::SE3::Identity(), "root");
    d.model.appendBodyToJoint(d.body, inertia, pin::SE3::Identity());
    d.limited = d.model.addJoint(d.body, pin::JointModelRZ(), pin::SE3::Identity(), "unilateral");
    d.model.appendBodyToJoint(d.limited, inertia, pin::SE3::Identity());
    const double inf = std::numeric_limits<double>::infinity();
    d.lower = Eigen::VectorXd::Constant(d.model.nq, -inf);
    d.upper = Eigen::VectorXd::Constant(d.model.nq, inf);
    d.margin = Eigen::VectorXd::Zero(d.model.nq);
    d.lower[d.model.joints[d.limited].idx_q()] = 0.0;  // one lower limit: one activable row
    return d;
  }();
  return dummy;
}

std::string fmt(double x) {
  std::ostringstream os;
  os.precision(3);
  os << x;
  return os.str();
}

/// Bytes of stack left below this frame on the calling thread (max size_t when unknown).
std::size_t remainingStack() {
#if defined(__linux__)
  thread_local std::uintptr_t low = 0;  // the lowest address of this thread's stack
  thread_local bool known = false;
  if (!known) {
    known = true;
    pthread_attr_t attr;
    if (pthread_getattr_np(pthread_self(), &attr) == 0) {
      void* addr = nullptr;
      std::size_t size = 0;
      if (pthread_attr_getstack(&attr, &addr, &size) == 0) low = reinterpret_cast<std::uintptr_t>(addr);
      pthread_attr_destroy(&attr);
    }
  }
  char here;
  const auto at = reinterpret_cast<std::uintptr_t>(&here);
  if (low != 0 && at > low) return static_cast<std::size_t>(at - low);
#endif
  return std::numeric_limits<std::size_t>::max();
}

/// |a - b|_inf / max(|a|_inf, |b|_inf) (0 when a = b): the relative change Pinocchio's step
/// test compares with its relative tolerance.
template <typename A, typename B>
double relativeStep(const A& current, const B& previous) {
  const double step = (current - previous).template lpNorm<Eigen::Infinity>();
  const double scale =
      std::max(current.template lpNorm<Eigen::Infinity>(), previous.template lpNorm<Eigen::Infinity>());
  if (step == 0.0) return 0.0;
  return scale > 0.0 ? step / scale : std::numeric_limits<double>::infinity();
}

class PinocchioFormulation final : public Formulation {
 public:
  PinocchioFormulation(bool admm, bool ncp) : admm_(admm), ncp_(ncp) {}

  std::string name() const override {
    return std::string(admm_ ? "pinocchio-admm" : "pinocchio-pgs") + (ncp_ ? "" : "-ccp");
  }
  std::string equations() const override { return ncp_ ? "73-77 (NCP)" : "78-79 (CCP)"; }

  void iterate(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result) override {
    refuseBoxRows(problem, name());  // (Pinocchio's solvers here take cones and anchors only)
    try {
      run(problem, settings, result);
    } catch (const std::invalid_argument&) {
      throw;
    } catch (const std::runtime_error&) {
      throw;
    } catch (const std::bad_alloc&) {
      throw std::runtime_error(name() + ": out of memory");
    } catch (const std::exception& e) {  // Pinocchio's std::logic_error (a dirty decomposition), ...
      throw std::runtime_error(name() + ": " + e.what());
    } catch (...) {
      throw std::runtime_error(name() + ": unknown exception from Pinocchio");
    }
  }

 private:
  struct Block {
    ConstraintKind kind;
    int size;
    double mu;
  };

  const char* solverName() const { return admm_ ? "Pinocchio ADMM" : "Pinocchio PGS"; }

  /// The Pinocchio models for the problem's blocks: rebuilt when the kinds or sizes change,
  /// friction coefficients updated in place.
  void updateLayout(const ContactProblem& problem) {
    const auto& cons = problem.constraints();
    bool same = cons.size() == layout_.size();
    for (std::size_t i = 0; same && i < cons.size(); ++i)
      same = cons[i].kind == layout_[i].kind && cons[i].size == layout_[i].size;
    if (same) {
      for (std::size_t i = 0; i < cons.size(); ++i) {
        if (cons[i].kind != ConstraintKind::kSpatialFriction || cons[i].mu == layout_[i].mu) continue;
        auto* contact = boost::get<pin::PointContactConstraintModel>(&models_[friction_model_[i]].toVariant());
        if (contact == nullptr) throw std::runtime_error(name() + ": internal error, friction model lost");
        contact->setFriction(cons[i].mu);
        layout_[i].mu = cons[i].mu;
      }
      return;
    }

    // Check everything before touching the cached layout.
    for (std::size_t i = 0; i < cons.size(); ++i) {
      const Constraint& c = cons[i];
      const std::string where = " (block " + std::to_string(i) + ", " + c.describe() + ")";
      if (c.kind == ConstraintKind::kPlanarFriction)
        throw std::invalid_argument(name() + " does not handle planar friction blocks" + where +
                                    ": Pinocchio 4.1's friction cone is 3-D only");
      if (c.kind == ConstraintKind::kBilateral && (c.size <= 0 || c.size % 3 != 0))
        throw std::invalid_argument(name() + " does not handle bilateral blocks of " + std::to_string(c.size) +
                                    " rows" + where +
                                    ": Pinocchio 4.1's bilateral constraints have 3 rows (point anchor) "
                                    "or 6 (frame anchor)");
      if (c.kind == ConstraintKind::kUnilateral && c.size != 1)
        throw std::invalid_argument(name() + ": unilateral block of " + std::to_string(c.size) + " rows" + where);
      if (c.kind == ConstraintKind::kSpatialFriction && c.size != 3)
        throw std::invalid_argument(name() + ": spatial friction block of " + std::to_string(c.size) + " rows" +
                                    where);
    }

    // Built aside, swapped in when complete.
    const DummyModel& d = dummyModel();
    std::vector<Block> layout;
    std::vector<pin::ConstraintModel> models;
    std::vector<pin::ConstraintData> datas;
    std::vector<std::size_t> friction_model(cons.size(), 0);
    for (std::size_t i = 0; i < cons.size(); ++i) {
      const Constraint& c = cons[i];
      switch (c.kind) {
        case ConstraintKind::kSpatialFriction: {
          pin::PointContactConstraintModel contact(d.model, d.body);
          contact.setFriction(c.mu);
          friction_model[i] = models.size();
          models.emplace_back(contact);
          break;
        }
        case ConstraintKind::kBilateral: {
          int left = c.size;  // a multiple of 3
          for (; left >= 6; left -= 6) models.emplace_back(pin::FrameAnchorConstraintModel(d.model, d.body));
          if (left == 3) models.emplace_back(pin::PointAnchorConstraintModel(d.model, d.body));
          break;
        }
        case ConstraintKind::kUnilateral: {
          const pin::JointLimitConstraintModel::JointIndexVector joints{d.limited};
          pin::JointLimitConstraintModel limit(d.model, joints, d.lower, d.upper, d.margin);
          if (limit.residualSize() != 1)
            throw std::runtime_error(name() + ": internal error, the joint-limit model has " +
                                     std::to_string(limit.residualSize()) + " rows instead of 1");
          models.emplace_back(limit);
          break;
        }
        case ConstraintKind::kPlanarFriction:
        case ConstraintKind::kBox: break;  // refused above
      }
      layout.push_back({c.kind, c.size, c.mu});
    }
    datas.reserve(models.size());
    Eigen::Index rows = 0;
    for (const auto& m : models) {
      datas.push_back(m.createData());
      rows += m.residualSize();
    }
    if (rows != problem.numRows())
      throw std::runtime_error(name() + ": internal error, the Pinocchio constraints have " + std::to_string(rows) +
                               " rows, the problem " + std::to_string(problem.numRows()));
    layout_.swap(layout);
    models_.swap(models);
    datas_.swap(datas);
    friction_model_.swap(friction_model);
  }

  void run(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result) {
    const Eigen::Index m = problem.numRows();
    if (!admm_) {
      if (m > kPgsMaxRows)
        throw std::invalid_argument(
            name() + ": Pinocchio's PGS copies the " + std::to_string(m) + " x " + std::to_string(m) +
            " Delassus matrix onto the stack (alloca in enforceSymmetry, 8 n^2 bytes) and crashes from about "
            "1024 rows on an 8 MiB stack; refused above " + std::to_string(kPgsMaxRows) +
            " rows (use pinocchio-admm)");
      const std::size_t need = 8 * static_cast<std::size_t>(m) * static_cast<std::size_t>(m) + (64u << 10);
      const std::size_t left = remainingStack();
      if (need > left)
        throw std::invalid_argument(name() + ": Pinocchio's PGS would put " + fmt(8.0 * m * m / 1048576.0) +
                                    " MiB on this thread's stack, which has " + fmt(left / 1048576.0) +
                                    " MiB left (alloca in enforceSymmetry); run it on a thread with a larger stack "
                                    "or use pinocchio-admm");
    }
    updateLayout(problem);
    if (result.lam.size() != m) result.lam = Eigen::VectorXd::Zero(m);  // the driver sizes it
    result.own_law = admm_ ? "Pinocchio ADMM's stopping test, min(KKT, step) <= tolerance: KKT = max(complementarity, "
                             "dual feasibility / (1 + max(|g|, |z|)), primal feasibility / (1 + max(|x|, |y|))), "
                             "step = max relative change of x, y, z (inf-norms, Pinocchio's own quantities)"
                           : "Pinocchio PGS's stopping test, min(KKT, step) <= tolerance: KKT = max over contacts of "
                             "dual feasibility and complementarity (absolute, De Saxce-corrected, each taken right "
                             "after that contact's update in the sweep), step = |lambda - lambda_prev| / "
                             "max(|lambda|, |lambda_prev|) (inf-norms)";
    if (m == 0) {
      result.iterations = 0;
      result.own_converged = true;
      result.own_residual = 0.0;
      result.message = "converged (no rows)";
      return;
    }
    if (settings.max_iterations <= 0) {  // Pinocchio always runs at least one iteration
      result.iterations = 0;
      result.own_converged = false;
      result.own_residual = std::numeric_limits<double>::infinity();
      result.message = "iteration limit reached (max_iterations = 0: " + std::string(solverName()) + " not run)";
      return;
    }

    delassus_.refill(problem.delassus().dense());
    g_.resize(m);
    g_ = -problem.b();
    const bool guess = (result.lam.array() != 0.0).any();
    const double tol = settings.tolerance;

    // One call of Pinocchio's solve with at most `iterations` iterations (>= 1), from result.lam when
    // `from_lam` (else from zero); returns the iterations it ran.
    bool converged = false, before_loop = false;
    std::size_t count = 0;
    double primal = 0.0, dual = 0.0, complementarity = 0.0;
    // The budget and the tolerance (every one of Pinocchio's four stopping tests at `tol`), for
    // either solver's settings (the same fields in two types).
    auto configure = [&](auto& solver_settings, std::size_t budget) {
      solver_settings.max_iterations = budget;
      solver_settings.absolute_feasibility_tol = tol;
      solver_settings.relative_feasibility_tol = tol;
      solver_settings.absolute_complementarity_tol = tol;
      solver_settings.relative_complementarity_tol = tol;
      solver_settings.solve_ncp = ncp_;
    };
    auto call = [&](std::size_t iterations, bool from_lam, bool warm_rho) -> std::size_t {
      const std::size_t budget = iterations - 1;  // (its loop runs max_iterations + 1 times)
      if (admm_) {
        configure(admm_settings_, budget);
        admm_settings_.lanczos_size = static_cast<std::size_t>(std::min<Eigen::Index>(kAdmmLanczosSize, m));
        admm_settings_.warmstart_rho_with_previous_result = warm_rho;
        if (from_lam)
          admm_result_.setConstraintImpulseGuess(result.lam);
        else
          admm_result_.clearConstraintImpulseGuess();
        admm_result_.clearConstraintVelocityGuess();
        converged = admm_solver_.solve(delassus_, g_, models_, datas_, admm_settings_, admm_result_);
        admm_result_.retrieveConstraintImpulses(result.lam);  // the projected iterate y
        count = admm_result_.iterations;
        primal = admm_result_.primal_feasibility;
        dual = admm_result_.dual_feasibility;
        complementarity = admm_result_.complementarity;
      } else {
        configure(pgs_settings_, budget);
        if (from_lam)
          pgs_result_.setConstraintImpulseGuess(result.lam);
        else
          pgs_result_.clearConstraintImpulseGuess();
        converged = pgs_solver_.solve(delassus_, g_, models_, datas_, pgs_settings_, pgs_result_);
        pgs_result_.retrieveConstraintImpulses(result.lam);
        count = pgs_result_.iterations;
        primal = pgs_result_.primal_feasibility;
        dual = pgs_result_.dual_feasibility;
        complementarity = pgs_result_.complementarity;
      }
      // Pinocchio's `iterations` is the index of the iteration that stopped (0-based) when it
      // converged, the number run otherwise; ADMM stops before its loop, with 0 iterations run,
      // when the guess already passes its (unscaled) test: then it factorized the Delassus once.
      before_loop = admm_ && converged && admm_result_.delassus_decomposition_update_count == 1;
      return converged ? (before_loop ? 0 : count + 1) : count;
    };

    // Pinocchio's loops have no clock. Without a time limit: one call with the whole budget. With
    // one: the same single call when a guess of its cost (a product or two triangular solves with A
    // per iteration, ADMM's factorization and Lanczos estimate per call) fits a tenth of the time;
    // otherwise chunks of iterations, each restarted from the last impulses (ADMM: and its last rho).
    // A first chunk of one iteration measures a call's own cost (set-up included: ADMM factorizes
    // A at every call), a second one sized from the guess measures an iteration's; the next ones
    // take half the time left at those costs, and none starts once that fits no iteration.
    const std::size_t total_budget = static_cast<std::size_t>(settings.max_iterations);
    std::size_t ran = 0;
    int chunks = 0;
    bool timed_out = false;
    if (settings.time_limit <= 0.0) {
      ran = call(total_budget, guess, false);
      chunks = 1;
    } else {
      const auto start = FastClock::now();
      auto since = [&]() { return std::chrono::duration<double>(FastClock::now() - start).count(); };
      const double rows = static_cast<double>(m);
      const double per_iteration_guess = 4e-9 * rows * rows + 1e-7;
      const double set_up_guess =
          admm_ ? 1e-9 * rows * rows * rows / 3.0 + 4e-9 * kAdmmLanczosSize * rows * rows : 2e-9 * rows * rows;
      double overhead = 0.0, per_iteration = per_iteration_guess;
      std::size_t last_chunk = 1;
      for (;;) {
        const double left = settings.time_limit - since();
        const std::size_t rest = total_budget - ran;
        double fits;
        if (chunks == 0)
          fits = set_up_guess + static_cast<double>(rest) * per_iteration_guess <= 0.1 * left ? static_cast<double>(rest)
                                                                                               : 1.0;
        else if (chunks == 1)
          fits = std::max(1.0, (0.25 * left - overhead) / per_iteration_guess);
        else
          fits = (0.5 * left - overhead) / per_iteration;
        if (left <= 0.0 || fits < 1.0) {
          timed_out = true;
          break;
        }
        // (at most 8 times the last chunk: a cost measured low by noise cannot buy a run-away chunk)
        const double most = chunks == 0 ? fits : 8.0 * static_cast<double>(std::max<std::size_t>(1, last_chunk));
        const std::size_t chunk = std::min(rest, static_cast<std::size_t>(std::min({fits, most, 1e15})));
        last_chunk = chunk;
        const double t0 = since();
        const std::size_t done = call(chunk, chunks == 0 ? guess : true, chunks > 0);
        const double took = since() - t0;
        ++chunks;
        ran += done;
        if (converged || ran >= total_budget || !result.lam.allFinite()) break;
        if (chunks == 1)
          overhead = took;  // one iteration and the call's set-up
        else  // (a call costs about overhead + done x per_iteration; with margins for noise)
          per_iteration = std::max({1e-9, (took - 0.9 * overhead) / static_cast<double>(std::max<std::size_t>(1, done)),
                                    0.25 * took / static_cast<double>(std::max<std::size_t>(1, done))});
      }
    }
    result.iterations = static_cast<int>(std::min<std::size_t>(ran, 2147483647u));

    // What its stopping test measured (all four tolerances are `tol`, see own_law).
    double kkt = 0.0, step = std::numeric_limits<double>::infinity();
    if (admm_) {
      const auto& r = admm_result_;
      if (before_loop) {
        kkt = std::max(complementarity, dual);
      } else {
        const double g_inf = g_.lpNorm<Eigen::Infinity>();
        const double z_inf = r.z.lpNorm<Eigen::Infinity>();
        const double x_inf = r.x.lpNorm<Eigen::Infinity>();
        const double y_inf = r.y.lpNorm<Eigen::Infinity>();
        kkt = std::max({complementarity, dual / (1.0 + std::max(g_inf, z_inf)),
                        primal / (1.0 + std::max(x_inf, y_inf))});
        const auto& ws = admm_solver_.workspace();
        step = std::max({relativeStep(ws.x, ws.x_previous), relativeStep(ws.y, ws.y_previous),
                         relativeStep(ws.z, ws.z_previous)});
      }
    } else {
      kkt = std::max({primal, dual, complementarity});
      const auto& ws = pgs_solver_.workspace();
      step = relativeStep(ws.x, ws.x_previous);
    }
    const double own = std::min(kkt, step);
    result.own_residual = std::isnan(own) ? std::numeric_limits<double>::infinity() : own;
    result.own_converged = converged;

    // The message, built in place (no allocation once its buffer has grown).
    std::string& msg = result.message;
    msg.clear();
    if (!result.lam.allFinite()) {
      result.own_converged = false;
      msg.append(solverName()).append(" returned non-finite impulses after ");
      appendNumber(msg, result.iterations);
      msg.append(" iterations");
    } else if (converged) {
      msg.append("converged (").append(solverName());
      if (before_loop) {
        msg.append(": the warm start passes its test)");
      } else if (kkt <= tol) {
        msg.append(", KKT test)");
      } else {
        msg.append(", step test: relative change ");
        appendNumber(msg, step);
        msg.append(")");
      }
    } else {
      msg.append(timed_out ? "time limit reached (" : "iteration limit reached (").append(solverName());
      if (chunks > 1) {
        msg.append(", ");
        appendNumber(msg, chunks);
        msg.append(" chunks");
      }
      msg.append(", KKT ");
      appendNumber(msg, kkt);
      msg.append(", step ");
      appendNumber(msg, step);
      msg.append(")");
    }
  }

  const bool admm_;
  const bool ncp_;

  std::vector<Block> layout_;
  std::vector<std::size_t> friction_model_;  // per block: its PointContact model (friction blocks)
  std::vector<pin::ConstraintModel> models_;
  std::vector<pin::ConstraintData> datas_;

  DenseOperator delassus_;
  Eigen::VectorXd g_;

  AdmmSolver admm_solver_;
  pin::ADMMSolverSettings admm_settings_;
  pin::ADMMSolverResult admm_result_;
  PgsSolver pgs_solver_;
  pin::PGSSolverSettings pgs_settings_;
  pin::PGSSolverResult pgs_result_;
};

}  // namespace

std::unique_ptr<Formulation> makePinocchioFormulation(const std::string& method, bool ncp) {
  if (method != "admm" && method != "pgs")
    throw std::invalid_argument("unknown Pinocchio solver '" + method + "' (known: admm, pgs)");
  if (method == "pgs" && !ncp)
    throw std::invalid_argument(
        "pinocchio-pgs-ccp: Pinocchio 4.1's PGS has no CCP mode (its solve_ncp setting only changes the "
        "statistics it records; the iteration is the Coulomb NCP either way): it would be pinocchio-pgs under "
        "another name. Use pinocchio-admm-ccp or ccp");
  return std::make_unique<PinocchioFormulation>(method == "admm", ncp);
}

}  // namespace stiction
