"""Box rows (ConstraintKind.box, issue 24): a 1-row block with C = [lower, upper], lower <= 0 <= upper,
so that eq. 65 reads u = A lambda - b in -N_C(lambda): box complementarity (u = 0 strictly inside,
u <= 0 at upper, u >= 0 at lower), a joint's dry friction or an actuator's effort limit.

Every answer is checked against an independent computation: the closed form of one row, and for
problems of box and unilateral rows alone (a convex QP, min 1/2 l'A l - b'l on the box) the KKT point
found by enumerating the active sets (m <= 6) or by scipy's L-BFGS-B polished on its active set,
verified by its own KKT conditions. Mixed with friction cones, box complementarity is checked row by
row from A, b and lambda in the test itself."""
import itertools
import math
import types

import numpy as np
import pytest
from scipy.optimize import minimize

import stiction
from stiction import Constraint, ContactProblem, ContactState, _core
from stiction.problems import random_problem

from conftest import spd

# Every exact solver name, and the default's ProxQP warm start.
EXACT = [(name, None) for name in stiction.solver_names()] + [("default", "proxqp"), ("newton", "proxqp")]
TOL = 1e-12


def solve(problem, solver="default", warm_start=None, tol=TOL, **kw):
    return stiction.solve(problem, solver=solver, warm_start=warm_start, tol=tol, max_iter=20000, **kw)


# ------------------------------------------------------------------ the independent QP solution

def kkt_point(A, b, lo, hi, state):
    """lambda with rows at their lower (state -1) or upper (+1) bound fixed, the free rows (0) solving
    their rows of A lambda = b; None unless the KKT conditions of the box QP hold there: free rows
    inside [lo, hi], u = A lambda - b >= 0 at lower bounds, <= 0 at upper bounds."""
    m = len(b)
    lam = np.where(state < 0, lo, np.where(state > 0, hi, 0.0))
    if not np.all(np.isfinite(lam[state != 0])):
        return None
    free = state == 0
    if free.any():
        fixed = ~free
        rhs = b[free] - A[np.ix_(free, fixed)] @ lam[fixed]
        lam[free] = np.linalg.solve(A[np.ix_(free, free)], rhs)
    u = A @ lam - b
    slack = 1e-12 * (1.0 + np.abs(lam).max() + np.abs(b).max())
    ok = np.all(lam[free] >= lo[free] - slack) and np.all(lam[free] <= hi[free] + slack)
    ok = ok and np.all(u[state < 0] >= -slack) and np.all(u[state > 0] <= slack)
    return lam if ok else None


def qp_by_enumeration(A, b, lo, hi):
    """The box QP's solution by trying every active set (3^m, or 2 per unilateral row)."""
    choices = [(-1, 0) if math.isinf(h) else (-1, 0, 1) for h in hi]
    found = [lam for state in itertools.product(*choices)
             if (lam := kkt_point(A, b, lo, hi, np.array(state))) is not None]
    assert found, "no active set satisfies the KKT conditions"
    for lam in found[1:]:  # SPD A: one solution
        np.testing.assert_allclose(lam, found[0], rtol=1e-9, atol=1e-12)
    return found[0]


def qp_by_lbfgsb(A, b, lo, hi):
    """L-BFGS-B at tight tolerance, then the exact point of the active set it found (KKT-checked)."""
    bounds = [(l, None if math.isinf(h) else h) for l, h in zip(lo, hi)]
    res = minimize(lambda x: (0.5 * x @ A @ x - b @ x, A @ x - b), np.zeros(len(b)), jac=True,
                   method="L-BFGS-B", bounds=bounds, options={"ftol": 1e-15, "gtol": 1e-13, "maxiter": 10000})
    x = res.x
    width = 1e-7 * (1.0 + np.abs(x).max())
    state = np.where(x <= lo + width, -1, np.where(x >= hi - width, 1, 0))
    lam = kkt_point(A, b, lo, hi, state)
    assert lam is not None, "L-BFGS-B's active set does not satisfy the KKT conditions"
    return lam


