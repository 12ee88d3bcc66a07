"""The default solver's rule (docs/solvers.md, "The default's rule"): which stages it runs, by
size and sparsity and by how the stages converge. No timings here: the stages, their counts and
outcomes are what the measured speed-ups rest on, and they are deterministic."""
import numpy as np
import pytest

import stiction
from stiction import fclib

from conftest import FCLIB_DIR, FCLIB_FILES, spd

CAPSULES = [n for n in FCLIB_FILES if n.startswith("Capsules--")]
KAPLAS = "KaplasTower--KaplasTower-i1061-4.hdf5.dat"
SPHERES = "Spheres--Spheres-i099-356-679.hdf5"


def solve(name, tol=1e-8, symmetrised=False):
    P = fclib.load(FCLIB_DIR / name)
    if symmetrised:
        problem = stiction.spatial_problem(0.5 * (P.A + P.A.T), P.b, P.mu)
    else:
        problem = P.problem()
    return problem, stiction.solve(problem, tol=tol, max_iter=5000, time_limit=60.0)


def stage_names(result):
    return [s.name for s in result.stages]


def density(problem):
    A = np.asarray(problem.A)
    return np.count_nonzero(A) / A.size


def test_the_bundled_set_has_the_problems_the_rule_was_measured_on():
    assert len(CAPSULES) == 5 and KAPLAS in FCLIB_FILES and SPHERES in FCLIB_FILES


def stored_entries(problem):
    return int(np.count_nonzero(np.asarray(problem.A)))


@pytest.mark.parametrize("symmetrised", [False, True], ids=["stored", "symmetrised"])
@pytest.mark.parametrize("name", CAPSULES + [SPHERES, "SpheresBox--spheres-in-a-box-98-i10000-256-10.hdf5"])
def test_cold_large_sparse_problems_with_few_entries_are_solved_by_sparse_newton(name, symmetrised):
    """Capsules (648-888 rows, 8.6-12.4k entries), Spheres (1068, 7.2k) and SpheresBox (768,
    17k): Newton from the guess with a sparse Jacobian and LU, before any ADMM (8-30 ms to 1e-8
    where ADMM took 13-42 ms and stalled on SpheresBox)."""
    problem, r = solve(name, symmetrised=symmetrised)
    assert problem.num_rows > 384 and density(problem) <= 0.1
    assert stored_entries(problem) <= stiction._core.DEFAULT_SPARSE_NEWTON_ENTRIES
    assert r.converged and r.relative_residual <= 1e-8, r.message
    assert stage_names(r) == ["newton"], r.stages
    assert r.message == "converged (newton)"


@pytest.mark.parametrize("symmetrised", [False, True], ids=["stored", "symmetrised"])
def test_large_sparse_problems_with_many_entries_go_to_admm_without_a_gauss_seidel_prelude(symmetrised):
    """KaplasTower (1710 rows, 117k entries, 4 % nonzero): its sparse LU fills in (Newton 255 ms),
    so ADMM, factorized sparsely, solves it alone (~80 ms; an NSGS prelude ran 1056 sweeps)."""
    problem, r = solve(KAPLAS, symmetrised=symmetrised)
    assert problem.num_rows > 384 and density(problem) <= 0.1
    assert stored_entries(problem) > stiction._core.DEFAULT_SPARSE_NEWTON_ENTRIES
    assert r.converged and r.relative_residual <= 1e-8, r.message
    assert stage_names(r) == ["admm"], r.stages
    assert r.stages[0].outcome == "converged" and r.message == "converged (admm)"


def test_a_warm_started_large_problem_tries_a_few_gauss_seidel_sweeps_then_sparse_newton():
    """Warm-started (the simulator's previous step): at most 10 NSGS sweeps first, then, A having
    few stored entries, sparse Newton from the guess (ADMM only if it fails); from the solution
    itself that is one sweep, from the previous step's solution stored in the file (Capsules-i97,
    relative residual 4e-3) the sweeps stop at 10 and Newton finishes (6 steps, ~4 ms, where ADMM
    took 436 iterations, ~10 ms)."""
    P = fclib.load(FCLIB_DIR / "Capsules--Capsules-i97-269.hdf5")
    problem = P.problem()
    cold = stiction.solve(problem, tol=1e-8, max_iter=5000)
    assert cold.converged and stage_names(cold) == ["newton"]
    again = stiction.solve(problem, tol=1e-8, max_iter=5000, warm_start=cold.lam)
    assert again.converged and stage_names(again) == ["nsgs"] and again.iterations <= 2, again.stages
    warm = stiction.solve(problem, tol=1e-8, max_iter=5000, warm_start=P.guess)
    assert warm.converged and stage_names(warm) == ["nsgs", "newton"], warm.stages
    assert warm.stages[0].iterations == 10 and warm.stages[1].outcome == "converged"
    assert warm.stages[1].iterations <= 20


