"""The joints' own rows of the step problem (issue 24, docs/joint-rows.md): position limits as
unilateral rows, dry friction as box rows |lambda| <= h tau_c, actuator effort limits as box rows
with the implicit PD as their compliance, viscous damping implicit.

Every check is against a closed form or Pinocchio's own algorithms (rnea, crba, the generalized
gravity), computed here from the recorded trajectory, never against the simulator's own numbers."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

import stiction
from stiction.scene import build_scene, load_scene
from stiction.scene_schema import SceneError
from stiction.simulator import Simulator

G = 9.81


def _gravity(model, q):
    return pin.computeGeneralizedGravity(model, model.createData(), np.asarray(q, dtype=float)).copy()


# ---- position limits

def test_ur5_elbow_falls_onto_its_limit_stops_and_holds_its_gravity_torque():
    """ur5-joint-limit: the elbow (PD off) falls onto the upper limit the scene narrows to 1.8 rad. It
    stops there (overshoot <= 1e-6 rad at h = 1 ms; measured ~1e-14), stays there, and at rest the limit
    torque is exactly what holds it: the elbow's gravity torque g(q) from Pinocchio at the final state."""
    sim = Simulator("ur5-joint-limit")
    model = sim.scene.model
    elbow = model.joints[model.getJointId("elbow_joint")]
    assert model.upperPositionLimit[elbow.idx_q] == 1.8
    traj = sim.rollout()
    q = traj.q[:, elbow.idx_q]
    hit = int(np.argmax(q >= 1.8 - 1e-9))
    assert 0 < hit and traj.t[hit] < 1.0  # it did fall onto it (from 1.6 rad)
    assert q.max() - 1.8 <= 1e-6
    late = traj.t >= 2.0
    assert np.abs(q[late] - 1.8).max() <= 1e-9  # it stays
    assert np.abs(traj.v[-1]).max() <= 1e-9  # the arm is at rest
    g = _gravity(model, traj.q[-1])
    limit = traj.limit_torque[-1]
    assert abs(limit[elbow.idx_v] - g[elbow.idx_v]) <= 1e-6 * abs(g[elbow.idx_v])
    assert np.count_nonzero(limit) == 1 and traj.tau[-1, elbow.idx_v] == 0.0  # only the elbow; its PD is off
    assert traj.converged[1:].all()
    summary = sim.summary(traj)
    assert summary["max_limit_overshoot"] == pytest.approx(max(0.0, q.max() - 1.8), abs=1e-15)


def test_a_joint_leaves_its_limit_freely():
    """From rest on the limit, a torque pulling away from it: the limit row pushes nothing (limit_torque
    0) and the first step's joint acceleration is Pinocchio's free one, M^-1 (tau - g), to 1e-9."""
    sim = Simulator("ur5-joint-limit")
    sim.rollout(2.5)
    model = sim.scene.model
    elbow = model.joints[model.getJointId("elbow_joint")].idx_v
    tau = np.asarray(sim.data.tau_ff).copy()
    tau[elbow] = -30.0  # gravity pushes the elbow up with ~13 N m; this pulls it down
    sim.data.tau_ff = tau
    q0, v0 = np.asarray(sim.data.q).copy(), np.asarray(sim.data.v).copy()
    traj = sim.rollout(0.05)
    assert np.all(traj.limit_torque[1:, elbow] == 0.0)
    assert np.all(np.diff(traj.q[:, elbow]) < 0)  # away from the limit, every step
    # the first step: the elbow row of M (v+ - v0) = h (tau_applied - g(q0)) (v0 = 0 at rest)
    data = model.createData()
    M = pin.crba(model, data, q0)
    M = np.triu(M) + np.triu(M, 1).T
    h = sim.dt
    residual = M @ (traj.v[1] - v0) - h * (traj.tau[1] - _gravity(model, q0) - pin.nonLinearEffects(
        model, data, q0, v0) + _gravity(model, q0))
    assert np.abs(residual).max() <= 1e-9 * h * 30.0


def test_without_limits_the_elbow_passes_through():
    """joint_limits=False: the same fall goes past 1.8 rad (the row is what stops it)."""
    traj = Simulator("ur5-joint-limit", joint_limits=False, duration=1.0).rollout()
    model_q = traj.q[:, 2]
    assert model_q.max() > 1.9


