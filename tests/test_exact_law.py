"""The exact-law yardstick (exact_law.hpp, docs/exact-law.md): at solutions every measure
vanishes; at hand-built answers (CCP-like lift-off, turned friction, λ outside the cone,
penetration) each measure equals its closed form. Most problems are built backwards: pick λ
and the post-step velocity u, then b = Aλ − u, so every measure is known exactly."""
import math

import numpy as np
import pytest

import stiction
from stiction import Constraint, ContactProblem, ContactState
from stiction.problems import cube_on_ground, random_problem, two_cube_stack

from conftest import spd

TOL = 1e-9


def backwards(A, constraints, lam, u):
    """The problem whose u = Aλ − b is the given u at the given λ."""
    A = np.asfortranarray(np.asarray(A, dtype=float))
    lam, u = np.asarray(lam, dtype=float), np.asarray(u, dtype=float)
    return ContactProblem(A, A @ lam - u, constraints)


def sliding_contact(mu=0.5, lam_n=2.0, speed=0.3, direction=(0.6, 0.8), a=(1.5, 4.0)):
    """One spatial contact sliding along `direction` at `speed`: the exact answer
    λ_t = −μ λ_n û_t, u_n = 0, on A = diag(a_t, a_t, a_n)."""
    d = np.asarray(direction, dtype=float)
    d /= np.linalg.norm(d)
    u = np.array([speed * d[0], speed * d[1], 0.0])
    lam = np.array([-mu * lam_n * d[0], -mu * lam_n * d[1], lam_n])
    A = np.diag([a[0], a[0], a[1]])
    return A, lam, u


def assert_all_vanish(e, lam_scale, b_scale, tol=TOL):
    assert e.relative_residual <= tol
    assert e.primal_max <= tol * lam_scale
    assert e.dual_max <= tol * b_scale
    assert e.complementarity_max <= tol * lam_scale * b_scale
    assert e.signorini_max <= tol * lam_scale * b_scale
    assert e.dissipation_max <= tol * lam_scale
    assert e.dissipation_angle_max <= 1e-6
    assert abs(e.liftoff_max) <= tol * b_scale


# ------------------------------------------------------------------ at solutions: all ~0

@pytest.mark.parametrize("seed", range(6))
def test_solutions_of_random_problems_satisfy_every_part(seed):
    rng = np.random.default_rng(seed)
    kinds = ["spatial", "spatial", "planar", "unilateral", "bilateral2", "spatial"]
    p = random_problem(rng, kinds, dofs=12)
    r = stiction.solve(p)
    assert r.converged
    e = stiction.exact_law_measures(p, r.lam)
    assert_all_vanish(e, 1.0 + e.lambda_norm, 1.0 + e.b_norm)
    # the same natural map (the verdict's is in extended precision: equal to rounding) and states
    scale = max(e.b_norm, 1.0)
    assert e.natural_map == pytest.approx(r.relative_residual * scale,
                                          abs=(r.residual_bound + 1e-12) * scale)
    assert list(e.states) == list(r.states)
    np.testing.assert_allclose(e.u, r.u, atol=1e-12 * (1 + e.b_norm))


def test_sliding_cube_satisfies_the_exact_law_and_slides():
    rp = cube_on_ground(velocity=(0.5, 0.2, 0.0))
    r = stiction.solve(rp.problem)
    assert r.converged
    e = stiction.exact_law_measures(rp.problem, r.lam)
    assert e.num_sliding == 4 and e.sliding.all()  # not vacuous: every corner slides
    assert e.states == [ContactState.slip] * 4
    assert_all_vanish(e, e.lambda_norm, e.b_norm)


def test_sliding_stack_with_mass_ratio_satisfies_the_exact_law():
    rp = two_cube_stack(mass_ratio=100.0, top_velocity=(0.3, 0.0, 0.0))
    r = stiction.solve(rp.problem)
    assert r.converged
    e = stiction.exact_law_measures(rp.problem, r.lam)
    assert e.num_sliding >= 4
    assert_all_vanish(e, e.lambda_norm, e.b_norm)