def test_a_warm_started_spinning_tower_is_solved_within_the_simulators_budget():
    """36 boxes stacked and spinning (432 rows, every interface sliding), the simulator's budget of
    200 iterations: each step's sweeps stop at 10 and sparse Newton from the previous step's answer
    converges. (With ADMM next, it took 450-930 iterations to stall, the budget ran out first and
    4 of 30 steps failed.)"""
    from stiction.scene import build_scene
    from stiction.simulator import Simulator

    cubes = 36
    sim = Simulator(build_scene({"array": {"layout": "tower", "count": cubes}, "ground": {"mu": 0.3}}))
    v = np.asarray(sim.data.v).copy()
    v[5::6] = np.linspace(-4.0, 4.0, cubes)  # each box spins about z, the next one faster
    v[0::6] = 0.2
    sim.set_state(v=v)
    for _ in range(10):
        sim.step()
        r = sim.data.result
        assert r.converged, r.message
        assert sum(s.iterations for s in r.stages) <= 200
    assert stage_names(r) == ["nsgs", "newton"], r.stages
    assert sum(state == stiction.ContactState.slip for state in r.states) >= 50  # 74 of 144 contacts slide


def test_admm_hands_over_to_newton_when_its_best_residual_stops_improving():
    """A large dense problem (SpheresBox's A, 768 rows, cond ~1e9, made dense by a rank-one term of
    1e-9 of its scale) warm-started from zero: NSGS stalls, then ADMM (a dense LU per step is too
    dear for Newton first) stays near its starting residual; its stall test stops it after the
    400-iteration window and Newton from the initial guess solves it."""
    P = fclib.load(FCLIB_DIR / "SpheresBox--spheres-in-a-box-98-i10000-256-10.hdf5")
    A = 0.5 * (P.A + P.A.T)
    v = np.ones(A.shape[0]) / np.sqrt(A.shape[0])
    A = A + 1e-9 * np.abs(A).max() * np.outer(v, v)
    problem = stiction.spatial_problem(A, P.b, P.mu)
    assert density(problem) == 1.0 and problem.num_rows > 384
    r = stiction.solve(problem, tol=1e-8, max_iter=5000, time_limit=60.0, warm_start=np.zeros(problem.num_rows))
    assert r.converged and r.relative_residual <= 1e-8
    names = stage_names(r)
    assert names == ["nsgs", "admm", "newton (from the initial guess)"], r.stages
    assert r.stages[1].outcome == "stalled" and r.stages[1].iterations <= 500
    assert r.stages[-1].outcome == "converged"


@pytest.mark.parametrize("name", ["BoxesStack--BoxesStack1-i100000-32.hdf5.dat",
                                  "OneObject--OneObject-i100000-316.hdf5.dat",
                                  "PerioBox--LMGC_100_PR_PerioBox-i00361-60-03000.hdf5"])
def test_medium_problems_hand_a_stalled_gauss_seidel_to_newton(name):
    """65-384 rows: a dense Newton step costs a few ms, and Newton from the NSGS iterate
    finishes in 4-17 steps where ADMM needs hundreds of iterations or stalls."""
    problem, r = solve(name)
    assert 64 < problem.num_rows <= 384
    assert r.converged and stage_names(r) == ["nsgs", "newton"], r.stages
    assert r.stages[0].outcome == "stalled"


@pytest.mark.parametrize("name", ["BoxStacks--Box_Stacks-i0122-82-5.hdf5", "NESpheres--NESpheres_30_1.dat",
                                  "Confeti--Confeti-ex13-Fc3D-SBM.dat"])
def test_medium_well_conditioned_problems_are_solved_by_gauss_seidel_alone(name):
    """BoxStacks 32 sweeps, NESpheres 1, Confeti-ex13 45: its 10-sweep rate at sweep 15 predicts
    160-320 more, under the hand-over's max(50, m) = 321 (Newton from there: 9.5 ms, NSGS 1.2)."""
    _, r = solve(name)
    assert r.converged and stage_names(r) == ["nsgs"], r.stages


@pytest.mark.parametrize("name", [n for n in FCLIB_FILES if n.startswith(("Rover--", "Toy--"))])
def test_small_problems_start_with_newton(name):
    problem, r = solve(name)
    assert problem.num_rows <= 64
    assert r.converged and stage_names(r) == ["newton"], r.stages


