"""The Simulator's Python API: overrides are checked and every one takes effect, settings are
read-only, the state is set through a checked method, durations are honest."""
import math

import numpy as np
import pytest

from stiction import _core
from stiction.bench.work_precision import slide_distance
from stiction.scene import build_scene
from stiction.simulator import OVERRIDES, Simulator, _contact_fields

G = 9.81


def test_unknown_override_names_it_and_the_closest():
    with pytest.raises(TypeError, match=r"unknown override 'durration' \(did you mean 'duration'\?"):
        Simulator("cube-slide", durration=1.0)


@pytest.mark.parametrize("key,value,exc", [
    ("dt", 0.0, ValueError), ("dt", -1e-3, ValueError), ("dt", math.nan, ValueError), ("dt", "1e-3", TypeError),
    ("duration", math.inf, ValueError), ("mode", "rk5", ValueError), ("delta", -1.0, ValueError),
    ("zeta", 0.0, ValueError), ("mu", -0.5, ValueError), ("mu", [0.5], TypeError), ("tolerance", 0.0, ValueError),
    ("max_iterations", 0, ValueError), ("max_iterations", 2.5, ValueError), ("solver", "pgs", ValueError),
    ("ode_tolerance", -1.0, ValueError), ("warm_start", 0, ValueError), ("warm_start", "no", ValueError),
])
def test_bad_override_values(key, value, exc):
    with pytest.raises(exc, match=key):
        Simulator("cube-slide", **{key: value})


def test_every_override_takes_effect():
    base = Simulator("cube-slide")
    changed = {"dt": 5e-4, "mode": "rk4", "delta": 2e-3, "zeta": 0.7, "tolerance": 1e-9, "max_iterations": 50,
               "solver": "nsgs", "ode_tolerance": 1e-5, "warm_start": False}
    sim = Simulator("cube-slide", **changed)
    for key, value in changed.items():
        got = sim.settings.mode.name if key == "mode" else getattr(sim.settings, key)
        assert got == value, key
        assert got != (base.settings.mode.name if key == "mode" else getattr(base.settings, key))
    assert Simulator("cube-slide", mode="ode").settings.mode.name == "rk4"
    assert Simulator("cube-slide", duration=0.25).rollout().t[-1] == pytest.approx(0.25)
    assert set(OVERRIDES) == {"dt", "duration", "mode", "delta", "zeta", "mu", "tolerance", "max_iterations",
                              "solver", "ode_tolerance", "warm_start", "formulation", "pyramid_facets", "pyramid_inscribed",
                              "penalty_stiffness", "penalty_damping", "rigid_body_passes", "joint_limits",
                              "joint_friction", "joint_damping", "effort_limits"}
    for key in ("joint_limits", "joint_friction", "joint_damping", "effort_limits"):
        assert getattr(base.settings, key) is True and getattr(Simulator("cube-slide", **{key: False}).settings, key) is False
        with pytest.raises(ValueError, match=key):
            Simulator("cube-slide", **{key: 1})
    # the formulation and its parameters (one formulation at a time: the others' parameters are refused)
    for name, params in (("pyramid", {"pyramid_facets": 8, "pyramid_inscribed": True}),
                         ("penalty", {"penalty_stiffness": 3e4, "penalty_damping": 2e-3})):
        sim = Simulator("cube-slide", formulation=name, **params)
        assert sim.settings.formulation == name != base.settings.formulation
        fs, default = sim.settings.formulation_settings, base.settings.formulation_settings
        for key, value in params.items():
            assert getattr(fs, key) == value != getattr(default, key), key


def test_cold_solves_take_more_iterations_for_the_same_motion():
    """warm_start=False: every step's solve starts from zero; the motion is the same (to the
    tolerance), the iterations are not."""
    warm, cold = (Simulator("cube-incline-stick", solver="nsgs", warm_start=w).rollout(0.2) for w in (True, False))
    assert np.abs(warm.q - cold.q).max() <= 1e-9
    assert cold.iterations[1:].sum() > 2 * warm.iterations[1:].sum()


def test_mu_override_changes_the_physics():
    """cube-slide (v0 = 1 m/s): symplectic time stepping stops it after slide_distance (the scheme's
    exact discrete stop; measured within 7e-16 m). v0^2 / (2 mu g) - v0 h / 2 is 2.3e-7 m (mu = 0.25)
    and 9.6e-7 m (mu = 0.8) short of it: v0 / (mu g h) = 407.75, 127.42 are no integers."""
    for mu in (0.25, 0.8):
        sim = Simulator("cube-slide", mu=mu, duration=0.6)
        traj = sim.rollout()
        expected = slide_distance(1.0, mu * G, sim.dt)
        assert abs((1.0 / (2 * mu * G) - 1.0 * sim.dt / 2) - expected) > 1e-7  # the old formula would fail
        assert abs(traj.q[-1, 0] - traj.q[0, 0] - expected) <= 1e-12
        assert all(c.mu == mu for c in sim.scene.contacts) and sim.scene.mu == mu
    assert Simulator("cube-slide").scene.contacts[0].mu == 0.5  # the scene itself is untouched


