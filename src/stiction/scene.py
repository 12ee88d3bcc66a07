"""Scenes: a robot or rigid bodies, a ground (slope, friction), the contacts the scene needs,
the initial state and the control. Every scene is a TOML file in ``robots/scenes/``.

A slope of angle θ is modelled by tilting gravity, g = 9.81 (sin θ, 0, -cos θ): the ground stays
the plane z = 0 and "downhill" is +x. Recordings rotate the picture back.

Keys (all optional unless stated):

    name, description
    robot = "solo12"                      # a name of stiction.robots.ROBOTS, or
    urdf = "cube.urdf"                    # a URDF path (relative to robots/), with free_flyer = true
    bodies = ["cube.urdf", "cube.urdf"]   # several free-flying URDF bodies, stacked in the listed order
    duration, dt, settle_time             # seconds
    mode = "timestep" | "rk4" | "adaptive"; delta, zeta (ODE modes)
    [ground]   slope_deg, mu
    [contacts] feet = true (the robot's foot spheres), radius, box_corners = true (URDF box visuals)
    [control]  kp, kd (joint PD towards the initial posture, or q_target = [...]),
               gravity_feedforward = true (tau_ff = g(q_target)), lock_joints = true (a rigid robot)
    [initial]  q = [...] (full configuration), base_velocity = [vx, vy, vz, wx, wy, wz],
               base_xy = [x, y], drop = 0.0 (m above touch)
    [[walls]]  name, normal, offset (free space: normal . x >= offset), frames (spheres on them),
               radius, mu
    [[anchors]] frame, offset (in the frame), target (world; default: where the point is at q0),
               or frame2, offset2 (a point of another body: a closed loop): 3 bilateral rows
               each (paper §3)
    [collision] general shapes through coal, for what the analytic spheres and points do not
               cover: pairs = [["geometry a", "geometry b"], ...] among the URDF's collision
               geometries, "ground" (the plane z = 0) and fixed world boxes
               [[collision.boxes]] name, size = [x, y, z], position = [x, y, z]; max_contacts
"""
from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from . import _core
from .robots import load_robot, load_urdf

SCENES_DIR = Path(__file__).resolve().parents[2] / "robots" / "scenes"
ROBOTS_DIR = Path(__file__).resolve().parents[2] / "robots"
GRAVITY = 9.81


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

    def settings(self, **overrides) -> _core.SimulatorSettings:
        s = _core.SimulatorSettings()
        s.dt = overrides.get("dt", self.dt)
        mode = overrides.get("mode", self.mode)
        modes = {"timestep": _core.IntegrationMode.timestep, "rk4": _core.IntegrationMode.rk4,
                 "adaptive": _core.IntegrationMode.adaptive, "ode": _core.IntegrationMode.rk4}
        if mode not in modes:
            raise ValueError(f"unknown integration mode {mode!r} (timestep, rk4, adaptive, ode)")
        s.mode = modes[mode]
        s.delta = overrides.get("delta", self.delta)
        s.zeta = overrides.get("zeta", self.zeta)
        s.tolerance = overrides.get("tolerance", 1e-10)
        s.max_iterations = overrides.get("max_iterations", 200)
        s.solver = overrides.get("solver", "default")
        if "ode_tolerance" in overrides:
            s.ode_tolerance = overrides["ode_tolerance"]
        return s


def list_scenes() -> list[str]:
    return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def _resolve(path: str) -> Path:
    p = Path(path)
    for candidate in (p, ROBOTS_DIR / p):
        if candidate.is_file():
            return candidate
    raise FileNotFoundError(f"{path}: not found (relative paths are looked up in {ROBOTS_DIR})")


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


def _sphere(name: str, frame: int, offset, radius: float, halfspace: int, mu: float) -> _core.SphereContact:
    c = _core.SphereContact()
    c.name, c.frame, c.offset, c.radius, c.halfspace, c.mu = name, int(frame), np.asarray(offset, float), float(radius), int(halfspace), float(mu)
    return c


def _corners(half: np.ndarray, z_sign: float | None = None):
    out = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            for sz in (-1, 1):
                if z_sign is None or sz == z_sign:
                    out.append(np.array([sx, sy, sz]) * half)
    return out