def test_resting_cube_sticks_and_nothing_slides():
    rp = cube_on_ground()
    r = stiction.solve(rp.problem)
    e = stiction.exact_law_measures(rp.problem, r.lam)
    assert e.num_sliding == 0 and not e.sliding.any()
    assert e.liftoff_max == 0.0 and e.dissipation_max == 0.0
    assert_all_vanish(e, e.lambda_norm, e.b_norm)


# ------------------------------------------------------------------ one sliding contact, closed forms

def test_exact_sliding_answer_has_no_liftoff_and_no_dissipation_violation():
    A, lam, u = sliding_contact()
    p = backwards(A, [Constraint.spatial_friction(0.5)], lam, u)
    e = stiction.exact_law_measures(p, lam)
    assert e.sliding.tolist() == [True] and e.states == [ContactState.slip]
    assert_all_vanish(e, 1.0, 1.0, tol=1e-14)
    np.testing.assert_allclose(e.w, [u[0], u[1], 0.5 * 0.3], atol=1e-15)  # w_n = u_n + μ‖u_t‖
    # and it is what the solver finds from b alone
    r = stiction.solve(p)
    np.testing.assert_allclose(r.lam, lam, atol=1e-10)


@pytest.mark.parametrize("mu", [0.3, 1.0])
def test_ccp_like_answer_lifts_off_by_mu_times_the_sliding_speed(mu):
    """CCP (Anitescu–Tasora) keeps λ but its u_n = μ‖u_t‖: the contact lifts off while sliding."""
    lam_n, s = 2.0, 0.3
    A, lam, u = sliding_contact(mu=mu, lam_n=lam_n, speed=s)
    u_ccp = u + np.array([0.0, 0.0, mu * s])
    p = backwards(A, [Constraint.spatial_friction(mu)], lam, u_ccp)
    e = stiction.exact_law_measures(p, lam)
    assert e.liftoff_max == pytest.approx(mu * s, rel=1e-14)
    assert e.liftoff.tolist() == pytest.approx([mu * s], rel=1e-14)
    # natural map: λ − P_C(λ − w) with w = (u_t, 2μs) is μ s / sqrt(1 + μ²)
    assert e.natural_map == pytest.approx(mu * s / math.sqrt(1 + mu * mu), rel=1e-12)
    assert e.relative_residual == pytest.approx(e.natural_map / e.b_norm, rel=1e-15)
    assert e.residual == pytest.approx(e.natural_map / (1 + e.b_norm), rel=1e-15)
    # feasible both ways, maximally dissipative, but not complementary: <λ, w> = λ_n u_n = μ λ_n s
    assert e.primal_max <= 1e-15 and e.dual_max <= 1e-15
    assert e.dissipation_max <= 1e-15 and e.dissipation_angle_max <= 1e-7
    assert e.complementarity_max == pytest.approx(mu * lam_n * s, rel=1e-12)
    assert e.signorini_max == pytest.approx(mu * lam_n * s, rel=1e-12)


@pytest.mark.parametrize("alpha", [0.1, 0.7, math.pi / 2, 2.5, math.pi])
def test_turned_friction_reports_its_angle(alpha):
    mu, lam_n, s = 0.5, 2.0, 0.3
    A, lam, u = sliding_contact(mu=mu, lam_n=lam_n, speed=s)
    c, sn = math.cos(alpha), math.sin(alpha)
    lam_t = np.array([[c, -sn], [sn, c]]) @ lam[:2]  # same magnitude, turned by α
    lam2 = np.array([lam_t[0], lam_t[1], lam_n])
    p = backwards(A, [Constraint.spatial_friction(mu)], lam2, u)
    e = stiction.exact_law_measures(p, lam2)
    assert e.dissipation_angle_max == pytest.approx(alpha, abs=1e-12)
    # ‖λ_t + μ λ_n û_t‖ = μ λ_n ‖R(α)d − d‖ = 2 μ λ_n sin(α/2)
    assert e.dissipation_max == pytest.approx(2 * mu * lam_n * math.sin(alpha / 2), rel=1e-12)
    assert e.primal_max <= 1e-15  # still on the cone boundary