def test_mu_override_keeps_every_other_contact_field():
    """A mu override copies the contacts: every field but mu must survive (a pair's ``patch`` was
    dropped once, turning pile-24's contact patches into coal's single points)."""
    base, over = Simulator("pile-24"), Simulator("pile-24", mu=0.3)
    assert any(p.patch for p in base.scene.pairs)
    for p, q in zip(base.scene.pairs, over.scene.pairs, strict=True):
        assert (q.name, q.pair, q.max_contacts, q.model, q.patch, q.mu) == (p.name, p.pair, p.max_contacts, p.model,
                                                                           p.patch, 0.3)
    for c, d in zip(base.scene.contacts, over.scene.contacts, strict=True):
        assert (d.name, d.frame, d.radius, d.halfspace, d.model, d.mu) == (c.name, c.frame, c.radius, c.halfspace,
                                                                           c.model, 0.3)
    assert {"patch", "max_contacts", "pair", "model"} <= set(_contact_fields(_core.GeometryPairContact))
    assert {"frame", "offset", "radius", "halfspace", "model"} <= set(_contact_fields(_core.SphereContact))


def test_settings_are_read_only():
    sim = Simulator("cube-slide")
    with pytest.raises(AttributeError, match="read-only"):
        sim.settings.dt = 0.01
    with pytest.raises(AttributeError):
        sim.dt = 0.01
    assert sim.dt == 1e-3


def test_dt_override_simulates_the_requested_duration():
    sim = Simulator("cube-slide", dt=2e-3)
    traj = sim.rollout(0.1)
    assert len(traj.t) == 51 and traj.t[-1] == pytest.approx(0.1)
    assert np.allclose(np.diff(traj.t), 2e-3)


def test_duration_shorter_than_a_step_is_refused():
    sim = Simulator("cube-slide")
    with pytest.raises(ValueError, match="shorter than one step"):
        sim.rollout(4e-4)
    with pytest.raises(ValueError, match="shorter than one step"):  # half a step: it used to run 0 steps
        sim.rollout(5e-4)
    assert len(sim.rollout(6e-4).t) == 2  # rounds to one step
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="duration"):
            sim.rollout(bad)


def test_state_is_read_only_and_set_state_sets_it():
    sim = Simulator("cube-slide")
    q = sim.data.q
    with pytest.raises(ValueError, match="read-only"):  # a copy: a write would be lost, so it raises
        q[0] = 5.0
    assert sim.data.q[0] == 0.0
    quat = np.array([0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 2.0])  # a non-unit quaternion is normalised
    sim.set_state(q=quat, v=np.zeros(6), t=0.5)
    np.testing.assert_allclose(sim.data.q[3:7], [0, 0, 0, 1])
    assert sim.data.t == 0.5
    with pytest.raises(ValueError, match=r"q must have shape \(7,\)"):
        sim.set_state(q=np.zeros(6))
    with pytest.raises(ValueError, match="quaternion"):
        sim.set_state(q=np.zeros(7))
    with pytest.raises(TypeError, match="q must be"):
        sim.set_state(q="0 0 0")
    with pytest.raises(TypeError, match="real numbers"):
        sim.set_state(v=np.zeros(6, dtype=complex))
    with pytest.raises(ValueError, match="NaN"):
        sim.set_state(v=[0, 0, math.nan, 0, 0, 0])
    sim.reset()
    assert sim.data.t == 0.0 and sim.data.q[2] == pytest.approx(0.05)


def test_scene_argument_type():
    with pytest.raises(TypeError, match="scene must be"):
        Simulator(42)


# ---- the control inputs are views on the simulator's data; everything else read-only

FALLING_CUBE = {"urdf": "cube.urdf", "contacts": {"box_corners": True}, "initial": {"drop": 1.0}}


def _pushed_x(sim: Simulator, steps: int) -> float:
    """Displacement along x of the falling cube (no contact yet) after `steps` steps."""
    x0 = sim.data.q[0]
    for _ in range(steps):
        sim.step()
    return sim.data.q[0] - x0


