"""A random pile of boxes and balls ([array] layout = "pile") and coal's contact patches between
free bodies: flat faces rest on four points, the pile is reproducible from its seed, it falls,
settles and never gains energy."""
import numpy as np
import pinocchio as pin
import pytest

from stiction.scene import PILE_MAX_BODIES, build_scene, load_scene
from stiction.scene_schema import SceneError
from stiction.simulator import Simulator

G = 9.81


def _cube_on_table(patch: bool):
    """A 1 kg cube of side 0.1 m resting on a fixed 0.4 m table box (its top at z = 0.2), both
    handled by coal as a general pair."""
    return build_scene({
        "urdf": "cube.urdf", "duration": 0.3, "contacts": {"feet": False},
        "initial": {"q": [0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 1.0]},
        "collision": {"pairs": [["cube_0", "table"]], "max_contacts": 4, "patch": patch,
                      "boxes": [{"name": "table", "size": [0.4, 0.4, 0.2], "position": [0.0, 0.0, 0.1]}]},
    })


def test_a_cube_rests_flat_on_a_box_at_the_four_corners_of_its_contact_patch():
    sim = Simulator(_cube_on_table(patch=True))
    traj = sim.rollout()
    s = sim.summary(traj)
    assert s["all_converged"] and s["max_body_drift"] <= 1e-10 and s["max_penetration"] <= 1e-10
    normal = traj.lam[-1, :, 2]
    assert np.count_nonzero(normal) == 4
    assert normal.sum() == pytest.approx(G, rel=1e-9)  # the cube's weight
    # the points are the cube's bottom corners, on the table top; the normal is up (table -> cube
    # is the pair's second -> first: coal's normal points from cube_0 to the table)
    points, normals = sim.data.pair_points.T, sim.data.pair_normals.T
    np.testing.assert_allclose(np.abs(points[:, :2]), 0.05, atol=1e-9)
    np.testing.assert_allclose(points[:, 2], 0.2, atol=1e-6)
    np.testing.assert_allclose(normals, np.tile([0.0, 0.0, -1.0], (4, 1)), atol=1e-9)
    # the four forces (not unique) balance the weight's moment about the centre
    moment = sum(np.cross(p - [0.0, 0.0, 0.25], [0.0, 0.0, f]) for p, f in zip(points, normal))
    np.testing.assert_allclose(moment, 0.0, atol=1e-9)


def test_without_patches_coal_gives_the_face_one_point():
    sim = Simulator(_cube_on_table(patch=False))
    traj = sim.rollout(0.01)
    assert np.count_nonzero(traj.lam[-1, :, 2]) == 1  # why piles need the patch


def _pile(count=24, seed=7, **array):
    return build_scene({"array": {"layout": "pile", "count": count, "seed": seed, **array}, "duration": 1.5,
                        "settle_time": 1.2})


def _pair_distances(scene, q):
    data, gdata = scene.model.createData(), scene.geometry.createData()
    pin.forwardKinematics(scene.model, data, q)
    pin.updateGeometryPlacements(scene.model, data, scene.geometry, gdata)
    return np.array([pin.computeDistance(scene.geometry, gdata, k).min_distance
                     for k in range(len(scene.geometry.collisionPairs))])


def test_a_pile_is_drawn_from_its_seed_without_overlaps():
    a, b, c = _pile(seed=7), _pile(seed=7), _pile(seed=8)
    np.testing.assert_array_equal(a.q0, b.q0)
    assert not np.allclose(a.q0, c.q0)
    kinds = [type(g.geometry).__name__ for g in a.geometry.geometryObjects]
    assert set(kinds) == {"Box", "Sphere"} and len(kinds) == 24
    # 8 corners per box, one sphere per ball against the ground; every two bodies a coal pair
    assert len(a.contacts) == 8 * kinds.count("Box") + kinds.count("Sphere")
    assert len(a.pairs) == 24 * 23 // 2 and all(p.patch for p in a.pairs)
    assert [p.max_contacts for p in a.pairs] == [
        4 if kinds[p_a] == kinds[p_b] == "Box" else 1 for p_a in range(24) for p_b in range(p_a + 1, 24)]
    assert _pair_distances(a, a.q0).min() > 0.01  # apart, and above the ground
    assert min(a.q0.reshape(-1, 7)[:, 2]) > 0.1
    quats = a.q0.reshape(-1, 7)[:, 3:]
    assert np.allclose(np.linalg.norm(quats, axis=1), 1.0) and np.abs(quats[:, :3]).max() > 0.3  # turned
    cubes = _pile(count=5, urdfs=["cube.urdf"])
    assert [type(g.geometry).__name__ for g in cubes.geometry.geometryObjects] == ["Box"] * 5