def test_uncoupled_blocks_take_unshifted_newton_steps():
    """Toy FC3D_Example1: A = I, three identical sliding contacts. A couples no two blocks, so
    Newton solves each block's 3 x 3 system alone and, where it is well-pivoted, without the
    regularising shift (capped at 1e-2, it made the first step from zero 1 % off: 3 steps). With
    A = I the answer is closed-form: lambda_n = b_n, lambda_t = b_t when |b_t| <= mu b_n, else
    mu b_n b_t / |b_t| (u_t = lambda_t - b_t opposite to lambda_t)."""
    problem, r = solve("Toy--FC3D_Example1.dat", tol=1e-10)
    assert r.converged and stage_names(r) == ["newton"] and r.stages[0].iterations == 1, r.stages
    B, mu = np.asarray(problem.b).reshape(-1, 3), 0.1
    bt = np.linalg.norm(B[:, :2], axis=1)
    assert (bt > mu * B[:, 2]).all()  # every contact slides
    expected = np.column_stack([mu * B[:, 2:3] * B[:, :2] / bt[:, None], B[:, 2]])
    np.testing.assert_allclose(np.asarray(r.lam).reshape(-1, 3), expected, rtol=0, atol=1e-12)
    assert list(r.states) == [stiction.ContactState.slip] * 3


@pytest.mark.parametrize("b", [(0.3, 0.2, 1.0), (0.05, 0.2, 1.0)])
def test_an_uncoupled_block_with_a_singular_newton_system_gets_the_shift(b):
    """A contact whose second tangential direction nothing moves (A = diag(1, 0, 1)): the block's
    unshifted Newton system has a zero pivot, so that block falls back to the shifted system (no
    'singular Newton system', no non-finite step). The answer satisfies the exact law; lambda_n = b_n
    (u_n = lambda_n - b_n = 0)."""
    problem = stiction.spatial_problem(np.diag([1.0, 0.0, 1.0]), np.array(b), [0.5])
    r = stiction.solve(problem, tol=1e-10)
    assert r.converged and stage_names(r)[-1] == "newton" and r.stages[-1].outcome == "converged", r.stages
    assert r.exact_law.relative_residual <= 1e-10
    assert r.lam[2] == pytest.approx(1.0, abs=1e-9)
    assert np.hypot(r.lam[0], r.lam[1]) <= 0.5 * r.lam[2] * (1 + 1e-9)


@pytest.mark.parametrize("name", [n for n in FCLIB_FILES if n.startswith("CubesH8--")])
def test_a_cold_problem_whose_natural_map_sticks_everywhere_at_zero_is_the_sticking_step(name):
    """From lambda = 0, when b lies strictly inside every shifted cone (|b_t| < mu (b_n - mu |b_t|):
    the natural map of eq. 65 at zero is in its sticking regime for every block), the default tries
    the all-stick solution by one factorization of A first. The CubesH8 problems (LMGC cubes at rest)
    are all-stick: one solve, and the answer is A^-1 b (numpy's, to the tolerance)."""
    problem, r = solve(name)
    A, b = np.asarray(problem.A), np.asarray(problem.b)
    B = b.reshape(-1, 3)
    assert (np.hypot(B[:, 0], B[:, 1]) < 0.3 * (B[:, 2] - 0.3 * np.hypot(B[:, 0], B[:, 1]))).all()
    assert r.converged and stage_names(r) == ["sticking step"] and r.iterations == 1, r.stages
    assert np.linalg.norm(A @ np.asarray(r.lam) - b) <= 1e-8 * (1 + np.linalg.norm(b))
    np.testing.assert_allclose(r.lam, np.linalg.solve(A, b), rtol=0, atol=1e-8 * np.abs(np.linalg.solve(A, b)).max())


def test_a_cold_sticking_prediction_that_fails_hands_over_to_newton():
    """The prediction at zero is only a prediction: two contacts pressed together side by side, each
    with b inside its own shifted cone, but coupled so that the all-stick forces leave a cone (the
    first contact's tangential force, 0.78, exceeds mu lambda_n = 0.5). The sticking step says so,
    Newton solves, and in the answer that contact slides while the other sticks."""
    mu = 0.5
    A = np.eye(6)
    A[0, 5] = A[5, 0] = 0.6  # contact 1's tangential row couples to contact 2's normal row
    b = np.array([0.1, 0.0, 1.0, 0.0, 0.0, 1.0])
    B = b.reshape(-1, 3)
    assert (np.hypot(B[:, 0], B[:, 1]) < mu * (B[:, 2] - mu * np.hypot(B[:, 0], B[:, 1]))).all()
    x = np.linalg.solve(A, b).reshape(-1, 3)
    assert not (np.hypot(x[:, 0], x[:, 1]) < mu * x[:, 2]).all()  # the all-stick forces leave a cone
    problem = stiction.spatial_problem(A, b, [mu, mu])
    r = stiction.solve(problem, tol=1e-10)
    assert r.converged and stage_names(r)[:2] == ["sticking step", "newton"], r.stages
    assert r.stages[0].outcome == "not all sticking"
    assert r.exact_law.relative_residual <= 1e-9
    assert list(r.states) == [stiction.ContactState.slip, stiction.ContactState.stick]


