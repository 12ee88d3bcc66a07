"""`stiction bench scaling --layout pile`: the rows on a tiny pile (never a timed assertion) and the
MuJoCo twin against the scene it copies."""
import json

import numpy as np
import pytest

from stiction.bench import pile_scaling
from stiction.cli import main
from stiction.scene import build_scene

mujoco = pytest.importorskip("mujoco")


def test_pile_rows_have_the_fields_for_each_body_count(capsys):
    assert main(["bench", "scaling", "--layout", "pile", "--sizes", "5", "9", "--steps", "20", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["layout"] == "pile" and out["exponent_in"] == "bodies"
    rows = out["rows"]
    assert [r["bodies"] for r in rows] == [5, 9] and [r["scene"] for r in rows] == ["pile-mix-5", "pile-mix-9"]
    for r in rows:
        assert set(r) >= {"scene", "bodies", "contacts", "us_per_step", "median_us_per_step", "mujoco_us_per_step",
                          "all_converged", "max_penetration", "energy_drift"}
        assert r["steps"] == 20 and r["contacts"] > 0 and r["mujoco_contacts"] > 0  # (after 300 steps of fall)
        assert r["us_per_step"] > 0 and r["median_us_per_step"] > 0 and r["mujoco_us_per_step"] > 0
        # the position correction (eq. 64) may return a little energy: here < 1 mJ of ~4 J
        assert r["all_converged"] and 0 < r["max_penetration"] <= 1e-3 and r["energy_drift"] <= 1e-3
        assert r["mujoco_max_penetration"] > 0 and r["mujoco_energy_drift"] >= 0
    assert out["ratio_to_mujoco"] == pytest.approx([r["us_per_step"] / r["mujoco_us_per_step"] for r in rows])
    assert isinstance(out["exponent"], float) and isinstance(out["mujoco_exponent"], float)


def test_largest_rise_is_the_largest_later_minus_earlier_difference():
    rng = np.random.default_rng(0)
    for _ in range(20):
        e = rng.normal(size=30) + 10.0
        brute = max(max(e[j] - e[i] for i in range(30) for j in range(i, 30)), 0.0)
        assert pile_scaling.largest_rise(list(e)) == pytest.approx(brute / e[0])
    assert pile_scaling.largest_rise([5.0, 4.0, 3.0]) == 0.0


def test_the_mujoco_twin_has_the_scenes_shapes_masses_inertias_poses_and_friction():
    from stiction.bench.mujoco_twins import pile_spec

    scene = build_scene(pile_scaling.scene_config(15))
    model = pile_spec(scene).compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.nbody == 16 and model.ngeom == 15 + 5 and model.opt.timestep == scene.dt
    q0 = scene.q0.reshape(-1, 7)
    np.testing.assert_allclose(data.qpos.reshape(-1, 7)[:, :3], q0[:, :3], atol=1e-12)
    np.testing.assert_allclose(np.abs(np.sum(data.qpos.reshape(-1, 7)[:, 3:] * q0[:, [6, 3, 4, 5]], axis=1)), 1.0,
                               atol=1e-12)  # the same rotation (w first in MuJoCo)
    for j in range(1, scene.model.njoints):
        inertia = scene.model.inertias[j]
        assert model.body_mass[j] == pytest.approx(inertia.mass, rel=1e-12)
        np.testing.assert_allclose(np.sort(model.body_inertia[j]), np.linalg.eigvalsh(inertia.inertia), rtol=1e-9)
    np.testing.assert_allclose(model.geom_friction[:, 0], 0.5)
    kinds = {int(mujoco.mjtGeom.mjGEOM_BOX): "Box", int(mujoco.mjtGeom.mjGEOM_SPHERE): "Sphere",
             int(mujoco.mjtGeom.mjGEOM_CAPSULE): "Capsule", int(mujoco.mjtGeom.mjGEOM_CYLINDER): "Cylinder",
             int(mujoco.mjtGeom.mjGEOM_MESH): "Convex"}
    for go in scene.geometry.geometryObjects:  # (MuJoCo puts the world's geoms first: by name)
        geom, shape = model.geom(go.name), go.geometry
        assert kinds[int(geom.type[0])] == type(shape).__name__
        assert model.body(int(geom.bodyid[0])).name == (scene.model.names[go.parentJoint] if go.parentJoint else "world")
        if type(shape).__name__ == "Box":
            np.testing.assert_allclose(geom.size, shape.halfSide)
        elif type(shape).__name__ in ("Capsule", "Cylinder"):
            np.testing.assert_allclose(geom.size[:2], [shape.radius, shape.halfLength])
        elif type(shape).__name__ == "Sphere":
            assert geom.size[0] == shape.radius
