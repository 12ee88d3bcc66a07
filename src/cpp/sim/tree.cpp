// Stage 1 for a robot part, fused: one pass over its joints gives what Pinocchio's
// forwardKinematics + computeJointJacobians gave (placements oMi, the world-frame joint Jacobian
// J) and, in world coordinates, each body's spatial velocity ov and bias acceleration oa (at zero
// joint acceleration: the classical accelerations they give are J' v), its inertia oY and the
// force of rnea's forward pass, of = oY (oa - g) + ov x* (oY ov). Stage 4's backward pass
// (compositeBackwardPass) sums those into M and nle = C(q, v) v + g(q) without a second pass
// over the joints' kinematics.
//
// Measured on Solo-12 (18 coordinates, 13 joints): Pinocchio's forwardKinematics and
// computeJointJacobians cost 1.6 us of a 7.8 us step, this pass 0.66 us (most of the difference:
// loads that spanned two earlier stores, below). The joints here are the kinds robots are made
// of (revolute and prismatic about x, y, z or any unit axis, free flyer: SimulatorModel refuses a
// non-unit axis); a part with any other joint keeps Pinocchio's pass (treeOf returns an empty
// description), followed by worldFrameTerms. rigid_body_passes "pinocchio" skips this file's
// passes altogether (Pinocchio's kinematics, crba, nonLinearEffects and Cholesky: the reference).
#include <algorithm>
#include <cmath>
#include <limits>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include <pinocchio/algorithm/cholesky.hpp>
#include <pinocchio/multibody/joint/joints.hpp>

#include "stages.hpp"
#include "stiction/vector_kernels.hpp"

#if defined(STICTION_X86_KERNELS) && defined(STICTION_HAVE_LIBMVEC)
#include <immintrin.h>
// glibc's vector math library (libmvec, linked when CMake finds it): 4 lanes, AVX2, within 4 ulp
extern "C" __attribute__((target("avx2"))) __m256d _ZGVdN4v_sin(__m256d);
extern "C" __attribute__((target("avx2"))) __m256d _ZGVdN4v_cos(__m256d);
#endif