def test_a_pile_of_cubes_falls_settles_and_never_gains_energy():
    scene = _pile(count=12, seed=2, urdfs=["cube.urdf"])
    sim = Simulator(scene)
    traj = sim.rollout()
    s = sim.summary(traj)
    assert s["max_residual"] <= 1e-6
    model, data = scene.model, scene.model.createData()
    energy = np.array([pin.computeKineticEnergy(model, data, q, v) + pin.computePotentialEnergy(model, data, q)
                       for q, v in zip(traj.q[::10], traj.v[::10])])
    # the contacts dissipate; the position correction (eq. 64) may return at most a few mJ
    assert np.diff(energy).max() <= 5e-3
    assert energy[-1] < energy[0] - 1.0
    q, v = traj.q[-1], traj.v[-1].reshape(-1, 6)
    assert np.abs(v).max() <= 1e-6  # at rest
    assert _pair_distances(scene, q).min() >= -1e-6  # no two cubes overlap
    heights = q.reshape(-1, 7)[:, 2]
    assert heights.min() >= 0.05 - 1e-6 and heights.max() > 0.11  # on the ground, some on others
    assert s["max_body_drift"] <= 1e-6  # nothing creeps after settling


def test_the_bundled_pile_loads():
    scene = load_scene("pile-24")
    assert scene.model.nv == 24 * 6 and len(scene.pairs) == 276


@pytest.mark.parametrize("array, message", [
    ({"layout": "grid", "count": 2, "seed": 1}, "seed applies to layout = \"pile\" only"),
    ({"layout": "tower", "count": 2, "urdfs": ["cube.urdf"]}, "urdfs applies to layout = \"pile\" only"),
    ({"layout": "pile", "count": 2, "urdf": "cube.urdf"}, "draws its bodies from `urdfs`"),
    ({"layout": "pile", "count": PILE_MAX_BODIES + 1}, "at most"),
    ({"layout": "pile", "count": 2, "spacing": 0.1}, "could overlap"),
    ({"layout": "pile", "count": 2, "seed": -1}, "seed"),
])
def test_pile_input_errors_name_the_key(array, message):
    with pytest.raises(SceneError, match=message):
        build_scene({"array": array})


CYLINDER = """<robot name="can"><link name="can">
  <inertial><mass value="1"/><inertia ixx="1e-3" ixy="0" ixz="0" iyy="1e-3" iyz="0" izz="1e-3"/></inertial>
  <visual><geometry><cylinder radius="0.05" length="0.1"/></geometry></visual>
</link></robot>"""


def test_a_pile_refuses_bodies_that_are_neither_boxes_nor_balls(tmp_path):
    (tmp_path / "can.urdf").write_text(CYLINDER)
    with pytest.raises(SceneError, match=r"array.urdfs\[1\] = 'can.urdf': a pile's bodies must be boxes or balls"):
        build_scene({"array": {"layout": "pile", "count": 2, "urdfs": ["cube.urdf", "can.urdf"]}},
                    base_dir=tmp_path)


def test_a_pile_takes_no_collision_table():
    with pytest.raises(SceneError, match="makes its own pairs"):
        build_scene({"array": {"layout": "pile", "count": 2},
                     "collision": {"pairs": [["body0", "ground"]]}})


def test_a_redundant_contact_set_whose_right_hand_side_no_force_can_meet_is_made_consistent():
    """pile-24, step 384 (step 234 before time stepping's tangential rows carried the free flyers'
    frame turn, docs/controllers.md: the pile's chaotic trajectory changed): a tilted, moving box on
    the ground by its 4 corners (12 rows, 6 relative degrees of freedom). The normal rows' drift J'v
    and gap terms Psi / h^2 do not fit one rigid motion: b had a part in J's left null space (4.2e-9
    ||b|| at step 234 then), which no lambda can cancel (nu^T (A lambda - b)
    = -nu^T b), so the step missed the tolerance 1e-10 ||b||. The simulator removes that part from
    the set's rows (only for a step that missed) and solves again: every step converges, and the b
    it solved has no component out of J's range above a tenth of the tolerance."""
    sim = Simulator(load_scene("pile-24"))
    for _ in range(384):
        sim.step()
        assert sim.data.result.converged, (sim.data.t, sim.data.result.message)
    J, b = np.asarray(sim.data.J), np.asarray(sim.data.b)
    U, s, _ = np.linalg.svd(J)
    null = U[:, (s > 1e-10 * s[0]).sum():]
    assert null.shape[1] >= 6  # redundant rows
    assert np.linalg.norm(null.T @ b) <= 0.1 * 1e-10 * np.linalg.norm(b)
    traj = sim.rollout(0.1)  # (ends before pile-24's settle_time: no summary, whose drift would be refused)
    assert traj.converged[1:].all() and traj.residual.max() <= 1e-10