def test_a_large_dense_problem_keeps_the_gauss_seidel_prelude(rng):
    """Above 384 rows but dense (more than 10 % nonzero): NSGS first, as before the rule."""
    nc = 140
    A = spd(rng, 3 * nc, cond=50.0)
    b = rng.standard_normal(3 * nc)
    problem = stiction.spatial_problem(A, b, 0.5)
    assert density(problem) > 0.1
    r = stiction.solve(problem, tol=1e-8, max_iter=5000)
    assert r.converged and stage_names(r)[0] == "nsgs", r.stages


def block_sparse_problem(rng, groups, contacts_per_group, asymmetry=0.0):
    """A block-diagonal Delassus operator: `groups` independent bodies with a few contacts each."""
    k = 3 * contacts_per_group
    m = groups * k
    A = np.zeros((m, m))
    for g in range(groups):
        A[g * k:(g + 1) * k, g * k:(g + 1) * k] = spd(rng, k, cond=20.0)
    if asymmetry:
        skew = rng.standard_normal((m, m)) * (A != 0)
        A = A + asymmetry * np.abs(A).max() * (skew - skew.T) / 2
    b = rng.standard_normal(m)
    b[2::3] = np.abs(b[2::3]) + 0.5  # push every contact closed
    return stiction.spatial_problem(A, b, 0.6, asymmetry_tolerance=max(1e-9, 10 * asymmetry))


@pytest.mark.parametrize("asymmetry", [0.0, 1e-6], ids=["symmetric (sparse Cholesky)", "asymmetric (sparse LU)"])
def test_admm_on_a_sparse_operator_solves_as_the_dense_solvers_do(rng, asymmetry):
    """ADMM factorizes a sparse A (> 64 rows, <= 10 % nonzero) sparsely: same answers as Newton
    (dense LU) on a block-diagonal problem, symmetric or slightly not."""
    problem = block_sparse_problem(rng, groups=20, contacts_per_group=2, asymmetry=asymmetry)
    assert problem.num_rows == 120 and density(problem) <= 0.1
    admm = stiction.solve(problem, solver="admm", tol=1e-10, max_iter=20000)
    newton = stiction.solve(problem, solver="newton", tol=1e-12)
    assert admm.converged and newton.converged, (admm.message, newton.message)
    np.testing.assert_allclose(admm.lam, newton.lam, atol=1e-7 * np.abs(newton.lam).max())


def test_a_warm_start_that_solves_the_problem_costs_no_solve():
    """The simulator's per-step problem at rest (A and b unchanged, warm-started from the previous
    step's forces): the guess is checked and kept, no factorization."""
    from stiction.problems import cube_on_ground

    problem = cube_on_ground(mu=0.3).problem
    first = stiction.solve(problem)
    again = stiction.solve(problem, warm_start=first.lam)
    assert again.converged and stage_names(again) == ["sticking step"] and again.iterations == 0
    np.testing.assert_array_equal(again.lam, first.lam)


def test_the_sticking_step_keeps_the_guess_share_of_non_unique_forces():
    """A cube on its 4 corners: 12 rows, A of rank 6, so the forces that hold it are not unique.
    Warm-started strictly inside the cones, the default solves the all-stick system by one proximal
    factorization: the answer satisfies the law (A lambda = b, inside the cones) and differs from
    the guess only within A's range (to rounding: the shifted factor's condition is ~1e10), so the
    guess's share of the null space (how the weight is spread over the corners) is kept."""
    from stiction.problems import cube_on_ground

    problem = cube_on_ground(mu=0.3).problem
    A, b = np.asarray(problem.A), np.asarray(problem.b)
    w, V = np.linalg.eigh(A)
    null = V[:, w < 1e-9 * w.max()]
    assert null.shape[1] == 6
    first = stiction.solve(problem)
    # corners 0 and 3 carry 20 % more than 1 and 2: a null-space share, still inside the cones
    diagonal = np.zeros(12)
    diagonal[2::3] = [1.0, -1.0, -1.0, 1.0]
    share = null @ (null.T @ diagonal)
    guess = first.lam + 0.2 * first.lam[2] * share / np.abs(share).max()
    moved = stiction.spatial_problem(A, 1.01 * b, 0.3)  # the next step: b moved
    r = stiction.solve(moved, warm_start=guess)
    assert r.converged and stage_names(r) == ["sticking step"] and r.iterations <= 2
    np.testing.assert_allclose(A @ r.lam, 1.01 * b, atol=1e-10 * np.abs(b).max())
    kept = null.T @ (r.lam - guess)
    assert np.abs(kept).max() <= 1e-5 * np.abs(null.T @ (guess - first.lam)).max()


