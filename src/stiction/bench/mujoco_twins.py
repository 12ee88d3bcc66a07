"""The MuJoCo 4.0 twin of a stiction scene (the optional ``bench`` extra): the one place every bench
builds its MuJoCo models and runs them.

Every twin has the scene's masses, sizes, friction, gravity (a slope tilts it, as in stiction) and
time step; MuJoCo's own soft contact model otherwise (default ``solref``/``solimp``, margin 0,
``condim = 3``). Two ways to stand for the scene's contacts, each kept for the benches that use it:

- **the scene's own contacts** (:func:`mujoco_twin`, the robot benchmark
  ``benchmarks/bench_robots_mujoco.py``): bodies, joints and inertias from the scene's
  ``pinocchio.Model``, each stiction contact a sphere with an explicit ``<pair>`` against its
  half-space, the joint PD as affine actuators, the joints' limits, dry friction, damping and
  actuator effort limits as the stiction Simulator applies them (same switches: the scene's
  ``[joints]`` table and the Simulator's overrides), and maps between the two state vectors; it builds
  any scene made of free-flyer, revolute and prismatic joints whose contacts are spheres or points
  on half-spaces (section "Twins from the scene's model" below);
- **MuJoCo's own geometry** (the sweeps: ``stiction bench work-precision`` and ``scaling``, and
  ``benchmarks/bench_step_mujoco.py``): box geoms on a plane whose corners MuJoCo's collision
  detection finds (as stiction's four bottom corner points) — :func:`boxes_spec`,
  :func:`cube_array_spec` —, the pinch's pad spheres (:func:`pinch_spec`), and Solo-12 from its URDF
  (:func:`solo12_spec`).

Options, one function per setting:

- :func:`accurate_options` (robot twins, Solo-12 step bench, scaling): ``cone = elliptic``,
  ``solver = Newton``, ``iterations = 100``, ``tolerance = 1e-10``, ``impratio`` 1 unless given,
  ``integrator = implicitfast`` (stiction's joint PD is implicit too; the scaling's free cubes keep
  MuJoCo's default Euler), everything else at MuJoCo's defaults (``ls_iterations = 50``, no noslip,
  warm start on);
- :func:`apply_options` (work-precision): ``integrator = implicitfast``, the case's tolerance and,
  unless a variant says otherwise, MuJoCo's defaults: pyramidal cone, Newton, ``solref = (0.02, 1)``,
  ``impratio = 1``, no noslip. The variants (``VARIANTS``) change one thing each:

  - ``default``: as above;
  - ``stiff``: ``solref = (2 dt, 1)``, the stiffest time constant MuJoCo accepts at that step;
  - ``impratio10``: elliptic cones and ``impratio = 10`` (MuJoCo's advice against slip);
  - ``noslip``: 10 noslip iterations (the post-processing that removes tangential creep).

Running a twin: :func:`state_of`, :func:`solo12_state` (initial states), :func:`timed_rollout`
(``mujoco.rollout`` timed) and :func:`record` (an ``mj_step`` loop recording contacts for the exact
law's yardstick); :func:`contact_geometry` and :func:`contact_accuracy` measure a stiction and a
MuJoCo trajectory with the same code.
"""
from __future__ import annotations

import math
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

VARIANTS = ("default", "stiff", "impratio10", "noslip")
POINT_RADIUS = 1e-3  # m: the sphere standing for a stiction point contact
WALL_HALF_THICKNESS = 0.05  # m: the box standing for a half-space that moves with a body
WALL_HALF_WIDTH = 2.0  # m
ITERATIONS = 100
TOLERANCE = 1e-10


def _mujoco():
    import mujoco  # noqa: PLC0415 - optional

    return mujoco


def available() -> bool:
    try:
        _mujoco()
    except ImportError:
        return False
    return True


def accurate_options(spec, dt: float, gravity, impratio: float = 1.0, implicit: bool = True) -> None:
    """The robot twins' settings (module doc): the scene's time step and gravity, elliptic cones,
    Newton, ``ITERATIONS`` iterations to ``TOLERANCE``, `impratio`; ``implicitfast`` unless
    `implicit` is False (MuJoCo's default Euler: the scaling's free cubes)."""
    mj = _mujoco()
    if not np.isfinite(impratio) or impratio < 1.0:
        raise ValueError(f"impratio must be a finite number >= 1, got {impratio!r}")
    opt = spec.option
    opt.timestep = float(dt)
    opt.gravity = np.asarray(gravity, dtype=float)
    if implicit:
        opt.integrator = mj.mjtIntegrator.mjINT_IMPLICITFAST
    opt.cone = mj.mjtCone.mjCONE_ELLIPTIC
    opt.solver = mj.mjtSolver.mjSOL_NEWTON
    opt.iterations = ITERATIONS
    opt.tolerance = TOLERANCE
    opt.impratio = float(impratio)


def apply_options(spec, scene, dt: float, tol: float, variant: str) -> None:
    """The work-precision settings: time step, gravity, tolerance and the variant's (module doc)."""
    mj = _mujoco()
    if variant not in VARIANTS:
        raise ValueError(f"MuJoCo variant must be one of {', '.join(VARIANTS)}, got {variant!r}")
    opt = spec.option
    opt.timestep = dt
    opt.gravity = np.asarray(scene.model.gravity.linear, dtype=float)
    opt.tolerance = tol
    opt.integrator = mj.mjtIntegrator.mjINT_IMPLICITFAST
    if variant == "impratio10":
        opt.cone = mj.mjtCone.mjCONE_ELLIPTIC
        opt.impratio = 10.0
    elif variant == "noslip":
        opt.noslip_iterations = 10
    if variant == "stiff":
        for g in spec.geoms:
            g.solref = [2.0 * dt, 1.0]



