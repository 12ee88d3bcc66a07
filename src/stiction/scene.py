"""Scenes: a robot or rigid bodies, a ground (slope, friction), the contacts the scene needs,
the initial state and the control. Every scene is a TOML file in ``robots/scenes/``.

A slope of angle θ is modelled by tilting gravity, g = 9.81 (sin θ, 0, -cos θ): the ground stays
the plane z = 0 and "downhill" is +x. Recordings rotate the picture back.

Every key a scene file may hold is defined, with its type, range, default and meaning, in
:mod:`stiction.scene_schema` (rendered in the docs as the scene key reference); the loader
validates a scene against it before building anything. In short: one of ``robot`` (a bundled
robot), ``urdf`` (a URDF path) or ``bodies`` (stacked boxes); ``[ground]`` slope and friction;
``[contacts]`` the sphere/point contacts; ``[control]`` joint PD; ``[initial]`` the state;
``[[walls]]``, ``[[anchors]]`` and ``[collision]`` (coal pairs, ``[[collision.boxes]]``).
"""
from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from . import _core
from ._validation import vector
from .resources import robots_dir as bundled_robots_dir
from .resources import scenes_dir
from .robots import load_robot, load_urdf, robot_package_dirs
from .scene_schema import SceneError, did_you_mean, validate_scene

GRAVITY = 9.81
OVERLAP_TOLERANCE = 1e-9  # m: two [[objects]] boxes may touch (a face on a face), not interpenetrate


def __getattr__(name: str):
    # SCENES_DIR and ROBOTS_DIR: resolved on use (package data of a wheel, or the source checkout)
    if name == "SCENES_DIR":
        return scenes_dir()
    if name == "ROBOTS_DIR":
        return bundled_robots_dir()
    raise AttributeError(f"module 'stiction.scene' has no attribute {name!r}")


@dataclass
class Scene:
    """A loaded scene: everything the simulator needs, plus what the summary reports."""

    name: str
    description: str
    model: pin.Model
    visual_model: pin.GeometryModel
    halfspaces: list
    contacts: list
    anchors: list
    q0: np.ndarray
    v0: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    q_target: np.ndarray
    tau_ff: np.ndarray
    duration: float
    dt: float
    settle_time: float
    mode: str
    delta: float
    zeta: float
    slope_deg: float
    mu: float
    config: dict = field(default_factory=dict)
    geometry: pin.GeometryModel | None = None  # shapes for the coal pairs
    pairs: list = field(default_factory=list)  # _core.GeometryPairContact

    @property
    def slope(self) -> float:
        return math.radians(self.slope_deg)


def list_scenes() -> list[str]:
    """Names of the bundled scenes."""
    return sorted(p.stem for p in scenes_dir().glob("*.toml"))


def scene_description(name: str) -> str:
    """The `description` of a bundled scene (read without building it)."""
    with open(scenes_dir() / f"{name}.toml", "rb") as fh:
        return str(tomllib.load(fh).get("description", ""))


def _resolve(path: str, base_dir=None, what: str = "URDF") -> Path:
    """A URDF (or MJCF) path: absolute, relative to the scene file's folder, or a bundled file."""
    p = Path(path)
    candidates = [p] if p.is_absolute() else ([Path(base_dir) / p] if base_dir is not None else []) + \
        [bundled_robots_dir() / p, p]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"{what} {path!r} not found (looked in: {', '.join(str(c.parent) for c in candidates)})")


def _package_dirs(urdf: Path) -> list[str]:
    """Where `package://NAME/...` meshes of a user's URDF are searched: the folders above the URDF
    (a ROS package layout NAME/urdf/robot.urdf), the bundled robots and example-robot-data."""
    urdf = Path(urdf).resolve()
    dirs = [str(p) for p in list(urdf.parents)[:3]]
    dirs.append(str(bundled_robots_dir()))
    try:
        dirs += robot_package_dirs()
    except FileNotFoundError:
        pass
    return dirs


def _box_half_extents(visual_model: pin.GeometryModel) -> np.ndarray | None:
    import coal

    for go in visual_model.geometryObjects:
        if isinstance(go.geometry, coal.Box):
            return np.asarray(go.geometry.halfSide, dtype=float)
    return None


def _halfspace(name: str, normal, offset: float, frame: int = 0) -> _core.HalfSpace:
    h = _core.HalfSpace()
    h.name, h.normal, h.offset, h.frame = name, np.asarray(normal, dtype=float), float(offset), int(frame)
    return h


def _sphere(name: str, frame: int, offset, radius: float, halfspace: int, mu: float,
            model: str = "spatial") -> _core.SphereContact:
    c = _core.SphereContact()
    c.name, c.frame, c.offset, c.radius, c.halfspace, c.mu = name, int(frame), np.asarray(offset, float), float(radius), int(halfspace), float(mu)
    c.model = getattr(_core.ContactModel, model)
    return c


def _corners(half: np.ndarray, z_sign: float | None = None, planar: bool = False):
    if planar:  # the box's outline in the planar joint's x-y plane (z = 0)
        return [np.array([sx * half[0], sy * half[1], 0.0]) for sx in (-1, 1) for sy in (-1, 1)]
    out = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                if z_sign is None or sz == z_sign:
                    out.append(np.array([sx, sy, sz]) * half)
    return out


def load_scene(name_or_path: str | os.PathLike) -> Scene:
    """A scene by name (a bundled file, see :func:`list_scenes`) or by path to a TOML file.

    The file is checked against :mod:`stiction.scene_schema` first: unknown keys, wrong types,
    shapes and ranges raise :class:`~stiction.scene_schema.SceneError` (a ValueError) naming
    the field. Relative URDF paths are looked up next to the scene file, then in the bundled
    robots directory."""
    if not isinstance(name_or_path, (str, os.PathLike)):
        raise TypeError(f"scene must be a name, a path or a Scene, got {type(name_or_path).__name__}")
    p = Path(name_or_path)
    if not p.suffix and not p.exists():
        p = scenes_dir() / f"{name_or_path}.toml"
        if not p.is_file():
            hint = did_you_mean(name_or_path, list_scenes(), cutoff=0.6)
            raise SceneError(f"unknown scene {str(name_or_path)!r} ({hint}known: {', '.join(list_scenes())}; "
                             "or give the path of a .toml file)")
    if not p.is_file():
        raise FileNotFoundError(f"scene file not found: {p}")
    try:
        with open(p, "rb") as fh:
            cfg = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{p}: not valid TOML: {exc}") from None
    except UnicodeDecodeError:
        raise SceneError(f"{p}: not a text (UTF-8) TOML file") from None
    return build_scene(cfg, default_name=p.stem, source=str(p), base_dir=p.parent)