def box_qp_problem(rng, m, unilateral=0):
    """Random SPD A (m rows: m - unilateral box rows, then unilateral ones), b, bounds drawn so that
    some rows end inside their interval and some at each bound."""
    A = spd(rng, m, cond=float(rng.uniform(2.0, 50.0)))
    b = rng.standard_normal(m)
    free = np.linalg.solve(A, b)  # the unconstrained minimum: bounds around its scale
    scale = np.abs(free).max()
    nbox = m - unilateral
    lo = np.concatenate([-rng.uniform(0.05, 1.0, nbox) * scale, np.zeros(unilateral)])
    hi = np.concatenate([rng.uniform(0.05, 1.0, nbox) * scale, np.full(unilateral, np.inf)])
    cons = [Constraint.box(float(l), float(h)) for l, h in zip(lo[:nbox], hi[:nbox])]
    cons += [Constraint.unilateral() for _ in range(unilateral)]
    return ContactProblem(np.asfortranarray(A), b, cons), A, b, lo, hi


def box_natural_map(lam, u, lo, hi):
    """lambda - clamp(lambda - u, lo, hi), row by row (the natural map of box complementarity)."""
    return lam - np.clip(lam - u, lo, hi)


# ------------------------------------------------------------------ one row: the closed form

@pytest.mark.parametrize("solver, warm", EXACT)
def test_one_box_row_is_the_clamped_ratio(solver, warm):
    rng = np.random.default_rng(24)
    hit = {"lower": 0, "upper": 0, "inside": 0}
    for _ in range(30):
        a = float(rng.uniform(0.1, 10.0))
        b = float(rng.standard_normal() * 3.0)
        lo, hi = -float(rng.uniform(0.0, 1.0)), float(rng.uniform(0.0, 1.0))
        expected = min(max(b / a, lo), hi)
        hit["lower" if expected == lo else "upper" if expected == hi else "inside"] += 1
        p = ContactProblem(np.array([[a]], order="F"), np.array([b]), [Constraint.box(lo, hi)])
        r = solve(p, solver, warm)
        assert r.converged, r.message
        assert r.lam[0] == pytest.approx(expected, rel=1e-12, abs=1e-15)
    assert min(hit.values()) >= 3  # both bounds and the interior were exercised


def test_a_box_row_that_moves_nothing_goes_to_the_bound_its_velocity_pushes():
    # A = 0 on the box row (a joint the contacts lock): u = -b whatever lambda; b > 0 (u < 0) needs
    # lambda = upper, b < 0 needs lambda = lower; NSGS's local solve and Newton's agree.
    A = np.asfortranarray(np.diag([0.0, 2.0]))
    for b0, expected in ((0.5, 0.7), (-0.5, -0.3)):
        p = ContactProblem(A, np.array([b0, 1.0]), [Constraint.box(-0.3, 0.7), Constraint.unilateral()])
        for solver in stiction.solver_names():
            r = solve(p, solver)
            assert r.converged, (solver, r.message)
            np.testing.assert_allclose(r.lam, [expected, 0.5], rtol=1e-12)


# ------------------------------------------------------------------ box QPs: every exact solver

@pytest.mark.parametrize("solver, warm", EXACT)
@pytest.mark.parametrize("m, reference, draws", [(m, "enumeration", 4) for m in (2, 3, 4, 5, 6)] +
                         [(m, "lbfgsb", 3) for m in (8, 10, 12)])
def test_box_qp_matches_an_independent_qp_solution(solver, warm, m, reference, draws):
    """Box-only problems are the box QP: against the enumeration of every active set (m <= 6) or
    scipy's L-BFGS-B polished on its active set (m = 8..12)."""
    rng = np.random.default_rng((1000 if reference == "enumeration" else 2000) + m)
    qp = qp_by_enumeration if reference == "enumeration" else qp_by_lbfgsb
    for _ in range(draws):
        p, A, b, lo, hi = box_qp_problem(rng, m)
        expected = qp(A, b, lo, hi)
        r = solve(p, solver, warm)
        assert r.converged, r.message
        np.testing.assert_allclose(r.lam, expected, rtol=0, atol=1e-8 * np.linalg.norm(expected))