# ---------------------------------------------------------------- MuJoCo's own geometry
def _box(body, half, mu, mass, name):
    mj = _mujoco()
    return body.add_geom(name=name, type=mj.mjtGeom.mjGEOM_BOX, size=list(half), mass=mass,
                         friction=[mu, 0, 0], condim=3)


def _ground(spec, mu, name="ground", size=(0, 0, 1)):
    mj = _mujoco()
    spec.worldbody.add_geom(name=name, type=mj.mjtGeom.mjGEOM_PLANE, size=list(size), friction=[mu, 0, 0],
                            condim=3)


def boxes_spec(scene, positions: list[tuple[float, float, float]], mu: float, mass: float = 1.0,
               half: float = 0.05, push: tuple[float, float] | None = None):
    """Free boxes (cube.urdf: 1 kg, side 0.1 m) on the ground plane at the given centres; `push`
    (Fx, Fy) adds a motor on the first box's centre, in its own frame (stiction's body-frame
    tau_ff), driven by ctrl = 1."""
    mj = _mujoco()
    spec = mj.MjSpec()
    _ground(spec, mu)
    for k, p in enumerate(positions):
        b = spec.worldbody.add_body(name=f"box{k}", pos=list(p))
        b.add_freejoint()
        _box(b, [half] * 3, mu, mass, f"box{k}")
        if k == 0 and push is not None:
            b.add_site(name="push", pos=[0, 0, 0])
            act = spec.add_actuator(name="push", target="push", trntype=mj.mjtTrn.mjTRN_SITE)
            act.gear = [push[0], push[1], 0, 0, 0, 0]
    return spec


def cube_array_spec(cubes: int, layout: str = "grid", spacing: float = 0.2, mu: float = 0.5):
    """The scaling bench's scene (``{"array": {"layout": layout, "count": cubes}}``: cube.urdf, 1 kg,
    side 0.1 m): `cubes` unnamed free boxes on the ground, side by side in rows of ceil(sqrt(cubes))
    centred on the origin `spacing` apart (stiction's grid), or each on the one below (its tower);
    a ground plane of render size 10 x 10 m; :func:`accurate_options` at dt = 1 ms with MuJoCo's
    Euler integrator."""
    if layout not in ("grid", "tower"):
        raise ValueError(f"cube array layout must be grid or tower, got {layout!r}")
    if cubes < 1:
        raise ValueError(f"cube array: at least one cube, got {cubes}")
    mj = _mujoco()
    spec = mj.MjSpec()
    _ground(spec, mu, name="", size=(10, 10, 0.1))
    per_row = math.ceil(math.sqrt(cubes))
    rows = math.ceil(cubes / per_row)
    for k in range(cubes):
        if layout == "tower":
            x, y, z = 0.0, 0.0, 0.05 + 0.1 * k
        else:
            i, j = divmod(k, per_row)
            x, y, z = (j - (per_row - 1) / 2) * spacing, (i - (rows - 1) / 2) * spacing, 0.05
        body = spec.worldbody.add_body(pos=[x, y, z])
        body.add_freejoint()
        _box(body, [0.05] * 3, mu, 1.0, "")
    accurate_options(spec, 1e-3, (0.0, 0.0, -9.81), implicit=False)
    return spec


def pinch_spec(scene, pad_mu: float = 0.5):
    """robots/scenes/pinch.toml: a 1 kg box held at 0.3 m by two fingers on x slides (0.1 kg),
    two pad spheres (r = 1 cm at z = +-2 cm) each, position actuators kp = 2000, kv = 20."""
    mj = _mujoco()
    spec = mj.MjSpec()
    _ground(spec, float(scene.mu))
    box = spec.worldbody.add_body(name="box0", pos=[0, 0, 0.3])
    box.add_freejoint()
    _box(box, [0.05] * 3, pad_mu, 1.0, "box0")
    for side, x in (("left", -0.06), ("right", 0.06)):
        finger = spec.worldbody.add_body(name=f"{side}_finger", pos=[x, 0, 0.3], mass=0.1,
                                         inertia=[1e-4, 1e-4, 1e-4])
        finger.add_joint(name=f"{side}_slide", type=mj.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0])
        for z in (-0.02, 0.02):
            finger.add_geom(type=mj.mjtGeom.mjGEOM_SPHERE, size=[0.01, 0, 0], pos=[0, 0, z], mass=0,
                            friction=[pad_mu, 0, 0], condim=3)
        act = spec.add_actuator(name=f"{side}_slide", target=f"{side}_slide", trntype=mj.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=float(scene.kp[0]), kv=float(scene.kd[0]))
    return spec


def solo12_spec(scene, lock_joints: bool = False):
    """Solo-12 from its URDF (every visual and collision removed, ``fusestatic = false`` so the
    ``*_FOOT`` links stay bodies, a free joint on ``base_link``, joint limits off), a sphere of
    the foot radius on each foot and the ground plane, friction = the scene's mu (condim 3).
    Joints: a position actuator each with the scene's kp, kd; or, with `lock_joints`, held at
    q0 by joint equality constraints (stiction's lock_joints makes the robot rigid)."""
    from ..robots import ROBOTS, robots_dir  # noqa: PLC0415

    mj = _mujoco()
    robot = ROBOTS["solo12"]
    root = ET.parse(robots_dir() / robot.urdf).getroot()
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for element in link.findall(tag):
                link.remove(element)
    ET.SubElement(ET.SubElement(root, "mujoco"), "compiler", fusestatic="false")
    spec = mj.MjSpec.from_string(ET.tostring(root, encoding="unicode"))
    spec.body("base_link").add_freejoint()
    for joint in spec.joints:
        joint.limited = mj.mjtLimited.mjLIMITED_FALSE
    for foot in robot.feet:
        spec.body(foot).add_geom(name=foot, type=mj.mjtGeom.mjGEOM_SPHERE, size=[robot.foot_radius, 0, 0],
                                 friction=[scene.mu, 0, 0], condim=3)
    _ground(spec, float(scene.mu))
    names = solo12_joint_names()
    for k, name in enumerate(names):
        if lock_joints:
            eq = spec.add_equality(type=mj.mjtEq.mjEQ_JOINT, name1=name)
            eq.data[0] = float(_solo12_q0()[7 + k])
        else:
            actuator = spec.add_actuator(name=name, target=name, trntype=mj.mjtTrn.mjTRN_JOINT)
            actuator.set_to_position(kp=float(scene.kp[6 + k]), kv=float(scene.kd[6 + k]))
    return spec