def test_a_fast_joint_far_from_its_limit_gets_its_row_in_time():
    """A joint thrown at its limit at 8 rad/s from 0.5 rad away (beyond the 0.02 rad margin): the row
    enters when the joint would reach the limit within a step, and the joint stops at it."""
    cfg = {"name": "ur5-throw", "robot": "ur5", "duration": 0.3, "dt": 1e-3, "contacts": {"feet": False},
           "initial": {"q": [0.0, -1.2, 1.3, -1.97, -1.5708, 0.0]},
           "joints": {"override": [{"joints": ["elbow_joint"], "upper": 1.8}]}}
    sim = Simulator(build_scene(cfg))
    sim.set_state(v=np.array([0.0, 0.0, 8.0, 0.0, 0.0, 0.0]))
    traj = sim.rollout()
    assert traj.q[:, 2].max() - 1.8 <= 1e-9
    assert np.abs(traj.q[-1, 2] - 1.8) <= 1e-9 or traj.q[-1, 2] < 1.8


def test_ode_modes_relax_the_limit_rows():
    """rk4 (the relaxed DAI, eq. 64, delta = 1 ms): the limit row is relaxed like a contact's, the elbow
    goes past 1.8 rad by less than a millimetre-radian on impact and comes back to the limit."""
    sim = Simulator("ur5-joint-limit", mode="rk4", dt=1e-4, delta=1e-3, duration=1.0)
    traj = sim.rollout()
    q = traj.q[:, 2]
    assert 0.0 < q.max() - 1.8 <= 1e-3
    assert abs(q[-1] - 1.8) <= 1e-6
    assert traj.converged[1:].all()


# ---- dry friction

def test_pendulum_below_its_friction_torque_holds_without_creep():
    """pendulum-friction-hold: gravity torque 0.9 tau_c at release; over 10 s the hinge moves <= 1e-12
    rad, and the friction torque is exactly the one that holds it, g(q0) (Pinocchio), strictly inside
    [-tau_c, tau_c]."""
    sim = Simulator("pendulum-friction-hold")
    model = sim.scene.model
    tau_c = model.friction[0]
    q0 = sim.scene.q0.copy()
    g0 = _gravity(model, q0)[0]
    assert abs(abs(g0) - 0.9 * tau_c) <= 1e-12  # the scene's angle
    traj = sim.rollout()
    assert traj.t[-1] == pytest.approx(10.0)
    assert np.abs(traj.q[:, 0] - q0[0]).max() <= 1e-12
    assert np.abs(traj.joint_friction[1:, 0] - g0).max() <= 1e-12 * tau_c
    assert traj.converged[1:].all()
    assert sim.summary(traj)["max_joint_drift"] <= 1e-12


def test_pendulum_above_its_friction_torque_slips_at_the_closed_form_acceleration():
    """pendulum-friction-slip: gravity torque 1.1 tau_c; the first step's acceleration is
    (tau_g - tau_c sign(tau_g)) / I from Pinocchio's rnea and crba at q0, to 1e-6; while it slides the
    friction torque is exactly tau_c against the motion."""
    sim = Simulator("pendulum-friction-slip")
    model = sim.scene.model
    tau_c = model.friction[0]
    q0 = sim.scene.q0.copy()
    data = model.createData()
    tau_g = -pin.rnea(model, data, q0, np.zeros(1), np.zeros(1))[0]
    inertia = pin.crba(model, data, q0)[0, 0]
    assert abs(abs(tau_g) - 1.1 * tau_c) <= 1e-12
    expected = (tau_g - np.sign(tau_g) * tau_c) / inertia
    traj = sim.rollout()
    h = sim.dt
    first = traj.v[1, 0] / h
    assert abs(first - expected) <= 1e-6 * abs(expected)
    sliding = np.abs(traj.v[1:, 0]) > 1e-9
    assert sliding[:100].all()
    assert np.array_equal(traj.joint_friction[1:][sliding, 0], -np.sign(traj.v[1:][sliding, 0]) * tau_c)


