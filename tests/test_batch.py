"""Batched rollouts on C++ threads and the GIL released in long calls (rollout, solve)."""
import threading

import numpy as np
import pytest

import stiction
from stiction import _core, problems
from stiction.bench.work_precision import slide_distance
from stiction.simulator import Batch, Simulator, batch_rollout


def test_a_batch_is_bit_identical_to_rollouts_one_by_one():
    scenes = ["solo12-stand", "cube-slide", "cube-incline-slip", "solo12-stand"]
    alone = [Simulator(s).rollout(0.2) for s in scenes]
    batch = batch_rollout([Simulator(s) for s in scenes], 0.2, threads=2)
    assert isinstance(batch, Batch) and batch.errors == [None] * 4
    for a, b in zip(alone, batch.trajectories):
        for key in ("t", "q", "v", "lam", "gaps", "states", "residual", "converged"):
            assert np.array_equal(getattr(a, key), getattr(b, key), equal_nan=True), key  # (lam[0]: NaN)
    with pytest.raises(ValueError, match="differ in shape"):
        batch.stacked("q")  # solo12 (19) and cubes (7) differ


def test_batch_of_initial_states_matches_the_closed_form():
    """cube-slide thrown at v0 (mu = 0.5, h = 1 ms): it stops after slide_distance, the symplectic
    scheme's exact discrete stop (measured within 2e-15 m), each run on its own thread.
    v0^2 / (2 mu g) - v0 h / 2 is 1.4e-7 to 4.6e-7 m short of it (v0 / (mu g h) is no integer)."""
    sim = Simulator("cube-slide")
    speeds = (0.5, 1.0, 1.5, 2.0)
    batch = sim.batch_rollout([(None, [v, 0, 0, 0, 0, 0]) for v in speeds], duration=0.6, threads=2)
    for v, traj in zip(speeds, batch.trajectories):
        expected = slide_distance(v, 0.5 * 9.81, 1e-3)
        assert abs((v**2 / (2 * 0.5 * 9.81) - v * 1e-3 / 2) - expected) > 1e-7  # the old formula would fail
        assert abs(traj.q[-1, 0] - traj.q[0, 0] - expected) <= 1e-12
    assert batch.stacked("q").shape == (4, 601, 7)
    assert sim.data.t == 0.0  # the simulator's own state is untouched


def test_the_last_record_is_the_final_state_whatever_record_every():
    """70 steps recorded every 8: records at steps 0, 8, ..., 64 and the final state, step 70 (before,
    the trajectory stopped at 64, 6 steps short), alike in the C++ loop, the callback loop and a
    batch; each record equal to the same step of an every-step rollout."""
    every = Simulator("cube-slide", dt=3e-3).rollout(0.21)
    recorded = list(range(0, 70, 8)) + [70]
    trajs = [Simulator("cube-slide", dt=3e-3).rollout(0.21, record_every=8),
             Simulator("cube-slide", dt=3e-3).rollout(0.21, record_every=8, callback=lambda s: None),
             batch_rollout([Simulator("cube-slide", dt=3e-3)], 0.21, record_every=8).trajectories[0]]
    for traj in trajs:
        assert traj.t[-1] == every.t[-1] == pytest.approx(0.21, abs=1e-12)
        for key in ("t", "q", "v", "lam", "gaps", "states", "residual", "converged", "dt"):
            assert np.array_equal(getattr(traj, key), getattr(every, key)[recorded], equal_nan=True), key


def test_a_failing_simulation_stops_alone_with_its_reason():
    good = Simulator("cube-slide")
    bad = Simulator("cube-slide")
    bad.data.tau_ff = np.array([1e7, 0.0, 0.0, 0.0, 0.0, 0.0])  # an absurd push: the blow-up check stops it
    batch = batch_rollout([good, bad, Simulator("cube-slide")], 0.1, threads=2)
    assert batch.errors[0] is None and batch.errors[2] is None
    assert batch.errors[1] and "diverged" in batch.errors[1]
    assert len(batch.trajectories[1].t) < len(batch.trajectories[0].t) == 101
    assert np.isfinite(batch.trajectories[1].q).all()


def test_bad_batches_are_refused():
    sim = Simulator("cube-slide")
    with pytest.raises(ValueError, match="appears twice"):
        batch_rollout([sim, sim], 0.1)
    with pytest.raises(ValueError, match="different time steps"):
        batch_rollout([sim, Simulator("cube-slide", dt=2e-3)], 0.1)
    with pytest.raises(ValueError, match="adaptive"):
        batch_rollout([Simulator("cube-slide", mode="adaptive")], 0.1)
    with pytest.raises(ValueError, match="threads"):
        batch_rollout([sim], 0.1, threads=0)
    with pytest.raises(RuntimeError, match="in use by another thread"):
        _core.batch_rollout([sim.model, sim.model], [sim.data, sim.data], 10, 1, 2)


