"""stiction bench stability: each failure mode is found where the physics says, and only there."""
import argparse
import csv
import math

import numpy as np
import pytest

from stiction.bench import stability as st


def run(map_, method, x, y):
    return st.evaluate({"map": map_, "method": method, "x": float(x), "y": float(y)})


def test_heavy_stack_exact_converges_at_10ms():
    """The issue's check: the two-cube stack at mass ratio 1e6, dt = 10 ms, exact: no failure."""
    r = run("stack-rest", "exact", 1e6, 1e-2)
    assert r["failure"] is None, r
    assert r["unconverged_steps"] == 0
    assert r["residual"] <= st.RESIDUAL_LIMIT
    assert r["drift"] <= r["drift_limit"]
    assert r["steps"] == 200  # 2 s at 10 ms: the whole run


def test_sliding_stack_exact_keeps_the_heavy_top_and_decelerates_at_mu_g():
    r = run("stack-slide", "exact", 1e6, 1e-3)
    assert r["failure"] is None, r
    assert r["accel_error"] < 1e-6 and r["direction_error_deg"] < 1e-3
    assert r["drift"] < 1e-9  # the top does not move on the bottom


@pytest.mark.parametrize("slope,mu", [(25.0, 0.5), (28.0, 0.5), (20.0, 0.6), (35.0, 0.6)])
def test_incline_exact_is_right_on_both_sides_of_tan_theta_eq_mu(slope, mu):
    """tan 25° = 0.466 < 0.5 sticks, tan 28° = 0.532 > 0.5 slides: exact passes the stick test on
    one side and the sliding test (a = g (sin - mu cos) to 1 %) on the other."""
    r = run("incline", "exact", slope, mu)
    assert r["failure"] is None, r
    assert r["boundary"] == pytest.approx(math.tan(math.radians(slope)))
    if math.tan(math.radians(slope)) < mu:
        assert r["accel_error"] is None and r["drift"] < 1e-9
    else:
        assert r["drift"] is None and r["accel_error"] < 1e-6 and r["direction_error_deg"] < 1e-3


def test_ccp_on_a_sliding_cube_fails_the_exact_law_and_sticking_it_passes():
    """CCP lifts a sliding contact (eq. 78-79: u_n = mu |u_t|): the residual mode, where it slides;
    where every contact sticks CCP coincides with exact."""
    slide = run("incline", "ccp", 35.0, 0.5)
    assert slide["failure"] == "residual" and slide["residual"] > 1e-3
    stick = run("incline", "ccp", 20.0, 0.5)
    assert stick["failure"] is None, stick


def test_nakaoka_creeps_where_exact_sticks():
    """Nakaoka's per-contact projection (eq. 80-81) lets the cube on the 30° slope (mu 0.6) creep."""
    r = run("incline", "nakaoka", 30.0, 0.6)
    assert "stiction-violated" in r["failures"].split("|")
    assert r["drift"] > 100 * r["drift_limit"]


def test_penalty_soft_springs_penetrate_and_stiff_ones_do_not():
    """mg cos(30°) / (4K) per corner at rest: 2 mm at K = 1e3 (> 1 mm), 2 µm at K = 1e6."""
    soft = run("penalty", "penalty", 1e3, 1e-3)
    assert "penetration" in soft["failures"].split("|") and soft["penetration"] > 1e-3
    stiff = run("penalty", "penalty", 1e6, 1e-3)
    assert "penetration" not in stiff["failures"].split("|") and stiff["penetration"] < 1e-5
    # the penalty never satisfies the rigid law (§4.6): the residual mode everywhere
    assert soft["failure"] == stiff["failure"] == "residual"


def test_penalty_explicit_limit_reduces_to_two_sqrt_m_over_k():
    """One spring on a point mass (lambda_max(A) = 1/m), no damping: dt = 2 sqrt(m/K); damping
    lowers it; the cube on the slope: the stiffest mode of A = J M^-1 J^T."""
    m, k = 2.0, 1e5
    assert st.penalty_explicit_limit(k, 1.0 / m, beta=0.0) == pytest.approx(2 * math.sqrt(m / k), rel=1e-12)
    assert st.penalty_explicit_limit(k, 1.0 / m, beta=1e-3) < 2 * math.sqrt(m / k)
    from stiction.scene import load_scene

    lam = st.delassus_lambda_max(load_scene("cube-incline-stick"))
    assert 6.0 < lam < 20.0  # 1 kg cube, 4 corners: above the 6/m of the normal rocking mode


