// Stage 4b for a problem that is one robot's alone (a legged robot or an arm on the ground):
// A = J M^-1 J^T (eq. 22) by the chains of the kinematic tree.
//
// With M = U D U^T (Pinocchio's tree factor: U(i, j) != 0 only for j in i's subtree), A =
// Y^T Y with Y = D^-1/2 U^-1 J^T. The rows of a contact (a block of 1-3 rows) move only the
// coordinates on the path from the root to its deepest nonzero column (its chain: a foot's is
// the base and its leg, 9 of Solo-12's 18), and the block's columns of Y are nonzero only there:
// Y_f solves U y = j on the chain alone (a back substitution over the chain's entries of U).
// Two blocks share the chain of their common ancestor, a prefix of both (coordinates are
// numbered parents first): A_fg = Y_f[prefix]^T Y_g[prefix]. Solo-12: 4 chains of 9, 1.0k
// multiply-adds, against 2.6k for the whole W = D^-1/2 U^-1 J^T and its 78 dot products.
//
// Each chain entry of Y_f is the block's k <= 3 values padded to 4 (zeros), so the AVX2 kernel
// handles one entry as one register. Both kernels write A(f, g) and A(g, f) from the same
// products in the same order: A is exactly symmetric. Measured on this machine (AMD EPYC): a
// load that spans two earlier, narrower stores waits until both retire (tens of cycles); the
// kernels write each padded entry whole and read it whole.
#include <algorithm>
#include <cmath>

#include "stiction/vector_kernels.hpp"
#ifdef STICTION_X86_KERNELS
#include <immintrin.h>
#endif

#include "stages.hpp"

