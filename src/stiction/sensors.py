"""Sensors: what a robot's instruments read after each step (docs/simulator.md, "Sensors").

Named after MuJoCo's sensors and Drake's ContactResults where they have a name:

- ``contact_force`` (nc, 3): each candidate contact's force in the **world** frame, N (Drake's
  ``PointPairContactInfo.contact_force``). Computed in C++ at the end of each step
  (src/cpp/sim/sensors.cpp) from the solver's (t1, t2, n) force (time stepping: the impulse P / h of
  eq. 70) and the contact frame the step's problem was built in (a moving half-space's, a coal pair
  slot's: they change from step to step, so the frame is only known there). It is the force on the
  contact's own body: the sphere's (the contact's ``frame``), a coal pair's *second* geometry's; the
  other side (a half-space attached to a body, the pair's first geometry) receives its opposite.
- per frame (``frame_names``): the frames that carry contacts, each body's side of every contact it is
  part of; ``frame_force`` (nf, 3) the total world force on the frame's body from its contacts (MuJoCo's
  ``touch`` is its normal part, summed) and ``frame_states`` (nf,) one state per frame: 2 when one of its
  contacts slips, else 1 when one sticks, else 3 when one is closed (frictionless), else 0 open;
  -1 (NO_STATE) with no step behind. ``frame_in_contact`` = ``frame_states > 0``.
- an IMU at the origin of the first free-flyer joint hanging from the universe (a robot's base, the
  first free body), in that joint's frame: ``accelerometer`` (3,) the proper acceleration
  R0^T (a - g) of the step, m/s^2 (MuJoCo's ``accelerometer``: +|g| up at rest, 0 in a free fall) and
  ``gyro`` (3,) the angular velocity, rad/s (MuJoCo's ``gyro``; Pinocchio's
  ``getFrameVelocity(..., LOCAL).angular``). None without such a joint.
- ``tau`` (nv,): the joint torques the actuators applied over the step (Trajectory.tau,
  ``sim.data.actuator_torque``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from .scene_schema import did_you_mean

NO_STATE = -1  # (as stiction.simulator.NO_STATE: no solve classified the contacts)


def imu_joint(model: pin.Model) -> int:
    """The IMU's joint: the first free flyer whose parent is the universe (0: none). The C++
    sensors (src/cpp/sim/sensors.cpp, imuJoint) pick the same one."""
    for j in range(1, model.njoints):
        if model.parents[j] == 0 and model.joints[j].shortname() == "JointModelFreeFlyer":
            return j
    return 0


def _geometry_frame(model: pin.Model, geometry, index: int) -> tuple[int, str]:
    """(joint, frame name) of geometry `index`: its parent frame's name, or its joint's when the
    parent frame is not on that joint."""
    obj = geometry.geometryObjects[index]
    joint, frame = int(obj.parentJoint), int(obj.parentFrame)
    if 0 <= frame < model.nframes and model.frames[frame].parentJoint == joint:
        return joint, model.frames[frame].name
    return joint, model.names[joint]


def contact_sides(scene) -> list[tuple[str | None, str | None]]:
    """Per candidate (the sphere contacts, then max_contacts slots per coal pair): the frame names of
    its two sides, (the body the contact force acts on, the body its opposite acts on); None for a
    side fixed in the world."""
    model = scene.model
    sides: list[tuple[str | None, str | None]] = []
    for c in scene.contacts:
        frame = model.frames[c.frame]
        plus = frame.name if frame.parentJoint != 0 else None
        h = scene.halfspaces[c.halfspace]
        minus = None
        if h.frame != 0 and model.frames[h.frame].parentJoint != 0:
            minus = model.frames[h.frame].name
        sides.append((plus, minus))
    for p in scene.pairs:
        if p.dynamic:  # a pool entry: its two bodies change from step to step (stiction.pile); no frame's
            sides += [(None, None)] * p.max_contacts
            continue
        pair = scene.geometry.collisionPairs[p.pair]
        first_joint, first = _geometry_frame(model, scene.geometry, pair.first)
        second_joint, second = _geometry_frame(model, scene.geometry, pair.second)
        sides += [(second if second_joint != 0 else None, first if first_joint != 0 else None)] * p.max_contacts
    return sides


def frame_incidence(scene) -> tuple[list[str], np.ndarray]:
    """The frames that carry contacts (in the order they first appear, the contacts' own bodies before
    the other sides) and the (nf, nc) int8 matrix S with S[f, i] = +1 when contact i's force acts on
    frame f, -1 when its opposite does, 0 else: frame_force = S contact_force (Newton's third law)."""
    sides = contact_sides(scene)
    names: list[str] = []
    for k in (0, 1):
        for side in sides:
            if side[k] is not None and side[k] not in names:
                names.append(side[k])
    S = np.zeros((len(names), len(sides)), dtype=np.int8)
    for i, (plus, minus) in enumerate(sides):
        if plus is not None:
            S[names.index(plus), i] += 1
        if minus is not None:
            S[names.index(minus), i] -= 1
    return names, S


def frame_totals(incidence: np.ndarray, contact_force: np.ndarray, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, from per-candidate arrays with any leading shape (..., nc, 3) and (..., nc): the total
    world force (..., nf, 3) (NaN where a contact's force is: no step behind it) and the frame's state
    (..., nf) int8: 2 if a contact of it slips, else 1 if one sticks, else 3 if one is closed, else 0
    (open), and NO_STATE where its contacts' states are all NO_STATE."""
    lead = states.shape[:-1]
    nf = len(incidence)
    force = np.zeros(lead + (nf, 3))
    out = np.zeros(lead + (nf,), dtype=np.int8)
    for f in range(nf):  # (frame by frame over its few contacts: a dense S product is nf x nc per record)
        touching = np.flatnonzero(incidence[f])
        force[..., f, :] = np.einsum("c,...cx->...x", incidence[f, touching].astype(float),
                                     contact_force[..., touching, :])
        s = states[..., touching]
        state = np.where((s == 2).any(-1), 2, np.where((s == 1).any(-1), 1, np.where((s == 3).any(-1), 3, 0)))
        if s.shape[-1]:
            state = np.where((s == NO_STATE).all(-1), NO_STATE, state)
        out[..., f] = state
    return force, out


def lookup(names: list[str], name: str, what: str) -> int:
    """The index of `name` in `names`, or a KeyError naming the closest one."""
    try:
        return names.index(name)
    except ValueError:
        raise KeyError(f"no {what} named {name!r} ({did_you_mean(name, names)}{what}s: "
                       f"{', '.join(names) if names else 'none'})") from None


@dataclass
class Sensors:
    """The sensors after the simulator's last step (:meth:`stiction.simulator.Simulator.sensors`);
    the arrays are copies. t: the time they were read at (the end of that step); NaN with no step
    behind the current state (a fresh or reset simulator, or its time set since), and then every
    reading is NaN (states NO_STATE) but the gyro, which is the current state's."""

    t: float
    contact_names: list[str]
    contact_force: np.ndarray      # (nc, 3) world, N
    contact_states: np.ndarray     # (nc,) int8: -1 no step, 0 open, 1 stick, 2 slip, 3 closed
    frame_names: list[str]
    frame_force: np.ndarray        # (nf, 3) world, N
    frame_states: np.ndarray       # (nf,) int8
    accelerometer: np.ndarray | None  # (3,) IMU frame, m/s^2
    gyro: np.ndarray | None           # (3,) IMU frame, rad/s
    tau: np.ndarray                # (nv,) applied actuator torque

    @property
    def frame_in_contact(self) -> np.ndarray:
        """(nf,) bool: some contact of the frame carries a force (stick, slip or closed)."""
        return self.frame_states > 0

    def contact_force_of(self, name: str) -> np.ndarray:
        """The world force (3,) of the contact named `name` (a coal pair slot: ``pair#k``)."""
        return self.contact_force[lookup(self.contact_names, name, "contact")]

    def frame_force_of(self, name: str) -> np.ndarray:
        """The total world force (3,) on the frame named `name` (e.g. a foot)."""
        return self.frame_force[lookup(self.frame_names, name, "contact frame")]


def read(sim) -> Sensors:
    """The sensors of `sim` (a Simulator) after its last step."""
    data, model = sim.data, sim.scene.model
    nc = sim.model.num_candidates
    names, incidence = sim._sensor_frames()
    stepped = bool(data.sensor_time == data.t)  # (NaN before any step: never equal)
    if stepped:
        force = np.asarray(data.contact_force, dtype=float).T.reshape(nc, 3).copy()
        states = np.array([int(s) for s in data.states], dtype=np.int8).reshape(nc)
        tau = np.array(data.actuator_torque, dtype=float)
    else:
        force = np.full((nc, 3), np.nan)
        states = np.full(nc, NO_STATE, dtype=np.int8)
        tau = np.full(model.nv, np.nan)
    frame_force, frame_states = frame_totals(incidence, force, states)
    j = imu_joint(model)
    accelerometer = gyro = None
    if j:
        accelerometer = np.array(data.accelerometer, dtype=float) if stepped else np.full(3, np.nan)
        iv = model.joints[j].idx_v
        gyro = np.array(data.v[iv + 3:iv + 6], dtype=float)
    return Sensors(t=float(data.sensor_time) if stepped else float("nan"), contact_names=sim.contact_names,
                   contact_force=force, contact_states=states, frame_names=list(names), frame_force=frame_force,
                   frame_states=frame_states, accelerometer=accelerometer, gyro=gyro, tau=tau)
