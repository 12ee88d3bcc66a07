"""The Simulator's Python API: overrides are checked and every one takes effect, settings are
read-only, the state is set through a checked method, durations are honest."""
import math

import numpy as np
import pytest

from stiction.simulator import OVERRIDES, Simulator

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
                              "penalty_stiffness", "penalty_damping", "rigid_body_passes"}
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
    """cube-slide (v0 = 1 m/s): it stops after v0^2 / (2 mu g) - v0 h / 2 (symplectic time stepping)."""
    for mu in (0.25, 0.8):
        sim = Simulator("cube-slide", mu=mu, duration=0.6)
        traj = sim.rollout()
        expected = 1.0 / (2 * mu * G) - 1.0 * sim.dt / 2
        assert traj.q[-1, 0] - traj.q[0, 0] == pytest.approx(expected, abs=1e-6)
        assert all(c.mu == mu for c in sim.scene.contacts) and sim.scene.mu == mu
    assert Simulator("cube-slide").scene.contacts[0].mu == 0.5  # the scene itself is untouched


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
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="duration"):
            sim.rollout(bad)


def test_state_copy_semantics_and_set_state():
    sim = Simulator("cube-slide")
    q = sim.data.q
    q[0] = 5.0  # a copy: the simulator does not see it
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
