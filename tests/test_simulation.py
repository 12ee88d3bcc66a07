"""Simulation against closed-form answers (paper §4.4 time stepping, eq. 70)."""
import math

import numpy as np
import pytest

from stiction.bench.work_precision import slide_distance
from stiction.simulator import Simulator

G = 9.81


def stop_time(traj, threshold=1e-9):
    moving = np.abs(traj.v[:, 0]) > threshold
    return traj.t[np.nonzero(moving)[0][-1] + 1]


@pytest.mark.parametrize("h", [1e-3, 2e-3])
def test_sliding_cube_stops_where_coulomb_says(h):
    """v0 = 1 m/s, mu = 0.5: stop at v0/(mu g) within one step; distance the symplectic scheme's exact
    discrete stop N h v0 - mu g h^2 N (N + 1) / 2, N = floor(v0 / (mu g h)) (slide_distance; measured
    within 5e-16 m at h = 1 ms, 3e-15 m at 2 ms), which v0^2/(2 mu g) - v0 h/2 misses by 2.7e-7 and
    5.8e-7 m (v0 / (mu g h) = 203.87, 101.94); no hop: |v_n| <= 1e-9 while sliding."""
    v0, mu = 1.0, 0.5
    sim = Simulator("cube-slide", dt=h)
    traj = sim.rollout(0.5)
    assert traj.converged[1:].all()
    assert abs(stop_time(traj) - v0 / (mu * G)) <= h
    d = traj.q[-1, 0] - traj.q[0, 0]
    expected = slide_distance(v0, mu * G, h)
    assert abs((v0**2 / (2 * mu * G) - v0 * h / 2) - expected) > 1e-7  # the old formula would fail
    assert abs(d - expected) <= 1e-12
    sliding = traj.states == 2
    assert sliding.any()
    assert np.abs(traj.contact_velocity[..., 2][sliding]).max() <= 1e-9
    assert np.abs(traj.v[:, 2]).max() <= 1e-9  # the cube itself never leaves the ground
    assert -traj.gaps.min() <= 1e-9


def test_cube_sticks_on_the_incline():
    """30 degree slope, mu = 0.6 > tan 30: drift <= 1e-9 m in 2 s."""
    sim = Simulator("cube-incline-stick")
    traj = sim.rollout(2.0)
    assert sim.scene.mu > math.tan(math.radians(30))
    assert np.linalg.norm(traj.q[-1, :3] - traj.q[0, :3]) <= 1e-9
    assert (traj.states[1:, [0, 2, 4, 6]] == 1).all()  # the four bottom corners stick


def test_cube_slides_down_the_incline_at_the_analytic_rate():
    """mu = 0.5: a = g (sin 30 - mu cos 30) within 0.1 %."""
    sim = Simulator("cube-incline-slip")
    traj = sim.rollout(2.0)
    expected = G * (math.sin(math.radians(30)) - 0.5 * math.cos(math.radians(30)))
    summary = sim.summary(traj)
    assert summary["mean_acceleration_along_slope"] == pytest.approx(expected, rel=1e-3)
    assert summary["max_normal_velocity_while_sliding"] <= 1e-9


def test_solo12_stands_still_for_10_s():
    """Exact Coulomb friction holds ft/fn ~ 0.37 with zero slip (MuJoCo's soft contact
    lets the feet splay by millimetres, shared/reference/peers-mujoco-drake.md)."""
    sim = Simulator("solo12-stand")
    traj = sim.rollout(10.0, record_every=10)
    s = sim.summary(traj)
    assert s["all_converged"]
    assert s["max_foot_slip"] <= 1e-6
    assert s["max_foot_displacement"] <= 1e-6
    assert s["max_penetration"] <= 1e-6  # stated: ~3e-8 m (Baumgarte closes what the step leaves)
    ratio = np.linalg.norm(traj.lam[-1, :, :2], axis=-1) / traj.lam[-1, :, 2]
    assert ratio == pytest.approx(0.366, abs=0.01)
    assert traj.lam[-1, :, 2].sum() == pytest.approx(sim.scene.model.gravity.linear[2] * -sum(
        i.mass for i in sim.scene.model.inertias), rel=1e-3)