def solo12_joint_names() -> list[str]:
    """The 12 actuated joints, in Pinocchio's order."""
    from ..robots import load_robot  # noqa: PLC0415

    model = load_robot("solo12").model
    return [model.names[j] for j in range(2, model.njoints)]


def _solo12_q0() -> np.ndarray:
    from ..robots import load_robot  # noqa: PLC0415

    return load_robot("solo12").q0


# ---------------------------------------------------------------- twins from the scene's model
# Why built from the scene's ``pinocchio.Model`` and not by re-importing the URDF: the scene's model
# *is* that URDF as stiction simulates it (visuals and collisions play no part; fixed links already
# merged into their moving parent, objects such as ``ur5-push-box``'s crate appended), so the
# MuJoCo bodies get exactly the same masses, centres of mass, inertia tensors and joint frames —
# MuJoCo's URDF importer would add its own choices (``fusestatic``, ``balanceinertia``, URDF
# damping and friction, joint limits) that stiction does not make. One MuJoCo body per Pinocchio
# joint, at ``jointPlacements[j]`` in its parent's frame, with ``inertias[j]`` as an explicit full
# inertia; free flyer → ``freejoint``, revolute/prismatic (aligned or not, bounded or not) →
# ``hinge`` / ``slide`` (no armature, no spring).
#
# Joint rows (stiction's docs/joint-rows.md, issue 24): the twin carries what the stiction Simulator
# applies, from the same model values and with the same switches (``joint_switches``: the keyword
# overrides, else the scene's ``[joints]`` table, else on), each left at MuJoCo's own soft model
# (default ``solref``/``solimp``):
# - ``joint_limits``: a 1-dof joint (nq = nv = 1) with a finite limit gets ``range`` =
#   (model.lowerPositionLimit, upperPositionLimit) and ``limited`` (one infinite side stays infinite;
#   stiction's ``limit_margin`` is when its row enters the problem, not a change of the law, so
#   MuJoCo's joint ``margin`` stays 0);
# - ``joint_friction``: ``frictionloss`` = model.friction (MuJoCo's dry friction rows);
# - ``joint_damping``: ``damping`` = model.damping (implicit under ``implicitfast``, as in stiction);
# - ``effort_limits``: the joint's PD actuator gets ``forcerange`` = ±model.effortLimit and
#   ``forcelimited`` (0, inf and max-double: none) — a clamp of feed-forward + PD, as stiction's box row.
# With a switch off, or a model without the values, the joint is as before (unlimited, no damping,
# no frictionloss, actuator unlimited). A free joint takes friction or damping only when its six
# values are equal (MuJoCo has one value per joint).
#
# Contacts (eq. 65 in stiction, soft in MuJoCo): each stiction contact — a sphere or a point on a
# frame against a half-space — becomes a sphere geom on the body of the frame's joint, and each
# half-space a ``plane`` geom (a thin ``box`` whose top face is the plane when the half-space moves
# with a body: MuJoCo allows planes only on static bodies); one explicit ``<pair>`` per stiction
# contact (``contype = conaffinity = 0`` elsewhere), ``condim = 3``, friction μ of that contact,
# MuJoCo's default ``solref``/``solimp``, margin 0. A point (radius 0) is a sphere of radius
# ``POINT_RADIUS`` whose centre is moved by that radius along the half-space normal as seen from
# the frame in the initial state, so its lowest point is the stiction point (exactly while the frame
# keeps that orientation; a tilt θ moves it by POINT_RADIUS (1 − cos θ)).
#
# Joint PD (stiction: tau = kp (q_target ⊖ q) + kd (0 − v) + tau_ff, implicit in the step): one
# ``general`` actuator per actuated 1-dof joint, force = kp ctrl + tau_ff − kp q − kd q̇
# (``gainprm[0] = kp``, ``biasprm = (tau_ff, −kp, −kd)``, unlimited), ctrl = q_target; with
# ``integrator = implicitfast`` MuJoCo makes the kd part implicit (the kp part stays explicit).

_HINGE = {"JointModelRX": (1, 0, 0), "JointModelRY": (0, 1, 0), "JointModelRZ": (0, 0, 1),
          "JointModelRUBX": (1, 0, 0), "JointModelRUBY": (0, 1, 0), "JointModelRUBZ": (0, 0, 1)}
_SLIDE = {"JointModelPX": (1, 0, 0), "JointModelPY": (0, 1, 0), "JointModelPZ": (0, 0, 1)}


@dataclass
class JointMap:
    """Where one Pinocchio joint's coordinates live in MuJoCo."""

    name: str
    kind: str  # "free", "hinge", "hinge-unbounded" (cos, sin in Pinocchio), "slide"
    idx_q: int  # Pinocchio
    idx_v: int
    qposadr: int  # MuJoCo
    dofadr: int
    root: pin.SE3 = field(default_factory=pin.SE3.Identity)  # free flyer: its jointPlacement


