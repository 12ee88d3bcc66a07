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
    with pytest.raises(TypeError, match=r"constraints\[0\] must be a stiction.Constraint, got str"):
        ContactProblem(A3, B3, ["spatial"])


def test_python_helpers_validate():
    with pytest.raises(ValueError, match="multiple of 3"):
        stiction.spatial_problem(np.eye(4), np.ones(4), 0.5)
    with pytest.raises(ValueError, match="2-D"):
        stiction.spatial_problem(np.ones(3), np.ones(3), 0.5)
    with pytest.raises(TypeError, match="numeric"):
        stiction.spatial_problem([["a"] * 3] * 3, np.ones(3), 0.5)
    with pytest.raises(TypeError, match="mu"):
        stiction.spatial_problem(np.eye(3), np.ones(3), "high")


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
    with pytest.raises(ValueError, match="set_b: b needs 3 entries, got 2"):
        p.set_b(np.ones(2))
    with pytest.raises(ValueError, match="lam needs 3 entries, got 2"):
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


# ---------------------------------------------------------------- wrong kinds of argument
# Every bad call raises TypeError (wrong kind: None, str, complex, a list of the wrong things)
# or ValueError (wrong shape or range), names the argument, and never shows Boost.Python's
# "did not match C++ signature" text. Lists of numbers are accepted where arrays are.

P3 = ContactProblem(A3, B3, SPATIAL)


def _sim():
    from stiction.simulator import Simulator

    return Simulator("cube-slide")