@pytest.mark.parametrize("solver, warm", EXACT)
@pytest.mark.parametrize("m, unilateral", [(3, 1), (5, 2), (6, 3), (10, 4), (12, 6)])
def test_box_and_unilateral_rows_match_the_qp(solver, warm, m, unilateral):
    rng = np.random.default_rng(3000 + m)
    for _ in range(3):
        p, A, b, lo, hi = box_qp_problem(rng, m, unilateral)
        expected = (qp_by_enumeration if m <= 6 else qp_by_lbfgsb)(A, b, lo, hi)
        r = solve(p, solver, warm)
        assert r.converged, r.message
        np.testing.assert_allclose(r.lam, expected, rtol=0, atol=1e-8 * np.linalg.norm(expected))


def test_the_independent_qp_solutions_agree():
    # the two references against each other, where both apply
    rng = np.random.default_rng(5)
    for m, unilateral in ((4, 0), (5, 2), (6, 1)):
        _, A, b, lo, hi = box_qp_problem(rng, m, unilateral)
        np.testing.assert_allclose(qp_by_lbfgsb(A, b, lo, hi), qp_by_enumeration(A, b, lo, hi), rtol=1e-10,
                                   atol=1e-12)


def test_an_extreme_scale_scales_the_intervals_too():
    # (A 2^100, b 2^-90, bounds 2^-190 [lo, hi]): outside the driver's 2^+-30 window it solves the problem
    # scaled by powers of two, whose intervals must scale with lambda: lambda = 2^-190 lambda*.
    rng = np.random.default_rng(7)
    _, A, b, lo, hi = box_qp_problem(rng, 5)
    expected = qp_by_enumeration(A, b, lo, hi)
    sa, sb = 2.0 ** 100, 2.0 ** -90
    cons = [Constraint.box(float(l * sb / sa), float(h * sb / sa)) for l, h in zip(lo, hi)]
    p = ContactProblem(np.asfortranarray(A * sa), b * sb, cons)
    for solver, warm in EXACT:
        r = solve(p, solver, warm)
        assert r.converged, (solver, r.message)
        np.testing.assert_allclose(r.lam * (sa / sb), expected, rtol=0, atol=1e-8 * np.linalg.norm(expected))
        e = stiction.exact_law_measures(p, r.lam)
        assert e.relative_residual <= 1e-10


# ------------------------------------------------------------------ the sticking step

def test_the_sticking_step_takes_box_rows_inside_their_interval():
    # Every box row strictly inside at A^-1 b: the default's all-stick stage solves it, cold (b / A_ii
    # inside the interval predicts it at zero) and from an interior guess.
    rng = np.random.default_rng(11)
    A = spd(rng, 6, cond=5.0)
    b = rng.standard_normal(6)
    exact = np.linalg.solve(A, b)
    cons = [Constraint.box(float(-2 * abs(x) - 1), float(2 * abs(x) + 1)) for x in exact]
    p = ContactProblem(np.asfortranarray(A), b, cons)
    for warm in (None, 0.5 * exact):
        r = solve(p, "default", warm)
        assert r.converged and r.message == "converged (sticking step)", r.message
        np.testing.assert_allclose(r.lam, exact, rtol=1e-10)
        assert all(s == ContactState.stick for s in r.states)


# ------------------------------------------------------------------ more rows than velocities

