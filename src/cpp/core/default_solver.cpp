// The default solver (default_solver.hpp): its rule, defaultPlan, and the executor that runs the
// plan's stages (DefaultSolver::Cascade), with the measurements behind each stage.
#include "stiction/default_solver.hpp"

#include <algorithm>
#include <chrono>
#include <limits>
#include <stdexcept>

#include "stiction/clock.hpp"
#include "stiction/proxqp_warm_start.hpp"

namespace stiction {

namespace {

// Entries A stores (a dense A: its nonzeros).
Eigen::Index storedEntries(const ContactProblem& problem) {
  if (const Eigen::SparseMatrix<double>* S = problem.delassus().sparse()) return S->nonZeros();
  const Eigen::MatrixXd& A = problem.delassus().dense();
  return static_cast<Eigen::Index>((A.array() != 0.0).count());
}

}  // namespace

const char* toString(DefaultStage stage) {
  switch (stage) {
    case DefaultStage::kStickingStep: return "sticking_step";
    case DefaultStage::kNewtonFirst: return "newton_first";
    case DefaultStage::kProxqpNewton: return "proxqp_newton";
    case DefaultStage::kWarmSweeps: return "warm_sweeps";
    case DefaultStage::kSparseNewton: return "sparse_newton";
    case DefaultStage::kAdmm: return "admm";
    case DefaultStage::kNsgs: return "nsgs";
    case DefaultStage::kAdmmAfterNsgs: return "admm_after_nsgs";
    case DefaultStage::kWarmAdmm: return "warm_admm";
    case DefaultStage::kNewtonAfterNsgs: return "newton_after_nsgs";
    case DefaultStage::kNewtonFromGuess: return "newton_from_guess";
    case DefaultStage::kFallbacks: return "fallbacks";
  }
  throw std::logic_error("toString: unknown DefaultStage");
}

DefaultPlan defaultPlan(const DefaultRuleInput& in) {
  using S = DefaultStage;
  DefaultPlan plan;
  // 0. A guess with every contact closed and sticking: the all-stick solution, if it is one.
  if (in.has_budget && in.rows > 0 && in.sticking_guess) plan.add(S::kStickingStep);
  if (in.rows <= kNewtonFirstRows) {
    // 1a. Small problems (a robot's feet, a box's corners): a dense Newton step costs less than a
    //     few Gauss-Seidel sweeps and converges in a handful; then from ProxQP's solution.
    plan.add(S::kNewtonFirst);
    plan.add(S::kProxqpNewton);
  } else if (in.rows > kAdmmAboveRows && in.sparse) {
    // 1b. Large sparse problems: (warm-started: a few sweeps), sparse Newton from the guess when
    //     A has few entries, ADMM; Newton from the initial guess unless sparse Newton ran from it.
    if (in.warm_started) plan.add(S::kWarmSweeps);
    const bool sparse_newton = in.stored_entries <= kSparseNewtonEntries;
    if (sparse_newton) plan.add(S::kSparseNewton);
    plan.add(S::kAdmm);
    if (!sparse_newton) plan.add(S::kNewtonFromGuess);
  } else if (in.rows > kAdmmAboveRows) {
    // 1c. Large dense problems: NSGS until it stalls, then ADMM.
    plan.add(S::kNsgs);
    plan.add(S::kAdmmAfterNsgs);
    plan.add(S::kNewtonFromGuess);
  } else {
    // 1d. Medium problems: NSGS until it stalls, (warm-started: a few ADMM iterations), Newton.
    plan.add(S::kNsgs);
    if (in.warm_started) plan.add(S::kWarmAdmm);
    plan.add(S::kNewtonAfterNsgs);
    plan.add(S::kNewtonFromGuess);
  }
  plan.add(S::kFallbacks);
  return plan;
}

DefaultRuleInput defaultRuleInput(const ContactProblem& problem, const Eigen::VectorXd& guess,
                                  const SolverSettings& settings) {
  DefaultRuleInput in;
  in.rows = problem.numRows();
  in.has_budget = settings.max_iterations > 0;
  in.warm_started = settings.warm_start != WarmStart::kNone;
  in.sticking_guess = in.has_budget && in.rows > 0 && stickingGuess(problem, guess);
  if (in.rows > kAdmmAboveRows) {
    in.sparse = sparseEnough(problem, kSparseProblemDensity);
    if (in.sparse) in.stored_entries = storedEntries(problem);
  }
  return in;
}

/// One solve by the default: the plan's stages in order, the iterations and time they share, the
/// best iterate met.
class DefaultSolver::Cascade {
 public:
  using Clock = FastClock;  // the time-stamp counter (clock.hpp)

