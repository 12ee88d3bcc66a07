"""Sensors (issue 25; docs/simulator.md, "Sensors"): world-frame contact forces, per-frame totals,
the base's IMU, in the trajectory and live (Simulator.sensors()).

Every expected value is computed here independently of stiction.sensors and src/cpp/sim/sensors.cpp:
the contact frames from the half-spaces' normals and tangents and Pinocchio's frame placements, the
forces from the solver's impulses (sim.data.result.lam, P = h lambda in time stepping, eq. 70), the
masses from pinocchio.computeTotalMass, the IMU from Pinocchio's frame velocity and classical
acceleration, and the physics (m g at rest, 0 proper acceleration in a free fall, the Coulomb cone's
edge |F_t| = mu F_n while slipping)."""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from stiction.simulator import Simulator, Trajectory

G = 9.81


def _yawed(sim: Simulator, angle: float) -> np.ndarray:
    """The scene's initial q with every free flyer turned by `angle` about the world z axis (positions
    and orientations): the same physics on an isotropic ground, with tangents off the world axes."""
    model, q = sim.scene.model, np.array(sim.scene.q0, dtype=float)
    Rz = pin.utils.rotate("z", angle)
    for j in range(1, model.njoints):
        if model.joints[j].shortname() == "JointModelFreeFlyer":
            iq = model.joints[j].idx_q
            q[iq:iq + 3] = Rz @ q[iq:iq + 3]
            quat = pin.Quaternion(Rz @ pin.Quaternion(q[iq + 3:iq + 7]).matrix())
            q[iq + 3:iq + 7] = quat.coeffs()
    return q


def _expected_world_forces(sim: Simulator, q_start: np.ndarray) -> np.ndarray:
    """Each sphere contact's world force after the step just taken, from the solver's impulses / h and
    the contact frame (t1, t2, n) of its half-space at the step's start configuration (Pinocchio)."""
    model, scene = sim.scene.model, sim.scene
    data = model.createData()
    pin.framesForwardKinematics(model, data, q_start)
    impulse = np.asarray(sim.data.result.lam, dtype=float)
    h = sim.dt
    rows = np.asarray(sim.data.rows)
    out = np.zeros((sim.model.num_candidates, 3))
    row = 0
    for i in sim.data.active:
        k = int(rows[i])
        c = scene.contacts[i]
        hs = sim.model.halfspaces[c.halfspace]  # (the C++ model's copy: its tangents completed)
        B = np.column_stack([np.asarray(hs.tangent1), np.asarray(hs.tangent2), np.asarray(hs.normal)])
        np.testing.assert_allclose(B.T @ B, np.eye(3), atol=1e-15)
        assert np.linalg.det(B) > 0
        if hs.frame != 0:
            B = data.oMf[hs.frame].rotation @ B
        axes = {3: [0, 1, 2], 2: [0, 2], 1: [2]}[k]  # spatial (t1, t2, n), planar (t1, n), frictionless (n)
        out[i] = B[:, axes] @ (impulse[row:row + k] / h)
        row += k
    return out


@pytest.mark.parametrize("name, yaw", [("solo12-stand", 0.7), ("solo12-on-board", 0.7), ("pinch", 0.0),
                                       ("cube-incline-slip", 0.3), ("planar-box-slide", 0.0)])
def test_world_force_is_the_impulse_over_h_in_the_contact_frame(name, yaw):
    """contact_force = (t1 t2 n) P / h, the frame from the half-space (a body's face: turned by
    Pinocchio's placement of its frame at the step's start), live after each step and in the
    trajectory. solo12-on-board: the feet stand on the free board's top face (a moving half-space);
    pinch: the finger pads' half-spaces are faces of the held box."""
    sim = Simulator(name)
    sim.set_state(q=_yawed(sim, yaw))
    worst, scale, touched = 0.0, 0.0, 0
    for _ in range(150):
        q_start = np.array(sim.data.q)
        sim.step()
        expected = _expected_world_forces(sim, q_start)
        got = sim.sensors().contact_force
        worst = max(worst, float(np.abs(got - expected).max()))
        scale = max(scale, float(np.abs(expected).max()))
        touched += len(sim.data.active)
    assert touched > 0 and scale > 1.0
    assert worst <= 1e-12 * scale
    # the trajectory records the same, step by step
    traj = sim.rollout(0.02)
    live = sim.sensors()
    np.testing.assert_array_equal(traj.contact_force[-1], live.contact_force)
    assert np.isnan(traj.contact_force[0]).all() and np.isnan(traj.frame_force[0]).all()
    assert (traj.frame_states[0] == -1).all()


