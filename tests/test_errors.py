"""Bad input raises ValueError naming the fault; non-convergence is reported, never hidden."""
import numpy as np
import pytest

import stiction
from stiction import Constraint, ContactProblem

A3 = np.diag([1.0, 1.0, 2.0])
B3 = np.array([0.0, 0.0, 1.0])
SPATIAL = [Constraint.spatial_friction(0.5)]


@pytest.mark.parametrize(
    "A, b, constraints, match",
    [
        (np.ones((3, 2)), B3, SPATIAL, "square"),
        (A3, np.ones(4), SPATIAL, "b has 4 entries"),
        (A3, B3, [Constraint.unilateral()], "rows"),
        (A3, B3, [Constraint.spatial_friction(-0.1)], "mu = -0.1"),
        (A3, B3, [Constraint.spatial_friction(float("nan"))], "mu"),
        (A3, B3, [Constraint.planar_friction(float("inf")), Constraint.unilateral()], "mu"),
        (np.where(np.eye(3) > 0, np.nan, 0.0), B3, SPATIAL, "NaN or infinite"),
        (A3, np.array([0.0, np.inf, 1.0]), SPATIAL, "b has NaN or infinite"),
        (A3 + np.triu(np.ones((3, 3)), 1) * 0.1, B3, SPATIAL, "not symmetric"),
        (np.diag([1.0, -1.0, 2.0]), B3, SPATIAL, "negative"),
    ],
)
def test_bad_problem_raises(A, b, constraints, match):
    with pytest.raises(ValueError, match=match):
        ContactProblem(np.asfortranarray(A), b, constraints)


def test_asymmetry_tolerance_is_explicit():
    A = A3.copy()
    A[0, 1] = 1e-6
    with pytest.raises(ValueError, match="not symmetric"):
        ContactProblem(A, B3, SPATIAL)
    p = ContactProblem(A, B3, SPATIAL, 1e-5)  # the caller accepts it knowingly
    assert p.asymmetry == pytest.approx(5e-7)


def test_bilateral_needs_rows():
    with pytest.raises(ValueError, match="at least 1 row"):
        Constraint.bilateral(0)


def test_constraints_must_be_constraints():
    with pytest.raises(ValueError, match="not a stiction.Constraint"):
        ContactProblem(A3, B3, ["spatial"])


def test_python_helpers_validate():
    with pytest.raises(ValueError, match="multiple of 3"):
        stiction.spatial_problem(np.eye(4), np.ones(4), 0.5)
    with pytest.raises(ValueError, match="2-D"):
        stiction.spatial_problem(np.ones(3), np.ones(3), 0.5)
    with pytest.raises(ValueError, match="numeric"):
        stiction.spatial_problem([["a"] * 3] * 3, np.ones(3), 0.5)


def test_bad_solver_settings_raise():
    p = ContactProblem(A3, B3, SPATIAL)
    with pytest.raises(ValueError, match="unknown solver 'pgs'"):
        stiction.solve(p, solver="pgs")
    with pytest.raises(ValueError, match="tolerance"):
        stiction.solve(p, tol=0.0)
    with pytest.raises(ValueError, match="initial lambda has 2 entries"):
        stiction.solve(p, warm_start=np.zeros(2))
    with pytest.raises(ValueError, match="NaN"):
        stiction.solve(p, warm_start=np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="warm_start"):
        stiction.solve(p, warm_start="previous")
    with pytest.raises(ValueError, match="set_b: expected 3"):
        p.set_b(np.ones(2))
    with pytest.raises(ValueError, match="lambda has 2 entries"):
        stiction.residual(p, np.zeros(2))


@pytest.mark.parametrize("solver", ["default", "nsgs", "newton", "admm"])
def test_non_convergence_is_reported_with_its_residual(solver):
    from stiction.problems import two_cube_stack

    p = two_cube_stack(1e4, 0.3, (0.5, 0.0, 0.0)).problem
    r = stiction.solve(p, solver=solver, tol=1e-14, max_iter=2)
    assert not r.converged
    assert r.residual > 1e-14 and np.isfinite(r.residual)
    assert r.residual == pytest.approx(stiction.residual(p, r.lam), rel=1e-12)
    assert r.message and r.message != "converged"
    assert np.all(np.isfinite(r.lam))


@pytest.mark.parametrize("solver", ["default", "nsgs", "newton", "admm"])
def test_zero_iterations_evaluates_the_guess(solver):
    p = ContactProblem(A3, B3, SPATIAL)
    guess = np.array([0.1, 0.0, 0.2])
    r = stiction.solve(p, solver=solver, max_iter=0, warm_start=guess)
    assert r.iterations == 0
    np.testing.assert_array_equal(r.lam, guess)
    assert r.residual == pytest.approx(stiction.residual(p, guess))


@pytest.mark.parametrize("solver", ["default", "nsgs", "newton", "admm"])
@pytest.mark.parametrize("warm", [None, "proxqp"])
def test_empty_problem_is_solved_trivially(solver, warm):
    """No active contact (a robot in the air): nothing to solve, no crash."""
    p = ContactProblem(np.zeros((0, 0)), np.zeros(0), [])
    r = stiction.solve(p, solver=solver, warm_start=warm)
    assert r.converged and r.lam.shape == (0,) and r.residual == 0.0


@pytest.mark.parametrize("solver", ["default", "nsgs", "newton", "admm"])
def test_rows_that_move_nothing_get_no_force(solver):
    """A zero diagonal block (a contact on something that cannot move) next to a real one:
    no division by zero, the idle contact gets lambda = 0 and the other its exact value."""
    A = np.zeros((6, 6))
    A[3:, 3:] = np.diag([1.0, 1.0, 2.0])
    b = np.array([0.0, 0.0, -1.0, 0.0, 0.0, 1.0])  # the idle contact separates
    p = ContactProblem(A, b, [Constraint.spatial_friction(0.5)] * 2)
    r = stiction.solve(p, solver=solver, tol=1e-12, max_iter=5000)
    assert r.converged, (r.residual, r.message)
    np.testing.assert_allclose(r.lam[:3], 0.0, atol=1e-12)
    assert r.lam[5] == pytest.approx(0.5, rel=1e-10)
