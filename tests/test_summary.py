"""Simulator.summary, key by key, against numbers this file computes itself from the trajectory:
positions and velocities of the contact spheres and bodies from Pinocchio (forwardKinematics,
updateFramePlacements, getFrameVelocity), gaps from the half-spaces' geometry, the rest with numpy.

The keys `Simulator.summary` emits (every one is covered here; test_every_key_is_covered lists them):
scene, mode, formulation, dt, duration, steps, recorded_steps, contacts, max_body_drift, us_per_step, median_us_per_step,
us_per_phase, median_us_per_phase, max_penetration, max_residual, all_converged, unconverged_steps, first_unconverged_t, settle_time,
base_drift, max_normal_velocity_while_sliding, mean_acceleration_along_slope,
expected_sliding_acceleration, max_foot_slip, max_foot_displacement, rows_per_contact, contact_rows,
warnings; final_base_speed, final_base_sway and settled are covered by tests/test_standing.py.

Record 0 (the initial state, not a step) is left out of every per-step reference here."""
import dataclasses
import math
import tomllib

import numpy as np
import pinocchio as pin
import pytest

from stiction.scene import SCENES_DIR, build_scene, load_scene
from stiction.simulator import PENETRATION_WARNING, Simulator

G = 9.81
KEYS = {"scene", "mode", "formulation", "dt", "duration", "steps", "recorded_steps", "contacts", "max_body_drift", "us_per_step",
        "median_us_per_step", "us_per_phase", "median_us_per_phase", "max_penetration", "max_residual", "all_converged", "unconverged_steps",
        "first_unconverged_t", "settle_time", "base_drift", "max_normal_velocity_while_sliding",
        "mean_acceleration_along_slope", "expected_sliding_acceleration", "max_foot_slip", "max_foot_displacement",
        "rows_per_contact", "contact_rows", "warnings",
        "final_base_speed", "final_base_sway", "settled",  # these three: tests/test_standing.py
        "max_limit_overshoot", "max_joint_drift", "max_effort_ratio", "saturated_steps"}  # and the joints' below
CLOSED_GAP = 1e-4  # [m] the summary's "stays closed" (its docstring: gaps <= 1e-4 m after settling)


# ------------------------------------------------------------------ independent references

def sphere_centres(sim, q):
    """World centre of every sphere contact at configuration q (Pinocchio frame placements)."""
    model = sim.scene.model
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    return np.array([data.oMf[c.frame].act(np.asarray(c.offset, float)) for c in sim.scene.contacts])


def sphere_gaps(sim, q):
    """Signed distance of every sphere contact to its (world-fixed) half-space: n.c - offset - r."""
    out = []
    for c, x in zip(sim.scene.contacts, sphere_centres(sim, q)):
        h = sim.model.halfspaces[c.halfspace]
        assert h.frame == 0, "this reference handles world half-spaces only"
        out.append(np.dot(h.normal, x) - h.offset - c.radius)
    return np.array(out)


def contact_point_velocities(sim, q_start, q_end, v_end):
    """World velocity, after a step, of each sphere's lowest material point (centre - r n) where
    the step's contact problem was built: at the step's start q_start (time stepping's J(q_k)
    v_k+1). The body's velocity v_end is re-expressed in q_start's body frame from Pinocchio's
    placements (the same world twist: R_start^T R_end v), then Pinocchio's frame velocity
    (LOCAL_WORLD_ALIGNED) is moved to the point. A single free-flyer body (the cube)."""
    model = sim.scene.model
    assert model.njoints == 2 and model.joints[1].shortname() == "JointModelFreeFlyer"
    data = model.createData()
    pin.forwardKinematics(model, data, q_end)
    R_end = data.oMi[1].rotation.copy()
    pin.forwardKinematics(model, data, q_start)
    turn = data.oMi[1].rotation.T @ R_end
    v = np.concatenate([turn @ v_end[:3], turn @ v_end[3:]])
    pin.forwardKinematics(model, data, q_start, v)
    pin.updateFramePlacements(model, data)
    out = []
    for c in sim.scene.contacts:
        h = sim.model.halfspaces[c.halfspace]
        mv = pin.getFrameVelocity(model, data, c.frame, pin.LOCAL_WORLD_ALIGNED)
        point = data.oMf[c.frame].act(np.asarray(c.offset, float)) - c.radius * np.asarray(h.normal)
        out.append(mv.linear + np.cross(mv.angular, point - data.oMf[c.frame].translation))
    return np.array(out)


