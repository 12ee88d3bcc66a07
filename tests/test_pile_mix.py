"""A pile of mixed shapes in a bin ([array] layout = "pile" with `mix`, stiction.pile): the bodies'
masses against closed forms and scipy, the broad phase (sweep-and-prune, a pool of dynamic pairs)
against brute force over every pair, and a short drop."""
import itertools
import math

import coal
import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial import ConvexHull

from stiction import _core
from stiction.pile import DENSITY, SHAPES, make_shape
from stiction.scene import build_scene
from stiction.scene_schema import SceneError
from stiction.simulator import Simulator


def _mixed(count=24, seed=3, **array):
    return build_scene({"array": {"layout": "pile", "count": count, "seed": seed, "mix": list(SHAPES), **array},
                        "ground": {"mu": 0.5}, "duration": 0.5})


def _brute_force_boxes(lower, upper):
    n = lower.shape[1]
    return {(a, b) for a in range(n) for b in range(a + 1, n)
            if np.all(lower[:, a] <= upper[:, b]) and np.all(lower[:, b] <= upper[:, a])}


@pytest.mark.parametrize("seed", range(5))
def test_sweep_and_prune_finds_exactly_the_overlapping_boxes_of_all_pairs(seed):
    rng = np.random.default_rng(seed)
    n = 300
    centre = rng.uniform(-1.0, 1.0, (3, n))
    half = rng.uniform(0.01, 0.15, (3, n))
    lower, upper = centre - half, centre + half
    lower[:, 7], upper[:, 7] = -np.inf, np.inf  # a half-space: everywhere
    # two boxes that just touch along x count as overlapping
    lower[:, 11], upper[:, 11] = [0.3, 0.0, 0.0], [0.5, 0.1, 0.1]
    lower[:, 12], upper[:, 12] = [0.5, 0.05, 0.05], [0.6, 0.2, 0.2]
    found = _core._sweep_and_prune(lower, upper)
    pairs = {(int(a), int(b)) for a, b in found}
    assert len(pairs) == len(found)  # each once
    assert pairs == _brute_force_boxes(lower, upper)
    assert len(pairs) > n  # (not a vacuous check)


def _touching_pairs(scene, q, margin):
    """Every two shapes of different bodies within `margin` of each other, by coal over all pairs."""
    model, geometry = scene.model, scene.geometry
    data, gdata = model.createData(), geometry.createData()
    pin.forwardKinematics(model, data, q)
    pin.updateGeometryPlacements(model, data, geometry, gdata)
    objects = geometry.geometryObjects
    req = coal.CollisionRequest()
    req.security_margin = margin
    touching = set()
    for a, b in itertools.combinations(range(len(objects)), 2):
        if objects[a].parentJoint == objects[b].parentJoint:
            continue
        res = coal.CollisionResult()
        oMa, oMb = gdata.oMg[a], gdata.oMg[b]
        if coal.collide(objects[a].geometry, coal.Transform3s(oMa.rotation, oMa.translation), objects[b].geometry,
                        coal.Transform3s(oMb.rotation, oMb.translation), req, res):
            touching.add((a, b))
    return touching


@pytest.mark.parametrize("seed", range(3))
def test_the_broad_phase_holds_exactly_the_pairs_an_all_pairs_check_finds_in_contact(seed):
    scene = _mixed(count=40, seed=seed, pairs_per_body=12)
    sim = Simulator(scene)
    rng = np.random.default_rng(100 + seed)
    margin = sim.model.settings.activation_distance
    for _ in range(3):  # random poses packed into a small box: many bodies overlap, some the floor and walls
        q = scene.q0.copy().reshape(-1, 7)
        q[:, :3] = rng.uniform([-0.25, -0.25, -0.02], [0.25, 0.25, 0.25], (len(q), 3))
        quat = rng.normal(size=(len(q), 4))
        q[:, 3:] = quat / np.linalg.norm(quat, axis=1)[:, None]
        q = q.ravel()
        _core.build_contact_problem(sim.model, sim.data, q, np.zeros(sim.model.nv), 1e-3, 0.5)
        gaps = np.asarray(sim.data.gaps)
        held = np.asarray(sim.data.pool_pairs).astype(int)
        first_slot = {p: 4 * k for k, p in enumerate(range(len(scene.pairs)))}  # 4 slots per entry, no spheres
        in_range = {(a, b) for p, a, b in held if np.any(gaps[first_slot[p]:first_slot[p] + 4] <= margin)}
        expected = _touching_pairs(scene, q, margin)
        assert len(expected) > 40
        assert in_range == expected
        assert len({(a, b) for _, a, b in held}) == len(held)  # a pair holds one entry


