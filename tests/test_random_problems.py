"""Random problems A = J M^-1 J^T with mixed constraint kinds, full rank and rank-deficient."""
import numpy as np
import pytest

import stiction
from stiction.problems import random_problem

from conftest import SOLVERS

MIXES = {
    "spatial": ["spatial"] * 6,
    "mixed": ["spatial", "planar", "unilateral", "bilateral3", "spatial", "bilateral1", "planar", "unilateral"],
    "planar_scene": ["planar"] * 5 + ["bilateral2"],
}


def check_ncp(problem, lam, tol):
    """The conditions of eq. 73-77 block by block, independently of the C++ residual."""
    u = problem.A @ lam - problem.b
    off = problem.offsets
    for i, c in enumerate(problem.constraints):
        l, v = lam[off[i]:off[i + 1]], u[off[i]:off[i + 1]]
        kind = c.kind.name
        if kind == "bilateral":
            assert np.abs(v).max() <= tol
            continue
        ln, un = l[-1], v[-1]
        lt, ut = l[:-1], v[:-1]
        assert ln >= -tol and un >= -tol and abs(ln * un) <= tol * (1 + abs(ln) + abs(un))
        if kind == "unilateral":
            continue
        assert np.linalg.norm(lt) <= c.mu * ln + tol
        if ln > tol:
            gap = c.mu * ln - np.linalg.norm(lt)
            # stick (u_t = 0) or slip (on the cone, u_t opposite to lambda_t)
            assert np.linalg.norm(ut) <= tol * 10 or (gap <= tol * 10 and np.allclose(
                lt * np.linalg.norm(ut), -c.mu * ln * ut, atol=10 * tol * (1 + np.linalg.norm(ut))))