def standing_robot_problem(seed, rows_on_bounds=0, irreducible=0.03, offset=3.0):
    """A legged robot standing with dry friction on every joint, as the simulator poses it: 18
    velocities (a free base and 12 joints), 4 spatial contacts and 12 box rows J = e_dof, so
    A = J M^-1 J^T has 24 rows of rank 18 (statically indeterminate). The answer lam_stick sticks
    everywhere (contacts inside their cones, friction rows inside |lambda| <= tau, `rows_on_bounds` of
    them exactly on a bound with u = 0: a joint held by exactly its friction limit). b = A lam_stick
    plus `irreducible` times the tolerance along A's null space (what a computed A's rounding leaves
    out of its range), and the guess lam_stick moved along A's range by `offset` times the tolerance
    (the previous step's answer). Returns the problem, the guess and the tolerance."""
    rng = np.random.default_rng(seed)
    nv, contacts, joints, mu, tau, tol = 18, 4, 12, 0.8, 5e-3, 1e-10
    M = spd(rng, nv, cond=20.0)
    J = np.vstack([rng.standard_normal((3 * contacts, nv)), np.hstack([np.zeros((joints, 6)), np.eye(joints)])])
    A = J @ np.linalg.solve(M, J.T)
    A = 0.5 * (A + A.T)
    lam = np.empty(3 * contacts + joints)
    for c in range(contacts):
        normal, angle = rng.uniform(1.0, 2.0), rng.uniform(0.0, 2.0 * np.pi)
        lam[3 * c:3 * c + 3] = [0.3 * mu * normal * np.cos(angle), 0.3 * mu * normal * np.sin(angle), normal]
    lam[3 * contacts:] = rng.uniform(-0.8, 0.8, joints) * tau
    lam[3 * contacts:3 * contacts + rows_on_bounds] = tau * np.sign(rng.standard_normal(rows_on_bounds))
    U, sigma, _ = np.linalg.svd(A)
    assert sigma[nv - 1] > 1e-8 * sigma[0] and sigma[nv] < 1e-12 * sigma[0]  # rank 18 of 24
    b = A @ lam
    threshold = tol * np.linalg.norm(b)
    null = U[:, nv:] @ rng.standard_normal(len(b) - nv)
    b = b + irreducible * threshold * null / np.linalg.norm(null)
    along_range = U[:, :nv] @ rng.standard_normal(nv)
    guess = lam + offset * threshold * along_range / np.linalg.norm(A @ along_range)
    cons = [Constraint.spatial_friction(mu)] * contacts + [Constraint.box(-tau, tau)] * joints
    return ContactProblem(np.asfortranarray(A), b, cons), guess, tol


def natural_map(p, lam):
    """||lambda - P_C(lambda - (u + mu |u_t| e_n))||, De Saxce's cones (eq. 76-77) and the boxes'
    clamp, from A, b and lambda alone."""
    A, b = np.asarray(p.A), np.asarray(p.b)
    u = A @ lam - b
    r = []
    for c, o in zip(p.constraints, p.offsets):
        if c.kind == stiction.ConstraintKind.box:
            r.append(box_natural_map(lam[o], u[o], c.lower, c.upper))
            continue
        w = u[o:o + 3] + np.array([0.0, 0.0, c.mu * np.linalg.norm(u[o:o + 2])])
        z = lam[o:o + 3] - w
        t, n = np.linalg.norm(z[:2]), z[2]
        if t <= c.mu * n:
            proj = z
        elif c.mu * t <= -n:
            proj = np.zeros(3)
        else:
            a = (n + c.mu * t) / (1.0 + c.mu ** 2)
            proj = np.array([c.mu * a * z[0] / t, c.mu * a * z[1] / t, a])
        r.extend(lam[o:o + 3] - proj)
    return float(np.linalg.norm(r))


def assert_sticks_everywhere(p, lam, tol):
    b = np.asarray(p.b)
    scale = 2.0 * tol * np.linalg.norm(b)
    assert natural_map(p, lam) <= scale
    assert np.linalg.norm(np.asarray(p.A) @ lam - b) <= scale  # u = 0: every row holds
    for c, o in zip(p.constraints, p.offsets):
        if c.kind == stiction.ConstraintKind.box:
            assert c.lower - scale <= lam[o] <= c.upper + scale
        else:
            assert np.linalg.norm(lam[o:o + 2]) < c.mu * lam[o + 2]


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("offset", [3.0, 30.0])
def test_newton_converges_where_the_rows_outnumber_the_velocities(seed, offset):
    # dF = K A is singular at every all-stick iterate, and the part of F no lambda cancels (3 % of the
    # tolerance here, b's rounding out of A's range in a simulator's A) became a step as large as lambda
    # along A's null space: out of the boxes, no descent (measured on anymal-stand with joint friction;
    # here 14 of these 16 stalled after 5-22 steps). The step filtered to J's range converges in one.
    p, guess, tol = standing_robot_problem(seed, offset=offset)
    r = solve(p, "newton", guess, tol=tol)
    assert r.converged and r.iterations <= 2, (r.message, r.iterations)
    assert_sticks_everywhere(p, r.lam, tol)


@pytest.mark.parametrize("seed", range(6))
def test_the_sticking_step_takes_box_rows_resting_on_their_bounds(seed):
    # Joints held by exactly their friction limit (ProxQP's answer is a vertex of the box; a robot's
    # joints stop slipping on it): the guess is not strictly inside, yet the all-stick answer holds.
    # The default's first stage takes it (before: Newton, which stalled, then ProxQP).
    p, guess, tol = standing_robot_problem(seed, rows_on_bounds=4)
    r = solve(p, "default", guess, tol=tol)
    assert r.message == "converged (sticking step)" and r.iterations == 1, (r.message, r.iterations)
    assert_sticks_everywhere(p, r.lam, tol)


