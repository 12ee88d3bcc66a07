"""Record 0 of a trajectory is the state the rollout starts from, with that state's own contact
fields: its gaps (checked against Pinocchio's frame placements: a corner's height above the ground
z = 0 is its gap), the rows each contact has there and J v of that state; lam NaN and states -1 (no
step led there). Every path that records: the C++ loop, the Python callback loop, the adaptive
mode's loop and batched rollouts."""
import math

import numpy as np
import pinocchio as pin
import pytest

from stiction.casestudies import slide_lift
from stiction.simulator import NO_STATE, Simulator, batch_rollout

ACTIVATION = 0.02  # m, the scenes' activation distance (SimulatorSettings.activation_distance)


def pinocchio_gaps(sim, q):
    """Each sphere contact's height above the ground z = 0 minus its radius, from Pinocchio's
    frame placements (every contact of the cube scenes is on that ground: checked)."""
    model = sim.scene.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    out = []
    for c in sim.scene.contacts:
        h = sim.model.halfspaces[c.halfspace]
        assert h.frame == 0 and np.allclose(h.normal, [0, 0, 1]) and h.offset == 0.0
        out.append(data.oMf[c.frame].act(np.asarray(c.offset))[2] - c.radius)
    return np.array(out)


def recordings(sim, mode):
    """Record 0 of each recording path from the simulator's current state."""
    q, v = sim.data.q, sim.data.v
    if mode == "callback":
        return sim.rollout(2 * sim.dt, callback=lambda s: None)
    if mode == "batch":
        batch = batch_rollout([sim], 2 * sim.dt)
        assert batch.errors == [None]
        return batch.trajectories[0]
    if mode == "adaptive":
        ode = Simulator(sim.scene, mode="adaptive", dt=1e-4, delta=1e-2)
        ode.set_state(q=q, v=v)
        return ode.rollout(2e-4)
    return sim.rollout(2 * sim.dt)


PATHS = ["c++", "callback", "batch", "adaptive"]


@pytest.mark.parametrize("path", PATHS)
def test_resting_cube_first_gaps_are_its_corner_heights(path):
    """cube-slide at t = 0: four corners on the ground (gap 0), four 0.1 m up. Before, every gap
    of record 0 read 0 (the top corners too)."""
    sim = Simulator("cube-slide")
    q0 = sim.data.q
    expected = pinocchio_gaps(sim, q0)
    assert sorted(np.round(expected, 12)) == [0.0] * 4 + [0.1] * 4  # the scene as described
    traj = recordings(sim, path)
    np.testing.assert_array_equal(traj.q[0], q0)
    np.testing.assert_allclose(traj.gaps[0], expected, atol=1e-12)
    bottom = expected < ACTIVATION
    # the rows each contact has at that state: 3 (spatial friction) when active, else 0
    np.testing.assert_array_equal(traj.rows[0], np.where(bottom, 3, 0))
    # J v of the start: the bottom corners slide at the launch speed along t1 = x, no normal motion
    np.testing.assert_allclose(traj.contact_velocity[0, bottom], [[1.0, 0.0, 0.0]] * 4, atol=1e-12)
    np.testing.assert_array_equal(traj.contact_velocity[0, ~bottom], 0.0)
    # no step led to record 0: no force, no state of a solve
    assert np.isnan(traj.lam[0]).all() and (traj.states[0] == NO_STATE).all()
    # the steps' records are the steps' own (forces carried by the bottom corners)
    assert np.isfinite(traj.lam[1:]).all() and (traj.states[1:] >= 0).all()
    assert traj.lam[1, bottom, 2].sum() == pytest.approx(9.81, rel=1e-6)


@pytest.mark.parametrize("path", PATHS)
def test_dropped_cube_first_gaps_are_its_height(path):
    """The cube 5 cm above the ground: every gap of record 0 is 0.05 m or 0.15 m, no contact is
    active (beyond the 2 cm activation distance), and the body falls freely meanwhile."""
    sim = Simulator("cube-slide")
    q = sim.data.q.copy()
    q[2] += 0.05
    sim.set_state(q=q, v=np.zeros(6))
    expected = pinocchio_gaps(sim, q)
    np.testing.assert_allclose(sorted(expected), [0.05] * 4 + [0.15] * 4, atol=1e-12)
    traj = recordings(sim, path)
    np.testing.assert_allclose(traj.gaps[0], expected, atol=1e-12)
    assert (traj.rows[0] == 0).all() and (traj.contact_velocity[0] == 0.0).all()
    assert np.isnan(traj.lam[0]).all() and (traj.states[0] == NO_STATE).all()
    # the later records: the gaps the steps computed, all falling, no force yet
    assert (traj.lam[1:] == 0.0).all() and (np.diff(traj.gaps[:, 0]) <= 0.0).all()


