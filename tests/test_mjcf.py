"""Robots from MJCF (stiction.mjcf, the `mjcf` scene key; docs/mjcf.md).

The models Pinocchio's parser builds are compared with MuJoCo's of the same file computed here
(nq, nv, masses, ranges, M(qpos0) from mj_fullM, geom positions from mj_forward); the scenes'
physics with Newton's law at rest (the contact forces carry m g) and the ground's geometry."""
from __future__ import annotations

import importlib.util
import math
import sys

import numpy as np
import pinocchio as pin
import pytest

from stiction import mjcf
from stiction.resources import robots_dir
from stiction.scene import build_scene, load_scene
from stiction.scene_schema import SceneError
from stiction.simulator import Simulator

HAS_MUJOCO = importlib.util.find_spec("mujoco") is not None
needs_mujoco = pytest.mark.skipif(not HAS_MUJOCO, reason="MuJoCo is not installed (pip install mujoco)")
G = 9.81
BUNDLED = ("hopper", "walker", "humanoid", "cheetah")


def bundled(name: str):
    return robots_dir() / "mjcf" / "dm_control" / f"{name}.xml"


def mujoco_model(path):
    return mjcf.mujoco_model(path)  # from_xml_path, its compiler warnings caught (no MUJOCO_LOG.TXT)


def total_mass(model) -> float:
    return float(sum(model.inertias[j].mass for j in range(model.njoints)))


# ---- the models against MuJoCo's

@needs_mujoco
@pytest.mark.parametrize("name", BUNDLED)
def test_bundled_models_have_mujocos_sizes_masses_and_ranges(name):
    robot = mjcf.load_mjcf(bundled(name))
    mj = mujoco_model(bundled(name))
    assert robot.checked and robot.differences == {}
    assert (robot.model.nq, robot.model.nv) == (mj.nq, mj.nv)
    assert abs(total_mass(robot.model) - float(mj.body_mass.sum())) <= 1e-9 * float(mj.body_mass.sum())
    limited = 0
    for j in range(mj.njnt):
        if mj.jnt_type[j] in (2, 3):  # slide, hinge: the same qpos address in both
            a = mj.jnt_qposadr[j]
            if mj.jnt_limited[j]:
                limited += 1
                assert robot.model.lowerPositionLimit[a] == pytest.approx(mj.jnt_range[j, 0], abs=1e-9)
                assert robot.model.upperPositionLimit[a] == pytest.approx(mj.jnt_range[j, 1], abs=1e-9)
            else:
                assert math.isinf(robot.model.lowerPositionLimit[a]) and math.isinf(robot.model.upperPositionLimit[a])
    assert limited >= 4


@needs_mujoco
@pytest.mark.parametrize("name", ("hopper", "walker", "cheetah"))
def test_planar_robots_have_mujocos_mass_matrix(name):
    """Slides and hinges only: the coordinates are the same in both, so M(qpos0) with armature
    from Pinocchio's crba must be MuJoCo's mj_fullM entry by entry."""
    import mujoco

    robot = mjcf.load_mjcf(bundled(name))
    mj = mujoco_model(bundled(name))
    data = mujoco.MjData(mj)
    mujoco.mj_forward(mj, data)
    M_mj = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, data, M_mj)
    M = pin.crba(robot.model, robot.model.createData(), np.array(mj.qpos0))
    M = np.triu(M) + np.triu(M, 1).T
    np.testing.assert_allclose(M, M_mj, rtol=0, atol=1e-9 * np.abs(M_mj).max())
    assert np.abs(np.diag(M_mj) - np.diag(M)).max() <= 1e-9 and robot.model.armature.max() > 0  # armature counted


@needs_mujoco
def test_humanoid_mass_matrix_in_pinocchios_free_flyer_coordinates():
    """A free joint: MuJoCo's linear velocity is in the world frame, Pinocchio's in the base's;
    at qpos0 the base is not rotated (R = I), so M agrees entry by entry there, and at a rotated
    base it agrees after v_world = R v_local."""
    import mujoco

    robot = mjcf.load_mjcf(bundled("humanoid"))
    mj = mujoco_model(bundled("humanoid"))
    data = mujoco.MjData(mj)
    angle = 0.7
    data.qpos[:] = mj.qpos0
    data.qpos[3:7] = [math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0]  # (w, x, y, z): about y
    data.qpos[10] = 0.3  # a hip joint
    mujoco.mj_forward(mj, data)
    M_mj = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, data, M_mj)
    q = np.array(data.qpos)
    q[3:7] = [0.0, math.sin(angle / 2), 0.0, math.cos(angle / 2)]  # (x, y, z, w)
    M = pin.crba(robot.model, robot.model.createData(), q)
    M = np.triu(M) + np.triu(M, 1).T
    T = np.eye(mj.nv)
    T[:3, :3] = pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix()
    np.testing.assert_allclose(M, T.T @ M_mj @ T, rtol=0, atol=1e-9 * np.abs(M_mj).max())


