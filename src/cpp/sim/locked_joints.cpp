// Stages 4b and 5 of a time step while the joints' dry friction holds (docs/joint-rows.md, "Joints
// that hold"): the contacts' problem with every friction-row coordinate locked.
//
// The step's problem (eq. 65, impulses P = h lambda) has the contacts' rows C and one friction row per
// locked coordinate, J = [J_C; E] with E selecting the set L of those coordinates, A = J M^-1 J^T and
// u = A P - h b. Write x = M^-1 (J_C^T P_C + E^T P_J) (the velocity change the impulses make). Every
// friction row sticking means u_J = x_L - h b_J = 0, so x_L = h b_J, and M x = J_C^T P_C + E^T P_J read
// on the other coordinates F (E^T P_J has none there) gives
//   x_F = M_FF^-1 (J_CF^T P_C - M_FL x_L),
//   u_C = J_C x - h b_C = A_r P_C - b_r,  A_r = J_CF M_FF^-1 J_CF^T,
//   b_r = h b_C + J_CF M_FF^-1 M_FL x_L - J_CL x_L,
// and the friction impulses follow from M x's rows L: P_J = M_LF x_F + M_LL x_L - J_CL^T P_C. This is
// the Schur complement of eq. 65's equations u_J = 0, done on M (M_FF: the free coordinates only, 6
// for a legged robot's base) rather than on A (whose J rows with the joints' rows would cost as many
// pairs of chains again, robot_delassus.cpp). The contacts' problem (A_r, b_r) is solved to the
// tolerance as any other; when every |P_J| then lies within its bound h tau_c, (P_C, P_J) solves the
// full problem: its contact rows' natural map is the reduced one's, and each friction row has u = 0
// inside its interval (box complementarity holds exactly). The full problem's all-stick family (24 rows
// of rank <= 18 on Solo-12) is then resolved by the reduced solve's own choice from the warm start, a
// solution as exact as the full solver's but not necessarily the same one.
#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>
#include <Eigen/QR>

#include "stages.hpp"