def load_scene(name_or_path: str) -> Scene:
    """A scene by name (a file of robots/scenes/) or by path to a TOML file."""
    p = Path(name_or_path)
    if not p.suffix:
        p = SCENES_DIR / f"{name_or_path}.toml"
    if not p.is_file():
        raise ValueError(f"unknown scene {name_or_path!r}; known: {', '.join(list_scenes())}")
    with open(p, "rb") as fh:
        cfg = tomllib.load(fh)
    return build_scene(cfg, default_name=p.stem)


def build_scene(cfg: dict, default_name: str = "scene") -> Scene:
    ground = cfg.get("ground", {})
    slope_deg = float(ground.get("slope_deg", 0.0))
    mu = float(ground.get("mu", 0.5))
    if mu < 0:
        raise ValueError(f"ground mu must be >= 0, got {mu}")
    contacts_cfg = cfg.get("contacts", {})
    control = cfg.get("control", {})
    initial = cfg.get("initial", {})

    halfspaces = [_halfspace("ground", (0, 0, 1), 0.0)]
    contacts: list = []
    if "robot" in cfg or "urdf" in cfg:
        robot = (load_robot(cfg["robot"]) if "robot" in cfg
                 else load_urdf(_resolve(cfg["urdf"]), bool(cfg.get("free_flyer", True))))
        model, visual, q0 = robot.model, robot.visual_model, robot.q0.copy()
        spec = robot.spec
        if "q" in initial:
            q0 = np.asarray(initial["q"], dtype=float)
            if q0.shape != (model.nq,):
                raise ValueError(f"initial.q needs nq = {model.nq} entries, got {q0.shape[0]}")
        if control.get("lock_joints", False) and model.njoints > 2:
            # A rigid robot: every joint but the free flyer held at its initial value.
            lock = list(range(2, model.njoints))
            model, visual = pin.buildReducedModel(model, visual, lock, q0)
            q0 = q0[:7].copy()
        if contacts_cfg.get("feet", spec is not None and bool(spec.feet)):
            if spec is None or not spec.feet:
                raise ValueError("contacts.feet: this robot has no foot frames; list them with contacts.frames")
            radius = float(contacts_cfg.get("radius", spec.foot_radius))
            for f in spec.feet:
                contacts.append(_sphere(f, model.getFrameId(f), (0, 0, 0), radius, 0, mu))
        for frame_name in contacts_cfg.get("frames", []):
            if not model.existFrame(frame_name):
                raise ValueError(f"contacts.frames: no frame {frame_name!r} in the model")
            contacts.append(_sphere(frame_name, model.getFrameId(frame_name), (0, 0, 0),
                                    float(contacts_cfg.get("radius", 0.0)), 0, mu))
        if spec is not None and spec.points and contacts_cfg.get("soles", True):
            for frame_name, offset in spec.points:
                contacts.append(_sphere(f"{frame_name}{offset}", model.getFrameId(frame_name), offset, 0.0, 0, mu))
        if contacts_cfg.get("box_corners", False):
            half = _box_half_extents(visual)
            if half is None:
                raise ValueError("contacts.box_corners: the URDF has no box visual")
            body_frame = next(i for i, f in enumerate(model.frames) if f.type == pin.FrameType.BODY)
            for k, corner in enumerate(_corners(half)):
                contacts.append(_sphere(f"corner{k}", body_frame, corner, 0.0, 0, mu))
    elif "bodies" in cfg:
        model, visual, q0, contacts, halfspaces = _stacked_bodies(cfg["bodies"], mu, halfspaces)
    else:
        raise ValueError("a scene needs `robot`, `urdf` or `bodies`")

    for wall in cfg.get("walls", []):
        halfspaces.append(_halfspace(wall.get("name", f"wall{len(halfspaces)}"), wall["normal"], wall["offset"]))
        for frame_name in wall.get("frames", []):
            if not model.existFrame(frame_name):
                raise ValueError(f"walls.frames: no frame {frame_name!r} in the model")
            contacts.append(_sphere(f"{frame_name}-{wall.get('name', 'wall')}", model.getFrameId(frame_name),
                                    wall.get("offset_in_frame", (0, 0, 0)), float(wall.get("radius", 0.0)),
                                    len(halfspaces) - 1, float(wall.get("mu", mu))))

    geometry, pairs = None, []
    if "collision" in cfg:
        geometry, pairs = _collision_pairs(cfg, model, mu)

    anchors = []
    for k, a in enumerate(cfg.get("anchors", [])):
        if not model.existFrame(a["frame"]):
            raise ValueError(f"anchors[{k}]: no frame {a['frame']!r} in the model")
        pa = _core.PointAnchor()
        pa.name, pa.frame = a.get("name", f"anchor{k}"), model.getFrameId(a["frame"])
        pa.offset = np.asarray(a.get("offset", (0.0, 0.0, 0.0)), dtype=float)
        if "frame2" in a:  # a closed loop: held to a point of another body
            if not model.existFrame(a["frame2"]):
                raise ValueError(f"anchors[{k}]: no frame {a['frame2']!r} in the model")
            pa.frame2 = model.getFrameId(a["frame2"])
            pa.offset2 = np.asarray(a.get("offset2", (0.0, 0.0, 0.0)), dtype=float)
        elif "target" in a:
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
    v0 = np.zeros(model.nv)
    if free and "bodies" not in cfg and not anchors:
        if "base_xy" in initial or "q" not in initial:
            q0[:2] = initial.get("base_xy", [0.0, 0.0])
        # lower (or raise) the base so the lowest contact touches z = 0, plus `drop`
        data = model.createData()
        pin.framesForwardKinematics(model, data, q0)
        lowest = min((data.oMf[c.frame].act(c.offset)[2] - c.radius for c in contacts if c.halfspace == 0),
                     default=math.inf)
        if geometry is not None:  # coal pairs with the ground: their signed distances
            gdata = geometry.createData()
            pin.updateGeometryPlacements(model, data, geometry, gdata)
            for gp in pairs:
                cp = geometry.collisionPairs[gp.pair]
                if "ground" in (geometry.geometryObjects[cp.first].name, geometry.geometryObjects[cp.second].name):
                    lowest = min(lowest, pin.computeDistance(geometry, gdata, gp.pair).min_distance)
        if math.isfinite(lowest) and "q" not in initial:
            q0[2] += -lowest + float(initial.get("drop", 0.0))
        v0[:6] = initial.get("base_velocity", [0.0] * 6)
    elif "bodies" in cfg and "top_velocity" in initial:
        v0[6:12] = initial["top_velocity"]
    if "base_velocity" in initial and "bodies" in cfg:
        v0[:6] = initial["base_velocity"]

    kp = np.zeros(model.nv)
    kd = np.zeros(model.nv)
    start = 6 if free else 0
    kp[start:] = float(control.get("kp", 0.0))
    kd[start:] = float(control.get("kd", 0.0))
    q_target = q0.copy()
    if "q_target" in control:
        joints = np.asarray(control["q_target"], dtype=float)
        if joints.shape != (model.nq - (7 if free else 0),):
            raise ValueError(f"control.q_target needs the {model.nq - (7 if free else 0)} joint positions")
        q_target[(7 if free else 0):] = joints
    tau_ff = np.zeros(model.nv)
    if control.get("gravity_feedforward", False):
        tau_ff = pin.computeGeneralizedGravity(model, model.createData(), q_target).copy()
        tau_ff[:start] = 0.0

    dt = float(cfg.get("dt", 1e-3))
    return Scene(
        name=cfg.get("name", default_name), description=cfg.get("description", ""), model=model,
        visual_model=visual, halfspaces=halfspaces, contacts=contacts, anchors=anchors, q0=q0, v0=v0, kp=kp, kd=kd,
        q_target=q_target, tau_ff=tau_ff, geometry=geometry, pairs=pairs,
        duration=float(cfg.get("duration", 2.0)), dt=dt, settle_time=float(cfg.get("settle_time", 0.0)),
        mode=cfg.get("mode", "timestep"), delta=float(cfg.get("delta", 0.0)), zeta=float(cfg.get("zeta", 0.5)),
        slope_deg=slope_deg, mu=mu, config=cfg)


