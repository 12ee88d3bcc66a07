// Stage 4, the Delassus stage: the mass matrix and its factor, the free acceleration,
// then the contact problem's A = J M^-1 J^T (eq. 22) and b (eq. 27).
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <sstream>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>

#include <Eigen/SVD>

#include "stiction/vector_kernels.hpp"
#ifdef STICTION_X86_KERNELS
#include <immintrin.h>
#endif

#include <pinocchio/algorithm/cholesky.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>
#include <pinocchio/algorithm/rnea.hpp>

#include "stages.hpp"

namespace stiction {

void computeControl(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                    const Eigen::VectorXd& v) {
  sd.out.tau.resize(sim.model.nv);
  const JointControl& c = sd.control;
  const int nv = sim.model.nv;
  if (c.kp.size() != nv || c.kd.size() != nv || c.v_target.size() != nv || c.tau_ff.size() != nv ||
      c.q_target.size() != sim.model.nq)
    throw std::invalid_argument("control: kp, kd, v_target, tau_ff need nv = " + std::to_string(nv) +
                                " entries and q_target nq = " + std::to_string(sim.model.nq));
  // q_target (-) q on the manifold, where a stiffness uses it: a vector-space joint's is
  // q_target - q (as Pinocchio's difference), a joint without stiffness (a robot's free base: its
  // log6 was most of Pinocchio's difference) contributes kp dv = 0; else Pinocchio's difference.
  const pinocchio::Model& model = sim.model;
  const auto vector_space = [&](pinocchio::JointIndex j) { return sim.tree[j].kind != TreeJoint::Kind::kFreeFlyer; };
  bool direct = !sim.tree.empty();
  for (pinocchio::JointIndex j = 1; direct && j < static_cast<pinocchio::JointIndex>(model.njoints); ++j)
    direct = vector_space(j) || c.kp.segment(model.idx_vs[j], model.nvs[j]).isZero(0.0);
  if (direct) {
    sd.work->dv.resize(nv);
    for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j) {
      const int iv = model.idx_vs[j], iq = model.idx_qs[j], n = model.nvs[j];
      for (int k = 0; k < n; ++k) sd.work->dv[iv + k] = vector_space(j) ? c.q_target[iq + k] - q[iq + k] : 0.0;
    }
  } else {
    pinocchio::difference(model, q, c.q_target, sd.work->dv);
  }
  sd.out.tau = c.kp.cwiseProduct(sd.work->dv) + c.kd.cwiseProduct(c.v_target - v) + c.tau_ff;
}

namespace stages {

namespace {

// nle for one free flyer, whose motion subspace is the identity in its own frame: nle is
// the force of rnea's backward pass in that frame, Y a_gf + v x* (Y v) (freeBodyKinematics fills
// no joint Jacobian to rotate it with).
void freeBodyNonLinearEffects(const pinocchio::Model& model, const pinocchio::Data& data, Eigen::VectorXd& nle) {
  const pinocchio::SE3& oMi = data.oMi[1];
  const pinocchio::Motion a_gf(data.a[1].linear() - oMi.rotation().transpose() * model.gravity.linear(),
                               data.a[1].angular());
  const pinocchio::Inertia& Y = model.inertias[1];
  const pinocchio::Force f = Y * a_gf + data.v[1].cross(Y * data.v[1]);
  nle.resize(6);
  nle.head<3>() = f.linear();
  nle.tail<3>() = f.angular();
}

// x = M^-1 x for a free body (6 coordinates): Pinocchio's cholesky::solve (U^-1, D^-1, U^-T with
// its factor M = U D U^T) in fixed-size loops. (The generic tree solve, twice a step per body, was
// 4 % of a 256-box tower's step.)
void freeBodyMassSolve(const pinocchio::Data& data, double* x) {
  const Eigen::MatrixXd& U = data.U;
  for (int i = 4; i >= 0; --i)
    for (int j = i + 1; j < 6; ++j) x[i] -= U(i, j) * x[j];
  for (int i = 0; i < 6; ++i) x[i] *= data.Dinv[i];
  for (int i = 0; i < 5; ++i)
    for (int j = i + 1; j < 6; ++j) x[j] -= U(i, j) * x[i];
}

// A free body's S = D^-1/2 U^-1 from its factor M = U D U^T (W = S J^T, delassusFactors).
void freeBodyScaling(SystemWork& w) {
  const Eigen::Matrix<double, 6, 6> U = w.data.U;
  const Eigen::Matrix<double, 6, 6> U_inverse =
      U.triangularView<Eigen::UnitUpper>().solve(Eigen::Matrix<double, 6, 6>::Identity());
  w.free_body_scaling_diagonal = true;
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) {
      w.free_body_scaling[6 * i + j] = j >= i ? std::sqrt(w.data.Dinv[i]) * U_inverse(i, j) : 0.0;
      if (j != i && w.free_body_scaling[6 * i + j] != 0.0) w.free_body_scaling_diagonal = false;
    }
}

// x = M^-1 x for one part.
void partMassSolve(const SystemModel& part, pinocchio::Data& data, Eigen::VectorXd& x) {
  if (part.free_body)
    freeBodyMassSolve(data, x.data());
  else if (part.pinocchio_passes)
    pinocchio::cholesky::solve(part.model, data, x);
  else
    treeSolve(part, data, x);
}

// The message of a mass matrix that is not positive definite: where (robot, part, the first
// coordinate whose pivot failed, in the factor's order: from the last) and the usual causes.
std::string notPositiveDefinite(const std::string& robot, const SystemModel& part, const pinocchio::Data& data) {
  const pinocchio::Model& model = part.model;
  Eigen::Index k = model.nv - 1;
  while (k > 0 && data.D[k] > 0.0) --k;
  std::string joint = "?";
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j)
    if (k >= model.idx_vs[j] && k < model.idx_vs[j] + model.nvs[j]) joint = model.names[j];
  std::ostringstream os;
  os << "the mass matrix of " << (robot.empty() ? std::string("the model") : "robot '" + robot + "'")
     << " (part '" << model.name << "') is not positive definite at this configuration: pivot " << data.D[k]
     << " at its velocity coordinate " << k << " (joint '" << joint
     << "'). Usual causes: a massless link (mass 0 and no rotational inertia), so that a joint's subtree has no "
        "inertia about its axis (a massless end effector, a point mass on the joint's axis), "
        "with zero armature on that joint; give the links mass and inertia, or the joint an armature "
        "(model.armature)";
  return os.str();
}