def test_rigid_solo12_sticks_on_a_slope_below_its_friction_angle():
    sim = Simulator("solo12-slope-stick")
    traj = sim.rollout(2.0)
    assert sim.scene.mu > math.tan(math.radians(sim.scene.slope_deg))
    assert np.linalg.norm(traj.q[-1, :3] - traj.q[0, :3]) <= 1e-9


def test_rigid_solo12_slides_with_the_analytic_acceleration():
    sim = Simulator("solo12-slope-slip")
    traj = sim.rollout(1.0)
    th = math.radians(sim.scene.slope_deg)
    expected = G * (math.sin(th) - sim.scene.mu * math.cos(th))
    s = sim.summary(traj)
    assert s["mean_acceleration_along_slope"] == pytest.approx(expected, rel=1e-3)
    assert s["max_normal_velocity_while_sliding"] <= 1e-9


@pytest.mark.parametrize("scene", ["two-cube-stack", "go2-stand", "anymal-stand", "ur5-push-wall", "talos-stand"])
def test_other_scenes_run_converged_without_penetration(scene):
    sim = Simulator(scene)
    # past settle_time (ur5-push-wall's is 1 s: a 1 s run measured its slip over no time at all)
    traj = sim.rollout(max(1.0, sim.scene.settle_time + 0.25), record_every=5)
    s = sim.summary(traj)
    assert s["all_converged"] and s["max_residual"] <= 1e-9
    assert s["max_penetration"] <= 1e-6
    assert s["max_foot_slip"] <= 1e-6


def test_ur5_presses_on_the_wall():
    """The PD target lies 5 cm beyond the wall: at rest the wall pushes back along -x and
    the tool sphere stays on the wall surface."""
    sim = Simulator("ur5-push-wall")
    traj = sim.rollout(2.0)
    assert traj.states[-1, 0] in (1, 2)  # closed
    assert traj.lam[-1, 0, 2] > 10.0
    assert abs(traj.gaps[-1, 0]) <= 1e-6
    assert np.abs(traj.v[-1]).max() <= 1e-4


def test_ode_mode_converges_to_the_nonsmooth_answer_as_delta_shrinks():
    """The relaxed DAI (eq. 39 + 64) integrated by RK4 (dt = delta / 20): the sliding
    distance error against v0^2/(2 mu g) falls as delta^2 (measured order 2.0), while
    time stepping carries its v0 h / 2 floor."""
    d_star = 1.0 / (2 * 0.5 * G)
    errors = []
    for delta in (8e-3, 4e-3, 2e-3):
        sim = Simulator("cube-slide", mode="rk4", dt=delta / 20, delta=delta)
        traj = sim.rollout(0.4, record_every=20)
        errors.append(abs(traj.q[-1, 0] - d_star))
        assert np.abs(traj.contact_velocity[..., 2][traj.states == 2]).max() <= 1e-9
    orders = [math.log2(errors[i] / errors[i + 1]) for i in range(2)]
    assert all(1.8 <= o <= 2.2 for o in orders), (errors, orders)


def test_adaptive_ode_mode_controls_its_error():
    sim = Simulator("cube-slide", mode="adaptive", dt=1e-3, delta=1e-3, ode_tolerance=1e-8)
    traj = sim.rollout(0.4)
    rk4 = Simulator("cube-slide", mode="rk4", dt=5e-5, delta=1e-3).rollout(0.4, record_every=100)
    assert traj.q[-1, 0] == pytest.approx(rk4.q[-1, 0], abs=1e-7)
    assert traj.dt[1:].min() < traj.dt[1:].max()  # the step adapted


def test_trajectory_round_trip(tmp_path):
    from stiction.simulator import Trajectory

    sim = Simulator("cube-slide")
    traj = sim.rollout(0.05)
    traj.save(tmp_path / "t.npz")
    back = Trajectory.load(tmp_path / "t.npz")
    np.testing.assert_array_equal(back.q, traj.q)
    np.testing.assert_array_equal(back.lam, traj.lam)
    assert back.contact_names == traj.contact_names and back.scene == "cube-slide"