def test_friction_below_the_boundary_while_sliding_violates_dissipation_not_feasibility():
    mu, lam_n = 0.5, 2.0
    A, lam, u = sliding_contact(mu=mu, lam_n=lam_n)
    lam2 = lam * np.array([0.5, 0.5, 1.0])  # half the friction, same direction
    p = backwards(A, [Constraint.spatial_friction(mu)], lam2, u)
    e = stiction.exact_law_measures(p, lam2)
    assert e.dissipation_max == pytest.approx(0.5 * mu * lam_n, rel=1e-13)
    assert e.dissipation_angle_max <= 1e-7
    assert e.primal_max == 0.0 and e.natural_map > 0.1


def test_zero_friction_while_sliding_has_no_direction():
    mu, lam_n = 0.5, 2.0
    A, lam, u = sliding_contact(mu=mu, lam_n=lam_n)
    lam2 = np.array([0.0, 0.0, lam_n])
    e = stiction.exact_law_measures(backwards(A, [Constraint.spatial_friction(mu)], lam2, u), lam2)
    assert e.dissipation_angle_max == 0.0  # no direction: the norm reports it
    assert e.dissipation_max == pytest.approx(mu * lam_n, rel=1e-14)


@pytest.mark.parametrize("lam, expected", [
    ([3.0, 4.0, 2.0], (5.0 - 0.5 * 2.0) / math.sqrt(1.25)),  # outside, onto the boundary ray
    ([0.3, 0.4, -1.0], math.sqrt(0.25 + 1.0)),               # in the polar cone: to the apex
    ([0.0, 0.0, -1.0], 1.0),                                 # λ_n < 0
    ([0.3, 0.4, 1.0], 0.0),                                  # on the boundary
    ([0.1, 0.0, 1.0], 0.0),                                  # inside
])
def test_primal_violation_is_the_distance_to_the_cone(lam, expected):
    mu = 0.5
    p = backwards(np.diag([1.0, 1.0, 2.0]), [Constraint.spatial_friction(mu)], lam, [0.0, 0.0, 0.0])
    e = stiction.exact_law_measures(p, lam)
    assert e.primal_max == pytest.approx(expected, rel=1e-14, abs=1e-15)
    assert e.primal.tolist() == pytest.approx([expected], rel=1e-14, abs=1e-15)
    assert e.primal_norm == pytest.approx(expected, rel=1e-14, abs=1e-15)


@pytest.mark.parametrize("mu", [0.0, 0.5, 2.0])
def test_dual_violation_of_a_penetrating_contact(mu):
    """w = u + E s(u) outside C* = {μ‖w_t‖ ≤ w_n}: the distance is −u_n/sqrt(1 + μ²) when it
    slides slowly into the ground (onto the boundary), |u_n| when it only penetrates."""
    lam = [0.0, 0.0, 0.0]
    sliding = stiction.exact_law_measures(
        backwards(np.eye(3), [Constraint.spatial_friction(mu)], lam, [0.6, 0.8, -0.01]), lam)
    assert sliding.dual_max == pytest.approx(0.01 / math.sqrt(1 + mu * mu), rel=1e-12)
    straight = stiction.exact_law_measures(
        backwards(np.eye(3), [Constraint.spatial_friction(mu)], lam, [0.0, 0.0, -0.01]), lam)
    assert straight.dual_max == pytest.approx(0.01, rel=1e-12)
    assert sliding.num_sliding == 0  # λ_n = 0: free flight, not sliding


def test_speed_floor_is_relative_to_b():
    A, lam, u = sliding_contact(speed=1e-9)
    lam = lam * np.array([0.0, 0.0, 1.0])  # no friction: a violation if it counted as sliding
    p = backwards(A, [Constraint.spatial_friction(0.5)], lam, u)
    e = stiction.exact_law_measures(p, lam)
    assert e.speed_floor == pytest.approx(1.5e-8 * np.abs(p.b).max(), rel=1e-15)
    assert e.num_sliding == 0 and e.dissipation_max == 0.0  # 1e-9 < 1.5e-8 * 8: noise
    tight = stiction.exact_law_measures(p, lam, relative_speed_floor=1e-12)
    assert tight.num_sliding == 1 and tight.dissipation_max == pytest.approx(0.5 * 2.0, rel=1e-12)