  Cascade(DefaultSolver& solver, const ContactProblem& problem, const SolverSettings& settings,
          SolverResult& result)
      : s_(solver),
        problem_(problem),
        settings_(settings),
        result_(result),
        lam_(result.lam),
        budget_(settings.max_iterations),
        tol_(settings.tolerance),
        m_(static_cast<double>(problem.numRows())),
        // NSGS hands over when its rate predicts more sweeps than a few dense Newton steps
        // would cost. A step's LU is ~m^3/3 multiply-adds against a sweep's ~m^2, so a step is
        // ~m/3 sweeps; Newton typically needs 5-30 steps. (Before the local solve's warm slip
        // search a sweep cost ~3x more and this was m/2.) Measured on FCLib: Confeti-ex13 (321
        // rows) is predicted 160-320 more sweeps at sweep 15 and converges at 45 (1.2 ms, where
        // handing over at m/2 took 9.5 ms). PerioBox (180 rows, rank 72) hands over at sweep 30
        // instead of 23; its Newton from there took 10-27 steps in builds that differ only in
        // rounding (3.3-8.2 ms, against 4.4); with 2m, 35 steps (10.4 ms).
        switch_after_(std::max(50.0, m_)) {
    budget_clock_.startClock(settings.time_limit);  // (reads the clock for a limit only)
    s_.best_ = lam_;
    s_.initial_ = lam_;
    s_.u_ws_.resize(problem.numRows());
  }

  void run(const DefaultPlan& plan) {
    for (DefaultStage stage : plan)
      if (runStage(stage)) return;
  }

 private:
  // True when the solve is finished (result.iterations and message set).
  bool runStage(DefaultStage stage) {
    switch (stage) {
      case DefaultStage::kStickingStep: return stickingStep();
      case DefaultStage::kNewtonFirst: return newtonFirst();
      case DefaultStage::kProxqpNewton: return proxqpNewton();
      case DefaultStage::kWarmSweeps: return warmSweeps();
      case DefaultStage::kSparseNewton: return sparseNewton();
      case DefaultStage::kAdmm: return admmThenPolish("converged (admm)", budget_);
      case DefaultStage::kNsgs: return nsgs();
      case DefaultStage::kAdmmAfterNsgs:
        // Large dense problems: ADMM, not Newton (a dense LU of > 384 rows per step; with
        // dense factorizations ADMM took 0.15-0.6 s on the Capsules, NSGS then Newton
        // 0.15-8 s). From the initial guess, not the NSGS iterate: from there ADMM took 36
        // iterations instead of 12 on KaplasTower and crawled at 2e-8 for 400 iterations
        // on Capsules-i122 and -i101 (measured).
        return used_ < budget_ && !outOfTime() && admmThenPolish("converged (nsgs, admm)", budget_);
      case DefaultStage::kWarmAdmm:
        // Medium problems warm-started from the previous step (a simulation): a few ADMM
        // iterations from that guess. A tower of 20 cubes on 4 corners each (240 rows, A of
        // rank <= 120): Newton stalled (no descent along its direction) from the NSGS iterate
        // and from the guess, 22 ms per step, where ADMM from the guess converged in 4
        // iterations, 1.5 ms (measured on box-tower-20, before the sticking step). Where ADMM
        // needs more than kWarmAdmmIterations, Newton does better (spinning towers).
        return used_ < budget_ && !outOfTime() && admmThenPolish("converged (nsgs, admm)", kWarmAdmmIterations);
      case DefaultStage::kNewtonAfterNsgs: return newtonAfterNsgs();
      case DefaultStage::kNewtonFromGuess: return newtonFromGuess();
      case DefaultStage::kFallbacks: fallbacks(); return true;
    }
    return false;
  }

