"""The MuJoCo twin carries the joints' own rows the stiction Simulator applies (issue 24,
docs/joint-rows.md): position limits (``range`` + ``limited``), dry friction (``frictionloss``), viscous
damping (``damping``) and actuator effort limits (``forcerange`` + ``forcelimited``), from the same
values and with the same switches (the scene's ``[joints]`` table, the keyword overrides).

The compiled MjModel is read back and compared with the values written in the scene dict here and
with the URDF's own ``<limit>`` / ``<dynamics>`` elements (parsed with ElementTree, not Pinocchio);
then MuJoCo's own dynamics shows each one acting: a limit stops the UR5's falling elbow at the
scene's 1.8 rad, dry friction holds a pendulum whose gravity torque is below tau_c, an effort limit
caps Solo-12's actuators at 2.7 N m."""
from __future__ import annotations

import dataclasses
import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from stiction.robots import ROBOTS, robots_dir
from stiction.scene import build_scene, load_scene

mujoco = pytest.importorskip("mujoco")
import mujoco.rollout  # noqa: E402

from stiction.bench import mujoco_twins  # noqa: E402

LEGS = [f"{leg}_{j}" for leg in ("FL", "FR", "HL", "HR") for j in ("HAA", "HFE", "KFE")]
OFF = {"joint_limits": False, "joint_friction": False, "joint_damping": False, "effort_limits": False}

# Solo-12 with per-joint values over its URDF's (limits +-10 rad, effort 1000 N m, no friction or damping)
OVERRIDES = [
    {"joints": ["FL_*"], "friction": 0.03, "damping": 0.01, "effort": 2.7},
    {"joints": ["FL_KFE"], "lower": -2.5, "upper": -0.2},
    {"joints": ["HR_HAA"], "lower": -0.4},
    {"joints": ["HL_HFE", "HL_KFE"], "friction": 0.5, "effort": 0.0},  # effort 0: no limit
]
FL = {"FL_HAA", "FL_HFE", "FL_KFE"}


def _solo_cfg(**joints) -> dict:
    return {"name": "solo12-overrides", "robot": "solo12", "dt": 0.001, "control": {"kp": 20.0, "kd": 0.2},
            "joints": {"override": OVERRIDES, **joints}}


def _urdf_joints(robot: str) -> dict[str, dict[str, float]]:
    """Every joint's <limit lower upper effort> and <dynamics friction damping> in the robot's URDF
    (absent: 0, as Pinocchio reads it)."""
    root = ET.parse(robots_dir() / ROBOTS[robot].urdf).getroot()
    out = {}
    for joint in root.findall("joint"):  # (not the <transmission>s' <joint> elements)
        values = {}
        for tag, keys in (("limit", ("lower", "upper", "effort")), ("dynamics", ("friction", "damping"))):
            element = joint.find(tag)
            for key in keys:
                values[key] = float(element.get(key, 0.0)) if element is not None else 0.0
        out[joint.get("name")] = values
    return out


def _actuator_of(m, joint: str):
    ids = [a for a in range(m.nu) if m.actuator_trnid[a, 0] == m.joint(joint).id]
    assert len(ids) == 1
    return ids[0]


def test_override_values_reach_the_compiled_model():
    """Every leg joint's range, frictionloss, damping and actuator forcerange are the scene's values
    where [[joints.override]] gives them and the URDF's elsewhere, and equal the Pinocchio model's."""
    urdf = _urdf_joints("solo12")
    scene = build_scene(_solo_cfg())
    twin = mujoco_twins.mujoco_twin(scene)
    m, model = twin.model, scene.model
    expected_range = {"FL_KFE": (-2.5, -0.2), "HR_HAA": (-0.4, urdf["HR_HAA"]["upper"])}
    for name in LEGS:
        u = urdf[name]
        assert (u["lower"], u["upper"], u["effort"]) == (-10.0, 10.0, 1000.0)  # what the defaults below rely on
        j = m.joint(name)
        assert j.limited[0] == 1
        np.testing.assert_array_equal(j.range, expected_range.get(name, (u["lower"], u["upper"])))
        friction = 0.03 if name in FL else 0.5 if name in ("HL_HFE", "HL_KFE") else u["friction"]
        damping = 0.01 if name in FL else u["damping"]
        assert m.dof_frictionloss[j.dofadr[0]] == friction
        assert m.dof_damping[j.dofadr[0]] == damping
        a = _actuator_of(m, name)
        if name in ("HL_HFE", "HL_KFE"):
            assert m.actuator_forcelimited[a] == 0
        else:
            assert m.actuator_forcelimited[a] == 1
            effort = 2.7 if name in FL else u["effort"]
            np.testing.assert_array_equal(m.actuator_forcerange[a], (-effort, effort))
        # the same numbers as the Pinocchio model stiction simulates
        pj = model.joints[model.getJointId(name)]
        assert tuple(j.range) == (model.lowerPositionLimit[pj.idx_q], model.upperPositionLimit[pj.idx_q])
        assert (m.dof_frictionloss[j.dofadr[0]], m.dof_damping[j.dofadr[0]]) == (model.friction[pj.idx_v],
                                                                                 model.damping[pj.idx_v])
    assert not m.jnt_limited[m.joint("root_joint").id]
    assert not m.dof_frictionloss[:6].any() and not m.dof_damping[:6].any()
    assert m.nu == 12