// M of one part (a robot's: already from this step's kinematics, compositeBackwardPass; a free
// body's: crba), h kd + h^2 kp on its diagonal for an implicit PD over h > 0, and its factor
// M = U D U^T, in w.data. Throws when M is not positive definite.
void factorMass(const std::string& robot, const SimulatorModel& sim, const SystemModel& part, SystemWork& w,
                const JointControl& control, const std::vector<char>& effort_row, double implicit_pd_step) {
  const pinocchio::Model& model = part.model;
  // q as Eigen::Ref: the instantiation libpinocchio ships (extern template), not a fresh one
  // here (a VectorXd argument made this file take 55 s to compile instead of 14 s).
  // (freeBodyKinematics fills no joint Jacobian; rigid_body_passes "pinocchio": Pinocchio's M)
  if (part.free_body || part.pinocchio_passes)
    pinocchio::crba(model, w.data, Eigen::Ref<const Eigen::VectorXd>(w.q), pinocchio::Convention::LOCAL);
  if (implicit_pd_step > 0.0) {
    // Implicit joint PD over a step h: tau(q+, v+) ~ kp (q_t - q - h v+) + kd (v_t - v+)
    // moves h kd + h^2 kp onto M's diagonal (stable for any gains; MuJoCo's implicitfast
    // does the damping part). The -h kp v part of tau is added above. An actuator with an effort
    // row keeps its PD in the row instead (its compliance, joint_rows.cpp); the joint's viscous
    // damping -d v+ adds h d.
    const double h = implicit_pd_step;
    for (Eigen::Index k = 0; k < model.nv; ++k) {
      const int world = part.v_index[k];
      if (!effort_row[static_cast<std::size_t>(world)]) w.data.M(k, k) += h * control.kd[world] + h * h * control.kp[world];
      w.data.M(k, k) += h * sim.joint_damping[world];
    }
  }
  // M = U D U^T by Pinocchio's tree-sparse Cholesky (cheaper than a dense LLT)
  if (part.free_body || part.pinocchio_passes)
    pinocchio::cholesky::decompose(model, w.data);
  else
    treeDecompose(part, w.data);
  if (model.nv > 0 && !(w.data.D.minCoeff() > 0.0)) throw std::runtime_error(notPositiveDefinite(robot, part, w.data));
}

// The coordinates J's rows can move: its nonzero columns and all their ancestors (Pinocchio's
// parents_fromRow: the previous coordinate on the path to the root). M^-1 J^T vanishes
// outside them, and U^-1 restricted to them is exact: U(i, j) != 0 only for j in i's subtree,
// and no descendant of a coordinate outside the set is inside it. True when they are few
// enough (under 3/4 of the part's) for the restricted products to pay.
bool contactSupport(const pinocchio::Data& data, SystemWork& w) {
  const Eigen::Index nv = w.J.cols();
  w.in_support.assign(static_cast<std::size_t>(nv), 0);
  for (Eigen::Index k = nv - 1; k >= 0; --k) {
    if (w.in_support[k] || !(w.J.col(k).array() != 0.0).any()) continue;
    for (int j = static_cast<int>(k); j >= 0 && !w.in_support[j]; j = data.parents_fromRow[j]) w.in_support[j] = 1;
  }
  w.support.clear();
  for (Eigen::Index k = 0; k < nv; ++k)
    if (w.in_support[k]) w.support.push_back(static_cast<int>(k));
  return 4 * w.support.size() < 3 * static_cast<std::size_t>(nv);
}

}  // namespace

void freeDynamics(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v, double implicit_pd_step) {
  // (sd.out.tau: the control torque at (q, v), selectJointRows's)
  // The joints' generalized force: the control torque, but an actuator with an effort row acts through
  // its row; the implicit PD's -h kp v part (factorMass) and the viscous damping -d v.
  const std::vector<char>& effort_row = sd.work->effort_row;
  for (int dof : sim.effort_dofs)
    if (effort_row[static_cast<std::size_t>(dof)]) sd.out.tau[dof] = 0.0;
  if (implicit_pd_step > 0.0)
    for (Eigen::Index i = 0; i < sd.out.tau.size(); ++i)
      if (!effort_row[static_cast<std::size_t>(i)]) sd.out.tau[i] -= implicit_pd_step * sd.control.kp[i] * v[i];
  if (!sim.joint_damping.isZero(0.0)) sd.out.tau -= sim.joint_damping.cwiseProduct(v);
  for (std::size_t s = 0; s < sim.systems.size(); ++s) {
    const SystemModel& part = sim.systems[s];
    const pinocchio::Model& model = part.model;
    SystemWork& w = sd.work->parts[s];
    // A free body without joint PD: its mass matrix in its own frame is constant (factored at
    // the first step). Else M (a robot's from stage 1's terms, a free body's by crba) and the
    // tree Cholesky every step.
    bool pd_on_diagonal = false;
    if (implicit_pd_step > 0.0)
      for (int world : part.v_index)
        pd_on_diagonal = pd_on_diagonal || sd.control.kd[world] != 0.0 || sd.control.kp[world] != 0.0 ||
                         sim.joint_damping[world] != 0.0;
    const bool reuse = part.free_body && w.mass_factored && !pd_on_diagonal;
    w.mass_factored = part.free_body && !pd_on_diagonal;
    if (part.pinocchio_passes)  // (M by crba in factorMass)
      w.nle = pinocchio::nonLinearEffects(model, w.data, Eigen::Ref<const Eigen::VectorXd>(w.q),
                                          Eigen::Ref<const Eigen::VectorXd>(w.v));
    else if (!part.free_body)
      compositeBackwardPass(part, w.data, w.nle);  // M and nle (stage 1's terms)
    if (!reuse) {
      factorMass(sim.model.name, sim, part, w, sd.control, sd.work->effort_row, implicit_pd_step);
      w.has_free_body_scaling = part.free_body;
      if (part.free_body) freeBodyScaling(w);
    }
    if (part.free_body) freeBodyNonLinearEffects(model, w.data, w.nle);
    gatherV(part, sd.out.tau, w.tau);
    w.v_free = w.tau - w.nle;
    partMassSolve(part, w.data, w.v_free);  // M^-1 (tau - nle): the free acceleration
    scatterV(part, w.nle, sd.out.nle);
    scatterV(part, w.v_free, sd.work->v_free);
  }
}