def test_relaxed_ode_fails_by_sliding_wrong_when_delta_is_large_and_zeta_small():
    """eq. 64 with delta = 0.1 s, zeta = 0.1 relaxes the friction: the cube decelerates wrongly;
    delta = 1 ms, zeta = 1 reproduces mu g."""
    bad = run("ode", "exact-rk4", 0.1, 0.1)
    assert bad["failure"] == "sliding-wrong" and bad["accel_error"] > 0.1
    good = run("ode", "exact-rk4", 1e-3, 1.0)
    assert good["failure"] is None and good["accel_error"] < 1e-3


def test_heavy_top_blows_penalty_up():
    """1e6 kg on 1e5 N/m springs sinks past the simulator's bound: non-finite, the first mode."""
    r = run("stack-rest", "penalty", 1e6, 1e-3)
    assert r["failure"] == "non-finite" and "diverged" in r["error"]


def test_classify_orders_the_modes():
    row = {"error": None, "unconverged_steps": 2, "residual": 1e-3, "penetration": 2e-3, "energy_gain": 0.0,
           "drift": 1.0, "drift_limit": 1e-5, "accel_error": None, "direction_error_deg": None, "tilt_deg": 0.0}
    assert st.classify(row) == ["own-solver-failed", "residual", "penetration", "stiction-violated"]
    row.update(unconverged_steps=0, residual=1e-9, penetration=0.0, drift=None, accel_error=0.02,
               direction_error_deg=0.0, tilt_deg=10.0)
    assert st.classify(row) == ["sliding-wrong", "structure-lost"]


def test_bad_input_is_loud():
    with pytest.raises(ValueError, match="maps"):
        st.cases(argparse.Namespace(quick=True, maps="incline,heap", methods=None))
    with pytest.raises(ValueError, match="methods"):
        st.cases(argparse.Namespace(quick=True, maps="incline", methods="exakt"))
    with pytest.raises(ValueError, match="multiple of 4"):
        st.tower_scene(10)
    with pytest.raises(ValueError, match="2 n"):
        st.pile_scene(16)
    with pytest.raises(ValueError, match="mass ratio"):
        st.stack_scene(-1.0, False)


def test_quick_sweep_through_the_cli_writes_csv_png_and_finite_rows(tmp_path, capsys):
    """`stiction bench stability --quick --json --out DIR`: the CSV's columns are FIELDS, one row per
    case, finite numbers, a chart per map; a second run resumes (every case already in the CSV)."""
    import json

    from stiction.cli import main

    argv = ["bench", "stability", "--quick", "--maps", "incline,tower,ode", "--methods", "exact,ccp",
            "--workers", "1", "--json", "--out", str(tmp_path)]
    assert main(argv) in (0, None)
    res = json.loads(capsys.readouterr().out)
    cases = st.cases(argparse.Namespace(quick=True, maps="incline,tower,ode", methods="exact,ccp"))
    assert len(res["rows"]) == len(cases) == 4 * 2 + 4 * 2 + 4
    with open(tmp_path / "stability.csv", newline="") as fh:
        header = next(csv.reader(fh))
    assert tuple(header) == st.FIELDS
    for r in res["rows"]:
        assert r["failure"] is None or r["failure"] in st.FAILURE_MODES
        for k in ("residual", "penetration", "energy_gain", "seconds"):
            assert r[k] is not None and np.isfinite(r[k]), (k, r)
    for m in ("incline", "tower", "ode"):
        assert (tmp_path / f"stability-{m}.png").stat().st_size > 10_000
    # exact passes every incline cell; on the tower a looser tolerance leaves a larger residual
    assert all(r["failure"] is None for r in res["rows"] if r["map"] == "incline" and r["method"] == "exact")
    tower = {(r["method"], r["x"], r["y"]): r for r in res["rows"] if r["map"] == "tower"}
    for n in (8.0, 32.0):
        assert tower[("exact", n, 1e-8)]["failure"] is None
        assert tower[("exact", n, 1e-4)]["residual"] > 100 * tower[("exact", n, 1e-8)]["residual"]
    assert res["maps"]["incline"]["exact"]["failed"] == 0
    assert main(argv) in (0, None)
    assert json.loads(capsys.readouterr().out)["resumed"] == len(cases)