def base_world_velocity(sim, q, v):
    """The root free flyer's linear velocity in the world frame (Pinocchio: oMi R times data.v)."""
    model = sim.scene.model
    data = model.createData()
    pin.forwardKinematics(model, data, q, v)
    return data.oMi[1].rotation @ data.v[1].linear


def free_body_positions(sim, q):
    """World position of every free-flyer joint (Pinocchio oMi), (nbodies, 3)."""
    model = sim.scene.model
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    return np.array([data.oMi[j].translation for j in range(1, model.njoints)
                     if model.joints[j].shortname() == "JointModelFreeFlyer"])


def after_settling(traj, settle_time):
    return traj.t >= settle_time - 1e-12


# ------------------------------------------------------------------ scenes

def spinning_uphill():
    """cube-incline-slip (30 deg, mu 0.5 < tan 30) launched uphill (body -x, 1 m/s) while spinning
    (yaw 30 rad/s), measured from t = 0: it rises ~5 cm, turns and slides back; the corners slide
    different distances (the spin), the base's body x is not the world's (the yaw), and the body's
    largest displacement (at the top) is not its last."""
    scene = load_scene("cube-incline-slip")
    v0 = np.zeros(6)
    v0[0], v0[5] = -1.0, 30.0
    return Simulator(dataclasses.replace(scene, v0=v0, settle_time=0.0))


def dropped_cube(**overrides):
    """cube-slide 3 cm above the ground (falls 78 ms, lands at 0.77 m/s sliding at 1 m/s)."""
    scene = load_scene("cube-slide")
    q0 = scene.q0.copy()
    q0[2] += 0.03
    return Simulator(dataclasses.replace(scene, q0=q0), **overrides)


@pytest.fixture(scope="module")
def uphill():
    sim = spinning_uphill()
    traj = sim.rollout(0.3)
    return sim, traj, sim.summary(traj)


@pytest.fixture(scope="module")
def dropped():
    sim = dropped_cube(dt=4e-3)  # a coarse step: the landing sinks in by ~v dt
    traj = sim.rollout(0.3)
    return sim, traj, sim.summary(traj)


# ------------------------------------------------------------------ tests

def test_every_key_is_covered(uphill):
    """The keys this file checks are the keys summary emits: a new key needs a test here."""
    assert set(uphill[2]) == KEYS


def test_identity_keys_are_the_inputs():
    """scene, mode, formulation, dt, settle_time, contacts: what the scene file and the overrides
    said (the file read here with tomllib; the cube has 8 corner spheres)."""
    with open(SCENES_DIR / "cube-incline-slip.toml", "rb") as f:
        cfg = tomllib.load(f)
    for overrides, mode in (({}, "timestep"), ({"mode": "ode", "dt": 5e-4, "delta": 2e-3}, "rk4"),
                            ({"mode": "adaptive", "dt": 1e-3, "delta": 2e-3}, "adaptive"),
                            ({"formulation": "ccp", "dt": 2e-3}, "timestep")):
        sim = Simulator("cube-incline-slip", **overrides)
        s = sim.summary(sim.rollout(0.12))
        assert s["scene"] == cfg["name"] == "cube-incline-slip"
        assert s["mode"] == mode
        assert s["formulation"] == overrides.get("formulation", "exact")
        assert s["dt"] == overrides.get("dt", cfg["dt"])
        assert s["settle_time"] == cfg["settle_time"] == 0.1
        assert s["contacts"] == 8


