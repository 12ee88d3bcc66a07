"""Case study painleve (§5.3, eq. 105-121): every check passes, and the key numbers hold when
recomputed here from the paper's closed forms (not from the module's helpers)."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

import stiction
from stiction.casestudies import painleve
from stiction.cli import main
from stated_checks import assert_checks_as_stated

G = 9.81


@pytest.fixture(scope="module")
def result():
    return painleve.run(quick=True)


def closed_forms(theta, mu, m=painleve.MASS, l=painleve.HALF_LENGTH, theta_dot=painleve.THETA_DOT):
    """A (eq. 117 = J M^-1 J^T, expanded), A^-1, G_A (eq. 121), G_B (eq. 120), r_b (eq. 119)."""
    s, c = math.sin(theta), math.cos(theta)
    A = np.array([[1 + 3 * s * s, -3 * s * c], [-3 * s * c, 1 + 3 * c * c]]) / m
    Ainv = m / 4 * np.array([[1 + 3 * c * c, 3 * s * c], [3 * s * c, 1 + 3 * s * s]])
    return A, Ainv, G - l * theta_dot**2 * s, m / 4 * (1 + 3 * c * c - 3 * mu * s * c), Ainv[:, 0]


# The module's checks as this file states them (docs/casestudies/painleve.md): pattern, expected,
# tolerance, kind. Measured (quick run): A, b, G_B at rounding (<= 7e-16), G_A 5e-13, mu* 2e-16,
# theta* 4e-7 deg, residuals 7e-16, picked forces <= 1e-9, jam rate 5e-8, jam impulse 7.6e-4.
STATED = [
    (r"^simulator Delassus operator vs eq\. 117", 0.0, 1e-12, "=="),
    (r"^simulator right-hand side b vs eq\. 116", 0.0, 1e-12, "=="),
    (r"^G_A from the simulator", 0.0, 1e-11, "=="),
    (r"^G_B from the simulator's A", 0.0, 1e-12, "=="),
    (r"^smallest mu with G_B < 0", 4.0 / 3.0, 1e-9, "=="),  # eq. 120 minimised: mu = 4/3
    (r"^theta of the smallest such mu", math.degrees(math.atan(2.0)), 1e-3, "=="),  # at tan theta = 2
    (r"^every enumerated solution satisfies eq\. 65", 1e-10, 0.0, "<="),
    (r"^grid points whose number of solutions", 0.0, 0.0, "=="),
    (r"^solutions whose kind differs", 0.0, 0.0, "=="),
    (r"^grid points in the (non-unique|no-solution) region", 1.0, 0.0, ">="),
    (r"^(unique-slip|unique-detach|no-solution|non-unique): the simulator's first force", 0.0, 1e-7, "=="),
    (r"^no-solution: the rod jams: stick phase", 2 * 1e-5, 0.0, ">="),  # two steps of delta = 1e-5 s
    (r"^no-solution: slip velocity decay rate", 1.0, 1e-6, "=="),
    (r"^no-solution: jam impulse", 0.0, 2e-3, "=="),
    (r"^every rollout converged", 1.0, 0.0, "=="),
]


def test_every_check_passes(result):
    failed = [(c.quantity, c.measured, c.expected, c.tolerance) for c in result.checks if not c.passed]
    assert not failed
    assert_checks_as_stated(result, STATED)
    assert result.passed and len(result.checks) >= 15


def test_grid_points_against_closed_forms(result):
    grid = [p for p in result.points if p["type"] == "grid"]
    assert len(grid) >= 100
    seen = set()
    for p in grid:
        theta, mu = math.radians(p["theta_deg"]), p["mu"]
        A, _, ga, gb, _ = closed_forms(theta, mu)
        assert p["G_A"] == pytest.approx(ga, rel=1e-12, abs=1e-12)
        assert p["G_B"] == pytest.approx(gb, rel=1e-12, abs=1e-14)
        region = {(True, True): "unique-slip", (False, True): "unique-detach", (False, False): "non-unique",
                  (True, False): "no-solution"}[(ga > 0, gb > 0)]
        assert p["region"] == region
        seen.add(region)
        # b of eq. 116 at p_n = pdot_n = 0: A r_a - (2 zeta pdot_t / delta) e_t, with A r_a = (l thetadot^2 ... )
        # written out: A r_a = (0, g) - l thetadot^2 (c, s)  (eq. 118 times A)
        s, c = math.sin(theta), math.cos(theta)
        b = np.array([0.0, G]) - painleve.HALF_LENGTH * painleve.THETA_DOT**2 * np.array([c, s]) \
            + np.array([2 * painleve.ZETA * painleve.SLIP_SPEED / painleve.DELTA_ENUM, 0.0])
        kinds = sorted(sol["kind"] for sol in p["solutions"])
        expected = {"unique-slip": ["slip"], "unique-detach": ["detach"], "non-unique": ["detach", "slip", "stick"],
                    "no-solution": ["stick"]}[region]
        assert kinds == expected, (p["theta_deg"], mu, kinds)
        for sol in p["solutions"]:
            lam = np.asarray(sol["lambda"])
            u = A @ lam - b  # the relaxed contact acceleration of eq. 113
            if sol["kind"] == "detach":
                assert np.all(lam == 0) and b[1] <= 0
            elif sol["kind"] == "stick":
                assert np.allclose(u, 0, atol=1e-9 * np.abs(b).max()) and abs(lam[0]) < mu * lam[1]
            else:  # slip: friction +mu lambda_n against pdot_t < 0, no normal motion, u_t <= 0
                assert lam[0] == pytest.approx(mu * lam[1], rel=1e-14) and lam[1] > 0
                assert abs(u[1]) <= 1e-9 * np.abs(b).max() and u[0] <= 0
            problem = stiction.ContactProblem(A, b, [stiction.Constraint.planar_friction(mu)])
            assert stiction.exact_law_measures(problem, lam).relative_residual <= 1e-10
            assert sol["residual"] <= 1e-10
    assert seen == set(painleve.REGIONS)


def test_non_unique_needs_mu_above_four_thirds(result):
    nonunique = [p for p in result.points if p["type"] == "grid" and p["region"] == "non-unique"]
    assert nonunique and min(p["mu"] for p in nonunique) > 4 / 3


def test_simulated_points(result):
    sims = {p["region"]: p for p in result.points if p["type"] == "simulation"}
    assert set(sims) == set(painleve.REGIONS)
    assert sims["unique-slip"]["picked"] == "slip"
    assert sims["unique-detach"]["picked"] == "detach"
    assert sims["no-solution"]["picked"] == "stick"
    assert sims["non-unique"]["picked"] in ("detach", "stick", "slip")
    assert len(sims["non-unique"]["solutions"]) == 3
    # the slip point keeps slipping on the ground; the detach point leaves it
    assert sims["unique-slip"]["rollout"]["state_fractions"]["slip"] == 1.0
    assert sims["unique-slip"]["rollout"]["final_slip_velocity"] < 0
    assert sims["unique-detach"]["rollout"]["final_gap"] > 0
    # the jam: its impulse is the rigid sticking impulse |pdot_t| r_b up to O(delta)
    jam = sims["no-solution"]["rollout"]
    theta = math.radians(sims["no-solution"]["theta_deg"])
    r_b = closed_forms(theta, sims["no-solution"]["mu"])[4]
    assert np.allclose(jam["rigid_impulse"], painleve.SLIP_SPEED * r_b, rtol=1e-12)
    assert np.linalg.norm(np.asarray(jam["stick_impulse"]) - painleve.SLIP_SPEED * r_b) \
        <= 0.02 * np.linalg.norm(r_b)
    assert jam["max_force"] > 100 * painleve.MASS * G  # an impact: forces of order |pdot_t| / delta


def test_stiction_solve_finds_one_of_the_three():
    theta, mu = math.radians(60.0), 2.0
    A, _, ga, gb, _ = closed_forms(theta, mu)
    assert ga < 0 and gb < 0
    b = painleve.rhs(theta, painleve.THETA_DOT, -1.0, 1e-4)
    sols = painleve.enumerate_solutions(A, b, mu)
    assert [k for k, _ in sols] == ["detach", "stick", "slip"]
    for start in (None, "proxqp"):
        res = stiction.solve(stiction.ContactProblem(A, b, [stiction.Constraint.planar_friction(mu)]), warm_start=start)
        assert res.converged
        assert min(np.linalg.norm(res.lam - lam) / max(np.linalg.norm(lam), 1.0) for _, lam in sols) < 1e-8


def test_scene_file_is_the_case_study_rod():
    """robots/scenes/painleve-rod.toml: the same body and the no-solution state."""
    from stiction.scene import load_scene
    from stiction.simulator import Simulator

    path = Path(__file__).resolve().parents[1] / "robots" / "scenes" / "painleve-rod.toml"
    sc = load_scene(str(path))
    theta = math.atan2(sc.q0[3], sc.q0[2])
    q, v = painleve.rod_state(theta, painleve.THETA_DOT, -painleve.SLIP_SPEED)
    assert np.allclose(sc.q0, q, atol=1e-15) and np.allclose(sc.v0, v, atol=1e-14)
    sim = Simulator(sc)
    stiction._core.build_contact_problem(sim.model, sim.data, sc.q0, sc.v0, sc.delta, sc.zeta)
    A, _, ga, gb, _ = closed_forms(theta, sc.mu)
    # b_n = G_A - p_n / delta^2 - ...: the gap's rounding (~1e-17 m) over delta^2 = 1e-8 s^2
    assert np.allclose(sim.data.A, A, rtol=1e-12) and sim.data.b[1] == pytest.approx(ga, abs=1e-8)
    assert ga > 0 > gb  # no slipping solution: the jam


def test_cli_json(capsys):
    rc = main(["casestudy", "painleve", "--json", "--quick"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["passed"] is True
    assert out["name"] == "painleve" and out["equations"] == "105-121"
    for c in out["checks"]:
        assert {"quantity", "measured", "expected", "error", "tolerance", "passed", "kind"} <= set(c)
    grid = [p for p in out["points"] if p["type"] == "grid"]
    sims = [p for p in out["points"] if p["type"] == "simulation"]
    assert grid and len(sims) == 4
    for p in grid + sims:
        assert {"theta_deg", "mu", "region", "G_A", "G_B", "solutions"} <= set(p)
        for sol in p["solutions"]:
            assert {"kind", "lambda"} <= set(sol) and len(sol["lambda"]) == 2
    for p in grid:
        for sol in p["solutions"]:
            assert isinstance(sol["residual"], float)
    assert all("picked" in p for p in sims)