namespace {

// A part's share of A, dense: A_s = W_s^T W_s (W_s: its scaled rows, delassusFactors).
void partOperator(SystemWork& w) {
  const auto n = static_cast<Eigen::Index>(w.rows.size());
  w.A.resize(n, n);
  if (n == 0) return;
  if (w.W.rows() == 6) {
    // a free body's contacts (a cube's 4 corners: 12 rows x 6; a tower's box, 24): one fixed-size
    // 6-term dot product per entry of the lower triangle, mirrored (exactly symmetric; Eigen's
    // dynamic-size coefficient-wise product spent most of its time in loop set-up at this size)
    const Eigen::Map<const Eigen::Matrix<double, 6, Eigen::Dynamic>> W6(w.W.data(), 6, n);
    for (Eigen::Index c = 0; c < n; ++c) {
      const Eigen::Matrix<double, 6, 1> wc = W6.col(c);
      for (Eigen::Index r = c; r < n; ++r) w.A(r, c) = w.A(c, r) = W6.col(r).dot(wc);
    }
  } else if (w.W.rows() <= 6) {
    // (robots keep the rank update below: TALOS's 24 x 44 was 5 us slower coefficient-wise)
    w.A.noalias() = w.W.transpose().lazyProduct(w.W);
  } else if (n <= 32) {
    // a robot's few contacts (Solo-12: 12 rows of 18 coordinates): a dot product of W's contiguous
    // columns per entry of the lower triangle, mirrored (Eigen's rank update, blocked for large
    // matrices, spent ~8k instructions on Solo-12's 12 x 12)
    for (Eigen::Index c = 0; c < n; ++c)
      for (Eigen::Index r = c; r < n; ++r) w.A(r, c) = w.A(c, r) = w.W.col(r).dot(w.W.col(c));
  } else {
    w.A.setZero();
    w.A.selfadjointView<Eigen::Lower>().rankUpdate(w.W.transpose());
    w.A.triangularView<Eigen::StrictlyUpper>() = w.A.transpose();
  }
}

// W = D^-1/2 U^-1 X^T for U unit upper triangular (its strict upper triangle read) and X = J's
// columns (those of the coordinates W covers): X's columns are W's rows, contiguous, so the back
// substitution is column operations on X, from the last, skipping U's zeros (Pinocchio's U is
// tree-sparse: U(i, j) != 0 only for j in i's subtree, so a leg's rows take only that leg's), then
// one scaled transposition. (Eigen's blocked triangular solve on W spent ~13k instructions on
// Solo-12's 18 x 12; row operations on W, strided, as many.)
void scaledUnitUpperSolve(const Eigen::MatrixXd& U, const double* dinv, const std::vector<int>* index,
                          Eigen::MatrixXd& X, Eigen::MatrixXd& W) {
  const Eigen::Index s = X.cols();
  for (Eigen::Index i = s - 2; i >= 0; --i)
    for (Eigen::Index j = i + 1; j < s; ++j) {
      const double u = U(i, j);
      if (u != 0.0) X.col(i) -= u * X.col(j);
    }
  W.resize(s, X.rows());
  for (Eigen::Index i = 0; i < s; ++i)
    W.row(i) = std::sqrt(dinv[index != nullptr ? (*index)[static_cast<std::size_t>(i)] : i]) * X.col(i).transpose();
}

// W_s = D^-1/2 U^-1 J_s^T for every part, so that A = sum_s W_s^T W_s (symmetric by construction);
// returns the entries of the parts' dense shares, sum of n_s^2.
Eigen::Index delassusFactors(SimulatorData& sd) {
  Eigen::Index entries = 0;
  for (SystemWork& w : sd.work->parts) {
    const auto n = static_cast<Eigen::Index>(w.rows.size());
    entries += n * n;
    if (n == 0) continue;
    if (w.J.cols() > 6 && contactSupport(w.data, w)) {
      // A robot touching with a few limbs (TALOS's two soles: base and legs, 18 of 38
      // coordinates): the triangular solve on those coordinates only.
      const auto s = static_cast<Eigen::Index>(w.support.size());
      w.U_support.resize(s, s);
      w.X.resize(n, s);
      for (Eigen::Index c = 0; c < s; ++c) {
        for (Eigen::Index r = 0; r < c; ++r) w.U_support(r, c) = w.data.U(w.support[r], w.support[c]);
        w.X.col(c) = w.J.col(w.support[c]);
      }
      scaledUnitUpperSolve(w.U_support, w.data.Dinv.data(), &w.support, w.X, w.W);
      // (W has more rows than 6: partOperator's rank update, as for any robot)
      continue;
    }
    if (w.has_free_body_scaling && w.J.cols() == 6) {
      // A free body: W = S J^T column by column from its constant S (upper triangular), W^T for the
      // vector kernel in the same pass. With a diagonal mass matrix (a box), S's zeros keep each
      // value exactly sqrt(D_k^-1) J_ck, as the row operations and scaling gave.
      const bool transposed = vectorKernels();
      w.W.resize(6, n);
      if (transposed) w.Wt.resize(static_cast<std::size_t>(6 * n + 4));
      const double* J = w.J.data();  // column-major n x 6
      const Eigen::Map<const Eigen::Matrix<double, 6, 6, Eigen::RowMajor>> S(w.free_body_scaling.data());
      double* Wt = transposed ? w.Wt.data() : nullptr;
      if (w.free_body_scaling_diagonal) {
        // (a box, a sphere: its centre of mass at its origin) row k of W is column k of J scaled
        double* W = w.W.data();
        for (int k = 0; k < 6; ++k) {
          const double scale = S(k, k);
          const double* column = J + k * n;
          for (Eigen::Index c = 0; c < n; ++c) W[6 * c + k] = scale * column[c];
          if (Wt != nullptr)
            for (Eigen::Index c = 0; c < n; ++c) Wt[k * n + c] = scale * column[c];
        }
        if (Wt != nullptr) std::fill(w.Wt.end() - 4, w.Wt.end(), 0.0);
        continue;
      }
      for (Eigen::Index c = 0; c < n; ++c) {
        Eigen::Matrix<double, 6, 1> jc;
        for (int l = 0; l < 6; ++l) jc[l] = J[c + l * n];
        const Eigen::Matrix<double, 6, 1> wc = S * jc;
        w.W.col(c) = wc;
        if (Wt != nullptr)
          for (int k = 0; k < 6; ++k) Wt[k * n + c] = wc[k];
      }
      if (transposed) std::fill(w.Wt.end() - 4, w.Wt.end(), 0.0);
      continue;
    }
    w.X = w.J;
    scaledUnitUpperSolve(w.data.U, w.data.Dinv.data(), nullptr, w.X, w.W);
    if (w.W.rows() == 6 && vectorKernels()) {
      // W^T by columns (row k of W contiguous), padded: the vector kernel of assembleFromPlan reads
      // a block's three values of row k four at a time (written here, while W is in cache)
      w.Wt.resize(static_cast<std::size_t>(6 * n + 4));
      for (Eigen::Index k = 0; k < 6; ++k)
        for (Eigen::Index c = 0; c < n; ++c) w.Wt[static_cast<std::size_t>(k * n + c)] = w.W(k, c);
      std::fill(w.Wt.end() - 4, w.Wt.end(), 0.0);
    }
  }
  return entries;
}

#ifdef STICTION_X86_KERNELS
// The free-body blocks of assembleFromPlan with AVX2 and FMA (chosen at run time: the module is
// built for any x86-64). Raw pointers and intrinsics only: no Eigen code is compiled for these
// instructions, so no template meets the rest of the binary compiled twice (docs/development.md,
// "No -march=native"). Column c of a block is sum_k W_i[k, :] W_j[k, c] (row k of W_i, three
// values of W^T's column k, one fused multiply-add per k); its mirror's row r the same products
// in the same order, so A stays exactly symmetric.
__attribute__((target("avx2,fma"))) bool freeBodyBlocksAvx2(const AssemblyBlock* blocks, std::size_t count,
                                                            const double* const* wt, const int* stride,
                                                            double* value) {
  // x * 0 is 0 for finite x, NaN for inf and NaN: their sum tells whether every value written is
  // finite (solveContacts then need not read A again to check). Lane 3 is not a value: masked.
  const __m256d zero_lane3 = _mm256_castsi256_pd(_mm256_set_epi64x(0, -1, -1, -1));
  __m256d finite = _mm256_setzero_pd();
  // three lanes: two and one (a masked store is microcoded on some processors: it was most of this loop)
  const auto store3 = [](double* to, __m256d v) __attribute__((target("avx2,fma"))) {
    _mm_storeu_pd(to, _mm256_castpd256_pd128(v));
    _mm_store_sd(to + 2, _mm256_extractf128_pd(v, 1));
  };
  for (std::size_t b = 0; b < count; ++b) {
    const AssemblyBlock& e = blocks[b];
    if (!e.free_bodies) continue;
    const bool mirror = e.mirror[0] >= 0;
    __m256d col0 = _mm256_setzero_pd(), col1 = col0, col2 = col0, row0 = col0, row1 = col0, row2 = col0;
    for (int p = 0; p < 2 && e.part[p] >= 0; ++p) {
      const int n = stride[e.part[p]];
      const double* ti = wt[e.part[p]] + e.row[p];
      const double* tj = wt[e.part[p]] + e.col[p];
      for (int k = 0; k < 6; ++k, ti += n, tj += n) {
        const __m256d wi = _mm256_loadu_pd(ti);  // W_i[k, 0..2] (and one value past: unused)
        col0 = _mm256_fmadd_pd(wi, _mm256_broadcast_sd(tj), col0);
        col1 = _mm256_fmadd_pd(wi, _mm256_broadcast_sd(tj + 1), col1);
        col2 = _mm256_fmadd_pd(wi, _mm256_broadcast_sd(tj + 2), col2);
        if (mirror) {
          const __m256d wj = _mm256_loadu_pd(tj);
          row0 = _mm256_fmadd_pd(wj, _mm256_broadcast_sd(ti), row0);
          row1 = _mm256_fmadd_pd(wj, _mm256_broadcast_sd(ti + 1), row1);
          row2 = _mm256_fmadd_pd(wj, _mm256_broadcast_sd(ti + 2), row2);
        }
      }
    }
    store3(value + e.position[0], col0);
    store3(value + e.position[1], col1);
    store3(value + e.position[2], col2);
    if (mirror) {
      store3(value + e.mirror[0], row0);
      store3(value + e.mirror[1], row1);
      store3(value + e.mirror[2], row2);
    }
    // (a mirror's values are the block's, transposed: the block alone decides)
    const __m256d block = _mm256_add_pd(_mm256_add_pd(col0, col1), col2);
    finite = _mm256_add_pd(finite, _mm256_and_pd(_mm256_mul_pd(block, _mm256_setzero_pd()), zero_lane3));
  }
  alignas(32) double lanes[4];
  _mm256_store_pd(lanes, finite);
  return !std::isnan((lanes[0] + lanes[1]) + (lanes[2] + lanes[3]));
}

#endif

// The sparse A's values straight from the parts' W (the plan, sd.work->assembly, listed when the pattern
// was last assembled): each block of the lower triangle (a pair of contacts, or anchors) is the
// product of its two blocks' columns of W in the one or two parts both belong to, written with its
// mirror, three values at a time. (The parts' dense shares summed into place entry by entry cost
// twice that: a quarter of a 256-contact tower's step went to the scattered sums.) True when the
// vector kernel wrote every value and found them all finite (solveContacts' check, 2 % of a
// 1024-contact tower's step, is then done).
bool assembleFromPlan(SimulatorData& sd, double* value) {
  sd.work->part_w.resize(sd.work->parts.size());
  for (std::size_t s = 0; s < sd.work->parts.size(); ++s) sd.work->part_w[s] = sd.work->parts[s].W.data();
  bool known_finite = false;
#ifdef STICTION_X86_KERNELS
  const bool vector = vectorKernels();
  if (vector) {
    sd.work->part_wt.resize(sd.work->parts.size());
    sd.work->part_stride.resize(sd.work->parts.size());
    for (std::size_t s = 0; s < sd.work->parts.size(); ++s) {
      sd.work->part_wt[s] = sd.work->parts[s].Wt.data();
      sd.work->part_stride[s] = static_cast<int>(sd.work->parts[s].rows.size());
    }
    known_finite =
        freeBodyBlocksAvx2(sd.work->assembly.data(), sd.work->assembly.size(), sd.work->part_wt.data(), sd.work->part_stride.data(), value);
  }
#else
  const bool vector = false;
#endif
  const auto dot6 = [](const double* a, const double* b) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5];
  };
  double block[9];  // column-major 3 x 3
  for (const AssemblyBlock& e : sd.work->assembly) {
    const int ki = e.rows, kj = e.cols;
    if (e.free_bodies && vector) continue;  // done above
    known_finite = false;  // (checked by solveContacts)
    if (e.free_bodies) {  // free bodies' spatial contacts: W has 6 rows, blocks are 3 x 3
      const double* wi = sd.work->part_w[static_cast<std::size_t>(e.part[0])] + 6 * e.row[0];
      const double* wj = sd.work->part_w[static_cast<std::size_t>(e.part[0])] + 6 * e.col[0];
      for (int c = 0; c < 3; ++c)
        for (int r = 0; r < 3; ++r) block[r + 3 * c] = dot6(wi + 6 * r, wj + 6 * c);
      if (e.part[1] >= 0) {
        wi = sd.work->part_w[static_cast<std::size_t>(e.part[1])] + 6 * e.row[1];
        wj = sd.work->part_w[static_cast<std::size_t>(e.part[1])] + 6 * e.col[1];
        for (int c = 0; c < 3; ++c)
          for (int r = 0; r < 3; ++r) block[r + 3 * c] += dot6(wi + 6 * r, wj + 6 * c);
      }
    } else {
      for (int p = 0; p < 2 && e.part[p] >= 0; ++p) {
        const Eigen::MatrixXd& W = sd.work->parts[static_cast<std::size_t>(e.part[p])].W;
        for (int c = 0; c < kj; ++c)
          for (int r = 0; r < ki; ++r) {
            const double d = W.col(e.row[p] + r).dot(W.col(e.col[p] + c));
            block[r + 3 * c] = p == 0 ? d : block[r + 3 * c] + d;
          }
      }
    }
    for (int c = 0; c < kj; ++c)
      for (int r = 0; r < ki; ++r) value[e.position[c] + r] = block[r + 3 * c];
    if (e.mirror[0] >= 0)
      for (int r = 0; r < ki; ++r)
        for (int c = 0; c < kj; ++c) value[e.mirror[r] + c] = block[r + 3 * c];
  }
  return known_finite;
}

