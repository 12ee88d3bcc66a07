"""The verdict at every magnitude (issue 23): one problem with A and b scaled independently by
1e-300 ... 1e300, solved by every formulation and every exact solver.

Before: ||b|| below ~1e-154 squared to 0, so the relative residual and its rounding bound were 0
and lambda = 0 was "converged" where the true relative residual is 1 (all 11 pairs at b x 1e-300);
A x 1e-50 made solvable problems "infeasible" (the certificate compared ||lambda|| with ||b||
alone); A and b x 1e200 overflowed to "unresolvable". Now ||b|| is a scaled norm, the driver solves
extreme problems scaled by powers of two, the verdict is evaluated on (A, b 2^-c) at lambda 2^-c,
and the certificate measures lambda against ||b|| / max diag A.

What a scaled verdict may be: b scaled alone changes nothing the relative natural map sees (u and
lambda scale together), so the verdict must equal scale 1's (or be `unresolvable`); A scaled alone
changes what the natural map adds up (lambda ~ b / A against u ~ b): converged results must be true
(80-digit natural map of the scaled A, b at the returned lambda within the tolerance), and any other
verdict may only be `unresolvable`. Never a false `converged`, never `infeasible` (the problem has
a solution at every scale).
"""
import numpy as np
import pytest

import stiction
from stiction import Constraint, ContactProblem, SolveStatus

mpmath = pytest.importorskip("mpmath")
import exact_natural_map  # noqa: E402  (after the mpmath skip)

TOL = 1e-8
# Powers of two near 1e+-30, 1e+-50, 1e+-100, 1e+-150, 1e+-200, 1e+-300: the driver's scaling by powers
# of two then gives the algorithms exactly the problem of scale 1 (its max diag A and ||b|| lie in
# [0.5, 1), where nothing is scaled).
EXPONENTS = [-996, -664, -498, -332, -166, -100, 100, 166, 332, 498, 664, 996]
# Powers of ten: the scaled problem is then scale 1's up to a factor in [0.5, 2) on A and on b, so an
# algorithm with absolute constants (Pinocchio's tolerances) may end elsewhere near its tolerance;
# what must hold there is honesty (no false converged, no infeasible) and the exact solvers' verdicts.
DECIMALS = [1e-300, 1e-200, 1e-150, 1e-100, 1e-50, 1e-20, 1e20, 1e50, 1e100, 1e150, 1e200, 1e300]
PAIRS = [("exact", s) for s in ("default", "nsgs", "admm", "newton")] + [
    (f, None) for f in ("ccp", "nakaoka", "pyramid", "penalty", "pinocchio-admm", "pinocchio-pgs",
                        "pinocchio-admm-ccp")]


def base_problem():
    """Three spatial contacts: one sticking, one sliding, one opening (mixed states, so the verdict
    goes through every branch of the natural map); A = J J^T of a 9-DoF body chain, well conditioned."""
    rng = np.random.default_rng(7)
    J = rng.standard_normal((9, 9))
    A = J @ J.T / 9.0 + 0.1 * np.eye(9)
    lam = np.array([0.1, -0.05, 1.0,   0.4, 0.3, 1.0,   0.0, 0.0, 0.0])  # inside, on the boundary, open
    mu = np.array([0.5, 0.5, 0.5])
    # u: 0 at the sticking contact, sliding opposite lam_t at the second, separating at the third
    u = np.array([0.0, 0.0, 0.0,   -0.8, -0.6, 0.0,   0.2, -0.1, 0.5])
    b = A @ lam - u
    # max diag A and ||b|| in [0.5, 1): the scale the driver scales extreme problems to
    return A / 2.0 ** np.frexp(A.diagonal().max())[1], b / 2.0 ** np.frexp(np.linalg.norm(b))[1], mu


def natural_map_80_digits(A, b, mus, lam):
    """The relative natural map ||lam - P_C(...)|| / ||b|| in 80 digits (tests/exact_natural_map.py)."""
    return exact_natural_map.relative_natural_map_80_digits(A, b, mus, lam)