def test_urdf_friction_damping_and_limits_of_talos():
    """TALOS's URDF gives its upper body (torso, arms, grippers, head: 20 joints) dry friction and damping:
    the twin's are the URDF's, joint by joint, as are every joint's range and effort limit."""
    urdf = _urdf_joints("talos")
    scene = load_scene("talos-stand")
    m = mujoco_twins.mujoco_twin(scene).model
    checked = 0
    for j in range(1, m.njnt):
        name = m.joint(j).name
        if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            continue
        u, dof = urdf[name], m.jnt_dofadr[j]
        assert (m.dof_frictionloss[dof], m.dof_damping[dof]) == (u["friction"], u["damping"]), name
        assert m.jnt_limited[j] == 1 and tuple(m.jnt_range[j]) == (u["lower"], u["upper"]), name
        a = _actuator_of(m, name)
        assert m.actuator_forcelimited[a] == 1
        assert tuple(m.actuator_forcerange[a]) == (-u["effort"], u["effort"]), name
        checked += 1
    assert checked == 32
    assert (m.dof_frictionloss == 1.0).sum() == 20 and set(m.dof_damping) == {0.0, 0.5, 1.0}


@pytest.mark.parametrize("how", ["keywords", "scene table"])
def test_switches_off_leave_the_joints_bare(how):
    """With every switch off (keyword overrides as the Simulator's, or the scene's [joints] table) the
    twin has no limit, frictionloss, damping or actuator force limit — the twin of before issue 24."""
    if how == "keywords":
        twin = mujoco_twins.mujoco_twin(build_scene(_solo_cfg()), **OFF)
    else:
        twin = mujoco_twins.mujoco_twin(build_scene(_solo_cfg(limits=False, friction=False, damping=False,
                                                              effort_limits=False)))
    m = twin.model
    assert not m.jnt_limited.any() and not m.dof_frictionloss.any() and not m.dof_damping.any()
    assert not m.actuator_forcelimited.any() and m.nu == 12


def test_each_switch_alone_and_keywords_over_the_table():
    """One switch off removes only its own values; a keyword True turns on what the table turned off."""
    scene = build_scene(_solo_cfg())
    full = mujoco_twins.mujoco_twin(scene).model
    for switch, field in (("joint_limits", "jnt_limited"), ("joint_friction", "dof_frictionloss"),
                          ("joint_damping", "dof_damping"), ("effort_limits", "actuator_forcelimited")):
        m = mujoco_twins.mujoco_twin(scene, **{switch: False}).model
        assert getattr(full, field).any() and not getattr(m, field).any(), switch
        for other in ("jnt_limited", "dof_frictionloss", "dof_damping", "actuator_forcelimited"):
            if other != field:
                np.testing.assert_array_equal(getattr(m, other), getattr(full, other))
    table_off = build_scene(_solo_cfg(limits=False, friction=False))
    m = mujoco_twins.mujoco_twin(table_off, joint_friction=True).model
    assert not m.jnt_limited.any()
    np.testing.assert_array_equal(m.dof_frictionloss, full.dof_frictionloss)
    with pytest.raises(ValueError, match="joint_limits must be True or False"):
        mujoco_twins.mujoco_twin(scene, joint_limits="yes")


def test_one_sided_and_absent_limits():
    """A joint with one finite limit keeps the other side infinite (still limited); none finite: not limited."""
    scene = load_scene("solo12-stand")
    model = scene.model.copy()
    iq = {name: model.joints[model.getJointId(name)].idx_q for name in ("HR_KFE", "HL_KFE")}
    model.lowerPositionLimit[iq["HR_KFE"]], model.upperPositionLimit[iq["HR_KFE"]] = -math.inf, 0.5
    model.lowerPositionLimit[iq["HL_KFE"]], model.upperPositionLimit[iq["HL_KFE"]] = -math.inf, math.inf
    m = mujoco_twins.mujoco_twin(dataclasses.replace(scene, model=model)).model
    assert m.joint("HR_KFE").limited[0] == 1 and tuple(m.joint("HR_KFE").range) == (-math.inf, 0.5)
    assert m.joint("HL_KFE").limited[0] == 0