def test_python_callback_sets_torques():
    """A callback runs before each step: a constant horizontal push on a resting cube
    (free-flyer force tau_ff[0]) below mu m g = 4.905 N keeps it still, above it slides
    with acceleration (push - mu m g) / m."""
    for push in (4.0, 6.0):
        sim = Simulator("cube-slide")
        sim.data.v = np.zeros(6)

        def callback(s, push=push):
            tau = np.zeros(6)
            tau[0] = push
            s.data.tau_ff = tau

        traj = sim.rollout(0.2, callback=callback)
        if push < 0.5 * G:
            assert abs(traj.q[-1, 0] - traj.q[0, 0]) <= 1e-12
        else:
            assert traj.v[-1, 0] == pytest.approx((push - 0.5 * G) * 0.2, rel=1e-9)


@pytest.mark.parametrize("mode, dt, extra", [("timestep", 1e-4, {}), ("rk4", 1e-3, {"delta": 1e-2})])
def test_pinned_pendulum_swings_with_the_right_period(mode, dt, extra):
    """Bilateral rows (a point anchor, paper §3): a rod pinned at one end, released at
    theta0 = 0.05 rad. Period T0 (1 + theta0^2 / 16) with T0 = 2 pi sqrt(I_pivot / (m g d)),
    the pivot held to 1e-8 m."""
    import pinocchio as pin

    sim = Simulator("rod-pendulum", mode=mode, dt=dt, **extra)
    traj = sim.rollout(3.0, record_every=10 if mode == "timestep" else 1)
    model, data = sim.scene.model, sim.scene.model.createData()
    frame = model.getFrameId("rod")
    x, err = [], []
    for q in traj.q:
        pin.framesForwardKinematics(model, data, q)
        x.append(data.oMf[frame].translation[0])
        err.append(np.linalg.norm(data.oMf[frame].act(np.array([-0.25, 0, 0])) - [0, 0, 1.0]))
    x, t = np.array(x), traj.t
    crossings = [t[i] - x[i] * (t[i + 1] - t[i]) / (x[i + 1] - x[i]) for i in range(len(x) - 1) if x[i] > 0 >= x[i + 1]]
    period = np.diff(crossings).mean()
    inertia = 0.0208666667 + 1.0 * 0.25**2  # about the pivot
    expected = 2 * math.pi * math.sqrt(inertia / (G * 0.25)) * (1 + 0.05**2 / 16)
    assert period == pytest.approx(expected, rel=2e-5)
    assert max(err) <= 1e-8
    assert (traj.converged[1:]).all()


def test_scene_from_a_user_model_matches_the_scene_file():
    """Passing the pinocchio.Model you have gives the same motion as the bundled scene."""
    from stiction.robots import ROBOTS, load_robot
    from stiction.scene import scene_from_model

    robot = load_robot("solo12")
    spec = ROBOTS["solo12"]
    scene = scene_from_model(robot.model, robot.visual_model, robot.q0, spheres=[(f, 0.016) for f in spec.feet],
                             mu=1.0, kp=20.0, kd=0.2)
    a = Simulator(scene).rollout(0.3)
    b = Simulator("solo12-stand").rollout(0.3)
    np.testing.assert_allclose(a.q, b.q, atol=1e-12)
    np.testing.assert_allclose(a.lam, b.lam, atol=1e-9)


def test_rolling_ball_accelerates_at_five_sevenths_g_sin_theta():
    """A solid ball rolls without slipping down a 20 degree slope (mu 0.8): a = (5/7) g
    sin(theta), rolling counts as sticking, and the ball never leaves the slope."""
    from stiction.scene import build_scene

    scene = build_scene({"urdf": "ball.urdf", "ground": {"slope_deg": 20.0, "mu": 0.8}, "settle_time": 0.1,
                         "contacts": {"frames": ["ball"], "radius": 0.05}, "duration": 1.0})
    sim = Simulator(scene)
    traj = sim.rollout()
    s = sim.summary(traj)
    assert s["mean_acceleration_along_slope"] == pytest.approx(5 / 7 * G * math.sin(math.radians(20)), rel=1e-6)
    assert (traj.states[1:, 0] == 1).all()
    assert np.abs(traj.contact_velocity[1:, 0, 2]).max() <= 1e-12
    assert np.abs(traj.gaps[1:]).max() <= 1e-12