@dataclass
class MujocoTwin:
    """A compiled MuJoCo model of a stiction scene and the maps between the two state vectors."""

    model: object  # mujoco.MjModel
    joints: list[JointMap]
    contact_geoms: list[int]  # MuJoCo geom id of stiction contact k
    plane_geoms: list[int]  # MuJoCo geom id of stiction half-space k
    pairs: list[int]  # MuJoCo pair id of stiction contact k
    ctrl: np.ndarray  # the constant control (q_target of each actuated joint)
    impratio: float

    def qpos(self, q: np.ndarray) -> np.ndarray:
        """Pinocchio q (free flyer: xyz, quaternion xyzw) -> MuJoCo qpos (xyz, quaternion wxyz)."""
        mj = _mujoco()
        out = np.array(self.model.qpos0, dtype=float)
        for j in self.joints:
            if j.kind == "free":
                world = j.root * pin.XYZQUATToSE3(q[j.idx_q:j.idx_q + 7])
                quat = q[j.idx_q + 3:j.idx_q + 7] if np.allclose(j.root.rotation, np.eye(3)) else \
                    pin.Quaternion(world.rotation).coeffs()  # x, y, z, w (the given sign kept)
                out[j.qposadr:j.qposadr + 3] = world.translation
                out[j.qposadr + 3:j.qposadr + 7] = [quat[3], quat[0], quat[1], quat[2]]
                mj.mju_normalize4(out[j.qposadr + 3:j.qposadr + 7])
            elif j.kind == "hinge-unbounded":
                out[j.qposadr] = np.arctan2(q[j.idx_q + 1], q[j.idx_q])
            else:
                out[j.qposadr] = q[j.idx_q]
        return out

    def qvel(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Pinocchio v (free flyer: linear and angular velocity in the body frame) -> MuJoCo qvel
        (free joint: linear velocity in the world frame, angular in the body frame)."""
        out = np.zeros(self.model.nv)
        for j in self.joints:
            if j.kind == "free":  # the MuJoCo body frame is Pinocchio's joint frame oMi = root * M(q)
                rotation = (j.root * pin.XYZQUATToSE3(q[j.idx_q:j.idx_q + 7])).rotation
                out[j.dofadr:j.dofadr + 3] = rotation @ v[j.idx_v:j.idx_v + 3]
                out[j.dofadr + 3:j.dofadr + 6] = v[j.idx_v + 3:j.idx_v + 6]
            else:
                out[j.dofadr] = v[j.idx_v]
        return out

    def q_from_qpos(self, qpos: np.ndarray, nq: int) -> np.ndarray:
        """MuJoCo qpos (rows) -> Pinocchio q (rows): the inverse of :meth:`qpos`."""
        qpos = np.atleast_2d(qpos)
        out = np.zeros((len(qpos), nq))
        for j in self.joints:
            a = j.qposadr
            if j.kind == "free":
                wxyz = qpos[:, a + 3:a + 7] / np.linalg.norm(qpos[:, a + 3:a + 7], axis=1, keepdims=True)
                if np.allclose(j.root.homogeneous, np.eye(4)):
                    out[:, j.idx_q:j.idx_q + 3] = qpos[:, a:a + 3]
                    out[:, j.idx_q + 3:j.idx_q + 6] = wxyz[:, 1:]
                    out[:, j.idx_q + 6] = wxyz[:, 0]
                else:
                    inv = j.root.inverse()
                    for r in range(len(qpos)):
                        quat = pin.Quaternion(wxyz[r, 0], *wxyz[r, 1:])
                        local = inv * pin.SE3(quat.matrix(), qpos[r, a:a + 3])
                        out[r, j.idx_q:j.idx_q + 7] = pin.SE3ToXYZQUAT(local)
            elif j.kind == "hinge-unbounded":
                out[:, j.idx_q], out[:, j.idx_q + 1] = np.cos(qpos[:, a]), np.sin(qpos[:, a])
            else:
                out[:, j.idx_q] = qpos[:, a]
        return out

    def initial_state(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The mjSTATE_FULLPHYSICS vector of (q, v) at t = 0 (what mujoco.rollout starts from)."""
        mj = _mujoco()
        data = mj.MjData(self.model)
        data.qpos[:] = self.qpos(q)
        data.qvel[:] = self.qvel(q, v)
        data.ctrl[:] = self.ctrl
        spec = mj.mjtState.mjSTATE_FULLPHYSICS
        state = np.empty(mj.mj_stateSize(self.model, spec))
        mj.mj_getState(self.model, data, state, spec)
        return state


def _quat_wxyz(rotation: np.ndarray) -> list[float]:
    x, y, z, w = pin.Quaternion(rotation).coeffs()
    return [float(w), float(x), float(y), float(z)]


def _quat_z_to(normal: np.ndarray) -> list[float]:
    mj = _mujoco()
    quat = np.zeros(4)
    mj.mju_quatZ2Vec(quat, np.asarray(normal, dtype=float))
    return [float(x) for x in quat]


def _joint_dynamics(joint, model: pin.Model, j: int, switches: dict) -> None:
    """MuJoCo's frictionloss and (linear) damping of Pinocchio joint j, as the switches say (0 when off)."""
    nv, iv = model.joints[j].nv, model.joints[j].idx_v
    values = {}
    for setting, array, what in (("joint_friction", model.friction, "friction"),
                                 ("joint_damping", model.damping, "damping")):
        v = np.asarray(array[iv:iv + nv], dtype=float) if switches[setting] else np.zeros(nv)
        if not (np.isfinite(v).all() and (v >= 0).all()):
            raise ValueError(f"joint {model.names[j]!r}: {what} must be finite and >= 0, got {v.tolist()}")
        if (v != v[0]).any():
            raise ValueError(f"joint {model.names[j]!r}: {what} {v.tolist()} differs between its coordinates; "
                             "a MuJoCo joint has one value")
        values[what] = float(v[0])
    joint.frictionloss = values["friction"]
    joint.damping = [values["damping"], 0.0, 0.0]  # (MuJoCo 4: linear, then polynomial terms)


def _position_limits(model: pin.Model, j: int) -> tuple[float, float] | None:
    """(lower, upper) of a 1-dof joint with a finite limit (model.lower/upperPositionLimit), else None."""
    joint = model.joints[j]
    if joint.nq != 1 or joint.nv != 1:
        return None
    lower, upper = float(model.lowerPositionLimit[joint.idx_q]), float(model.upperPositionLimit[joint.idx_q])
    if not (np.isfinite(lower) or np.isfinite(upper)):
        return None
    if not lower < upper:
        raise ValueError(f"joint {model.names[j]!r}: position limits [{lower:g}, {upper:g}]; MuJoCo needs lower < "
                         "upper")
    return lower, upper


def mujoco_twin(scene, impratio: float = 1.0, point_radius: float = POINT_RADIUS, *,
                joint_limits: bool | None = None, joint_friction: bool | None = None,
                joint_damping: bool | None = None, effort_limits: bool | None = None) -> MujocoTwin:
    """The MuJoCo model of a stiction Scene (every choice: the comment above; the options:
    :func:`accurate_options`). `joint_limits`, `joint_friction`, `joint_damping`, `effort_limits`:
    as the Simulator's overrides of those names (None: the scene's ``[joints]`` switch, else on).

    Raises ValueError for what has no MuJoCo counterpart here: a joint type other than free
    flyer, revolute or prismatic, a joint PD on a multi-dof joint, coal collision pairs or anchors,
    a mode other than time stepping, a joint limit with lower = upper (MuJoCo needs lower < upper),
    unequal friction or damping over a free joint's six coordinates."""
    from ..simulator import joint_switches  # noqa: PLC0415

    mj = _mujoco()
    given = {"joint_limits": joint_limits, "joint_friction": joint_friction, "joint_damping": joint_damping,
             "effort_limits": effort_limits}
    switches = joint_switches(scene, {k: v for k, v in given.items() if v is not None})
    if not np.isfinite(impratio) or impratio < 1.0:
        raise ValueError(f"impratio must be a finite number >= 1, got {impratio!r}")
    if not point_radius > 0.0:
        raise ValueError(f"point_radius must be > 0, got {point_radius!r}")
    if scene.pairs:
        raise ValueError(f"scene {scene.name!r}: coal collision pairs have no MuJoCo twin here (only sphere and "
                         "point contacts against half-spaces)")
    if scene.anchors:
        raise ValueError(f"scene {scene.name!r}: anchors have no MuJoCo twin here")
    if scene.mode != "timestep":
        raise ValueError(f"scene {scene.name!r}: mode {scene.mode!r}; the MuJoCo twin is for time stepping")
    model = scene.model
    spec = mj.MjSpec()
    spec.modelname = scene.name
    spec.compiler.inertiafromgeom = mj.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    spec.compiler.autolimits = False
    spec.compiler.degree = False  # hinge ranges in radians, as Pinocchio's

    # bodies and joints, one per Pinocchio joint (parents come first in Pinocchio's order)
    bodies = {0: spec.worldbody}
    kinds: dict[int, str] = {}
    roots: dict[int, pin.SE3] = {}
    for j in range(1, model.njoints):
        shortname = model.joints[j].shortname()
        placement = model.jointPlacements[j]
        body = bodies[model.parents[j]].add_body(name=model.names[j])
        inertia = model.inertias[j]
        body.mass = float(inertia.mass)
        body.ipos = np.asarray(inertia.lever, dtype=float)
        I = np.asarray(inertia.inertia, dtype=float)
        body.fullinertia = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
        body.explicitinertial = True
        name = model.names[j]
        if shortname == "JointModelFreeFlyer":
            if model.parents[j] != 0:
                raise ValueError(f"joint {name!r}: a free flyer below another joint")
            _joint_dynamics(body.add_freejoint(name=name), model, j, switches)
            kinds[j], roots[j] = "free", placement
            body.pos, body.quat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]  # qpos carries the placement
            bodies[j] = body
            continue
        body.pos = np.asarray(placement.translation, dtype=float)
        body.quat = _quat_wxyz(placement.rotation)
        if shortname in _HINGE or shortname in ("JointModelRevoluteUnaligned", "JointModelRevoluteUnboundedUnaligned"):
            axis = _HINGE.get(shortname) or np.asarray(model.joints[j].extract().axis, dtype=float)
            unbounded = "RUB" in shortname or "Unbounded" in shortname  # (cos, sin) in Pinocchio
            jtype, kinds[j] = mj.mjtJoint.mjJNT_HINGE, "hinge-unbounded" if unbounded else "hinge"
        elif shortname in _SLIDE or shortname == "JointModelPrismaticUnaligned":
            axis = _SLIDE.get(shortname) or np.asarray(model.joints[j].extract().axis, dtype=float)
            jtype, kinds[j] = mj.mjtJoint.mjJNT_SLIDE, "slide"
        else:
            raise ValueError(f"joint {name!r}: {shortname} has no MuJoCo twin here (free flyer, revolute and "
                             "prismatic joints only)")
        joint = body.add_joint(name=name, type=jtype, axis=[float(a) for a in axis])
        joint.stiffness, joint.armature = np.zeros(3), 0.0
        _joint_dynamics(joint, model, j, switches)
        joint.limited = mj.mjtLimited.mjLIMITED_FALSE
        limits = _position_limits(model, j) if switches["joint_limits"] else None
        if limits is not None:
            joint.limited, joint.range = mj.mjtLimited.mjLIMITED_TRUE, list(limits)
        bodies[j] = body

    # half-spaces: planes in the world, thin boxes on moving bodies
    data = model.createData()
    pin.framesForwardKinematics(model, data, scene.q0)
    plane_names = []
    for k, h in enumerate(scene.halfspaces):
        name = f"halfspace{k}:{h.name}"
        normal = np.asarray(h.normal, dtype=float)
        if np.linalg.norm(normal) == 0:
            raise ValueError(f"half-space {h.name!r}: zero normal")
        normal = normal / np.linalg.norm(normal)
        frame = model.frames[int(h.frame)]
        if int(h.frame) == 0 or frame.parentJoint == 0:
            # the plane {x : n.x = d} in the frame, then in the world
            fMw = frame.placement if int(h.frame) != 0 else pin.SE3.Identity()
            n_w = fMw.rotation @ normal
            d_w = float(h.offset) + float(n_w @ fMw.translation)
            spec.worldbody.add_geom(name=name, type=mj.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], pos=n_w * d_w,
                                    quat=_quat_z_to(n_w), contype=0, conaffinity=0)
        else:
            n_j = frame.placement.rotation @ normal
            d_j = float(h.offset) + float(n_j @ frame.placement.translation)
            centre = n_j * (d_j - WALL_HALF_THICKNESS)  # the box's top face is the plane
            bodies[frame.parentJoint].add_geom(name=name, type=mj.mjtGeom.mjGEOM_BOX,
                                               size=[WALL_HALF_WIDTH, WALL_HALF_WIDTH, WALL_HALF_THICKNESS],
                                               pos=centre, quat=_quat_z_to(n_j), contype=0, conaffinity=0)
        plane_names.append(name)

    # contacts: a sphere geom on the frame's body and one explicit pair with its half-space
    contact_names = []
    for k, c in enumerate(scene.contacts):
        frame = model.frames[int(c.frame)]
        if frame.parentJoint == 0:
            raise ValueError(f"contact {c.name!r}: on a fixed frame (it can never move onto its half-space)")
        centre = frame.placement.act(np.asarray(c.offset, dtype=float))  # in the joint's frame
        radius = float(c.radius)
        if radius == 0.0:
            # a point: the sphere's lowest point (along the half-space normal at q0) is the point
            h = scene.halfspaces[int(c.halfspace)]
            n_w = data.oMf[int(h.frame)].rotation @ (np.asarray(h.normal, float) / np.linalg.norm(h.normal))
            n_joint = data.oMi[frame.parentJoint].rotation.T @ n_w
            centre = centre + point_radius * n_joint
            radius = point_radius
        name = f"contact{k}:{c.name}"
        bodies[frame.parentJoint].add_geom(name=name, type=mj.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0],
                                           pos=centre, contype=0, conaffinity=0)
        mu = float(c.mu)
        spec.add_pair(name=f"pair{k}", geomname1=plane_names[int(c.halfspace)], geomname2=name, condim=3,
                      friction=[mu, mu, 0.0, 0.0, 0.0])
        contact_names.append(name)

    # joint PD: force = kp ctrl + tau_ff - kp q - kd qdot on each actuated 1-dof joint
    ctrl = []
    for j in range(1, model.njoints):
        jm = model.joints[j]
        kp, kd, ff = (np.asarray(x[jm.idx_v:jm.idx_v + jm.nv], dtype=float) for x in (scene.kp, scene.kd, scene.tau_ff))
        if not (kp.any() or kd.any() or ff.any()):
            continue
        if kinds[j] == "free" or jm.nv != 1:
            raise ValueError(f"joint {model.names[j]!r}: a joint PD or feed-forward on a {jm.nv}-dof joint has no "
                             "MuJoCo twin here")
        act = spec.add_actuator(name=model.names[j], target=model.names[j], trntype=mj.mjtTrn.mjTRN_JOINT)
        act.gaintype, act.biastype = mj.mjtGain.mjGAIN_FIXED, mj.mjtBias.mjBIAS_AFFINE
        act.gainprm[:3] = [kp[0], 0.0, 0.0]
        act.biasprm[:3] = [ff[0], -kp[0], -kd[0]]
        act.ctrllimited = mj.mjtLimited.mjLIMITED_FALSE
        act.forcelimited = mj.mjtLimited.mjLIMITED_FALSE
        effort = float(model.effortLimit[jm.idx_v])
        if switches["effort_limits"] and 0.0 < effort < np.finfo(float).max:  # (0, inf, max-double: none)
            act.forcelimited, act.forcerange = mj.mjtLimited.mjLIMITED_TRUE, [-effort, effort]
        q_t = scene.q_target[jm.idx_q:jm.idx_q + jm.nq]
        ctrl.append(float(np.arctan2(q_t[1], q_t[0]) if kinds[j] == "hinge-unbounded" else q_t[0]))

    accurate_options(spec, scene.dt, model.gravity.linear, impratio)
    compiled = spec.compile()

    joints = []
    for j in range(1, model.njoints):
        mjj = compiled.joint(model.names[j])
        joints.append(JointMap(model.names[j], kinds[j], model.joints[j].idx_q, model.joints[j].idx_v,
                               int(mjj.qposadr[0]), int(mjj.dofadr[0]), roots.get(j, pin.SE3.Identity())))
    return MujocoTwin(compiled, joints, [compiled.geom(n).id for n in contact_names],
                      [compiled.geom(n).id for n in plane_names],
                      [compiled.pair(f"pair{k}").id for k in range(len(contact_names))],
                      np.asarray(ctrl, dtype=float), float(impratio))


