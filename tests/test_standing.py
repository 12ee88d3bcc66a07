"""Robots that a scene says stand do stand: the base comes to rest, the contacts carry m g, and
the summary's `settled` says so (issue 23). Also the scene keys that make a robot stand:
[[control.gains]] (per-joint gains), gravity_feedforward on a free-flyer robot (its static
equilibrium on its contacts) and [initial] level_frame (a sole laid flat).

Every measure is recomputed here from the trajectory (positions, velocities, forces) and the
model (Pinocchio), independently of Simulator.summary."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from stiction.scene import build_scene, list_scenes, load_scene, scene_description
from stiction.scene_schema import SceneError
from stiction.simulator import Simulator

G = 9.81
WINDOW = 0.5  # s: the final part of a run over which the base's sway is measured
SPEED, SWAY = 1e-3, 1e-3  # m/s, m: at rest

# Every bundled scene whose description says a robot stands or something rests, must not move.
STANDING = ("talos-stand", "solo12-stand", "go2-stand", "anymal-stand", "solo12-on-board", "solo12-slope-stick",
            "cube-incline-stick", "two-cube-stack", "box-tower-20", "cube-grid-64", "cube-grid-256", "cube-grid-1024",
            "pinch", "ball-on-table", "solo12-stand-joint-rows", "solo12-effort-limit", "dmc-humanoid-stand")
CLAIMS = ("stand", "must not", "stay put", "nothing may move", "nothing moves", "rest", "holds")
# Scenes whose claim to hold still is a joint's, checked by tests/test_joint_rows.py
JOINT_HOLDS = ("pendulum-friction-hold", "pendulum-friction-slip", "ur5-joint-limit")
# MJCF robots on a root of slides and hinges (no free flyer), at rest: checked by tests/test_mjcf.py
MJCF_RESTS = ("dmc-walker-stand", "dmc-cheetah-stand", "dmc-hopper-fall")

# talos-stand as it was before issue 23 (uniform PD, the SRDF posture with its ankle roll, no
# feed-forward): it sways by centimetres.
OLD_TALOS = {"robot": "talos", "duration": 2.0, "settle_time": 0.5, "ground": {"mu": 0.8},
             "control": {"kp": 3000.0, "kd": 50.0}}


def _base_motion(traj, window: float = WINDOW):
    """(speed at the end, largest distance from the final position over the final window) of
    the free-flyer base: world-frame velocity from the body-frame one, rotated."""
    R = pin.Quaternion(traj.q[-1, 3:7]).matrix()
    speed = float(np.linalg.norm(R @ traj.v[-1, :3]))
    last = traj.t >= traj.t[-1] - window - 1e-12
    sway = float(np.linalg.norm(traj.q[last, :3] - traj.q[-1, :3], axis=1).max())
    return speed, sway


def _robot_mass(scene) -> float:
    """Mass of the robot (the subtree of joint 1, objects excluded)."""
    model = scene.model
    robot = {1}
    for j in range(2, model.njoints):
        if model.parents[j] in robot:
            robot.add(j)
    return float(sum(model.inertias[j].mass for j in robot))


def test_every_scene_that_says_stand_is_checked():
    for name in list_scenes():
        text = scene_description(name).lower()
        if any(claim in text for claim in CLAIMS):
            assert name in STANDING or name in JOINT_HOLDS or name in MJCF_RESTS, f"{name} says it stands or rests: add it to STANDING"


@pytest.mark.parametrize("name", STANDING)
def test_standing_scenes_come_to_rest(name):
    """The base moves < 1e-3 m/s at the end and stays within 1 mm over the final 0.5 s, every
    step converged, and the summary's settled flag and rest measures agree with this file's."""
    sim = Simulator(name)
    traj = sim.rollout()
    assert traj.converged[1:].all()
    model = sim.scene.model
    roots = [j for j in range(1, model.njoints) if model.parents[j] == 0 and
             model.joints[j].shortname() == "JointModelFreeFlyer"]
    assert roots  # every one of these scenes has a free base or free bodies
    speeds, sways = [], []
    last = traj.t >= traj.t[-1] - WINDOW - 1e-12
    for j in roots:
        iq, iv = model.joints[j].idx_q, model.joints[j].idx_v
        R = pin.Quaternion(traj.q[-1, iq + 3:iq + 7]).matrix()
        speeds.append(float(np.linalg.norm(R @ traj.v[-1, iv:iv + 3])))
        sways.append(float(np.linalg.norm(traj.q[last, iq:iq + 3] - traj.q[-1, iq:iq + 3], axis=1).max()))
    speed, sway = max(speeds), max(sways)
    assert speed < SPEED and sway < SWAY, f"{name}: base speed {speed:.3g} m/s, sway {sway:.3g} m"
    s = sim.summary(traj)
    assert s["settled"] is True
    assert s["final_base_speed"] == pytest.approx(speed, rel=1e-9, abs=1e-15)
    assert s["final_base_sway"] == pytest.approx(sway, rel=1e-9, abs=1e-15)
    assert not [w for w in s["warnings"] if "settled" in w]


def test_talos_stands_still_on_its_soles():
    """talos-stand over 2 s: the base sways < 1 mm over the last 0.5 s and moves < 1e-3 m/s at
    the end, the soles carry the robot's weight (sum of normal forces = m g to 1e-6 relative at
    the end), every step converged; the joints hold their target (no sag) and the soles stick."""
    sim = Simulator("talos-stand")
    traj = sim.rollout(2.0)
    speed, sway = _base_motion(traj)
    assert traj.converged[1:].all()
    assert speed < SPEED and sway < SWAY
    m = pin.computeTotalMass(sim.scene.model)
    assert 85.0 < m < 95.0
    fn = traj.lam[-1, :, 2].sum()
    assert abs(fn - m * G) / (m * G) < 1e-6
    # the feed-forward holds the posture itself: no PD sag
    assert np.abs(traj.q[-1, 7:] - sim.scene.q_target[7:]).max() < 1e-6
    assert (traj.states[1:] == 1).all()  # all 8 sole corners stick at every step


def test_old_talos_scene_sways_and_the_summary_says_so():
    """The scene as it was (uniform kp 3000, kd 50 from the SRDF posture, no feed-forward) is
    not at rest after 2 s: the summary says settled = false, warns, and its measures are this
    file's."""
    sim = Simulator(build_scene(OLD_TALOS, "old-talos"))
    traj = sim.rollout()
    speed, sway = _base_motion(traj)
    assert speed > SPEED or sway > SWAY
    s = sim.summary(traj)
    assert s["settled"] is False
    assert s["final_base_speed"] == pytest.approx(speed, rel=1e-12)
    assert s["final_base_sway"] == pytest.approx(sway, rel=1e-12)
    assert any("not settled" in w for w in s["warnings"])