def test_coal_pair_rolling_ball_matches_the_analytic_path():
    """The same rolling ball, its sphere-vs-ground contact found by coal (a general pair)
    instead of the analytic sphere/half-space path: the same exact answer."""
    from stiction.scene import build_scene

    scene = build_scene({"urdf": "ball.urdf", "ground": {"slope_deg": 20.0, "mu": 0.8}, "settle_time": 0.1,
                         "duration": 1.0, "contacts": {"feet": False},
                         "collision": {"pairs": [["ball_0", "ground"]], "max_contacts": 1}})
    assert scene.contacts == [] and len(scene.pairs) == 1
    sim = Simulator(scene)
    traj = sim.rollout()
    s = sim.summary(traj)
    assert s["mean_acceleration_along_slope"] == pytest.approx(5 / 7 * G * math.sin(math.radians(20)), rel=1e-6)
    assert s["max_penetration"] <= 1e-12
    assert np.abs(traj.contact_velocity[1:, 0, 2]).max() <= 1e-12
    assert sim.contact_names == ["ball_0|ground#0"]


def test_ball_lands_and_rests_on_a_table_through_coal():
    """Sphere against a box fixed in the world (coal): after landing the ball rests on the
    table top at height 0.2 + r, carrying m g, and the ground pair stays open."""
    sim = Simulator("ball-on-table")
    traj = sim.rollout(1.0)
    s = sim.summary(traj)
    assert s["all_converged"]
    assert traj.q[-1, 2] == pytest.approx(0.25, abs=1e-9)
    assert traj.q[-1, 0] == pytest.approx(0.05, abs=1e-9)  # no sideways push
    assert traj.lam[-1, 1, 2] == pytest.approx(0.5 * G, rel=1e-9)
    assert np.isinf(traj.gaps[-1, 0]) or traj.gaps[-1, 0] > 0.1  # ground: far below
    assert s["max_penetration"] <= 1e-6


def test_user_model_with_coal_pairs():
    """A user's pinocchio.Model and collision GeometryModel (a ball), its contact with the
    ground handled by coal: at rest the ground carries m g."""
    import pinocchio as pin

    from stiction.scene import ROBOTS_DIR, scene_from_model

    urdf = str(ROBOTS_DIR / "ball.urdf")
    model = pin.buildModelFromUrdf(urdf, pin.JointModelFreeFlyer())
    collision = pin.buildGeomFromUrdf(model, urdf, pin.GeometryType.COLLISION)
    q0 = pin.neutral(model)
    q0[2] = 0.05
    scene = scene_from_model(model, None, q0, collision_model=collision, pairs=[("ball_0", "ground")],
                             place_on_ground=False, max_contacts=1)
    traj = Simulator(scene).rollout(0.2)
    assert traj.lam[-1, 0, 2] == pytest.approx(0.5 * G, rel=1e-9)
    assert abs(traj.q[-1, 2] - 0.05) <= 1e-12


def test_closed_loop_truss_hangs_still():
    """A closed loop (paper §3: bilateral rows): two 0.5 m rods pinned to the world 0.6 m
    apart and to each other at their free ends form a triangle with the ground. At its
    equilibrium nothing moves, the loop stays closed, and the world pins carry 2 m g."""
    import pinocchio as pin

    from stiction import _core
    from stiction.scene import scene_from_model

    inertia = pin.Inertia(1.0, np.zeros(3), np.diag([6.67e-5, 0.0208667, 0.0208667]))
    model = pin.Model()
    for k in range(2):
        j = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), f"rod{k}_joint")
        model.appendBodyToJoint(j, inertia, pin.SE3.Identity())
        model.addBodyFrame(f"rod{k}", j, pin.SE3.Identity(), 0)
    q0 = np.zeros(model.nq)
    pivots = [np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 1.0])]
    for k, (pivot, phi) in enumerate(zip(pivots, (math.atan2(0.8, 0.6), math.atan2(0.8, -0.6)))):
        R = pin.utils.rotate("y", phi)  # the rod's x axis from its pivot towards the joint at (0.3, 0, 0.6)
        q0[7 * k: 7 * k + 3] = pivot + 0.25 * R[:, 0]
        q0[7 * k + 3: 7 * k + 7] = pin.Quaternion(R).coeffs()
    scene = scene_from_model(model, None, q0, place_on_ground=False, duration=1.0)
    for k, pivot in enumerate(pivots):
        a = _core.PointAnchor()
        a.name, a.frame, a.offset, a.target = f"pin{k}", model.getFrameId(f"rod{k}"), np.array([-0.25, 0, 0]), pivot
        scene.anchors.append(a)
    loop = _core.PointAnchor()
    loop.name, loop.frame, loop.offset = "loop", model.getFrameId("rod0"), np.array([0.25, 0, 0])
    loop.frame2, loop.offset2 = model.getFrameId("rod1"), np.array([0.25, 0, 0])
    scene.anchors.append(loop)
    sim = Simulator(scene)
    traj = sim.rollout(1.0, record_every=100)
    assert traj.converged[1:].all()
    assert np.abs(traj.v).max() <= 1e-9
    np.testing.assert_allclose(traj.q[-1], q0, atol=1e-9)
    forces = np.asarray(sim.data.anchor_lambda).reshape(3, -1)
    assert forces[2, :2].sum() == pytest.approx(2 * G, rel=1e-9)  # the world pins carry both rods
    assert abs(forces[0, 0] + forces[0, 1]) <= 1e-8 * abs(forces[0, 0])  # horizontal pin forces cancel


