"""The step's phase timers and the solver's stage times read the processor's time-stamp counter
(FastClock, clock.hpp), converted at a rate measured against the system's steady clock: the
recorded times must add up to the wall time they measure."""
import time

import numpy as np

from stiction import _core
from stiction.scene import load_scene
from stiction.simulator import Simulator


def test_step_timers_add_up_to_the_wall_time():
    sim = Simulator(load_scene("solo12-stand"))
    sim.rollout(0.01)
    start = time.perf_counter()
    rec = _core.rollout(sim.model, sim.data, 3000, 1)
    wall = time.perf_counter() - start
    t = np.asarray(rec["timings"])[1:]  # kinematics, delassus, solve, integrate, total (us)
    assert np.isfinite(t).all() and (t >= 0.0).all()
    # the phases are within the step; the steps within the rollout, and most of it
    assert (t[:, :4].sum(axis=1) <= t[:, 4] * (1 + 1e-9) + 1e-3).all()
    total = t[:, 4].sum() * 1e-6
    # Time is the subject here: the timers' conversion rate (counter ticks -> us) is checked
    # against the steady clock. Time spent preempted on a loaded machine lands mostly inside the
    # steps (they are most of the rollout), so both sides grow together; the lower bound allows
    # the recording between steps and stalls outside them, the upper one a 5 % rate error (a
    # wrong rate, e.g. the nominal instead of the measured frequency, is off by far more).
    assert 0.5 * wall <= total <= 1.05 * wall, (total, wall)
    # a solve's own time (its stages) is no longer than the step's solve phase
    assert sim.data.result.seconds * 1e6 <= t[-1, 2] * 1.02 + 0.5
