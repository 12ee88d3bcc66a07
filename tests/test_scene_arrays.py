"""Arrays of free bodies in scene files ([array]: a grid on the ground, a tower) and the summary's
max_body_drift."""
import numpy as np
import pytest

from stiction.scene import build_scene, load_scene
from stiction.scene_schema import SceneError
from stiction.simulator import Simulator


def test_grid_of_cubes_rests_in_place():
    sc = build_scene({"array": {"layout": "grid", "count": 5, "spacing": 0.3}, "duration": 0.2})
    assert sc.model.nv == 30 and len(sc.contacts) == 20
    xy = sc.q0.reshape(5, 7)[:, :2]
    dist = np.linalg.norm(xy[:, None] - xy[None], axis=-1)[np.triu_indices(5, 1)]
    assert dist.min() == pytest.approx(0.3)  # rows of ceil(sqrt(5)) = 3, 0.3 m apart
    assert np.allclose(sc.q0.reshape(5, 7)[:, 2], 0.05)  # resting on their bottom faces
    sim = Simulator(sc)
    s = sim.summary(sim.rollout())
    assert s["all_converged"] and s["contacts"] == 20
    assert s["max_body_drift"] <= 1e-12 and s["max_penetration"] <= 1e-12


def test_tower_of_boxes_stands_and_equals_the_bodies_list():
    tower = build_scene({"array": {"layout": "tower", "count": 4}, "duration": 0.2})
    listed = build_scene({"bodies": ["cube.urdf"] * 4, "duration": 0.2})
    np.testing.assert_array_equal(tower.q0, listed.q0)
    assert len(tower.contacts) == len(listed.contacts) == 16
    sim = Simulator(tower)
    s = sim.summary(sim.rollout())
    assert s["max_body_drift"] <= 1e-10 and s["max_penetration"] <= 1e-10
    # the top cube carries 1 weight, the bottom one's ground contacts all four
    lam = sim.rollout(0.01).lam[-1]
    assert lam[:4, 2].sum() == pytest.approx(4 * 9.81, rel=1e-6)
    assert lam[12:16, 2].sum() == pytest.approx(9.81, rel=1e-6)


def test_overlapping_grid_is_refused():
    with pytest.raises(SceneError, match="overlap"):
        build_scene({"array": {"layout": "grid", "count": 2, "spacing": 0.05}})


def test_bundled_arrays_load():
    assert len(load_scene("box-tower-20").contacts) == 80
    assert len(load_scene("cube-grid-64").contacts) == 64


def test_max_body_drift_is_the_slide_distance_of_a_sliding_cube():
    sim = Simulator("cube-slide")
    traj = sim.rollout(0.5)
    s = sim.summary(traj)
    assert s["max_body_drift"] == pytest.approx(np.linalg.norm(traj.q[-1, :3] - traj.q[0, :3]), rel=1e-12)