  double secondsSince(Clock::time_point t) const { return std::chrono::duration<double>(Clock::now() - t).count(); }
  // Every stage gets what is left of the time limit (0 = none).
  double remaining() const { return budget_clock_.remaining(); }
  bool outOfTime() const { return budget_clock_.outOfTime(); }

  double score(const Eigen::VectorXd& x) {
    problem_.delassus().multiply(x, s_.u_ws_);
    s_.u_ws_ -= problem_.b();
    return naturalMapNorm(problem_, x, s_.u_ws_);
  }
  // The initial guess's residual is only needed once something failed (keeps the usual
  // warm-started single Newton step free of extra products).
  void keepBest(const Eigen::VectorXd& x, const char* stage) {
    if (!initial_scored_) {
      initial_scored_ = true;
      best_res_ = score(s_.initial_);
    }
    const double r = score(x);
    if (r < best_res_) {
      s_.best_ = x;
      best_res_ = r;
      best_stage_ = stage;
    }
  }
  // Each stage's cost goes into result.stages.
  // (into the strings of the last solve's reports: no allocation once they have grown)
  template <typename Outcome>
  void record(const char* name, int iterations, Clock::time_point t0, const Outcome& outcome) {
    addStage(result_.stages, name, iterations, secondsSince(t0), outcome);
  }
  // (a literal is copied into the message's buffer: no string made)
  bool finish(const char* how) {
    result_.iterations = used_;
    result_.message.assign(how);
    return true;
  }
  bool finish(const std::string& how) {
    result_.iterations = used_;
    result_.message.assign(how);
    return true;
  }
  // A stage found lambda where the tolerance cannot be verified in double precision: no other
  // stage will do better at that scale; the verdict says so.
  static bool unresolvable(const std::string& stage_msg) { return stage_msg == kUnresolvableMessage; }

  // Newton from lam for at most `steps` (within the budget); true when it converged.
  bool newtonFromHere(int steps, const char* name) {
    if (used_ >= budget_) return false;  // nothing left: no empty stage in the report
    const auto t0 = Clock::now();
    const int done = s_.newton_.run(problem_, lam_, std::min(steps, std::max(0, budget_ - used_)), tol_, remaining(),
                                    newton_msg_);
    used_ += done;
    record(name, done, t0, newton_msg_);
    if (newton_msg_ == "converged") return true;
    keepBest(lam_, name);
    return false;
  }

  bool stickingStep() {
    const auto t0 = Clock::now();
    int solves = 0;
    const bool done = s_.sticking_.run(problem_, lam_, tol_, solves);
    used_ += solves;
    record("sticking step", solves, t0,
           !done ? "not all sticking" : s_.sticking_.usedHeldFactor() ? "converged (held factor)" : "converged");
    return done && finish("converged (sticking step)");
  }

  bool newtonFirst() {
    if (newtonFromHere(30, "newton")) return finish("converged (newton)");
    if (unresolvable(newton_msg_)) return finish(newton_msg_ + " (newton)");
    return false;
  }