def test_standing_feet_carry_the_total_weight():
    """solo12-stand settled: the feet's world forces sum to m g (m: pinocchio.computeTotalMass), up."""
    sim = Simulator("solo12-stand")
    traj = sim.rollout(3.0)
    mass = pin.computeTotalMass(sim.scene.model)
    feet = ["FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"]
    assert traj.frame_names == feet
    total = sum(traj.frame_force_of(f)[-1] for f in feet)
    np.testing.assert_allclose(total, [0.0, 0.0, mass * G], rtol=0, atol=1e-6 * mass * G)
    assert traj.frame_in_contact[-1].all() and (traj.frame_states[-1] == 1).all()
    # by contact name too, and the frame total is its one contact's
    np.testing.assert_array_equal(traj.contact_force_of("FL_FOOT"), traj.frame_force_of("FL_FOOT"))
    with pytest.raises(KeyError, match="FL_FOOT"):
        traj.contact_force_of("FL_FOT")


def test_board_carries_robot_and_its_own_weight():
    """solo12-on-board, settled: the feet push the board (the moving half-space's body gets the
    opposite of their forces) and the ground holds both: the board's total is its own weight, the
    feet's the robot's."""
    sim = Simulator("solo12-on-board")
    sim.set_state(q=_yawed(sim, 0.7))
    traj = sim.rollout(2.0)
    model = sim.scene.model
    board_joint = model.getJointId("board_root") if model.existJointName("board_root") else model.njoints - 1
    board_mass = sum(model.inertias[j].mass for j in range(1, model.njoints) if j >= board_joint)
    robot_mass = pin.computeTotalMass(model) - board_mass
    feet = sum(traj.frame_force_of(f)[-1] for f in ["FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"])
    np.testing.assert_allclose(feet, [0, 0, robot_mass * G], atol=1e-6 * robot_mass * G)
    board = traj.frame_force[-1, traj.frame_names.index("board_board")]
    np.testing.assert_allclose(board, [0, 0, board_mass * G], atol=1e-6 * robot_mass * G)
    assert abs(board_mass - 2.0) < 1e-12


def test_ball_on_table_coal_pair():
    """A coal pair (the ball is the pair's first geometry): the slot's force acts on the table (down),
    the ball's frame total is its weight, up."""
    sim = Simulator("ball-on-table")
    traj = sim.rollout(1.0)
    mass = pin.computeTotalMass(sim.scene.model)
    on_table = traj.contact_force_of("ball_0|table#0")[-1]
    np.testing.assert_allclose(on_table, [0, 0, -mass * G], atol=1e-8 * mass * G)
    np.testing.assert_allclose(traj.frame_force_of("ball")[-1], [0, 0, mass * G], atol=1e-8 * mass * G)
    # before it lands: no force, frame open
    first = int(np.argmax(traj.t > 0.05))
    assert (traj.frame_force[1:first] == 0).all() and (traj.frame_states[1:first] == 0).all()