def test_a_pool_too_small_for_the_pairs_in_range_is_a_loud_error():
    scene = _mixed(count=40, seed=1, pairs_per_body=1)
    sim = Simulator(scene)
    q = scene.q0.copy().reshape(-1, 7)
    q[:, :3] = np.random.default_rng(0).uniform([-0.2, -0.2, 0.0], [0.2, 0.2, 0.2], (len(q), 3))
    with pytest.raises(RuntimeError, match=r"pairs of shapes overlap .* but the pool has 40 dynamic pair entries"):
        _core.build_contact_problem(sim.model, sim.data, q.ravel(), np.zeros(sim.model.nv), 1e-3, 0.5)


def test_each_body_weighs_its_volume_of_water_with_the_inertia_of_its_solid():
    rng = np.random.default_rng(0)
    box, m, inertia, _ = make_shape("box", rng)
    a, b, c = 0.10, 0.08, 0.06
    assert m == pytest.approx(DENSITY * a * b * c, rel=1e-12)
    np.testing.assert_allclose(np.diag(inertia), m / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b]),
                               rtol=1e-12)
    _, m, inertia, _ = make_shape("sphere", rng)
    r = 0.04
    assert m == pytest.approx(DENSITY * 4 / 3 * math.pi * r ** 3, rel=1e-12)
    np.testing.assert_allclose(inertia, 0.4 * m * r * r * np.eye(3), rtol=1e-12)
    _, m, inertia, _ = make_shape("cylinder", rng)
    r, h = 0.035, 0.07
    assert m == pytest.approx(DENSITY * math.pi * r * r * h, rel=1e-12)
    np.testing.assert_allclose(np.diag(inertia), [m * (3 * r * r + h * h) / 12] * 2 + [m * r * r / 2], rtol=1e-12)
    _, m, inertia, _ = make_shape("capsule", rng)
    r, h = 0.025, 0.06  # a cylinder of length h and two half balls (their centres of mass 3 r / 8 off the caps)
    m_cyl, m_ball = DENSITY * math.pi * r * r * h, DENSITY * 4 / 3 * math.pi * r ** 3
    assert m == pytest.approx(m_cyl + m_ball, rel=1e-12)
    axial = m_cyl * r * r / 2 + 0.4 * m_ball * r * r
    across = (m_cyl * (3 * r * r + h * h) / 12
              + m_ball * (0.4 * r * r + h * h / 4 + 3 * h * r / 8))
    np.testing.assert_allclose(np.diag(inertia), [across, across, axial], rtol=1e-9)
    mesh, m, inertia, radius = make_shape("mesh", rng)
    points = np.array(mesh.points())
    hull = ConvexHull(points)
    assert m == pytest.approx(DENSITY * hull.volume, rel=1e-9)
    # its centre of mass at the origin, its inertia from scipy's hull cut into tetrahedra from the origin
    com, second = np.zeros(3), np.zeros((3, 3))
    for tri in hull.simplices:
        p = points[tri]
        vol = abs(np.linalg.det(p)) / 6
        com += vol * p.sum(0) / 4
        second += vol / 20 * (p.T @ p + np.outer(p.sum(0), p.sum(0)))  # integral of x x^T over the tetrahedron
    np.testing.assert_allclose(com / hull.volume, 0.0, atol=1e-12)
    np.testing.assert_allclose(inertia, DENSITY * (np.trace(second) * np.eye(3) - second), rtol=1e-9, atol=1e-14)
    assert radius == pytest.approx(np.linalg.norm(points, axis=1).max(), rel=0.5)


def test_a_mixed_pile_is_drawn_from_its_seed_in_its_bin_without_overlaps():
    a, b, c = _mixed(seed=3), _mixed(seed=3), _mixed(seed=4)
    np.testing.assert_array_equal(a.q0, b.q0)
    assert not np.allclose(a.q0, c.q0)
    kinds = [type(g.geometry).__name__ for g in a.geometry.geometryObjects]
    assert set(kinds[:24]) == {"Box", "Sphere", "Capsule", "Cylinder", "Convex"} and kinds[24:] == ["Box"] * 5
    assert not a.contacts and len(a.pairs) == 6 * 24 and all(p.dynamic and p.patch for p in a.pairs)
    assert _touching_pairs(a, a.q0, 0.01) == set()  # apart, off the floor and the walls
    walls = _mixed(seed=3, bin=0.5)
    x_walls = [g.placement.translation[0] for g in walls.geometry.geometryObjects if g.name in ("wall+x", "wall-x")]
    assert x_walls == pytest.approx([0.6, -0.6])  # inner faces at +-0.5 (0.2 m thick)
    assert np.abs(walls.q0.reshape(-1, 7)[:, :2]).max() < 0.5