@needs_mujoco
def test_cheetah_settotalmass_is_applied_as_mujoco_does(tmp_path):
    """Pinocchio alone gives the density's 21.18 kg; MuJoCo without settotalmass gives the same;
    with it MuJoCo scales to 14 kg and so does the loader, every body by the same factor."""
    import mujoco

    text = bundled("cheetah").read_text()
    assert '<compiler settotalmass="14"/>' in text
    robot = mjcf.load_mjcf(bundled("cheetah"))
    flat = tmp_path / "cheetah.xml"
    flat.write_text(mjcf.flatten_mjcf(bundled("cheetah")))
    unscaled = total_mass(pin.buildModelFromMJCF(str(flat)))  # Pinocchio's parser alone
    no_total = mujoco.MjModel.from_xml_string(text.replace('<compiler settotalmass="14"/>', ""),
                                              _assets(bundled("cheetah").parent))
    assert float(no_total.body_mass.sum()) == pytest.approx(unscaled, rel=1e-9)
    assert unscaled == pytest.approx(21.1837, abs=1e-4)
    assert total_mass(robot.model) == pytest.approx(14.0, rel=1e-12)
    mj = mujoco_model(bundled("cheetah"))
    for name in ("bthigh", "bshin", "bfoot", "fthigh", "fshin", "ffoot"):  # each body's joint has its name
        assert robot.model.inertias[robot.model.getJointId(name)].mass == pytest.approx(
            float(mj.body(name).mass[0]), rel=1e-9)


def _assets(folder):
    """The files the bundled MJCFs include, for MjModel.from_xml_string."""
    return {f"./common/{p.name}": p.read_bytes() for p in (folder / "common").glob("*.xml")}


@needs_mujoco
@pytest.mark.parametrize("name", ("walker", "humanoid"))
def test_capsule_end_spheres_are_mujocos_capsule_ends(name):
    """contacts.geoms: a capsule's two spheres sit at the ends of MuJoCo's capsule axis
    (geom_xpos +- half length along the geom's z) with its radius."""
    import mujoco

    robot = mjcf.load_mjcf(bundled(name))
    mj = mujoco_model(bundled(name))
    data = mujoco.MjData(mj)
    mujoco.mj_forward(mj, data)
    q = mjcf._mujoco_to_pinocchio_q(mj, mj.qpos0)
    pdata = robot.model.createData()
    pin.framesForwardKinematics(robot.model, pdata, q)
    spheres = mjcf.geom_spheres(robot.model, robot.collision_model, ["*"])
    checked = 0
    for g in range(mj.ngeom):
        if mj.geom_type[g] != mujoco.mjtGeom.mjGEOM_CAPSULE or mj.geom_bodyid[g] == 0:
            continue
        name_g = mj.geom(g).name
        ends = {s.name: pdata.oMf[s.frame].act(s.offset) for s in spheres if s.name in (f"{name_g}@a", f"{name_g}@b")}
        axis = data.geom_xmat[g].reshape(3, 3)[:, 2] * mj.geom_size[g, 1]
        expected = [data.geom_xpos[g] - axis, data.geom_xpos[g] + axis]
        got = [ends[f"{name_g}@a"], ends[f"{name_g}@b"]]
        if np.linalg.norm(got[0] - expected[0]) > np.linalg.norm(got[0] - expected[1]):
            got.reverse()  # the two ends, in either order (the axis' sign is a convention)
        np.testing.assert_allclose(np.array(got), np.array(expected), rtol=0, atol=1e-12)
        radii = {s.radius for s in spheres if s.name.startswith(name_g + "@")}
        assert len(radii) == 1 and abs(radii.pop() - float(mj.geom_size[g, 0])) <= 1e-15
        checked += 1
    assert checked >= 6