def test_implicit_damping_is_the_backward_euler_step():
    """A hinge with viscous damping d only: one step from (q0, v0) gives v+ = (I v0 - h (g + c)) / (I + h d),
    the damping evaluated at v+, from Pinocchio's crba and rnea."""
    cfg = {"name": "damped", "urdf": "friction-pendulum.urdf", "free_flyer": False, "duration": 0.01,
           "contacts": {"feet": False}, "initial": {"q": [0.4]},
           "joints": {"override": [{"joints": ["hinge"], "friction": 0.0, "damping": 0.7}]}}
    sim = Simulator(build_scene(cfg))
    model = sim.scene.model
    sim.set_state(v=np.array([1.5]))
    q0, v0, h = np.array([0.4]), np.array([1.5]), sim.dt
    traj = sim.rollout(h)
    data = model.createData()
    inertia = pin.crba(model, data, q0)[0, 0]
    nle = pin.nonLinearEffects(model, data, q0, v0)[0]
    expected = (inertia * v0[0] - h * nle) / (inertia + h * 0.7)
    assert abs(traj.v[1, 0] - expected) <= 1e-14 * abs(expected)
    undamped = Simulator(build_scene(cfg), joint_damping=False)
    undamped.set_state(v=v0)
    assert abs(undamped.rollout(h).v[1, 0] - (v0[0] - h * nle / inertia)) <= 1e-14


# ---- effort limits

def test_solo12_effort_limits_hold_exactly_and_the_motion_is_the_saturated_law():
    """solo12-effort-limit: a stiff PD asks for a fast crouch with 2.7 N m actuators. Every recorded
    actuator torque is within the limit (exactly, every step) and many steps saturate. Each torque is
    the implicit PD law at the step's end, clamped: clip(tau_ff + kp (q_t - q_k - h v_k+1) + kd (v_t -
    v_k+1), -e, e), recomputed here; and each step satisfies Pinocchio's dynamics with it:
    M(q_k) (v_k+1 - v_k - turn) = h (tau - nle(q_k, v_k)) + J^T P."""
    sim = Simulator("solo12-effort-limit")
    model = sim.scene.model
    effort = 2.7
    traj = sim.rollout()
    tau = traj.tau[1:, 6:]
    assert np.abs(tau).max() <= effort
    saturated = (np.abs(tau) == effort).any(axis=1)
    assert saturated.sum() >= 20
    assert traj.converged[1:].all()
    h = sim.dt
    kp, kd = np.asarray(sim.data.kp)[6:], np.asarray(sim.data.kd)[6:]
    q_t = np.asarray(sim.data.q_target)[7:]
    law = np.clip(kp * (q_t - traj.q[:-1, 7:] - h * traj.v[1:, 6:]) - kd * traj.v[1:, 6:], -effort, effort)
    assert np.abs(tau - law).max() <= 1e-9 * effort
    summary = sim.summary(traj)
    assert summary["max_effort_ratio"] == pytest.approx(1.0) and summary["saturated_steps"] == int(saturated.sum())


def test_saturated_step_satisfies_the_dynamics_with_the_recorded_torque():
    """One saturated step of solo12-effort-limit checked against Pinocchio's crba and nle: the recorded
    actuator torque is the one the step applied (the contact impulses P and J are the step's)."""
    sim = Simulator("solo12-effort-limit")
    sim.rollout(0.002)
    model = sim.scene.model
    q0, v0 = np.asarray(sim.data.q).copy(), np.asarray(sim.data.v).copy()
    traj = sim.rollout(0.001)
    tau = traj.tau[1]
    assert (np.abs(tau[6:]) == 2.7).any()
    J, P = np.asarray(sim.data.J), np.asarray(sim.data.result.lam)
    contact_rows = J.shape[0] - len(sim.data.joint_rows)  # (the joint rows' impulses are the recorded torques)
    assert len(sim.data.joint_rows) > 0
    J, P = J[:contact_rows], P[:contact_rows]
    data = model.createData()
    M = pin.crba(model, data, q0)
    M = np.triu(M) + np.triu(M, 1).T
    nle = pin.nonLinearEffects(model, data, q0, v0)
    h = sim.dt
    turn = np.zeros(model.nv)
    turn[:3] = h * np.cross(v0[3:6], v0[:3])  # the base's frame turn (integrate.cpp)
    # v+ as the solve left it: the recorded base linear velocity is re-expressed in the base's frame after
    # its turn by h omega (integrate.cpp); turned back here
    v1 = traj.v[1].copy()
    v1[:3] = pin.exp3(h * v1[3:6]) @ v1[:3]
    lhs = (M @ (v1 - v0 - turn))[6:]
    rhs = (h * (tau - nle) + J.T @ P)[6:]
    assert np.abs(lhs - rhs).max() <= 1e-9 * np.abs(rhs).max()