def test_in_place_write_of_tau_ff_moves_the_body_as_whole_assignment_does():
    """A constant push F along x on a free-falling cube: time stepping (v += h F/m, then q += h v)
    gives x_n = h^2 (F/m) n (n + 1) / 2. Writing the force into sim.data.tau_ff in place must
    give exactly that, bit for bit the motion of assigning the whole array."""
    force, steps = 3.0, 20
    u = np.array([force, 0.0, 0.0, 0.0, 0.0, 0.0])
    in_place, whole, single = (Simulator(build_scene(FALLING_CUBE)) for _ in range(3))
    in_place.data.tau_ff[:] = u
    whole.data.tau_ff = u
    single.data.tau_ff[0] = force  # one entry
    m, h = in_place.scene.model.inertias[1].mass, in_place.dt
    expected = h * h * force / m * steps * (steps + 1) / 2
    got = [_pushed_x(s, steps) for s in (in_place, whole, single)]
    assert got[0] == pytest.approx(expected, rel=1e-9)
    assert got[0] == got[1] == got[2]
    np.testing.assert_array_equal(in_place.data.q, whole.data.q)


def test_a_control_view_stays_bound_to_the_simulator():
    """A view taken once keeps steering: per-step writes through it take effect, reset() writes the
    scene's control into it, and it keeps the data alive after the Simulator is gone."""
    sim = Simulator(build_scene(FALLING_CUBE))
    tau = sim.data.tau_ff
    assert isinstance(tau.base, _core.SimulatorData) and tau.flags.writeable
    m, h = sim.scene.model.inertias[1].mass, sim.dt
    forces = [1.0, -2.0, 4.0]
    x0 = sim.data.q[0]
    for f in forces:  # v_k = h / m * (f_1 + ... + f_k), x_n = h * sum v_k
        tau[0] = f
        sim.step()
    expected = h * h / m * sum(np.cumsum(forces))
    assert sim.data.q[0] - x0 == pytest.approx(expected, rel=1e-9)
    sim.data.v_target[:] = 1.0
    sim.reset()
    assert np.all(tau == 0.0) and np.all(sim.data.v_target == 0.0)  # the scene's control, in the same memory
    tau[1] = 2.0
    assert sim.data.tau_ff[1] == 2.0
    kp = Simulator("cube-slide").data.kp  # the Simulator is collected: the view holds its data
    kp[:] = 3.0
    assert np.all(kp == 3.0)


def test_simulator_data_cannot_be_replaced():
    sim = Simulator("cube-slide")
    with pytest.raises(AttributeError, match="cannot be replaced"):
        sim.data = _core.SimulatorData(sim.model)


def test_control_assignment_is_checked():
    sim = Simulator("cube-slide")
    with pytest.raises(ValueError, match=r"SimulatorData\.tau_ff needs 6"):
        sim.data.tau_ff = np.ones(5)
    with pytest.raises(ValueError, match="broadcast"):  # numpy's own check of an in-place write
        sim.data.tau_ff[:] = np.ones(5)
    with pytest.raises(ValueError, match=r"SimulatorData\.kd has NaN"):
        sim.data.kd = [0, 0, 0, 0, 0, math.nan]
    with pytest.raises(TypeError, match=r"SimulatorData\.q_target"):
        sim.data.q_target = "0 0 0"
    with pytest.raises(ValueError, match=r"SimulatorData\.tau_ff has NaN"):  # a float64 array (the fast path)
        sim.data.tau_ff = np.array([0, 0, 0, 0, 0, math.inf])
    with pytest.raises(ValueError, match=r"SimulatorData\.kd\[5\] is -0\.5: a joint gain must be >= 0"):
        sim.data.kd = [0, 0, 0, 0, 0, -0.5]
    with pytest.raises(ValueError, match=r"SimulatorData\.kp\[2\] is -1: a joint gain must be >= 0"):
        sim.data.kp = np.array([0, 0, -1.0, 0, 0, 0])  # (the fast path)
    sim.data.kd = [0, 0, 0, 0, 0, -0.0]  # -0.0 is 0
    tau = sim.data.tau_ff
    sim.data.tau_ff = [1, 2, 3, 4, 5, 6]  # a whole assignment writes into the same memory
    np.testing.assert_array_equal(tau, [1, 2, 3, 4, 5, 6])
    sim.data.tau_ff = tau[::-1]  # itself, reversed (a strided view of the same memory)
    np.testing.assert_array_equal(tau, [6, 5, 4, 3, 2, 1])
    sim.data.tau_ff = np.arange(6, dtype=">f8")  # big-endian: converted
    np.testing.assert_array_equal(tau, [0, 1, 2, 3, 4, 5])
    sim.data.tau_ff = np.arange(12.0)[::2]  # strided
    np.testing.assert_array_equal(tau, [0, 2, 4, 6, 8, 10])
    assert np.all(sim.data.kp == sim.scene.kp) and np.all(sim.data.q_target == sim.scene.q_target)


@pytest.mark.parametrize("field, index, value, shown", [
    ("tau_ff", 4, math.nan, "nan"), ("q_target", 6, math.inf, "inf"), ("v_target", 0, -math.inf, "-inf"),
    ("kp", 2, math.nan, "nan"), ("kd", 5, -1.0, "-1"), ("kp", 1, -1e-300, "-1e-300")])