namespace stiction {
namespace stages {

namespace {

// A friction impulse must lie this far inside its bound (relative): its rounding stays inside.
constexpr double kInsideBound = 1e-6;
// After a try whose joints did not hold, the next tries wait 1, 2, 4 ... up to this many steps.
constexpr int kLockedMaxBackoff = 64;

// The reduced problem (A_r, b_r) from M's upper triangle and J (m x nv, column-major), NF the number
// of free coordinates (or Eigen::Dynamic): M_FF = L L^T, Z = L^-1 J_CF^T (column r: contact row r),
// A_r = Z^T Z (its lower triangle, mirrored: exactly symmetric), y = L^-1 M_FL x_L and
// b_r = h b_C + Z^T y - J_CL x_L. Leaves x = [0; x_L] in lk.x. False when M_FF is not positive
// definite or a value is not finite. (Per contact row, its column of Z in registers: on Solo-12 the
// loops over a runtime size of 6 were latency-bound, ~1.5 us for ~1k multiply-adds.)
template <int NF>
bool reducedOperator(LockedJoints& lk, const Eigen::MatrixXd& M, const Eigen::MatrixXd& J, double h,
                     const Eigen::VectorXd& b) {
  using MatF = Eigen::Matrix<double, NF, NF>;
  using VecF = Eigen::Matrix<double, NF, 1>;
  // (NF fixed: the loops over it unroll)
  const Eigen::Index nf = NF == Eigen::Dynamic ? static_cast<Eigen::Index>(lk.free.size()) : NF;
  const Eigen::Index nv = M.rows(), m = J.rows(), mc = static_cast<Eigen::Index>(lk.kept.size());
  const int* F = lk.free.data();
  const int* R = lk.kept.data();  // the rows kept (mc of them: the contacts', then unlocked joints')
  const double* Mp = M.data();
  const double* Jp = J.data();  // J(r, c) at c * m + r
  MatF L(nf, nf);
  for (Eigen::Index j = 0; j < nf; ++j)
    for (Eigen::Index i = j; i < nf; ++i) L(i, j) = F[i] <= F[j] ? Mp[F[j] * nv + F[i]] : Mp[F[i] * nv + F[j]];
  // L L^T in place (lower triangle), with the pivots' reciprocals
  VecF inv(nf);
  for (Eigen::Index j = 0; j < nf; ++j) {
    double d = L(j, j);
    for (Eigen::Index k = 0; k < j; ++k) d -= L(j, k) * L(j, k);
    if (!(d > 0.0)) return false;
    L(j, j) = std::sqrt(d);
    inv[j] = 1.0 / L(j, j);
    for (Eigen::Index i = j + 1; i < nf; ++i) {
      double s = L(i, j);
      for (Eigen::Index k = 0; k < j; ++k) s -= L(i, k) * L(j, k);
      L(i, j) = s * inv[j];
    }
  }
  // Zt = J_CF L^-T (mc x nf by columns: Z = L^-1 J_CF^T transposed), column a of Zt once the columns
  // before it are final: each update runs along the contact rows (independent, vectorized), where a
  // substitution per contact row was one chain of dependent multiply-adds
  lk.z.resize(mc, nf);
  double* Zp = lk.z.data();  // Zt(r, a) at a * mc + r
  for (Eigen::Index a = 0; a < nf; ++a) {
    double* za = Zp + a * mc;
    const double* ja = Jp + F[a] * m;
    for (Eigen::Index r = 0; r < mc; ++r) za[r] = ja[R[r]];
    for (Eigen::Index k = 0; k < a; ++k) {
      const double l = L(a, k);
      const double* zk = Zp + k * mc;
      for (Eigen::Index r = 0; r < mc; ++r) za[r] -= l * zk[r];
    }
    for (Eigen::Index r = 0; r < mc; ++r) za[r] *= inv[a];
  }
  // x = [0; x_L]; y = L^-1 M_FL x_L (M_FL from M's upper triangle)
  lk.x.setZero(nv);
  for (std::size_t i = 0; i < lk.locked_dofs.size(); ++i) lk.x[lk.locked_dofs[i]] = lk.xl[static_cast<Eigen::Index>(i)];
  VecF y(nf);  // M_FL x_L, then L^-1 of it
  y.setZero();
  for (std::size_t i = 0; i < lk.locked_dofs.size(); ++i) {
    const int l = lk.locked_dofs[i];
    const double xl = lk.xl[static_cast<Eigen::Index>(i)];
    for (Eigen::Index a = 0; a < nf; ++a) y[a] += (F[a] <= l ? Mp[l * nv + F[a]] : Mp[F[a] * nv + l]) * xl;
  }
  for (Eigen::Index a = 0; a < nf; ++a) {
    double s = y[a];
    for (Eigen::Index k = 0; k < a; ++k) s -= L(a, k) * y[k];
    y[a] = s * inv[a];
  }
  lk.y = y;
  lk.mff = L;  // (for x_F after the solve)
  // A_r = Zt Zt^T: column c along the rows r (the sum over the nf columns of Zt in registers), then
  // the lower triangle mirrored (exactly symmetric)
  lk.a.resize(mc, mc);
  double* Ap = lk.a.data();
  for (Eigen::Index c = 0; c < mc; ++c) {
    VecF zc(nf);
    for (Eigen::Index a = 0; a < nf; ++a) zc[a] = Zp[a * mc + c];
    double* ac = Ap + c * mc;
    for (Eigen::Index r = c; r < mc; ++r) {  // (the lower triangle)
      double s = 0.0;
      for (Eigen::Index a = 0; a < nf; ++a) s += Zp[a * mc + r] * zc[a];
      ac[r] = s;
    }
  }
  for (Eigen::Index c = 0; c < mc; ++c)
    for (Eigen::Index r = c + 1; r < mc; ++r) Ap[r * mc + c] = Ap[c * mc + r];
  // b_r = h b_R + Z^T y - J_R x (J_R x = J_CL x_L on the contacts' rows, the first; 0 on a kept joint
  // row, whose coordinate is free)
  // (J_CL x_L column by column of J: x is 0 on the free coordinates)
  const Eigen::Index contacts = lk.contact_rows;
  lk.b.resize(mc);
  double* bp = lk.b.data();
  for (Eigen::Index r = 0; r < contacts; ++r) bp[r] = h * b[r];
  for (Eigen::Index r = contacts; r < mc; ++r) bp[r] = h * b[R[r]];
  for (std::size_t i = 0; i < lk.locked_dofs.size(); ++i) {
    const double* jl = Jp + lk.locked_dofs[i] * m;
    const double xl = lk.xl[static_cast<Eigen::Index>(i)];
    for (Eigen::Index r = 0; r < contacts; ++r) bp[r] -= jl[r] * xl;
  }
  for (Eigen::Index a = 0; a < nf; ++a) {  // + Z^T y
    const double* za = Zp + a * mc;
    const double ya = y[a];
    for (Eigen::Index r = 0; r < mc; ++r) bp[r] += za[r] * ya;
  }
  // (x * 0 sums to 0 exactly unless some x is inf or NaN; a non-finite entry of Z reaches A_r's
  // diagonal, its row's sum of squares, which bounds the others: |A_rc| <= sqrt(A_rr A_cc))
  return !std::isnan((lk.a.diagonal().array() * 0.0).sum() + (lk.b.array() * 0.0).sum());
}

// The all-stick answers of the step form a family: forces between sticking feet that move nothing
// (the null space of J_SF^T, S the sticking contacts' rows), which the joints' friction balances. The
// reduced solve picks one from its warm start, not knowing the joints' bounds; this moves P_S along
// that null space to the smallest locked friction impulses, min |P_L - G d|^2 (+ a 1e-10 regulariser),
// G = J_SL^T (M x does not change: J_SF^T d = 0). Kept when every sticking contact stays strictly in its
// cone and the reduced problem's natural map still meets the tolerance; u_R is then recomputed.
bool rebalance(const SimulatorModel& sim, SimulatorData& sd, LockedJoints& lk, double h, double threshold) {
  SolverResult& rr = lk.result;
  const Eigen::MatrixXd& J = sd.work->parts[0].J;
  std::vector<int>& S = lk.sticking_rows;
  std::vector<Eigen::Index>& offsets = lk.sticking_offsets;  // each sticking contact's first row
  S.clear();
  offsets.clear();
  std::vector<std::size_t>& blocks = lk.sticking_blocks;
  blocks.clear();
  Eigen::Index row = 0;
  for (std::size_t blk = 0; blk < sd.out.active.size(); ++blk) {
    const int k = sd.out.candidate_rows[sd.out.active[blk]];
    if (k == 3 && rr.states[blk] == ContactState::kStick) {
      blocks.push_back(blk);
      offsets.push_back(row);
      for (int q = 0; q < k; ++q) S.push_back(static_cast<int>(row + q));
    }
    row += k;
  }
  const auto ms = static_cast<Eigen::Index>(S.size()), nf = static_cast<Eigen::Index>(lk.free.size()),
             nl = static_cast<Eigen::Index>(lk.locked_dofs.size());
  if (ms <= nf) return false;
  Eigen::MatrixXd &N = lk.rb_n, &G = lk.rb_g;
  N.resize(ms, nf);
  G.resize(nl, ms);
  for (Eigen::Index s = 0; s < ms; ++s) {
    for (Eigen::Index a = 0; a < nf; ++a) N(s, a) = J(S[s], lk.free[a]);
    for (Eigen::Index i = 0; i < nl; ++i) G(i, s) = J(S[s], lk.locked_dofs[i]);
  }
  lk.rb_qr.compute(N);
  lk.rb_q = lk.rb_qr.householderQ();
  const auto B = lk.rb_q.rightCols(ms - nf);  // orthogonal to J_SF's columns
  lk.rb_gb.noalias() = G * B;
  lk.rb_h.noalias() = lk.rb_gb.transpose() * lk.rb_gb;
  lk.rb_h.diagonal().array() += 1e-10 * (lk.rb_h.trace() / double(lk.rb_h.rows()) + 1e-300);
  lk.rb_xi.noalias() = lk.rb_gb.transpose() * lk.pj;
  lk.rb_ldlt.compute(lk.rb_h);
  lk.rb_ldlt.solveInPlace(lk.rb_xi);
  lk.rb_d.noalias() = B * lk.rb_xi;
  const Eigen::VectorXd& d = lk.rb_d;
  if (!d.allFinite()) return false;
  Eigen::VectorXd& lam = lk.rb_lam;
  lam = rr.lam;
  for (Eigen::Index s = 0; s < ms; ++s) lam[S[s]] += d[s];
  for (std::size_t c = 0; c < blocks.size(); ++c) {  // strictly inside the cone still
    const Eigen::Index o = offsets[c];
    const double mu = candidateMu(sim, sd.out.active[blocks[c]]);
    if (!(lam[o + 2] > 0.0 && std::hypot(lam[o], lam[o + 1]) < (1.0 - kInsideBound) * mu * lam[o + 2])) return false;
  }
  // the reduced problem's natural map at the new forces
  const double nm = residual(*lk.problem, lam) * (1.0 + lk.problem->bNorm());
  if (!(nm <= 0.5 * threshold)) return false;
  rr.lam = lam;
  lk.delassus->multiply(rr.lam, rr.u);
  rr.u -= lk.problem->b();
  return true;
}

bool missed(LockedJoints& lk) {
  lk.backoff = std::min(kLockedMaxBackoff, 2 * lk.backoff + 1);
  lk.skip = lk.backoff;
  return false;
}

}  // namespace

bool solveJointsLocked(const SimulatorModel& sim, SimulatorData& sd, double h, Stopwatch& watch) {
  SimulatorWorkspace& w = *sd.work;
  LockedJoints& lk = w.locked;
  lk.pending_full = false;
  if (!lk.held) return false;
  if (lk.skip > 0) {
    --lk.skip;
    return false;
  }
  const std::vector<JointRow>& joint_rows = sd.out.joint_rows;
  const auto nj = static_cast<Eigen::Index>(joint_rows.size());
  const Eigen::Index m = sd.out.rows, mc = m - nj;
  if (nj == 0 || mc <= 0 || !sim.anchors.empty() || sim.systems.size() != 1 || sim.systems[0].free_body ||
      sim.systems[0].pinocchio_passes || !w.solver->exactLaw() || !wholeWorldPart(sim, sd))
    return false;
  const SystemWork& part = w.parts[0];
  const Eigen::MatrixXd& M = part.data.M;
  const Eigen::MatrixXd& J = part.J;  // m x nv
  const Eigen::Index nv = J.cols();
  if (J.rows() != m || M.rows() != nv) return false;
  // A coordinate whose only row is its dry friction is locked; every other joint row stays a row of
  // the reduced problem (a limit, the friction of a joint on its limit), on the coordinates left free.
  // (Classified again when the rows change.)
  if (lk.contact_rows != mc || lk.classified != joint_rows) {
    lk.rows_on.assign(static_cast<std::size_t>(nv), 0);
    for (const JointRow& r : joint_rows) ++lk.rows_on[static_cast<std::size_t>(r.dof)];
    lk.locked.assign(static_cast<std::size_t>(nv), 0);
    lk.kept.clear();
    lk.locked_rows.clear();
    lk.locked_dofs.clear();
    lk.contact_rows = -1;
    for (Eigen::Index r = 0; r < mc; ++r) lk.kept.push_back(static_cast<int>(r));
    for (Eigen::Index k = 0; k < nj; ++k) {
      const JointRow& r = joint_rows[static_cast<std::size_t>(k)];
      if (r.kind == JointRowKind::kEffort) return false;  // (its compliance joins A after the Delassus stage)
      if (r.kind == JointRowKind::kFriction && lk.rows_on[static_cast<std::size_t>(r.dof)] == 1) {
        lk.locked[static_cast<std::size_t>(r.dof)] = 1;
        lk.locked_rows.push_back(static_cast<int>(k));
        lk.locked_dofs.push_back(r.dof);
      } else {
        lk.kept.push_back(static_cast<int>(mc + k));
      }
    }
    lk.free.clear();
    for (int i = 0; i < nv; ++i)
      if (!lk.locked[static_cast<std::size_t>(i)]) lk.free.push_back(i);
    lk.contact_rows = mc;
    lk.classified = joint_rows;
  }
  const auto nl = static_cast<Eigen::Index>(lk.locked_rows.size());
  if (nl == 0) return false;
  const auto nf = static_cast<Eigen::Index>(lk.free.size());
  if (nf == 0) return false;
  const auto mr = static_cast<Eigen::Index>(lk.kept.size());
  lk.xl.resize(nl);
  for (Eigen::Index i = 0; i < nl; ++i) lk.xl[i] = h * sd.out.b[mc + lk.locked_rows[static_cast<std::size_t>(i)]];
  // (a floating base's 6 free coordinates: sizes known to the compiler, the loops unrolled)
  const bool built = nf == 6 ? reducedOperator<6>(lk, M, J, h, sd.out.b)
                             : reducedOperator<Eigen::Dynamic>(lk, M, J, h, sd.out.b);
  if (!built) return false;  // (M_FF not positive definite, or a non-finite value: the full path says)
  watch.lap(sd.out.timings.delassus);

  // The reduced problem: its operator updated in place while the contacts and joint rows are the same
  if (!lk.problem || lk.active != sd.out.active || lk.joint_rows != joint_rows) {
    std::vector<Constraint> cons;
    appendContactConstraints(sim, sd, cons);
    for (Eigen::Index r = mc; r < mr; ++r)
      cons.push_back(jointRowConstraint(sim, sd, static_cast<std::size_t>(lk.kept[static_cast<std::size_t>(r)] - mc), h));
    lk.delassus = std::make_shared<DenseDelassus>(lk.a);
    lk.problem = std::make_unique<ContactProblem>(lk.delassus, lk.b, std::move(cons), 1e-6, false);
    lk.active = sd.out.active;
    lk.joint_rows = joint_rows;
  } else {
    lk.delassus->matrix() = lk.a;
    lk.problem->setB(lk.b);
  }
  if (!lk.solver) {
    FormulationSettings fs = sim.settings.formulation_settings;
    fs.exact_solver = sim.settings.solver;
    lk.solver = makeFormulation(sim.settings.formulation, fs);
  }
  SolverSettings settings = sim.settings.solver_settings;
  settings.measure_exact_law = false;
  const bool any = stepGuess(sim, sd, h, /*exact=*/true);
  lk.guess.resize(mr);
  for (Eigen::Index r = 0; r < mr; ++r) lk.guess[r] = w.guess[lk.kept[static_cast<std::size_t>(r)]];
  settings.warm_start = sim.settings.warm_start && any ? WarmStart::kGiven : WarmStart::kNone;
  solve(*lk.problem, *lk.solver, settings, lk.result, &lk.guess);
  SolverResult& rr = lk.result;
  // Judged against the full problem's b: its natural map is the reduced one's (u_J = 0)
  const double full_b = h * sd.out.b.norm();
  const double full_scale = full_b > 0.0 ? full_b : 1.0;
  const double reduced_scale = stoppingScale(*lk.problem);
  const double natural_map = rr.relative_residual * reduced_scale, bound = rr.residual_bound * reduced_scale;
  if (!rr.converged || !(natural_map + bound <= settings.tolerance * full_scale)) {
    watch.lap(sd.out.timings.solve);
    return missed(lk);
  }
  // x_F = L^-T (Z P_R - y) (L^T x_F = Z P_R - y, L from M_FF's factor kept in lk.mff); x = [x_F; x_L]
  // is M^-1 J^T P (the integration's velocity change); P_L = (M x - J_R^T P_R)_L
  const int* F = lk.free.data();
  const auto lockedImpulses = [&]() {
    lk.xf.noalias() = lk.z.transpose() * rr.lam;
    lk.xf -= lk.y;
    for (Eigen::Index a = nf - 1; a >= 0; --a) {
      double s = lk.xf[a];
      for (Eigen::Index k = a + 1; k < nf; ++k) s -= lk.mff(k, a) * lk.xf[k];
      lk.xf[a] = s / lk.mff(a, a);
    }
    for (Eigen::Index a = 0; a < nf; ++a) lk.x[F[a]] = lk.xf[a];
    // P_L = M_L. x - J_CL^T P_C, per locked coordinate l (M's row l from its upper triangle: column l
    // above the diagonal, row l after it). A kept joint row's coordinate is free: its J row is 0 on
    // L. (Only the locked rows of M x and J^T P: Eigen's symmetric product and J^T P over every
    // coordinate cost ~0.15 us more on Solo-12.)
    const double* Mp = M.data();
    const double* Jp = J.data();
    const double* xp = lk.x.data();
    const double* lam = rr.lam.data();
    const Eigen::Index contacts = lk.contact_rows;
    lk.pj.resize(nl);
    bool inside = true;
    for (Eigen::Index i = 0; i < nl; ++i) {
      const int dof = lk.locked_dofs[static_cast<std::size_t>(i)];
      const double* mcol = Mp + dof * nv;  // M(0..dof, dof)
      double s = 0.0;
      for (Eigen::Index j = 0; j <= dof; ++j) s += mcol[j] * xp[j];
      for (Eigen::Index j = dof + 1; j < nv; ++j) s += Mp[j * nv + dof] * xp[j];
      const double* jl = Jp + dof * m;  // J(0..contacts, dof)
      for (Eigen::Index r = 0; r < contacts; ++r) s -= jl[r] * lam[r];
      lk.pj[i] = s;
      inside = inside && std::abs(s) <= (1.0 - kInsideBound) * h * sim.joint_friction[dof];
    }
    return inside;
  };
  // each locked row's friction within its bound; else the sticking contacts' internal forces chosen
  // for the smallest friction torques (rebalance), and checked again
  bool rebalanced = false;
  if (!lockedImpulses() &&
      !((rebalanced = rebalance(sim, sd, lk, h, settings.tolerance * full_scale)) && lockedImpulses())) {
    watch.lap(sd.out.timings.solve);
    return missed(lk);
  }
  lk.backoff = 0;
  // The full problem's result: the kept rows' from the reduced solve, the locked rows sticking (u = 0)
  SolverResult& r = sd.out.result;
  const std::size_t contact_blocks = sd.out.active.size();
  r.resize(m, contact_blocks + static_cast<std::size_t>(nj));
  for (Eigen::Index k = 0; k < mr; ++k) {
    r.lam[lk.kept[static_cast<std::size_t>(k)]] = rr.lam[k];
    r.u[lk.kept[static_cast<std::size_t>(k)]] = rr.u[k];
  }
  for (Eigen::Index i = 0; i < nl; ++i) {
    r.lam[mc + lk.locked_rows[static_cast<std::size_t>(i)]] = lk.pj[i];
    r.u[mc + lk.locked_rows[static_cast<std::size_t>(i)]] = 0.0;
  }
  std::copy(rr.states.begin(), rr.states.begin() + static_cast<std::ptrdiff_t>(contact_blocks), r.states.begin());
  for (std::size_t k = 0, kept = contact_blocks; k < static_cast<std::size_t>(nj); ++k) {
    const std::size_t blk = contact_blocks + k;
    if (lk.locked[static_cast<std::size_t>(joint_rows[k].dof)] != 0) {
      r.states[blk] = ContactState::kStick;
      continue;
    }
    r.states[blk] = rr.states[kept++];
    // a kept box row that slips holds its bound exactly (as solveContacts sets it)
    const Constraint c = jointRowConstraint(sim, sd, k, h);
    const Eigen::Index row = mc + static_cast<Eigen::Index>(k);
    if (c.kind == ConstraintKind::kBox && r.states[blk] == ContactState::kSlip) r.lam[row] = r.u[row] < 0.0 ? c.upper : c.lower;
  }
  r.iterations = rr.iterations;
  r.converged = true;
  r.status = SolveStatus::kConverged;
  r.relative_residual = natural_map / full_scale;
  r.residual = natural_map / (1.0 + full_b);
  r.residual_bound = bound / full_scale;
  r.precision_floor = rr.precision_floor * reduced_scale / full_scale;
  r.lambda_norm = r.lam.norm();
  r.min_solution_norm = 0.0;
  r.implicated_blocks.clear();
  r.divergence_candidates.clear();
  r.seconds = rr.seconds;
  r.warm_start_seconds = rr.warm_start_seconds;
  r.warm_start_iterations = rr.warm_start_iterations;
  // (swapped and assigned: no allocation once the strings have grown)
  std::swap(r.stages, lk.result.stages);
  r.solver.assign(rr.solver);
  r.message.assign(rr.message).append(rebalanced ? " (joints locked: their dry friction holds; rebalanced)"
                                                  : " (joints locked: their dry friction holds)");
  r.own_converged = true;
  r.own_residual = r.relative_residual;
  r.own_law.assign(rr.own_law);
  r.exact_law_measured = false;
  // (integration's M^-1 J^T P: x above; the chains' Y not built)
  sd.out.sparse = false;
  w.robot_chains = false;
  w.a_in_operator = false;
  lk.pending_full = true;
  lk.sim = &sim;
  lk.scale = h;
  recordSolution(sim, sd, h, r.iterations);
  watch.lap(sd.out.timings.solve);
  return true;
}

}  // namespace stages

void completeLockedStep(const SimulatorData& data) {
  LockedJoints& lk = data.work->locked;
  if (!lk.pending_full) return;
  // (the step's own data, whose A was left for later: built now from that step's J, M and b)
  SimulatorData& sd = const_cast<SimulatorData&>(data);
  const SimulatorModel& sim = *lk.sim;
  stages::delassusOperator(sim, sd);  // (clears pending_full)
  stages::setStepProblem(sim, sd, lk.scale);
}

}  // namespace stiction