def _quaternion_check(model: pin.Model, q: np.ndarray, field: str, strict: bool = True) -> np.ndarray:
    """Normalise the quaternions of free-flyer and spherical joints and the (cos θ, sin θ) pair
    of planar joints in q; a zero one (with `strict`, one whose norm is not within 10 % of 1:
    likely a typo in a scene file), one whose norm is not a finite number (entries so large that
    their squares overflow, e.g. (0, 0, 0, 1e300), which would normalise to zeros) or one that
    is not a unit one after normalising is an error naming the joint and the value."""
    q = q.copy()
    for j in range(1, model.njoints):
        kind = model.joints[j].shortname()
        start, size = {"JointModelFreeFlyer": (3, 4), "JointModelSpherical": (0, 4),
                       "JointModelPlanar": (2, 2)}.get(kind, (None, 0))
        if start is None:
            continue
        i = model.joints[j].idx_q + start
        what = "quaternion (x, y, z, w)" if size == 4 else "(cos, sin) pair"
        hint = "a unit quaternion (x, y, z, w)" if size == 4 else "cos and sin of the angle"
        value = "(" + ", ".join(f"{x:.17g}" for x in q[i:i + size]) + ")"
        where = f"{field}: the {what} of joint {model.names[j]!r} (entries {i}..{i + size - 1}) = {value}"
        with np.errstate(over="ignore", invalid="ignore"):
            norm = float(np.linalg.norm(q[i:i + size]))
        if not math.isfinite(norm):
            raise SceneError(f"{where} has no finite norm (its squares overflow or it is not finite); give {hint}")
        if not (0.9 < norm < 1.1 if strict else norm > 1e-12):
            raise SceneError(f"{where} has norm {norm:g}; give {hint}")
        unit = q[i:i + size] / norm
        if not (np.isfinite(unit).all() and abs(float(np.linalg.norm(unit)) - 1.0) <= 1e-12):
            raise SceneError(f"{where} does not normalise to a unit one (got {unit.tolist()}); give {hint}")
        q[i:i + size] = unit
    return q


def build_scene(cfg: dict, default_name: str = "scene", source: str | None = None,
                base_dir: str | os.PathLike | None = None) -> Scene:
    """A Scene from a scene dict (the keys of a scene TOML file, see :mod:`stiction.scene_schema`).
    The dict is validated first; nothing is built from an invalid one."""
    if source is None:
        name = cfg.get("name") if isinstance(cfg, dict) else None
        source = f"scene {name if isinstance(name, str) else default_name!r}"
    cfg = validate_scene(cfg, source)
    try:
        return _build_scene(cfg, default_name, base_dir)
    except SceneError as exc:
        raise SceneError(f"{source}: {exc}") from None