@pytest.mark.parametrize("seed", range(6))
def test_a_real_misfit_along_the_null_space_still_makes_joints_slip(seed):
    # b's part out of A's range far above the tolerance (a gap no joint motion closes while every joint
    # sticks, as a UR5 pressing on a wall): no all-stick answer; Newton keeps its plain step there, and
    # the box rows that must slip reach their bounds.
    p, guess, tol = standing_robot_problem(seed, irreducible=1e5)
    assert natural_map(p, guess) > 100 * tol * np.linalg.norm(np.asarray(p.b))
    r = solve(p, "newton", guess, tol=tol)
    assert r.converged, r.message
    assert natural_map(p, r.lam) <= 2.0 * tol * np.linalg.norm(np.asarray(p.b))
    assert check_box_complementarity(p, r.lam, tol) == 12
    assert any(s == ContactState.slip for s in r.states[4:])


def pressing_arm_problem(seed, misfit):
    """A fixed-base arm (6 joints, dry friction on each) pressing a tool on a wall: 1 spatial contact
    and 6 box rows, A of rank 6 in 9 rows. b has a part out of A's range `misfit` times the
    tolerance (the contact's gap term, which no motion with every joint stuck fits): no all-stick
    answer; some joints must slip, barely. The guess is an all-stick point (the previous step's)."""
    rng = np.random.default_rng(seed)
    nv, mu, tau, tol = 6, 0.5, 5e-4, 1e-10
    M = spd(rng, nv, cond=20.0)
    J = np.vstack([rng.standard_normal((3, nv)), np.eye(nv)])
    A = J @ np.linalg.solve(M, J.T)
    A = 0.5 * (A + A.T)
    normal, angle = rng.uniform(0.05, 0.2), rng.uniform(0.0, 2.0 * np.pi)
    lam = np.concatenate([[0.15 * normal * np.cos(angle), 0.15 * normal * np.sin(angle), normal],
                          rng.uniform(-0.9, 0.9, nv) * tau])
    U, _, _ = np.linalg.svd(A)
    b = A @ lam
    null = U[:, nv:] @ rng.standard_normal(3)
    b = b + misfit * tol * np.linalg.norm(b) * null / np.linalg.norm(null)
    cons = [Constraint.spatial_friction(mu)] + [Constraint.box(-tau, tau)] * nv
    return ContactProblem(np.asfortranarray(A), b, cons), lam, tol


@pytest.mark.parametrize("seed", range(10))
@pytest.mark.parametrize("misfit", [5.0, 50.0])
def test_newton_finds_the_joints_that_slip_barely(seed, misfit):
    # Along A's null space u does not change: a joint can only take up the misfit by reaching its
    # bound, and descent lies only just past the point where its row's z = lambda - kappa u crosses
    # it (a window the line search's halvings missed: every one of these stalled, as a UR5 pressing
    # on a wall did). The line search also tries those crossings.
    p, guess, tol = pressing_arm_problem(seed, misfit)
    r = solve(p, "newton", guess, tol=tol)
    assert r.converged and r.iterations <= 30, (r.message, r.iterations)
    b = np.asarray(p.b)
    assert natural_map(p, r.lam) <= 2.0 * tol * np.linalg.norm(b)
    assert check_box_complementarity(p, r.lam, tol) == 6
    u = np.asarray(p.A) @ r.lam - b
    slipping = [o for c, o in zip(p.constraints, p.offsets) if c.kind == stiction.ConstraintKind.box
                and abs(u[o]) > 2.0 * tol * np.linalg.norm(b)]
    assert slipping and all(abs(abs(r.lam[o]) - 5e-4) <= 2.0 * tol * np.linalg.norm(b) for o in slipping)


# ------------------------------------------------------------------ mixed with friction cones

