"""Case study §4.3 (eq. 67-69): the relaxed lambda at the position, velocity and acceleration
levels; references re-derived here with finite differences (no pinocchio Jacobians)."""
import json
import math

import numpy as np
import pinocchio as pin
import pytest

from stiction import cli
from stiction.casestudies import kinematic_levels as cs
from stated_checks import assert_checks_as_stated


@pytest.fixture(scope="module")
def result():
    return cs.run(quick=True)


def fd_terms(model, q, v):
    """A and b_0 with J q' and J' q' from the end point's path p(q + t v) by finite differences."""
    data = model.createData()

    def end(t):
        pin.forwardKinematics(model, data, pin.integrate(model, q, t * v))
        return data.oMi[1].act(cs.END)

    h = 1e-4
    Jv = (end(h) - end(-h)) / (2 * h)
    Jdot_v = (end(h) - 2 * end(0.0) + end(-h)) / h**2
    J = np.zeros((3, model.nv))
    for k in range(model.nv):
        e = np.zeros(model.nv)
        e[k] = 1e-6
        pin.forwardKinematics(model, data, pin.integrate(model, q, e))
        p1 = data.oMi[1].act(cs.END)
        pin.forwardKinematics(model, data, pin.integrate(model, q, -e))
        J[:, k] = (p1 - data.oMi[1].act(cs.END)) / 2e-6
    M = pin.crba(model, model.createData(), q)
    M = np.triu(M) + np.triu(M, 1).T
    nle = pin.rnea(model, model.createData(), q, v, np.zeros(model.nv))
    A = J @ np.linalg.solve(M, J.T)
    return A, J @ np.linalg.solve(M, nle) - Jdot_v, Jv


# The module's checks as this file states them (docs/casestudies/kinematic-levels.md): pattern,
# expected, tolerance, kind. Measured (quick run): thresholds 5e-12 relative, sliding rate 1.018,
# sliding error 2.5e-4, acceleration limits 9e-14, package A, b 3.4e-14.
STATED = [
    (r"^eq\. 6[78] \(Psi_p = [01]", 0.0, 0.0, "=="),  # no force below delta*
    (r"^eq\. 6[78]: delta\*", 1.0, 1e-6, "=="),
    (r"^eq\. 68-69 sliding \(v_t", 1.0, 0.05, "=="),  # convergence order 1
    (r"^eq\. 68-69 sliding: \|lambda", 1e-3, 0.0, "<="),
    (r"^eq\. 69 \((stick|slip),", 1e-8, 0.0, "<="),
    (r"^eq\. 22, 27:", 1e-9, 0.0, "<="),
    (r"^solves that did not converge", 0.0, 0.0, "=="),
]


def test_every_check_passes(result):
    failed = [(c.quantity, c.measured, c.expected) for c in result.checks if not c.passed]
    assert not failed
    assert_checks_as_stated(result, STATED)
    assert len(result.checks) >= 9


def test_sliding_reference_from_finite_differences(result):
    model = cs.rod_model()
    q, R = cs.pose(0.0)
    phi = math.radians(100.0)
    v = cs.velocity(R, [0.5 * math.cos(phi), 0.5 * math.sin(phi), 0.0], [0.0, 0.0, 1.0])
    A, b0, Jv = fd_terms(model, q, v)
    mu = 0.3
    vt = Jv[:2] / np.linalg.norm(Jv[:2])
    ref = b0[2] / (A[2, 2] - mu * A[2, :2] @ vt) * np.array([-mu * vt[0], -mu * vt[1], 1.0])
    pts = [p for p in result.points if p["level"] == "velocity-sliding"]
    np.testing.assert_allclose(pts[0]["reference"], ref, rtol=1e-5)
    errs = [np.linalg.norm(p["lam"] - ref) / np.linalg.norm(ref) for p in pts]
    assert errs[-1] < 1e-3 and errs == sorted(errs, reverse=True)  # smaller delta, closer
    d = np.array([p["delta"] for p in pts])
    assert np.polyfit(np.log(d[d <= 1e-2]), np.log(np.array(errs)[d <= 1e-2]), 1)[0] == pytest.approx(1.0, abs=0.05)
    # the limit satisfies eq. 68 in its rows: lambda_t on the cone's edge against v_t
    lam = pts[-1]["lam"]
    assert np.linalg.norm(lam[:2]) == pytest.approx(mu * lam[2], rel=1e-9)
    assert lam[:2] @ vt / np.linalg.norm(lam[:2]) == pytest.approx(-1.0, abs=1e-4)


def test_position_threshold_from_finite_differences(result):
    model = cs.rod_model()
    q, R = cs.pose(1e-3)
    v = cs.velocity(R, [0.2, 0.1, -0.3], [0.0, 0.4, 0.0])
    _, b0, Jv = fd_terms(model, q, v)
    zeta = cs.ZETA
    # b_n(delta) = b0_n - 2 zeta v_n / delta - psi / delta^2 = 0
    d_star = (2 * zeta * Jv[2] + math.sqrt((2 * zeta * Jv[2]) ** 2 + 4 * b0[2] * 1e-3)) / (2 * b0[2])
    pts = [p for p in result.points if p["level"] == "position"]
    assert pts[0]["delta_star"] == pytest.approx(d_star, rel=1e-5)
    for p in pts:
        assert (np.linalg.norm(p["lam"]) == 0.0) == (p["delta"] < d_star)


def test_acceleration_level_is_delta_independent(result):
    for level in ("acceleration-stick", "acceleration-slip"):
        pts = [p for p in result.points if p["level"] == level]
        lams = np.array([p["lam"] for p in pts])
        np.testing.assert_allclose(lams, np.broadcast_to(lams[0], lams.shape), rtol=1e-8)
    slip = [p for p in result.points if p["level"] == "acceleration-slip"][0]
    assert np.linalg.norm(slip["lam"][:2]) == pytest.approx(0.2 * slip["lam"][2], rel=1e-8)
    stick = [p for p in result.points if p["level"] == "acceleration-stick"][0]
    assert np.linalg.norm(stick["lam"][:2]) < 1.0 * stick["lam"][2]


def test_cli_json(capsys):
    assert cli.main(["casestudy", "kinematic-levels", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["name"] == "kinematic-levels" and out["equations"] == "64-69" and out["passed"]
    assert all({"quantity", "measured", "expected", "tolerance", "passed"} <= set(c) for c in out["checks"])
    levels = {p["level"] for p in out["points"]}
    assert levels == {"position", "velocity-separating", "velocity-sliding", "acceleration-stick",
                      "acceleration-slip"}
    assert all({"delta", "zeta", "lam", "reference", "error"} <= set(p) for p in out["points"])