def test_first_record_of_a_continued_rollout_is_its_own_state():
    """A second rollout starts from where the first stopped: its record 0 holds that state's gaps,
    not those of the last step's start (the cube falls 0.5 mm a step there), and no force."""
    sim = Simulator("cube-slide")
    q = sim.data.q.copy()
    q[2] += 0.05
    sim.set_state(q=q, v=np.zeros(6))
    first = sim.rollout(0.05)
    second = sim.rollout(0.01)
    np.testing.assert_array_equal(second.q[0], first.q[-1])
    expected = pinocchio_gaps(sim, second.q[0])
    assert (first.gaps[-1] - expected).min() > 4e-4  # the last step's start was higher
    np.testing.assert_allclose(second.gaps[0], expected, atol=1e-12)
    assert np.isnan(second.lam[0]).all() and (second.states[0] == NO_STATE).all()


def test_recording_the_first_state_changes_no_step():
    """The first record's detection (kinematics, coal's pair queries) leaves the steps as they were:
    the Python callback loop (one C++ rollout per step, each with its own first record) gives
    bit for bit the trajectory of the C++ loop. pile-24: boxes and balls landing on each other
    through coal pairs, whose GJK warm-starts from the pair's previous query (an extra detection
    between the steps that kept its guesses moved the bodies by 5e-11 m within 0.3 s)."""
    a = Simulator("pile-24")
    b = Simulator("pile-24")
    ta = a.rollout(0.3)
    tb = b.rollout(0.3, callback=lambda s: None)
    first_slot = len(a.scene.contacts)  # coal pair slots follow the sphere/point contacts
    assert (ta.rows[1:, first_slot:] > 0).sum() > 100
    for key in ("q", "v", "lam", "gaps", "contact_velocity", "states", "rows"):
        np.testing.assert_array_equal(getattr(ta, key), getattr(tb, key), err_msg=key)


def test_a_chunk_whose_first_record_is_dropped_skips_its_detection():
    """The callback loops step one C++ chunk at a time and drop each chunk's record 0:
    initial_contacts=False skips that record's detection (kinematics and contact queries once more
    per step: pile-24's callback rollout 170 -> 157 us a step), so record 0 keeps the gaps the last
    step wrote (those of its start, 0.5 mm higher for the falling cube), while the default measures
    the current state's; the steps after are the same either way."""
    from stiction import _core

    def falling():
        sim = Simulator("cube-slide")
        q = sim.data.q.copy()
        q[2] += 0.05
        sim.set_state(q=q, v=np.zeros(6))
        sim.rollout(0.05)
        return sim

    measured, skipped = falling(), falling()
    last_step_gaps = measured.data.gaps.copy()
    a = _core.rollout(measured.model, measured.data, 3, 1)
    b = _core.rollout(skipped.model, skipped.data, 3, 1, False)
    expected = pinocchio_gaps(measured, np.asarray(a["q"])[0])
    np.testing.assert_allclose(np.asarray(a["gaps"])[0], expected, atol=1e-12)
    np.testing.assert_array_equal(np.asarray(b["gaps"])[0], last_step_gaps)
    assert (last_step_gaps - expected).min() > 4e-4
    for key in ("q", "v", "gaps"):
        np.testing.assert_array_equal(np.asarray(a[key])[1:], np.asarray(b[key])[1:], err_msg=key)


def test_slide_lift_selects_the_four_bottom_corners():
    """The case study's "bottom corners" are the four of the cube's eight whose height at t = 0 is
    zero (Pinocchio's placements); before, record 0's gaps were all 0 and it took all eight."""
    sim = Simulator(slide_lift.SCENE)
    heights = pinocchio_gaps(sim, sim.data.q)
    expected = [c.name for c, h in zip(sim.scene.contacts, heights) if abs(h) <= 1e-9]
    assert len(expected) == 4
    run = slide_lift.slide_run("exact")
    assert run["bottom_contacts"] == expected
    # and what it measures of them: the lowest bottom corner stays on the ground while sliding
    assert math.isclose(run["max_bottom_gap"], 0.0, abs_tol=1e-9)
