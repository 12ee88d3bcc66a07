"""Case study §3 (eq. 24-36): Baumgarte stabilisation of the pinned rod, and the time step as the
relaxed form at delta = h, zeta = 1/2; key numbers re-derived here independently of the module."""
import json

import numpy as np
import pytest
from scipy.linalg import expm

from stiction import cli
from stiction.casestudies import pendulum as cs
from stated_checks import assert_checks_as_stated


@pytest.fixture(scope="module")
def result():
    return cs.run(quick=True)


def second_order(t, delta, zeta, e0, edot0):
    """eq. 24 per component by the matrix exponential (independent of Gamma)."""
    S = np.array([[0.0, 1.0], [-1.0 / delta**2, -2.0 * zeta / delta]])
    return np.array([[(expm(S * tk) @ np.array([a, b]))[0] for a, b in zip(e0, edot0)] for tk in np.atleast_1d(t)])


# The module's checks as this file states them (docs/casestudies/pendulum.md): pattern, expected,
# tolerance, kind. Measured (quick run): eq. 24 2.5e-6, the step at delta = h 3.6e-8, consistent
# drift 2.3e-13 m, eq. 36 3.8e-11, deadbeat 9e-5, order 2.0008, constant 1.00006.
H = 1e-3


def _first_step_expected(c):  # eq. 24 written out here (expm), not the module's closed form
    return np.linalg.norm(second_order(H, H, 0.5, cs.E0_TS, cs.EDOT0_TS)[0]) / np.linalg.norm(cs.E0_TS)


STATED = [
    (r"^eq\. 24: worst", 1e-4, 0.0, "<="),
    (r"^eq\. 24, relaxed ODE at delta = h = 0\.001 s", _first_step_expected,
     1e-4 * (np.linalg.norm(cs.E0_TS) + H * np.linalg.norm(cs.EDOT0_TS)) / np.linalg.norm(cs.E0_TS), "=="),
    (r"^relaxed ODE from a consistent start", 1e-10, 0.0, "<="),
    (r"^eq\. 36:", 1e-8, 0.0, "<="),
    (r"^eq\. 34-36 \(deadbeat\)", 1e-2, 0.0, "<="),
    (r"^eq\. 35 remainder: order", 2.0, 0.05, "=="),
    (r"^eq\. 35 remainder: max", 1.0, 0.01, "=="),
    (r"^steps whose contact solve did not converge", 0.0, 0.0, "=="),
]


def test_every_check_passes(result):
    failed = [(c.quantity, c.measured, c.expected) for c in result.checks if not c.passed]
    assert not failed
    assert_checks_as_stated(result, STATED)
    assert len(result.checks) >= 7


@pytest.mark.parametrize("zeta", [0.2, 0.5, 1.0, 2.0])
def test_closed_form_is_the_second_order_system(zeta):
    t = np.linspace(0, 0.05, 11)
    np.testing.assert_allclose(cs.error_closed_form(t, 0.01, zeta, cs.E0, cs.EDOT0),
                               second_order(t, 0.01, zeta, cs.E0, cs.EDOT0), atol=1e-15)


def test_decay_points_follow_eq24(result):
    decay = [p for p in result.points if p["experiment"] == "ode-decay"]
    assert len(decay) >= 4
    for p in decay:
        ref = np.linalg.norm(second_order(3 * p["delta"], p["delta"], p["zeta"], cs.E0, cs.EDOT0)[0])
        assert p["expected_error_at_3delta"] == pytest.approx(ref, rel=1e-9)
        assert p["error_at_3delta"] == pytest.approx(ref, rel=1e-3)


def test_time_stepping_is_deadbeat_where_the_ode_is_not(result):
    pts = sorted((p for p in result.points if p["experiment"] == "timestep-vs-ode"), key=lambda p: p["step"])
    h = pts[0]["h"]
    e0 = np.linalg.norm(cs.E0_TS)
    assert pts[0]["timestep_error"] == pytest.approx(e0, rel=1e-6)
    # zeta = 1/2 removes it (to the eq. 35 remainder); zeta = 1 would leave h |e'_0|, about e0 here
    assert pts[1]["timestep_error"] < 1e-2 * h * np.linalg.norm(cs.EDOT0_TS)
    ode = np.linalg.norm(second_order(h, h, 0.5, cs.E0_TS, cs.EDOT0_TS)[0])
    assert pts[1]["ode_error"] == pytest.approx(ode, rel=1e-3)
    assert ode > 0.5 * e0  # the continuous relaxed form keeps most of it after one h


def test_time_stepping_drift_order_two(result):
    pts = [p for p in result.points if p["experiment"] == "timestep-drift"]
    h = np.array([p["h"] for p in pts])
    e = np.array([p["max_error"] for p in pts])
    assert np.polyfit(np.log(h), np.log(e), 1)[0] == pytest.approx(2.0, abs=0.05)
    # (h^2/2) omega_max^2 |r|, omega_max from energy: (1/2) I omega^2 = m g d (1 - cos theta0)
    inertia = 0.0208666667 + 0.25**2
    omega2 = 2 * 9.81 * 0.25 * (1 - np.cos(cs.THETA0)) / inertia
    np.testing.assert_allclose(e, 0.5 * h**2 * omega2 * 0.25, rtol=0.01)


def test_cli_json(capsys):
    assert cli.main(["casestudy", "pendulum", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["name"] == "pendulum" and out["equations"] == "24-36" and out["passed"]
    assert all({"quantity", "measured", "expected", "tolerance", "passed"} <= set(c) for c in out["checks"])
    kinds = {p["experiment"] for p in out["points"]}
    assert kinds == {"ode-decay", "ode-consistent", "timestep-vs-ode", "timestep-drift"}
    assert all({"delta", "zeta", "max_deviation_from_eq24"} <= set(p) for p in out["points"]
               if p["experiment"] == "ode-decay")
