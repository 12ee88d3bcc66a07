"""A stiction robot scene as an equivalent MuJoCo 4.0 model (the optional ``bench`` extra).

Why built from the scene's ``pinocchio.Model`` and not by re-importing the URDF: the scene's model
*is* that URDF as stiction simulates it (visuals and collisions play no part; fixed links already
merged into their moving parent, objects such as ``ur5-push-box``'s crate appended), so the
MuJoCo bodies get exactly the same masses, centres of mass, inertia tensors and joint frames —
MuJoCo's URDF importer would add its own choices (``fusestatic``, ``balanceinertia``, URDF
damping and friction, joint limits) that stiction does not make. One MuJoCo body per Pinocchio
joint, at ``jointPlacements[j]`` in its parent's frame, with ``inertias[j]`` as an explicit full
inertia; free flyer → ``freejoint``, revolute/prismatic (aligned or not, bounded or not) →
``hinge`` / ``slide`` (no limits, damping, armature or frictionloss: stiction has none).

Contacts (eq. 65 in stiction, soft in MuJoCo): each stiction contact — a sphere or a point on a
frame against a half-space — becomes a sphere geom on the body of the frame's joint, and each
half-space a ``plane`` geom (a thin ``box`` whose top face is the plane when the half-space moves
with a body: MuJoCo allows planes only on static bodies); one explicit ``<pair>`` per stiction
contact (``contype = conaffinity = 0`` elsewhere), ``condim = 3``, friction μ of that contact,
MuJoCo's default ``solref``/``solimp``, margin 0. A point (radius 0) is a sphere of radius
``POINT_RADIUS`` whose centre is moved by that radius along the half-space normal as seen from
the frame in the initial state, so its lowest point is the stiction point (exactly while the frame
keeps that orientation; a tilt θ moves it by POINT_RADIUS (1 − cos θ)).

Joint PD (stiction: tau = kp (q_target ⊖ q) + kd (0 − v) + tau_ff, implicit in the step): one
``general`` actuator per actuated 1-dof joint, force = kp ctrl + tau_ff − kp q − kd q̇
(``gainprm[0] = kp``, ``biasprm = (tau_ff, −kp, −kd)``, unlimited), ctrl = q_target; with
``integrator = implicitfast`` MuJoCo makes the kd part implicit (the kp part stays explicit).

Options: the scene's dt and gravity (a slope tilts gravity in both), ``cone = elliptic``,
``solver = Newton``, ``iterations = 100``, ``tolerance = 1e-10``, ``impratio`` 1 unless given,
everything else at MuJoCo's defaults (``ls_iterations = 50``, no noslip, warm start on).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from .mujoco_scenes import _mujoco, available  # MuJoCo is the optional bench extra: imported on use

POINT_RADIUS = 1e-3  # m: the sphere standing for a stiction point contact
WALL_HALF_THICKNESS = 0.05  # m: the box standing for a half-space that moves with a body
WALL_HALF_WIDTH = 2.0  # m
ITERATIONS = 100
TOLERANCE = 1e-10

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


def mujoco_twin(scene, impratio: float = 1.0, point_radius: float = POINT_RADIUS) -> MujocoTwin:
    """The MuJoCo model of a stiction Scene (see the module docstring for every choice).

    Raises ValueError for what has no MuJoCo counterpart here: a joint type other than free
    flyer, revolute or prismatic, a joint PD on a multi-dof joint, coal collision pairs or anchors,
    a mode other than time stepping."""
    mj = _mujoco()
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
            body.add_freejoint(name=name)
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
        joint.limited = mj.mjtLimited.mjLIMITED_FALSE
        joint.damping, joint.stiffness = np.zeros(3), np.zeros(3)
        joint.armature, joint.frictionloss = 0.0, 0.0
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
        q_t = scene.q_target[jm.idx_q:jm.idx_q + jm.nq]
        ctrl.append(float(np.arctan2(q_t[1], q_t[0]) if kinds[j] == "hinge-unbounded" else q_t[0]))

    opt = spec.option
    opt.timestep = float(scene.dt)
    opt.gravity = np.asarray(model.gravity.linear, dtype=float)
    opt.integrator = mj.mjtIntegrator.mjINT_IMPLICITFAST
    opt.cone = mj.mjtCone.mjCONE_ELLIPTIC
    opt.solver = mj.mjtSolver.mjSOL_NEWTON
    opt.iterations = ITERATIONS
    opt.tolerance = TOLERANCE
    opt.impratio = float(impratio)
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