def test_a_sliding_guess_skips_the_sticking_step():
    """A guess on the cone's boundary (a sliding contact) is not tried as all-stick: Newton runs."""
    from stiction.problems import cube_on_ground

    problem = cube_on_ground(mu=0.3).problem
    lam = np.tile([0.3, 0.0, 1.0], 4)  # ||lambda_t|| = mu lambda_n: on the boundary
    r = stiction.solve(problem, warm_start=lam)
    assert r.converged and stage_names(r)[0] == "newton"


def test_a_warm_started_tower_step_is_the_sticking_step():
    """A tower of 20 cubes on 4 corners each (240 rows, A of rank <= 120, warm-started by the
    simulator): Newton stalled there from the NSGS iterate and from the guess (no descent
    direction), and ADMM took ~2.7 ms; every contact sticks, so the proximal all-stick
    factorization (A is block-tridiagonal: factored sparsely) solves each step."""
    from stiction.scene import load_scene
    from stiction.simulator import Simulator

    sim = Simulator(load_scene("box-tower-20"))
    traj = sim.rollout(0.05)
    r = sim.data.result
    assert traj.converged[1:].all()
    assert r.converged and 64 < len(r.lam) <= 384
    assert stage_names(r) == ["sticking step"] and r.iterations <= STICK_SOLVES, r.stages


STICK_SOLVES = 4  # DefaultSolver::kStickSolves: the refinement solves the sticking step takes at most


def test_the_sticking_step_does_not_wander_along_the_null_space():
    """b with a part no force can cancel (outside A's range: b's rounding, gaps no rigid motion fits).
    A plain proximal step (A + rho I)^-1 (b - A lambda) moves lambda by that part / rho along A's null
    space at every step (on a 64-box tower 2e-3 N s a step, until a corner left its cone); the
    sticking step's steps are filtered to A's range, so the guess's share of the non-unique forces
    stays where it was, to rounding."""
    from stiction.problems import cube_on_ground

    problem = cube_on_ground(mu=0.3).problem
    A, b = np.asarray(problem.A), np.asarray(problem.b)
    w, V = np.linalg.eigh(A)
    null = V[:, w < 1e-9 * w.max()]
    first = stiction.solve(problem)
    stray = 1e-3 * 1e-10 * np.linalg.norm(b) * null[:, 0]  # well within the tolerance's reach
    moved = stiction.spatial_problem(A, 1.001 * b + stray, 0.3)
    rho = 1e-10 * np.abs(np.diag(A)).max()  # DefaultSolver::kStickShift
    plain = np.linalg.solve(A + rho * np.eye(12), 1.001 * b + stray - A @ first.lam)
    assert np.abs(null.T @ plain).max() >= 1e-4 * np.abs(first.lam).max()  # the drift a plain step makes
    r = stiction.solve(moved, warm_start=first.lam)
    assert r.converged and stage_names(r) == ["sticking step"], r.stages
    assert np.abs(null.T @ (r.lam - first.lam)).max() <= 1e-7 * np.abs(first.lam).max()