def _build_scene(cfg: dict, default_name: str, base_dir) -> Scene:
    ground, contacts_cfg, control, initial = cfg["ground"], cfg["contacts"], cfg["control"], cfg["initial"]
    slope_deg, mu = ground["slope_deg"], ground["mu"]
    cmodel = contacts_cfg["model"]
    root = cfg["joint"] or ("free_flyer" if cfg["free_flyer"] else "fixed")

    halfspaces = [_halfspace("ground", (0, 0, 1), 0.0)]
    contacts: list = []
    urdf_path = None
    mjcf_robot = None
    pile_geometry = pile_pairs = None
    if cfg["robot"] is not None or cfg["urdf"] is not None or cfg["mjcf"] is not None:
        if cfg["mjcf"] is not None:
            from .mjcf import MjcfMismatch, load_mjcf

            try:
                robot = mjcf_robot = load_mjcf(_resolve(cfg["mjcf"], base_dir, "MJCF"), cfg["mjcf_accept"])
            except MjcfMismatch as exc:
                raise SceneError(f"mjcf = {cfg['mjcf']!r}: {exc}") from None
        elif cfg["robot"] is not None:
            from .robots import ROBOTS

            if cfg["robot"] not in ROBOTS:
                hint = did_you_mean(cfg["robot"], ROBOTS)
                raise SceneError(f"robot = {cfg['robot']!r}: unknown robot ({hint}known: {', '.join(sorted(ROBOTS))}; "
                                 "or give `urdf`)")
            robot = load_robot(cfg["robot"])
        else:
            urdf_path = _resolve(cfg["urdf"], base_dir)
            robot = load_urdf(urdf_path, root == "free_flyer", _package_dirs(urdf_path), planar=root == "planar")
        model, visual, q0 = robot.model, robot.visual_model, robot.q0.copy()
        spec = None if mjcf_robot is not None else robot.spec
        if initial["q"] is not None:
            q0 = np.asarray(initial["q"], dtype=float)
            if q0.shape != (model.nq,):
                raise SceneError(f"initial.q needs nq = {model.nq} entries, got {q0.shape[0]}")
            q0 = _quaternion_check(model, q0, "initial.q")
        if initial["joints"] is not None:
            q0 = _named_joint_positions(model, q0, initial["joints"], initial["q"] is not None)
        if cfg["joints"]["override"]:
            model = model.copy()  # (the loaded robot's model stays as its URDF says)
            _joint_overrides(model, cfg["joints"]["override"])
        if control["lock_joints"] and model.njoints > 2:
            # A rigid robot: every joint but the free flyer held at its initial value.
            lock = list(range(2, model.njoints))
            if mjcf_robot is not None:  # its collision geoms too (they name the reduced model's frames)
                try:
                    model, (visual, mjcf_collision) = pin.buildReducedModel(
                        model, [visual, mjcf_robot.collision_model], lock, q0)
                except ValueError as exc:  # e.g. a body and a site of one name: two frames Pinocchio cannot tell
                    raise SceneError(f"control.lock_joints: Pinocchio cannot reduce this MJCF model "
                                     f"({str(exc).strip().splitlines()[-1]})") from None
                mjcf_robot = dataclasses.replace(mjcf_robot, model=model, collision_model=mjcf_collision)
            else:
                model, visual = pin.buildReducedModel(model, visual, lock, q0)
            q0 = q0[:model.nq].copy()  # the root joint's coordinates come first
        feet = contacts_cfg["feet"] if contacts_cfg["feet"] is not None else (spec is not None and bool(spec.feet))
        if feet:
            if spec is None or not spec.feet:
                raise SceneError("contacts.feet = true: this robot has no foot frames; list them with contacts.frames")
            radius = contacts_cfg["radius"] if contacts_cfg["radius"] is not None else spec.foot_radius
            for f in spec.feet:
                contacts.append(_sphere(f, model.getFrameId(f), (0, 0, 0), radius, 0, mu, cmodel))
        if contacts_cfg["geoms"]:
            from .mjcf import geom_spheres

            try:
                spheres = geom_spheres(model, mjcf_robot.collision_model, contacts_cfg["geoms"])
            except ValueError as exc:
                raise SceneError(str(exc)) from None
            for sp in spheres:
                contacts.append(_sphere(sp.name, sp.frame, sp.offset, sp.radius, 0, mu, cmodel))
        for frame_name in contacts_cfg["frames"]:
            contacts.append(_sphere(frame_name, _frame_id(model, frame_name, "contacts.frames"), (0, 0, 0),
                                    contacts_cfg["radius"] or 0.0, 0, mu, cmodel))
        if spec is not None and spec.points and contacts_cfg["soles"]:
            for frame_name, offset in spec.points:
                contacts.append(_sphere(f"{frame_name}{offset}", model.getFrameId(frame_name), offset, 0.0, 0, mu,
                                        cmodel))
        if contacts_cfg["box_corners"]:
            half = _box_half_extents(visual)
            if half is None:
                raise SceneError("contacts.box_corners = true: the URDF has no box visual")
            body_frame = next(i for i, f in enumerate(model.frames) if f.type == pin.FrameType.BODY)
            for k, corner in enumerate(_corners(half, planar=root == "planar")):
                contacts.append(_sphere(f"corner{k}", body_frame, corner, 0.0, 0, mu, cmodel))
    else:
        for key in ("feet", "radius"):
            if contacts_cfg[key] is not None:
                raise SceneError(f"contacts.{key}: `bodies` scenes use their box corners")
        if cfg["array"] is not None and cfg["array"]["layout"] == "grid":
            a = cfg["array"]
            model, visual, q0, contacts = _grid_bodies(a["urdf"], a["count"], a["spacing"], mu, base_dir, cmodel)
        elif cfg["array"] is not None and cfg["array"]["layout"] == "pile":
            a = cfg["array"]
            if a["mix"] is not None:  # shapes of every kind in a bin, every contact through coal (pile.py)
                from .pile import mixed_pile

                model, visual, q0, pile_geometry, pile_pairs = mixed_pile(
                    a["count"], a["seed"], a["mix"], a["spacing"], a["bin"], mu, a["pairs_per_body"], cmodel)
                contacts = []
            else:
                model, visual, q0, contacts, pile_geometry, pile_pairs = _pile_bodies(
                    a["urdfs"], a["count"], a["spacing"], a["seed"], mu, base_dir, cmodel)
        else:
            paths = cfg["bodies"] if cfg["bodies"] is not None else [cfg["array"]["urdf"]] * cfg["array"]["count"]
            model, visual, q0, contacts, halfspaces = _stacked_bodies(paths, mu, halfspaces, base_dir, cmodel)

    # Free boxes beside the robot: appended after its joints (each its own part of the world).
    robot_nq, robot_nv = model.nq, model.nv
    object_frames, cache = {}, {}
    if cfg["objects"]:  # appended in place: to copies (the robot's models stay as loaded)
        model = model.copy()
        visual = visual.copy() if visual is not None else pin.GeometryModel()
    placed = []  # (index, centre, half extents) of the objects so far
    for k, obj in enumerate(cfg["objects"]):
        model, visual, frame, half = _append_box(model, visual, obj["urdf"], obj["name"], base_dir,
                                                 f"objects[{k}].urdf", cache)
        centre = np.array([obj["xy"][0], obj["xy"][1], float(half[2]) + obj["z"]])
        for j, other, other_half in placed:
            # axis-aligned boxes (q0 holds the identity rotation) overlap when they do along every axis
            depth = float(np.min(half + other_half - np.abs(centre - other)))
            if depth > OVERLAP_TOLERANCE:
                raise SceneError(f"objects[{k}] ({obj['name']!r}) overlaps objects[{j}] "
                                 f"({cfg['objects'][j]['name']!r}) by {depth:.3g} m: move its xy or z")
        placed.append((k, centre, half))
        object_frames[obj["name"]] = frame
        obj_mu = mu if obj["mu"] is None else obj["mu"]
        for c, corner in enumerate(_corners(half, z_sign=-1)):
            contacts.append(_sphere(f"{obj['name']}-corner{c}", frame, corner, 0.0, 0, obj_mu, cmodel))
        q0 = np.concatenate([q0, [*centre, 0.0, 0.0, 0.0, 1.0]])

    for w, wall in enumerate(cfg["walls"]):
        name = wall["name"] or f"wall{len(halfspaces)}"
        wall_frame = 0
        if wall["body"] is not None:
            if wall["body"] not in object_frames:
                hint = did_you_mean(wall["body"], list(object_frames))
                raise SceneError(f"walls[{w}].body = {wall['body']!r}: no such object ({hint}objects: "
                                 f"{', '.join(object_frames) or 'none'})")
            wall_frame = object_frames[wall["body"]]
        halfspaces.append(_halfspace(name, wall["normal"], wall["offset"], wall_frame))
        for frame_name in wall["frames"]:
            fid = _frame_id(model, frame_name, f"walls[{w}].frames")
            contacts.append(_sphere(f"{frame_name}-{name}", fid, wall["offset_in_frame"], wall["radius"],
                                    len(halfspaces) - 1, mu if wall["mu"] is None else wall["mu"],
                                    cmodel if wall["model"] is None else wall["model"]))

    geometry, pairs = None, []
    if pile_geometry is not None:
        if cfg["collision"]["pairs"] is not None or cfg["collision"]["boxes"]:
            raise SceneError("collision: a pile makes its own pairs (every two bodies); it takes no [collision]")
        geometry, pairs = pile_geometry, pile_pairs
    elif cfg["collision"]["pairs"] is not None:
        geometry, pairs = _collision_pairs(cfg, model, mu, urdf_path,
                                           mjcf_robot.collision_model if mjcf_robot is not None else None)
    elif cfg["collision"]["boxes"] or cfg["collision"]["mu"] is not None:
        raise SceneError("collision: boxes or mu without pairs do nothing; list the pairs")

    anchors = []
    for k, a in enumerate(cfg["anchors"]):
        pa = _core.PointAnchor()
        pa.name, pa.frame = a["name"] or f"anchor{k}", _frame_id(model, a["frame"], f"anchors[{k}].frame")
        pa.offset = np.asarray(a["offset"], dtype=float)
        if a["frame2"] is not None:  # a closed loop: held to a point of another body
            pa.frame2 = _frame_id(model, a["frame2"], f"anchors[{k}].frame2")
            pa.offset2 = np.asarray(a["offset2"], dtype=float)
        elif a["target"] is not None:
            pa.target = np.asarray(a["target"], dtype=float)
        else:
            data = model.createData()
            pin.framesForwardKinematics(model, data, q0)
            pa.target = data.oMf[pa.frame].act(pa.offset)
        anchors.append(pa)

    # Tilted gravity models the slope (downhill = +x).
    th = math.radians(slope_deg)
    model.gravity = pin.Motion(np.array([GRAVITY * math.sin(th), 0.0, -GRAVITY * math.cos(th)]), np.zeros(3))

    free = model.joints[1].shortname() == "JointModelFreeFlyer" if model.njoints > 1 else False
    planar = model.njoints > 1 and model.joints[1].shortname() == "JointModelPlanar"
    bodies = cfg["bodies"] is not None or cfg["array"] is not None
    # An MJCF top body's own slides and hinges (dm_control's planar walkers: rootx, rootz, rooty), one
    # composite joint in Pinocchio: an unactuated root like a free flyer's.
    slid_root = (mjcf_robot is not None and model.njoints > 1 and model.parents[1] == 0
                 and model.joints[1].shortname() == "JointModelComposite")
    if mjcf_robot is not None and any(c.model == _core.ContactModel.planar for c in contacts):
        _check_planar_motion(model, q0)
    for key in ("base_velocity", "base_xy"):
        if initial[key] is not None and not free:
            raise SceneError(f"initial.{key}: the model has no free-flyer base" +
                             (" (planar joint: initial.planar_velocity)" if planar else ""))
    if initial["planar_velocity"] is not None and not planar:
        raise SceneError("initial.planar_velocity: the model has no planar root joint (joint = \"planar\")")
    if initial["top_velocity"] is not None and not bodies:
        raise SceneError("initial.top_velocity applies to `bodies` scenes only")
    v0 = np.zeros(model.nv)
    if free and not bodies and not anchors:
        if initial["base_xy"] is not None or initial["q"] is None:
            q0[:2] = initial["base_xy"] if initial["base_xy"] is not None else [0.0, 0.0]
        # lower (or raise) the base so the lowest contact touches z = 0, plus `drop`
        lowest = _lowest_contact(model, q0, contacts, geometry, pairs)
        if math.isfinite(lowest) and initial["q"] is None:
            q0[2] += -lowest + initial["drop"]
        if initial["base_velocity"] is not None:
            v0[:6] = initial["base_velocity"]
    elif bodies:
        if initial["top_velocity"] is not None:
            v0[-6:] = initial["top_velocity"]
        if initial["base_velocity"] is not None:
            v0[:6] = initial["base_velocity"]
    elif slid_root and not anchors:
        if initial["q"] is None:  # lower (or raise) it along its vertical slide so its lowest contact touches
            iz = _vertical_coordinate(model, q0)
            lowest = _lowest_contact(model, q0, contacts, geometry, pairs)
            if iz is not None and math.isfinite(lowest):
                q0[iz] += -lowest + initial["drop"]
    elif planar and not anchors:
        if initial["q"] is None:  # lower (or raise) the body so its lowest contact touches z = 0, plus `drop`
            lowest = _lowest_contact(model, q0, contacts, None, [])  # (its sphere/point contacts)
            if math.isfinite(lowest):
                q0[1] += -lowest + initial["drop"]  # joint y = world z
        if initial["planar_velocity"] is not None:
            v0[:3] = initial["planar_velocity"]
    elif initial["base_velocity"] is not None:
        v0[:6] = initial["base_velocity"]
    elif planar and initial["planar_velocity"] is not None:
        v0[:3] = initial["planar_velocity"]

    kp = np.zeros(model.nv)
    kd = np.zeros(model.nv)
    start = 6 if free else 3 if planar else model.joints[1].nv if slid_root else 0
    root_nq = 7 if free else 4 if planar else model.joints[1].nq if slid_root else 0
    kp[start:robot_nv] = control["kp"]  # the robot's joints (objects are not actuated)
    kd[start:robot_nv] = control["kd"]
    _per_joint_gains(model, control["gains"], start, robot_nv, kp, kd)
    q_target = q0.copy()
    if control["q_target"] is not None:
        joints = np.asarray(control["q_target"], dtype=float)
        if joints.shape != (robot_nq - root_nq,):
            raise SceneError(f"control.q_target needs the {robot_nq - root_nq} joint positions, "
                             f"got {joints.shape[0]}")
        q_target[root_nq:robot_nq] = joints
    tau_ff = np.zeros(model.nv)
    if control["gravity_feedforward"]:
        if free:
            if pairs:
                raise SceneError("control.gravity_feedforward: a free-flyer robot stands on its sphere/point contacts; "
                                 "the [collision] pairs' contact points are not known before the step")
            tau_ff = standing_feedforward(model, q_target, contacts, halfspaces, robot_nv)
        elif slid_root:
            raise SceneError("control.gravity_feedforward: not for a robot on an unactuated root of slides and "
                             "hinges (its weight rests on its contacts); use the PD alone")
        else:
            tau_ff = pin.computeGeneralizedGravity(model, model.createData(), q_target).copy()
        tau_ff[:start] = 0.0
        tau_ff[robot_nv:] = 0.0

    return Scene(
        name=cfg["name"] or default_name, description=cfg["description"], model=model,
        visual_model=visual, halfspaces=halfspaces, contacts=contacts, anchors=anchors, q0=q0, v0=v0, kp=kp, kd=kd,
        q_target=q_target, tau_ff=tau_ff, geometry=geometry, pairs=pairs,
        duration=cfg["duration"], dt=cfg["dt"], settle_time=cfg["settle_time"],
        mode=cfg["mode"], delta=cfg["delta"], zeta=cfg["zeta"],
        slope_deg=slope_deg, mu=mu, config=cfg)


