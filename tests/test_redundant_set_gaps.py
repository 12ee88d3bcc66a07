"""A redundant contact set (two bodies, more than 6 rows) whose contacts sit at different gaps:
the part of b that no rigid motion fits is physics (some contacts open), not rounding, and the
simulator must solve eq. 27's b as it is (projectRedundantSets removes only rounding-level parts).
pile-1000, step 505: a 0.17 kg hull by the floor (gap 19 mm) and a wall (gap 2.8 mm); a missed
step's projection rewrote the wall contact's h b to (0.47, -11.6, 5.1) m/s where J v was 2.9 m/s:
an impulse of 1 N s, +2 J, 147 rad/s and the blow-up guard."""
import numpy as np
import pinocchio as pin
import pytest

from stiction import _core
from stiction.scene import build_scene
from stiction.simulator import Simulator


def _box_by_floor_and_wall(**overrides):
    """One box (0.10 x 0.08 x 0.06 m) in a pile's bin, 5 mm above the floor, 1 mm from the inner
    face of wall-x and sliding into it at 3 m/s: the floor's and the wall's coal patches (4 + 4
    points, 24 rows between the box and the world, rank 6) at different gaps."""
    scene = build_scene({"array": {"layout": "pile", "count": 1, "seed": 0, "mix": ["box"]}, "ground": {"mu": 0.5},
                         "duration": 0.1})
    inner = next(g for g in scene.geometry.geometryObjects if g.name == "wall-x").placement.translation[0] + 0.1
    sim = Simulator(scene, **overrides)
    q = np.array([inner + 0.05 + 1e-3, 0.0, 0.03 + 5e-3, 0.0, 0.0, 0.0, 1.0])
    v = np.array([-3.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    sim.set_state(q, v, 0.0)
    return sim, q, v


def _rhs_of_state(sim, q, v):
    """eq. 27 for time stepping (delta = h, zeta = 1/2) of a body that does not turn (omega = 0: no
    drift, no frame turn): b = -J (a_free + v / h) - Psi / h^2, Psi the gap on each normal row;
    a_free from pinocchio's ABA (no contact force)."""
    model = sim.scene.model
    a_free = pin.aba(model, model.createData(), q, v, np.zeros(model.nv))
    h = sim.dt
    J = np.asarray(sim.data.J)
    gaps = np.asarray(sim.data.gaps)[list(sim.data.active)]
    psi = np.zeros(J.shape[0])
    psi[2::3] = gaps  # rows (t1, t2, n) per contact
    return -J @ (a_free + v / h) - psi / h**2


@pytest.mark.parametrize("solver,iterations", [("default", 200), ("nsgs", 2)])
def test_a_redundant_set_at_different_gaps_is_solved_with_the_right_hand_side_of_its_state(solver, iterations):
    sim, q, v = _box_by_floor_and_wall(solver=solver, max_iterations=iterations)
    _core.step(sim.model, sim.data)
    assert len(sim.data.active) == 8 and np.asarray(sim.data.J).shape[0] == 24  # 4 floor + 4 wall points
    gaps = np.asarray(sim.data.gaps)[list(sim.data.active)]
    assert gaps.min() == pytest.approx(1e-3, abs=1e-9) and gaps.max() == pytest.approx(5e-3, abs=1e-9)
    if solver == "nsgs":
        assert not sim.data.all_converged_step  # (the missed step, where the projection is tried)
    expected = _rhs_of_state(sim, q, v)
    b = np.asarray(sim.data.b)
    assert np.abs(b - expected).max() <= 1e-9 * np.abs(expected).max()


def test_the_box_sliding_into_the_wall_stops_against_it_when_solved():
    """(The converged step against the closed form: the wall's patch sticks, the box moves by
    exactly its 1 mm gap in the step, the floor 5 mm below does not act.)"""
    sim, _, _ = _box_by_floor_and_wall()
    _core.step(sim.model, sim.data)
    assert sim.data.all_converged_step
    np.testing.assert_allclose(np.asarray(sim.data.v), [-1e-3 / sim.dt, 0, 0, 0, 0, 0], atol=1e-9)