def test_feed_forward_alone_is_clamped():
    """An actuator without PD gains (kp = kd = 0): its feed-forward torque is clamped to the limit."""
    cfg = {"name": "ff", "urdf": "friction-pendulum.urdf", "free_flyer": False, "duration": 0.01,
           "contacts": {"feet": False}, "initial": {"q": [0.0]},
           "joints": {"override": [{"joints": ["hinge"], "friction": 0.0, "effort": 3.0}]}}
    sim = Simulator(build_scene(cfg))
    sim.data.tau_ff = np.array([10.0])
    traj = sim.rollout()
    assert np.all(traj.tau[1:, 0] == 3.0)
    inertia = pin.crba(sim.scene.model, sim.scene.model.createData(), np.zeros(1))[0, 0]
    assert abs(traj.v[1, 0] / sim.dt - 3.0 / inertia) <= 1e-12 * 3.0 / inertia


def test_solo12_standing_with_every_joint_row():
    """solo12-stand-joint-rows: limits, dry friction on all 12 joints and effort limits beside the 4 foot
    contacts. Every step converges; the contacts carry the weight (sum of normal forces = m g); once
    settled, no joint moves at all (friction holds them: exact stiction) and no foot slips."""
    sim = Simulator("solo12-stand-joint-rows")
    traj = sim.rollout(2.0)
    assert traj.converged[1:].all()
    model = sim.scene.model
    assert sorted(kind for kind, _ in sim.data.joint_rows).count("friction") == 12
    mass = sum(model.inertias[j].mass for j in range(1, model.njoints))
    assert abs(traj.lam[-1, :, 2].sum() - mass * G) <= 1e-6 * mass * G
    summary = sim.summary(traj)
    assert summary["max_joint_drift"] <= 1e-12 and summary["max_foot_slip"] <= 1e-9
    assert np.all(np.abs(traj.joint_friction[1:, 6:]) <= 0.03)


def test_anymal_standing_with_joint_friction_solves_every_step_in_the_cheap_stages():
    """anymal-stand with dry friction 0.5 N m on its 12 joints: 12 contact and 12 joint rows for 18
    velocities, a statically indeterminate A at every step. The joints slip under the PD until their
    friction holds them (~0.2 s), then every row sticks. Every step is solved by the sticking step or
    Newton within 20 iterations: before, Newton found no descent in over half the steps (its step ran
    along A's null space) and ProxQP took over (~85 us a solve instead of ~3). The contacts carry the
    weight (sum of normal forces = m g), every friction torque is within tau_c, and once settled no
    joint moves."""
    import tomllib

    from stiction.resources import scenes_dir

    cfg = tomllib.loads((scenes_dir() / "anymal-stand.toml").read_text())
    cfg["joints"] = {"override": [{"joints": ["*_HAA", "*_HFE", "*_KFE"], "friction": 0.5}]}
    sim = Simulator(build_scene(cfg))
    stages, iterations = set(), []

    def record_last_solve(s):
        if s.data.t > 0.0:
            stages.update(stage.name for stage in s.data.result.stages)
            iterations.append(s.data.result.iterations)

    traj = sim.rollout(1.0, callback=record_last_solve)
    record_last_solve(sim)
    assert len(iterations) == 1000 and traj.converged[1:].all()
    assert stages <= {"sticking step", "newton"}, stages
    assert max(iterations) <= 20
    assert sorted(kind for kind, _ in sim.data.joint_rows).count("friction") == 12
    model = sim.scene.model
    mass = sum(model.inertias[j].mass for j in range(1, model.njoints))
    assert abs(traj.lam[-1, :, 2].sum() - mass * G) <= 1e-6 * mass * G
    assert np.all(np.abs(traj.joint_friction[1:, 6:]) <= 0.5 * (1.0 + 1e-6))  # (a sticking row: within the tolerance)
    assert sim.summary(traj)["max_joint_drift"] <= 1e-12


# ---- scene keys