def test_the_held_factor_serves_a_resting_tower_and_never_decides_an_answer():
    """The sticking step keeps its factor: on the next step of a resting tower (the same contacts, A
    a step later) the warm start is the answer already (b repeated), or one refinement step with the
    held factor converges: no factorization is needed. A held factor of another matrix with the same
    diagonal only costs a try: the answer is the stopping test's, as a fresh solver's."""
    from stiction.scene import build_scene, load_scene
    from stiction.simulator import Simulator

    def resting_steps(sim, n):
        sim.rollout(0.02)
        seen = []
        for _ in range(n):
            sim.step()
            r = sim.data.result
            assert r.converged and stage_names(r) == ["sticking step"], r.stages
            seen.append("warm start" if r.stages[0].iterations == 0 else r.stages[0].outcome)
        return seen

    for sim, n in [(Simulator(load_scene("box-tower-20")), 20),
                   (Simulator(build_scene({"name": "tower-48", "array": {"layout": "tower", "count": 48},
                                           "ground": {"mu": 0.5}})), 40)]:
        seen = resting_steps(sim, n)
        assert seen.count("converged (held factor)") >= n // 4, seen
        assert seen.count("converged (held factor)") + seen.count("warm start") >= n - 1, seen

    rng = np.random.default_rng(4)
    from stiction.problems import cube_on_ground

    problem = cube_on_ground(mu=0.3).problem
    A, b = np.asarray(problem.A), np.asarray(problem.b)
    first = stiction.solve(problem, solver="default")
    stiction.solve(stiction.spatial_problem(A, 1.001 * b, 0.3), warm_start=first.lam)  # holds A's factor
    # the same diagonal, other off-diagonal entries: a cube held differently
    Q = np.eye(12) + 0.3 * np.diag(rng.uniform(-1, 1, 11), 1)
    other = Q @ A @ Q.T
    other *= np.sqrt(np.outer(np.diag(A), np.diag(A)) / np.outer(np.diag(other), np.diag(other)))
    other = 0.5 * (other + other.T)
    np.testing.assert_allclose(np.diag(other), np.diag(A), rtol=1e-12)
    target = other @ first.lam * 1.001
    r = stiction.solve(stiction.spatial_problem(other, target, 0.3), warm_start=first.lam)
    assert r.converged and stage_names(r) == ["sticking step"], r.stages
    np.testing.assert_allclose(other @ r.lam, target, rtol=0, atol=1e-10 * np.linalg.norm(target))


def test_a_well_conditioned_held_factor_steps_by_one_product():
    """A standing robot's A (12 rows, condition ~6) keeps its factor for hundreds of steps; from the
    factor's first reuse on, the refinement step is one product with G = R^-1 A R^-1 (made once, from
    the held factor) instead of four triangular solves. Each step must still land on the all-stick
    solution in one refinement: A lambda = b to the tolerance, the answer the held factor's solves
    give. (A wrong G, e.g. R^-2 subtracted without rho, misses by far more than 1e-10 and the solver
    falls back to a fresh factor: the outcome would not say "held factor".) In a thread of its own:
    its own solver, whose held-factor history (which other tests leave behind) starts empty."""
    import threading

    outcomes, failures = [], []

    def run():
        try:
            _standing_robot_steps(outcomes)
        except BaseException as e:  # noqa: BLE001 - re-raised in the test's thread
            failures.append(e)

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    if failures:
        raise failures[0]
    assert outcomes == ["converged (held factor)"] * 6, outcomes


def _standing_robot_steps(outcomes):
    rng = np.random.default_rng(7)
    Q, _ = np.linalg.qr(rng.normal(size=(12, 12)))
    A = Q @ np.diag(np.linspace(1.0, 6.0, 12)) @ Q.T
    A = 0.5 * (A + A.T)
    lam = np.tile([0.0, 0.0, 1.0], 4)  # the feet's weight, friction well inside the cones
    b = A @ lam
    first = stiction.solve(stiction.spatial_problem(A, b, 0.5), solver="default")
    first = stiction.solve(stiction.spatial_problem(A, 1.001 * b, 0.5), warm_start=first.lam)  # factors A
    assert first.converged
    for k in range(6):
        # a step later: the same A (to its rounding), b moved by the robot's sway
        Ak = A * (1.0 + 1e-9 * k)
        target = Ak @ (lam + 1e-3 * np.tile(rng.uniform(-1, 1, 3) * [0.1, 0.1, 1.0], 4))
        r = stiction.solve(stiction.spatial_problem(Ak, target, 0.5), warm_start=first.lam)
        assert r.converged and stage_names(r) == ["sticking step"], r.stages
        assert r.stages[0].iterations == 1, r.stages  # one refinement step
        outcomes.append(r.stages[0].outcome)
        np.testing.assert_allclose(Ak @ r.lam, target, rtol=0, atol=1e-10 * np.linalg.norm(target))
        np.testing.assert_allclose(r.lam, np.linalg.solve(Ak, target), rtol=0, atol=1e-12 * np.linalg.norm(target))
        first = r


def test_a_settling_robot_keeps_its_factor_for_a_few_product_steps():
    """Solo-12 settling on its feet (the first 0.5 s): A moves a little every step, so its held
    factor needs 2-3 refinement steps where a fresh one needs 1. With the step matrix G a step is one
    product, cheaper than a fresh factor: the held factor serves most steps (one step's rule
    refactored 320 of these 500). Every step still ends on the stopping test's verdict."""
    import collections

    from stiction.scene import load_scene
    from stiction.simulator import Simulator

    sim = Simulator(load_scene("solo12-stand"))
    seen = collections.Counter()
    for _ in range(500):
        sim.step()
        r = sim.data.result
        assert r.converged and stage_names(r) == ["sticking step"], r.stages
        assert r.relative_residual + r.residual_bound <= 1e-10
        stage = r.stages[0]
        seen["warm start" if stage.iterations == 0 else "held" if "held" in stage.outcome else "fresh"] += 1
    assert seen["fresh"] <= 60, seen
    assert seen["held"] >= 400, seen