BAD_CALLS = [
    # ContactProblem(A, b, constraints, asymmetry_tolerance)
    ("A None", lambda: ContactProblem(None, B3, SPATIAL), TypeError, "A must be"),
    ("A complex", lambda: ContactProblem(A3.astype(complex), B3, SPATIAL), TypeError, "A must be real"),
    ("A str", lambda: ContactProblem("eye", B3, SPATIAL), TypeError, "A must be"),
    ("A 1-D", lambda: ContactProblem(np.ones(3), B3, SPATIAL), ValueError, r"A must be a 2-D array.*shape \(3,\)"),
    ("A ragged", lambda: ContactProblem([[1.0, 0.0], [1.0]], B3, SPATIAL), TypeError, "A must be"),
    ("b str", lambda: ContactProblem(A3, "abc", SPATIAL), TypeError, "b must be"),
    ("b column", lambda: ContactProblem(A3, B3.reshape(3, 1), SPATIAL), ValueError, r"b must be a 1-D.*\(3, 1\)"),
    ("b complex", lambda: ContactProblem(A3, B3 + 0j, SPATIAL), TypeError, "b must be real"),
    ("constraints None", lambda: ContactProblem(A3, B3, None), TypeError, "constraints"),
    ("constraints missing", lambda: ContactProblem(A3, B3), TypeError, "constraints"),
    ("constraints not a list", lambda: ContactProblem(A3, B3, SPATIAL[0]), TypeError, "constraints must be a list"),
    ("constraints of str", lambda: ContactProblem(A3, B3, ["spatial"]), TypeError, r"constraints\[0\]"),
    ("asymmetry str", lambda: ContactProblem(A3, B3, SPATIAL, "tight"), TypeError, "asymmetry_tolerance"),
    ("asymmetry < 0", lambda: ContactProblem(A3, B3, SPATIAL, -1.0), ValueError, "asymmetry_tolerance"),
    # Constraint factories
    ("mu str", lambda: Constraint.spatial_friction("x"), TypeError, "spatial_friction: mu must be a real number"),
    ("mu None", lambda: Constraint.spatial_friction(None), TypeError, "mu must be a real number, got None"),
    ("mu complex", lambda: Constraint.planar_friction(1 + 2j), TypeError, "planar_friction: mu"),
    ("mu bool", lambda: Constraint.spatial_friction(True), TypeError, "mu"),
    ("rows -1", lambda: Constraint.bilateral(-1), ValueError, "at least 1 row, got -1"),
    ("rows float", lambda: Constraint.bilateral(2.5), TypeError, "bilateral: rows must be an integer"),
    ("rows str", lambda: Constraint.bilateral("3"), TypeError, "rows must be an integer"),
    # solve(problem, solver, tol, max_iter, warm_start, time_limit)
    ("problem str", lambda: stiction.solve("p"), TypeError, "problem must be a stiction.ContactProblem"),
    ("solver int", lambda: stiction.solve(P3, solver=3), TypeError, "solver must be"),
    ("solver unknown", lambda: stiction.solve(P3, solver="pgs"), ValueError, "unknown solver 'pgs'"),
    ("tol str", lambda: stiction.solve(P3, tol="1e-8"), TypeError, "tol must be a real number"),
    ("tol complex", lambda: stiction.solve(P3, tol=1e-8j), TypeError, "tol"),
    ("tol 0", lambda: stiction.solve(P3, tol=0.0), ValueError, "tol"),
    ("tol nan", lambda: stiction.solve(P3, tol=float("nan")), ValueError, "tol"),
    ("tol None", lambda: stiction.solve(P3, tol=None), TypeError, "tol"),
    ("max_iter float", lambda: stiction.solve(P3, max_iter=2.5), TypeError, "max_iter must be an integer"),
    ("max_iter < 0", lambda: stiction.solve(P3, max_iter=-1), ValueError, "max_iter must be >= 0"),
    ("time_limit < 0", lambda: stiction.solve(P3, time_limit=-1.0), ValueError, "time_limit"),
    ("time_limit nan", lambda: stiction.solve(P3, time_limit=float("nan")), ValueError, "time_limit"),
    ("time_limit inf", lambda: stiction.solve(P3, time_limit=float("inf")), ValueError, "time_limit"),
    ("time_limit str", lambda: stiction.solve(P3, time_limit="1 s"), TypeError, "time_limit"),
    ("warm_start size", lambda: stiction.solve(P3, warm_start=np.zeros(2)), ValueError, "initial lambda has 2"),
    ("warm_start complex", lambda: stiction.solve(P3, warm_start=np.zeros(3, complex)), TypeError, "warm_start"),
    ("warm_start 2-D", lambda: stiction.solve(P3, warm_start=np.zeros((3, 1))), ValueError, "warm_start"),
    ("warm_start name", lambda: stiction.solve(P3, warm_start="previous"), ValueError, "warm_start"),
    # residual, set_b, the Solver object and its settings
    ("residual lam None", lambda: stiction.residual(P3, None), TypeError, "residual: lam"),
    ("residual lam size", lambda: stiction.residual(P3, [1.0, 2.0]), ValueError, "lam needs 3 entries"),
    ("residual problem", lambda: stiction.residual("p", np.zeros(3)), TypeError, "residual: problem"),
    ("set_b None", lambda: P3.set_b(None), TypeError, "set_b: b"),
    ("set_b size", lambda: P3.set_b([1.0, 2.0]), ValueError, "set_b: b needs 3 entries"),
    ("set_b complex", lambda: P3.set_b(np.ones(3) * 1j), TypeError, "set_b: b must be real"),
    ("Solver name", lambda: stiction.Solver(3), TypeError, "Solver: name must be a str"),
    ("Solver unknown", lambda: stiction.Solver("pgs"), ValueError, "unknown solver"),
    ("Solver.solve settings", lambda: stiction.Solver("nsgs").solve(P3, "fast"), TypeError,
     "settings must be a stiction.SolverSettings"),
    ("settings.tolerance str", lambda: setattr(stiction.SolverSettings(), "tolerance", "1e-8"), TypeError,
     "tolerance must be a real number"),
    ("settings.max_iterations float", lambda: setattr(stiction.SolverSettings(), "max_iterations", 1.5), TypeError,
     "max_iterations must be an integer"),
    ("settings.warm_start str", lambda: setattr(stiction.SolverSettings(), "warm_start", "proxqp"), TypeError,
     "warm_start must be a stiction.WarmStart"),
    # the simulator's data, model and settings
    ("data.q size", lambda: setattr(_sim().data, "q", [1.0, 2.0]), ValueError, r"SimulatorData.q needs 7 entries, got 2"),
    ("data.q None", lambda: setattr(_sim().data, "q", None), TypeError, "SimulatorData.q must be"),
    ("data.q complex", lambda: setattr(_sim().data, "q", np.zeros(7, complex)), TypeError, "SimulatorData.q must be real"),
    ("data.v str", lambda: setattr(_sim().data, "v", "still"), TypeError, "SimulatorData.v"),
    ("data.v nan", lambda: setattr(_sim().data, "v", [np.nan] * 6), ValueError, "SimulatorData.v has NaN"),
    ("data.kp size", lambda: setattr(_sim().data, "kp", np.ones(3)), ValueError, "SimulatorData.kp needs 6"),
    ("data.tau_ff 2-D", lambda: setattr(_sim().data, "tau_ff", np.ones((6, 1))), ValueError, "SimulatorData.tau_ff"),
    ("data.t str", lambda: setattr(_sim().data, "t", "0"), TypeError, "SimulatorData.t must be a real number"),
    ("model None", lambda: stiction._core.SimulatorModel(None, [], [], [], _sim().settings), TypeError,
     "SimulatorModel: model must be a pinocchio.Model, got None"),
    ("model halfspaces", lambda: stiction._core.SimulatorModel(_sim().scene.model, None, [], [], _sim().settings),
     TypeError, "SimulatorModel: halfspaces must be a list"),
    ("model contacts", lambda: stiction._core.SimulatorModel(_sim().scene.model, [], [3], [], _sim().settings),
     TypeError, r"SimulatorModel: contacts\[0\] must be a stiction.SphereContact, got int"),
    ("model settings", lambda: stiction._core.SimulatorModel(_sim().scene.model, [], [], [], "fast"), TypeError,
     "SimulatorModel: settings"),
    ("data of None", lambda: stiction._core.SimulatorData(None), TypeError,
     "SimulatorData: sim must be a stiction.SimulatorModel, got None"),
    ("data of str", lambda: stiction._core.SimulatorData("cube"), TypeError, "SimulatorData: sim"),
    ("settings.dt str", lambda: setattr(stiction._core.SimulatorSettings(), "dt", "1ms"), TypeError,
     "dt must be a real number"),
    ("settings.mode str", lambda: setattr(stiction._core.SimulatorSettings(), "mode", "rk4"), TypeError,
     "mode must be a stiction.IntegrationMode"),
    ("settings.solver int", lambda: setattr(stiction._core.SimulatorSettings(), "solver", 3), TypeError,
     "solver must be a str"),
    ("contact.offset size", lambda: setattr(stiction._core.SphereContact(), "offset", [1.0, 2.0]), ValueError,
     "offset needs 3 entries"),
    ("contact.frame < 0", lambda: setattr(stiction._core.SphereContact(), "frame", -1), ValueError, "frame must be >= 0"),
    ("step None", lambda: stiction._core.step(None, _sim().data), TypeError, "step: sim"),
]


@pytest.mark.parametrize("call, error, match", [c[1:] for c in BAD_CALLS], ids=[c[0] for c in BAD_CALLS])
def test_bad_arguments_are_named(call, error, match):
    with pytest.raises(error, match=match) as info:
        call()
    assert "C++ signature" not in str(info.value)


def test_lists_and_integers_are_accepted_where_numpy_would():
    p = ContactProblem([[1, 0, 0], [0, 1, 0], [0, 0, 2]], [0, 0, 1], [Constraint.spatial_friction(1)])
    r = stiction.solve(p, tol=1e-12, max_iter=np.int64(50), warm_start=[0, 0, 0], time_limit=1)
    assert r.converged and r.lam[2] == pytest.approx(0.5)
    p.set_b([0, 0, 2])
    assert stiction.residual(p, [0, 0, 1]) == 0.0
    assert Constraint.bilateral(np.int32(2)).size == 2
    sim = _sim()
    sim.data.v = [0, 0, 0, 0, 0, 0]
    sim.data.t = 0
