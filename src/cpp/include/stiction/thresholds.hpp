// The size and sparsity thresholds that choose a path: which stages the default runs, whether a
// factorization is dense or sparse, whether the simulator holds A sparse. One place for all, each
// with where its value comes from (docs/solvers.md, docs/simulator.md, docs/scaling.md). Tuning
// parameters of one algorithm (shifts, margins, iteration counts) stay with that algorithm.
//
// Some share a value but not a meaning, and are named apart: kNewtonFirstRows (the rule's small
// class) and kDenseFactorRows (a factorization's dense/sparse cut) are both 64; the rule's
// kAdmmAboveRows (384) is not the simulator's kSparseDelassusRows (96, a storage choice); the
// rule's "sparse" (kSparseProblemDensity) and Newton's sparse Jacobian (kSparseJacobianDensity)
// used to borrow ADMM's factorization test (AdmmSolver::factorsSparsely) and now say so apart.
#pragma once

#include <Eigen/Core>

namespace stiction {

// ---- the default's rule (default_solver.hpp: defaultPlan; docs/solvers.md, "The default's rule",
//      measured on the 36 bundled FCLib problems, docs/default-rule-table.md)

/// Up to this many rows the default starts with Newton: a dense step on 12-64 rows costs less
/// than a few sweeps (the FCLib problems of <= 64 rows, 3-27: Newton alone fastest, 5-30 us).
constexpr Eigen::Index kNewtonFirstRows = 64;
/// Above this many rows ADMM, not Newton, follows a stalled NSGS, and a sparse A (kSparseProblemDensity
/// below) skips NSGS: the FCLib problems where Newton wins have <= 321 rows, those where ADMM
/// wins >= 648.
constexpr Eigen::Index kAdmmAboveRows = 384;
/// Above kAdmmAboveRows rows the rule calls a problem sparse (no NSGS prelude; sparse Newton, ADMM)
/// when A is held sparse or at most this fraction of it is nonzero (sparseEnough, admm.hpp).
/// Source: the FCLib problems of that size are 0.6-4 % nonzero (Capsules 1.6-2 %, Spheres 0.6 %,
/// KaplasTower 4 %), where skipping NSGS saved 10-100 ms; a dense A (100 %) keeps NSGS. No
/// problem between 4 % and 100 % above 384 rows was measured.
constexpr double kSparseProblemDensity = 0.1;
/// A large sparse problem whose A stores at most this many entries tries sparse Newton from the
/// guess before ADMM: Capsules (8.6-12.4k entries) 8-30 ms against ADMM's 18-42; KaplasTower
/// (117k) 255 ms against ADMM's 81 (its LU fills in). Raised from 50k (2026-12-08): pile-1000's
/// largest island (2124 rows, past 50k entries) got ADMM alone, which spent the simulator's 200
/// iterations at 3e-6 on steps 508-526, where sparse Newton converges (the step in 89 ms).
constexpr Eigen::Index kSparseNewtonEntries = 100000;

// ---- dense or sparse factorizations of A + shift I (ADMM, the sticking step) and of Newton's
//      Jacobian

/// Up to this many rows a dense A is factored densely whatever its sparsity (ADMM; the sticking
/// step): below, a dense Cholesky costs less than building and ordering a sparse copy.
constexpr Eigen::Index kDenseFactorRows = 64;
/// ADMM factors (and multiplies) a dense A sparsely above kDenseFactorRows rows with at most this
/// fraction of nonzeros (AdmmSolver::factorsSparsely). Source: the FCLib problems ADMM is the
/// rule's stage for are 0.6-4 % nonzero (Capsules 1.6-2 %, KaplasTower 4 %) and their Cholesky
/// factors barely fill in (Capsules-i122: 6.7k nonzeros against 395k dense; KaplasTower 150k
/// against 1.46M); no problem between 10 and 25 % was measured for ADMM (see kStickSparseDensity).
constexpr double kAdmmSparseDensity = 0.1;
/// The sticking step factors a dense A sparsely above kDenseFactorRows rows with at most this
/// fraction of nonzeros. Source: a tower's block-tridiagonal A (14-20 % nonzero): box-tower-20,
/// 2.7 ms -> ~0.3 ms per step (2026-12-02, docs/solvers.md); it matches the simulator's
/// kSparseDelassusDensity, so an A the simulator holds dense is not factored sparsely here but
/// for a tower.
constexpr double kStickSparseDensity = 0.25;
/// Above kSmallDenseLuRows rows Newton builds a sparse Jacobian (A's pattern widened to whole
/// block rows) and a sparse LU when A is held sparse or at most this fraction of it is nonzero.
/// Source: SpheresBox (768 rows, 3 %) took 31 ms per dense step; chosen with ADMM's value and not
/// measured between 4 % and 100 % (Confeti-ex13, 321 rows at 17 %, keeps the dense LU).
constexpr double kSparseJacobianDensity = 0.1;
/// Newton's systems up to this many rows go to its small dense LU (dense_lu.hpp), and only above
/// it does a sparse A get a sparse Jacobian and LU. Measured on random spatial problems, whole
/// Newton solves: 1.5x faster than Eigen's LU at 24-63 rows, 1.2x at 96-150, even at 192-240,
/// 0.9x at 321; SpheresBox (768 rows) took 31 ms per dense step.
constexpr Eigen::Index kSmallDenseLuRows = 192;

// ---- ADMM's own size classes (admm.cpp)

/// Above this many rows ADMM runs its stopping test (a product with A) every 4th iteration and
/// makes rho's residual-balancing threshold grow on each reversal: there a factorization costs
/// more than many iterations (Capsules-i122, 888 rows: 14 -> 7 refactorizations); below,
/// refactorizing is cheap and a growing threshold only slows convergence (the CCP on a two-cube
/// stack, 24 rows: 3258 iterations with it, 1405 without).
constexpr Eigen::Index kAdmmLargeRows = 64;

// ---- the simulator's storage of A (sim/dynamics.cpp; docs/simulator.md, "The world in parts")

/// A world of several parts holds A sparse above this many rows when at most
/// kSparseDelassusDensity of it is nonzero. Measured on cube grids: the dense A's assembly,
/// products and sweeps cost O(rows^2) where the sparse ones cost O(rows); at 128 contacts (384
/// rows) a step took 0.95 ms dense, 0.57 ms sparse; lowered from 384 to 96 rows (2026-12-02).
/// Not the rule's kAdmmAboveRows: this chooses a storage, the rule a stage.
constexpr Eigen::Index kSparseDelassusRows = 96;
/// ... and at most this fraction of A nonzero (a tower's block-tridiagonal A is 14-20 %; raised
/// from 10 % with the sticking step, whose sparse factor it feeds: kStickSparseDensity).
constexpr double kSparseDelassusDensity = 0.25;

// Islands (islands.hpp) of at least this many rows are solved alone; the smaller ones together, as
// one problem. Measured (2026-12-07, load ~3.5 on 2 cores): every island alone made a grid of 256
// lone cubes (1024 contacts) solve in 2x the whole problem's time (a driver and a verdict per
// 12-row island, where one sticking step takes the grid); pile-24's heaps are 60-250 rows.
constexpr Eigen::Index kIslandAloneRows = 64;
/// The small islands go together into groups of at most this many rows (filled in island order):
/// each group then stays in the default's medium class (<= kAdmmAboveRows: NSGS, then dense or
/// sparse Newton), where one group of all of pile-1000's (4458 rows, 50.7k entries) fell in the
/// large sparse class past kSparseNewtonEntries, and ADMM missed the tolerance at every step from
/// step 266 (2026-12-08).
constexpr Eigen::Index kIslandGroupRows = kAdmmAboveRows;

}  // namespace stiction