# ------------------------------------------------------------------ other block kinds

def test_planar_block():
    mu, lam_n, s = 0.4, 3.0, 0.2
    A = np.diag([2.0, 5.0])
    planar = [Constraint.planar_friction(mu)]
    exact = np.array([-mu * lam_n, lam_n])  # sliding towards +t
    e = stiction.exact_law_measures(backwards(A, planar, exact, [s, 0.0]), exact)
    assert e.num_sliding == 1
    assert_all_vanish(e, 1.0, 1.0, tol=1e-14)
    wrong = np.array([mu * lam_n, lam_n])  # friction pushing along the sliding
    e = stiction.exact_law_measures(backwards(A, planar, wrong, [s, 0.0]), wrong)
    assert e.dissipation_angle_max == pytest.approx(math.pi)
    assert e.dissipation_max == pytest.approx(2 * mu * lam_n, rel=1e-14)
    ccp = stiction.exact_law_measures(backwards(A, planar, exact, [s, mu * s]), exact)
    assert ccp.liftoff_max == pytest.approx(mu * s, rel=1e-13)
    assert ccp.natural_map == pytest.approx(mu * s / math.sqrt(1 + mu * mu), rel=1e-12)
    outside = np.array([2.0, 1.0])
    e = stiction.exact_law_measures(backwards(A, planar, outside, [0.0, 0.0]), outside)
    assert e.primal_max == pytest.approx((2.0 - mu) / math.sqrt(1 + mu * mu), rel=1e-14)


def test_unilateral_block():
    uni = [Constraint.unilateral()]
    A = np.array([[2.0]])
    e = stiction.exact_law_measures(backwards(A, uni, [-2.0], [-3.0]), [-2.0])
    assert (e.primal_max, e.dual_max) == pytest.approx((2.0, 3.0), rel=1e-15)
    assert e.signorini_max == pytest.approx(6.0) and e.complementarity_max == pytest.approx(6.0)
    assert e.num_sliding == 0 and e.dissipation_max == 0.0
    e = stiction.exact_law_measures(backwards(A, uni, [1.0], [2.0]), [1.0])
    assert e.primal_max == 0.0 and e.dual_max == 0.0 and e.signorini_max == pytest.approx(2.0)
    e = stiction.exact_law_measures(backwards(A, uni, [1.5], [0.0]), [1.5])
    assert_all_vanish(e, 1.0, 1.0, tol=1e-15)
    assert e.states == [ContactState.closed]


def test_bilateral_block_is_free_in_lambda_and_must_not_move():
    bil = [Constraint.bilateral(2)]
    A = np.diag([1.0, 3.0])
    lam = np.array([-7.0, 100.0])  # any λ is feasible
    e = stiction.exact_law_measures(backwards(A, bil, lam, [3.0, 4.0]), lam)
    assert e.primal_max == 0.0
    assert e.dual_max == pytest.approx(5.0, rel=1e-15)  # w = u must be 0: ‖u‖
    assert e.complementarity_max == pytest.approx(abs(-7.0 * 3.0 + 100.0 * 4.0), rel=1e-14)
    assert e.signorini_max == 0.0 and e.num_sliding == 0
    assert e.states == [ContactState.closed]