@pytest.mark.parametrize("mix", sorted(MIXES))
@pytest.mark.parametrize("rank", ["full", "deficient"])
@pytest.mark.parametrize("solver", SOLVERS)
def test_random_problems_solve_to_1e_10(mix, rank, solver):
    kinds = MIXES[mix]
    rows = rows_of(kinds)
    failures = []
    for seed in range(8):
        rng = np.random.default_rng(seed)
        dofs = rows + 3 if rank == "full" else max(3, rows // 2)
        if rank == "deficient" and "bilateral" in " ".join(kinds):
            dofs = rows - 2  # keep the bilateral rows solvable
        p = random_problem(rng, kinds, dofs, mu_range=(0.1, 0.8))
        r = stiction.solve(p, solver=solver, tol=1e-10, max_iter=20000)
        if not r.converged:
            failures.append((seed, r.residual, r.message))
            continue
        assert r.residual <= 1e-10
        # the verdict: the residual plus its rounding bound is within the tolerance
        assert r.status == stiction.SolveStatus.converged
        assert r.relative_residual + r.residual_bound <= 1e-10 and r.residual_bound < 1e-12
        check_ncp(p, r.lam, 1e-7)
    # ADMM is first-order: allow it one slow draw in eight, never the others.
    assert len(failures) <= (1 if solver == "admm" else 0), failures


def rows_of(kinds):
    return sum(3 if k == "spatial" else 2 if k == "planar" else 1 if k == "unilateral" else int(k[-1])
               for k in kinds)


@pytest.mark.parametrize("mix", ["spatial", "mixed"])
def test_solvers_agree_where_the_solution_is_unique(mix):
    """Full-rank A and small mu: the NCP has one solution, every algorithm finds it.
    (With redundant rows and larger mu the exact Coulomb problem can have several,
    so there only the residual is compared.)"""
    for seed in range(6):
        kinds = MIXES[mix]
        p = random_problem(np.random.default_rng(100 + seed), kinds, rows_of(kinds) + 4, mu_range=(0.05, 0.3))
        lams = [stiction.solve(p, solver=s, tol=1e-13, max_iter=50000).lam for s in ("nsgs", "newton", "admm")]
        for lam in lams[1:]:
            np.testing.assert_allclose(lam, lams[0], atol=1e-8 * np.abs(lams[0]).max())


@pytest.mark.parametrize("mix", [["spatial"] * 5, ["spatial", "bilateral3", "spatial", "bilateral6", "spatial"]])
def test_agrees_with_pinocchio_admm(mix):
    """Pinocchio's ADMMConstraintSolver with solve_ncp=True solves the same exact Coulomb
    NCP: on full-rank problems (unique solution) the impulses agree."""
    from stiction.baselines import pinocchio_solve

    for seed in range(6):
        p = random_problem(np.random.default_rng(200 + seed), mix, rows_of(mix) + 4, mu_range=(0.1, 0.5))
        ours = stiction.solve(p, tol=1e-13, max_iter=5000)
        theirs = pinocchio_solve(p, "admm", tol=1e-12, max_iter=20000)
        assert ours.converged and theirs.residual < 1e-9, (ours.residual, theirs.residual)
        np.testing.assert_allclose(ours.lam, theirs.lam, atol=1e-7 * np.abs(ours.lam).max())


@pytest.mark.parametrize("sliding", [False, True])
def test_agrees_with_pinocchio_admm_on_the_rank_deficient_cube(sliding):
    """A cube on 4 corners: lambda is not unique (rank 6 of 12), the velocities are."""
    from stiction.baselines import pinocchio_solve
    from stiction.problems import cube_on_ground

    p = cube_on_ground(mu=0.3, velocity=(0.5 if sliding else 0.0, 0.0, 0.0)).problem
    ours = stiction.solve(p, tol=1e-13)
    theirs = pinocchio_solve(p, "admm", tol=1e-12, max_iter=20000)
    np.testing.assert_allclose(ours.u, p.A @ theirs.lam - p.b, atol=1e-9)


@pytest.mark.parametrize("m", [1, 2, 3, 9, 27, 64, 192])
def test_newton_small_lu_solves_systems_that_need_pivoting(m):
    """The Newton step's own dense LU (dense_lu.hpp, SmallDenseLU, up to 192 rows): a generalized
    Jacobian of the natural map is not symmetric and its diagonal can vanish (a sliding block's
    I - JP + kappa JP A rows), so rows must be swapped. Matrices with a zero diagonal, checked
    against numpy; without the row swaps the 2 x 2 case divides by zero and the others lose
    every digit."""
    rng = np.random.default_rng(m)
    for trial in range(20):
        a = rng.standard_normal((m, m))
        if m > 1:
            a[np.diag_indices(m)] = 0.0
        x = rng.standard_normal(m)
        rhs = a @ x
        got = stiction._core._small_dense_lu_solve(a, rhs)
        expected = np.linalg.solve(a, rhs)
        cond = np.linalg.cond(a)
        assert np.linalg.norm(got - expected) <= 1e-13 * cond * np.linalg.norm(expected), (trial, cond)
    # a singular matrix gives non-finite values, which Newton reports as a singular system
    a = np.ones((m, m))
    if m > 1:
        assert not np.isfinite(stiction._core._small_dense_lu_solve(a, np.arange(m, dtype=float))).all()
    with pytest.raises(ValueError, match="at most 192 rows"):
        stiction._core._small_dense_lu_solve(np.eye(193), np.ones(193))


LU_AGAINST_NUMPY = """
import sys, numpy as np, stiction
worst = 0.0
for m in (2, 5, 27, 64, 150):
    rng = np.random.default_rng(m)
    a = rng.standard_normal((m, m)); a[np.diag_indices(m)] = 0.0
    x = rng.standard_normal(m)
    got = stiction._core._small_dense_lu_solve(a, a @ x)
    worst = max(worst, np.linalg.norm(got - x) / (np.linalg.cond(a) * np.linalg.norm(x)))
print(worst)
"""


@pytest.mark.parametrize("kernels", ["0", "1"])
def test_newton_small_lu_is_the_same_with_and_without_vector_kernels(kernels):
    """The LU's column updates run in an AVX2/FMA kernel where the processor has it
    (STICTION_VECTOR_KERNELS=0: the portable loop); both solve to rounding."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, STICTION_VECTOR_KERNELS=kernels)
    out = subprocess.run([sys.executable, "-c", LU_AGAINST_NUMPY], capture_output=True, text=True, env=env, check=True)
    assert float(out.stdout) <= 1e-14, out.stdout