def test_cli_says_when_a_robot_has_not_settled(tmp_path, capsys):
    """`stiction simulate` on the old talos-stand: the JSON summary has settled = false with the
    rest measures, stderr warns, and the run still succeeds (exit 0: nothing failed to solve)."""
    import json

    from stiction.cli import main

    path = tmp_path / "old-talos.toml"
    path.write_text('robot = "talos"\nduration = 1.0\n[ground]\nmu = 0.8\n[control]\nkp = 3000.0\nkd = 50.0\n')
    rc = main(["simulate", str(path), "--json"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    s = json.loads(out)
    assert s["settled"] is False and s["final_base_speed"] > SPEED
    assert "warning: the robot has not settled" in err
    rc = main(["simulate", "talos-stand", "--duration", "1.0"])
    out, err = capsys.readouterr()
    assert rc == 0 and "not settled" not in err
    assert [line.split()[1] for line in out.splitlines() if line.startswith("settled ")] == ["True"]


def test_a_sliding_robot_is_not_settled_and_not_warned_about():
    sim = Simulator("solo12-slope-slip")
    traj = sim.rollout()
    speed, sway = _base_motion(traj)
    s = sim.summary(traj)
    # it slides at a = g (sin 20 - mu cos 20) from rest: v(1 s) ~ 1.51 m/s
    assert speed == pytest.approx(1.5116, rel=1e-2)
    assert s["settled"] is False and s["final_base_speed"] == pytest.approx(speed, rel=1e-12)
    assert s["final_base_sway"] == pytest.approx(sway, rel=1e-12)
    assert not [w for w in s["warnings"] if "settled" in w]


def test_rest_measures_of_every_free_body_and_of_a_fixed_base():
    """solo12-on-board: two floating bases (robot and board); the measures are the larger of
    the two. A fixed-base arm has none: null."""
    sim = Simulator("solo12-on-board")
    traj = sim.rollout(0.6)
    s = sim.summary(traj)
    board = sim.scene.model.joints[sim.scene.model.getJointId("root_joint_board")]
    last = traj.t >= traj.t[-1] - WINDOW - 1e-12
    speeds, sways = [], []
    for iq, iv in ((0, 0), (board.idx_q, board.idx_v)):
        speeds.append(np.linalg.norm(traj.v[-1, iv:iv + 3]))
        sways.append(np.linalg.norm(traj.q[last, iq:iq + 3] - traj.q[-1, iq:iq + 3], axis=1).max())
    assert s["final_base_speed"] == pytest.approx(max(speeds), rel=1e-12, abs=1e-18)
    assert s["final_base_sway"] == pytest.approx(max(sways), rel=1e-12, abs=1e-18)
    arm = Simulator("ur5-push-wall")
    s = arm.summary(arm.rollout(1.1))
    assert s["final_base_speed"] is None and s["final_base_sway"] is None and s["settled"] is None


# ---- gravity_feedforward on a free-flyer robot: the static equilibrium on its contacts

def test_standing_feedforward_is_the_static_equilibrium():
    """tau_ff of talos-stand: g(q) - tau_ff (the joint rows) equals J^T lambda for contact forces
    lambda that also balance the base (g_b = J_b^T lambda): rnea at rest. lambda is solved here
    from the 6 + 32 rows together, not taken from the loader."""
    sc = load_scene("talos-stand")
    model, q = sc.model, sc.q_target
    data = model.createData()
    g = pin.rnea(model, data, q, np.zeros(model.nv), np.zeros(model.nv))
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    cols = []
    for c in sc.contacts:
        point = data.oMf[c.frame].rotation @ np.asarray(c.offset)
        J = pin.getFrameJacobian(model, data, c.frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        cols.append(J[:3] - pin.skew(point) @ J[3:])
    J = np.vstack(cols)
    lam, *_ = np.linalg.lstsq(J.T, g - sc.tau_ff, rcond=None)
    assert np.linalg.norm(J.T @ lam - (g - sc.tau_ff)) < 1e-9 * np.linalg.norm(g)
    forces = lam.reshape(-1, 3)
    assert forces[:, 2].sum() == pytest.approx(pin.computeTotalMass(model) * G, rel=1e-12)
    assert (forces[:, 2] > 0).all()
    assert np.all(sc.tau_ff[:6] == 0)
    # the naive feed-forward g(q) (the robot hung from its base) is far from it
    assert np.abs(g[6:] - sc.tau_ff[6:]).max() > 10.0


def test_feedforward_holds_a_quadruped_posture_exactly():
    """go2 with gravity_feedforward and its uniform PD: the joints stay at their target (the PD
    carries nothing), against a deflection of about g/kp without it."""
    base = {"robot": "go2", "duration": 0.5, "ground": {"mu": 0.8}, "control": {"kp": 100.0, "kd": 3.0}}
    with_ff = dict(base, control=dict(base["control"], gravity_feedforward=True))
    for cfg, expect_still in ((with_ff, True), (base, False)):
        sim = Simulator(build_scene(cfg))
        traj = sim.rollout()
        sag = np.abs(traj.q[-1, 7:] - sim.scene.q_target[7:]).max()
        assert (sag < 1e-7) if expect_still else (sag > 1e-3), sag


def test_feedforward_errors_are_loud():
    with pytest.raises(SceneError, match="no contact to stand on"):
        build_scene({"robot": "solo12", "contacts": {"feet": False}, "control": {"kp": 1.0, "gravity_feedforward": True}})
    # TALOS on its left sole only: its weight is not over that foot
    left = {"robot": "talos", "contacts": {"soles": False, "frames": ["left_sole_link"]},
            "control": {"kp": 1.0, "gravity_feedforward": True}}
    with pytest.raises(SceneError, match="cannot balance|pull"):
        build_scene(left)


# ---- [[control.gains]]: per-joint gains

def test_talos_leg_damping_settles_a_push():
    """talos-stand pushed at 5 cm/s: with its legs and torso at kd 300 the base is settled
    (< 1e-3 m/s, < 1 mm over the final 0.5 s) after 3 s; with kd 50 on every joint it still sways."""
    import dataclasses

    sc = load_scene("talos-stand")
    assert sc.kd[sc.model.joints[sc.model.getJointId("leg_left_4_joint")].idx_v] == 300.0
    uniform = dataclasses.replace(sc, kd=np.where(sc.kd > 0, 50.0, 0.0))
    for scene, settles in ((sc, True), (uniform, False)):
        sim = Simulator(scene)
        sim.set_state(v=np.r_[0.05, np.zeros(scene.model.nv - 1)])
        traj = sim.rollout(3.0)
        speed, sway = _base_motion(traj)
        assert (speed < SPEED and sway < SWAY) == settles, (speed, sway)


def test_per_joint_gains_by_name_pattern():
    cfg = {"robot": "talos", "control": {"kp": 100.0, "kd": 1.0, "gains": [
        {"joints": ["leg_*"], "kp": 3000.0, "kd": 200.0},
        {"joints": ["leg_left_4_joint", "arm_*_1_joint"], "kd": 7.0}]}}
    sc = build_scene(cfg)
    model = sc.model
    for j in range(2, model.njoints):
        name, iv = model.names[j], model.joints[j].idx_v
        kp = 3000.0 if name.startswith("leg_") else 100.0
        kd = 7.0 if name in ("leg_left_4_joint", "arm_left_1_joint", "arm_right_1_joint") else \
            200.0 if name.startswith("leg_") else 1.0
        assert (sc.kp[iv], sc.kd[iv]) == (kp, kd), name
    assert np.all(sc.kp[:6] == 0) and np.all(sc.kd[:6] == 0)


def test_per_joint_stiffness_sets_each_joint_deflection():
    """A fixed-base UR5 held by a PD with a different kp per joint, no feed-forward: at rest each
    joint's deflection is g_i(q) / kp_i (checked with Pinocchio's g at the final q)."""
    cfg = {"robot": "ur5", "duration": 3.0, "control": {"kp": 2000.0, "kd": 60.0, "gains": [
        {"joints": ["shoulder_lift_joint"], "kp": 20000.0, "kd": 500.0},
        {"joints": ["elbow_joint"], "kp": 500.0, "kd": 30.0}]}}
    sim = Simulator(build_scene(cfg))
    traj = sim.rollout()
    model, q = sim.scene.model, traj.q[-1]
    g = pin.computeGeneralizedGravity(model, model.createData(), q)
    kp = sim.scene.kp
    assert len(set(kp)) == 3
    assert np.abs(traj.v[-1]).max() < 1e-6
    np.testing.assert_allclose(kp * (sim.scene.q_target - q), g, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("gains, message", [
    ([{"joints": ["leg_lft_*"], "kp": 1.0}], "matches no actuated joint"),
    ([{"joints": ["root_joint"], "kp": 1.0}], "matches no actuated joint"),
    ([{"joints": ["leg_*"]}], "give kp, kd or both"),
    ([{"joints": ["leg_*"], "kq": 1.0}], "did you mean 'kp'"),
    ([{"joints": [], "kp": 1.0}], "must not be empty"),
    ([{"joints": ["leg_*"], "kp": -1.0}], ">= 0"),
])
def test_per_joint_gains_errors(gains, message):
    with pytest.raises(SceneError, match=message):
        build_scene({"robot": "talos", "control": {"kp": 1.0, "gains": gains}})


# ---- [initial] joints

def test_named_joints_lay_talos_soles_flat():
    """TALOS's half-sitting posture rolls both ankles by 1.7 mrad: with the base level its sole
    corners differ by 0.22 mm in height (4 of 8 touch); with the ankle roll set to 0 by name all
    8 touch, and the PD holds the named value."""
    def corner_heights(sc):
        data = sc.model.createData()
        pin.framesForwardKinematics(sc.model, data, sc.q0)
        return np.array([data.oMf[c.frame].act(np.asarray(c.offset))[2] for c in sc.contacts])

    flat = build_scene({"robot": "talos", "initial": {"joints": {"leg_left_6_joint": 0.0, "leg_right_6_joint": 0.0}}})
    srdf = build_scene({"robot": "talos"})
    assert np.ptp(corner_heights(srdf)) > 2e-4
    assert np.abs(corner_heights(flat)).max() < 1e-12
    for sc, roll in ((srdf, -1.708e-3), (flat, 0.0)):
        iq = sc.model.joints[sc.model.getJointId("leg_left_6_joint")].idx_q
        assert sc.q0[iq] == pytest.approx(roll, abs=1e-9) and sc.q_target[iq] == sc.q0[iq]
    changed = np.flatnonzero(flat.q0[7:] != srdf.q0[7:]) + 7
    assert sorted(changed) == sorted(flat.model.joints[flat.model.getJointId(n)].idx_q
                                     for n in ("leg_left_6_joint", "leg_right_6_joint"))


@pytest.mark.parametrize("cfg, message", [
    ({"robot": "talos", "initial": {"joints": {"leg_lft_6_joint": 0.0}}}, "did you mean 'leg_left_6_joint'"),
    ({"robot": "talos", "initial": {"joints": {"root_joint": 0.0}}}, "1-dof"),
    ({"robot": "talos", "initial": {"joints": {"leg_left_6_joint": "zero"}}}, "table of name = number"),
    ({"robot": "talos", "initial": {"joints": [0.0]}}, "table of name = number"),
    ({"robot": "solo12", "initial": {"joints": {"FL_HFE": 0.5}, "q": [0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0] + [0.0] * 12}},
     "give one of them"),
])
def test_named_joints_errors(cfg, message):
    with pytest.raises(SceneError, match=message):
        build_scene(cfg)