def test_flattening_lets_pinocchio_find_materials_of_includes(tmp_path):
    """Pinocchio 4.1 alone fails on a material defined in an <include>d file or in a second
    <asset> section; the flattened copy parses, with the geom and its colour."""
    (tmp_path / "inc.xml").write_text('<mujoco><asset><material name="red" rgba="1 0 0 1"/></asset></mujoco>')
    (tmp_path / "robot.xml").write_text(
        '<mujoco model="r"><include file="inc.xml"/><asset><material name="blue" rgba="0 0 1 1"/></asset>'
        '<worldbody><body name="b" pos="0 0 1"><freejoint name="root"/>'
        '<geom name="g" type="capsule" fromto="0 0 0 0 0 .5" size=".05" material="red"/>'
        '<geom name="h" type="sphere" pos=".1 0 0" size=".05" material="blue"/></body></worldbody></mujoco>')
    path = tmp_path / "robot.xml"
    model = pin.buildModelFromMJCF(str(path))
    with pytest.raises(ValueError, match="Cannot find material"):
        pin.buildGeomFromMJCF(model, str(path), pin.GeometryType.VISUAL)
    robot = mjcf.load_mjcf(path, check=False)
    colours = {go.name: tuple(go.meshColor) for go in robot.visual_model.geometryObjects}
    assert colours == {"g": (1.0, 0.0, 0.0, 1.0), "h": (0.0, 0.0, 1.0, 1.0)}


# ---- refusing and accepting differences

SLIDE = ('<mujoco model="s"><worldbody><body name="cart" pos="0 0 .1"><joint name="slider" type="slide" '
         'axis="1 0 0" range="-0.5 0.5" limited="true"/><geom name="c" type="sphere" size=".1" mass="1"/>'
         '</body></worldbody></mujoco>')


@needs_mujoco
def test_a_differing_model_is_refused_with_one_line_naming_the_difference(tmp_path):
    """Pinocchio 4.1 reads a slide's range in degrees (compiler angle="degree", MuJoCo's default):
    ±0.5 m becomes ±0.0087. Refused by default; accepted by name; a name not shown is an error."""
    path = tmp_path / "slide.xml"
    path.write_text(SLIDE)
    mj = mujoco_model(path)
    assert list(mj.jnt_range[0]) == [-0.5, 0.5]
    with pytest.raises(mjcf.MjcfMismatch) as info:
        mjcf.load_mjcf(path)
    message = str(info.value)
    assert "\n" not in message and "joint ranges of 1 joint(s): slider" in message and "'joint_range'" in message
    robot = mjcf.load_mjcf(path, accept=["joint_range"])
    assert robot.differences.keys() == {"joint_range"}
    assert robot.model.upperPositionLimit[0] == pytest.approx(math.radians(0.5), rel=1e-12)  # the parser's reading
    with pytest.raises(mjcf.MjcfMismatch, match="shows no 'total_mass' difference"):
        mjcf.load_mjcf(path, accept=["joint_range", "total_mass"])
    with pytest.raises(mjcf.MjcfMismatch, match="did you mean 'joint_range'"):
        mjcf.load_mjcf(path, accept=["joint_ranges"])
    scene = tmp_path / "s.toml"
    scene.write_text('mjcf = "slide.xml"\n')
    with pytest.raises(SceneError, match=r"s.toml: mjcf = 'slide.xml': .*joint ranges of 1 joint\(s\): slider"):
        load_scene(scene)
    scene.write_text('mjcf = "slide.xml"\nmjcf_accept = ["joint_range"]\n')
    assert load_scene(scene).model.nq == 1