def _lowest_contact(model: pin.Model, q: np.ndarray, contacts: list, geometry, pairs: list) -> float:
    """The lowest gap to the ground z = 0 at q: of the sphere/point contacts on it and of the coal
    pairs with "ground" (inf when there is none)."""
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    lowest = min((data.oMf[c.frame].act(c.offset)[2] - c.radius for c in contacts if c.halfspace == 0),
                 default=math.inf)
    if geometry is not None:
        gdata = geometry.createData()
        pin.updateGeometryPlacements(model, data, geometry, gdata)
        for gp in pairs:
            cp = geometry.collisionPairs[gp.pair]
            if "ground" in (geometry.geometryObjects[cp.first].name, geometry.geometryObjects[cp.second].name):
                lowest = min(lowest, pin.computeDistance(geometry, gdata, gp.pair).min_distance)
    return float(lowest)


def _vertical_coordinate(model: pin.Model, q: np.ndarray) -> int | None:
    """The coordinate of the root joint that translates its body straight up (a slide along world
    z: raising it by 1 moves the body by (0, 0, 1) without turning it), or None."""
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    before = data.oMi[1].copy()
    for i in range(model.joints[1].idx_q, model.joints[1].idx_q + model.joints[1].nq):
        moved = q.copy()
        moved[i] += 1.0
        pin.forwardKinematics(model, data, moved)
        if (np.allclose(data.oMi[1].translation - before.translation, [0.0, 0.0, 1.0], atol=1e-12)
                and np.allclose(data.oMi[1].rotation, before.rotation, atol=1e-12)):
            return i
    return None


