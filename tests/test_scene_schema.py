"""Scene files are strict: every malformed key, type, shape or range is one clear line naming the
field; nothing is built from an invalid scene; the schema renders the docs' key reference."""
import math
import textwrap

import numpy as np
import pytest

from stiction.scene import build_scene, list_scenes, load_scene
from stiction.scene_schema import SCENE, SceneError, reference_markdown, validate_scene

CUBE = {"urdf": "cube.urdf", "contacts": {"box_corners": True}}


def with_(base: dict, **changes) -> dict:
    """A deep-ish copy of a scene dict with tables merged."""
    out = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.items()}
    for k, v in changes.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = {**out[k], **v}
        else:
            out[k] = v
    return out


BAD_SCENES = [
    # (scene dict, substrings the one-line message must contain)
    (with_(CUBE, ground={"slop_deg": 10.0}), ["'slop_deg'", "[ground]", "'slope_deg'"]),
    (with_(CUBE, groud={"mu": 0.3}), ["'groud'", "top level", "'ground'"]),
    (with_(CUBE, durration=1.0), ["'durration'", "'duration'"]),
    (with_(CUBE, ground={"mu": [0.5]}), ["ground.mu", "[0.5]", "number"]),
    (with_(CUBE, ground={"mu": -0.1}), ["ground.mu", "-0.1", ">= 0"]),
    (with_(CUBE, ground={"mu": math.nan}), ["ground.mu", "finite"]),
    (with_(CUBE, walls=[{"normal": [1, 0], "offset": 0.0}]), ["walls[0].normal", "[1, 0]", "3 entries"]),
    (with_(CUBE, walls=[{"normal": [0, 0, 0], "offset": 0.0}]), ["walls[0].normal", "zero vector"]),
    (with_(CUBE, walls=[{"normal": [1, 0, 0]}]), ["walls[0]", "offset"]),
    (with_(CUBE, walls={"normal": [1, 0, 0], "offset": 0.0}), ["walls", "[[walls]]"]),
    (with_(CUBE, ground=[{"mu": 0.5}]), ["ground", "[ground]"]),
    (with_(CUBE, ground=5), ["ground", "table"]),
    (with_(CUBE, duration=math.inf), ["duration", "inf", "finite"]),
    (with_(CUBE, duration=math.nan), ["duration", "nan", "finite"]),
    (with_(CUBE, duration=0.0), ["duration", "> 0"]),
    (with_(CUBE, dt=-1e-3), ["dt", "> 0"]),
    (with_(CUBE, dt="1ms"), ["dt", "'1ms'", "number"]),
    (with_(CUBE, control={"kp": -5.0}), ["control.kp", "-5.0"]),
    (with_(CUBE, control={"kd": -1.0}), ["control.kd", "-1.0"]),
    (with_(CUBE, contacts={"radius": -0.01}), ["contacts.radius", "-0.01"]),
    (with_(CUBE, contacts={"box_corners": "yes"}), ["contacts.box_corners", "true or false"]),
    (with_(CUBE, anchors=[{"offset": [0, 0, 0]}]), ["anchors[0]", "missing required key 'frame'"]),
    (with_(CUBE, anchors=[{"frame": "cube", "target": [0, 0, 1], "frame2": "cube"}]), ["anchors[0]", "not both"]),
    ({"bodies": []}, ["bodies", "empty"]),
    ({"bodies": ["cube.urdf", 3]}, ["bodies", "list of strings"]),
    (with_(CUBE, initial={"q": [0, 0, 0.5, 0, 0, 0, 0]}), ["initial.q", "quaternion", "norm 0"]),
    (with_(CUBE, initial={"q": [0, 0, 0.5, 0, 0, 1]}), ["initial.q", "nq = 7"]),
    (with_(CUBE, initial={"base_velocity": [1, 0, 0]}), ["initial.base_velocity", "6 entries"]),
    (with_(CUBE, robot="solo12"), ["exactly one", "robot", "urdf"]),
    ({"duration": 1.0}, ["exactly one of `robot`, `urdf`, `mjcf`, `bodies` or `[array]`"]),
    ({"array": {"layout": "grid"}}, ["missing required key 'count'"]),
    ({"array": {"layout": "ring", "count": 2}}, ["ring"]),
    ({"array": {"layout": "tower", "count": 2, "spacing": 0.3}}, ["spacing applies to layout = \"grid\" or \"pile\" only"]),
    ({"array": {"layout": "grid", "count": 0}}, ["count"]),
    ({"urdf": "cube.urdf", "array": {"layout": "grid", "count": 2}}, ["got urdf, array"]),
    ({"robot": "solo13"}, ["solo13", "solo12"]),
    ({"urdf": "no-such.urdf"}, ["no-such.urdf", "not found"]),
    (with_(CUBE, contacts={"frames": ["cubee"]}), ["contacts.frames", "'cubee'", "did you mean"]),
    (with_(CUBE, mode="rk5"), ["mode", "'rk5'", "timestep"]),
    (with_(CUBE, delta=1e-3), ["delta", "ODE modes"]),
    (with_(CUBE, zeta=0.0), ["zeta", "> 0"]),
    (with_(CUBE, ground={"slope_deg": 95.0}), ["ground.slope_deg", "<= 89"]),
    ({"urdf": "ball.urdf", "contacts": {"feet": False}, "collision": {"pairs": [["ball_0", "grnd"]]}},
     ["collision.pairs[0]", "'grnd'", "'ground'"]),
    ({"urdf": "ball.urdf", "contacts": {"feet": False}, "collision": {"pairs": [["ball_0", "ground"]],
                                                                      "max_contacts": 0}},
     ["collision.max_contacts", ">= 1"]),
    ({"urdf": "ball.urdf", "contacts": {"feet": False},
      "collision": {"pairs": [["ball_0", "t"]], "boxes": [{"name": "t", "size": [1, -1, 1]}]}},
     ["collision.boxes[0].size", "> 0"]),
    ({"urdf": "ball.urdf", "collision": {"max_contacts": 2}}, ["[collision]", "missing required key 'pairs'"]),
    ({"urdf": "ball.urdf", "contacts": {"feet": True}}, ["contacts.feet", "no foot frames"]),
    # drift and slip are measured after settle_time: it must come before the end
    (with_(CUBE, duration=1.0, settle_time=1.5), ["settle_time = 1.5", "shorter than duration = 1"]),
    (with_(CUBE, duration=1.0, settle_time=1.0), ["settle_time = 1", "shorter than duration = 1"]),
    # planar contacts (rows t1, n) on a body moving in 3-D would slide across the plane without friction
    (with_(CUBE, contacts={"box_corners": True, "model": "planar"}),
     ["contacts.model = \"planar\"", "joint = \"planar\""]),
    (with_(CUBE, walls=[{"normal": [1, 0, 0], "offset": -1.0, "model": "planar"}]),
     ["walls[0].model = \"planar\"", "joint = \"planar\""]),
    ({"array": {"layout": "grid", "count": 2}, "contacts": {"model": "planar"}}, ["contacts.model", "planar"]),
]


