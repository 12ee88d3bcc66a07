"""A controller in the loop (issue 25): rollout(callback=...) calls the callback from the C++ loop
before each step, records what the C++ rollout records, and gives bit for bit the trajectory of a
Python loop `callback(sim); sim.step()`; what the callback raises propagates as raised, the
simulator left after the steps done. No timing here: counts of work only (the costs are measured
by benchmarks/bench_control_loop.py)."""
import math

import numpy as np
import pytest

import stiction.simulator as simulator_module
from stiction import _core
from stiction.simulator import Simulator


def controller(sim):
    """A controller writing every kind of control input, in place and whole, from the state and the
    time: a sinusoidal feed-forward torque on the joints, a moving PD target on one hip, the gains
    of one knee switched at 5 ms, and a velocity target."""
    d = sim.data
    t = d.t
    nv = sim.model.nv
    d.tau_ff[6:] = 0.3 * np.sin(40.0 * t + np.arange(nv - 6))  # in place
    q_target = np.array(sim.scene.q_target, dtype=float)
    q_target[8] += 0.2 * math.sin(30.0 * t)
    d.q_target = q_target  # whole
    d.v_target[7] = 0.1 * math.cos(30.0 * t)
    if t > 0.005:
        d.kp[8] = 1.5
        d.kd[8] = 0.05
    d.tau_ff[7] -= 0.01 * d.v[7]  # reads the state too


def python_loop(sim, n_steps, every=1):
    """The reference: `callback(sim); sim.step()` in Python, reading the state and forces after the
    steps a rollout records (the first state, every `every`-th step, the last)."""
    d = sim.data
    t, q, v, lam = [d.t], [d.q], [d.v], [np.full(3 * sim.model.num_candidates, np.nan)]
    for k in range(1, n_steps + 1):
        controller(sim)
        sim.step()
        if k % every == 0 or k == n_steps:
            t.append(d.t)
            q.append(d.q)
            v.append(d.v)
            lam.append(np.asarray(d.candidate_lambda).T.reshape(-1))  # (3 x nc) -> per contact t1, t2, n
    return np.array(t), np.array(q), np.array(v), np.array(lam).reshape(len(t), -1, 3)


@pytest.mark.parametrize("every", [1, 3])
def test_the_callback_rollout_is_the_python_loop_bit_for_bit(every):
    """Solo-12 standing under a controller that writes tau_ff, q_target, v_target, kp and kd: the
    trajectory of rollout(callback=controller) equals, bit for bit, a Python loop of
    `controller(sim); sim.step()` (q, v and the contact forces after each recorded step), with
    record_every 1 and 3 (25 steps: the last record follows 1 step)."""
    n = 25
    a, b = Simulator("solo12-stand"), Simulator("solo12-stand")
    traj = a.rollout(n * a.dt, record_every=every, callback=controller)
    t, q, v, lam = python_loop(b, n, every)
    assert len(traj.t) == math.ceil(n / every) + 1
    np.testing.assert_array_equal(traj.t, t)
    np.testing.assert_array_equal(traj.q, q)
    np.testing.assert_array_equal(traj.v, v)
    np.testing.assert_array_equal(traj.lam, lam)
    np.testing.assert_array_equal(a.data.q, b.data.q)
    np.testing.assert_array_equal(a.data.tau_ff, b.data.tau_ff)
    np.testing.assert_array_equal(a.data.kp, b.data.kp)
    assert a.data.kp[8] == 1.5
    # the controller moved the robot: the comparison is not of two standing robots
    assert np.abs(traj.q[-1, 7:] - traj.q[0, 7:]).max() > 1e-4