def check_box_complementarity(p, lam, tol):
    """From A, b and lambda alone: each box row inside its interval, u = 0 inside, u <= 0 at its
    upper bound, u >= 0 at its lower bound, to tol ||b||."""
    A, b = np.asarray(p.A), np.asarray(p.b)
    u = A @ lam - b
    scale = tol * max(np.linalg.norm(b), 1.0)
    offsets = p.offsets
    checked = 0
    for i, c in enumerate(p.constraints):
        if c.kind != stiction.ConstraintKind.box:
            continue
        o = offsets[i]
        lo, hi, l, v = c.lower, c.upper, lam[o], u[o]
        assert lo - scale <= l <= hi + scale
        assert abs(box_natural_map(l, v, lo, hi)) <= scale
        if l < hi - scale:
            assert v >= -scale  # not held at the upper bound: no negative velocity
        if l > lo + scale:
            assert v <= scale  # not held at the lower bound: no positive velocity
        checked += 1
    return checked


@pytest.mark.parametrize("solver, warm", EXACT)
@pytest.mark.parametrize("seed", range(6))
def test_box_rows_mixed_with_spatial_friction(solver, warm, seed):
    rng = np.random.default_rng(4000 + seed)
    kinds = ["spatial", "box", "spatial", "box", "unilateral", "box", "spatial", "bilateral2", "planar", "box"]
    rng.shuffle(kinds)
    p = random_problem(rng, list(kinds), dofs=16)
    tol = 1e-10
    r = solve(p, solver, warm, tol=tol)
    assert r.converged, r.message
    e = stiction.exact_law_measures(p, r.lam)
    lam_scale, b_scale = 1.0 + e.lambda_norm, 1.0 + e.b_norm
    assert e.relative_residual <= tol
    assert e.primal_max <= tol * lam_scale
    assert e.dual_max <= tol * b_scale
    assert e.complementarity_max <= tol * lam_scale * b_scale
    assert check_box_complementarity(p, r.lam, tol) == 4


def test_mixed_problems_exercise_both_bounds_and_the_interior():
    # (the mixed problems above are not trivially all-inside or all-at-a-bound)
    where = {"lower": 0, "upper": 0, "inside": 0}
    for seed in range(6):
        rng = np.random.default_rng(4000 + seed)
        kinds = ["spatial", "box", "spatial", "box", "unilateral", "box", "spatial", "bilateral2", "planar", "box"]
        rng.shuffle(kinds)
        p = random_problem(rng, list(kinds), dofs=16)
        r = solve(p)
        assert r.converged and check_box_complementarity(p, r.lam, 1e-10) == 4  # (a lambda checked here)
        for i, c in enumerate(p.constraints):
            if c.kind == stiction.ConstraintKind.box:
                l = r.lam[p.offsets[i]]
                where["lower" if l <= c.lower + 1e-9 else "upper" if l >= c.upper - 1e-9 else "inside"] += 1
    assert min(where.values()) >= 2, where


# ------------------------------------------------------------------ the yardstick and the verdict

def backwards(A, constraints, lam, u):
    A = np.asfortranarray(np.asarray(A, dtype=float))
    return ContactProblem(A, A @ np.asarray(lam, float) - np.asarray(u, float), constraints)


