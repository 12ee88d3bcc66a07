"""Fuzz: malformed scenes and Simulator arguments (Hypothesis, derandomised so CI is repeatable).

For every mutated scene the package must either refuse it with one clear line (SceneError /
ValueError / TypeError / FileNotFoundError) or build it and simulate a few steps with a finite
trajectory whose unconverged steps are flagged, or stop with a one-line RuntimeError. Never a
crash, a hang, another exception type or a multi-line message."""
import copy
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stiction.scene import build_scene
from stiction.scene_schema import SCENE
from stiction.simulator import OVERRIDES, Simulator

BASES = [
    {"urdf": "cube.urdf", "contacts": {"box_corners": True}, "ground": {"slope_deg": 30.0, "mu": 0.6}},
    {"urdf": "ball.urdf", "contacts": {"frames": ["ball"], "radius": 0.05}, "initial": {"drop": 0.01}},
    {"bodies": ["cube.urdf", "cube.urdf"], "ground": {"mu": 0.5}},
    {"urdf": "rod.urdf", "contacts": {"feet": False},
     "anchors": [{"name": "pivot", "frame": "rod", "offset": [-0.25, 0.0, 0.0]}]},
    {"urdf": "ball.urdf", "contacts": {"feet": False}, "initial": {"q": [0.0, 0.0, 0.35, 0.0, 0.0, 0.0, 1.0]},
     "collision": {"pairs": [["ball_0", "ground"], ["ball_0", "table"]], "max_contacts": 1,
                   "boxes": [{"name": "table", "size": [0.4, 0.4, 0.2], "position": [0.0, 0.0, 0.1]}]}},
    {"urdf": "cube.urdf", "contacts": {"box_corners": True},
     "walls": [{"name": "w", "normal": [-1.0, 0.0, 0.0], "offset": -0.2, "frames": ["cube"], "radius": 0.05}]},
]

ACCEPTED = (ValueError, TypeError, FileNotFoundError)


def _paths(table, prefix=()):
    """(path, Key) for every key of the schema."""
    for k in table.keys:
        yield prefix + (k.name,), k
    for t in table.tables:
        yield from _paths(t, prefix + ((t.name, 0) if t.array else (t.name,)))


PATHS = list(_paths(SCENE))

junk = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
    st.lists(st.one_of(st.floats(-10, 10), st.just(math.nan)), max_size=8),
    st.lists(st.text(max_size=6), max_size=3),
    st.lists(st.lists(st.text(max_size=6), min_size=0, max_size=3), max_size=3),
    st.dictionaries(st.text(max_size=6), st.integers(), max_size=2),
)


def _set(cfg: dict, path: tuple, value) -> None:
    """Set cfg[path] = value, creating tables ({}) and arrays of tables ([{}]) on the way."""
    node = cfg
    for i, part in enumerate(path[:-1]):
        if isinstance(part, int):
            continue
        is_array = i + 1 < len(path) - 1 and isinstance(path[i + 1], int) or \
            (i + 1 < len(path) and isinstance(path[i + 1], int))
        nxt = node.get(part)
        if nxt is None:
            nxt = [{}] if is_array else {}
            node[part] = nxt
        if isinstance(nxt, list):
            if not nxt:
                nxt.append({})
            nxt = nxt[0]
        if not isinstance(nxt, dict):
            return
        node = nxt
    node[path[-1]] = value


@st.composite
def mutated_scenes(draw):
    cfg = copy.deepcopy(draw(st.sampled_from(BASES)))
    for _ in range(draw(st.integers(1, 2))):
        kind = draw(st.sampled_from(["junk", "unknown", "delete", "valid-number", "valid-number", "small-number"]))
        path, key = draw(st.sampled_from(PATHS))
        if kind == "junk":
            _set(cfg, path, draw(junk))
        elif kind == "valid-number":  # a plausible number anywhere: ranges must catch the bad ones
            _set(cfg, path, draw(st.floats(-1e3, 1e3)))
        elif kind == "small-number":  # in the range a user would type
            _set(cfg, path, draw(st.floats(0.0, 2.0)))
        elif kind == "unknown":
            _set(cfg, path[:-1] + (draw(st.text(min_size=1, max_size=10)),), 1.0)
        else:
            node = cfg
            for part in path[:-1]:
                node = node[0] if isinstance(part, int) and isinstance(node, list) and node else (
                    node.get(part, {}) if isinstance(node, dict) else {})
            if isinstance(node, dict):
                node.pop(path[-1], None)
    return cfg