@pytest.mark.parametrize("array,message", [
    ({"mix": ["box", "capsul"]}, "did you mean 'capsule'"),
    ({"mix": ["box"], "urdfs": ["cube.urdf"]}, "one of them"),
    ({"bin": 0.5}, "with `mix` only"),
    ({"mix": ["box"], "bin": 0.05}, "narrower than one body"),
])
def test_bad_mix_keys_are_one_line_errors(array, message):
    with pytest.raises(SceneError, match=message):
        build_scene({"array": {"layout": "pile", "count": 4, **array}})


def test_grid_takes_no_mix():
    with pytest.raises(SceneError, match="applies to layout"):
        build_scene({"array": {"layout": "grid", "count": 4, "mix": ["box"]}})


def test_a_mixed_pile_falls_into_its_bin_converged_without_sinking_or_gaining_energy():
    scene = _mixed(count=24, seed=5)
    sim = Simulator(scene)
    traj = sim.rollout(0.6, record_every=10)
    s = sim.summary(traj)
    assert s["all_converged"] and s["max_penetration"] <= 1e-3
    model, data = scene.model, scene.model.createData()
    energy = np.array([pin.computeKineticEnergy(model, data, q, v) + pin.computePotentialEnergy(model, data, q)
                       for q, v in zip(traj.q, traj.v)])
    assert np.diff(energy).max() <= 1e-2 and energy[-1] < energy[0] - 1.0
    xyz = traj.q[-1].reshape(-1, 7)[:, :3]
    bin_half = scene.geometry.geometryObjects[scene.geometry.getGeometryId("wall+x")].placement.translation[0] - 0.1
    assert np.abs(xyz[:, :2]).max() < bin_half and xyz[:, 2].min() > 0.0  # inside the bin, above its floor


def _energy(scene, q, v):
    """Kinetic + potential energy of free bodies (centre of mass at each joint), computed per body."""
    model = scene.model
    mass = np.array([model.inertias[j].mass for j in range(1, model.njoints)])
    inertia = np.array([model.inertias[j].inertia for j in range(1, model.njoints)])
    q, v = q.reshape(-1, 7), v.reshape(-1, 6)
    return float(0.5 * (mass * (v[:, :3] ** 2).sum(1)).sum() + 0.5 * np.einsum("ki,kij,kj->", v[:, 3:], inertia, v[:, 3:])
                 + 9.81 * (mass * q[:, 2]).sum())


def _checked_run(sim, steps):
    """Over the steps: how many did not converge, the largest residual, the deepest overlap, the
    energy after each; and the contacts of the last."""
    unconverged, residual, deepest, energy = 0, 0.0, 0.0, [_energy(sim.scene, sim.data.q, sim.data.v)]
    for _ in range(steps):
        _core.step(sim.model, sim.data)
        unconverged += not sim.data.all_converged_step
        residual = max(residual, sim.data.max_residual_step)
        active = list(sim.data.active)
        if active:
            deepest = max(deepest, -float(np.asarray(sim.data.gaps)[active].min()))
        energy.append(_energy(sim.scene, sim.data.q, sim.data.v))
    return unconverged, residual, deepest, np.array(energy), len(active)


@pytest.mark.parametrize("name,steps,missed,depth", [("pile-256", 300, 2, 2e-3), ("pile-1000", 200, 0, 1e-3)])
def test_the_bundled_piles_fall_converged_without_overlap_or_energy_gain(name, steps, missed, depth):
    """The claims of robots/scenes/pile-256.toml and pile-1000.toml (the whole 2 s is a benchmark's
    length, not a test's: docs/scaling.md, Piles): at most `missed` steps short of the default
    tolerance (1e-10; 400 iterations), none above 1e-8; no overlap deeper than `depth` (pile-256: 1.9 mm
    once, two cylinders meeting edge on edge, a pair whose coal patch is a single point)."""
    sim = Simulator(name)
    assert sim.scene.config["array"]["mix"] == list(SHAPES) and len(sim.scene.pairs) == 6 * sim.scene.model.njoints - 6
    unconverged, residual, deepest, energy, contacts = _checked_run(sim, steps)
    assert unconverged <= missed and residual <= 1e-8 and deepest <= depth
    assert np.diff(energy).max() <= 1e-6 * energy[0]  # the contacts only dissipate (gravity's work aside)
    assert contacts > sim.scene.model.njoints // 10  # (not vacuous: the lowest layer has landed)


def test_a_reset_pile_runs_again_as_a_fresh_one():
    """A new trajectory hands the pool's entries out afresh: the same run, bit for bit."""
    scene = _mixed(count=16, seed=2)
    sim = Simulator(scene)
    first = sim.rollout(0.3, record_every=10)
    sim.reset()
    again = sim.rollout(0.3, record_every=10)
    fresh = Simulator(scene).rollout(0.3, record_every=10)
    assert np.count_nonzero(first.rows[-1]) > 0  # (bodies in contact at the end)
    np.testing.assert_array_equal(again.q, first.q)
    np.testing.assert_array_equal(fresh.q, first.q)