  // Newton from ProxQP's facetized-cone QP solution: measured on stick-dominated, ill-conditioned
  // problems (a 1e4 stack at rest), where Newton stalls from zero and converges in one step from
  // the QP point; the QP costs ~0.1-0.3 ms at this size (docs/warm-start.md), so only after a
  // failure and only for small problems.
  bool proxqpNewton() {
    if (used_ >= budget_ || outOfTime()) return false;
    Eigen::VectorXd ray;
    StageReport qp = proxqpWarmStart(problem_, settings_, remaining(), lam_, &ray);
    result_.warm_start_iterations += qp.iterations;
    result_.warm_start_seconds += qp.seconds;
    result_.stages.push_back(qp);
    if (ray.size() == lam_.size()) result_.divergence_candidates.push_back(ray);
    const bool usable = qp.outcome == "solved" || qp.outcome == "iteration limit reached" ||
                        qp.outcome == "time limit reached";
    if (usable && !outOfTime()) {
      if (newtonFromHere(30, "newton (from proxqp)")) return finish("converged (proxqp, newton)");
      if (unresolvable(newton_msg_)) return finish(newton_msg_ + " (newton from proxqp)");
    }
    return false;
  }

  // A warm start close to the solution (the simulator's previous step) lets Gauss-Seidel finish
  // in a sweep or two, for less than ADMM's set-up (sparse copy, ordering, factorization,
  // spectrum): a resting grid of 48 cubes (576 rows), 1 sweep, where ADMM took 4 iterations and
  // 1.4x the time. At most kWarmSweeps sweeps, then ADMM.
  bool warmSweeps() {
    const auto t0 = Clock::now();
    const int sweeps = s_.nsgs_.sweep(problem_, lam_, std::min(budget_, kWarmSweeps), tol_, switch_after_,
                                      remaining(), msg_);
    used_ += sweeps;
    record("nsgs", sweeps, t0, msg_);
    if (msg_ == "converged") return finish(msg_);
    if (unresolvable(msg_) || msg_ == "time limit reached") return finish(msg_ + " (nsgs)");
    keepBest(lam_, "nsgs");
    return false;
  }

  // Large sparse problems with few stored entries: Newton from the guess, with its sparse
  // Jacobian and LU (NewtonSolver::run), before ADMM. Measured on FCLib to 1e-8: the Capsules
  // 8-30 ms (ADMM 18-42), Spheres 10 ms (13), SpheresBox 80 ms (ADMM stalls after 25 ms, then
  // the same Newton); KaplasTower (117k entries) 255 ms against ADMM's 81: the LU fills in,
  // hence the bound on A's entries. Warm-started ones the same once the sweeps did not finish,
  // from the guess (the previous step's answer): a tower of 36 spinning boxes (432 rows, every
  // interface sliding) took 450-930 ADMM iterations (10-19 ms) to stall, then Newton from the
  // guess converged in 5-34 steps (3-13 ms); within the simulator's budget of 200 iterations
  // ADMM used them all and 4 of 30 steps failed.
  bool sparseNewton() {
    lam_ = s_.initial_;
    if (newtonFromHere(50, "newton")) return finish("converged (newton)");
    if (unresolvable(newton_msg_)) return finish(newton_msg_ + " (newton)");
    keepBest(lam_, "newton");
    if (outOfTime()) return finish(newton_msg_ + " (newton)");
    return false;
  }