def solve(A, b, mu, formulation, solver):
    p = ContactProblem(np.asfortranarray(A), b, [Constraint.spatial_friction(float(m)) for m in mu])
    kw = {"h": 0.01} if formulation == "penalty" else {}
    if solver is not None:
        kw["solver"] = solver
    return stiction.solve(p, tol=TOL, max_iter=20000, formulation=formulation, **kw)


@pytest.fixture(scope="module")
def at_scale_one():
    A, b, mu = base_problem()
    return {pair: solve(A, b, mu, *pair) for pair in PAIRS}


def test_the_issue_example_is_not_converged_at_lambda_zero():
    """A = diag(1, 1, 2), b = (0, 0, 1e-200): lambda = 0 has relative residual 1 (before: 0, converged)."""
    p = ContactProblem(np.diag([1.0, 1.0, 2.0]), np.array([0.0, 0.0, 1e-200]), [Constraint.spatial_friction(0.5)])
    s = stiction.SolverSettings()
    s.max_iterations = 0  # lambda stays 0
    r = stiction.Solver("nsgs").solve(p, s)
    assert r.relative_residual == pytest.approx(1.0, rel=1e-12)
    assert r.status == SolveStatus.not_converged and not r.converged
    r = stiction.solve(p)
    assert r.converged and r.lam[2] == pytest.approx(0.5e-200, rel=1e-12)
    assert r.u[2] == pytest.approx(0.0, abs=1e-210)


def check(A, b, mu, which, at_scale_one, compare):
    """The failures of every pair at this (A, b); `compare(pair)`: whether its verdict must match scale 1's."""
    failures = []
    for pair in PAIRS:
        ref = at_scale_one[pair]
        r = solve(A, b, mu, *pair)
        name = "/".join(x for x in pair if x)
        if r.status == SolveStatus.infeasible:
            failures.append(f"{name}: infeasible ({r.message})")
            continue
        if r.converged:
            true = natural_map_80_digits(A, b, mu, r.lam)
            if not true <= TOL:
                failures.append(f"{name}: converged, but the 80-digit relative residual is {mpmath.nstr(true, 3)}")
        if which == "b" and np.isfinite(r.relative_residual):
            # u and the exact-law measures came back to the caller's scale (computed on b 2^-c)
            big = np.abs(b).max()
            b_norm = np.linalg.norm(b / big) * big  # (numpy's own norm squares 1e-300 to 0)
            if not np.allclose(r.u, A @ r.lam - b, rtol=1e-9, atol=1e-9 * b_norm):
                failures.append(f"{name}: u is not A lambda - b")
            law = r.exact_law
            if not (law.relative_residual == pytest.approx(r.relative_residual, rel=1e-6, abs=1e-15)
                    and law.b_norm == pytest.approx(b_norm, rel=1e-12)):
                failures.append(f"{name}: exact_law {law} against relative residual {r.relative_residual}")
        if r.status == SolveStatus.unresolvable or not compare(pair):
            continue
        # b alone: the same problem for the relative natural map, so the same verdict. A (alone or with
        # b): the algorithm solves the same problem, but the natural map weighs lambda ~ b / A against
        # u ~ b differently: where scale 1 is not converged, a (verified) converged is true too.
        if which != "b" and r.status == SolveStatus.converged:
            continue
        if r.status != ref.status:
            failures.append(f"{name}: {r.status} (scale 1: {ref.status}; {r.message})")
    return failures


@pytest.mark.parametrize("which", ["A", "b", "A and b"])
@pytest.mark.parametrize("exponent", EXPONENTS)
def test_verdict_at_every_power_of_two_scale(at_scale_one, which, exponent):
    A, b, mu = base_problem()
    if "A" in which:
        A = A * 2.0 ** exponent
    if "b" in which:
        b = b * 2.0 ** exponent
    # (penalty is solved as given, its K and h having units: only honesty is asked of it)
    assert not check(A, b, mu, which, at_scale_one, lambda pair: pair[0] != "penalty")


@pytest.mark.parametrize("which", ["A", "b", "A and b"])
@pytest.mark.parametrize("scale", DECIMALS)
def test_verdict_at_every_decimal_scale(at_scale_one, which, scale):
    A, b, mu = base_problem()
    if "A" in which:
        A = A * scale
    if "b" in which:
        b = b * scale
    assert not check(A, b, mu, which, at_scale_one, lambda pair: pair[0] == "exact")