def test_errors_name_the_joint():
    scene = load_scene("solo12-stand")
    model = scene.model.copy()
    iq = model.joints[model.getJointId("FR_HFE")].idx_q
    model.lowerPositionLimit[iq] = model.upperPositionLimit[iq] = 0.3
    with pytest.raises(ValueError, match="'FR_HFE'.*lower < upper"):
        mujoco_twins.mujoco_twin(dataclasses.replace(scene, model=model))
    mujoco_twins.mujoco_twin(dataclasses.replace(scene, model=model), joint_limits=False)  # off: nothing to map
    model = scene.model.copy()
    model.friction[0] = 0.1  # the free flyer's first coordinate only
    with pytest.raises(ValueError, match="'root_joint'.*friction.*differs"):
        mujoco_twins.mujoco_twin(dataclasses.replace(scene, model=model))


def _mujoco_run(scene, seconds: float, **switches):
    """MuJoCo's rollout of the scene's twin: the joint positions (steps, nq) in MuJoCo's qpos order,
    and the twin."""
    twin = mujoco_twins.mujoco_twin(scene, **switches)
    m = twin.model
    control = twin.ctrl.reshape(1, 1, -1) if m.nu else None
    states, _ = mujoco.rollout.rollout(m, mujoco.MjData(m), twin.initial_state(scene.q0, scene.v0), control,
                                       nstep=int(round(seconds / scene.dt)))
    return states[0, :, 1:1 + m.nq], twin


def test_mujoco_limit_stops_the_falling_elbow():
    """ur5-joint-limit: the elbow (PD off) falls from 1.6 rad onto the scene's upper limit 1.8 rad. With the
    limit MuJoCo's soft limit lets it in by under 0.05 rad and it settles within 5 mrad of 1.8; without
    it the elbow swings far past (> 2.8 rad)."""
    scene = load_scene("ur5-joint-limit")
    qpos, twin = _mujoco_run(scene, 1.0)
    elbow = qpos[:, twin.model.joint("elbow_joint").qposadr[0]]
    assert 1.8 < elbow.max() < 1.85 and abs(elbow[-1] - 1.8) < 5e-3
    qpos, twin = _mujoco_run(scene, 1.0, joint_limits=False)
    assert qpos[:, twin.model.joint("elbow_joint").qposadr[0]].max() > 2.8


def test_mujoco_dry_friction_holds_below_tau_c():
    """The friction pendulum (1 kg, centre of mass d = 0.25 m below the hinge, URDF tau_c = 0.5 N m),
    released at rest where m g d sin(theta0) = 0.9 tau_c: MuJoCo's frictionloss holds it (its soft
    friction creeps by under 0.01 rad in 1 s); without friction it swings through the bottom to about
    -theta0 (energy). Released at 1.1 tau_c it slides and comes to rest inside the sticking range
    |theta| <= asin(tau_c / (m g d))."""
    tau_c, mgd = 0.5, 1.0 * 9.81 * 0.25
    theta_stick = math.asin(tau_c / mgd)
    hold = load_scene("pendulum-friction-hold")
    theta0 = float(hold.q0[0])
    assert mgd * math.sin(theta0) == pytest.approx(0.9 * tau_c, rel=1e-12)
    qpos, _ = _mujoco_run(hold, 1.0)
    assert np.abs(qpos[:, 0] - theta0).max() < 0.01
    qpos, _ = _mujoco_run(hold, 1.0, joint_friction=False)
    assert qpos[:, 0].min() < -0.95 * theta0
    slip = load_scene("pendulum-friction-slip")
    qpos, _ = _mujoco_run(slip, 2.0)
    assert qpos[0, 0] > theta_stick and abs(qpos[-1, 0]) <= theta_stick
    assert abs(qpos[-1, 0] - qpos[-101, 0]) < 1e-3  # at rest over the last 0.1 s (but for the creep)


def test_mujoco_effort_limit_caps_the_actuators():
    """solo12-effort-limit (2.7 N m actuators asked for a fast crouch): MuJoCo's actuator torques reach
    2.7 N m and never exceed it; without effort limits the same PD asks for more."""
    scene = load_scene("solo12-effort-limit")
    for effort_limits in (True, False):
        twin = mujoco_twins.mujoco_twin(scene, effort_limits=effort_limits)
        m, d = twin.model, mujoco.MjData(twin.model)
        mujoco.mj_setState(m, d, twin.initial_state(scene.q0, scene.v0), mujoco.mjtState.mjSTATE_FULLPHYSICS)
        peak = 0.0
        for _ in range(300):
            mujoco.mj_step(m, d)
            peak = max(peak, float(np.abs(d.actuator_force).max()))
        if effort_limits:
            assert peak == pytest.approx(2.7, rel=1e-12)
        else:
            assert peak > 4.0