// The plan of assembleFromPlan for A_sparse's pattern just built (dense: for sd.out.A, stored by
// columns): the blocks are the active contacts' rows, then the anchors' (3 each). False when a
// block pair has more than two shares (blocks in more than two parts: not a contact's) or a block
// is wider than 3 rows.
bool planAssembly(const SimulatorModel& sim, SimulatorData& sd, bool dense) {
  const Eigen::Index rows = sd.out.rows;
  std::vector<int> block_of(static_cast<std::size_t>(rows)), start;  // each row's block; each block's first row
  int row = 0;
  for (int i : sd.out.active) {
    start.push_back(row);
    row += sd.out.candidate_rows[i];
  }
  for (std::size_t a = 0; a < sim.anchors.size(); ++a, row += 3) start.push_back(row);
  for (std::size_t k = 0; k < sd.out.joint_rows.size(); ++k, row += 1) start.push_back(row);
  start.push_back(row);
  if (row != rows) return false;
  const auto blocks = static_cast<int>(start.size()) - 1;
  for (int b = 0; b < blocks; ++b) {
    if (start[b + 1] - start[b] > 3) return false;
    for (int r = start[b]; r < start[b + 1]; ++r) block_of[static_cast<std::size_t>(r)] = b;
  }
  const int* outer = sd.out.A_sparse.outerIndexPtr();
  const int* inner = sd.out.A_sparse.innerIndexPtr();
  auto position = [&](int r, int c) {
    if (dense) return static_cast<int>(r + c * rows);
    return static_cast<int>(std::lower_bound(inner + outer[c], inner + outer[c + 1], r) - inner);
  };
  std::unordered_map<long long, int> index;  // (block i, block j) -> its entry
  sd.work->assembly.clear();
  for (std::size_t s = 0; s < sd.work->parts.size(); ++s) {
    const std::vector<int>& part_rows = sd.work->parts[s].rows;
    // the part's blocks and the local row each starts at (a block's rows are all in its parts)
    std::vector<std::pair<int, int>> part_blocks;
    for (std::size_t k = 0; k < part_rows.size(); ++k)
      if (part_rows[k] == start[static_cast<std::size_t>(block_of[static_cast<std::size_t>(part_rows[k])])])
        part_blocks.emplace_back(block_of[static_cast<std::size_t>(part_rows[k])], static_cast<int>(k));
    for (const auto& [bj, lj] : part_blocks)
      for (const auto& [bi, li] : part_blocks) {
        if (bi < bj) continue;  // the lower triangle; the mirror takes the rest
        const long long key = static_cast<long long>(bi) * blocks + bj;
        auto [it, fresh] = index.emplace(key, static_cast<int>(sd.work->assembly.size()));
        if (fresh) {
          AssemblyBlock e;
          e.rows = start[static_cast<std::size_t>(bi) + 1] - start[static_cast<std::size_t>(bi)];
          e.cols = start[static_cast<std::size_t>(bj) + 1] - start[static_cast<std::size_t>(bj)];
          for (int c = 0; c < e.cols; ++c) e.position[c] = position(start[bi], start[bj] + c);
          if (bi != bj)
            for (int r = 0; r < e.rows; ++r) e.mirror[r] = position(start[bj], start[bi] + r);
          e.part[0] = static_cast<int>(s);
          e.row[0] = li;
          e.col[0] = lj;
          e.free_bodies = e.rows == 3 && e.cols == 3 && sim.systems[s].free_body;
          sd.work->assembly.push_back(e);
        } else {
          AssemblyBlock& e = sd.work->assembly[static_cast<std::size_t>(it->second)];
          if (e.part[1] >= 0) return false;
          e.part[1] = static_cast<int>(s);
          e.row[1] = li;
          e.col[1] = lj;
          e.free_bodies = e.free_bodies && sim.systems[s].free_body;
        }
      }
  }
  return true;
}