def test_a_resting_grid_is_solved_by_the_sticking_step():
    """16 cubes side by side (192 rows): the first solves are Gauss-Seidel's, which leave some corners'
    friction on the cone's boundary (the corners squeezing the ground at mu lambda_n: forces in A's
    null space). The simulator starts such a sticking contact's guess without its friction, so once
    the cubes rest each step is the sticking step (a Gauss-Seidel sweep and its verdict before), and
    every corner's friction is strictly inside its cone."""
    from stiction.scene import build_scene
    from stiction.simulator import Simulator

    sim = Simulator(build_scene({"name": "grid-16", "array": {"layout": "grid", "count": 16}, "ground": {"mu": 0.5}}))
    traj = sim.rollout(0.05)
    assert traj.converged[1:].all()
    for _ in range(10):
        sim.step()
        r = sim.data.result
        assert r.converged and stage_names(r) == ["sticking step"], r.stages
    lam = np.asarray(r.lam).reshape(-1, 3)
    assert (np.hypot(lam[:, 0], lam[:, 1]) < (1 - 1e-3) * 0.5 * lam[:, 2]).all()


def test_a_warm_start_that_stalls_is_retried_from_zero():
    """A 1e6 : 1 two-cube stack at dt = 0.1 ms: from the previous step's impulses, Newton stalls and
    ADMM ran out of budget on 58 of 5000 steps (first at step 1843); from zero the same problems
    converge. The simulator retries a missed warm-started solve from zero and keeps the better one."""
    from stiction.bench.stability import stack_scene
    from stiction.simulator import Simulator

    sim = Simulator(stack_scene(1e6, False), dt=1e-4, tolerance=1e-8)
    traj = sim.rollout(0.25)
    assert traj.converged[1:].all()
    assert traj.residual.max() <= 1e-8 * 1e-2  # far below the tolerance: a clean solve, not a lucky stop
    assert np.abs(traj.q[-1] - traj.q[0]).max() <= 1e-9  # the stack rests


# ---- the rule itself (default_solver.hpp: defaultPlan, a pure function of size and structure)

def plan(rows, sparse=False, stored_entries=0, warm_started=False, sticking_guess=False, has_budget=True):
    return stiction._core._default_plan(rows, sparse, stored_entries, warm_started, sticking_guess, has_budget)


SMALL = ["newton_first", "proxqp_newton", "fallbacks"]
MEDIUM = ["nsgs", "newton_after_nsgs", "newton_from_guess", "fallbacks"]


@pytest.mark.parametrize("rows", [3, 12, 27, 64])
def test_the_rule_starts_problems_of_up_to_64_rows_with_newton(rows):
    """docs/solvers.md, "The default's rule": <= 64 rows (Rover 12-15, Toy and CubesH8 3-27,
    Confeti-4 12): Newton first, then Newton from ProxQP's solution, then the fallbacks; with a
    sticking guess (CubesH8 at rest) the sticking step before them. Sparsity is not read there."""
    assert plan(rows) == SMALL
    assert plan(rows, sparse=True, stored_entries=rows, warm_started=True) == SMALL
    assert plan(rows, sticking_guess=True) == ["sticking_step"] + SMALL