# ---------------------------------------------------------------- running a twin
def solo12_state(model, q0: np.ndarray, q_target: np.ndarray | None = None) -> np.ndarray:
    """A Pinocchio configuration of Solo-12 (xyz, quaternion xyzw, joints) as MuJoCo's
    mjSTATE_INTEGRATION vector (qpos: xyz, quaternion wxyz, joints by name; zero velocity;
    ctrl = q_target's joints when given)."""
    mj = _mujoco()
    data = mj.MjData(model)
    data.qpos[:3] = q0[:3]
    data.qpos[3] = q0[6]
    data.qpos[4:7] = q0[3:6]
    for k, name in enumerate(solo12_joint_names()):
        data.qpos[model.joint(name).qposadr[0]] = q0[7 + k]
        if q_target is not None:
            data.ctrl[model.actuator(name).id] = q_target[7 + k]
    return state_of(model, data)


def state_of(model, data) -> np.ndarray:
    mj = _mujoco()
    state = np.empty(mj.mj_stateSize(model, mj.mjtState.mjSTATE_INTEGRATION))
    mj.mj_getState(model, data, state, mj.mjtState.mjSTATE_INTEGRATION)
    return state


def rollout(model, data, initial: np.ndarray, control: np.ndarray | None, nstep: int) -> tuple[float, float, np.ndarray]:
    """`nstep` steps by ``mujoco.rollout.rollout`` (a C++ loop that records the full physics state)
    from `initial` (mjSTATE_FULLPHYSICS) under the constant `control` (shape (1, 1, nu), or None):
    its wall seconds, the process's CPU seconds (time the machine's other work held the core left
    out) and the recorded states (1, nstep, state size). The one MuJoCo timing of every bench."""
    import mujoco.rollout  # noqa: PLC0415

    t0, c0 = time.perf_counter(), time.process_time()
    states, _ = mujoco.rollout.rollout(model, data, initial, control, nstep=nstep)
    return time.perf_counter() - t0, time.process_time() - c0, states