// The parts hold the rows they held when the plan was made (sd.work->triplet_part_rows).
bool samePartRows(const SimulatorData& sd) {
  if (sd.work->triplet_part_rows.size() != sd.work->parts.size()) return false;
  for (std::size_t s = 0; s < sd.work->parts.size(); ++s)
    if (sd.work->parts[s].rows != sd.work->triplet_part_rows[s]) return false;
  return true;
}

}  // namespace

void delassusOperator(const SimulatorModel& sim, SimulatorData& sd) {
  const Eigen::Index rows = sd.out.rows;
  sd.work->robot_chains = false;
  sd.work->locked.pending_full = false;  // (this step's A is built here: solveJointsLocked did not)
  if (wholeWorldPart(sim, sd) && !sim.systems[0].free_body && robotOperator(sim, sd)) {
    // one robot, each contact on one root path: A by the tree's chains (robot_delassus.cpp)
    sd.work->robot_chains = true;
    sd.out.sparse = false;
    sd.work->a_in_operator = false;
    if (sd.out.A_sparse.rows() != 0) sd.out.A_sparse.resize(0, 0);
    return;
  }
  const Eigen::Index entries = delassusFactors(sd);
  // Sparse when the parts leave most of A empty: many parts, more than kSparseDelassusRows rows
  // (a storage choice measured on cube grids, not the default rule's kAdmmAboveRows), at most
  // kSparseDelassusDensity of the entries (a tower's block-tridiagonal A is 14-20 %;
  // thresholds.hpp).
  sd.out.sparse = sd.work->parts.size() > 1 && rows > kSparseDelassusRows &&
              double(entries) <= kSparseDelassusDensity * double(rows) * double(rows);
  sd.work->a_in_operator = false;  // A_sparse holds this step's A again
  sd.work->a_known_finite = false;
  if (sd.out.sparse && sd.work->parts_share_rows) {  // rows shared by two parts (contacts between bodies)
    // While the entries' (row, column) sequence is last step's (the same contacts on the same
    // rows), A's pattern and the plan of its entries hold: the values are computed in place
    // (setFromTriplets was a third of a tower's step).
    const auto count = static_cast<std::size_t>(entries);
    bool same = sd.work->assembly_kind == AssemblyKind::kSparse && sd.out.A_sparse.rows() == rows &&
                sd.work->triplet_position.size() == count && sd.work->triplets.size() == count && samePartRows(sd);
    if (same) {
      sd.work->a_known_finite = assembleFromPlan(sd, sd.out.A_sparse.valuePtr());
      sd.out.A.resize(0, 0);
      return;
    }
    for (SystemWork& w : sd.work->parts) partOperator(w);
    sd.work->triplets.clear();
    sd.work->triplets.reserve(count);
    for (const SystemWork& w : sd.work->parts)
      for (Eigen::Index c = 0; c < w.A.cols() && !w.rows.empty(); ++c)
        for (Eigen::Index r = 0; r < w.A.rows(); ++r) sd.work->triplets.emplace_back(w.rows[r], w.rows[c], w.A(r, c));
    sd.work->triplet_part_rows.resize(sd.work->parts.size());
    for (std::size_t s = 0; s < sd.work->parts.size(); ++s) sd.work->triplet_part_rows[s] = sd.work->parts[s].rows;
    sd.out.A_sparse.resize(rows, rows);
    sd.out.A_sparse.setFromTriplets(sd.work->triplets.begin(), sd.work->triplets.end());
    ++sd.work->pattern_version;
    sd.out.A_sparse.makeCompressed();
    // each entry's position in the compressed storage (a search in its column)
    sd.work->triplet_position.resize(count);
    const int* outer = sd.out.A_sparse.outerIndexPtr();
    const int* inner = sd.out.A_sparse.innerIndexPtr();
    for (std::size_t t = 0; t < count; ++t) {
      const int row = sd.work->triplets[t].row(), col = sd.work->triplets[t].col();
      sd.work->triplet_position[t] = static_cast<int>(std::lower_bound(inner + outer[col], inner + outer[col + 1], row) - inner);
    }
    sd.work->assembly_kind = planAssembly(sim, sd, /*dense=*/false) ? AssemblyKind::kSparse : AssemblyKind::kNone;
    sd.out.A.resize(0, 0);
    return;
  }
  if (sd.out.sparse) {
    for (SystemWork& w : sd.work->parts) partOperator(w);
    // Every row in one part: column c of A is its part's column, rows in the part's (ascending)
    // order; written straight into the compressed storage.
    sd.work->row_part.assign(static_cast<std::size_t>(rows), -1);
    sd.work->row_local.resize(static_cast<std::size_t>(rows));
    for (std::size_t s = 0; s < sd.work->parts.size(); ++s)
      for (std::size_t k = 0; k < sd.work->parts[s].rows.size(); ++k) {
        sd.work->row_part[sd.work->parts[s].rows[k]] = static_cast<int>(s);
        sd.work->row_local[sd.work->parts[s].rows[k]] = static_cast<int>(k);
      }
    sd.out.A_sparse.resize(rows, rows);
    sd.out.A_sparse.resizeNonZeros(entries);
    ++sd.work->pattern_version;  // (written anew each step: assignValues compares it)
    int* outer = sd.out.A_sparse.outerIndexPtr();
    int* inner = sd.out.A_sparse.innerIndexPtr();
    double* value = sd.out.A_sparse.valuePtr();
    Eigen::Index pos = 0;
    outer[0] = 0;
    for (Eigen::Index c = 0; c < rows; ++c) {
      const int s = sd.work->row_part[c];
      if (s >= 0) {
        const SystemWork& w = sd.work->parts[s];
        const int k = sd.work->row_local[c];
        for (std::size_t r = 0; r < w.rows.size(); ++r, ++pos) {
          inner[pos] = w.rows[r];
          value[pos] = w.A(static_cast<Eigen::Index>(r), k);
        }
      }
      outer[c + 1] = static_cast<int>(pos);
    }
    sd.out.A.resize(0, 0);
    return;
  }
  sd.out.A_sparse.resize(0, 0);
  if (wholeWorldPart(sim, sd)) {
    partOperator(sd.work->parts[0]);
    sd.out.A = sd.work->parts[0].A;
    return;
  }
  // Several parts, dense (a few bodies): the same plan of blocks, positions in A's columns; the
  // entries no two rows of a part share stay zero while the parts' rows stay.
  if (sd.work->assembly_kind == AssemblyKind::kDense && sd.out.A.rows() == rows && sd.out.A.cols() == rows && samePartRows(sd)) {
    assembleFromPlan(sd, sd.out.A.data());
    return;
  }
  for (SystemWork& w : sd.work->parts) partOperator(w);
  sd.out.A.setZero(rows, rows);
  for (const SystemWork& w : sd.work->parts)
    for (Eigen::Index c = 0; c < static_cast<Eigen::Index>(w.rows.size()); ++c)
      for (Eigen::Index r = 0; r < static_cast<Eigen::Index>(w.rows.size()); ++r) sd.out.A(w.rows[r], w.rows[c]) += w.A(r, c);
  sd.work->triplet_part_rows.resize(sd.work->parts.size());
  for (std::size_t s = 0; s < sd.work->parts.size(); ++s) sd.work->triplet_part_rows[s] = sd.work->parts[s].rows;
  sd.work->assembly_kind = planAssembly(sim, sd, /*dense=*/true) ? AssemblyKind::kDense : AssemblyKind::kNone;
}