@pytest.mark.parametrize("rows", [65, 69, 156, 180, 240, 321, 384])
def test_the_rule_hands_medium_problems_from_gauss_seidel_to_newton(rows):
    """65-384 rows (OneObject 69, BoxesStack 156, PerioBox 180, Confeti-ex13 321; box-tower-20's
    240 when simulated): NSGS until it stalls, Newton from its iterate, then from the initial guess;
    warm-started, at most 50 ADMM iterations before that Newton. A sparse A changes nothing up to
    384 rows (BoxStacks, 246 rows at 3.3 %, stays here)."""
    assert plan(rows) == MEDIUM
    assert plan(rows, sparse=True, stored_entries=rows * rows // 30) == MEDIUM
    assert plan(rows, warm_started=True) == ["nsgs", "warm_admm"] + MEDIUM[1:]
    assert plan(rows, warm_started=True, sticking_guess=True) == ["sticking_step", "nsgs", "warm_admm"] + MEDIUM[1:]


@pytest.mark.parametrize("rows, entries", [(385, 5000), (648, 8600), (888, 12400), (1068, 7200), (768, 17000),
                                           (1710, 50000), (2124, 60000)])
def test_the_rule_sends_large_sparse_problems_with_few_entries_to_sparse_newton(rows, entries):
    """> 384 rows, sparse, at most 100,000 stored entries (Capsules 648-888 rows, 8.6-12.4k entries;
    Spheres 1068, 7.2k; SpheresBox 768, 17k; pile-1000's largest island at step 508, 2124 rows past
    50k, where ADMM alone missed within the simulator's budget): sparse Newton from the guess, then ADMM; no second
    Newton from the guess. Warm-started: at most 10 sweeps first (Capsules-i97 from its previous
    step; a resting grid of 48 cubes, 576 rows)."""
    assert entries <= stiction._core.DEFAULT_SPARSE_NEWTON_ENTRIES
    assert plan(rows, sparse=True, stored_entries=entries) == ["sparse_newton", "admm", "fallbacks"]
    assert plan(rows, sparse=True, stored_entries=entries, warm_started=True) == \
        ["warm_sweeps", "sparse_newton", "admm", "fallbacks"]


def test_the_rule_sends_large_sparse_problems_with_many_entries_to_admm():
    """KaplasTower (1710 rows, 117k entries, 4 % nonzero): its sparse LU fills in, so ADMM alone,
    then Newton from the initial guess if ADMM stalls."""
    assert plan(1710, sparse=True, stored_entries=117_000) == ["admm", "newton_from_guess", "fallbacks"]
    assert plan(1710, sparse=True, stored_entries=stiction._core.DEFAULT_SPARSE_NEWTON_ENTRIES + 1, warm_started=True) == \
        ["warm_sweeps", "admm", "newton_from_guess", "fallbacks"]


@pytest.mark.parametrize("rows", [385, 420, 2000])
def test_the_rule_keeps_the_gauss_seidel_prelude_on_large_dense_problems(rows):
    """> 384 rows with more than 10 % nonzero: NSGS, then ADMM (not a dense LU of > 384 rows),
    then Newton from the initial guess; stored entries are not read."""
    expected = ["nsgs", "admm_after_nsgs", "newton_from_guess", "fallbacks"]
    assert plan(rows) == expected
    assert plan(rows, stored_entries=10) == expected
    assert plan(rows, warm_started=True) == expected


def test_the_rule_skips_the_sticking_step_without_a_budget_or_rows():
    assert plan(12, sticking_guess=True, has_budget=False) == SMALL
    assert plan(0, sticking_guess=True) == SMALL
    assert plan(900, sparse=True, stored_entries=9000, sticking_guess=True)[0] == "sticking_step"


@pytest.mark.parametrize("name", ["KaplasTower--KaplasTower-i1061-4.hdf5.dat", "Capsules--Capsules-i97-269.hdf5",
                                  "PerioBox--LMGC_100_PR_PerioBox-i00361-60-03000.hdf5",
                                  "CubesH8--LMGC_GlobalFrictionContactProblem00046.hdf5", "Rover--Rover1039.dat"])
def test_the_rule_reads_size_and_structure_as_numpy_does(name):
    """What the rule reads of a bundled problem, against numpy: rows; above 384 rows, A sparse
    (at most 10 % nonzero) and its nonzero count; from zero, whether b lies strictly inside every
    cone shifted by De Saxce's term (|b_t| < mu (b_n - mu |b_t|), CubesH8 at rest); and the plan
    these give is the stages the solve runs."""
    P = fclib.load(FCLIB_DIR / name)
    problem = P.problem()
    A, b = np.asarray(problem.A), np.asarray(problem.b)
    m = A.shape[0]
    got = stiction._core._default_rule_input(problem, np.zeros(m), False)
    assert got["rows"] == m and not got["warm_started"] and got["has_budget"]
    if m > 384:
        assert got["sparse"] == (np.count_nonzero(A) <= 0.1 * A.size)
        assert got["stored_entries"] == (np.count_nonzero(A) if got["sparse"] else 0)
    else:
        assert not got["sparse"] and got["stored_entries"] == 0  # not read
    B = b.reshape(-1, 3)
    t = np.hypot(B[:, 0], B[:, 1])
    assert got["sticking_guess"] == bool((t < (1 - 1e-6) * P.mu * (B[:, 2] - P.mu * t)).all())
    assert stiction._core._default_rule_input(problem, np.zeros(m), True)["warm_started"]
    stages = plan(**got)
    r = stiction.solve(problem, tol=1e-8, max_iter=5000)
    # the first stage the plan names is the first the solve ran
    first = {"sticking_step": "sticking step", "newton_first": "newton", "sparse_newton": "newton",
             "admm": "admm", "nsgs": "nsgs"}[stages[0]]
    assert stage_names(r)[0] == first, (stages, r.stages)
