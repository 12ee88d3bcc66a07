"""One block against closed forms: open, stick, slip (eq. 66), planar, frictionless, bilateral."""
import numpy as np
import pytest

import stiction
from stiction import Constraint, ContactProblem, ContactState

from conftest import SOLVERS, spd


def solve1(A, b, constraint, solver="default", tol=1e-13):
    p = ContactProblem(np.asfortranarray(A, dtype=float), np.asarray(b, dtype=float), [constraint])
    r = stiction.solve(p, solver=solver, tol=tol, max_iter=5000)
    assert r.converged, (solver, r.residual, r.message)
    assert r.relative_residual + r.residual_bound <= tol  # what converged means (verdict.hpp)
    assert [s.name for s in r.stages][-1:] and r.stages[0].iterations >= 0
    return r


@pytest.mark.parametrize("solver", SOLVERS)
def test_sticking_block_with_a_huge_lambda_does_not_read_zero(solver):
    """lambda = 1e12 sticking, velocity error 1e-4: evaluated as lambda - P(lambda - w) the
    residual rounds to 0 (w is below lambda's rounding step); the verdict sees w."""
    A = np.diag([1e-12, 1e-12, 1e-12])
    lam = np.array([0.0, 0.0, 1e12])
    b = A @ lam + np.array([0.0, 0.0, 1e-4])  # u_n = -1e-4 at lam: not a solution
    p = ContactProblem(A, b, [Constraint.spatial_friction(0.5)])
    r = stiction.solve(p, solver=solver, warm_start=lam, max_iter=0)
    assert r.relative_residual == pytest.approx(1e-4 / np.linalg.norm(b), rel=1e-6)
    assert not r.converged


@pytest.mark.parametrize("solver", SOLVERS)
def test_open_contact_has_zero_force(rng, solver):
    A = spd(rng, 3)
    b = np.array([0.3, -0.2, -1.0])  # b_n < 0: the free motion separates
    r = solve1(A, b, Constraint.spatial_friction(0.5), solver)
    np.testing.assert_allclose(r.lam, 0.0, atol=1e-12)
    np.testing.assert_allclose(r.u, -b, atol=1e-12)
    assert r.states == [ContactState.open]


@pytest.mark.parametrize("solver", SOLVERS)
def test_stick_cancels_the_velocity(rng, solver):
    A = spd(rng, 3, cond=5.0)
    lam_true = np.array([0.1, -0.05, 1.0])  # inside the cone for mu = 0.5
    b = A @ lam_true
    r = solve1(A, b, Constraint.spatial_friction(0.5), solver)
    np.testing.assert_allclose(r.lam, lam_true, atol=1e-10)
    np.testing.assert_allclose(r.u, 0.0, atol=1e-10)
    assert r.states == [ContactState.stick]


@pytest.mark.parametrize("solver", SOLVERS)
def test_isotropic_slip_matches_projection_formula(solver):
    """A = diag(a_t, a_t, a_n): eq. 66 gives lambda_n = b_n / a_n and lambda_t the
    projection of A^-1 b onto the disk of radius mu lambda_n (the metric A U_eps with
    eps -> 0 keeps the normal component fixed)."""
    a_t, a_n, mu = 2.0, 5.0, 0.4
    A = np.diag([a_t, a_t, a_n])
    b = np.array([3.0, -4.0, 10.0])
    lam_hat = np.linalg.solve(A, b)
    lam_n = b[2] / a_n
    lam_t = lam_hat[:2] * min(1.0, mu * lam_n / np.linalg.norm(lam_hat[:2]))
    r = solve1(A, b, Constraint.spatial_friction(mu), solver)
    np.testing.assert_allclose(r.lam, [*lam_t, lam_n], rtol=1e-11)
    assert r.states == [ContactState.slip]
    assert abs(r.u[2]) < 1e-11  # a sliding contact neither hops nor sinks


def coulomb_slip_violation(A, b, mu, lam):
    u = A @ lam - b
    lt, ut = lam[:2], u[:2]
    return {
        "on_cone": abs(np.linalg.norm(lt) - mu * lam[2]) / lam[2],
        "u_n": abs(u[2]) / np.linalg.norm(b),
        # u_t opposite to lambda_t: cos(angle) = -1
        "direction": 1.0 + lt @ ut / (np.linalg.norm(lt) * np.linalg.norm(ut)),
    }


def all_slip_solutions(A, b, mu, samples=200_000):
    """Brute force: scan the slip angle, refine sign changes of the parallelism condition."""
    def lam_of(th):
        w = np.array([mu * np.cos(th), mu * np.sin(th), 1.0])
        return (b[2] / (A[2] @ w)) * w  # from u_n = 0

    def f(th):
        lam = lam_of(th)
        ut = (A @ lam - b)[:2]
        return ut[0] * np.sin(th) - ut[1] * np.cos(th)

    th = np.linspace(0, 2 * np.pi, samples, endpoint=False)
    w = np.stack([mu * np.cos(th), mu * np.sin(th), np.ones_like(th)])
    an = A[2] @ w
    lam = (b[2] / an) * w
    ut = (A @ lam - b[:, None])[:2]
    fv = ut[0] * np.sin(th) - ut[1] * np.cos(th)
    sols = []
    for i in np.nonzero(np.sign(fv) != np.sign(np.roll(fv, -1)))[0]:
        lo, hi = th[i], th[i] + 2 * np.pi / samples
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if np.sign(f(mid)) == np.sign(f(lo)) else (lo, mid)
        t = 0.5 * (lo + hi)
        cand = lam_of(t)
        u = A @ cand - b
        if A[2] @ np.array([mu * np.cos(t), mu * np.sin(t), 1]) > 0 and cand[:2] @ u[:2] < 0:
            sols.append(cand)
    return sols