  // ADMM from the initial guess until it converges or its best residual stops improving (its
  // stall test: no progress over 400 iterations, or a rate that needs more than 10 m further
  // ones), then a few Newton steps from the best iterate met if it is nearly there (on the
  // degenerate Capsules, Newton from a near-solution point only takes tiny steps, so no more
  // than a few). Large sparse problems go straight here: with A <= 10 % nonzero ADMM factorizes
  // and solves sparsely (admm.cpp): on the FCLib problems of this kind (648-1710 rows, 0.6-4 %
  // nonzero) it reaches 1e-8 in 20-130 ms where the NSGS prelude alone cost 10-100 ms and NSGS
  // then Newton 0.15-4 s (Spheres: ADMM 20 ms, NSGS 65 ms; KaplasTower: ADMM 0.08-0.13 s, NSGS
  // 1.5 s; docs/solvers.md, "The default's rule"). True when the solve is finished.
  bool admmThenPolish(const char* converged_how, int max_iterations) {
    const auto t1 = Clock::now();
    lam_ = s_.initial_;
    const int done = s_.admm_.run(problem_, lam_, std::min(max_iterations, budget_ - used_), tol_, remaining(), 0.0,
                                  false, msg_, kAdmmHorizonPerRow * m_);
    admm_started_ = true;
    admm_state_ = lam_;
    used_ += done;
    record("admm", done, t1, msg_);
    if (msg_ == "converged") return finish(converged_how);
    if (unresolvable(msg_)) return finish(msg_ + " (admm)");
    keepBest(lam_, "admm");
    // Only an iterate that is nearly there (within 1000 x the tolerance) is worth a few Newton
    // steps: from SpheresBox's (relative residual ~0.2) 5 steps cost 0.17 s for nothing; and from
    // the initial guess, Newton comes next anyway.
    if (best_stage_ == "initial guess" || best_res_ > kPolishWithin * tol_ * stoppingScale(problem_)) return false;
    lam_ = s_.best_;
    if (newtonFromHere(kPolishSteps, "newton (from the best iterate)")) return finish("converged (admm, newton)");
    if (unresolvable(newton_msg_)) return finish(newton_msg_ + " (newton)");
    return false;
  }

  // Medium problems, and large dense ones: NSGS while it makes progress (a sweep costs one
  // product with A), until its rate or its deceleration says it stalls, or its rate says it would
  // finish past the budget (the simulator's 200 iterations): then the next stage gets what is
  // left. Measured on pile-256's step 159 (342 rows, 100 islands of <= 2 contacts, one a hull on
  // an edge whose two normal rows correlate at 0.973): NSGS improved all along, needed ~306
  // sweeps and stopped at the budget at 4.5e-9; handed over at its first rate, Newton converges.
  bool nsgs() {
    const auto t0 = Clock::now();
    const int sweeps = s_.nsgs_.sweep(problem_, lam_, budget_, tol_, switch_after_, remaining(),
                                      msg_, std::max(1, budget_ - used_));
    used_ += sweeps;
    record("nsgs", sweeps, t0, msg_);
    if (msg_ != "stalled") return finish(msg_ == "converged" ? msg_ : msg_ + " (nsgs)");
    keepBest(lam_, "nsgs");
    return false;
  }

  // Medium problems (65-384 rows): Newton from the NSGS iterate; a dense step costs a few ms
  // (BoxesStack, OneObject, PerioBox, Confeti-ex13: 0.5-18 ms in all, where ADMM took 4-80 ms).
  bool newtonAfterNsgs() {
    if (admm_started_) lam_ = s_.best_;
    if (newtonFromHere(50, "newton")) return finish("converged (nsgs, newton)");
    if (unresolvable(newton_msg_)) return finish(newton_msg_ + " (newton)");
    return false;
  }

  // Newton from the initial guess: on some problems the NSGS or ADMM iterate sits in a region
  // where the line search stalls and the guess does not (SpheresBox).
  bool newtonFromGuess() {
    if (outOfTime()) return false;
    lam_ = s_.initial_;
    if (newtonFromHere(50, "newton (from the initial guess)")) return finish("converged (newton from the initial guess)");
    if (unresolvable(newton_msg_)) return finish(newton_msg_ + " (newton)");
    return false;
  }

