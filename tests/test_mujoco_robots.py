"""The MuJoCo twin of every bundled robot scene (stiction.bench.mujoco_twins.mujoco_twin) is the same robot:
same moving mass, joint frames and mass matrix at any configuration, the same contact gaps in the
standing posture, the same kinetic energy for any velocity; MuJoCo keeps each robot standing."""
from __future__ import annotations

import dataclasses
import importlib.util
import sys

import numpy as np
import pinocchio as pin
import pytest

from conftest import ROOT
from stiction.scene import load_scene

mujoco = pytest.importorskip("mujoco")
import mujoco.rollout  # noqa: E402

from stiction.bench import mujoco_twins  # noqa: E402

SCENES = ("solo12-stand", "go2-stand", "anymal-stand", "talos-stand", "ur5-push-wall", "ur5-push-box",
          "solo12-on-board")
STANDING = ("solo12-stand", "go2-stand", "anymal-stand", "talos-stand")


@pytest.fixture(scope="module")
def twins():
    out = {}
    for name in SCENES:
        scene = load_scene(name)
        out[name] = (scene, mujoco_twins.mujoco_twin(scene))
    return out


def _random_configuration(model: pin.Model, rng) -> np.ndarray:
    """Seeded: joint angles in (-pi, pi), free flyers anywhere in a 2 m box, any orientation."""
    q = pin.neutral(model)
    for j in range(1, model.njoints):
        i, kind = model.joints[j].idx_q, model.joints[j].shortname()
        if kind == "JointModelFreeFlyer":
            quat = rng.standard_normal(4)
            q[i:i + 7] = np.concatenate([rng.uniform(-1, 1, 3), quat / np.linalg.norm(quat)])
        else:
            q[i] = rng.uniform(-np.pi, np.pi)
    return q


@pytest.mark.parametrize("name", SCENES)
def test_same_mass_sizes_and_state_maps(twins, name):
    scene, twin = twins[name]
    model, m = scene.model, twin.model
    moving = sum(model.inertias[j].mass for j in range(1, model.njoints))  # inertias[0]: welded to the world
    assert m.body_mass.sum() == pytest.approx(moving, rel=1e-12)
    assert moving > 1.0
    assert (m.nq, m.nv) == (model.nq, model.nv)
    assert m.nu == int(((scene.kp != 0) | (scene.kd != 0) | (scene.tau_ff != 0)).sum()) > 0
    q0 = scene.q0
    np.testing.assert_allclose(twin.q_from_qpos(twin.qpos(q0), model.nq)[0], q0, atol=1e-15)


@pytest.mark.parametrize("name", SCENES)
def test_same_kinematics_and_mass_matrix_anywhere(twins, name, rng):
    """At random configurations and velocities: every body's world placement (Pinocchio's oMi),
    the joint-space mass matrix and the kinetic energy agree to round-off."""
    scene, twin = twins[name]
    model, m = scene.model, twin.model
    pdata, d = model.createData(), mujoco.MjData(m)
    for _ in range(3):
        q = _random_configuration(model, rng)
        v = rng.standard_normal(model.nv)
        d.qpos[:], d.qvel[:] = twin.qpos(q), twin.qvel(q, v)
        mujoco.mj_forward(m, d)
        pin.forwardKinematics(model, pdata, q)
        for j in range(1, model.njoints):
            b = m.body(model.names[j]).id
            np.testing.assert_allclose(d.xpos[b], pdata.oMi[j].translation, atol=1e-12)
            np.testing.assert_allclose(d.xmat[b].reshape(3, 3), pdata.oMi[j].rotation, atol=1e-12)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        Mp = pin.crba(model, pdata, q)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T
        # qvel = T v (a free flyer's linear velocity turns from its body frame to the world's)
        T = np.column_stack([twin.qvel(q, e) for e in np.eye(model.nv)])
        np.testing.assert_allclose(T.T @ M @ T, Mp, atol=1e-12 * np.abs(Mp).max())
        assert d.qvel @ M @ d.qvel == pytest.approx(v @ Mp @ v, rel=1e-10)
        np.testing.assert_allclose(twin.q_from_qpos(d.qpos, model.nq)[0], q, atol=1e-12)