def test_mixed_blocks_per_block_vectors_and_aggregates(rng):
    cons = [Constraint.bilateral(1), Constraint.unilateral(), Constraint.planar_friction(0.5),
            Constraint.spatial_friction(0.5)]
    lam = np.array([5.0, -1.0, 0.0, -2.0, 0.6, 0.8, 1.0])
    u = np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0, -0.2])
    e = stiction.exact_law_measures(backwards(spd(rng, 7), cons, lam, u), lam)
    primal = [0.0, 1.0, 2.0, (1.0 - 0.5) / math.sqrt(1.25)]
    dual = [0.5, 0.0, 0.0, 0.2]
    comp = [2.5, 0.0, 0.0, 0.2]
    np.testing.assert_allclose(e.primal, primal, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(e.dual, dual, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(e.complementarity, comp, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(e.signorini, [0.0, 0.0, 0.0, 0.2], rtol=1e-12, atol=1e-14)
    assert e.primal_max == pytest.approx(2.0) and e.primal_norm == pytest.approx(np.linalg.norm(primal))
    assert e.dual_max == pytest.approx(0.5) and e.dual_norm == pytest.approx(np.linalg.norm(dual))
    assert e.complementarity_sum == pytest.approx(2.7) and e.complementarity_max == pytest.approx(2.5)
    for v in (e.primal, e.dual, e.complementarity, e.signorini, e.dissipation, e.dissipation_angle,
              e.liftoff, e.sliding):
        assert isinstance(v, np.ndarray) and v.shape == (4,)
    assert e.sliding.dtype == bool and e.u.shape == (7,) and e.w.shape == (7,)
    assert "ExactLawMeasures(" in repr(e)


def test_no_blocks_left_is_fine():
    p = ContactProblem(np.zeros((0, 0)), np.zeros(0), [])
    e = stiction.exact_law_measures(p, np.zeros(0))
    assert e.primal_max == 0.0 and e.natural_map == 0.0 and e.primal.shape == (0,)


# ------------------------------------------------------------------ arguments

def test_arguments_are_checked_and_named():
    p = backwards(np.eye(3), [Constraint.spatial_friction(0.5)], [0, 0, 1], [0, 0, 0])
    with pytest.raises(ValueError, match="lam needs 3 entries, got 2"):
        stiction.exact_law_measures(p, [1.0, 2.0])
    with pytest.raises(ValueError, match="lam must be a 1-D array of 3 floats"):
        stiction.exact_law_measures(p, np.ones((3, 1)))
    with pytest.raises(TypeError, match="lam must be a 1-D array of 3 floats, got None"):
        stiction.exact_law_measures(p, None)
    with pytest.raises(TypeError, match="lam must be real"):
        stiction.exact_law_measures(p, np.ones(3) * 1j)
    with pytest.raises(TypeError, match="problem must be a stiction.ContactProblem"):
        stiction.exact_law_measures("p", np.ones(3))
    with pytest.raises(ValueError, match="relative_speed_floor"):
        stiction.exact_law_measures(p, np.ones(3), relative_speed_floor=-1.0)
    with pytest.raises(TypeError, match="relative_speed_floor"):
        stiction.exact_law_measures(p, np.ones(3), relative_speed_floor="x")
    e = stiction.exact_law_measures(p, [0, 0, 1])  # a list of ints is an array
    assert e.lambda_norm == 1.0


def test_a_simulated_steps_measures_are_taken_when_read():
    """The simulator's per-step solves leave the exact-law measures to whoever reads them
    (sim.data.result measures them then, of the problem that step solved: A and h b): they equal
    exact_law_measures of that problem and lambda, for a robot standing and a cube sliding."""
    import stiction
    from stiction.scene import load_scene
    from stiction.simulator import Simulator

    for name in ("solo12-stand", "cube-slide"):
        sim = Simulator(load_scene(name))
        sim.rollout(0.05)
        r = sim.data.result
        h = sim.model.settings.dt
        mu = [sim.scene.contacts[i].mu for i in sim.data.active]
        A, b = np.asarray(sim.data.A), h * np.asarray(sim.data.b)
        problem = stiction.spatial_problem(A, b, mu)
        independent = stiction.exact_law_measures(problem, r.lam)
        carried = r.exact_law
        # (u = A lambda - b here from numpy's product: the two differ by rounding, ~1e-16 of the scale)
        scale = np.linalg.norm(b) + np.linalg.norm(A) * np.linalg.norm(r.lam)
        for field in ("natural_map", "primal_max", "dual_max", "dissipation_max", "liftoff_max"):
            assert getattr(carried, field) == pytest.approx(getattr(independent, field), rel=1e-9, abs=1e-12 * scale), field
        assert carried.complementarity_max == pytest.approx(independent.complementarity_max, abs=1e-12 * scale ** 2)
        assert carried.num_sliding == independent.num_sliding
        assert list(carried.states) == list(r.states)
        assert carried.num_sliding == (4 if name == "cube-slide" else 0)