namespace stiction {
namespace stages {

namespace {

// The deepest coordinate a world joint's motion reaches in part 0 (-1: the world).
int deepestCoordinate(const SimulatorModel& sim, pinocchio::JointIndex j) {
  if (j == 0) return -1;
  const pinocchio::Model& m = sim.systems[0].model;
  const pinocchio::JointIndex local = sim.joint_local[j];
  return m.idx_vs[local] + m.nvs[local] - 1;
}

// The chain of a block touching two bodies: the root path of the deeper one's last coordinate,
// which must pass through the other's (-1: not one path: a contact between two limbs).
int blockChainEnd(const pinocchio::Data& data, int a, int b) {
  if (a < b) std::swap(a, b);
  if (b < 0) return a;
  for (int j = a; j >= 0; j = data.parents_fromRow[static_cast<std::size_t>(j)])
    if (j == b) return a;
  return -2;
}

// The blocks of rows, each block's chain (ascending coordinates, from the bodies its rows
// measure: J's nonzero columns lie on it) and the common prefix of every pair; false when a
// block's bodies are not on one root path. Kept while the active contacts are the same.
bool planChains(const SimulatorModel& sim, const SimulatorData& sd, const pinocchio::Data& data,
                RobotOperatorPlan& plan) {
  if (plan.valid && plan.active == sd.out.active && plan.anchors == sim.anchors.size() &&
      plan.joint_rows == sd.out.joint_rows)
    return true;
  plan.valid = false;
  plan.blocks.clear();
  plan.chain.clear();
  Eigen::Index row = 0;
  auto add = [&](int k, int end) {
    if (end < -1) return false;
    RobotOperatorPlan::Block b;
    b.row = static_cast<int>(row);
    b.k = k;
    b.start = static_cast<int>(plan.chain.size());
    for (int j = end; j >= 0; j = data.parents_fromRow[static_cast<std::size_t>(j)]) plan.chain.push_back(j);
    b.length = static_cast<int>(plan.chain.size()) - b.start;
    std::reverse(plan.chain.begin() + b.start, plan.chain.end());
    plan.blocks.push_back(b);
    row += k;
    return true;
  };
  if (sd.work->blocks.size() != sd.out.active.size()) return false;
  for (const SimulatorWorkspace::ContactBlock& c : sd.work->blocks)
    if (!add(c.k, blockChainEnd(data, deepestCoordinate(sim, c.plus), deepestCoordinate(sim, c.minus)))) return false;
  for (const PointAnchor& a : sim.anchors) {
    const int end = blockChainEnd(data, deepestCoordinate(sim, sim.model.frames[a.frame].parentJoint),
                                  a.frame2 != 0 ? deepestCoordinate(sim, sim.model.frames[a.frame2].parentJoint) : -1);
    if (!add(3, end)) return false;
  }
  // Joint rows (J = +-e_dof) in blocks of up to 3 consecutive rows whose coordinates lie on one root
  // path (a leg's HAA, HFE, KFE friction rows): one chain, the deepest coordinate's, for the three,
  // and a third of the blocks to pair (Solo-12's 12 friction rows: 4 blocks, not 12)
  const std::vector<JointRow>& joint_rows = sd.out.joint_rows;
  for (std::size_t i = 0; i < joint_rows.size();) {
    int deepest = sim.dof_local[static_cast<std::size_t>(joint_rows[i].dof)];
    int k = 1;
    while (k < 3 && i + static_cast<std::size_t>(k) < joint_rows.size()) {
      const int next = sim.dof_local[static_cast<std::size_t>(joint_rows[i + static_cast<std::size_t>(k)].dof)];
      if (next <= deepest || blockChainEnd(data, next, deepest) != next) break;  // not below it on one path
      deepest = next;
      ++k;
    }
    if (!add(k, deepest)) return false;
    i += static_cast<std::size_t>(k);
  }
  const std::size_t blocks = plan.blocks.size();
  plan.prefix.resize(blocks * blocks);
  for (std::size_t f = 0; f < blocks; ++f)
    for (std::size_t g = f; g < blocks; ++g) {
      const RobotOperatorPlan::Block &bf = plan.blocks[f], &bg = plan.blocks[g];
      int p = 0;
      while (p < bf.length && p < bg.length && plan.chain[bf.start + p] == plan.chain[bg.start + p]) ++p;
      plan.prefix[f * blocks + g] = p;
    }
  plan.active = sd.out.active;
  plan.anchors = sim.anchors.size();
  plan.joint_rows = sd.out.joint_rows;
  plan.valid = true;
  return true;
}

// Portable: Y by back substitution on each chain, scaled; then A's blocks.
void chainOperatorPortable(const pinocchio::Data& data, const SystemWork& w, RobotOperatorPlan& plan, double* A) {
  const Eigen::Index n = w.J.rows(), nu = data.U.rows();
  const double* J = w.J.data();
  const double* U = data.U.data();
  double* Y = plan.Y.data();
  for (const RobotOperatorPlan::Block& b : plan.blocks) {
    const int* chain = plan.chain.data() + b.start;
    double* y = Y + 4 * b.start;
    for (int a = 0; a < b.length; ++a) {  // the block's k values of J's column, zero-padded
      const double* j = J + chain[a] * n + b.row;
      for (int r = 0; r < 4; ++r) y[4 * a + r] = r < b.k ? j[r] : 0.0;
    }
    // U y = j from the deepest entry up: y_a is final once every entry below it has been
    // subtracted, then its own share leaves the entries above it (independent updates)
    for (int a = b.length - 1; a > 0; --a) {
      const double* Ucol = U + chain[a] * nu;  // U(., chain[a])
      for (int e = 0; e < a; ++e) {
        const double u = Ucol[chain[e]];
        for (int r = 0; r < 3; ++r) y[4 * e + r] -= u * y[4 * a + r];
      }
    }
  }
  for (const RobotOperatorPlan::Block& b : plan.blocks)
    for (int a = 0; a < b.length; ++a) {
      const double s = plan.scale[static_cast<std::size_t>(plan.chain[b.start + a])];
      for (int r = 0; r < 3; ++r) Y[4 * (b.start + a) + r] *= s;
    }
  const std::size_t blocks = plan.blocks.size();
  for (std::size_t f = 0; f < blocks; ++f)
    for (std::size_t g = f; g < blocks; ++g) {
      const RobotOperatorPlan::Block &bf = plan.blocks[f], &bg = plan.blocks[g];
      const int p = plan.prefix[f * blocks + g];
      double acc[3][3] = {};  // acc[c][r] = sum_k Y_f[k][r] Y_g[k][c]
      for (int k = 0; k < p; ++k) {
        const double* yf = Y + 4 * (bf.start + k);
        const double* yg = Y + 4 * (bg.start + k);
        for (int c = 0; c < 3; ++c)
          for (int r = 0; r < 3; ++r) acc[c][r] += yf[r] * yg[c];
      }
      for (int c = 0; c < bg.k; ++c)
        for (int r = 0; r < bf.k; ++r) {
          A[(bg.row + c) * n + bf.row + r] = acc[c][r];
          A[(bf.row + r) * n + bg.row + c] = acc[c][r];
        }
    }
}

#ifdef STICTION_X86_KERNELS
// A block's k values of J's column, zeros past them (read as 2 + 1: J ends somewhere).
__attribute__((target("avx2,fma"))) inline __m256d loadBlock(const double* j, int k) {
  const __m128d lo = k > 1 ? _mm_loadu_pd(j) : _mm_load_sd(j);
  const __m128d hi = k > 2 ? _mm_load_sd(j + 2) : _mm_setzero_pd();
  return _mm256_set_m128d(hi, lo);
}

// U y = j on a chain of L entries, held in registers (L a constant: the loops unroll), right-looking:
// once y_a is final its share leaves every entry above it, independent multiply-adds. Stored scaled.
template <int L>
__attribute__((target("avx2,fma"))) void chainSolveAvx2(const double* J, long n, const double* U, long nu,
                                                        const double* scale, const int* ch, int row, int k,
                                                        double* y) {
  __m256d Y[L];
#pragma GCC unroll 16
  for (int a = 0; a < L; ++a) Y[a] = loadBlock(J + ch[a] * n + row, k);
#pragma GCC unroll 16
  for (int a = L - 1; a > 0; --a) {
    const double* Ucol = U + ch[a] * nu;  // U(., ch[a])
#pragma GCC unroll 16
    for (int e = 0; e < a; ++e) Y[e] = _mm256_fnmadd_pd(_mm256_broadcast_sd(Ucol + ch[e]), Y[a], Y[e]);
  }
#pragma GCC unroll 16
  for (int a = 0; a < L; ++a) _mm256_storeu_pd(y + 4 * a, _mm256_mul_pd(Y[a], _mm256_broadcast_sd(scale + ch[a])));
}

// The same for a longer chain, through memory.
__attribute__((target("avx2,fma"))) void chainSolveAvx2(const double* J, long n, const double* U, long nu,
                                                        const double* scale, const int* ch, int length, int row,
                                                        int k, double* y) {
  for (int a = 0; a < length; ++a) _mm256_storeu_pd(y + 4 * a, loadBlock(J + ch[a] * n + row, k));
  for (int a = length - 1; a > 0; --a) {
    const __m256d ya = _mm256_loadu_pd(y + 4 * a);
    const double* Ucol = U + ch[a] * nu;
    for (int e = 0; e < a; ++e)
      _mm256_storeu_pd(y + 4 * e, _mm256_fnmadd_pd(_mm256_broadcast_sd(Ucol + ch[e]), ya, _mm256_loadu_pd(y + 4 * e)));
  }
  for (int a = 0; a < length; ++a)
    _mm256_storeu_pd(y + 4 * a, _mm256_mul_pd(_mm256_loadu_pd(y + 4 * a), _mm256_broadcast_sd(scale + ch[a])));
}

// The same as chainOperatorPortable with AVX2 and FMA, one chain entry per register (raw pointers
// and intrinsics only: docs/development.md, "No -march=native"). Returns whether every value of A
// is finite.
__attribute__((target("avx2,fma"))) bool chainOperatorAvx2(const double* J, long n, const double* U, long nu,
                                                            const double* scale, const RobotOperatorPlan::Block* blocks,
                                                            long count, const int* chain, const int* prefix, double* Y,
                                                            double* A) {
  for (long f = 0; f < count; ++f) {
    const RobotOperatorPlan::Block& b = blocks[f];
    const int* ch = chain + b.start;
    double* y = Y + 4 * b.start;
    switch (b.length) {  // (a legged robot's foot: 9 to 12; an arm's tool: 6 or 7)
#define STICTION_CHAIN(L) \
  case L: chainSolveAvx2<L>(J, n, U, nu, scale, ch, b.row, b.k, y); break;
      STICTION_CHAIN(1) STICTION_CHAIN(2) STICTION_CHAIN(3) STICTION_CHAIN(4) STICTION_CHAIN(5) STICTION_CHAIN(6)
      STICTION_CHAIN(7) STICTION_CHAIN(8) STICTION_CHAIN(9) STICTION_CHAIN(10) STICTION_CHAIN(11) STICTION_CHAIN(12)
      STICTION_CHAIN(13) STICTION_CHAIN(14)
#undef STICTION_CHAIN
      case 0: break;
      default: chainSolveAvx2(J, n, U, nu, scale, ch, b.length, b.row, b.k, y);
    }
  }
  __m256d finite = _mm256_setzero_pd();
  for (long f = 0; f < count; ++f)
    for (long g = f; g < count; ++g) {
      const RobotOperatorPlan::Block &bf = blocks[f], &bg = blocks[g];
      const int p = prefix[f * count + g];
      // col[c] = sum_k Y_f[k] Y_g[k][c] (A(f, g)'s column c); row[r] = sum_k Y_g[k] Y_f[k][r]: the
      // same products, for A(g, f)
      __m256d col0 = _mm256_setzero_pd(), col1 = col0, col2 = col0, row0 = col0, row1 = col0, row2 = col0;
      const double* yf = Y + 4 * bf.start;
      const double* yg = Y + 4 * bg.start;
      for (int k = 0; k < p; ++k, yf += 4, yg += 4) {
        const __m256d vf = _mm256_loadu_pd(yf), vg = _mm256_loadu_pd(yg);
        col0 = _mm256_fmadd_pd(vf, _mm256_broadcast_sd(yg), col0);
        col1 = _mm256_fmadd_pd(vf, _mm256_broadcast_sd(yg + 1), col1);
        col2 = _mm256_fmadd_pd(vf, _mm256_broadcast_sd(yg + 2), col2);
        row0 = _mm256_fmadd_pd(vg, _mm256_broadcast_sd(yf), row0);
        row1 = _mm256_fmadd_pd(vg, _mm256_broadcast_sd(yf + 1), row1);
        row2 = _mm256_fmadd_pd(vg, _mm256_broadcast_sd(yf + 2), row2);
      }
      // A(f, g) by columns and A(g, f) by columns (k values each: two and one, no masked store)
      alignas(32) double block[24];
      _mm256_store_pd(block, col0);
      _mm256_store_pd(block + 4, col1);
      _mm256_store_pd(block + 8, col2);
      _mm256_store_pd(block + 12, row0);
      _mm256_store_pd(block + 16, row1);
      _mm256_store_pd(block + 20, row2);
      for (int c = 0; c < bg.k; ++c)
        for (int r = 0; r < bf.k; ++r) A[(bg.row + c) * n + bf.row + r] = block[4 * c + r];
      for (int r = 0; r < bf.k; ++r)
        for (int c = 0; c < bg.k; ++c) A[(bf.row + r) * n + bg.row + c] = block[12 + 4 * r + c];
      finite = _mm256_add_pd(finite, _mm256_mul_pd(_mm256_add_pd(_mm256_add_pd(col0, col1), col2), _mm256_setzero_pd()));
    }
  alignas(32) double lanes[4];
  _mm256_store_pd(lanes, finite);
  return !std::isnan((lanes[0] + lanes[1]) + (lanes[2] + lanes[3]));
}
#endif

}  // namespace

bool robotOperator(const SimulatorModel& sim, SimulatorData& sd) {
  SystemWork& w = sd.work->parts[0];
  const pinocchio::Data& data = w.data;
  RobotOperatorPlan& plan = w.robot_plan;
  if (!planChains(sim, sd, data, plan)) return false;
  const Eigen::Index n = w.J.rows(), nv = w.J.cols();
  plan.scale.resize(static_cast<std::size_t>(nv));
  for (Eigen::Index i = 0; i < nv; ++i) plan.scale[static_cast<std::size_t>(i)] = std::sqrt(data.Dinv[i]);
  plan.Y.resize(4 * plan.chain.size());
  sd.out.A.resize(n, n);
  sd.work->a_known_finite = false;
#ifdef STICTION_X86_KERNELS
  if (vectorKernels()) {
    sd.work->a_known_finite = chainOperatorAvx2(w.J.data(), n, data.U.data(), data.U.rows(), plan.scale.data(),
                                          plan.blocks.data(), static_cast<long>(plan.blocks.size()), plan.chain.data(),
                                          plan.prefix.data(), plan.Y.data(), sd.out.A.data());
    return true;
  }
#endif
  chainOperatorPortable(data, w, plan, sd.out.A.data());
  return true;
}

}  // namespace stages
}  // namespace stiction