def _one_line(exc: BaseException) -> None:
    msg = str(exc)
    assert msg and "\n" not in msg, repr(msg)
    assert "C++ signature" not in msg and "Traceback" not in msg


@settings(max_examples=150, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(mutated_scenes())
def test_malformed_scenes_are_refused_or_simulated_honestly(cfg):
    try:
        scene = build_scene(cfg)
    except ACCEPTED as exc:
        _one_line(exc)
        return
    try:
        sim = Simulator(scene)
        if 0.005 / sim.dt > 5000:  # keep the fuzz quick: tiny steps are tested for refusal only
            with pytest.raises(ValueError, match="more than one rollout takes"):
                sim.rollout(0.005 * 1e9 * sim.dt / 0.005 * 2.0)
            return
        traj = sim.rollout(0.005)
    except (*ACCEPTED, RuntimeError) as exc:
        _one_line(exc)
        return
    assert np.isfinite(traj.q).all() and np.isfinite(traj.v).all()
    if (traj.t >= scene.settle_time - 1e-12).sum() < 2:  # ends before settling: no drift to report
        with pytest.raises(ValueError, match="settle_time") as info:
            sim.summary(traj)
        _one_line(info.value)
        return
    summary = sim.summary(traj)
    assert summary["all_converged"] == bool(traj.converged[1:].all())
    assert summary["unconverged_steps"] == int((~traj.converged[1:]).sum())


override_values = st.one_of(st.none(), st.booleans(), st.integers(-5, 5), st.floats(allow_nan=True),
                            st.text(max_size=6), st.sampled_from(["rk4", "ode", "adaptive", "timestep", "nsgs"]))


@settings(max_examples=80, deadline=None, derandomize=True)
@given(st.dictionaries(st.sampled_from(sorted(OVERRIDES) + ["durration", "Dt", "solver_name"]), override_values,
                       max_size=3))
def test_simulator_overrides_fuzz(overrides):
    try:
        sim = Simulator("cube-slide", **overrides)
    except ACCEPTED as exc:
        _one_line(exc)
        return
    for key, value in overrides.items():  # accepted: every value took effect
        if key == "dt":
            assert sim.dt == value
        elif key == "duration":
            assert sim.duration == value
        elif key == "mu":
            assert all(c.mu == value for c in sim.scene.contacts)
    try:
        traj = sim.rollout(min(sim.duration, 0.003) if sim.duration >= sim.dt else sim.dt)
    except (*ACCEPTED, RuntimeError) as exc:
        _one_line(exc)
        return
    assert np.isfinite(traj.q).all()


@pytest.mark.parametrize("value", ["x", [1.0], math.nan, -1.0, 1e-30, complex(1, 1)])
def test_rollout_duration_fuzz(value):
    sim = Simulator("cube-slide")
    with pytest.raises(ACCEPTED) as info:
        sim.rollout(value)
    _one_line(info.value)


NUMERIC = [(p, k) for p, k in PATHS if k.kind == "float"]


@settings(max_examples=60, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(st.sampled_from(BASES), st.lists(st.tuples(st.sampled_from(NUMERIC), st.floats(0.0, 2.0)), min_size=1,
                                        max_size=3))
def test_plausible_numbers_build_and_simulate_or_are_refused(base, changes):
    """Numbers a user might type into any numeric key (mostly valid scenes: this drives the simulator)."""
    cfg = copy.deepcopy(base)
    for (path, _), value in changes:
        _set(cfg, path, value)
    test_malformed_scenes_are_refused_or_simulated_honestly.hypothesis.inner_test(cfg)


def test_absurd_step_counts_are_refused_before_simulating():
    sim = Simulator("cube-slide", dt=1e-300)
    with pytest.raises(ValueError, match="more than one rollout takes"):
        sim.rollout(1.0)
    with pytest.raises(ValueError, match="GB; record less often"):
        Simulator("solo12-stand", dt=1e-7).rollout(10.0)


@pytest.mark.parametrize("scene", ["solo12-stand", "pile-24", "pinch", "ur5-joint-limit"])
def test_the_recording_size_guard_counts_every_recorded_array(scene):
    # the guard's estimate must not undercount what a rollout records (the sensors added arrays)
    sim = Simulator(scene)
    traj = sim.rollout(20 * sim.model.settings.dt, record_every=3)
    recorded = sum(a.nbytes for a in vars(traj).values()
                   if isinstance(a, np.ndarray) and a.dtype.kind in "fiub" and a.ndim >= 1 and len(a) == len(traj.t))
    estimate = sim._record_bytes(20, 3)
    assert recorded <= estimate <= 2 * recorded