def test_the_ode_line_relaxed_stiction_speed():
    """The line drawn on the delta x zeta map: below mu g delta / (2 zeta) the relaxed law (eq. 64)
    holds a_t = -(2 zeta / delta) v_t. At delta = 0.1 s, zeta = 0.1 that speed is 2.45 m/s > v0 = 1:
    the cube's velocity decays exponentially and it travels v0 delta/(2 zeta) (1 - exp(-2 zeta T / delta))."""
    from stiction import _core
    from stiction.simulator import Simulator

    delta, zeta, T = 0.1, 0.1, 0.4
    assert st.ODE_MU * st.G * delta / (2 * zeta) > st.ODE_V0
    sim = Simulator("cube-slide", mode="rk4", delta=delta, zeta=zeta,
                    dt=min(1e-3, 0.5 * _core.rk4_stable_step(delta, zeta)))
    traj = sim.rollout(T)
    expected = st.ODE_V0 * delta / (2 * zeta) * (1 - math.exp(-2 * zeta * T / delta))
    assert traj.q[-1, 0] - traj.q[0, 0] == pytest.approx(expected, rel=1e-3)


def test_explicit_limit_is_where_symplectic_euler_turns_unstable():
    """The derivation: x'' + beta w^2 x' + w^2 x = 0 by symplectic Euler grows just above
    h* = -beta + sqrt(beta^2 + 4/w^2) and does not just below (w^2 = K lambda_max)."""
    k, lam, beta = 1e5, 14.3, 1e-3
    w2 = k * lam
    h_star = float(st.penalty_explicit_limit(k, lam, beta))

    def amplitude(h, steps=4000):
        x, v = 1.0, 0.0
        for _ in range(steps):
            v += h * (-w2 * x - beta * w2 * v)
            x += h * v
        return abs(x) + abs(v) / math.sqrt(w2)

    assert amplitude(0.99 * h_star) < 1.0
    assert amplitude(1.01 * h_star) > 1e3


def test_implicit_penalty_survives_far_past_the_explicit_limit():
    """Kikuuwe-Fujimoto's implicit penalty (eq. 83-84) at K = 1e7, dt = 10 ms, ~700x the explicit
    limit: no blow-up (what fails there is its own iteration, not stability)."""
    r = run("penalty", "penalty", 1e7, 1e-2)
    assert r["y"] > 100 * r["boundary"]
    assert "non-finite" not in r["failures"] and r["steps"] == 200
    assert r["penetration"] < 1e-5


def test_pile_geometry_and_exact_rest():
    """Each upper cube's corners lie on the top faces of the two cubes below it (inside their
    outline), every gap is 0 at the start, and exact holds the 24-contact pile (3 layers)."""
    from stiction.simulator import Simulator

    scene, layers = st.pile_scene(24)
    assert layers == [3, 2, 1] and len(scene.contacts) == 24
    frames = [c.frame for c in scene.contacts[::4]]
    centre = {f: scene.q0[7 * k:7 * k + 3] for k, f in enumerate(frames)}
    for c in scene.contacts:
        corner = centre[c.frame] + np.asarray(c.offset)
        h = scene.halfspaces[c.halfspace]
        if c.halfspace == 0:
            assert corner[2] == pytest.approx(0.0, abs=1e-15)
        else:
            below = centre[h.frame]
            assert abs(corner[0] - below[0]) < st.CUBE / 2 and abs(corner[1] - below[1]) <= st.CUBE / 2 + 1e-15
            assert corner[2] == pytest.approx(below[2] + st.CUBE / 2, abs=1e-15)
            assert h.frame != c.frame
    sim = Simulator(scene)
    sim.step()
    assert np.abs(np.asarray(sim.data.q) - scene.q0).max() < 1e-12
    r = run("pile", "exact", 24, 1e-8)
    assert r["failure"] is None, r
    assert r["drift"] < 1e-9 and r["tilt_deg"] < 1e-6