@pytest.mark.parametrize("record_every", [1, 7, 8])
def test_duration_and_steps_count_the_rollout(record_every):
    """duration: the simulated time asked for; steps: the number of steps taken (0.21 s / 3 ms =
    70), whatever the recording interval; recorded_steps: the records after the first, the last
    being the final state even when 70 is no multiple of record_every (8: 8 records 8 steps
    apart, then one 6 steps on). (Before, steps counted records: 10 here with record_every = 7;
    and with 8 the trajectory ended at step 64, its duration 0.192 s.) The adaptive mode records
    every step."""
    sim = Simulator("cube-slide", dt=3e-3)
    traj = sim.rollout(0.21, record_every=record_every)
    s = sim.summary(traj)
    assert s["duration"] == pytest.approx(0.21, abs=1e-12)
    assert s["steps"] == 70 and s["recorded_steps"] == -(-70 // record_every)
    again = sim.summary(sim.rollout(0.21, record_every=record_every))  # continues from t = 0.21 s
    assert again["duration"] == pytest.approx(0.21, abs=1e-12) and again["steps"] == 70
    sim = Simulator("cube-slide", mode="adaptive", dt=1e-3, delta=2e-3)
    traj = sim.rollout(0.05)
    s = sim.summary(traj)
    assert s["steps"] == s["recorded_steps"] == len(traj.t) - 1 and np.diff(traj.t).min() < np.diff(traj.t).max()


def test_max_penetration_is_the_deepest_sphere_below_its_ground():
    """A soft penalty ground (K = 1e3 N/m: m g / (4 K) = 2.5 mm at rest) under the sliding cube
    sinks its corners in by ~8 mm: max_penetration is the deepest gap below zero, from the corner
    centres' heights (Pinocchio) at every step's start (where time stepping detects contacts and
    records gaps), and it is what the warning reports (above PENETRATION_WARNING)."""
    sim = Simulator("cube-slide", formulation="penalty", penalty_stiffness=1e3)
    traj = sim.rollout(0.3)
    s = sim.summary(traj)
    gaps = np.array([sphere_gaps(sim, q) for q in traj.q[:-1]])
    np.testing.assert_allclose(traj.gaps[1:], gaps, atol=1e-12)  # records 1.. hold these
    deepest = -gaps.min()
    assert deepest > 2 * PENETRATION_WARNING  # the scene does what it is for
    assert s["max_penetration"] == pytest.approx(deepest, rel=1e-9)
    assert len(s["warnings"]) == 1 and f"{deepest:.3g} m" in s["warnings"][0]


def test_max_penetration_is_zero_without_penetration():
    """A cube resting on its corners (gaps ~1e-16 m): no penetration, no warning."""
    sim = Simulator("cube-incline-stick")
    traj = sim.rollout(0.05)
    s = sim.summary(traj)
    gaps = np.array([sphere_gaps(sim, q) for q in traj.q])
    assert s["max_penetration"] == pytest.approx(max(0.0, -gaps.min()), abs=1e-12)
    assert s["max_penetration"] <= 1e-12 and s["warnings"] == []


def test_base_and_body_drift_from_pinocchio(uphill):
    """base_drift: |base(end) - base(settle)|; max_body_drift: the largest |body(t) - body(settle)|
    after settling. The cube rises ~5 cm and slides back ~1 cm by 0.3 s, so the two differ."""
    sim, traj, s = uphill
    after = after_settling(traj, sim.scene.settle_time)
    pos = np.array([free_body_positions(sim, q)[0] for q in traj.q])
    i0 = np.nonzero(after)[0][0]
    displacement = np.linalg.norm(pos[after] - pos[i0], axis=1)
    assert s["base_drift"] == pytest.approx(np.linalg.norm(pos[-1] - pos[i0]), rel=1e-12)
    assert s["max_body_drift"] == pytest.approx(displacement.max(), rel=1e-12)
    assert displacement.max() > displacement[-1] + 0.005 and displacement[-1] > 0.02  # the scene's shape


def test_max_body_drift_over_several_bodies():
    """two-cube-stack with the top cube launched at 0.4 m/s (it slides 1.6 cm on the lower one,
    measured from t = 0): the largest drift is the top cube's, the root body's far smaller."""
    scene = load_scene("two-cube-stack")
    v0 = scene.v0.copy()
    v0[-6] = 0.4
    sim = Simulator(dataclasses.replace(scene, v0=v0, settle_time=0.0))
    traj = sim.rollout(0.3)
    s = sim.summary(traj)
    after = after_settling(traj, 0.0)
    pos = np.array([free_body_positions(sim, q) for q in traj.q])  # (N, 2, 3)
    i0 = np.nonzero(after)[0][0]
    drift = np.linalg.norm(pos[after] - pos[i0], axis=-1).max(axis=0)
    assert drift[1] > 10 * drift[0] and drift[1] > 1e-3
    assert s["max_body_drift"] == pytest.approx(drift.max(), rel=1e-12)
    assert s["base_drift"] == pytest.approx(np.linalg.norm(pos[-1, 0] - pos[i0, 0]), rel=1e-9, abs=1e-15)


def test_mean_acceleration_along_slope_is_the_fit_of_the_world_velocity(uphill):
    """The least-squares slope of the base's world-frame x velocity (Pinocchio oMi R v) after
    settling; the spin turns the body frame, so its body-frame x is a different line."""
    sim, traj, s = uphill
    after = after_settling(traj, sim.scene.settle_time)
    vx = np.array([base_world_velocity(sim, q, v)[0] for q, v in zip(traj.q[after], traj.v[after])])
    t = traj.t[after]
    tc = t - t.mean()
    slope = float((tc * (vx - vx.mean())).sum() / (tc * tc).sum())
    assert s["mean_acceleration_along_slope"] == pytest.approx(slope, rel=1e-9)
    body_slope = float((tc * (traj.v[after, 0] - traj.v[after, 0].mean())).sum() / (tc * tc).sum())
    assert abs(body_slope - slope) > 0.1 * abs(slope)  # the frames differ here


def test_expected_sliding_acceleration_from_the_scene_file():
    """g (sin th - mu cos th) from the TOML's slope and mu when positive, else 0; g sin th when
    every contact is frictionless (mu = 0). (0.15 s: past the scenes' settle_time of 0.1 s, which
    summary requires.)"""
    for name in ("cube-incline-slip", "cube-incline-stick", "cube-slide"):
        with open(SCENES_DIR / f"{name}.toml", "rb") as f:
            ground = tomllib.load(f)["ground"]
        th, mu = math.radians(ground.get("slope_deg", 0.0)), ground["mu"]
        sim = Simulator(name)
        s = sim.summary(sim.rollout(0.15))
        assert s["expected_sliding_acceleration"] == pytest.approx(max(0.0, G * (math.sin(th) - mu * math.cos(th))),
                                                                   rel=1e-12, abs=1e-15)
    with open(SCENES_DIR / "cube-incline-slip.toml", "rb") as f:
        cfg = tomllib.load(f)
    cfg["contacts"]["model"] = "frictionless"  # the ground's mu stays 0.5; the contacts have none
    sim = Simulator(build_scene(cfg, base_dir=SCENES_DIR))
    assert sim.scene.mu == 0.5
    s = sim.summary(sim.rollout(0.15))
    assert s["expected_sliding_acceleration"] == pytest.approx(G * 0.5, rel=1e-12)
    slip = Simulator("cube-incline-slip")
    assert slip.summary(slip.rollout(0.15))["expected_sliding_acceleration"] == pytest.approx(
        G * (0.5 - 0.5 * math.cos(math.radians(30))), rel=1e-12)


def test_foot_slip_and_displacement_from_pinocchio(uphill):
    """max_foot_slip: over the corners that stay closed after settling, the largest integral of
    the contact point's tangential speed (Pinocchio frame velocity moved to the point, times the
    step); max_foot_displacement: the largest horizontal move of such a corner's centre from
    where it was at the settle time. The spin makes the four corners' numbers differ."""
    sim, traj, s = uphill
    after = after_settling(traj, sim.scene.settle_time)
    idx = np.nonzero(after)[0]
    gaps = np.array([sphere_gaps(sim, traj.q[k - 1]) for k in idx[1:]])  # each step's start; record 0 left out
    closed = (gaps <= CLOSED_GAP).all(axis=0)
    assert closed.sum() == 4  # the bottom corners
    slip = np.zeros(closed.sum())
    for k in idx[1:]:
        vel = contact_point_velocities(sim, traj.q[k - 1], traj.q[k], traj.v[k])[closed]
        slip += np.linalg.norm(vel[:, :2], axis=1) * traj.dt[k]
    assert slip.max() > 1.1 * slip.min()  # the corners slide different distances
    assert s["max_foot_slip"] == pytest.approx(slip.max(), rel=1e-9)
    centres = np.array([sphere_centres(sim, traj.q[k])[closed] for k in idx])
    disp = np.linalg.norm(centres[:, :, :2] - centres[0, :, :2], axis=-1)
    assert disp.max(axis=0).max() > 1.05 * disp.max(axis=0).min()
    assert s["max_foot_displacement"] == pytest.approx(disp.max(), rel=1e-12)


def test_max_normal_velocity_while_sliding_under_ccp():
    """CCP lifts a sliding corner at mu times its sliding speed (paper §4.5): the largest |v_n|
    of a slipping contact, from Pinocchio's contact point velocities, is ~0.5 m/s at the start
    and falls as the cube slows."""
    sim = Simulator("cube-slide", formulation="ccp")
    traj = sim.rollout(0.1)
    s = sim.summary(traj)
    slipping = traj.states[1:] == 2
    vn = np.array([contact_point_velocities(sim, traj.q[k - 1], traj.q[k], traj.v[k])[:, 2]
                   for k in range(1, len(traj.t))])
    want = np.abs(vn[slipping]).max()
    assert want > 0.3 and np.abs(vn[slipping]).min() < 0.5 * want
    assert s["max_normal_velocity_while_sliding"] == pytest.approx(want, rel=1e-9)
    # the lifted corners do not stay closed (gap <= 1e-4 m at every step's start): no foot slip
    # is measured on them
    gaps = np.array([sphere_gaps(sim, q) for q in traj.q[:-1]])
    assert not (gaps <= CLOSED_GAP).all(axis=0).any() and gaps.min(axis=0)[0] <= 1e-9
    assert s["max_foot_slip"] == 0.0 and s["max_foot_displacement"] == 0.0


def test_max_normal_velocity_counts_only_slipping_contacts(dropped):
    """The dropped cube's corners come within the activation distance falling at ~0.77 m/s (open,
    not slipping); once down they slide, v_n at most 0.044 m/s (the landing step): only those count."""
    sim, traj, s = dropped
    vn = np.array([contact_point_velocities(sim, traj.q[k - 1], traj.q[k], traj.v[k])[:, 2]
                   for k in range(1, len(traj.t))])
    slipping = traj.states[1:] == 2
    active_open = (traj.states[1:] == 0) & (traj.rows[1:] > 0)
    falling = np.abs(traj.contact_velocity[1:, :, 2][active_open]).max()
    assert slipping.any() and falling > 0.5
    assert s["max_normal_velocity_while_sliding"] == pytest.approx(np.abs(vn[slipping]).max(), abs=1e-12)
    assert s["max_normal_velocity_while_sliding"] < 0.1 * falling  # 0.044 m/s: the landing step's


def test_timing_keys_mean_is_total_time_over_steps_and_median_beside_it(dropped):
    """us_per_step: the C++ step timer's total over the rollout / the steps taken (every step is recorded);
    us_per_phase likewise per phase; median_us_per_step and median_us_per_phase: the median step."""
    _, traj, s = dropped
    t = traj.timings[1:]
    assert s["steps"] == len(t) == 75  # 0.3 s at dt = 4 ms, every step recorded
    assert s["us_per_step"] == pytest.approx(t[:, 4].sum() / s["steps"], rel=1e-12)
    assert s["median_us_per_step"] == np.median(t[:, 4])
    phases = ("kinematics", "delassus", "solve", "integrate")
    assert s["us_per_phase"] == pytest.approx({p: t[:, k].sum() / s["steps"] for k, p in enumerate(phases)}, rel=1e-12)
    assert s["median_us_per_phase"] == {p: np.median(t[:, k]) for k, p in enumerate(phases)}
    # the phases are parts of the step: their means add up to at most the step's mean
    assert sum(s["us_per_phase"].values()) <= s["us_per_step"] * (1 + 1e-12)


def test_us_per_step_counts_slow_steps_in_full(dropped):
    """A rollout whose steps take 1 us but one in ten takes 100 us costs 10.9 us a step (total / steps),
    although its median step is 1 us: the summary says both (timings set by hand, the rest as simulated)."""
    sim, traj, _ = dropped
    timings = np.ones_like(traj.timings)
    timings[1::10] = 100.0  # records 1, 11, ..., 71: 8 of the 75 steps
    s = sim.summary(dataclasses.replace(traj, timings=timings))
    assert s["us_per_step"] == pytest.approx((67 * 1.0 + 8 * 100.0) / 75, rel=1e-12)
    assert s["median_us_per_step"] == 1.0
    assert s["us_per_phase"]["solve"] == pytest.approx((67 + 800) / 75, rel=1e-12)
    assert s["median_us_per_phase"]["solve"] == 1.0


def test_convergence_keys_from_the_solver_results():
    """Three NSGS sweeps per solve leave the 10 steps after the landing unsolved (the fall, with no
    contact, and the slide after them converge): the summary's convergence keys against each
    step's SolverResult, read by a callback after every step."""
    sim = dropped_cube(max_iterations=3, solver="nsgs")
    seen = []

    def after_previous_step(s):
        if s.data.t > 0.0:
            r = s.data.result
            seen.append((s.data.t, bool(r.converged), float(r.residual)))

    traj = sim.rollout(0.19, callback=after_previous_step)
    r = sim.data.result
    seen.append((sim.data.t, bool(r.converged), float(r.residual)))
    s = sim.summary(traj)
    t, converged, residual = (np.array(x) for x in zip(*seen))
    assert len(t) == s["steps"] == 190
    assert 0 < (~converged).sum() < len(t) and converged[-1]  # the run does what it is for
    assert s["all_converged"] is False
    assert s["unconverged_steps"] == (~converged).sum()
    assert s["first_unconverged_t"] == pytest.approx(t[~converged][0], abs=1e-12)
    assert s["max_residual"] == pytest.approx(residual.max(), rel=1e-12)
    assert len(s["warnings"]) == 1 and f"{(~converged).sum()} of 190 steps" in s["warnings"][0]
    ok = Simulator("cube-slide")
    s = ok.summary(ok.rollout(0.05))
    assert s["all_converged"] is True and s["unconverged_steps"] == 0 and s["first_unconverged_t"] is None


def test_rows_per_contact_and_contact_rows(dropped):
    """Rows a contact uses: 3 (spatial) once its gap closes, 0 for the top corners that never
    touch; contact_rows the most rows of one step: the 4 bottom corners x 3. The cube falls for
    the first ~78 ms, so every corner starts without rows. With mu = 0 each contact has 1 row."""
    sim, traj, s = dropped
    gaps = np.array([sphere_gaps(sim, q) for q in traj.q[:-1]])  # each step's start
    touches = (gaps <= 1e-6).any(axis=0)
    assert touches.sum() == 4 and (gaps[0] > 0.01).all()  # falling at first
    assert s["rows_per_contact"] == [3 if x else 0 for x in touches]
    assert s["contact_rows"] == 3 * 4
    sim = dropped_cube(dt=4e-3, mu=0.0)
    traj = sim.rollout(0.3)
    s = sim.summary(traj)
    touches = (np.array([sphere_gaps(sim, q) for q in traj.q[:-1]]) <= 1e-6).any(axis=0)
    assert s["rows_per_contact"] == [1 if x else 0 for x in touches] and s["contact_rows"] == 4


def test_rows_per_contact_is_the_most_over_the_run():
    """The cube tossed up at 1 m/s: its bottom corners start on the ground (3 rows in the first
    step) and end in the air (none): rows_per_contact still lists 3 for them."""
    scene = load_scene("cube-slide")
    v0 = scene.v0.copy()
    v0[2] = 1.0
    sim = Simulator(dataclasses.replace(scene, v0=v0))
    traj = sim.rollout(0.1)
    s = sim.summary(traj)
    gaps = np.array([sphere_gaps(sim, q) for q in traj.q[:-1]])
    assert (gaps[-1] > 0.02).all()  # up in the air at the end
    assert s["rows_per_contact"] == [3 if x else 0 for x in (gaps <= 1e-9).any(axis=0)] == [3, 0] * 4
    assert s["contact_rows"] == 12


# ------------------------------------------------------------------ the joints' keys (docs/joint-rows.md)

def test_joint_keys_from_the_trajectory_and_the_model():
    """max_limit_overshoot, max_joint_drift, max_effort_ratio and saturated_steps recomputed from the
    trajectory and the Pinocchio model's limits: with the joints' rows on (the limit holds: overshoot ~0)
    and off (the elbow passes its limit, and nothing enforced it: 0 reported, the limit being off)."""
    for joint_limits in (True, False):
        sim = Simulator("ur5-joint-limit", joint_limits=joint_limits, duration=2.5)
        traj = sim.rollout()
        s = sim.summary(traj)
        model = sim.scene.model
        lower, upper = model.lowerPositionLimit, model.upperPositionLimit
        over = max(0.0, float(np.max(traj.q - upper)), float(np.max(lower - traj.q)))
        assert s["max_limit_overshoot"] == (over if joint_limits else 0.0)
        if not joint_limits:
            assert over > 0.05  # (it did pass the limit)
        after = int(np.argmax(traj.t >= sim.scene.settle_time - 1e-12))
        assert s["max_joint_drift"] == float(np.abs(traj.q[after:] - traj.q[after]).max())
        effort = model.effortLimit
        ratio = np.abs(traj.tau[1:]) / effort
        assert s["max_effort_ratio"] == pytest.approx(float(ratio.max()), rel=1e-15)
        assert s["saturated_steps"] == int((ratio >= 1.0).any(axis=1).sum())
    sim = Simulator("solo12-effort-limit")
    traj = sim.rollout()
    s = sim.summary(traj)
    tau = np.abs(traj.tau[1:, 6:])
    assert s["max_effort_ratio"] == 1.0 and s["saturated_steps"] == int((tau >= 2.7).any(axis=1).sum()) > 10