def test_a_bad_value_written_into_a_control_view_stops_the_next_step_naming_it(field, index, value, shown):
    """An in-place write into a control view is not checked when it is made: the next step checks
    every control input (finite; the gains kp, kd >= 0, as the scene schema and the implicit PD
    assume) before it changes anything, and names the field and the index. (Before: a NaN ran into
    "non-finite Delassus operator", a NaN gain "mass matrix not positive definite", and a negative
    gain ran on.) The C++ loop (rollout) and a callback write alike; fixed, the simulation goes on."""
    sim = Simulator("cube-slide")
    sim.step()
    q, t = sim.data.q, sim.data.t
    getattr(sim.data, field)[index] = value
    message = rf"sim\.data\.{field}\[{index}\] is {shown} at the step from t = 0\.001: a "
    with pytest.raises(ValueError, match=message):
        sim.step()
    with pytest.raises(ValueError, match=message):
        sim.rollout(0.01)
    assert sim.data.t == t and np.array_equal(sim.data.q, q)  # nothing moved
    getattr(sim.data, field)[index] = 0.0

    def write(s):
        if s.data.t > 0.0025:
            getattr(s.data, field)[index] = value
    with pytest.raises(ValueError, match=rf"sim\.data\.{field}\[{index}\] is {shown} at the step from t = 0\.003"):
        sim.rollout(0.01, callback=write)
    getattr(sim.data, field)[index] = 0.0
    sim.rollout(0.002)
    assert sim.data.t == pytest.approx(0.005)


def test_the_last_step_s_snapshots_refuse_writes():
    """sim.data.active, .states (tuples), .timings (a read-only mapping) and .result (a SolverResult
    copied at each read: its attributes and arrays are read-only) are snapshots of the last step: a
    write into one would be lost, so it raises. (Before: lists, a dict and a writable lam, whose
    writes were silently dropped.)"""
    sim = Simulator("cube-slide")
    sim.step()
    d = sim.data
    bottom = tuple(int(i) for i in np.flatnonzero(np.abs(d.gaps) <= 1e-9))  # (the top corners: 0.1 m up)
    assert len(bottom) == 4 and d.active == bottom and len(d.states) == 8
    assert [d.states[i] for i in bottom] == [_core.ContactState.slip] * 4  # thrown at 1 m/s
    with pytest.raises(TypeError):
        d.active[0] = 5
    with pytest.raises(TypeError):
        d.states[0] = _core.ContactState.open
    with pytest.raises(AttributeError):
        d.active.append(4)
    assert set(d.timings) == {"kinematics", "delassus", "solve", "integrate", "total"}
    assert d.timings["total"] >= d.timings["solve"] > 0.0
    with pytest.raises(TypeError):
        d.timings["solve"] = 0.0
    r = d.result
    assert r.converged and r.lam.shape == r.u.shape == (12,)
    for name in ("lam", "u"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(r, name)[0] = 0.0
    with pytest.raises(AttributeError):
        r.iterations = 0
    assert np.array_equal(d.result.lam, r.lam) and d.result is not r  # a copy at each read


def test_state_and_outputs_are_read_only():
    """A write into anything but a control input would be lost: it raises."""
    sim = Simulator("cube-slide")
    sim.step()
    for name in ("q", "v", "J", "A", "b", "drift", "position_error", "gaps", "M", "tau", "nle",
                 "candidate_lambda", "contact_velocity", "pair_points", "rows"):
        a = getattr(sim.data, name)
        assert not a.flags.writeable, name
        with pytest.raises(ValueError, match="read-only"):
            a[...] = 0
    assert sim.data.A.shape == (12, 12) and sim.data.q.shape == (7,) and sim.data.candidate_lambda.shape == (3, 8)


def test_solver_of_another_formulation_is_refused():
    """Only the exact formulation uses `solver` (as stiction.solve says): another is refused, not ignored."""
    with pytest.raises(ValueError, match="solver='nsgs' picks the exact law's algorithm; the ccp formulation"):
        Simulator("cube-slide", formulation="ccp", solver="nsgs")
    assert Simulator("cube-slide", formulation="ccp").settings.solver == "default"
    assert Simulator("cube-slide", formulation="exact", solver="nsgs").settings.solver == "nsgs"


def test_summary_refuses_a_trajectory_that_ends_before_settling():
    """Drift is measured after settle_time: a run that ends before it has nothing to measure (it used
    to report 0 drift)."""
    sim = Simulator("cube-incline-slip")  # settle_time 0.1 s; the cube slides: drift is not 0
    with pytest.raises(ValueError, match=r"settle_time = 0\.1 s .* ends at t = 0\.05 s"):
        sim.summary(sim.rollout(0.05))
    sim.reset()
    assert sim.summary(sim.rollout(0.2))["base_drift"] > 0.0