def _collision_pairs(cfg: dict, model: pin.Model, mu: float):
    """The coal geometry model and pairs of the [collision] table."""
    import coal

    col = cfg["collision"]
    if "urdf" in cfg:
        urdf = _resolve(cfg["urdf"])
    elif "robot" in cfg:
        from .robots import ROBOTS, robots_dir

        urdf = robots_dir() / ROBOTS[cfg["robot"]].urdf
    else:
        raise ValueError("collision: needs a `robot` or `urdf` scene")
    geometry = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.COLLISION)
    geometry.addGeometryObject(pin.GeometryObject("ground", 0, pin.SE3.Identity(),
                                                  coal.Halfspace(np.array([0.0, 0.0, 1.0]), 0.0)))
    for box in col.get("boxes", []):
        place = pin.SE3(np.eye(3), np.asarray(box["position"], dtype=float))
        geometry.addGeometryObject(pin.GeometryObject(box["name"], 0, place, coal.Box(*map(float, box["size"]))))
    names = [g.name for g in geometry.geometryObjects]
    pairs = []
    for a, b in col.get("pairs", []):
        for n in (a, b):
            if n not in names:
                raise ValueError(f"collision.pairs: no geometry {n!r} (known: {', '.join(names)})")
        geometry.addCollisionPair(pin.CollisionPair(names.index(a), names.index(b)))
        gp = _core.GeometryPairContact()
        gp.name, gp.pair = f"{a}|{b}", len(geometry.collisionPairs) - 1
        gp.mu, gp.max_contacts = float(col.get("mu", mu)), int(col.get("max_contacts", 4))
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
    model = model.copy()
    visual_model = visual_model if visual_model is not None else pin.GeometryModel()
    q = pin.neutral(model) if q0 is None else np.asarray(q0, dtype=float).copy()
    if q.shape != (model.nq,):
        raise ValueError(f"q0 needs nq = {model.nq} entries, got {q.shape}")
    contacts = []
    for spec in spheres:
        frame, radius = spec[0], float(spec[1])
        offset = spec[2] if len(spec) > 2 else (0.0, 0.0, 0.0)
        if not model.existFrame(frame):
            raise ValueError(f"spheres: no frame {frame!r} in the model")
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