def test_the_callback_rollout_is_one_c_plus_plus_rollout(monkeypatch):
    """The loop runs in C++: one call of the C++ rollout for the whole trajectory (the Python loop
    it replaces made one per step, plus one), and the callback runs once per step, before it."""
    calls = []
    real = _core.rollout

    def counting(*args):
        calls.append(args[2])  # n_steps
        return real(*args)

    monkeypatch.setattr(simulator_module._core, "rollout", counting)
    sim = Simulator("solo12-stand")
    seen = []
    traj = sim.rollout(10 * sim.dt, callback=lambda s: seen.append(s.data.t))
    assert calls == [10]
    np.testing.assert_allclose(seen, np.arange(10) * sim.dt, rtol=0, atol=1e-15)  # before each step
    assert len(traj.t) == 11


@pytest.mark.parametrize("steps, taken", [(2.5, 2), (2.6, 3), (3.5, 4), (1.0, 1)])
def test_a_callback_rollout_takes_round_duration_over_dt_steps(steps, taken):
    """round(duration / dt) steps (Python's rounding: 2.5 -> 2, 3.5 -> 4), the callback once before
    each, as without a callback."""
    sim, plain = Simulator("cube-slide"), Simulator("cube-slide")
    count = []
    traj = sim.rollout(steps * sim.dt, callback=lambda s: count.append(1))
    assert len(count) == taken and len(traj.t) == taken + 1
    assert sim.data.t == pytest.approx(taken * sim.dt, rel=1e-12)
    np.testing.assert_array_equal(traj.q, plain.rollout(steps * sim.dt).q)


def test_a_callback_rollout_shorter_than_a_step_is_refused():
    sim = Simulator("cube-slide")
    with pytest.raises(ValueError, match="shorter than one step"):
        sim.rollout(0.5 * sim.dt, callback=lambda s: None)


class ControllerFault(Exception):
    pass


def test_an_exception_in_the_callback_propagates_as_raised_and_the_state_is_the_steps_done():
    """The callback raises before step 8: that exception object (type, message, traceback through the
    callback) reaches the caller; the simulator is where 7 steps of the loop put it, is usable again,
    and goes on bit for bit as a simulator that took those steps."""
    sim, reference = Simulator("solo12-stand"), Simulator("solo12-stand")

    def failing(s):
        if s.data.t > 6.5 * s.dt:
            raise ControllerFault("joint 3 encoder lost")
        controller(s)

    with pytest.raises(ControllerFault, match="^joint 3 encoder lost$") as info:
        sim.rollout(20 * sim.dt, callback=failing)
    assert type(info.value) is ControllerFault
    assert any(entry.name == "failing" for entry in info.traceback)
    python_loop(reference, 7)
    assert sim.data.t == reference.data.t == pytest.approx(7 * sim.dt)
    np.testing.assert_array_equal(sim.data.q, reference.data.q)
    np.testing.assert_array_equal(sim.data.v, reference.data.v)
    # not left marked in use, and the steps go on as the reference's
    a = sim.rollout(3 * sim.dt, callback=controller)
    _, q, _, _ = python_loop(reference, 3)
    np.testing.assert_array_equal(a.q, q)


@pytest.mark.parametrize("error", [KeyboardInterrupt, StopIteration, SystemExit])
def test_base_exceptions_from_the_callback_propagate_too(error):
    sim = Simulator("cube-slide")

    def stop(s):
        raise error("stop")

    with pytest.raises(error):
        sim.rollout(10 * sim.dt, callback=stop)
    assert sim.data.t == 0.0


def test_a_step_that_fails_after_the_callback_still_names_it():
    """The callback writes a NaN into tau_ff in place at the 4th step: that step refuses it
    (ValueError naming the field) before moving anything; 3 steps were done."""
    sim = Simulator("cube-slide")

    def bad(s):
        if s.data.t > 2.5 * s.dt:
            s.data.tau_ff[2] = math.nan

    with pytest.raises(ValueError, match=r"sim\.data\.tau_ff\[2\] is nan"):
        sim.rollout(10 * sim.dt, callback=bad)
    assert sim.data.t == pytest.approx(3 * sim.dt)