def _check_planar_motion(model: pin.Model, q: np.ndarray) -> None:
    """Planar contacts (rows t1 = x, n: none across the plane) in an `mjcf` scene: everything must
    move in the world's x-z plane only (no joint's motion has a y velocity or an x or z rotation at
    q; a free object's does), else friction across the plane would be missing."""
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    for j in range(1, model.njoints):
        J = pin.getJointJacobian(model, data, j, pin.ReferenceFrame.WORLD)
        if np.max(np.abs(J[[1, 3, 5], :])) > 1e-12:
            raise SceneError(f"contacts.model = \"planar\": the scene does not move in the world's x-z plane only "
                             f"(joint {model.names[j]!r} moves out of it); use spatial contacts")


def _named_joint_positions(model: pin.Model, q: np.ndarray, joints: dict, explicit_q: bool) -> np.ndarray:
    """[initial] joints: q with the named 1-dof joints set (over the reference posture)."""
    if explicit_q:
        raise SceneError("initial.joints sets joints of the reference posture; initial.q gives every joint "
                         "itself: give one of them")
    names = [model.names[j] for j in range(1, model.njoints)]
    out = q.copy()
    for name, value in joints.items():
        if not model.existJointName(name):
            hint = did_you_mean(name, names)
            raise SceneError(f"initial.joints: no joint {name!r} in the model ({hint}joints: {', '.join(names)})")
        joint = model.joints[model.getJointId(name)]
        if joint.nq != 1:
            raise SceneError(f"initial.joints: {name!r} has {joint.nq} coordinates; name 1-dof joints (or give "
                             "initial.q)")
        out[joint.idx_q] = value
    return out


def _per_joint_gains(model: pin.Model, gains: list, start: int, robot_nv: int, kp: np.ndarray,
                     kd: np.ndarray) -> None:
    """[[control.gains]]: kp, kd of the robot's actuated joints whose names match a pattern, in
    place; every pattern must match a joint."""
    import fnmatch

    joints = [j for j in range(1, model.njoints) if start <= model.joints[j].idx_v < robot_nv]
    names = [model.names[j] for j in joints]
    for k, entry in enumerate(gains):
        for pattern in entry["joints"]:
            matched = [j for j, n in zip(joints, names) if fnmatch.fnmatchcase(n, pattern)]
            if not matched:
                hint = did_you_mean(pattern, names)
                raise SceneError(f"control.gains[{k}].joints: {pattern!r} matches no actuated joint ({hint}joints: "
                                 f"{', '.join(names) or 'none'})")
            for j in matched:
                iv, nvj = model.joints[j].idx_v, model.joints[j].nv
                if entry["kp"] is not None:
                    kp[iv:iv + nvj] = entry["kp"]
                if entry["kd"] is not None:
                    kd[iv:iv + nvj] = entry["kd"]


def _joint_overrides(model: pin.Model, entries: list) -> None:
    """[[joints.override]]: the position limits, dry friction, damping and effort limits of the joints
    whose names match a pattern, in place; every pattern must match a joint."""
    import fnmatch

    names = [model.names[j] for j in range(1, model.njoints)]
    for k, entry in enumerate(entries):
        for pattern in entry["joints"]:
            matched = [j for j in range(1, model.njoints) if fnmatch.fnmatchcase(model.names[j], pattern)]
            if not matched:
                hint = did_you_mean(pattern, names)
                raise SceneError(f"joints.override[{k}].joints: {pattern!r} matches no joint ({hint}joints: "
                                 f"{', '.join(names) or 'none'})")
            for j in matched:
                joint = model.joints[j]
                iv, nvj, iq = joint.idx_v, joint.nv, joint.idx_q
                for key, array in (("friction", model.friction), ("damping", model.damping),
                                   ("effort", model.effortLimit)):
                    if entry[key] is not None:
                        array[iv:iv + nvj] = entry[key]
                for key, array in (("lower", model.lowerPositionLimit), ("upper", model.upperPositionLimit)):
                    if entry[key] is None:
                        continue
                    if joint.nq != 1 or joint.nv != 1:
                        raise SceneError(f"joints.override[{k}].{key}: joint {model.names[j]!r} is not a 1-dof joint "
                                         "(position limits apply to revolute and prismatic joints)")
                    array[iq] = entry[key]
                if model.lowerPositionLimit[iq] > model.upperPositionLimit[iq]:
                    raise SceneError(f"joints.override[{k}]: joint {model.names[j]!r} would have lower limit "
                                     f"{model.lowerPositionLimit[iq]:g} above its upper limit "
                                     f"{model.upperPositionLimit[iq]:g}")


STANDING_CONTACT_TOLERANCE = 1e-6  # m: a contact within this of the lowest one carries weight