def test_exact_law_measures_of_box_rows_are_their_closed_forms():
    A = np.diag([2.0, 3.0, 1.5, 4.0])
    cons = [Constraint.box(-1.0, 2.0)] * 4
    # inside with a velocity, at upper pushing out (u > 0: wrong), at lower held (right), beyond upper
    lam = np.array([0.5, 2.0, -1.0, 2.5])
    u = np.array([0.3, 0.2, 0.4, -0.1])
    p = backwards(A, cons, lam, u)
    e = stiction.exact_law_measures(p, lam)
    comp = [(0.5 + 1.0) * 0.3, (2.0 + 1.0) * 0.2, 0.0, abs((2.0 - 2.5) * 0.1)]
    np.testing.assert_allclose(e.complementarity, comp, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(e.primal, [0, 0, 0, 0.5], atol=1e-15)
    np.testing.assert_allclose(e.dual, 0.0)
    np.testing.assert_allclose(e.signorini, 0.0)
    r = box_natural_map(lam, u, -1.0, 2.0)  # [0.3, 0.2 (2 - clamp(1.8)), 0, 0.5]
    assert e.natural_map == pytest.approx(np.linalg.norm(r), rel=1e-13)
    b = A @ lam - u
    assert stiction.residual(p, lam) == pytest.approx(np.linalg.norm(r) / (1 + np.linalg.norm(b)), rel=1e-13)
    # ... and at the solution every part vanishes
    r = solve(p)
    e = stiction.exact_law_measures(p, r.lam)
    assert e.relative_residual <= TOL and e.complementarity_max <= 1e-11 and e.primal_max == 0.0


def test_the_verdict_counts_box_rows():
    # lambda that satisfies every contact but not the box row is not converged: its residual is the box
    # row's natural map
    A = np.asfortranarray(np.diag([1.0, 1.0, 2.0, 3.0]))
    cons = [Constraint.spatial_friction(0.5), Constraint.box(-0.2, 0.2)]
    b = np.array([0.0, 0.0, 2.0, 3.0])  # contact: lambda = (0, 0, 1); box: clamp(1, -.2, .2) = 0.2
    p = ContactProblem(A, b, cons)
    wrong = np.array([0.0, 0.0, 1.0, 0.0])  # box row left at 0: u = -3
    assert stiction.residual(p, wrong) == pytest.approx(0.2 / (1 + np.linalg.norm(b)), rel=1e-12)
    r = solve(p)
    assert r.converged
    np.testing.assert_allclose(r.lam, [0, 0, 1, 0.2], atol=1e-12)
    r = stiction.solve(p, max_iter=0, warm_start=wrong)
    assert not r.converged and r.relative_residual == pytest.approx(0.2 / np.linalg.norm(b), rel=1e-12)


# ------------------------------------------------------------------ states

@pytest.mark.parametrize("solver", stiction.solver_names())
def test_states_inside_stick_at_a_bound_slip(solver):
    A = np.asfortranarray(np.diag([2.0, 2.0, 1.0, 1.0, 1.0, 3.0]))
    # rows: inside (b/a = 0.25), above upper (b/a = 2 > 0.5), below lower (-3 < -1), a contact resting
    cons = [Constraint.box(-1.0, 1.0), Constraint.box(-0.5, 0.5), Constraint.box(-1.0, 0.0),
            Constraint.spatial_friction(0.5)]
    b = np.array([0.5, 4.0, -3.0, 0.0, 0.0, 3.0])
    r = solve(cons_problem := ContactProblem(A, b, cons), solver)
    assert r.converged
    np.testing.assert_allclose(r.lam, [0.25, 0.5, -1.0, 0.0, 0.0, 1.0], atol=1e-12)
    assert list(r.states) == [ContactState.stick, ContactState.slip, ContactState.slip, ContactState.stick]
    e = stiction.exact_law_measures(cons_problem, r.lam)
    assert list(e.states) == list(r.states)
    assert not any(e.sliding)  # (sliding: friction blocks only)


# ------------------------------------------------------------------ formulations

@pytest.mark.parametrize("formulation", ["ccp", "nakaoka", "pyramid"])
@pytest.mark.parametrize("m, unilateral", [(4, 0), (6, 2), (10, 3)])
def test_formulations_that_take_box_rows_solve_them_exactly(formulation, m, unilateral):
    # On box (and unilateral) rows alone, CCP, Nakaoka and the pyramid LCP are the exact law: the QP.
    rng = np.random.default_rng(6000 + m)
    for _ in range(2):
        p, A, b, lo, hi = box_qp_problem(rng, m, unilateral)
        expected = (qp_by_enumeration if m <= 6 else qp_by_lbfgsb)(A, b, lo, hi)
        r = stiction.solve(p, formulation=formulation, tol=1e-11, max_iter=100000)
        assert r.own_converged, r.message
        np.testing.assert_allclose(r.lam, expected, rtol=0, atol=1e-7 * np.linalg.norm(expected))


@pytest.mark.parametrize("formulation", ["penalty", "pinocchio-admm", "pinocchio-pgs", "pinocchio-admm-ccp"])
def test_formulations_without_a_law_for_box_rows_refuse_them(formulation):
    A = np.asfortranarray(np.eye(4))
    p = ContactProblem(A, np.ones(4), [Constraint.spatial_friction(0.5), Constraint.box(-1.0, 1.0)])
    with pytest.raises(ValueError) as err:
        stiction.solve(p, formulation=formulation, h=1e-3)
    msg = str(err.value)
    assert "\n" not in msg and f"formulation '{formulation}'" in msg and "box rows" in msg
    assert "use the exact formulation" in msg


def test_pinocchio_baselines_refuse_box_rows():
    from stiction import baselines

    p = ContactProblem(np.asfortranarray(np.eye(4)), np.ones(4),
                       [Constraint.spatial_friction(0.5), Constraint.box(-1.0, 1.0)])
    with pytest.raises(ValueError, match="box row"):
        baselines._layout(p)


# ------------------------------------------------------------------ FCLib cannot store them

def test_fclib_writer_refuses_box_rows(tmp_path):
    from stiction.fclib import write_local

    p = ContactProblem(np.asfortranarray(np.eye(4)), np.ones(4),
                       [Constraint.spatial_friction(0.5), Constraint.box(-1.0, 1.0)])
    with pytest.raises(ValueError, match="FCLib has no box blocks") as err:
        write_local(tmp_path / "p.hdf5", p)
    assert "\n" not in str(err.value)
    assert not (tmp_path / "p.hdf5").exists()


# (a step with joint rows refused by stiction dump: tests/test_dump.py, test_dump_refuses_joint_rows)


# ------------------------------------------------------------------ Python API

def test_box_constraint_repr_eq_and_fields():
    c = Constraint.box(-0.1, 0.30000000000000004)
    assert (c.kind, c.size, c.lower, c.upper) == (stiction.ConstraintKind.box, 1, -0.1, 0.30000000000000004)
    assert eval(repr(c), {"stiction": stiction}) == c
    assert c != Constraint.box(-0.1, 0.3) and c != Constraint.unilateral()
    assert eval(repr(Constraint.spatial_friction(0.1)), {"stiction": stiction}) == Constraint.spatial_friction(0.1)
    for lower, upper in ((0.1, 1.0), (-1.0, -0.1), (-math.inf, 1.0), (math.nan, 1.0)):
        with pytest.raises(ValueError, match="lower <= 0 <= upper"):
            Constraint.box(lower, upper)


# ------------------------------------------------------------------ larger problems: the other paths

def coupled_groups(rng, groups, kinds, dofs, sparse):
    """`groups` random problems side by side, each group's A coupled to the next by a weak band
    (block tridiagonal, so A stays sparse), as bodies touching their neighbours."""
    import scipy.sparse as sp

    parts = [random_problem(rng, list(kinds), dofs=dofs) for _ in range(groups)]
    blocks = [np.asarray(p.A) for p in parts]
    A = sp.block_diag(blocks).tolil()
    offsets = np.cumsum([0] + [B.shape[0] for B in blocks])
    for g in range(groups - 1):  # a weak SPD coupling: A + e (x_g - x_g+1)(x_g - x_g+1)^T on one row pair
        i, j = offsets[g], offsets[g + 1]
        for r, c, v in ((i, i, 0.05), (j, j, 0.05), (i, j, -0.05), (j, i, -0.05)):
            A[r, c] += v
    A = A.tocsc()
    b = np.concatenate([np.asarray(p.b) for p in parts])
    cons = [c for p in parts for c in p.constraints]
    return ContactProblem(A if sparse else np.asfortranarray(A.toarray()), b, cons)


@pytest.mark.parametrize("solver", stiction.solver_names())
@pytest.mark.parametrize("groups, sparse", [(8, False), (30, True)])
def test_box_rows_in_medium_and_large_problems(solver, groups, sparse):
    # 8 groups: 104 rows, dense (the default's NSGS then Newton); 30 groups: 390 rows held sparse
    # (sparse Newton, sparse ADMM)
    rng = np.random.default_rng(7000 + groups)
    kinds = ["spatial", "box", "spatial", "box", "unilateral", "box", "spatial"]
    p = coupled_groups(rng, groups, kinds, dofs=12, sparse=sparse)
    assert p.num_rows == 13 * groups and p.is_sparse == sparse
    tol = 1e-10
    r = solve(p, solver, tol=tol)
    assert r.converged, r.message
    e = stiction.exact_law_measures(p, r.lam)
    assert e.relative_residual <= tol
    assert check_box_complementarity(p, r.lam, tol) == 3 * groups