def test_a_rollout_inside_the_callback_is_refused():
    """The data is in use by the rollout running the callback: a nested rollout raises (it would
    step the data under the outer loop's recording)."""
    sim = Simulator("cube-slide")
    with pytest.raises(RuntimeError, match="in use"):
        sim.rollout(5 * sim.dt, callback=lambda s: s.rollout(s.dt))
    assert sim.data.t == 0.0
    sim.rollout(2 * sim.dt)  # and released
    assert sim.data.t == pytest.approx(2 * sim.dt)


def test_the_core_rollout_refuses_a_callback_that_is_not_callable():
    sim = Simulator("cube-slide")
    with pytest.raises(TypeError, match="before_step must be callable or None, got int"):
        _core.rollout(sim.model, sim.data, 3, 1, True, 7)
    with pytest.raises(TypeError, match="callback must be callable, got int"):
        sim.rollout(3 * sim.dt, callback=7)
    assert sim.data.t == 0.0


def test_the_adaptive_mode_with_a_callback_is_the_python_loop():
    """The adaptive mode keeps its own Python loop (its step count is not known in advance): with a
    callback pushing the cube, it still equals `callback(sim); sim.step()` step for step."""
    def push(s):
        tau = np.zeros(6)
        tau[0] = 6.0 + 10.0 * s.data.t
        s.data.tau_ff = tau

    a, b = Simulator("cube-slide", mode="adaptive"), Simulator("cube-slide", mode="adaptive")
    traj = a.rollout(0.02, callback=push)
    q = [b.data.q]
    while b.data.t < 0.02 - 1e-12:
        push(b)
        b.step()
        q.append(b.data.q)
    np.testing.assert_array_equal(traj.q, np.array(q))
    assert traj.v[-1, 0] > 0.0  # the push (> mu m g) slides it


def test_the_step_function_takes_its_arguments_by_position_or_name_and_names_a_wrong_one():
    """_core.step is a C function (no Boost.Python dispatch): its arguments as before, by position or
    name; a missing, extra, repeated or unknown one, or an object of the wrong type, is a TypeError
    naming it. Two steps by name equal two by position bit for bit."""
    a, b = Simulator("cube-slide"), Simulator("cube-slide")
    _core.step(a.model, a.data)
    _core.step(sim=a.model, data=a.data)
    _core.step(b.model, b.data)
    _core.step(b.model, data=b.data)
    np.testing.assert_array_equal(a.data.q, b.data.q)
    assert a.data.t == pytest.approx(2 * a.dt)
    for args, kwargs, message in [
        ((a.model,), {}, "missing argument 'data'"), ((), {"data": a.data}, "missing argument 'sim'"),
        ((a.model, a.data, 1), {}, r"takes 2 arguments \(sim, data\), 3 given"),
        ((a.model, a.data), {"sim": a.model}, "multiple values for argument 'sim'"),
        ((a.model, a.data), {"dt": 1e-3}, "unexpected keyword argument 'dt'"),
        ((a.data, a.data), {}, "step: sim must be a stiction.SimulatorModel, got"),
        ((a.model, a.model), {}, "step: data must be a stiction.SimulatorData, got"),
    ]:
        with pytest.raises(TypeError, match=message):
            _core.step(*args, **kwargs)
    assert a.data.t == pytest.approx(2 * a.dt)  # nothing stepped


def test_a_control_attribute_cannot_be_deleted_and_reads_the_same_memory_each_time():
    sim = Simulator("cube-slide")
    with pytest.raises(AttributeError, match="SimulatorData.tau_ff cannot be deleted"):
        del sim.data.tau_ff
    first, second = sim.data.q_target, sim.data.q_target
    assert first is not second and np.shares_memory(first, second)  # a new view each read, one vector
    assert first.dtype == np.float64 and first.shape == (sim.model.nq,) and first.flags.c_contiguous
    assert first.base is sim.data  # the view holds the data alive
