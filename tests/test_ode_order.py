"""Observed order of the ODE modes on smooth problems (no contact changes): the final state's error
against a run of the same method at a step 8 times finer, at dt, dt/2, dt/4; the order is log2 of
successive error ratios. RK4 must be 4th order and the adaptive mode's Bogacki-Shampine pair (run
at fixed steps: a tolerance so loose that every step of dt is accepted) 3rd order on its
high-order solution, free flyers included (their configuration is on SE(3): the stages combine
Lie-algebra increments with the dexp^-1 correction, Runge-Kutta-Munthe-Kaas). Before, both gave
order 2 on a tumbling free body."""
import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from stiction.scene import load_scene
from stiction.simulator import Simulator

STEPS = (4e-3, 2e-3, 1e-3)
REFERENCE = 1.25e-4  # the finest step / 8: its error is 8^p times smaller than the finest run's


def final_state(scene, mode, dt, T, q0, v0, **overrides):
    extra = {"ode_tolerance": 1e6} if mode == "adaptive" else {}  # every step of dt accepted
    sim = Simulator(scene, mode=mode, dt=dt, tolerance=1e-14, **extra, **overrides)
    sim.set_state(q=q0, v=v0)
    traj = sim.rollout(T, record_every=int(round(T / dt)))
    assert traj.t[-1] == pytest.approx(T, abs=1e-12) and np.allclose(np.diff(traj.dt[1:]), 0.0)
    return traj.q[-1], traj.v[-1]


def observed_orders(scene, mode, T, q0, v0, **overrides):
    """log2(e(dt) / e(dt / 2)) for dt = 4 ms and 2 ms, e the error of the state at T (a multiple
    of every step; configuration by Pinocchio's difference, so a free flyer's is its SE(3) log,
    then velocity)."""
    q_ref, v_ref = final_state(scene, mode, REFERENCE, T, q0, v0, **overrides)
    errors = []
    for dt in STEPS:
        q, v = final_state(scene, mode, dt, T, q0, v0, **overrides)
        errors.append(np.linalg.norm(np.concatenate([pin.difference(scene.model, q_ref, q), v - v_ref])))
    return np.log2(np.array(errors[:-1]) / np.array(errors[1:])), errors


def anchored_rod():
    """rod-pendulum 2 mm off its pivot (the anchor's Baumgarte term acts), delta = 0.02 s, over
    1 s (over 0.2 s the relaxation's damped oscillation, zeta = 1/2, is not yet resolved at 4 ms:
    the first ratio read 3.4 there, 3.8 and 3.9 at finer steps)."""
    scene = load_scene("rod-pendulum")
    q0 = scene.q0.copy()
    q0[0] += 0.002
    return scene, 1.0, q0, scene.v0, {"delta": 0.02}


def tumbling_rod():
    """The same rod without its anchor, thrown spinning about an axis off its principal ones
    (axisymmetric: it precesses; gravity on the translation)."""
    scene = load_scene("rod-pendulum")
    free = dataclasses.replace(scene, anchors=[])
    return free, 0.2, scene.q0, np.array([0.3, -0.2, 0.5, 2.0, 5.0, -3.0]), {}


def flying_solo():
    """Solo-12 in the air (a free flyer and 12 revolute joints, no contact, no PD: its stiff light
    legs would need a smaller step), thrown upwards turning, its legs swinging."""
    scene = load_scene("solo12-stand")
    zero = np.zeros(scene.model.nv)
    scene = dataclasses.replace(scene, contacts=[], kp=zero, kd=zero)
    v0 = np.zeros(scene.model.nv)
    v0[:6] = [0.2, 0.1, 1.0, 1.5, -2.0, 0.8]
    v0[6:] = np.linspace(-3.0, 3.0, scene.model.nv - 6)
    return scene, 0.2, scene.q0, v0, {}


def swinging_ur5():
    """A revolute chain alone (UR5, fixed base, its tool contact and PD removed; gravity fed
    forward), swinging: every joint's group commutes, so the correction must change nothing there
    (this case was 4th order before too: it guards the abelian path)."""
    scene = load_scene("ur5-push-wall")
    zero = np.zeros(scene.model.nv)
    scene = dataclasses.replace(scene, contacts=[], kp=zero, kd=zero)
    v0 = np.linspace(-1.0, 1.5, scene.model.nv)
    return scene, 0.2, scene.q0, v0, {}


CASES = {"anchored-rod": anchored_rod, "tumbling-rod": tumbling_rod, "flying-solo": flying_solo,
         "ur5-chain": swinging_ur5}


@pytest.mark.parametrize("case", list(CASES))
def test_rk4_is_fourth_order(case):
    scene, T, q0, v0, overrides = CASES[case]()
    orders, errors = observed_orders(scene, "rk4", T, q0, v0, **overrides)
    assert errors[-1] > 1e-13, errors  # above rounding: the ratios measure the method
    assert (orders >= 3.7).all(), (orders, errors)


@pytest.mark.parametrize("case", ["anchored-rod", "tumbling-rod", "flying-solo"])
def test_bogacki_shampine_is_third_order(case):
    scene, T, q0, v0, overrides = CASES[case]()
    orders, errors = observed_orders(scene, "adaptive", T, q0, v0, **overrides)
    assert errors[-1] > 1e-13, errors
    assert (orders >= 2.8).all(), (orders, errors)
