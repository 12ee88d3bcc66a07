"""Case study planar-friction (§5.1, eq. 85-93): every check passes, and the key numbers hold when
recomputed here (eq. 90 by a plain fixed-step RK4 of this file, the penalty step's inclusion)."""
import json
import math
import re

import numpy as np
import pytest

from stiction.casestudies import planar_friction as pf
from stiction.cli import main
from stated_checks import assert_checks_as_stated

G = 9.81


@pytest.fixture(scope="module")
def result():
    return pf.run(quick=True)


# The module's checks as this file states them (docs/casestudies/planar-friction.md): pattern,
# expected, tolerance, kind. Measured (quick run): eq. 90 <= 3.4e-8 m/s, decay rates 2.5e-7 (rk4),
# 4.9e-5 (adaptive), normal force <= 1.0e-9, lag ratio 0.9958, accelerations 1.6e-14, penalty 2e-13.
G, F = 9.81, 0.5 * 9.81  # F = mu m g, m = 1 kg


def _normal_force_tolerance(c):
    """The solver's promise 1e-10 ||b||, b's rows at most g, ||f_e|| / m (0.9 F) and
    (2 zeta / delta) ||qdot|| <= ||v0|| / delta (v0 = 1 m/s), as a fraction of m g."""
    delta = float(re.search(r"delta ([\d.e-]+):", c.quantity).group(1))
    return 1e-10 * (G + 0.9 * F + 1.0 / delta) / G


STATED = [
    (r"largest step change of \|\|qdot\|\|\^2 while moving", 0.0, 0.0, "<="),  # eq. 91
    (r"max \|\|qdot - qdot_eq90\|\|", 0.0, 1e-7, "=="),
    (r"exponential rest, fitted decay rate x delta", 1.0, lambda c: 1e-5 if ", rk4," in c.quantity else 1e-3, "=="),
    (r"normal force / \(m g\) - 1", 0.0, _normal_force_tolerance, "=="),
    (r"eq\. 91's d\(", 0.0, 0.0, "<="),
    (r"rest entry vs the exact stop", 1.0, 0.02, "=="),
    (r"^1\.1 F from rest, .*: acceleration along f_e", 0.1 * F, 1e-8 * 0.1 * F, "=="),  # (1.1 F - F) / m
    (r"^1\.1 F from rest, .*: velocity across f_e", 0.0, 1e-9, "=="),
    (r"^0\.9 F from rest, relaxed ODE .* drift after", 0.0, 1e-12, "=="),
    (r"^penalty \(model C\)", 0.0, 1e-6, "=="),
    (r"^penalty: log-log slope", -1.0, 1e-6, "=="),
    (r"^penalty: largest \|\|lambda\|\| / F", 1.0, 0.0, "<="),
    (r"^penalty: the package's formulation='penalty'", 0.0, 1e-9, "=="),
    (r"^every rollout converged", 1.0, 0.0, "=="),
]


def test_every_check_passes(result):
    failed = [(c.quantity, c.measured, c.expected, c.tolerance) for c in result.checks if not c.passed]
    assert not failed
    assert_checks_as_stated(result, STATED)
    assert result.passed and len(result.checks) >= 10


def eq90_rk4(f_e, v0, delta, t_end, n, m=1.0, F=0.5 * 9.81):
    """eq. 90 by classical RK4 with n steps (independent of the module and of scipy)."""
    def f(v):
        z = f_e + m * v / delta
        nz = np.linalg.norm(z)
        return (f_e - (z if nz <= F else F * z / nz)) / m

    h = t_end / n
    v = np.array(v0, float)
    out = [v.copy()]
    for _ in range(n):
        k1 = f(v)
        k2 = f(v + h / 2 * k1)
        k3 = f(v + h / 2 * k2)
        k4 = f(v + h * k3)
        v = v + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(v.copy())
    return np.linspace(0, t_end, n + 1), np.array(out)


def test_relaxed_matches_eq90_recomputed(result):
    assert pf.MASS == 1.0 and pf.MU == 0.5
    F = 0.5 * 1.0 * G
    a = math.radians(135.0)
    f_e = 0.9 * F * np.array([math.cos(a), math.sin(a)])
    relaxed = [p for p in result.points if p["case"] == "relaxed"]
    assert {p["mode"] for p in relaxed} == {"rk4", "adaptive"}
    for p in relaxed:
        delta = p["delta"]
        t, v = eq90_rk4(f_e, [1.0, 0.0], delta, pf.DURATION, int(round(pf.DURATION / (delta / 50))))
        t_sim, v2_sim = np.asarray(p["t"]), np.asarray(p["v2"])
        v2_ref = np.interp(t_sim, t, np.einsum("ij,ij->i", v, v))
        # the simulator's ||qdot||^2 against this file's eq. 90 (interpolation error ~ dt^2 |v2''|)
        assert np.abs(v2_sim - v2_ref).max() < 1e-6
        assert np.all(np.diff(v2_sim[v2_sim > 1e-18]) < 0)  # monotone (eq. 91)
        assert p["max_difference"] < 1e-7 and p["final_speed"] < 1e-6
        assert p["decay_rate_x_delta"] == pytest.approx(1.0, abs=1e-4)


