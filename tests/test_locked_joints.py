"""A step whose joints' dry friction holds is solved with those joints locked (locked_joints.cpp,
docs/joint-rows.md "Joints that hold"): the contacts' problem on the free coordinates alone. Its answer
must solve the whole step problem (eq. 65 with the friction rows, |lambda| <= h tau_c): checked here
with numpy on the full A = J M^-1 J^T, built from the step's J and M, never from the reduced solve."""
import numpy as np
import pytest

from stiction.simulator import Simulator


@pytest.fixture(scope="module")
def settled():
    sim = Simulator("solo12-stand-joint-rows")
    for _ in range(600):  # 0.6 s: past the settle time, standing still
        sim.step()
    return sim


def test_settled_steps_lock_the_joints(settled):
    # (the message says which path solved the step; the old code solved the 24-row problem)
    assert "joints locked" in settled.data.result.message


def test_locked_answer_solves_the_full_problem(settled):
    d, h = settled.data, settled.dt
    J, M = np.asarray(d.J), np.asarray(d.M)
    A_numpy = J @ np.linalg.solve(M, J.T)
    A = np.asarray(d.A)  # (built on demand after a locked step)
    assert np.allclose(A, A_numpy, rtol=1e-10, atol=1e-12 * np.abs(A_numpy).max())
    r = d.result
    lam, b = np.asarray(r.lam), h * np.asarray(d.b)
    u = A_numpy @ lam - b
    rows = d.joint_rows
    nj = len(rows)
    mc = len(lam) - nj
    assert nj == 12 and all(kind == "friction" for kind, _ in rows)
    # friction rows: the joint holds (u = v+ = 0) with its impulse strictly inside [-h tau_c, h tau_c]
    assert np.abs(u[mc:]).max() <= 1e-12 * np.linalg.norm(b)
    assert np.abs(lam[mc:]).max() < h * 0.03
    # contact rows: Signorini and Coulomb at each foot (lambda = (t1, t2, n), mu = 1)
    for o in range(0, mc, 3):
        lt, ln = lam[o:o + 2], lam[o + 2]
        assert ln > 0.0 and abs(u[o + 2]) <= 1e-9 * np.linalg.norm(b)  # pushing, not separating
        assert np.linalg.norm(lt) < ln  # inside the cone: sticking
        assert np.linalg.norm(u[o:o + 2]) <= 1e-9 * np.linalg.norm(b)  # no slip
    # and the verdict of the exact law on the full problem
    assert r.converged and r.exact_law.relative_residual <= 1e-10


def test_locked_steps_hold_the_joints_exactly(settled):
    q0 = np.asarray(settled.data.q).copy()
    for _ in range(200):
        settled.step()
        assert "joints locked" in settled.data.result.message
    assert np.abs(np.asarray(settled.data.q)[7:] - q0[7:]).max() == 0.0


def full_problem_check(sim, tau_c):
    """The locked answer of sim's last step against the full problem, with numpy: every locked friction
    row holds (u = 0, impulse inside h tau_c), the exact-law verdict on the full A converged."""
    d, h = sim.data, sim.dt
    J, M = np.asarray(d.J), np.asarray(d.M)
    A_numpy = J @ np.linalg.solve(M, J.T)
    assert np.allclose(np.asarray(d.A), A_numpy, rtol=1e-9, atol=1e-12 * np.abs(A_numpy).max())
    r = d.result
    lam, b = np.asarray(r.lam), h * np.asarray(d.b)
    u = A_numpy @ lam - b
    mc = len(lam) - len(d.joint_rows)
    friction = [mc + k for k, (kind, dof) in enumerate(d.joint_rows)
                if kind == "friction" and sum(1 for _, other in d.joint_rows if other == dof) == 1]
    assert friction
    assert np.abs(u[friction]).max() <= 1e-12 * np.linalg.norm(b)
    assert all(abs(lam[i]) < h * tau_c[d.joint_rows[i - mc][1]] for i in friction)
    assert r.converged and r.exact_law.relative_residual <= 1e-10


@pytest.mark.parametrize("scene", ["go2-stand", "talos-stand"])
def test_rebalanced_locked_answer_solves_the_full_problem(scene):
    # the benchmark's robots with dry friction on every joint (TALOS: 2 grippers on their limits, their
    # rows kept): the reduced solve's choice among the all-stick family moved to the smallest friction
    # torques (rebalance) where it asked too much
    import sys
    from pathlib import Path
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from bench_robots_mujoco import joint_rows_scene
    sc, _ = joint_rows_scene(scene)
    sim = Simulator(sc)
    locked = 0
    for _ in range(700):
        sim.step()
        locked += "joints locked" in sim.data.result.message
    assert locked >= 400
    assert "joints locked" in sim.data.result.message
    full_problem_check(sim, np.asarray(sc.model.friction))