def test_implicit_pd_keeps_stiff_gains_stable():
    """TALOS with kp 3000, kd 50 on light wrist and head links: the explicit PD diverges within
    a few steps (reported as an error, never a crash); folded implicitly into the step it holds."""
    sim = Simulator("talos-stand")
    traj = sim.rollout(0.5, record_every=50)
    assert traj.converged[1:].all() and (traj.states[-1] == 1).all()  # all 8 sole corners stick
    explicit = Simulator("talos-stand")
    s = explicit.model.settings
    s.implicit_pd = False
    # (TALOS's effort limits would bound the explicit PD's torques, and its arms' dry friction rows hold
    # them: the joints' rows off, the instability of the explicit PD alone)
    s.effort_limits = s.joint_friction = s.joint_limits = s.joint_damping = False
    from stiction import _core

    model = _core.SimulatorModel(explicit.scene.model, explicit.scene.halfspaces, explicit.scene.contacts, [], s)
    data = _core.SimulatorData(model)
    data.q, data.kp, data.kd, data.q_target = explicit.scene.q0, explicit.scene.kp, explicit.scene.kd, explicit.scene.q0
    with pytest.raises(RuntimeError, match="diverged|non-finite"):
        _core.rollout(model, data, 500, 1)


def test_cli_simulate_json_and_errors(tmp_path):
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "stiction.cli", "simulate", "cube-incline-slip", "--duration", "0.5",
                          "--json", "--save", str(tmp_path / "t.npz")], capture_output=True, text=True, check=True)
    s = json.loads(out.stdout)
    for key in ("scene", "steps", "us_per_step", "max_penetration", "max_residual", "base_drift",
                "max_normal_velocity_while_sliding", "mean_acceleration_along_slope", "max_foot_slip"):
        assert key in s
    assert s["steps"] == 500 and s["scene"] == "cube-incline-slip"
    # the rollout's wall time holds every step's timed interval: its mean per step is at least the timer's mean,
    # and the timer's mean is its total / steps (the trajectory saved holds every step's timings)
    saved = np.load(tmp_path / "t.npz")
    assert s["us_per_step"] == pytest.approx(saved["timings"][1:, 4].sum() / 500, rel=1e-12)
    assert s["median_us_per_step"] == pytest.approx(float(np.median(saved["timings"][1:, 4])), rel=1e-12)
    assert s["wall_us_per_step"] >= s["us_per_step"] > 0
    assert (tmp_path / "t.npz").is_file()
    bad = subprocess.run([sys.executable, "-m", "stiction.cli", "simulate", "no-such-scene"],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "unknown scene" in bad.stderr
    listing = subprocess.run([sys.executable, "-m", "stiction.cli", "scenes"], capture_output=True, text=True,
                             check=True).stdout
    for name in ("cube-slide", "cube-incline-stick", "cube-incline-slip", "two-cube-stack", "solo12-stand",
                 "solo12-slope-stick", "solo12-slope-slip", "go2-stand", "anymal-stand", "ur5-push-wall"):
        assert name in listing