void multiplyJacobian(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& x, Eigen::VectorXd& y) {
  if (wholeWorldPart(sim, sd)) {
    y.noalias() = sd.work->parts[0].J * x;
    return;
  }
  y.setZero(sd.out.rows);
  for (std::size_t s = 0; s < sd.work->parts.size(); ++s) {
    SystemWork& w = sd.work->parts[s];
    if (w.rows.empty()) continue;
    gatherV(sim.systems[s], x, w.x);
    w.row_values.noalias() = w.J * w.x;  // (J is stored by columns: a product, not a dot per row)
    for (Eigen::Index r = 0; r < w.J.rows(); ++r) y[w.rows[r]] += w.row_values[r];
  }
}

void solveJacobianTransposed(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& lambda,
                             Eigen::VectorXd& dv) {
  if (sd.work->robot_chains) {
    // M^-1 J^T lambda = U^-T D^-1/2 (Y lambda), Y = D^-1/2 U^-1 J^T the Delassus stage's (chain by
    // chain, its blocks' entries on their chains): one back substitution instead of J^T lambda
    // and both of M's
    const RobotOperatorPlan& plan = sd.work->parts[0].robot_plan;
    dv.setZero(sim.model.nv);
    const double* Y = plan.Y.data();
    for (const RobotOperatorPlan::Block& b : plan.blocks) {
      const double* l = lambda.data() + b.row;
      for (int a = 0; a < b.length; ++a) {
        const double* y = Y + 4 * (b.start + a);  // (b.k values, zeros past them)
        double sum = y[0] * l[0];
        for (int r = 1; r < b.k; ++r) sum += y[r] * l[r];
        dv[plan.chain[static_cast<std::size_t>(b.start + a)]] += sum;
      }
    }
    for (Eigen::Index i = 0; i < dv.size(); ++i) dv[i] *= plan.scale[static_cast<std::size_t>(i)];
    pinocchio::cholesky::Utiv(sim.systems[0].model, sd.work->parts[0].data, dv);
    return;
  }
  if (wholeWorldPart(sim, sd)) {
    dv.noalias() = sd.work->parts[0].J.transpose() * lambda;
    partMassSolve(sim.systems[0], sd.work->parts[0].data, dv);
    return;
  }
  dv.setZero(sim.model.nv);
  for (std::size_t s = 0; s < sd.work->parts.size(); ++s) {
    SystemWork& w = sd.work->parts[s];
    if (w.rows.empty()) continue;
    w.x.setZero(w.J.cols());
    for (Eigen::Index r = 0; r < w.J.rows(); ++r) w.x += lambda[w.rows[r]] * w.J.row(r).transpose();
    partMassSolve(sim.systems[s], w.data, w.x);
    scatterV(sim.systems[s], w.x, dv);  // parts do not share coordinates
  }
}