def standing_feedforward(model: pin.Model, q: np.ndarray, contacts: list, halfspaces: list,
                         robot_nv: int | None = None) -> np.ndarray:
    """The joint torques that hold a free-flyer robot still at q on its contacts (nv entries, the
    base's rows 0): the static equilibrium of the equations of motion M q'' + Φ = J^T lambda
    (eq. 39) at rest, where Φ(q, 0) = g(q) - S^T tau:

        g(q) = S^T tau + J(q)^T lambda,

    whose 6 base rows g_b = J_b^T lambda (the weight and its moment) fix lambda up to the split
    among the contacts; the split taken is the least-norm one (a linear spread of the normal
    forces, no tangential force a flat ground does not need), and tau = g_a - J_a^T lambda.

    The contacts are the robot's spheres and points on a half-space (the ground, a wall, a face
    of a free object taken where it is) whose gap at q, the robot lowered onto its lowest one, is
    within STANDING_CONTACT_TOLERANCE of it. A split that needs a pulling contact or a force
    outside a friction cone is an error (the robot cannot stand there on these contacts)."""
    nv = model.nv if robot_nv is None else robot_nv
    data = model.createData()
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    g = pin.computeGeneralizedGravity(model, data, q)
    data_h = model.createData()  # half-spaces carried by bodies, where they are at q
    pin.framesForwardKinematics(model, data_h, q)
    rows, normals, mus, names, gaps = [], [], [], [], []
    for c in contacts:
        frame = model.frames[c.frame]
        if model.joints[frame.parentJoint].idx_v >= nv:
            continue  # a free object's own contact (its corner on the ground), not the robot's
        h = halfspaces[c.halfspace]
        place = data_h.oMf[h.frame] if h.frame else pin.SE3.Identity()
        normal = place.rotation @ (np.asarray(h.normal) / np.linalg.norm(h.normal))
        centre = data.oMf[c.frame].act(np.asarray(c.offset, dtype=float))
        offset = float(h.offset) + float(normal @ place.translation)
        gaps.append(float(normal @ centre) - offset - c.radius)
        point = centre - c.radius * normal - data.oMf[c.frame].translation
        J = pin.getFrameJacobian(model, data, c.frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        rows.append(J[:3, :nv] - pin.skew(point) @ J[3:, :nv])  # the material point at the contact
        normals.append(normal)
        mus.append(c.mu)
        names.append(c.name)
    if not rows:
        raise SceneError("control.gravity_feedforward: the free-flyer robot has no contact to stand on")
    gaps = np.asarray(gaps)
    touching = np.flatnonzero(gaps <= gaps.min() + STANDING_CONTACT_TOLERANCE)
    J = np.vstack([rows[i] for i in touching])  # (3k, nv), world-frame point velocities
    weight = g[:6]
    lam, *_ = np.linalg.lstsq(J[:, :6].T, weight, rcond=None)
    if np.linalg.norm(J[:, :6].T @ lam - weight) > 1e-9 * max(1.0, np.linalg.norm(weight)):
        raise SceneError(f"control.gravity_feedforward: the contacts touching at q_target "
                         f"({', '.join(names[i] for i in touching)}) cannot balance the robot's weight and its "
                         "moment (a line or a point of support)")
    forces = lam.reshape(-1, 3)
    for k, i in enumerate(touching):
        fn = float(forces[k] @ normals[i])
        ft = float(np.linalg.norm(forces[k] - fn * normals[i]))
        if fn < -1e-9 * np.linalg.norm(weight) or ft > mus[i] * fn + 1e-9 * np.linalg.norm(weight):
            raise SceneError(f"control.gravity_feedforward: standing at q_target needs contact {names[i]!r} to "
                             f"{'pull' if fn < 0 else 'slip'} (normal {fn:.4g} N, tangential {ft:.4g} N, mu "
                             f"{mus[i]:g}): its weight is not over its support")
    tau = g[:nv] - J.T @ lam
    out = np.zeros(model.nv)
    out[6:nv] = tau[6:]
    return out


def _frame_id(model: pin.Model, name: str, field: str) -> int:
    if not model.existFrame(name):
        hint = did_you_mean(name, [f.name for f in model.frames])
        raise SceneError(f"{field}: no frame {name!r} in the model" + (f" ({hint.strip()})" if hint else ""))
    return model.getFrameId(name)


def _collision_pairs(cfg: dict, model: pin.Model, mu: float, urdf_path: Path | None,
                     mjcf_collision: pin.GeometryModel | None = None):
    """The coal geometry model and pairs of the [collision] table (an `mjcf` scene: among the
    MJCF's geoms of moving bodies)."""
    import coal

    col = cfg["collision"]
    if mjcf_collision is not None:
        geometry = mjcf_collision.copy()
    elif cfg["robot"] is not None:
        from .robots import ROBOTS, robots_dir

        urdf, package_dirs = robots_dir() / ROBOTS[cfg["robot"]].urdf, robot_package_dirs()
    elif urdf_path is not None:
        urdf, package_dirs = urdf_path, _package_dirs(urdf_path)
    else:
        raise SceneError("collision: needs a `robot`, `urdf` or `mjcf` scene")
    if mjcf_collision is None:
        # the mesh search paths matter: a bundled robot's collision meshes are package:// URIs
        geometry = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.COLLISION, package_dirs=package_dirs)
    geometry.addGeometryObject(pin.GeometryObject("ground", 0, pin.SE3.Identity(),
                                                  coal.Halfspace(np.array([0.0, 0.0, 1.0]), 0.0)))
    for k, box in enumerate(col["boxes"]):
        if box["name"] in [g.name for g in geometry.geometryObjects]:
            raise SceneError(f"collision.boxes[{k}].name: {box['name']!r} is already a geometry name")
        place = pin.SE3(np.eye(3), np.asarray(box["position"], dtype=float))
        geometry.addGeometryObject(pin.GeometryObject(box["name"], 0, place, coal.Box(*box["size"])))
    names = [g.name for g in geometry.geometryObjects]
    pairs = []
    for k, (a, b) in enumerate(col["pairs"]):
        for n in (a, b):
            if n not in names:
                hint = did_you_mean(n, names)
                raise SceneError(f"collision.pairs[{k}]: no geometry {n!r} ({hint}known: {', '.join(names)})")
        if a == b:
            raise SceneError(f"collision.pairs[{k}]: a geometry cannot collide with itself ({a!r})")
        geometry.addCollisionPair(pin.CollisionPair(names.index(a), names.index(b)))
        gp = _core.GeometryPairContact()
        gp.name, gp.pair = f"{a}|{b}", len(geometry.collisionPairs) - 1
        gp.mu, gp.max_contacts = mu if col["mu"] is None else col["mu"], col["max_contacts"]
        gp.model = getattr(_core.ContactModel, col["model"])
        gp.patch = col["patch"]
        pairs.append(gp)
    return geometry, pairs


