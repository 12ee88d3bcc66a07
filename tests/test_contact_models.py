"""Contact models per contact set: spatial (3 rows), planar (2), frictionless (1); mu = 0 -> 1 row."""
import math
import tomllib

import numpy as np
import pytest

from stiction import _core
from stiction.bench.work_precision import slide_distance
from stiction.resources import scenes_dir
from stiction.scene import build_scene
from stiction.scene_schema import SceneError
from stiction.simulator import Simulator

G = 9.81


def scene_dict(name: str) -> dict:
    with open(scenes_dir() / f"{name}.toml", "rb") as fh:
        return tomllib.load(fh)


def test_planar_box_stops_at_the_closed_form_with_two_rows_per_contact():
    """Symplectic time stepping stops the box after N h v0 - mu g h^2 N (N + 1) / 2, N = floor(v0 / (mu g h))
    = 203 sliding steps (slide_distance: the scheme's exact discrete answer). Measured: within 1e-16 m
    of it; v0^2/(2 mu g) - v0 h/2 is 2.7e-7 m short here (v0 / (mu g h) = 203.87 is no integer)."""
    sim = Simulator("planar-box-slide")
    model = sim.scene.model
    assert model.joints[1].shortname() == "JointModelPlanar" and (model.nq, model.nv) == (4, 3)
    h, v0, mu = sim.dt, 1.0, 0.5
    traj = sim.rollout(0.5)
    assert traj.converged[1:].all()
    d = traj.q[-1, 0] - traj.q[0, 0]
    expected = slide_distance(v0, mu * G, h)
    assert abs((v0**2 / (2 * mu * G) - v0 * h / 2) - expected) > 1e-7  # the old formula would fail
    assert abs(d - expected) <= 1e-12
    assert abs(traj.v[-1]).max() <= 1e-9  # stopped, not turning
    bottom = [k for k, c in enumerate(sim.scene.contacts) if c.offset[1] < 0]
    assert len(bottom) == 2
    assert (traj.rows[1:, bottom] == 2).all()
    assert traj.rows[1:].max() == 2
    assert np.abs(traj.lam[1:, :, 1]).max() == 0.0  # the out-of-plane slot stays 0 (record 0: no step)
    assert -traj.gaps[:, bottom].min() <= 1e-9  # the box stays on the ground
    s = sim.summary(traj)
    assert [s["rows_per_contact"][k] for k in bottom] == [2, 2]
    assert s["contact_rows"] == 4
    # both corners carry the weight: m g in total
    assert traj.lam[-1, bottom, 2].sum() == pytest.approx(G, rel=1e-9)


def test_planar_joint_q_is_normalised():
    cfg = scene_dict("planar-box-slide")
    cfg["initial"] = {"q": [0.0, 0.05, 1.05, 0.0]}
    sc = build_scene(cfg)
    assert sc.q0[2:] == pytest.approx([1.0, 0.0], abs=1e-15)
    cfg["initial"] = {"q": [0.0, 0.05, 0.0, 0.0]}
    with pytest.raises(SceneError, match=r"\(cos, sin\) pair of joint"):
        build_scene(cfg)


def slope_cube(model: str, mu: float, velocity=(0.0,) * 6) -> dict:
    return {"name": f"cube-{model}", "urdf": "cube.urdf", "duration": 1.0,
            "ground": {"slope_deg": 30.0, "mu": mu}, "contacts": {"box_corners": True, "model": model},
            "initial": {"base_velocity": list(velocity)}}


def test_frictionless_cube_slides_at_g_sin_30_with_one_row_per_contact():
    sim = Simulator(build_scene(slope_cube("frictionless", 0.5)))
    traj = sim.rollout(1.0)
    a = np.diff(traj.v[:, 0]) / sim.dt  # no rotation: the body frame is the world's
    assert np.abs(a - G * math.sin(math.radians(30))).max() <= 1e-9
    assert np.abs(traj.v[:, 3:]).max() <= 1e-9
    active = traj.rows[1:] > 0
    assert active.sum(axis=1).min() == 4  # the four bottom corners
    assert (traj.rows[1:][active] == 1).all()
    assert np.abs(traj.lam[1:, :, :2]).max() == 0.0  # (record 0: no step, NaN)
    s = sim.summary(traj)
    assert s["contact_rows"] == 4 and max(s["rows_per_contact"]) == 1
    assert s["expected_sliding_acceleration"] == pytest.approx(G * 0.5, rel=1e-15)
    assert s["mean_acceleration_along_slope"] == pytest.approx(G * 0.5, rel=1e-9)


def test_mu_zero_spatial_is_the_frictionless_row():
    """mu = 0 with model spatial: the same trajectory as frictionless, 1 row per contact."""
    spin = (1.0, 0.3, 0.0, 0.0, 0.0, 2.0)
    a = Simulator(build_scene(slope_cube("spatial", 0.0, spin))).rollout(0.5)
    b = Simulator(build_scene(slope_cube("frictionless", 0.5, spin))).rollout(0.5)
    assert np.array_equal(a.q, b.q) and np.array_equal(a.lam, b.lam, equal_nan=True)
    assert a.rows[1:].max() == 1 and np.array_equal(a.rows, b.rows)
    # the mu override reduces the rows too
    c = Simulator(build_scene(slope_cube("spatial", 0.5, spin)), mu=0.0).rollout(0.5)
    assert np.array_equal(a.q, c.q)


def test_solo12_stand_spatial_unchanged():
    default = Simulator("solo12-stand")
    cfg = scene_dict("solo12-stand")
    cfg.setdefault("contacts", {})["model"] = "spatial"
    explicit = Simulator(build_scene(cfg))
    ta, tb = default.rollout(0.6), explicit.rollout(0.6)  # (past settle_time 0.5 s: the summary measures drift)
    assert np.array_equal(ta.q, tb.q)
    feet = ta.rows[-1] > 0
    assert feet.sum() == 4 and (ta.rows[1:][ta.rows[1:] > 0] == 3).all()
    s = default.summary(ta)
    assert s["contact_rows"] == 12 and sorted(s["rows_per_contact"]) == [3, 3, 3, 3]
    assert list(default.data.rows) == list(ta.rows[-1])


def test_binding_planar_alias():
    c = _core.SphereContact()
    assert c.model == _core.ContactModel.spatial and not c.planar
    c.planar = True
    assert c.model == _core.ContactModel.planar
    c.model = _core.ContactModel.frictionless
    assert not c.planar
    p = _core.GeometryPairContact()
    assert p.model == _core.ContactModel.spatial


@pytest.mark.parametrize("change, match", [
    (lambda c: c["contacts"].update(model="sphere"), r"contacts\.model = 'sphere': must be one of spatial, planar"),
    (lambda c: c.update(walls=[{"normal": [1, 0, 0], "offset": -1.0, "model": 3}]), r"walls\[0\]\.model = 3"),
    (lambda c: c.update(joint="prismatic"), r"joint = 'prismatic': must be one of"),
    (lambda c: c.update(free_flyer=True), r"contradicts free_flyer"),
])
def test_bad_model_is_a_one_line_error(change, match):
    cfg = scene_dict("planar-box-slide")
    change(cfg)
    with pytest.raises(SceneError, match=match) as info:
        build_scene(cfg)
    assert "\n" not in str(info.value)