def _runs_python_meanwhile(work) -> int:
    """How many times the main thread's Python loop ran while `work` ran in another thread."""
    done = threading.Event()

    def target():
        work()
        done.set()

    th = threading.Thread(target=target)
    count = 0
    th.start()
    while not done.is_set():
        count += 1
    th.join()
    return count


def test_the_gil_is_released_during_a_rollout_and_a_solve():
    """With the GIL held, the main thread's loop could not run at all during the C++ call. (3 s of
    Solo-12, ~15 ms of C++: a 0.5 s rollout, ~2.5 ms, once ended before a loaded machine scheduled the
    main thread at all.)"""
    sim = Simulator("solo12-stand")
    assert _runs_python_meanwhile(lambda: sim.rollout(3.0)) > 1000
    rp = problems.two_cube_stack(mass_ratio=1e4, top_velocity=(1.0, 0.0, 0.0))
    assert _runs_python_meanwhile(lambda: [stiction.solve(rp.problem, solver="nsgs") for _ in range(50)]) > 1000


def test_threads_solving_at_once_get_the_same_answers():
    rp = problems.two_cube_stack(mass_ratio=1e3, top_velocity=(1.0, 0.5, 0.0))
    expected = np.asarray(stiction.solve(rp.problem).lam)
    results = []

    def work():
        for _ in range(30):
            results.append(np.asarray(stiction.solve(rp.problem).lam))

    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(results) == 90 and all(np.array_equal(r, expected) for r in results)


def test_a_rollout_records_into_the_arrays_it_returns():
    """A rollout's arrays are views of one block it recorded into (no copy): every field, every
    record_every, the last record the simulator's own state, and each rollout its own memory."""
    sim = Simulator("solo12-stand")
    every = _core.rollout(sim.model, sim.data, 40, 1)
    q_end, v_end, t_end = np.array(sim.data.q), np.array(sim.data.v), sim.data.t
    sim2 = Simulator("solo12-stand")
    sparse = _core.rollout(sim2.model, sim2.data, 40, 7)  # steps 0, 7, ..., 35 and the last, 40
    recorded = list(range(0, 40, 7)) + [40]
    assert sparse["q"].shape == (len(recorded), sim.model.nq) and sparse["timings"].shape == (7, 5)
    for key in ("t", "q", "v", "lam", "contact_velocity", "gaps", "states", "rows", "residual", "iterations",
                "converged", "dt"):
        assert np.array_equal(sparse[key], every[key][recorded], equal_nan=True), key
        assert np.isfinite(every[key][1:]).all(), key
        # record 0, before any step: no force and no solve's state (NaN), the rest recorded
        assert np.isnan(every[key][0]).all() if key in ("lam", "states") else np.isfinite(every[key][0]).all(), key
    assert np.array_equal(every["q"][-1], q_end) and np.array_equal(every["v"][-1], v_end) and every["t"][-1] == t_end
    again = _core.rollout(sim.model, sim.data, 3, 1)
    again["q"][:] = 0.0  # its own memory: the first recording is untouched
    assert np.array_equal(every["q"][-1], q_end)


def _block(array: np.ndarray):
    """The object that owns an array's memory (a view's base, followed down to the end)."""
    while True:
        if isinstance(array, np.ndarray) and array.base is not None:
            array = array.base
        elif isinstance(array, memoryview):
            array = array.obj
        else:
            return array


def test_a_batch_records_into_the_arrays_it_returns():
    """Each simulation of a batch records into one block that its arrays are views of (no copy after
    the threads: done on one core, the copy and the blocks' layout held 2 threads to 1.5x one), each
    simulation its own block; its values those of the same rollout alone."""
    sims = [Simulator("solo12-stand") for _ in range(3)]
    recs = _core.batch_rollout([s.model for s in sims], [s.data for s in sims], 30, 1, 2)
    single = Simulator("solo12-stand")
    alone = _core.rollout(single.model, single.data, 30, 1)
    blocks = []
    for rec in recs:
        assert rec.pop("error") is None
        owners = {id(_block(a)) for a in rec.values()}
        assert len(owners) == 1 and isinstance(_block(rec["q"]), bytearray)
        blocks.append(owners.pop())
        for key in ("t", "q", "v", "lam", "gaps", "states", "residual", "converged", "dt"):
            assert np.array_equal(rec[key], alone[key], equal_nan=True), key
    assert len(set(blocks)) == 3
    recs[0]["q"][:] = 0.0  # its own memory: the other simulations' records are untouched
    assert np.array_equal(recs[1]["q"], alone["q"])