def scene_from_model(model: pin.Model, visual_model: pin.GeometryModel | None = None, q0=None, *,
                     name: str = "model", spheres=(), mu: float = 0.5, slope_deg: float = 0.0, kp: float = 0.0,
                     kd: float = 0.0, dt: float = 1e-3, duration: float = 1.0, settle_time: float = 0.0,
                     place_on_ground: bool = True, collision_model: pin.GeometryModel | None = None,
                     pairs=(), max_contacts: int = 4) -> Scene:
    """A scene from the pinocchio.Model (and GeometryModels) you already have.

    spheres: (frame name, radius) or (frame name, radius, offset) contact spheres against the
    ground z = 0 (the analytic path). pairs: (geometry name, geometry name) of `collision_model`
    handled by coal; the name "ground" is the plane z = 0 (added to a copy of the model).
    With place_on_ground the free-flyer base is lowered so the lowest sphere touches.
    """
    if not isinstance(model, pin.Model):
        raise TypeError(f"model must be a pinocchio.Model, got {type(model).__name__}")
    for label, gm in (("visual_model", visual_model), ("collision_model", collision_model)):
        if gm is not None and not isinstance(gm, pin.GeometryModel):
            raise TypeError(f"{label} must be a pinocchio.GeometryModel or None, got {type(gm).__name__}")
    checked = validate_scene({"urdf": "-", "ground": {"mu": mu, "slope_deg": slope_deg}, "control": {"kp": kp, "kd": kd},
                              "dt": dt, "duration": duration, "settle_time": settle_time}, "scene_from_model")
    mu, slope_deg, kp, kd = checked["ground"]["mu"], checked["ground"]["slope_deg"], checked["control"]["kp"], \
        checked["control"]["kd"]
    dt, duration, settle_time = checked["dt"], checked["duration"], checked["settle_time"]
    if isinstance(max_contacts, bool) or not isinstance(max_contacts, int) or not 1 <= max_contacts <= 64:
        raise ValueError(f"max_contacts must be an integer in 1..64, got {max_contacts!r}")
    model = model.copy()
    visual_model = visual_model if visual_model is not None else pin.GeometryModel()
    if q0 is None:
        q = pin.neutral(model)
    else:
        q = _quaternion_check(model, vector("q0", q0, model.nq), "q0", strict=False)
    contacts = []
    for k, spec in enumerate(spheres):
        if isinstance(spec, (str, bytes)) or not hasattr(spec, "__len__") or len(spec) not in (2, 3):
            raise ValueError(f"spheres[{k}] must be (frame name, radius) or (frame name, radius, offset), got {spec!r}")
        frame = spec[0]
        radius = validate_scene({"urdf": "-", "contacts": {"radius": spec[1]}}, f"spheres[{k}]")["contacts"]["radius"]
        offset = spec[2] if len(spec) > 2 else (0.0, 0.0, 0.0)
        if not isinstance(frame, str) or not model.existFrame(frame):
            raise ValueError(f"spheres[{k}]: no frame {frame!r} in the model")
        contacts.append(_sphere(frame, model.getFrameId(frame), offset, radius, 0, mu))
    th = math.radians(slope_deg)
    model.gravity = pin.Motion(np.array([GRAVITY * math.sin(th), 0.0, -GRAVITY * math.cos(th)]), np.zeros(3))
    free = model.njoints > 1 and model.joints[1].shortname() == "JointModelFreeFlyer"
    if free and place_on_ground and contacts:
        data = model.createData()
        pin.framesForwardKinematics(model, data, q)
        q[2] -= min(data.oMf[c.frame].act(np.asarray(c.offset))[2] - c.radius for c in contacts)
    start = 6 if free else 0
    kpv, kdv = np.zeros(model.nv), np.zeros(model.nv)
    kpv[start:], kdv[start:] = kp, kd
    geometry, pair_list = None, []
    if pairs:
        import coal

        if collision_model is None:
            raise ValueError("pairs need a collision_model (a pinocchio.GeometryModel)")
        geometry = collision_model.copy()
        names = [g.name for g in geometry.geometryObjects]
        if "ground" not in names:
            geometry.addGeometryObject(pin.GeometryObject("ground", 0, pin.SE3.Identity(),
                                                          coal.Halfspace(np.array([0.0, 0.0, 1.0]), 0.0)))
            names.append("ground")
        for a, b in pairs:
            for n in (a, b):
                if n not in names:
                    raise ValueError(f"pairs: no geometry {n!r} in the collision model")
            geometry.addCollisionPair(pin.CollisionPair(names.index(a), names.index(b)))
            gp = _core.GeometryPairContact()
            gp.name, gp.pair, gp.mu, gp.max_contacts = f"{a}|{b}", len(geometry.collisionPairs) - 1, mu, max_contacts
            pair_list.append(gp)
    return Scene(name=name, description="built from a pinocchio.Model", model=model, visual_model=visual_model,
                 halfspaces=[_halfspace("ground", (0, 0, 1), 0.0)], contacts=contacts, anchors=[], q0=q,
                 v0=np.zeros(model.nv), kp=kpv, kd=kdv, q_target=q.copy(), tau_ff=np.zeros(model.nv),
                 duration=duration, dt=dt, settle_time=settle_time, mode="timestep", delta=0.0, zeta=0.5,
                 slope_deg=slope_deg, mu=mu, geometry=geometry, pairs=pair_list)


def _load_box(path: str, base_dir, label: str, balls: bool = False):
    """A box URDF (balls: or a ball URDF) as a free body: (model, visual model, half extents of the
    box, or the ball's radius as a float)."""
    import coal

    urdf = _resolve(path, base_dir)
    body = load_urdf(urdf, True, _package_dirs(urdf), name="body")
    half = _box_half_extents(body.visual_model)
    if half is not None:
        return body.model, body.visual_model, half
    if balls:
        for go in body.visual_model.geometryObjects:
            if isinstance(go.geometry, coal.Sphere):
                return body.model, body.visual_model, float(go.geometry.radius)
        raise SceneError(f"{label} = {path!r}: a pile's bodies must be boxes or balls (a URDF with a box or "
                         "sphere visual)")
    raise SceneError(f"{label} = {path!r}: the bodies must be boxes (a URDF with a box visual)")


def _append_box(model, visual, path: str, k, base_dir, label: str, cache: dict | None = None,
                balls: bool = False):
    """Box URDF number k appended to (model, visual) as a free body with names suffixed _k; returns
    the model, visual, the body's frame and its half extents (balls: or a ball's radius). The URDF
    is read once per `cache`; its joints, frames and visuals are added to `model` in place
    (pin.appendModel copies the whole model each time: 3 s for 256 cubes)."""
    cache = {} if cache is None else cache
    if path not in cache:
        cache[path] = _load_box(path, base_dir, label, balls)
    body, body_visual, half = cache[path]
    joints = {0: 0}
    for j in range(1, body.njoints):
        joints[j] = model.addJoint(joints[body.parents[j]], body.joints[j], body.jointPlacements[j],
                                   f"{body.names[j]}_{k}")
        model.appendBodyToJoint(joints[j], body.inertias[j], pin.SE3.Identity())
    frames = {0: 0}
    body_frame = None
    for i in range(1, body.nframes):
        f = body.frames[i]
        frames[i] = model.addFrame(pin.Frame(f"{f.name}_{k}", joints[f.parentJoint], frames[f.parentFrame],
                                             f.placement, f.type, f.inertia), False)  # inertia: appended above
        if f.type == pin.FrameType.BODY:
            body_frame = frames[i]
    for go in body_visual.geometryObjects:
        copy = go.copy()
        copy.name = f"{go.name}_{k}"
        copy.parentJoint = joints[go.parentJoint]
        copy.parentFrame = frames[go.parentFrame]
        visual.addGeometryObject(copy)
    return model, visual, body_frame, half


