"""MuJoCo 4.0 twins of the stiction scenes (the optional ``bench`` extra), for the benches.

Same masses, sizes, friction, gravity (a slope tilts it, as in stiction), time step and
solver tolerance as the stiction scene; MuJoCo's own contact model otherwise. Every model uses
``integrator = implicitfast`` (stiction's joint PD is implicit too) and, unless a variant
says otherwise, MuJoCo's defaults: pyramidal cone, Newton, ``solref = (0.02, 1)``,
``impratio = 1``, no noslip. The variants (``VARIANTS``) change one thing each:

- ``default``: as above;
- ``stiff``: ``solref = (2 dt, 1)``, the stiffest time constant MuJoCo accepts at that step;
- ``impratio10``: elliptic cones and ``impratio = 10`` (MuJoCo's advice against slip);
- ``noslip``: 10 noslip iterations (the post-processing that removes tangential creep).

Boxes are box geoms on a plane (MuJoCo finds their corners, as stiction's four bottom corner
points); the pinch's pads are the same spheres as the stiction scene's; Solo-12 is its URDF
(``solo12_spec``, shared with benchmarks/bench_step_mujoco.py).
"""
from __future__ import annotations

import math
import time
import xml.etree.ElementTree as ET

import numpy as np

VARIANTS = ("default", "stiff", "impratio10", "noslip")


def _mujoco():
    import mujoco  # noqa: PLC0415 - optional

    return mujoco


def available() -> bool:
    try:
        _mujoco()
    except ImportError:
        return False
    return True


def apply_options(spec, scene, dt: float, tol: float, variant: str) -> None:
    """Time step, gravity, tolerance and the variant's settings (module doc)."""
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


def _box(body, half, mu, mass, name):
    mj = _mujoco()
    return body.add_geom(name=name, type=mj.mjtGeom.mjGEOM_BOX, size=list(half), mass=mass,
                         friction=[mu, 0, 0], condim=3)


def _ground(spec, mu):
    mj = _mujoco()
    spec.worldbody.add_geom(name="ground", type=mj.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], friction=[mu, 0, 0],
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


def timed_rollout(model, state0: np.ndarray, nstep: int) -> float:
    """Wall seconds of `nstep` steps by mujoco.rollout (a C++ loop; records the state), from
    state0 (mjSTATE_INTEGRATION, ctrl included)."""
    mj = _mujoco()
    import mujoco.rollout  # noqa: PLC0415

    data = mj.MjData(model)
    mj.mj_setState(model, data, state0, mj.mjtState.mjSTATE_INTEGRATION)
    physics = mj.mjtState.mjSTATE_FULLPHYSICS
    initial = np.empty(mj.mj_stateSize(model, physics))
    mj.mj_getState(model, data, initial, physics)
    control = data.ctrl.copy().reshape(1, 1, -1)
    t0 = time.perf_counter()
    mujoco.rollout.rollout(model, data, initial, control, nstep=nstep)
    return time.perf_counter() - t0


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