def _stacked_bodies(paths: list[str], mu: float, halfspaces: list):
    """Free-flying URDF boxes stacked on the ground in the listed order: each box's
    bottom corners touch the ground (the first) or the top face of the box below."""
    model = pin.Model()
    visual = pin.GeometryModel()
    contacts = []
    q_parts = []
    z = 0.0
    below_frame = None
    below_half = None
    for k, path in enumerate(paths):
        body = load_urdf(_resolve(path), True, name=f"body{k}")
        half = _box_half_extents(body.visual_model)
        if half is None:
            raise ValueError(f"{path}: stacked bodies must be boxes")
        # prefix names so several copies can coexist
        for f in body.model.frames:
            f.name = f"{f.name}_{k}" if f.name != "universe" else f.name
        names = list(body.model.names)
        for j in range(1, len(names)):
            body.model.names[j] = f"{names[j]}_{k}"
        for go in body.visual_model.geometryObjects:
            go.name = f"{go.name}_{k}"
        model, visual = pin.appendModel(model, body.model, visual, body.visual_model, 0, pin.SE3.Identity())
        body_frame = max(i for i, f in enumerate(model.frames) if f.type == pin.FrameType.BODY)
        if below_frame is None:
            target = 0
        else:
            halfspaces.append(_halfspace(f"top of body{k - 1}", (0, 0, 1), float(below_half[2]), below_frame))
            target = len(halfspaces) - 1
        for c, corner in enumerate(_corners(half, z_sign=-1)):
            contacts.append(_sphere(f"body{k}-corner{c}", body_frame, corner, 0.0, target, mu))
        z += half[2]
        q_parts.append(np.array([0.0, 0.0, z, 0.0, 0.0, 0.0, 1.0]))
        z += half[2]
        below_frame, below_half = body_frame, half
    return model, visual, np.concatenate(q_parts), contacts, halfspaces