def test_without_mujoco_a_model_loads_unchecked_and_accepting_is_an_error(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # import mujoco now raises ImportError
    robot = mjcf.load_mjcf(bundled("walker"))
    assert not robot.checked and robot.model.nq == 9
    path = tmp_path / "slide.xml"
    path.write_text(SLIDE)
    with pytest.raises(mjcf.MjcfMismatch, match="checked with MuJoCo, which is not installed"):
        mjcf.load_mjcf(path, accept=["joint_range"])


@needs_mujoco
def test_only_the_first_top_level_body_is_read(tmp_path):
    """Two bodies under <worldbody>: Pinocchio 4.1 reads the first only (why manipulator, finger,
    ball_in_cup, stacker and dog are refused, docs/mjcf.md)."""
    path = tmp_path / "two.xml"
    path.write_text('<mujoco model="two"><worldbody>'
                    '<body name="a"><joint name="ja" type="hinge" axis="0 1 0"/><geom type="sphere" size=".1"/></body>'
                    '<body name="b" pos="1 0 0"><joint name="jb" type="hinge" axis="0 1 0"/>'
                    '<geom type="sphere" size=".1"/></body></worldbody></mujoco>')
    with pytest.raises(mjcf.MjcfMismatch, match="nq 1 against MuJoCo's 2; nv 1 against MuJoCo's 2"):
        mjcf.load_mjcf(path)


# ---- the scene keys

def test_scene_keys_are_checked():
    walker = {"mjcf": "mjcf/dm_control/walker.xml"}
    with pytest.raises(SceneError, match="exactly one of `robot`, `urdf`, `mjcf`, `bodies` or `\\[array\\]`, got urdf, mjcf"):
        build_scene({"urdf": "cube.urdf", **walker})
    with pytest.raises(SceneError, match="mjcf_accept applies to `mjcf` scenes only"):
        build_scene({"urdf": "cube.urdf", "mjcf_accept": ["nq"]})
    with pytest.raises(SceneError, match="contacts.geoms applies to `mjcf` scenes only"):
        build_scene({"urdf": "cube.urdf", "contacts": {"geoms": ["foot"]}})
    with pytest.raises(SceneError, match="free_flyer: an `mjcf` scene's root joint is the MJCF file's own"):
        build_scene({**walker, "free_flyer": True})
    with pytest.raises(SceneError, match="unknown key 'mjfc' in the top level \\(did you mean 'mjcf'\\?\\)"):
        build_scene({"mjfc": "x.xml"})
    with pytest.raises(SceneError, match="contacts.geoms: 'rigth_foot' matches no geom.*did you mean 'right_foot'"):
        build_scene({**walker, "contacts": {"geoms": ["rigth_foot"]}})
    with pytest.raises(FileNotFoundError, match="MJCF .nowhere.xml. not found"):
        build_scene({"mjcf": "nowhere.xml"})
    with pytest.raises(SceneError, match="control.lock_joints: Pinocchio cannot reduce this MJCF model"):
        build_scene({"mjcf": "mjcf/dm_control/humanoid.xml", "control": {"lock_joints": True}})
    with pytest.raises(SceneError, match="planar.*joint 'root_joint_box' moves out of it"):  # a free box beside it
        build_scene({**walker, "contacts": {"geoms": ["*_foot"], "model": "planar"},
                     "objects": [{"name": "box", "xy": [1.0, 0.0]}]})
    with pytest.raises(SceneError, match="planar.*joint 'root' moves out of it"):
        build_scene({"mjcf": "mjcf/dm_control/humanoid.xml", "contacts": {"geoms": ["*_foot"], "model": "planar"}})


def test_capsule_feet_and_placement_of_a_planar_robot():
    """walker: each foot capsule gives two spheres of its radius; the robot is lowered along its
    vertical slide until the lowest touches (gap 0), the root's 3 dofs are not actuated."""
    scene = load_scene("dmc-walker-stand")
    assert [c.name for c in scene.contacts] == ["right_foot@a", "right_foot@b", "left_foot@a", "left_foot@b"]
    assert {c.radius for c in scene.contacts} == {0.05}
    data = scene.model.createData()
    pin.framesForwardKinematics(scene.model, data, scene.q0)
    lowest = min(data.oMf[c.frame].act(c.offset)[2] - c.radius for c in scene.contacts)
    assert abs(lowest) < 1e-12
    assert (scene.kp[:3] == 0).all() and (scene.kp[3:] == 200.0).all()


# ---- the scenes' physics

def _at_rest_checks(name, duration=None, penetration=1e-6):
    sim = Simulator(name)
    traj = sim.rollout(duration) if duration else sim.rollout()
    model = sim.scene.model
    m = pin.computeTotalMass(model)
    assert traj.converged[1:].all()
    assert -traj.gaps[1:].min() < penetration
    fn = float(traj.lam[-1, :, 2].sum())
    ft = float(traj.lam[-1, :, :2].sum(axis=0).__abs__().max())
    assert abs(fn - m * G) <= 1e-6 * m * G, (fn, m * G)
    assert ft <= 1e-6 * m * G  # no net tangential force at rest on flat ground
    return sim, traj, m


@needs_mujoco
def test_walker_stands_on_its_feet():
    sim, traj, m = _at_rest_checks("dmc-walker-stand")
    assert m == pytest.approx(float(mujoco_model(bundled("walker")).body_mass.sum()), rel=1e-12)
    after = traj.t >= sim.scene.settle_time
    assert (traj.states[after] == 1).all()  # all four foot spheres stick
    slip = np.abs(traj.q[after, 0] - traj.q[-1, 0]).max()
    assert slip < 1e-9


def test_humanoid_stands_on_its_four_foot_capsules():
    sim, traj, m = _at_rest_checks("dmc-humanoid-stand")
    assert len(sim.scene.contacts) == 8 and (traj.states[-1] == 1).all()
    assert 40.8 < m < 40.9
    assert traj.q[-1, 2] > 1.2  # upright (the root at qpos0 stands at 1.2855 m)


@needs_mujoco
def test_cheetah_rests_with_mujocos_mass():
    sim, traj, m = _at_rest_checks("dmc-cheetah-stand")
    assert m == pytest.approx(14.0, rel=1e-12)
    assert np.abs(traj.v[-1]).max() < 1e-5


def test_hopper_topples_and_comes_to_rest_on_its_back():
    sim, traj, m = _at_rest_checks("dmc-hopper-fall", penetration=1e-5)
    assert traj.q[0, 2] == 0.0 and traj.q[-1, 2] == pytest.approx(-math.pi / 2, abs=0.05)  # rooty: lying
    assert np.abs(traj.v[-1]).max() < 1e-5
    touching = {sim.scene.contacts[i].name.split("@")[0] for i in np.flatnonzero(traj.lam[-1, :, 2] > 1e-9)}
    assert "torso" in touching


def test_bundled_files_ship_with_their_licence():
    """The dm_control files are installed with robots/ (CMake installs the whole folder as package
    data) beside dm_control's Apache-2.0 licence and a README saying where they come from."""
    from pathlib import Path

    folder = bundled("walker").parent
    for name in BUNDLED:
        assert bundled(name).is_file()
    assert "Apache License" in (folder / "LICENSE").read_text()
    readme = (folder / "README.md").read_text()
    assert "dm-control` 1.0.52" in readme and "Apache License, Version 2.0" in readme
    for include in ("materials", "skybox", "visual"):
        assert (folder / "common" / f"{include}.xml").is_file()
    cmake = (Path(__file__).resolve().parents[1] / "CMakeLists.txt").read_text()
    assert "install(DIRECTORY robots/ DESTINATION stiction/data/robots)" in cmake


def test_mjcf_capsules_through_coal_carry_the_walker():
    """[collision] pairs among the MJCF's own geoms and "ground": the walker's foot capsules
    through coal (two contact points each, patches) carry its weight, as the end spheres do."""
    cfg = {"mjcf": "mjcf/dm_control/walker.xml", "duration": 2.0, "settle_time": 1.0, "ground": {"mu": 1.0},
           "control": {"kp": 200.0, "kd": 5.0},
           "collision": {"pairs": [["right_foot", "ground"], ["left_foot", "ground"]], "max_contacts": 2,
                         "patch": True}}
    scene = build_scene(cfg)
    assert [gp.name for gp in scene.pairs] == ["right_foot|ground", "left_foot|ground"] and not scene.contacts
    sim = Simulator(scene)
    traj = sim.rollout()
    m = pin.computeTotalMass(scene.model)
    assert traj.converged[1:].all() and -traj.gaps[1:].min() < 1e-9
    assert abs(traj.lam[-1, :, 2].sum() - m * G) <= 1e-6 * m * G
    assert (traj.states[-1] == 1).all() and len(traj.contact_names) == 4  # both ends of both feet, sticking
    with pytest.raises(SceneError, match="collision.pairs\\[0\\]: no geometry 'floor'"):
        build_scene({**cfg, "collision": {"pairs": [["floor", "right_foot"]]}})  # the world's geoms are left out


@needs_mujoco
def test_the_check_writes_no_mujoco_log(tmp_path, monkeypatch):
    """MuJoCo's compiler warns that settotalmass is deprecated (cheetah) by appending to
    MUJOCO_LOG.TXT in the working folder; the loader catches it instead."""
    monkeypatch.chdir(tmp_path)
    robot = mjcf.load_mjcf(bundled("cheetah"))
    assert robot.checked and not (tmp_path / "MUJOCO_LOG.TXT").exists()