def sliding_block(seed):
    """A general SPD block (tangent-normal coupling, anisotropy), mu = 0.3 and a b that slips
    (a draw that sticks is skipped)."""
    rng = np.random.default_rng(seed)
    A = spd(rng, 3, cond=20.0)
    mu = 0.3
    b = np.array([*rng.standard_normal(2) * 3.0, 1.0])
    lam_hat = np.linalg.solve(A, b)
    if lam_hat[2] > 0 and np.linalg.norm(lam_hat[:2]) <= mu * lam_hat[2]:
        pytest.skip("this draw sticks")
    return A, b, mu


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("solver", ["default", "nsgs", "newton"])
def test_anisotropic_coupled_slip_is_exact(seed, solver):
    """General SPD block (tangent-normal coupling, anisotropy): the slip solution meets
    all Coulomb conditions to round-off and is the one found by a brute-force scan."""
    A, b, mu = sliding_block(seed)
    r = solve1(A, b, Constraint.spatial_friction(mu), solver)
    viol = coulomb_slip_violation(A, b, mu, r.lam)
    assert viol["on_cone"] < 1e-11 and viol["u_n"] < 1e-11 and viol["direction"] < 1e-11, viol
    sols = all_slip_solutions(A, b, mu)
    assert sols, "the scan found no slip solution"
    assert min(np.linalg.norm(s - r.lam) for s in sols) < 1e-7 * np.linalg.norm(r.lam)


@pytest.mark.parametrize("solver", SOLVERS)
def test_planar_slip_closed_form(solver):
    """2 rows (t, n) with coupling c: slip to the + side gives lambda = lambda_n (mu, 1)
    with lambda_n = b_n / (a_n + mu c), from u_n = 0."""
    a_t, a_n, c, mu = 3.0, 2.0, 0.5, 0.3
    A = np.array([[a_t, c], [c, a_n]])
    b = np.array([5.0, 1.0])  # strong push along +t
    lam_n = b[1] / (a_n + mu * c)
    expected = np.array([mu * lam_n, lam_n])
    r = solve1(A, b, Constraint.planar_friction(mu), solver)
    np.testing.assert_allclose(r.lam, expected, rtol=1e-11)
    u = A @ r.lam - b
    assert u[0] < 0 and abs(u[1]) < 1e-11
    assert r.states == [ContactState.slip]


@pytest.mark.parametrize("solver", SOLVERS)
def test_planar_stick(solver):
    A = np.array([[3.0, 0.5], [0.5, 2.0]])
    lam_true = np.array([-0.2, 1.0])
    r = solve1(A, A @ lam_true, Constraint.planar_friction(0.5), solver)
    np.testing.assert_allclose(r.lam, lam_true, atol=1e-11)
    assert r.states == [ContactState.stick]


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("b", [2.0, -2.0])
def test_frictionless_unilateral(solver, b):
    r = solve1(np.array([[4.0]]), [b], Constraint.unilateral(), solver)
    assert r.lam[0] == pytest.approx(max(0.0, b / 4.0), abs=1e-13)
    assert r.states == [ContactState.closed if b > 0 else ContactState.open]


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("k", [1, 3, 6])
def test_bilateral_rows_solve_the_linear_system(rng, solver, k):
    A = spd(rng, k, cond=100.0)
    b = rng.standard_normal(k)
    r = solve1(A, b, Constraint.bilateral(k), solver)
    np.testing.assert_allclose(r.lam, np.linalg.solve(A, b), rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(r.u, 0.0, atol=1e-11)
    assert r.states == [ContactState.closed]


@pytest.mark.parametrize("solver", SOLVERS)
def test_zero_friction_spatial_contact(rng, solver):
    A = spd(rng, 3)
    b = np.array([1.0, 2.0, 3.0])
    r = solve1(A, b, Constraint.spatial_friction(0.0), solver)
    np.testing.assert_allclose(r.lam[:2], 0.0, atol=1e-12)
    assert r.lam[2] == pytest.approx(b[2] / A[2, 2], rel=1e-11)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("guess", ["near", "opposite", "tangent"])
def test_slip_from_a_sliding_guess_is_exact(seed, guess):
    """Gauss-Seidel hands the local solve the block's previous force; when that force slides,
    the slip direction is first sought by Newton from its direction (local_solve.cpp), and the
    quartic is solved only if that fails. From near the answer, from the opposite direction and
    from a purely tangential guess, the answer meets every Coulomb condition to round-off and
    is one of the brute-force scan's slip solutions."""
    A, b, mu = sliding_block(seed)
    sols = all_slip_solutions(A, b, mu)
    assert sols, "the scan found no slip solution"
    exact = sols[0]
    start = {"near": exact * (1 + 1e-3) + np.array([1e-3, -1e-3, 0.0]) * np.linalg.norm(exact),
             "opposite": np.array([-exact[0], -exact[1], exact[2]]),
             "tangent": np.array([exact[0], exact[1], 0.0])}[guess]
    p = ContactProblem(np.asfortranarray(A), b, [Constraint.spatial_friction(mu)])
    r = stiction.solve(p, solver="nsgs", tol=1e-13, max_iter=50, warm_start=start)
    assert r.converged, (r.residual, r.message)
    viol = coulomb_slip_violation(A, b, mu, r.lam)
    assert viol["on_cone"] < 1e-11 and viol["u_n"] < 1e-11 and viol["direction"] < 1e-11, viol
    assert min(np.linalg.norm(s - r.lam) for s in sols) < 1e-7 * np.linalg.norm(r.lam)
    if guess == "near":
        assert r.iterations == 1  # one sweep: the local solve is exact