void rightHandSide(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v, double delta, double zeta,
                   bool tangential_drift) {
  // eq. 27 with Phi = nle - tau: b = J M^-1 Phi - J' v - (2 zeta / delta) J v - Psi / delta^2
  // (J v_free and J v in one product: J (v_free + (2 zeta / delta) v))
  sd.work->nv_scratch = sd.work->v_free + (2.0 * zeta / delta) * v;
  multiplyJacobian(sim, sd, sd.work->nv_scratch, sd.work->row_scratch);
  sd.out.b = -sd.work->row_scratch;
  sd.out.b -= sd.out.drift;
  sd.out.b -= sd.out.position_error / (delta * delta);
  // Time stepping drops the J' v term on the tangential rows (the paper allows it, §3.3):
  // a sticking contact then ends the step with exactly zero slip velocity, J_t v+ = 0,
  // instead of -h J_t' v. Normal rows keep it: it predicts the gap. (It is added back
  // rather than left out, as it always was: b's rounding is part of the trajectories.)
  if (!tangential_drift) sd.out.b += sd.out.drift.cwiseProduct(sd.out.tangent_row);
  // Time stepping turns a free flyer's linear velocity with its frame (integrate.cpp, addFrameTurn:
  // v+ gains h omega x v). On normal rows the drift's omega x v part cancels it; on tangential rows,
  // whose drift was just dropped, b carries it, so a sticking contact of a turning base also ends
  // the step with J_t v+ = 0 (without it: a uniform h (omega x v)_t, ~6e-5 m/s on a trotting Solo-12).
  if (!tangential_drift && !sim.free_flyers.empty() && sd.out.rows > 0) {
    sd.work->nv_scratch.setZero(sim.model.nv);
    for (pinocchio::JointIndex j : sim.free_flyers) {
      const int iv = sim.model.idx_vs[j];
      sd.work->nv_scratch.segment<3>(iv) = v.segment<3>(iv + 3).cross(v.segment<3>(iv));
    }
    multiplyJacobian(sim, sd, sd.work->nv_scratch, sd.work->row_scratch);
    sd.out.b -= sd.work->row_scratch.cwiseProduct(sd.out.tangent_row);
  }
}