@pytest.mark.parametrize("name", SCENES)
def test_same_contact_heights_in_the_initial_posture(twins, name):
    """MuJoCo's own signed distance of each contact pair equals stiction's gap (n.c - d - r, from the
    C++ contact centres) to 1e-6 m: spheres on the same links, points as small spheres."""
    scene, twin = twins[name]
    from stiction.simulator import Simulator

    sim = Simulator(scene)
    centres = sim.contact_centers(type("T", (), {"q": scene.q0[None]})())[0]
    local, gaps = mujoco_twins.contact_geometry(scene, scene.q0)
    for k, c in enumerate(scene.contacts):  # the Python yardstick agrees with the C++ centres
        h = scene.halfspaces[c.halfspace]
        if h.frame == 0:
            n = np.asarray(h.normal) / np.linalg.norm(h.normal)
            assert gaps[0, k] == pytest.approx(n @ centres[k] - h.offset - c.radius, abs=1e-12)
    d = mujoco.MjData(twin.model)
    d.qpos[:] = twin.qpos(scene.q0)
    mujoco.mj_forward(twin.model, d)
    fromto = np.zeros(6)
    dist = [mujoco.mj_geomDistance(twin.model, d, twin.plane_geoms[c.halfspace], twin.contact_geoms[k], 1.0, fromto)
            for k, c in enumerate(scene.contacts)]
    np.testing.assert_allclose(dist, gaps[0], atol=1e-6)
    assert gaps.min() > -1e-6  # the scenes start touching, not inside (solo12-on-board: 0.25 µm)


@pytest.mark.parametrize("name", STANDING + ("ur5-push-wall", "solo12-on-board"))
def test_mujoco_keeps_the_robot_standing(twins, name):
    """0.5 s of MuJoCo from the scene's initial state: every contact stays closed (MuJoCo's soft
    contact sinks it by mm, not cm), the base keeps its height to 2 cm and stays upright; the UR5
    keeps pressing on its wall."""
    scene, twin = twins[name]
    n = int(round(0.5 / scene.dt))
    m = twin.model
    states, _ = mujoco.rollout.rollout(m, mujoco.MjData(m), twin.initial_state(scene.q0, scene.v0),
                                       twin.ctrl.reshape(1, 1, -1), nstep=n)
    Q = np.vstack([scene.q0, twin.q_from_qpos(states[0, :, 1:1 + m.nq], scene.model.nq)])
    assert np.isfinite(Q).all()
    _, gaps = mujoco_twins.contact_geometry(scene, Q[-50:])
    assert gaps.max() < 1e-3, "a contact opened"
    acc = mujoco_twins.contact_accuracy(scene, np.arange(n + 1) * scene.dt, Q, settle=0.0)
    assert 1e-6 < acc["penetration"] < 1e-2  # soft: mm, not exact, and not sinking through
    if name in STANDING:
        assert abs(Q[-1, 2] - Q[0, 2]) < 0.02
        up = pin.Quaternion(Q[-1, 3:7]).matrix()[:, 2]
        assert up[2] > np.cos(np.radians(5))


def test_accuracy_yardstick_on_a_known_motion():
    """Drift and penetration of a made-up trajectory: Solo-12 lowered 2 mm into the ground at
    t = 0.1 s, then its base slid 3 mm along y after the settle time."""
    scene = load_scene("solo12-stand")
    t = np.linspace(0.0, 1.0, 11)
    Q = np.tile(scene.q0, (len(t), 1))
    Q[1:, 2] -= 0.002
    Q[:, 1] += np.where(t > scene.settle_time, 0.003 * (t - scene.settle_time) / 0.5, 0.0)
    acc = mujoco_twins.contact_accuracy(scene, t, Q)
    assert acc["penetration"] == pytest.approx(0.002, abs=1e-12)
    assert acc["drift"] == pytest.approx(0.003, abs=1e-12)
    assert acc["closed"] == 4


def test_errors_name_what_is_wrong():
    scene = load_scene("solo12-stand")
    with pytest.raises(ValueError, match="impratio"):
        mujoco_twins.mujoco_twin(scene, impratio=0.5)
    with pytest.raises(ValueError, match="coal collision pairs"):
        mujoco_twins.mujoco_twin(dataclasses.replace(scene, pairs=[object()]))
    with pytest.raises(ValueError, match="mode"):
        mujoco_twins.mujoco_twin(dataclasses.replace(scene, mode="rk4"))
    with pytest.raises(ValueError, match="nq = 19"):
        mujoco_twins.contact_geometry(scene, np.zeros((2, 7)))


def _bench_module():
    spec = importlib.util.spec_from_file_location("bench_robots_mujoco", ROOT / "benchmarks" / "bench_robots_mujoco.py")
    bench = importlib.util.module_from_spec(spec)
    sys.modules["bench_robots_mujoco"] = bench
    spec.loader.exec_module(bench)
    return bench