@pytest.mark.parametrize("name", ["cube-incline-slip", "solo12-slope-slip"])
def test_slipping_force_on_the_cone_edge(name):
    """While a contact slips, its world tangential force over its world normal force is mu (the ground
    is the world's z = 0 plane: the slope tilts gravity)."""
    sim = Simulator(name)
    traj = sim.rollout(0.5)
    mu = sim.scene.mu
    slipping = traj.states == 2
    assert slipping[len(traj.t) // 2:].any()
    F = traj.contact_force[slipping]
    ratio = np.linalg.norm(F[:, :2], axis=1) / F[:, 2]
    assert (F[:, 2] > 0).all()
    np.testing.assert_allclose(ratio, mu, rtol=1e-8)


def test_accelerometer_at_rest_reads_g_up():
    """Standing still, the base's accelerometer reads +g along the base's up axis (R^T (0, 0, g))."""
    sim = Simulator("solo12-stand")
    traj = sim.rollout(3.0)
    R = pin.Quaternion(traj.q[-2, 3:7]).matrix()
    np.testing.assert_allclose(traj.accelerometer[-1], R.T @ [0.0, 0.0, G], rtol=0, atol=1e-6 * G)
    assert np.isnan(traj.accelerometer[0]).all()
    live = sim.sensors()
    np.testing.assert_array_equal(live.accelerometer, traj.accelerometer[-1])


@pytest.mark.parametrize("name, z", [("cube-incline-slip", 3.0), ("ball-on-table", None)])
def test_accelerometer_in_free_fall_reads_zero(name, z):
    """A body in free fall, tumbling (its centre of mass at the IMU's origin), reads 0 before it touches
    anything."""
    sim = Simulator(name)
    q = np.array(sim.scene.q0, dtype=float)
    if z is not None:
        q[2] = z
    sim.set_state(q=q, v=[0.4, -0.3, 0.2, 3.0, -2.0, 5.0])
    traj = sim.rollout(0.05)
    assert (traj.frame_force[1:] == 0).all()  # no contact yet
    assert np.abs(traj.accelerometer[1:]).max() < 1e-9
    assert np.abs(traj.gyro).max() > 1.0  # it tumbles


def test_imu_against_pinocchio():
    """A kicked Solo-12: the gyro is Pinocchio's LOCAL angular velocity of the base frame at each
    record; the accelerometer the change of the base origin's world velocity (Pinocchio's
    LOCAL_WORLD_ALIGNED frame velocity) over the step, minus g, in the base frame at the step's start."""
    sim = Simulator("solo12-stand")
    v0 = np.zeros(sim.scene.model.nv)
    v0[:6] = [0.2, -0.1, 0.3, 1.5, -1.0, 2.0]
    sim.set_state(v=v0)
    traj = sim.rollout(0.3)
    model = sim.scene.model
    data = model.createData()
    base = model.getFrameId("base_link")
    g = np.asarray(model.gravity.linear)
    world_velocity, rotation = [], []
    for k in range(len(traj.t)):
        pin.forwardKinematics(model, data, traj.q[k], traj.v[k])
        pin.updateFramePlacements(model, data)
        gyro = pin.getFrameVelocity(model, data, base, pin.LOCAL).angular
        np.testing.assert_allclose(traj.gyro[k], gyro, rtol=0, atol=1e-12)
        world_velocity.append(pin.getFrameVelocity(model, data, base, pin.LOCAL_WORLD_ALIGNED).linear.copy())
        rotation.append(data.oMf[base].rotation.copy())
    for k in range(1, len(traj.t)):
        expected = rotation[k - 1].T @ ((world_velocity[k] - world_velocity[k - 1]) / traj.dt[k] - g)
        np.testing.assert_allclose(traj.accelerometer[k], expected, rtol=0, atol=1e-9 * max(1.0, np.abs(expected).max()))
    assert np.abs(traj.gyro).max() > 0.5 and np.abs(traj.accelerometer[1:] - traj.accelerometer[1]).max() > 0.5


def test_live_sensors_and_names():
    """sim.sensors(): NaN before any step and after reset, the last record's values after a rollout,
    lookups by name (a wrong one names the candidates)."""
    sim = Simulator("solo12-stand")
    s = sim.sensors()
    assert math.isnan(s.t) and np.isnan(s.contact_force).all() and np.isnan(s.accelerometer).all()
    assert (s.frame_states == -1).all() and not s.frame_in_contact.any()
    traj = sim.rollout(0.5)
    s = sim.sensors()
    assert s.t == traj.t[-1]
    np.testing.assert_array_equal(s.contact_force, traj.contact_force[-1])
    np.testing.assert_array_equal(s.frame_force, traj.frame_force[-1])
    np.testing.assert_array_equal(s.frame_states, traj.frame_states[-1])
    np.testing.assert_array_equal(s.gyro, traj.gyro[-1])
    np.testing.assert_array_equal(s.tau, traj.tau[-1])
    np.testing.assert_array_equal(s.contact_force_of("HR_FOOT"), traj.contact_force[-1, 3])
    np.testing.assert_array_equal(s.frame_force_of("HR_FOOT"), traj.frame_force[-1, 3])
    with pytest.raises(KeyError, match="no contact frame named 'HR_FOO'.*HR_FOOT"):
        s.frame_force_of("HR_FOO")
    sim.reset()
    assert np.isnan(sim.sensors().contact_force).all()


def test_fixed_base_has_no_imu():
    """A fixed-base arm (no free flyer): no IMU, in the trajectory and live; its tool's contact still
    has its frame total."""
    sim = Simulator("ur5-push-wall")
    traj = sim.rollout(0.01)
    assert traj.accelerometer is None and traj.gyro is None
    live = sim.sensors()
    assert live.accelerometer is None and live.gyro is None
    assert traj.frame_names == ["tool0"] and traj.frame_force.shape == (len(traj.t), 1, 3)


def test_callback_batch_and_saved_trajectories_keep_sensors(tmp_path):
    """The callback loop, a batch and a saved file give the same sensor arrays as the C++ rollout; a
    file saved before sensors were recorded loads with None."""
    a = Simulator("solo12-stand")
    ref = a.rollout(0.05)
    b = Simulator("solo12-stand")
    via_callback = b.rollout(0.05, callback=lambda s: None)
    batch = Simulator("solo12-stand").batch_rollout(1, duration=0.05).trajectories[0]
    for other in (via_callback, batch):
        for key in ("contact_force", "frame_force", "frame_states", "accelerometer", "gyro"):
            np.testing.assert_array_equal(getattr(other, key), getattr(ref, key), err_msg=key)
    ref.save(tmp_path / "t.npz")
    back = Trajectory.load(tmp_path / "t.npz")
    assert back.frame_names == ref.frame_names
    for key in ("contact_force", "frame_incidence", "frame_force", "frame_states", "accelerometer", "gyro"):
        np.testing.assert_array_equal(getattr(back, key), getattr(ref, key), err_msg=key)
    with np.load(tmp_path / "t.npz") as f:
        old = {k: f[k] for k in f.files if k not in ("contact_force", "frame_names", "frame_incidence",
                                                     "frame_force", "frame_states", "accelerometer", "gyro")}
    np.savez_compressed(tmp_path / "old.npz", **old)
    legacy = Trajectory.load(tmp_path / "old.npz")
    assert legacy.contact_force is None and legacy.frame_names is None and legacy.accelerometer is None
    with pytest.raises(ValueError, match="saved before sensors"):
        legacy.contact_force_of("FL_FOOT")


@pytest.mark.parametrize("mode", ["timestep", "rk4"])
def test_accelerometer_times_mass_is_the_contact_force(mode):
    """Newton on a single rigid body (the cube, its centre of mass at the IMU's origin) sliding down
    the incline: m times the proper acceleration is the total contact force, in the body frame (rk4: its
    steady slide, where the last right-hand side's force is the whole step's)."""
    sim = Simulator("cube-incline-slip", mode=mode, dt=1e-3 if mode == "timestep" else 1e-4)
    traj = sim.rollout(0.3)
    mass = pin.computeTotalMass(sim.scene.model)
    R0 = np.array([pin.Quaternion(q[3:7]).matrix() for q in traj.q[:-1]])
    expected = np.einsum("kba,kb->ka", R0, traj.frame_force_of("cube")[1:]) / mass
    assert (traj.frame_states[len(traj.t) // 2:] == 2).all()  # sliding
    np.testing.assert_allclose(traj.accelerometer[1:], expected, rtol=0, atol=1e-9 * G)


def test_frame_totals_of_a_trajectory_are_those_of_its_recorded_contacts(tmp_path):
    # frame_force / frame_states are made on first read (simulator._FrameTotals): their values must be
    # the sums and states of the contacts as recorded, whatever happened to the other fields since, and
    # survive pickling, asdict and save/load. Reference: a plain loop over frames and contacts.
    import copy
    import dataclasses
    import pickle

    sim = Simulator("pile-24")
    traj = sim.rollout(0.4)
    force, states = traj.contact_force.copy(), traj.states.copy()
    incidence = traj.frame_incidence
    expected_force = np.zeros((len(traj.t), len(incidence), 3))
    expected_states = np.zeros((len(traj.t), len(incidence)), dtype=np.int8)
    for f, row in enumerate(incidence):
        touching = np.flatnonzero(row)
        for c in touching:
            expected_force[:, f] += row[c] * force[:, c]
        s = states[:, touching]
        expected_states[:, f] = np.where((s == 2).any(1), 2, np.where((s == 1).any(1), 1, np.where((s == 3).any(1), 3, 0)))
        expected_states[(s == -1).all(1), f] = -1
    assert len(incidence) > 2 and (expected_states[1:] > 0).any()
    clones = [pickle.loads(pickle.dumps(traj)), copy.deepcopy(traj)]
    traj.contact_force[:] = 0.0  # (in place, before the first read)
    traj.states[:] = 0
    for t in [traj] + clones:
        assert np.allclose(t.frame_force, expected_force, rtol=1e-12, atol=1e-12, equal_nan=True)
        assert t.frame_states.dtype == np.int8 and np.array_equal(t.frame_states, expected_states)
    assert np.array_equal(dataclasses.asdict(clones[0])["frame_states"], expected_states)
    clones[1].save(tmp_path / "t.npz")
    loaded = Trajectory.load(tmp_path / "t.npz")
    assert np.allclose(loaded.frame_force, expected_force, rtol=1e-12, atol=1e-12, equal_nan=True)
    # a field assigned while the totals are pending keeps its value, the other is still computed
    fresh = sim.rollout(0.01)
    fresh.frame_force = None
    assert fresh.frame_force is None and fresh.frame_states.shape == (len(fresh.t), len(incidence))