def timed_rollout(model, state0: np.ndarray, nstep: int) -> float:
    """Wall seconds of `nstep` steps by :func:`rollout` from state0 (mjSTATE_INTEGRATION, ctrl
    included)."""
    mj = _mujoco()
    data = mj.MjData(model)
    mj.mj_setState(model, data, state0, mj.mjtState.mjSTATE_INTEGRATION)
    physics = mj.mjtState.mjSTATE_FULLPHYSICS
    initial = np.empty(mj.mj_stateSize(model, physics))
    mj.mj_getState(model, data, initial, physics)
    control = data.ctrl.copy().reshape(1, 1, -1)
    return rollout(model, data, initial, control, nstep)[0]


def record(model, state0: np.ndarray, nstep: int, bodies: list[str], sites: list[str] = (),
           time_limit: float = math.inf) -> dict:
    """An mj_step loop from state0 recording after every step: the named bodies' positions
    (N + 1, len(bodies), 3), the named geoms' centres (``sites``: e.g. feet), and per contact of
    every step its force (normal, t1, t2) on geom2 and the velocity of geom2 relative to geom1
    in the contact frame (normal, t1, t2) after the step, with its penetration depth.
    Stops early (``stopped``) on a bad-acceleration warning (MuJoCo resets the state: divergence)
    or a non-finite state."""
    mj = _mujoco()
    data = mj.MjData(model)
    mj.mj_setState(model, data, state0, mj.mjtState.mjSTATE_INTEGRATION)
    mj.mj_forward(model, data)
    ids = [model.body(b).id for b in bodies]
    gids = [model.geom(g).id for g in sites]
    pos = np.full((nstep + 1, len(ids), 3), np.nan)
    cen = np.full((nstep + 1, len(gids), 3), np.nan)
    pos[0], cen[0] = data.xpos[ids], data.geom_xpos[gids]
    forces, velocities, depth = [], [], 0.0
    f6 = np.zeros(6)
    jp, jr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    stopped = None
    t0 = time.perf_counter()
    for k in range(1, nstep + 1):
        mj.mj_step(model, data)
        if data.warning[mj.mjtWarning.mjWARN_BADQACC].number > 0 or not np.isfinite(data.qpos).all():
            stopped = "non-finite"
            break
        for i in range(data.ncon):
            c = data.contact[i]
            mj.mj_contactForce(model, data, i, f6)
            frame = c.frame.reshape(3, 3)
            v = np.zeros(3)
            for b, sign in ((model.geom_bodyid[c.geom2], 1.0), (model.geom_bodyid[c.geom1], -1.0)):
                if b == 0:
                    continue
                mj.mj_jac(model, data, jp, jr, c.pos, b)
                v += sign * (jp @ data.qvel)
            forces.append(f6[:3].copy())
            velocities.append(frame @ v)
            depth = max(depth, -float(c.dist))
        mj.mj_kinematics(model, data)
        pos[k], cen[k] = data.xpos[ids], data.geom_xpos[gids]
        if time.perf_counter() - t0 > time_limit:
            stopped = "time-limit"
            break
    f = np.array(forces).reshape(-1, 3)
    u = np.array(velocities).reshape(-1, 3)
    return {"positions": pos[:k + 1], "centres": cen[:k + 1], "steps": k, "stopped": stopped,
            "lam_n": f[:, 0], "lam_t": f[:, 1:], "u_n": u[:, 0], "u_t": u[:, 1:], "penetration": depth}