def test_bench_script_runs_and_reports_every_scene_asked(capsys):
    """The robot benchmark on two scenes, 1.2 s each: past ur5-push-wall's settle_time of 1 s, which the
    summary behind its accuracy columns requires; and with the joint rows on, ur5-push-wall (the UR5's
    six joints given 0.5 N m of dry friction) and solo12-stand-joint-rows as bundled."""
    bench = _bench_module()
    res = bench.run(["ur5-push-wall", "solo12-stand"], repeats=1, duration=1.2, impratios=(1.0,),
                    joint_rows=["ur5-push-wall", "solo12-stand-joint-rows"])
    assert [r["scene"] for r in res["rows"]] == ["ur5-push-wall", "solo12-stand"]
    assert [r["scene"] for r in res["joint_rows"]] == ["ur5-push-wall", "solo12-stand-joint-rows"]
    for row in res["rows"] + res["joint_rows"]:
        for key in ("stiction rollout", "mujoco 1 rollout", "stiction rollout cpu", "mujoco 1 rollout cpu",
                    "stiction steps", "mujoco 1 steps"):
            assert row["us"][key]["median"] > 0
        for kind in ("rollout", "rollout cpu", "steps"):  # one repetition: the ratio of the two runs
            ratio = row["ratio"][f"{kind} vs impratio 1"]["median"]
            us = row["us"]
            assert ratio == pytest.approx(us[f"stiction {kind}"]["median"] / us[f"mujoco 1 {kind}"]["median"])
        acc = row["accuracy"]
        assert acc["stiction"]["converged"]
        assert acc["stiction"]["penetration"] < 1e-6 < acc["mujoco impratio 1"]["penetration"]
        assert acc["mujoco impratio 1"]["rollout_vs_steps"] == 0.0
    ur5, solo = res["joint_rows"]
    assert ur5["friction_added"] == 0.5 and solo["friction_added"] == 0.0
    assert ur5["rows_in_play"] == {"limits": 6, "friction": 6, "damping": 0, "effort": 6}
    assert solo["rows_in_play"] == {"limits": 12, "friction": 12, "damping": 0, "effort": 12}
    for row in res["joint_rows"]:  # warm-up and one repetition, each a rollout and a step-by-step run
        assert row["stiction_steps_run"] == 2 * 2 * row["steps"] and row["stiction_steps_unconverged"] == 0
    text = bench.markdown(res)
    assert "| ur5-push-wall | 6 | 1 |" in text
    assert "## Joint rows on" in text and "| ur5-push-wall | 6 / 6 / 0 / 6 | 0.5 |" in text
    assert f"yes ({2 * 2 * solo['steps']} steps) |" in text


def test_bench_joint_rows_scenes_add_friction_where_the_urdf_has_none():
    """The joint-rows set's scenes: every actuated joint without URDF friction gets the robot's tau_c
    (TALOS's legs 1.0 N m; its upper body keeps its URDF's 1.0), nothing else changes; a scene of
    locked joints or one already holding its rows is as bundled."""
    bench = _bench_module()
    talos, added = bench.joint_rows_scene("talos-stand")
    bundled = load_scene("talos-stand")
    assert added == 1.0
    for j in range(1, talos.model.njoints):
        name, iv = talos.model.names[j], talos.model.joints[j].idx_v
        nv = talos.model.joints[j].nv
        friction = talos.model.friction[iv:iv + nv]
        if name.startswith("leg_"):
            assert (friction == 1.0).all() and bundled.model.friction[iv] == 0.0
        elif name == "root_joint":
            assert not friction.any()
        else:
            assert (friction == bundled.model.friction[iv:iv + nv]).all() and friction[0] == 1.0
    np.testing.assert_array_equal(talos.model.effortLimit, bundled.model.effortLimit)
    np.testing.assert_array_equal(talos.model.damping, bundled.model.damping)
    box, added = bench.joint_rows_scene("ur5-push-box")
    assert added == 0.5 and list(box.model.friction) == [0.5] * 6 + [0.0] * 6  # the crate's free joint: none
    for name in ("solo12-slope-stick", "solo12-stand-joint-rows"):
        scene, added = bench.joint_rows_scene(name)
        assert added == 0.0
        np.testing.assert_array_equal(scene.model.friction, load_scene(name).model.friction)


@pytest.mark.parametrize("name", SCENES)
def test_same_joint_pd_torque(twins, name, rng):
    """MuJoCo's actuator torque at a random state is stiction's PD law kp (q_target - q) - kd v +
    tau_ff joint by joint (the UR5's gravity feed-forward included), clamped to the URDF's effort
    limit (the scenes' effort_limits are on)."""
    scene, twin = twins[name]
    model, m = scene.model, twin.model
    d = mujoco.MjData(m)
    q, v = _random_configuration(model, rng), rng.standard_normal(model.nv)
    d.qpos[:], d.qvel[:], d.ctrl[:] = twin.qpos(q), twin.qvel(q, v), twin.ctrl
    mujoco.mj_forward(m, d)
    law = scene.kp * pin.difference(model, q, scene.q_target) - scene.kd * v + scene.tau_ff
    effort = np.asarray(model.effortLimit, dtype=float)
    expected = np.clip(law, -effort, effort)
    for j in twin.joints:
        if j.kind != "free":
            assert d.qfrc_actuator[j.dofadr] == pytest.approx(expected[j.idx_v], rel=1e-12, abs=1e-12)
        else:
            assert not d.qfrc_actuator[j.dofadr:j.dofadr + 6].any()
    assert np.abs(expected).max() > 1.0
    if name in ("go2-stand", "talos-stand"):  # stiff PD far from its target: some actuator saturates
        assert (np.abs(law) > effort).any()