@pytest.mark.parametrize("cfg,expected", BAD_SCENES, ids=[str(i) for i in range(len(BAD_SCENES))])
def test_bad_scene_is_one_clear_line(cfg, expected):
    with pytest.raises((SceneError, FileNotFoundError)) as info:
        build_scene(cfg)
    msg = str(info.value)
    assert "\n" not in msg
    for part in expected:
        assert part in msg, f"{part!r} not in {msg!r}"


def test_typo_in_a_scene_file_names_the_file_the_table_and_the_closest_key(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text(textwrap.dedent("""
        urdf = "cube.urdf"
        [ground]
        slop_deg = 30.0
        """))
    with pytest.raises(SceneError, match=r"typo\.toml: unknown key 'slop_deg' in \[ground\] \(did you mean 'slope_deg'\?\)"):
        load_scene(str(path))


def test_not_toml_is_a_scene_error(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("urdf = 'cube.urdf\n[ground\n")
    with pytest.raises(SceneError, match="broken.toml: not valid TOML"):
        load_scene(str(path))
    binary = tmp_path / "binary.toml"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(SceneError, match="binary.toml"):
        load_scene(str(binary))


def test_urdf_relative_to_the_scene_file(tmp_path):
    """A scene file's relative URDF path is looked up next to the scene first."""
    from stiction.resources import robots_dir

    (tmp_path / "mycube.urdf").write_text((robots_dir() / "cube.urdf").read_text())
    (tmp_path / "s.toml").write_text('urdf = "mycube.urdf"\n[contacts]\nbox_corners = true\n')
    assert len(load_scene(str(tmp_path / "s.toml")).contacts) == 8


def test_every_bundled_scene_validates_with_defaults_filled():
    for name in list_scenes():
        sc = load_scene(name)
        assert sc.config["ground"]["mu"] == sc.mu
        assert set(sc.config) == set(SCENE.names())


def test_defaults_come_from_the_schema():
    cfg = validate_scene({"urdf": "cube.urdf"})
    assert cfg["dt"] == 1e-3 and cfg["duration"] == 2.0 and cfg["ground"] == {"slope_deg": 0.0, "mu": 0.5}
    assert cfg["walls"] == [] and cfg["collision"]["max_contacts"] == 4


def test_quaternion_is_normalised_not_rejected_when_nearly_unit():
    sc = build_scene(with_(CUBE, initial={"q": [0, 0, 0.5, 0, 0, 0, 1.0001]}))
    assert np.linalg.norm(sc.q0[3:7]) == pytest.approx(1.0, abs=1e-15)


def test_reference_lists_every_key():
    text = reference_markdown()

    def walk(table):
        for k in table.keys:
            yield k.name
        for t in table.tables:
            yield from walk(t)

    for name in walk(SCENE):
        assert f"`{name}`" in text
    assert "[[walls]]" in text and "[[collision.boxes]]" in text


def test_collision_pairs_with_a_bundled_robot():
    """[collision] with robot = "solo12": the collision meshes are package:// URIs of
    example-robot-data and must be found (they were not: no mesh search paths)."""
    from stiction.simulator import Simulator

    sc = build_scene({"robot": "solo12", "collision": {"pairs": [["FL_LOWER_LEG_0", "ground"]], "max_contacts": 2}})
    names = [g.name for g in sc.geometry.geometryObjects]
    assert "FL_LOWER_LEG_0" in names and "ground" in names
    assert sc.geometry.geometryObjects[names.index("FL_LOWER_LEG_0")].meshPath.endswith(".stl")
    traj = Simulator(sc).rollout(0.02)
    assert traj.converged[1:].all()
    # the lower leg mesh stays a few mm above the ground: the foot spheres carry the robot
    assert 1e-3 < traj.gaps[1:, -2:].min() < 0.05


def test_package_uri_meshes_of_a_user_urdf(tmp_path):
    """A user's URDF in a ROS package layout (mypkg/urdf/x.urdf with package://mypkg/meshes/...)
    loads its meshes."""
    pkg = tmp_path / "mypkg"
    (pkg / "urdf").mkdir(parents=True)
    (pkg / "meshes").mkdir()
    facets = [((0, 0, 0), (1, 0, 0), (0, 1, 0)), ((0, 0, 0), (0, 1, 0), (0, 0, 1)),
              ((0, 0, 0), (0, 0, 1), (1, 0, 0)), ((1, 0, 0), (0, 1, 0), (0, 0, 1))]
    stl = ["solid tet"]
    for tri in facets:
        stl += ["facet normal 0 0 0", "outer loop"] + [f"vertex {x * 0.1} {y * 0.1} {z * 0.1}" for x, y, z in tri]
        stl += ["endloop", "endfacet"]
    (pkg / "meshes" / "tet.stl").write_text("\n".join(stl + ["endsolid tet"]) + "\n")
    (pkg / "urdf" / "tet.urdf").write_text(textwrap.dedent("""\
        <robot name="tet">
          <link name="tet">
            <inertial><mass value="1.0"/><inertia ixx="1e-3" iyy="1e-3" izz="1e-3" ixy="0" ixz="0" iyz="0"/></inertial>
            <visual><geometry><mesh filename="package://mypkg/meshes/tet.stl"/></geometry></visual>
          </link>
        </robot>
        """))
    sc = build_scene({"urdf": str(pkg / "urdf" / "tet.urdf"), "contacts": {"frames": ["tet"], "radius": 0.02}})
    paths = [g.meshPath for g in sc.visual_model.geometryObjects]
    assert paths and paths[0] == str(pkg / "meshes" / "tet.stl")


def test_docs_scene_keys_page_is_current():
    from pathlib import Path

    page = Path(__file__).resolve().parents[1] / "docs" / "scene-keys.md"
    assert page.read_text() == reference_markdown() + "\n", "regenerate docs/scene-keys.md (see its header)"


UR5 = {"robot": "ur5", "contacts": {"feet": False}}


def test_overlapping_objects_are_refused():
    """Two [[objects]] boxes (cube.urdf: 0.1 m edges, axis-aligned) may touch but not interpenetrate:
    the same position, or 1 cm of overlap, is refused naming both."""
    def objects(*placements):
        return {**UR5, "objects": [{"name": f"box{k}", "xy": xy, "z": z} for k, (xy, z) in enumerate(placements)]}

    for placements, depth in ((([0.6, 0.0], 0.0), ([0.6, 0.0], 0.0)), 0.1), \
                              ((([0.6, 0.0], 0.0), ([0.69, 0.0], 0.0)), 0.01), \
                              ((([0.6, 0.0], 0.0), ([0.6, 0.3], 0.0), ([0.6, 0.0], 0.05)), 0.05):
        with pytest.raises(SceneError, match=rf"objects\[{len(placements) - 1}\] \('box{len(placements) - 1}'\) "
                                             rf"overlaps objects\[0\] \('box0'\) by {depth:g} m"):
            build_scene(objects(*placements))
    # side by side (faces touching) and stacked (the top one's bottom on the lower one's top) are fine
    scene = build_scene(objects(([0.6, 0.0], 0.0), ([0.7, 0.0], 0.0), ([0.6, 0.0], 0.1)))
    np.testing.assert_allclose(scene.q0[-7:-4], [0.6, 0.0, 0.15])
