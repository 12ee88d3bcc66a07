"""A Delassus operator held sparse (scipy.sparse in, Eigen compressed columns inside): the same
answers as the dense one, at a cost in its stored entries."""
import numpy as np
import pytest
import scipy.sparse as sp

import stiction
from stiction import _core, problems


def many_cubes(n: int, seed: int = 0):
    """n separate cubes on the ground, some sliding: A is block diagonal (12 x 12 blocks)."""
    rng = np.random.default_rng(seed)
    parts = [problems.cube_on_ground(mu=0.5, velocity=(rng.uniform(-1, 1), rng.uniform(-1, 1), 0.0))
             for _ in range(n)]
    A = sp.block_diag([np.asarray(p.problem.A) for p in parts], format="csc")
    b = np.concatenate([np.asarray(p.problem.b) for p in parts])
    cons = [c for p in parts for c in p.problem.constraints]
    return A, b, cons


def test_sparse_and_dense_problems_agree():
    A, b, cons = many_cubes(6)
    sparse = _core.ContactProblem(A, b, cons)
    dense = _core.ContactProblem(A.toarray(), b, cons)
    assert sparse.is_sparse and not dense.is_sparse
    assert sparse.nnz == 6 * 144 and dense.nnz == 72 * 72
    np.testing.assert_array_equal(sparse.A, dense.A)
    assert sparse.asymmetry == dense.asymmetry
    for solver in ("nsgs", "admm", "default"):
        rs, rd = stiction.solve(sparse, solver=solver), stiction.solve(dense, solver=solver)
        assert rs.converged and rd.converged, (solver, rs.message, rd.message)
        np.testing.assert_allclose(rs.lam, rd.lam, rtol=1e-8, atol=1e-12 * np.abs(rd.lam).max())
        assert [s for s in rs.states] == [s for s in rd.states]
    lam = np.asarray(stiction.solve(dense).lam)
    ms, md = stiction.exact_law_measures(sparse, lam), stiction.exact_law_measures(dense, lam)
    assert ms.natural_map == pytest.approx(md.natural_map, rel=1e-12, abs=1e-300)
    assert stiction.residual(sparse, lam) == pytest.approx(stiction.residual(dense, lam), rel=1e-12, abs=1e-300)


@pytest.mark.parametrize("name", ["ccp", "nakaoka", "pyramid"])
def test_formulations_take_sparse_problems(name):
    A, b, cons = many_cubes(3, seed=1)
    rs = stiction.solve(_core.ContactProblem(A, b, cons), formulation=name)
    rd = stiction.solve(_core.ContactProblem(A.toarray(), b, cons), formulation=name)
    assert rs.own_converged and rd.own_converged
    np.testing.assert_allclose(rs.lam, rd.lam, rtol=1e-6, atol=1e-9 * np.abs(rd.lam).max())


def test_sparse_input_is_checked_like_dense_input():
    A, b, cons = many_cubes(2)
    bad = A.copy().tolil()
    bad[0, 5] += 1.0  # asymmetric
    with pytest.raises(ValueError, match="not symmetric"):
        _core.ContactProblem(bad.tocsc(), b, cons)
    neg = A.copy().tolil()
    neg[0, 0] = -1.0
    with pytest.raises(ValueError, match="negative"):
        _core.ContactProblem(neg.tocsc(), b, cons)
    nan = A.copy()
    nan.data[3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        _core.ContactProblem(nan, b, cons)
    indefinite = sp.csc_matrix(np.array([[1.0, 2.0], [2.0, 1.0]]))
    with pytest.raises(ValueError, match="not positive semi-definite"):
        _core.ContactProblem(indefinite, np.zeros(2), [_core.Constraint.unilateral()] * 2)
    with pytest.raises(ValueError, match="square"):
        _core.ContactProblem(sp.csc_matrix(np.ones((2, 3))), np.zeros(2), [_core.Constraint.unilateral()] * 2)


def test_an_infeasible_sparse_problem_is_reported_as_such():
    """A contact on something that cannot move (zero rows) pushed closed: no solution."""
    A, b, cons = many_cubes(2)
    A = A.tolil()
    A[0:3, :] = 0.0
    A[:, 0:3] = 0.0
    A = A.tocsc()
    A.eliminate_zeros()
    b = b.copy()
    b[2] = 1.0  # pushes the immovable contact closed
    r = stiction.solve(_core.ContactProblem(A, b, cons))
    assert r.status == _core.SolveStatus.infeasible and 0 in list(r.implicated_blocks)


def test_the_rounding_bound_of_a_sparse_product_counts_its_row_not_its_size():
    """The verdict's worst-case rounding bound of u = A lambda - b is gamma_k (|A||lambda| + |b|)
    with k the terms a row sums: 72 for these 72 rows held dense, 12 held sparse (block diagonal),
    so the sparse bound is 74/14 = 5.3x tighter at (nearly) the same lambda."""
    A, b, cons = many_cubes(6)
    sparse = _core.ContactProblem(A, b, cons)
    dense = _core.ContactProblem(A.toarray(), b, cons)
    rd, rs = stiction.solve(dense), stiction.solve(sparse)
    assert rs.converged and rd.converged
    np.testing.assert_allclose(rs.lam, rd.lam, rtol=1e-8, atol=1e-12 * np.abs(rd.lam).max())
    assert rs.residual_bound == pytest.approx(rd.residual_bound * (12 + 2) / (72 + 2), rel=0.05)