namespace {
// The largest part of a redundant set's b (relative to the set's own b) that projectRedundantSets
// treats as rounding (pile-24's tilted box, step 234: 4.2e-9 of the whole b); pile-1000's hull by a
// wall and the floor had a part of the order of its set's b.
constexpr double kRoundingPart = 1e-6;
}  // namespace

void projectRedundantSets(const SimulatorModel& sim, SimulatorData& sd) {
  // Contacts between the same two bodies measure one relative twist (v, omega): a row t of a
  // contact at p is [t^T, (p x t)^T] (v, omega), so beyond 6 rows the set is redundant (a box's 4
  // corners: 12 rows, rank 6) and J has a left null space there: nu^T J = 0, hence nu^T (A lambda
  // - b) = -nu^T b whatever lambda. b's -J (...) part has no such component, but the normal rows'
  // drift J'v and Psi / delta^2 of a tilted, moving set do (the tangential drift is dropped in
  // time stepping): pile-24's step 234 had 4.2e-9 ||b|| there, so no lambda met the tolerance
  // 1e-10 ||b||. Where that part exceeds a tenth of the tolerance, b loses it (its least-squares
  // consistent value: nothing any lambda could produce is removed). Called only for a step whose
  // solve missed the tolerance (solveContacts): an SVD per redundant set (every tower interface
  // is one) would cost a tenth of a tower's step.
  sd.out.inconsistent_groups = 0;
  const std::size_t count = sd.work->blocks.size();
  if (count < 3) return;
  sd.work->block_order.resize(count);
  for (std::size_t i = 0; i < count; ++i) sd.work->block_order[i] = static_cast<int>(i);
  const auto key = [&](int i) { return std::make_pair(sd.work->blocks[i].plus, sd.work->blocks[i].minus); };
  std::sort(sd.work->block_order.begin(), sd.work->block_order.end(), [&](int a, int b) { return key(a) < key(b); });
  const double threshold = 0.1 * sim.settings.solver_settings.tolerance * sd.out.b.norm();
  Eigen::MatrixXd G;
  Eigen::VectorXd bg;
  for (std::size_t first = 0; first < count;) {
    std::size_t last = first + 1;
    int rows = sd.work->blocks[sd.work->block_order[first]].k;
    while (last < count && key(sd.work->block_order[last]) == key(sd.work->block_order[first]))
      rows += sd.work->blocks[sd.work->block_order[last++]].k;
    if (rows > 6) {
      G.resize(rows, 6);
      bg.resize(rows);
      int r = 0;
      for (std::size_t j = first; j < last; ++j) {
        const SimulatorWorkspace::ContactBlock& block = sd.work->blocks[sd.work->block_order[j]];
        for (int q = 0; q < block.k; ++q, ++r) {
          const Eigen::Vector3d t = block.T.row(q).transpose();
          G.row(r).head<3>() = t.transpose();
          G.row(r).tail<3>() = block.point.cross(t).transpose();
          bg[r] = sd.out.b[block.row + q];
        }
      }
      const Eigen::JacobiSVD<Eigen::MatrixXd> svd(G, Eigen::ComputeFullU);
      const Eigen::VectorXd& sv = svd.singularValues();
      Eigen::Index rank = 0;
      while (rank < sv.size() && sv[rank] > 1e-12 * sv[0]) ++rank;
      const auto null = svd.matrixU().rightCols(rows - rank);
      const Eigen::VectorXd component = null.transpose() * bg;
      // Only a part at the scale of rounding is removed. A large one is physics, not noise: the
      // set's contacts at different gaps (a body by the floor at 19 mm and a wall at 3 mm: Psi /
      // delta^2 on the normal rows, not one rigid motion), which the contact law meets by opening
      // some of them. Removing it rewrote every row of the set by m/s (pile-1000 step 505: the
      // wall contact's h b went to (0.47, -11.6, 5.1) m/s where J v was 2.9 m/s, an impulse of
      // 1 N s on a 0.17 kg hull, +2 J, 147 rad/s, the blow-up guard).
      if (component.norm() > threshold && component.norm() <= kRoundingPart * bg.norm()) {
        bg -= null * component;
        r = 0;
        for (std::size_t j = first; j < last; ++j) {
          const SimulatorWorkspace::ContactBlock& block = sd.work->blocks[sd.work->block_order[j]];
          for (int q = 0; q < block.k; ++q, ++r) sd.out.b[block.row + q] = bg[r];
        }
        ++sd.out.inconsistent_groups;
      }
    }
    first = last;
  }
}

}  // namespace stages
}  // namespace stiction