def test_joint_override_keys_are_checked():
    base = {"name": "x", "robot": "ur5", "contacts": {"feet": False}}
    with pytest.raises(SceneError, match="did you mean 'friction'"):
        build_scene({**base, "joints": {"fricton": True}})
    with pytest.raises(SceneError, match="matches no joint"):
        build_scene({**base, "joints": {"override": [{"joints": ["elbow"], "upper": 1.0}]}})
    with pytest.raises(SceneError, match="at least one of"):
        build_scene({**base, "joints": {"override": [{"joints": ["elbow_joint"]}]}})
    with pytest.raises(SceneError, match="above its upper"):
        build_scene({**base, "joints": {"override": [{"joints": ["elbow_joint"], "lower": 4.0}]}})
    sc = build_scene({**base, "joints": {"override": [{"joints": ["*_joint"], "friction": 0.25, "effort": 9.0}]}})
    assert np.all(sc.model.friction == 0.25) and np.all(sc.model.effortLimit == 9.0)
    assert np.all(load_scene("ur5-push-wall").model.friction == 0.0)  # the robot's own model is untouched


def test_bad_model_values_are_errors_naming_the_joint():
    sc = load_scene("pendulum-friction-hold")
    sc.model.friction[0] = -1.0
    with pytest.raises(ValueError, match="joint 'hinge': friction"):
        Simulator(sc)


def test_formulations_without_box_rows_refuse_at_construction():
    """penalty and Pinocchio's solvers have no law for box rows: a model with dry joint friction is
    refused when the Simulator is built (one line), unless the friction is switched off; CCP, Nakaoka
    and the pyramid take the box as it is and hold the pendulum as the exact law does."""
    for name in ("penalty", "pinocchio-admm"):
        with pytest.raises(ValueError, match=f"formulation '{name}' does not handle box rows.*joint_friction"):
            Simulator("pendulum-friction-hold", formulation=name)
    Simulator("pendulum-friction-hold", formulation="penalty", joint_friction=False).rollout(0.01)
    for name in ("ccp", "nakaoka", "pyramid"):
        traj = Simulator("pendulum-friction-hold", formulation=name, duration=0.5).rollout()
        assert np.abs(traj.q[:, 0] - traj.q[0, 0]).max() <= 1e-12, name


def test_cli_runs_the_joint_scenes():
    for name in ("pendulum-friction-hold", "ur5-joint-limit"):
        out = subprocess.run([sys.executable, "-m", "stiction.cli", "simulate", name, "--duration", "2.5", "--json"],
                             capture_output=True, text=True, check=True)
        s = json.loads(out.stdout)
        assert s["scene"] == name and s["all_converged"]
        if name == "ur5-joint-limit":
            assert s["max_limit_overshoot"] <= 1e-6
        else:
            assert s["max_joint_drift"] <= 1e-12


def test_joint_rows_meet_the_exact_law():
    """The step's answer with joint rows (friction boxes, a limit, contacts) meets the exact-law
    measures of its own problem to the solver's tolerance."""
    sim = Simulator("pendulum-friction-hold")
    sim.rollout(0.01)
    r = sim.data.result
    assert r.converged and r.residual <= 1e-10
    assert any(kind == "friction" for kind, _ in sim.data.joint_rows)
    assert stiction.Constraint.box(-1.0, 1.0).kind == stiction.ConstraintKind.box


def test_inspected_problem_carries_the_actuators_compliance():
    """build_contact_problem with the implicit PD's step h (the problem a step solves, for inspection):
    A = J M^-1 J^T (M with the PD on the diagonal of the actuators without a row) plus 1 / (h K) on each
    effort row's diagonal, K = kd + h kp; nothing else."""
    from stiction import _core

    sim = Simulator("solo12-effort-limit")
    sim.rollout(0.004)  # saturating: effort rows in the problem
    q, v, h = np.asarray(sim.data.q).copy(), np.asarray(sim.data.v).copy(), sim.dt
    _core.build_contact_problem(sim.model, sim.data, q, v, h, 0.5, h)
    rows = sim.data.joint_rows
    assert any(kind == "effort" for kind, _ in rows)
    J, M, A = np.asarray(sim.data.J), np.asarray(sim.data.M), np.asarray(sim.data.A)
    extra = A - J @ np.linalg.solve(M, J.T)
    expected = np.zeros_like(A)
    first = A.shape[0] - len(rows)
    kp, kd = np.asarray(sim.data.kp), np.asarray(sim.data.kd)
    for k, (kind, dof) in enumerate(rows):
        if kind == "effort":
            expected[first + k, first + k] = 1.0 / (h * (kd[dof] + h * kp[dof]))
    assert np.abs(extra - expected).max() <= 1e-9 * np.abs(A).max()