namespace stiction {

namespace {

// sin and cos of x[0..n) into s, c (each padded to a multiple of 4). A robot's revolute joints all
// at once, before the pass: Solo-12's 12 scalar sincos calls cost 0.17 us of a 4.8 us step, four
// lanes at a time ~0.03 us.
#if defined(STICTION_X86_KERNELS) && defined(STICTION_HAVE_LIBMVEC)
__attribute__((target("avx2,fma"))) void sinCosAvx2(const double* x, std::size_t padded, double* s, double* c) {
  for (std::size_t i = 0; i < padded; i += 4) {
    const __m256d v = _mm256_loadu_pd(x + i);
    _mm256_storeu_pd(s + i, _ZGVdN4v_sin(v));
    _mm256_storeu_pd(c + i, _ZGVdN4v_cos(v));
  }
}
#endif

void jointSinCos(const double* x, std::size_t n, std::size_t padded, double* s, double* c) {
#if defined(STICTION_X86_KERNELS) && defined(STICTION_HAVE_LIBMVEC)
  if (vectorKernels()) {
    sinCosAvx2(x, padded, s, c);
    return;
  }
#endif
  for (std::size_t i = 0; i < n; ++i) {
    s[i] = std::sin(x[i]);
    c[i] = std::cos(x[i]);
  }
}

}  // namespace

std::vector<TreeJoint> treeOf(const pinocchio::Model& model) {
  std::vector<TreeJoint> tree(static_cast<std::size_t>(model.njoints));
  for (pinocchio::JointIndex j = 1; j < static_cast<pinocchio::JointIndex>(model.njoints); ++j) {
    TreeJoint& t = tree[j];
    const std::string kind = model.joints[j].shortname();
    const auto& joint = model.joints[j].toVariant();
    if (kind == "JointModelFreeFlyer") {
      t.kind = TreeJoint::Kind::kFreeFlyer;
    } else if (kind == "JointModelRX" || kind == "JointModelRY" || kind == "JointModelRZ") {
      t.kind = TreeJoint::Kind::kRevolute;
      t.axis = kind.back() - 'X';
    } else if (kind == "JointModelPX" || kind == "JointModelPY" || kind == "JointModelPZ") {
      t.kind = TreeJoint::Kind::kPrismatic;
      t.axis = kind.back() - 'X';
    } else if (kind == "JointModelRevoluteUnaligned") {
      t.kind = TreeJoint::Kind::kRevolute;
      t.direction = boost::get<pinocchio::JointModelRevoluteUnaligned>(joint).axis;
    } else if (kind == "JointModelPrismaticUnaligned") {
      t.kind = TreeJoint::Kind::kPrismatic;
      t.direction = boost::get<pinocchio::JointModelPrismaticUnaligned>(joint).axis;
    } else {
      return {};  // (planar, spherical, unbounded revolute, ...: Pinocchio's pass)
    }
    if (t.axis >= 0) t.direction = Eigen::Vector3d::Unit(t.axis);
    t.parent = static_cast<int>(model.parents[j]);
    t.idx_q = model.idx_qs[j];
    t.idx_v = model.idx_vs[j];
    t.rotation = model.jointPlacements[j].rotation();
    t.translation = model.jointPlacements[j].translation();
    t.rotation_identity = t.rotation == Eigen::Matrix3d::Identity();
  }
  return tree;
}

namespace stages {

namespace {

// The forward and backward passes below are written on scalars: each quantity is stored and read
// back one double at a time. A joint reads its parent's placement, velocity and acceleration
// right after they were written (the parent is usually the joint before); written as Eigen's
// 3-vectors (two doubles and one) and read as 6-vectors (pairs), each such read spanned two
// stores and waited for both to retire: most of the pass's time on this AMD EPYC (1.1 us of
// Solo-12's step). This file is compiled without GCC's auto-vectorizer (CMakeLists.txt), which
// would pair the scalars again.
struct Vec3 {
  double x, y, z;
};
inline Vec3 operator+(const Vec3& a, const Vec3& b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline Vec3 operator-(const Vec3& a, const Vec3& b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec3 operator*(double s, const Vec3& a) { return {s * a.x, s * a.y, s * a.z}; }
inline Vec3 cross(const Vec3& a, const Vec3& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double dot(const Vec3& a, const Vec3& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 load(const double* p) { return {p[0], p[1], p[2]}; }
inline void store(double* p, const Vec3& v) { p[0] = v.x, p[1] = v.y, p[2] = v.z; }

// A rotation by its columns (Eigen's column-major Matrix3d).
struct Mat3 {
  Vec3 c0, c1, c2;
};
inline Mat3 load3x3(const double* p) { return {load(p), load(p + 3), load(p + 6)}; }
inline void store(double* p, const Mat3& R) { store(p, R.c0), store(p + 3, R.c1), store(p + 6, R.c2); }
inline Vec3 operator*(const Mat3& R, const Vec3& v) { return v.x * R.c0 + v.y * R.c1 + v.z * R.c2; }
inline Mat3 operator*(const Mat3& A, const Mat3& B) { return {A * B.c0, A * B.c1, A * B.c2}; }
inline const Vec3& column(const Mat3& R, int k) { return k == 0 ? R.c0 : (k == 1 ? R.c1 : R.c2); }

// A spatial motion or force (linear, angular), as Pinocchio stores them: 6 doubles.
struct Spatial {
  Vec3 linear, angular;
};
inline Spatial load6(const double* p) { return {load(p), load(p + 3)}; }
inline void store(double* p, const Spatial& m) { store(p, m.linear), store(p + 3, m.angular); }
inline Spatial operator+(const Spatial& a, const Spatial& b) { return {a.linear + b.linear, a.angular + b.angular}; }
inline Spatial operator*(double s, const Spatial& a) { return {s * a.linear, s * a.angular}; }
// motion x motion: (w1 x v2 + v1 x w2, w1 x w2)
inline Spatial crossMotion(const Spatial& a, const Spatial& b) {
  return {cross(a.angular, b.linear) + cross(a.linear, b.angular), cross(a.angular, b.angular)};
}
// motion x* force: (w x f, w x tau + v x f)
inline Spatial crossForce(const Spatial& v, const Spatial& f) {
  return {cross(v.angular, f.linear), cross(v.angular, f.angular) + cross(v.linear, f.linear)};
}

// An inertia as Pinocchio's: mass, centre of mass c, rotational inertia about c (symmetric:
// xx, xy, yy, xz, yz, zz).
struct Inertia {
  double mass;
  Vec3 c;
  double I[6];
};
inline Inertia loadInertia(const pinocchio::Inertia& Y) {
  const double* s = Y.inertia().data().data();
  return {Y.mass(), load(Y.lever().data()), {s[0], s[1], s[2], s[3], s[4], s[5]}};
}
inline void store(pinocchio::Inertia& Y, const Inertia& y) {
  Y.mass() = y.mass;
  store(Y.lever().data(), y.c);
  double* s = Y.inertia().data().data();
  for (int k = 0; k < 6; ++k) s[k] = y.I[k];
}
inline Vec3 symmetricTimes(const double* I, const Vec3& w) {
  return {I[0] * w.x + I[1] * w.y + I[3] * w.z, I[1] * w.x + I[2] * w.y + I[4] * w.z,
          I[3] * w.x + I[4] * w.y + I[5] * w.z};
}
// Y v: (m (v - c x w), I w + c x f_linear), as Pinocchio's Inertia * Motion
inline Spatial operator*(const Inertia& Y, const Spatial& v) {
  const Vec3 linear = Y.mass * (v.linear - cross(Y.c, v.angular));
  return {linear, symmetricTimes(Y.I, v.angular) + cross(Y.c, linear)};
}
// (R, p) Y: the inertia in the world, as Pinocchio's oMi.act(Y)
inline Inertia transform(const Mat3& R, const Vec3& p, const Inertia& Y) {
  Inertia out;
  out.mass = Y.mass;
  out.c = R * Y.c + p;
  // R I R^T: T = R I (I symmetric), then the lower triangle of T R^T
  const Vec3 t0 = R * Vec3{Y.I[0], Y.I[1], Y.I[3]}, t1 = R * Vec3{Y.I[1], Y.I[2], Y.I[4]},
             t2 = R * Vec3{Y.I[3], Y.I[4], Y.I[5]};  // columns of T
  const Mat3 T{t0, t1, t2};
  const Vec3 r0{R.c0.x, R.c1.x, R.c2.x}, r1{R.c0.y, R.c1.y, R.c2.y}, r2{R.c0.z, R.c1.z, R.c2.z};  // rows of R
  const Vec3 s0 = T * r0, s1 = T * r1, s2 = T * r2;  // columns of T R^T
  out.I[0] = s0.x, out.I[1] = s0.y, out.I[2] = s1.y, out.I[3] = s0.z, out.I[4] = s1.z, out.I[5] = s2.z;
  return out;
}
// Ya += Yb, as Pinocchio's Inertia::operator+= (the parallel-axis term about the joint centre)
inline void accumulate(Inertia& a, const Inertia& b) {
  const double mab = a.mass + b.mass;
  const double mab_inv = 1.0 / std::max(mab, std::numeric_limits<double>::epsilon());
  const Vec3 AB = a.c - b.c;
  a.c = (a.mass * mab_inv) * a.c + (b.mass * mab_inv) * b.c;
  const double alpha = a.mass * b.mass * mab_inv;
  const double x = AB.x, y = AB.y, z = AB.z;
  a.I[0] += b.I[0] + alpha * (y * y + z * z);
  a.I[1] += b.I[1] - alpha * (x * y);
  a.I[2] += b.I[2] + alpha * (x * x + z * z);
  a.I[3] += b.I[3] - alpha * (x * z);
  a.I[4] += b.I[4] - alpha * (y * z);
  a.I[5] += b.I[5] + alpha * (x * x + y * y);
  a.mass = mab;
}

inline double* motionData(pinocchio::Motion& m) { return m.toVector().data(); }
inline double* forceData(pinocchio::Force& f) { return f.toVector().data(); }

}  // namespace

void treeKinematics(const SystemModel& part, SystemWork& w) {
  const pinocchio::Model& model = part.model;
  pinocchio::Data& data = w.data;
  const double* q = w.q.data();
  const double* v = w.v.data();
  double* J = data.J.data();  // 6 x nv, column-major
  data.oMi[0].setIdentity();
  data.ov[0].setZero();
  data.oa[0].setZero();
  // the revolute joints' sines and cosines first, all at once
  const std::size_t padded = w.trig.size() / 3;
  double* angle = w.trig.data();
  const double* sines = angle + padded;
  const double* cosines = angle + 2 * padded;
  std::size_t revolute = 0;
  for (int i = 1; i < model.njoints; ++i)
    if (part.tree[static_cast<std::size_t>(i)].kind == TreeJoint::Kind::kRevolute)
      angle[revolute++] = q[part.tree[static_cast<std::size_t>(i)].idx_q];
  jointSinCos(angle, revolute, padded, angle + padded, angle + 2 * padded);
  revolute = 0;
  for (int i = 1; i < model.njoints; ++i) {
    const TreeJoint& t = part.tree[static_cast<std::size_t>(i)];
    pinocchio::SE3& parent = data.oMi[t.parent];
    const Mat3 Rp = load3x3(parent.rotation().data());
    const Vec3 pp = load(parent.translation().data());
    // the joint's frame at q = 0 in the world: the parent's placement times jointPlacement
    const Mat3 R0 = t.rotation_identity ? Rp : Rp * load3x3(t.rotation.data());
    const Vec3 p = pp + Rp * load(t.translation.data());
    Mat3 R = R0;
    Vec3 origin = p;
    Spatial motion;  // S q' in the world (the joint's motion subspace times its velocity)
    switch (t.kind) {
      case TreeJoint::Kind::kRevolute: {
        const double c = cosines[revolute], s = sines[revolute];
        ++revolute;
        if (t.axis >= 0) {
          // R0 times the rotation by q about axis k: columns k1, k2 turn in their plane
          const int k = t.axis;
          const Vec3 &a1 = column(R0, (k + 1) % 3), &a2 = column(R0, (k + 2) % 3);
          const Vec3 b1 = c * a1 + s * a2, b2 = c * a2 - s * a1;
          if (k == 0) R = {R0.c0, b1, b2};
          else if (k == 1) R = {b2, R0.c1, b1};
          else R = {b1, b2, R0.c2};
        } else {
          // Rodrigues: c I + s [u]x + (1 - c) u u^T
          const Vec3 u = load(t.direction.data());
          const double d = 1.0 - c;
          const Mat3 turn{{c + d * u.x * u.x, d * u.x * u.y + s * u.z, d * u.x * u.z - s * u.y},
                          {d * u.x * u.y - s * u.z, c + d * u.y * u.y, d * u.y * u.z + s * u.x},
                          {d * u.x * u.z + s * u.y, d * u.y * u.z - s * u.x, c + d * u.z * u.z}};
          R = R0 * turn;
        }
        const Vec3 axis = R0 * load(t.direction.data());  // (unchanged by the turn about it)
        const Vec3 linear = cross(p, axis);
        store(J + 6 * t.idx_v, linear);
        store(J + 6 * t.idx_v + 3, axis);
        motion = v[t.idx_v] * Spatial{linear, axis};
        break;
      }
      case TreeJoint::Kind::kPrismatic: {
        const Vec3 axis = R0 * load(t.direction.data());
        origin = p + q[t.idx_q] * axis;
        store(J + 6 * t.idx_v, axis);
        store(J + 6 * t.idx_v + 3, Vec3{0.0, 0.0, 0.0});
        motion = {v[t.idx_v] * axis, {0.0, 0.0, 0.0}};
        break;
      }
      case TreeJoint::Kind::kFreeFlyer: {
        // q = (x, y, z, qx, qy, qz, qw), v = (linear, angular) in the joint's own frame
        const Eigen::Map<const Eigen::Quaterniond> quaternion(q + t.idx_q + 3);
        const Eigen::Matrix3d Rq = quaternion.toRotationMatrix();
        R = R0 * load3x3(Rq.data());
        origin = p + R0 * load(q + t.idx_q);
        for (int k = 0; k < 3; ++k) {  // oMi's action matrix: a local unit motion seen in the world
          double* linear = J + 6 * (t.idx_v + k);
          double* angular = J + 6 * (t.idx_v + 3 + k);
          store(linear, column(R, k));
          store(linear + 3, Vec3{0.0, 0.0, 0.0});
          store(angular, cross(origin, column(R, k)));
          store(angular + 3, column(R, k));
        }
        const Vec3 omega = R * load(v + t.idx_v + 3);
        motion = {R * load(v + t.idx_v) + cross(origin, omega), omega};
        break;
      }
    }
    pinocchio::SE3& oMi = data.oMi[i];
    store(oMi.rotation().data(), R);
    store(oMi.translation().data(), origin);
    // velocity, and acceleration at q'' = 0: the world-frame S moves with the body (S' = ov x S)
    const Spatial ov = load6(motionData(data.ov[t.parent])) + motion;
    const Spatial oa = load6(motionData(data.oa[t.parent])) + crossMotion(ov, motion);
    store(motionData(data.ov[i]), ov);
    store(motionData(data.oa[i]), oa);
    // the body's inertia and rnea's forward force in the world
    const Inertia Y = transform(R, origin, loadInertia(model.inertias[i]));
    store(data.oYcrb[i], Y);
    const Vec3 minus_g = -1.0 * load(model.gravity.linear().data());
    store(forceData(data.of[i]), Y * Spatial{oa.linear + minus_g, oa.angular} + crossForce(ov, Y * ov));
  }
}

void worldFrameTerms(const pinocchio::Model& model, pinocchio::Data& data) {
  // (after Pinocchio's own pass: its local v, a to the world; oYcrb and of as treeKinematics)
  const Vec3 minus_g = -1.0 * load(model.gravity.linear().data());
  for (int i = 1; i < model.njoints; ++i) {
    data.ov[i] = data.oMi[i].act(data.v[i]);
    data.oa[i] = data.oMi[i].act(data.a[i]);
    const Mat3 R = load3x3(data.oMi[i].rotation().data());
    const Vec3 origin = load(data.oMi[i].translation().data());
    const Inertia Y = transform(R, origin, loadInertia(model.inertias[i]));
    store(data.oYcrb[i], Y);
    const Spatial ov = load6(motionData(data.ov[i])), oa = load6(motionData(data.oa[i]));
    store(forceData(data.of[i]), Y * Spatial{oa.linear + minus_g, oa.angular} + crossForce(ov, Y * ov));
  }
}

void compositeBackwardPass(const SystemModel& part, pinocchio::Data& data, Eigen::VectorXd& nle) {
  const pinocchio::Model& model = part.model;
  const int* ancestors = part.ancestors.data();
  const int* ancestors_start = part.ancestors_start.data();
  // Column k of M: the composite inertia of k's joint (its subtree) applied to J's column k,
  // dotted with the columns of k and its ancestors (Pinocchio's parents_fromRow); nle[k]: J's
  // column k dotted with the subtree's force. Armature on the diagonal, as crba adds it.
  const double* J = data.J.data();
  double* M = data.M.data();
  const Eigen::Index nv = model.nv;
  for (int i = model.njoints - 1; i >= 1; --i) {
    const int iv = model.idx_vs[i], nv_i = model.nvs[i];
    const Inertia Y = loadInertia(data.oYcrb[i]);
    const Spatial f = load6(forceData(data.of[i]));
    for (int k = iv; k < iv + nv_i; ++k) {
      const Spatial column = load6(J + 6 * k);
      const Spatial F = Y * column;
#ifdef __SSE2__
      // J's columns were written long before (stage 1): read two values at a time
      const __m128d f01 = _mm_set_pd(F.linear.y, F.linear.x), f23 = _mm_set_pd(F.angular.x, F.linear.z),
                    f45 = _mm_set_pd(F.angular.z, F.angular.y);
      for (const int* a = ancestors + ancestors_start[k]; a != ancestors + ancestors_start[k + 1]; ++a) {
        const int j = *a;
        const double* cj = J + 6 * j;
        const __m128d sum = _mm_add_pd(_mm_add_pd(_mm_mul_pd(_mm_loadu_pd(cj), f01), _mm_mul_pd(_mm_loadu_pd(cj + 2), f23)),
                                       _mm_mul_pd(_mm_loadu_pd(cj + 4), f45));
        M[k * nv + j] = _mm_cvtsd_f64(_mm_add_sd(sum, _mm_unpackhi_pd(sum, sum)));
      }
#else
      for (const int* a = ancestors + ancestors_start[k]; a != ancestors + ancestors_start[k + 1]; ++a) {
        const int j = *a;
        const Spatial cj = load6(J + 6 * j);
        M[k * nv + j] = dot(cj.linear, F.linear) + dot(cj.angular, F.angular);
      }
#endif
      M[k * nv + k] += model.armature[k];
      nle[k] = dot(column.linear, f.linear) + dot(column.angular, f.angular);
    }
    const int parent = static_cast<int>(model.parents[i]);
    if (parent > 0) {
      Inertia Yp = loadInertia(data.oYcrb[parent]);
      accumulate(Yp, Y);
      store(data.oYcrb[parent], Yp);
      store(forceData(data.of[parent]), load6(forceData(data.of[parent])) + f);
    }
  }
}

void treeDecompose(const SystemModel& part, pinocchio::Data& data) {
  // Pinocchio's cholesky::decompose, in its order of operations: for j from the last coordinate,
  // D_j = M_jj - sum_c U_jc^2 D_c and U_ij = (M_ij - sum_c U_ic U_jc D_c) / D_j for i among j's
  // ancestors, c over j's subtree. Its D_c U_jc went to a scratch vector written one entry at a
  // time and read two at a time by the dot products (a load spanning two stores, each j): 0.39 us
  // of Solo-12's step; here written and read one at a time (0.2 us).
  const Eigen::Index nv = data.M.rows();
  const double* M = data.M.data();
  double* U = data.U.data();  // column-major: U(i, c) at c * nv + i
  double* D = data.D.data();
  double* Dinv = data.Dinv.data();
  double* DUt = data.tmp.data();
  for (Eigen::Index j = nv - 1; j >= 0; --j) {
    const Eigen::Index nvt = data.nvSubtree_fromRow[static_cast<std::size_t>(j)] - 1;
    double d = M[j * nv + j];
    for (Eigen::Index c = 0; c < nvt; ++c) {
      const double u = U[(j + 1 + c) * nv + j];
      DUt[c] = u * D[j + 1 + c];
    }
    double sum = 0.0;
    for (Eigen::Index c = 0; c < nvt; ++c) sum += U[(j + 1 + c) * nv + j] * DUt[c];
    d -= sum;
    D[j] = d;
    Dinv[j] = 1.0 / d;
    // (j's ancestors past j itself)
    for (auto a = part.ancestors.begin() + part.ancestors_start[j] + 1; a != part.ancestors.begin() + part.ancestors_start[j + 1];
         ++a) {
      const int i = *a;
      double t = 0.0;
      for (Eigen::Index c = 0; c < nvt; ++c) t += U[(j + 1 + c) * nv + i] * DUt[c];
      U[j * nv + i] = (M[j * nv + i] - t) * Dinv[j];
    }
  }
}

void treeSolve(const SystemModel& part, const pinocchio::Data& data, Eigen::VectorXd& x) {
  // M^-1 x = U^-T D^-1 U^-1 x. U^-1 by columns from the last: x_j is final once every deeper
  // coordinate's share has left it, then its own share leaves its ancestors (independent updates;
  // Pinocchio's Uiv sums each row's dot product in one chain of multiply-adds, a free-flying base's
  // rows 12-17 terms long, bound by their latency: 0.14 us of Solo-12's step)
  const Eigen::Index nv = x.size();
  const double* U = data.U.data();  // column-major: U(i, j) at j * nv + i
  double* v = x.data();
  for (Eigen::Index j = nv - 1; j >= 1; --j) {
    const double vj = v[j];
    const double* Uj = U + j * nv;
    for (auto a = part.ancestors.begin() + part.ancestors_start[static_cast<std::size_t>(j)] + 1;
         a != part.ancestors.begin() + part.ancestors_start[static_cast<std::size_t>(j) + 1]; ++a)
      v[*a] -= Uj[*a] * vj;
  }
  const double* Dinv = data.Dinv.data();
  for (Eigen::Index j = 0; j < nv; ++j) v[j] *= Dinv[j];
  pinocchio::cholesky::Utiv(part.model, data, x);  // (its updates are independent already)
}

}  // namespace stages
}  // namespace stiction