def test_exact_stop_time(result):
    """eq. 47-48 from v0 = (1, 0): recomputed here with a fine explicit Euler until the speed
    vanishes (the unrelaxed mass stops in finite time)."""
    F = 0.5 * G
    a = math.radians(135.0)
    f_e = 0.9 * F * np.array([math.cos(a), math.sin(a)])
    v, t, h = np.array([1.0, 0.0]), 0.0, 1e-5
    while np.linalg.norm(v) > F * h:  # the last step would overshoot the stop
        v = v + h * (f_e - F * v / np.linalg.norm(v))
        t += h
    (exact,) = [p for p in result.points if p["case"] == "exact"]
    assert exact["stop_time"] == pytest.approx(t, abs=1e-4)
    for p in (q for q in result.points if q["case"] == "relaxed"):
        assert 0 < exact["stop_time"] - p["rest_entry_time"] < 10 * p["delta"]


def test_sliding_acceleration(result):
    F = 0.5 * G
    for p in (q for q in result.points if q["case"] == "sliding"):
        assert p["acceleration"] == pytest.approx((1.1 * F - F) / 1.0, rel=1e-8)


def test_penalty_step_solves_the_discrete_inclusion():
    """Each step of the penalty model is the implicit Euler discretisation of eq. 92-93:
    lambda = K (e+ + beta (e+ - e)/h) and v+ + (e+ - e)/h in -N_{F B}(lambda)."""
    rng = np.random.default_rng(3)
    F, h, beta, m = 0.5 * G, 1e-3, 0.05, 1.0
    Ks = np.array([1e2, 1e3, 1e5])
    x = np.zeros((3, 2))
    v = rng.normal(size=(3, 2))
    e = rng.normal(size=(3, 2)) * 1e-3
    slipped = stuck = 0
    for _ in range(300):
        f_e = rng.normal(size=2) * F
        x1, v1, e1, lam = pf.penalty_step(x, v, e, f_e, Ks, beta, h)
        edot = (e1 - e) / h
        assert np.allclose(lam, Ks[:, None] * (e1 + beta * edot), rtol=1e-9, atol=1e-9)
        assert np.allclose(v1, v + h * (f_e + lam) / m, atol=1e-12)
        w = v1 + edot
        for k in range(3):
            nl = np.linalg.norm(lam[k])
            assert nl <= F * (1 + 1e-12)
            if nl < F * (1 - 1e-12):  # inside: no slip of the spring
                assert np.linalg.norm(w[k]) < 1e-8
                stuck += 1
            else:  # on the boundary: w = -c lambda, c >= 0
                c = -(w[k] @ lam[k]) / nl**2
                assert c >= -1e-12 and np.allclose(w[k], -c * lam[k], atol=1e-8)
                slipped += 1
        x, v, e = x1, v1, e1
    assert slipped and stuck


def test_penalty_drift(result):
    pen = [p for p in result.points if p["case"] == "penalty"]
    assert len(pen) >= 3
    for p in pen:
        assert p["drift"] * p["K"] / (0.9 * 0.5 * G) == pytest.approx(1.0, abs=1e-6)
        assert p["max_force_ratio"] < 1.0
        # the package's own penalty formulation: the same drift, and a normal spring m g / K
        assert p["simulator_drift"] == pytest.approx(p["drift"], rel=1e-9)
        assert p["simulator_penetration"] == pytest.approx(1.0 * G / p["K"], rel=1e-9)
    rest = [p for p in result.points if p["case"] == "relaxed-at-rest"]
    assert rest and all(p["drift"] <= 1e-12 for p in rest)


def test_cli_json(capsys):
    rc = main(["casestudy", "planar-friction", "--json", "--quick"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["passed"] is True
    assert out["name"] == "planar-friction" and out["equations"] == "85-93"
    for c in out["checks"]:
        assert {"quantity", "measured", "expected", "error", "tolerance", "passed", "kind"} <= set(c)
    cases = {p["case"] for p in out["points"]}
    assert cases == {"exact", "relaxed", "sliding", "relaxed-at-rest", "penalty"}
    for p in out["points"]:
        if p["case"] == "relaxed":
            assert {"mode", "delta", "max_increase_v2", "max_difference", "t", "v2", "v2_closed_form"} <= set(p)
        if p["case"] == "penalty":
            assert {"K", "beta", "drift", "predicted_drift", "max_force_ratio"} <= set(p)
