// Stage 4, the Delassus stage: the mass matrix and its factor, the free acceleration,
// then the contact problem's A = J M^-1 J^T (eq. 22) and b (eq. 27).
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include <pinocchio/algorithm/cholesky.hpp>
#include <pinocchio/algorithm/crba.hpp>
#include <pinocchio/algorithm/joint-configuration.hpp>

#include "stages.hpp"

namespace stiction {

void computeControl(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                    const Eigen::VectorXd& v) {
  sd.tau.resize(sim.model.nv);
  const JointControl& c = sd.control;
  const int nv = sim.model.nv;
  if (c.kp.size() != nv || c.kd.size() != nv || c.v_target.size() != nv || c.tau_ff.size() != nv ||
      c.q_target.size() != sim.model.nq)
    throw std::invalid_argument("control: kp, kd, v_target, tau_ff need nv = " + std::to_string(nv) +
                                " entries and q_target nq = " + std::to_string(sim.model.nq));
  pinocchio::difference(sim.model, q, c.q_target, sd.dv);  // q_target (-) q, on the manifold
  sd.tau = c.kp.cwiseProduct(sd.dv) + c.kd.cwiseProduct(c.v_target - v) + c.tau_ff;
}

namespace stages {

namespace {

// nle = C(q, v) v + g(q) (Pinocchio's rnea at zero acceleration) from the forward
// kinematics already in `data` (placements, velocities, accelerations at q'' = 0)
// and the world-frame joint Jacobian: the backward pass of rnea, in world
// coordinates, without repeating the forward pass (saves ~1 us on Solo-12).
void nonLinearEffectsFromKinematics(const pinocchio::Model& model, pinocchio::Data& data,
                                    std::vector<pinocchio::Force>& forces, Eigen::VectorXd& nle) {
  const int n = model.njoints;
  forces.resize(n);
  const Eigen::Vector3d minus_g = -model.gravity.linear();
  for (int i = 1; i < n; ++i) {
    const pinocchio::SE3& oMi = data.oMi[i];
    // a_gf = a + gravity seen as an upward acceleration of the base, in frame i
    const pinocchio::Motion a_gf(data.a[i].linear() + oMi.rotation().transpose() * minus_g, data.a[i].angular());
    const pinocchio::Inertia& Y = model.inertias[i];
    const pinocchio::Force f_local = Y * a_gf + data.v[i].cross(Y * data.v[i]);
    forces[i] = oMi.act(f_local);
  }
  for (int i = n - 1; i >= 1; --i) {
    const int nv_i = model.nvs[i], iv = model.idx_vs[i];
    for (int k = iv; k < iv + nv_i; ++k)
      nle[k] = data.J.col(k).head<3>().dot(forces[i].linear()) + data.J.col(k).tail<3>().dot(forces[i].angular());
    const auto parent = model.parents[i];
    if (parent > 0) forces[parent] += forces[i];
  }
}

// M of one part (crba; h kd + h^2 kp on its diagonal for an implicit PD over h > 0) and its
// factor M = U D U^T, in w.data. Throws when M is not positive definite.
void factorMass(const SystemModel& part, SystemWork& w, const JointControl& control, double implicit_pd_step) {
  const pinocchio::Model& model = part.model;
  // q as Eigen::Ref: the instantiation libpinocchio ships (extern template), not a fresh one
  // here (a VectorXd argument made this file take 55 s to compile instead of 14 s).
  pinocchio::crba(model, w.data, Eigen::Ref<const Eigen::VectorXd>(w.q), pinocchio::Convention::LOCAL);
  if (implicit_pd_step > 0.0) {
    // Implicit joint PD over a step h: tau(q+, v+) ~ kp (q_t - q - h v+) + kd (v_t - v+)
    // moves h kd + h^2 kp onto M's diagonal (stable for any gains; MuJoCo's implicitfast
    // does the damping part). The -h kp v part of tau is added above.
    const double h = implicit_pd_step;
    for (Eigen::Index k = 0; k < model.nv; ++k) {
      const int world = part.v_index[k];
      w.data.M(k, k) += h * control.kd[world] + h * h * control.kp[world];
    }
  }
  // M = U D U^T by Pinocchio's tree-sparse Cholesky (cheaper than a dense LLT).
  pinocchio::cholesky::decompose(model, w.data);
  if (model.nv > 0 && !(w.data.D.minCoeff() > 0.0))
    throw std::runtime_error("the mass matrix of '" + model.name + "' is not positive definite at this configuration");
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

void freeDynamics(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& q,
                  const Eigen::VectorXd& v, double implicit_pd_step) {
  computeControl(sim, sd, q, v);  // tau (world coordinates)
  if (implicit_pd_step > 0.0) sd.tau -= implicit_pd_step * sd.control.kp.cwiseProduct(v);
  for (std::size_t s = 0; s < sim.systems.size(); ++s) {
    const SystemModel& part = sim.systems[s];
    const pinocchio::Model& model = part.model;
    SystemWork& w = sd.parts[s];
    // A free body without joint PD: its mass matrix in its own frame is constant (factored at
    // the first step). Else crba and the tree Cholesky every step.
    bool pd_on_diagonal = false;
    if (implicit_pd_step > 0.0)
      for (int world : part.v_index) pd_on_diagonal = pd_on_diagonal || sd.control.kd[world] != 0.0 || sd.control.kp[world] != 0.0;
    const bool reuse = part.free_body && w.mass_factored && !pd_on_diagonal;
    w.mass_factored = part.free_body && !pd_on_diagonal;
    if (!reuse) factorMass(part, w, sd.control, implicit_pd_step);
    nonLinearEffectsFromKinematics(model, w.data, w.forces, w.nle);
    gatherV(part, sd.tau, w.tau);
    w.v_free = w.tau - w.nle;
    pinocchio::cholesky::solve(model, w.data, w.v_free);  // M^-1 (tau - nle): the free acceleration
    scatterV(part, w.nle, sd.nle);
    scatterV(part, w.v_free, sd.v_free);
  }
}

void delassusOperator(const SimulatorModel& sim, SimulatorData& sd) {
  // A = sum over parts of (D^-1/2 U^-1 J_s^T)^T (D^-1/2 U^-1 J_s^T): symmetric by construction.
  // (dense triangular solve: cheaper than Pinocchio's per-column Uiv at these sizes)
  const Eigen::Index rows = sd.rows;
  Eigen::Index entries = 0;
  for (SystemWork& w : sd.parts) {
    const auto n = static_cast<Eigen::Index>(w.rows.size());
    w.A.resize(n, n);
    if (n == 0) continue;
    if (w.J.cols() > 6 && contactSupport(w.data, w)) {
      // A robot touching with a few limbs (TALOS's two soles: base and legs, 18 of 38
      // coordinates): the triangular solve and the rank update on those coordinates only.
      const auto s = static_cast<Eigen::Index>(w.support.size());
      w.U_support.resize(s, s);
      w.W.resize(s, n);
      for (Eigen::Index c = 0; c < s; ++c) {
        for (Eigen::Index r = 0; r < c; ++r) w.U_support(r, c) = w.data.U(w.support[r], w.support[c]);
        w.W.row(c) = w.J.col(w.support[c]).transpose();
      }
      w.U_support.triangularView<Eigen::StrictlyLower>().setZero();
      w.U_support.diagonal().setOnes();
      w.U_support.triangularView<Eigen::UnitUpper>().solveInPlace(w.W);
      for (Eigen::Index c = 0; c < s; ++c) w.W.row(c) *= std::sqrt(w.data.Dinv[w.support[c]]);
      w.A.setZero();
      w.A.selfadjointView<Eigen::Lower>().rankUpdate(w.W.transpose());
      w.A.triangularView<Eigen::StrictlyUpper>() = w.A.transpose();
      entries += n * n;
      continue;
    }
    w.W = w.J.transpose();
    if (w.W.rows() <= 6) {
      // a free body's 6 x 6 factor: back substitution by rows (Eigen's blocked triangular
      // solve costs more than the arithmetic at this size)
      const Eigen::MatrixXd& U = w.data.U;
      for (Eigen::Index i = w.W.rows() - 2; i >= 0; --i)
        for (Eigen::Index j = i + 1; j < w.W.rows(); ++j)
          if (U(i, j) != 0.0) w.W.row(i) -= U(i, j) * w.W.row(j);
    } else {
      w.data.U.triangularView<Eigen::UnitUpper>().solveInPlace(w.W);
    }
    w.W = w.data.Dinv.cwiseSqrt().asDiagonal() * w.W;
    if (w.W.rows() == 6) {
      // a free body's contacts (a cube's 4 corners: 12 rows x 6; a tower's box, 24): one fixed-size
      // 6-term dot product per entry of the lower triangle, mirrored (exactly symmetric; Eigen's
      // dynamic-size coefficient-wise product spent most of its time in loop set-up at this size)
      const Eigen::Map<const Eigen::Matrix<double, 6, Eigen::Dynamic>> W6(w.W.data(), 6, n);
      for (Eigen::Index c = 0; c < n; ++c) {
        const Eigen::Matrix<double, 6, 1> wc = W6.col(c);
        for (Eigen::Index r = c; r < n; ++r) w.A(r, c) = w.A(c, r) = W6.col(r).dot(wc);
      }
    } else if (w.J.cols() <= 6) {
      // (robots keep the rank update below: TALOS's 24 x 44 was 5 us slower coefficient-wise)
      w.A.noalias() = w.W.transpose().lazyProduct(w.W);
    } else {
      w.A.setZero();
      w.A.selfadjointView<Eigen::Lower>().rankUpdate(w.W.transpose());
      w.A.triangularView<Eigen::StrictlyUpper>() = w.A.transpose();
    }
    entries += n * n;
  }
  // Sparse when the parts leave most of A empty: many parts, more rows than the dense
  // solvers handle well (the default rule's threshold), at most 25 % of the entries (a tower's
  // block-tridiagonal A is 14-20 %).
  sd.sparse = sd.parts.size() > 1 && rows > kSparseDelassusRows && entries * 4 <= rows * rows;
  if (sd.sparse && !sd.parts_share_rows) {
    // Every row in one part: column c of A is its part's column, rows in the part's (ascending)
    // order; written straight into the compressed storage.
    sd.row_part.assign(static_cast<std::size_t>(rows), -1);
    sd.row_local.resize(static_cast<std::size_t>(rows));
    for (std::size_t s = 0; s < sd.parts.size(); ++s)
      for (std::size_t k = 0; k < sd.parts[s].rows.size(); ++k) {
        sd.row_part[sd.parts[s].rows[k]] = static_cast<int>(s);
        sd.row_local[sd.parts[s].rows[k]] = static_cast<int>(k);
      }
    sd.A_sparse.resize(rows, rows);
    sd.A_sparse.resizeNonZeros(entries);
    int* outer = sd.A_sparse.outerIndexPtr();
    int* inner = sd.A_sparse.innerIndexPtr();
    double* value = sd.A_sparse.valuePtr();
    Eigen::Index pos = 0;
    outer[0] = 0;
    for (Eigen::Index c = 0; c < rows; ++c) {
      const int s = sd.row_part[c];
      if (s >= 0) {
        const SystemWork& w = sd.parts[s];
        const int k = sd.row_local[c];
        for (std::size_t r = 0; r < w.rows.size(); ++r, ++pos) {
          inner[pos] = w.rows[r];
          value[pos] = w.A(static_cast<Eigen::Index>(r), k);
        }
      }
      outer[c + 1] = static_cast<int>(pos);
    }
    sd.A.resize(0, 0);
    return;
  }
  if (sd.sparse) {  // rows shared by two parts (contacts between bodies): their shares summed
    // While the entries' (row, column) sequence is last step's (the same contacts on the same
    // rows), their positions in A_sparse are known: the shares are summed in place rather than
    // sorted again (setFromTriplets was a third of a tower's step).
    // (The entries are listed part by part, column by column from each part's rows: the same rows
    // per part, the same sequence.)
    const auto count = static_cast<std::size_t>(entries);
    bool same = sd.A_sparse.rows() == rows && sd.triplet_position.size() == count && sd.triplets.size() == count &&
                sd.triplet_part_rows.size() == sd.parts.size();
    for (std::size_t s = 0; same && s < sd.parts.size(); ++s) same = sd.parts[s].rows == sd.triplet_part_rows[s];
    std::size_t k = 0;
    if (same) {
      double* value = sd.A_sparse.valuePtr();
      std::fill(value, value + sd.A_sparse.nonZeros(), 0.0);
      k = 0;
      for (const SystemWork& w : sd.parts)
        for (Eigen::Index c = 0; c < w.A.cols() && !w.rows.empty(); ++c)
          for (Eigen::Index r = 0; r < w.A.rows(); ++r, ++k) value[sd.triplet_position[k]] += w.A(r, c);
      sd.A.resize(0, 0);
      return;
    }
    sd.triplets.clear();
    sd.triplets.reserve(count);
    for (const SystemWork& w : sd.parts)
      for (Eigen::Index c = 0; c < w.A.cols() && !w.rows.empty(); ++c)
        for (Eigen::Index r = 0; r < w.A.rows(); ++r) sd.triplets.emplace_back(w.rows[r], w.rows[c], w.A(r, c));
    sd.triplet_part_rows.resize(sd.parts.size());
    for (std::size_t s = 0; s < sd.parts.size(); ++s) sd.triplet_part_rows[s] = sd.parts[s].rows;
    sd.A_sparse.resize(rows, rows);
    sd.A_sparse.setFromTriplets(sd.triplets.begin(), sd.triplets.end());
    sd.A_sparse.makeCompressed();
    // each entry's position in the compressed storage (a search in its column)
    sd.triplet_position.resize(count);
    const int* outer = sd.A_sparse.outerIndexPtr();
    const int* inner = sd.A_sparse.innerIndexPtr();
    for (std::size_t t = 0; t < count; ++t) {
      const int row = sd.triplets[t].row(), col = sd.triplets[t].col();
      sd.triplet_position[t] = static_cast<int>(std::lower_bound(inner + outer[col], inner + outer[col + 1], row) - inner);
    }
    sd.A.resize(0, 0);
    return;
  }
  sd.A_sparse.resize(0, 0);
  if (wholeWorldPart(sim, sd)) {
    sd.A = sd.parts[0].A;
    return;
  }
  sd.A.setZero(rows, rows);
  for (const SystemWork& w : sd.parts)
    for (Eigen::Index c = 0; c < static_cast<Eigen::Index>(w.rows.size()); ++c)
      for (Eigen::Index r = 0; r < static_cast<Eigen::Index>(w.rows.size()); ++r) sd.A(w.rows[r], w.rows[c]) += w.A(r, c);
}

void multiplyJacobian(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& x, Eigen::VectorXd& y) {
  if (wholeWorldPart(sim, sd)) {
    y.noalias() = sd.parts[0].J * x;
    return;
  }
  y.setZero(sd.rows);
  for (std::size_t s = 0; s < sd.parts.size(); ++s) {
    SystemWork& w = sd.parts[s];
    if (w.rows.empty()) continue;
    gatherV(sim.systems[s], x, w.x);
    for (Eigen::Index r = 0; r < w.J.rows(); ++r) y[w.rows[r]] += w.J.row(r).dot(w.x);
  }
}

void solveJacobianTransposed(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& lambda,
                             Eigen::VectorXd& dv) {
  if (wholeWorldPart(sim, sd)) {
    dv.noalias() = sd.parts[0].J.transpose() * lambda;
    pinocchio::cholesky::solve(sim.systems[0].model, sd.parts[0].data, dv);
    return;
  }
  dv.setZero(sim.model.nv);
  for (std::size_t s = 0; s < sd.parts.size(); ++s) {
    SystemWork& w = sd.parts[s];
    if (w.rows.empty()) continue;
    w.x.setZero(w.J.cols());
    for (Eigen::Index r = 0; r < w.J.rows(); ++r) w.x += lambda[w.rows[r]] * w.J.row(r).transpose();
    pinocchio::cholesky::solve(sim.systems[s].model, w.data, w.x);
    scatterV(sim.systems[s], w.x, dv);  // parts do not share coordinates
  }
}

void rightHandSide(const SimulatorModel& sim, SimulatorData& sd, const Eigen::VectorXd& v, double delta, double zeta,
                   bool tangential_drift) {
  // eq. 27 with Phi = nle - tau: b = J M^-1 Phi - J' v - (2 zeta / delta) J v - Psi / delta^2
  multiplyJacobian(sim, sd, sd.v_free, sd.row_scratch);
  sd.b = -sd.row_scratch;
  sd.b -= sd.drift;
  multiplyJacobian(sim, sd, v, sd.row_scratch);
  sd.b -= (2.0 * zeta / delta) * sd.row_scratch;
  sd.b -= sd.position_error / (delta * delta);
  // Time stepping drops the J' v term on the tangential rows (the paper allows it, §3.3):
  // a sticking contact then ends the step with exactly zero slip velocity, J_t v+ = 0,
  // instead of -h J_t' v. Normal rows keep it: it predicts the gap. (It is added back
  // rather than left out, as it always was: b's rounding is part of the trajectories.)
  if (!tangential_drift) sd.b += sd.drift.cwiseProduct(sd.tangent_row);
}

}  // namespace stages
}  // namespace stiction