  void fallbacks() {
    // 2. Before the long fallbacks: if even the best iterate's own rounding moves the residual
    //    beyond the tolerance (lambda ~ 1e12 on a nearly singular A), no stage can verify
    //    anything at that scale: stop and let the verdict say so.
    if (initial_scored_ && precisionFloor(problem_, s_.best_) > kFloorMargin * tol_ * stoppingScale(problem_)) {
      lam_ = s_.best_;
      finish(std::string(kUnresolvableMessage) + " at the best iterate (from " + best_stage_ + ")");
      return;
    }
    // 3. Alternate chunks of NSGS and of ADMM (never diverges, handles rank deficiency; its
    //    state carries over between its chunks), each followed by a Newton attempt from the
    //    chunk's iterate, until the budget is spent.
    bool use_admm = false;
    if (!admm_started_) admm_state_ = s_.best_;
    std::string last = result_.stages.empty() ? "the start" : result_.stages.back().name;
    while (used_ < budget_ && !outOfTime()) {
      const int chunk = std::min(500, budget_ - used_);
      const auto t0 = Clock::now();
      int done;
      if (use_admm) {
        lam_ = admm_state_;
        done = s_.admm_.run(problem_, lam_, chunk, tol_, remaining(), 0.0, admm_started_, msg_);
        admm_started_ = true;
        admm_state_ = lam_;
      } else {
        lam_ = s_.best_;
        done = s_.nsgs_.sweep(problem_, lam_, chunk, tol_, switch_after_, remaining(), msg_);
      }
      used_ += done;
      last = use_admm ? "admm" : "nsgs";
      record(use_admm ? "admm" : "nsgs", done, t0, msg_);
      keepBest(lam_, use_admm ? "admm" : "nsgs");
      if (msg_ == "converged") {
        finish(use_admm ? "converged (nsgs, newton, admm)" : "converged (nsgs, newton, nsgs)");
        return;
      }
      if (unresolvable(msg_)) {
        finish(msg_ + " (" + last + ")");
        return;
      }
      if (msg_ == "time limit reached" || used_ >= budget_) break;
      s_.trial_ = lam_;
      const auto t1 = Clock::now();
      const int steps = s_.newton_.run(problem_, s_.trial_, std::min(20, budget_ - used_), tol_, remaining(), newton_msg_);
      used_ += steps;
      last = use_admm ? "newton (from admm)" : "newton (from nsgs)";
      record(last.c_str(), steps, t1, newton_msg_);
      keepBest(s_.trial_, use_admm ? "newton (from admm)" : "newton (from nsgs)");
      if (newton_msg_ == "converged") {
        lam_ = s_.trial_;
        finish("converged (nsgs, newton, admm/nsgs, newton)");
        return;
      }
      if (unresolvable(newton_msg_)) {
        lam_ = s_.trial_;
        finish(newton_msg_ + " (" + last + ")");
        return;
      }
      use_admm = !use_admm;
    }
    // An ADMM state far larger than the best iterate is a direction of divergence: the verdict
    // tests it as an infeasibility certificate.
    if (admm_started_) result_.divergence_candidates.push_back(admm_state_);
    lam_ = s_.best_;
    finish(std::string(outOfTime() ? "time limit reached" : "iteration limit reached") + " after " + last +
           "; returning the best iterate (from " + best_stage_ + ")");
  }

  DefaultSolver& s_;
  const ContactProblem& problem_;
  const SolverSettings& settings_;
  SolverResult& result_;
  Eigen::VectorXd& lam_;
  const int budget_;
  const double tol_;
  const double m_;
  const double switch_after_;
  IterationMonitor budget_clock_;  // the time limit of the whole cascade
  std::string msg_, newton_msg_;
  int used_ = 0;
  double best_res_ = std::numeric_limits<double>::infinity();
  std::string best_stage_ = "initial guess";  // (short: no allocation)
  bool initial_scored_ = false;
  bool admm_started_ = false;
  Eigen::VectorXd admm_state_;
};

void DefaultSolver::iterate(const ContactProblem& problem, const SolverSettings& settings, SolverResult& result) {
  Cascade cascade(*this, problem, settings, result);
  cascade.run(defaultPlan(defaultRuleInput(problem, result.lam, settings)));
}

}  // namespace stiction