# ---------------------------------------------------------------- one yardstick for both simulators
def contact_geometry(scene, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each contact's point in its half-space's frame and its signed gap (as stiction's detection:
    n.c - d - r), at every configuration (row of Q, Pinocchio coordinates): ((N, nc, 3), (N, nc)).

    Computed with Pinocchio from the configurations alone, so a stiction trajectory and a MuJoCo
    trajectory (mapped back by :meth:`MujocoTwin.q_from_qpos`) are measured by the same code."""
    Q = np.atleast_2d(np.asarray(Q, dtype=float))
    model = scene.model
    if Q.shape[1] != model.nq:
        raise ValueError(f"configurations need nq = {model.nq} columns, got {Q.shape[1]}")
    data = model.createData()
    nc = len(scene.contacts)
    local, gaps = np.zeros((len(Q), nc, 3)), np.zeros((len(Q), nc))
    normals = [np.asarray(h.normal, float) / np.linalg.norm(h.normal) for h in scene.halfspaces]
    for r, q in enumerate(Q):
        pin.framesForwardKinematics(model, data, q)
        for k, c in enumerate(scene.contacts):
            h = scene.halfspaces[int(c.halfspace)]
            wMh = data.oMf[int(h.frame)]
            point = wMh.actInv(data.oMf[int(c.frame)].act(np.asarray(c.offset, dtype=float)))
            local[r, k] = point
            gaps[r, k] = normals[int(c.halfspace)] @ point - float(h.offset) - float(c.radius)
    return local, gaps


def contact_accuracy(scene, t: np.ndarray, Q: np.ndarray, settle: float | None = None,
                     closed_gap: float = 1e-3) -> dict:
    """The accuracy numbers of one trajectory, the same for both simulators.

    drift: the largest displacement along its half-space (normal part removed; in the half-space's
    own frame, so a wall on a pushed box moves with it) of a contact point from where it was at
    the settle time, over the rest of the run, among the contacts closed (gap <= closed_gap) at
    the settle time and at the end; for a sphere it is its centre's, so rolling counts.
    penetration: the deepest gap below zero over the whole run (0 if none).
    closed: how many contacts the drift is taken over."""
    t = np.asarray(t, dtype=float)
    settle = scene.settle_time if settle is None else settle
    local, gaps = contact_geometry(scene, Q)
    i0 = int(np.argmin(np.abs(t - settle)))
    closed = (gaps[i0] <= closed_gap) & (gaps[-1] <= closed_gap)
    drift = 0.0
    if closed.any():
        move = local[i0:, closed] - local[i0, closed]
        normals = np.array([np.asarray(scene.halfspaces[int(c.halfspace)].normal, float)
                            / np.linalg.norm(scene.halfspaces[int(c.halfspace)].normal)
                            for c, keep in zip(scene.contacts, closed) if keep])
        move -= (move * normals).sum(axis=-1, keepdims=True) * normals
        drift = float(np.linalg.norm(move, axis=-1).max())
    return {"drift": drift, "penetration": float(max(0.0, -gaps.min())), "closed": int(closed.sum()),
            "finite": bool(np.isfinite(Q).all())}


def pile_spec(scene):
    """The MuJoCo twin of a mixed pile (``[array] layout = "pile"`` with ``mix``, stiction.pile): each
    body a free body at the scene's initial pose with the same mass and inertia (explicit, about its
    centre of mass), the same coal shape as a MuJoCo geom (box, sphere, capsule, cylinder; a convex
    mesh from the hull's vertices, which MuJoCo hulls again), the bin's floor and walls as the same
    world boxes; every geom mu of the scene (condim 3); :func:`accurate_options` at the scene's dt with
    MuJoCo's Euler integrator (as the cube scaling twins)."""
    from ..pile import shape_parameters  # noqa: PLC0415

    mj = _mujoco()
    model = scene.model
    if model.njoints < 2 or any(model.joints[j].shortname() != "JointModelFreeFlyer" for j in range(1, model.njoints)):
        raise ValueError("pile_spec: the scene's joints must all be free flyers (a pile)")
    if not scene.pairs or not all(p.dynamic for p in scene.pairs):
        raise ValueError("pile_spec: a pile with `mix` (its pairs found by the broad phase) is needed")
    mu = float(scene.pairs[0].mu)
    spec = mj.MjSpec()
    spec.compiler.inertiafromgeom = mj.mjtInertiaFromGeom.mjINERTIAFROMGEOM_FALSE
    bodies = {}
    q0 = scene.q0.reshape(-1, 7)
    for j in range(1, model.njoints):
        x, y, z, qx, qy, qz, qw = q0[j - 1]
        body = spec.worldbody.add_body(name=model.names[j], pos=[x, y, z], quat=[qw, qx, qy, qz])
        body.add_freejoint()
        inertia = model.inertias[j]
        I = np.asarray(inertia.inertia)
        body.mass = float(inertia.mass)
        body.ipos = np.asarray(inertia.lever, dtype=float)
        body.fullinertia = [I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]]
        body.explicitinertial = True
        bodies[j] = body
    for go in scene.geometry.geometryObjects:
        p = shape_parameters(go.geometry)
        where = bodies[go.parentJoint] if go.parentJoint != 0 else spec.worldbody
        pos, quat = np.asarray(go.placement.translation, dtype=float), _quat_wxyz(go.placement.rotation)
        kw = {"name": go.name, "pos": list(pos), "quat": quat, "friction": [mu, 0, 0], "condim": 3}
        if p["kind"] == "box":
            where.add_geom(type=mj.mjtGeom.mjGEOM_BOX, size=list(p["half"]), **kw)
        elif p["kind"] == "sphere":
            where.add_geom(type=mj.mjtGeom.mjGEOM_SPHERE, size=[p["radius"], 0, 0], **kw)
        elif p["kind"] == "capsule":
            where.add_geom(type=mj.mjtGeom.mjGEOM_CAPSULE, size=[p["radius"], p["half_length"], 0], **kw)
        elif p["kind"] == "cylinder":
            where.add_geom(type=mj.mjtGeom.mjGEOM_CYLINDER, size=[p["radius"], p["half_length"], 0], **kw)
        else:
            spec.add_mesh(name=f"{go.name}-mesh", uservert=np.asarray(p["vertices"], dtype=float).ravel().tolist())
            where.add_geom(type=mj.mjtGeom.mjGEOM_MESH, meshname=f"{go.name}-mesh", **kw)
    accurate_options(spec, scene.dt, model.gravity.linear, implicit=False)
    return spec