def _grid_bodies(path: str, count: int, spacing: float | None, mu: float, base_dir=None, cmodel: str = "spatial"):
    """`count` free boxes side by side on the ground, in rows of ceil(sqrt(count)), centred on the
    origin; each box's four bottom corners touch the ground."""
    model, visual = pin.Model(), pin.GeometryModel()
    contacts, q_parts, cache = [], [], {}
    per_row = math.ceil(math.sqrt(count))
    rows = math.ceil(count / per_row)
    for k in range(count):
        model, visual, frame, half = _append_box(model, visual, path, k, base_dir, "array.urdf", cache)
        step = spacing if spacing is not None else 4.0 * float(max(half[0], half[1]))
        if spacing is not None and spacing <= 2.0 * float(max(half[0], half[1])):
            raise SceneError(f"array.spacing = {spacing:g}: the boxes would overlap (their width is "
                             f"{2 * max(half[0], half[1]):g} m)")
        i, j = divmod(k, per_row)
        x, y = (j - (per_row - 1) / 2) * step, (i - (rows - 1) / 2) * step
        for c, corner in enumerate(_corners(half, z_sign=-1)):
            contacts.append(_sphere(f"body{k}-corner{c}", frame, corner, 0.0, 0, mu, cmodel))
        q_parts.append(np.array([x, y, float(half[2]), 0.0, 0.0, 0.0, 1.0]))
    return model, visual, np.concatenate(q_parts), contacts


def _stacked_bodies(paths: list[str], mu: float, halfspaces: list, base_dir=None, cmodel: str = "spatial"):
    """Free-flying URDF boxes stacked on the ground in the listed order: each box's
    bottom corners touch the ground (the first) or the top face of the box below."""
    model = pin.Model()
    visual = pin.GeometryModel()
    contacts = []
    q_parts = []
    z = 0.0
    below_frame = None
    below_half = None
    cache = {}
    for k, path in enumerate(paths):
        model, visual, body_frame, half = _append_box(model, visual, path, k, base_dir, f"bodies[{k}]", cache)
        if below_frame is None:
            target = 0
        else:
            halfspaces.append(_halfspace(f"top of body{k - 1}", (0, 0, 1), float(below_half[2]), below_frame))
            target = len(halfspaces) - 1
        for c, corner in enumerate(_corners(half, z_sign=-1)):
            contacts.append(_sphere(f"body{k}-corner{c}", body_frame, corner, 0.0, target, mu, cmodel))
        z += half[2]
        q_parts.append(np.array([0.0, 0.0, z, 0.0, 0.0, 0.0, 1.0]))
        z += half[2]
        below_frame, below_half = body_frame, half
    return model, visual, np.concatenate(q_parts), contacts, halfspaces


PILE_MAX_BODIES = 256  # the broad phase tests every pair of bodies (count^2 / 2 bounding-sphere checks)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit quaternion (x, y, z, w): a normalised Gaussian 4-vector."""
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _pile_bodies(paths: list[str], count: int, spacing: float | None, seed: int, mu: float, base_dir=None,
                 cmodel: str = "spatial"):
    """`count` boxes and balls drawn from `paths` with the random `seed`, at random orientations
    on a jittered lattice of ceil(count^(1/3)) bodies a side above the ground, no two overlapping:
    they fall into a pile. Each box's eight corners and each ball touch the ground as point and
    sphere contacts (analytic); every pair of bodies is a coal pair with contact patches (four
    points for faces, one with a ball), checked by coal only when their bounding spheres come
    within the activation distance. Returns model, visual, q0, contacts, geometry, pairs."""
    import coal

    if count > PILE_MAX_BODIES:
        raise SceneError(f"array.count = {count}: a pile holds at most {PILE_MAX_BODIES} bodies (its broad phase "
                         "checks every pair)")
    rng = np.random.default_rng(seed)
    model, visual, geometry = pin.Model(), pin.GeometryModel(), pin.GeometryModel()
    cache: dict = {}
    for k, path in enumerate(paths):  # every kind read (and checked) once, whether drawn or not
        cache[path] = _load_box(path, base_dir, f"array.urdfs[{k}]", balls=True)
    shapes = {p: cache[p][2] for p in paths}
    radius = {p: float(np.linalg.norm(h)) if isinstance(h, np.ndarray) else h for p, h in shapes.items()}
    largest = max(radius.values())
    step = spacing if spacing is not None else 2.4 * largest
    if step <= 2.0 * largest:
        raise SceneError(f"array.spacing = {step:g}: bodies on the lattice could overlap (the largest body's "
                         f"bounding diameter is {2 * largest:g} m)")
    side = math.ceil(count ** (1.0 / 3.0) - 1e-9)
    jitter = 0.45 * (step - 2.0 * largest)  # each centre moves at most this far along each axis
    kinds = [paths[int(i)] for i in rng.integers(len(paths), size=count)]
    contacts, q_parts, frames = [], [], []
    for k, path in enumerate(kinds):
        model, visual, frame, shape = _append_box(model, visual, path, k, base_dir, "array.urdfs", cache)
        frames.append(frame)
        layer, rest = divmod(k, side * side)
        i, j = divmod(rest, side)
        centre = np.array([(j - (side - 1) / 2) * step, (i - (side - 1) / 2) * step,
                           largest + 0.5 * step + layer * step]) + rng.uniform(-jitter, jitter, size=3)
        q_parts.append(np.concatenate([centre, _random_rotation(rng)]))
        joint = model.frames[frame].parentJoint
        if isinstance(shape, np.ndarray):
            for c, corner in enumerate(_corners(shape)):
                contacts.append(_sphere(f"body{k}-corner{c}", frame, corner, 0.0, 0, mu, cmodel))
            collision = coal.Box(*(2.0 * shape))
        else:
            contacts.append(_sphere(f"body{k}-ball", frame, (0, 0, 0), shape, 0, mu, cmodel))
            collision = coal.Sphere(shape)
        geometry.addGeometryObject(pin.GeometryObject(f"body{k}", joint, frame, model.frames[frame].placement,
                                                      collision))
    pairs = []
    for a in range(count):
        for b in range(a + 1, count):
            geometry.addCollisionPair(pin.CollisionPair(a, b))
            gp = _core.GeometryPairContact()
            gp.name, gp.pair, gp.mu = f"body{a}|body{b}", len(geometry.collisionPairs) - 1, mu
            both_boxes = isinstance(shapes[kinds[a]], np.ndarray) and isinstance(shapes[kinds[b]], np.ndarray)
            gp.max_contacts = 4 if both_boxes else 1
            gp.model = getattr(_core.ContactModel, cmodel)
            gp.patch = True
            pairs.append(gp)
    return model, visual, np.concatenate(q_parts), contacts, geometry, pairs
