"""Controllers in the loop: a scene names one, ``Simulator.rollout`` runs it before every step.

A controller is written against the public state and control only, so the same object drives
stiction and its MuJoCo twin (:class:`MujocoLoop`):

- it is built as ``Controller(scene, **parameters)`` (a :class:`stiction.scene.Scene`: the robot's
  ``pinocchio.Model``, its initial state, time step and gains);
- ``reset()`` forgets its memory (the Simulator calls it on ``reset()``);
- ``controller(state, control)`` is called before every step with the state (``state.q``,
  ``state.v`` in Pinocchio's coordinates, ``state.t``) and writes the step's control *in place* into
  ``control.tau_ff``, ``.q_target``, ``.v_target``, ``.kp``, ``.kd`` (stiction's ``sim.data``
  views, or the arrays the MuJoCo loop maps to its actuators). The joint PD is the simulator's:
  ``tau = tau_ff + kp (q_target - q) + kd (v_target - v)``, implicit in the step.

A scene names its controller in a ``[controller]`` table: ``name`` is a bundled controller
(:data:`CONTROLLERS`) or ``"module:Class"`` for a user's own (imported from the Python path), and
``parameters`` its numbers (each checked against the class's ``PARAMETERS``, a typo is an error
with the closest name).

Bundled: ``trot`` (:class:`TrotController`), a Raibert-style trot for a four-legged robot with
Solo-12's leg layout (hip abduction about x, hip and knee flexion about y).
"""
from __future__ import annotations

import importlib
import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pinocchio as pin

from .scene_schema import SceneError, did_you_mean


@dataclass
class State:
    """What a controller reads: Pinocchio's q (nq), v (nv; a free flyer's in its base frame) and t,
    and the contact sensors of the last step (``contacts``, a :class:`ContactReading`; None when the
    loop has none, or before the first step)."""

    q: np.ndarray
    v: np.ndarray
    t: float
    contacts: "ContactReading | None" = None


@dataclass
class ContactReading:
    """Each contact-carrying frame's reading after the last step (docs/simulator.md, "Sensors"):
    ``frame_names`` (nf,), ``frame_force`` (nf, 3) the total world force on it (N) and
    ``frame_in_contact`` (nf,) bool (a contact of it sticks, slips or is closed)."""

    frame_names: list
    frame_force: np.ndarray
    frame_in_contact: np.ndarray


class Controller:
    """Base of the controllers: ``PARAMETERS`` maps each parameter to (default, meaning)."""

    PARAMETERS: dict[str, tuple[float, str]] = {}

    def __init__(self, scene, **parameters):
        self.scene = scene
        self.parameters = check_parameters(type(self), parameters)

    def reset(self) -> None:
        """Forget what earlier steps left (called when the simulation restarts)."""

    def __call__(self, state: State, control) -> None:
        raise NotImplementedError


def check_parameters(cls, parameters: dict, where: str = "controller.parameters") -> dict:
    """The parameters with the class's defaults filled in; an unknown name is a SceneError naming the
    closest known one, a value that is not a finite number too."""
    known = getattr(cls, "PARAMETERS", None)
    out = {}
    for name, value in parameters.items():
        if known is not None and name not in known:
            hint = did_you_mean(name, known)
            raise SceneError(f"{where}: unknown parameter {name!r} of {cls.__name__} "
                             f"({hint}valid: {', '.join(known) or 'none'})")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SceneError(f"{where}.{name} = {value!r}: must be a finite number")
        out[name] = float(value)
    for name, (default, _) in (known or {}).items():
        out.setdefault(name, float(default))
    return out


# ---------------------------------------------------------------- a trot

def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class TrotController(Controller):
    """A Raibert-style trot (Raibert, *Legged Robots That Balance*, 1986): the diagonal pairs (FL, HR)
    and (FR, HL) half a cycle apart, each foot ``duty`` of the ``period`` in stance, after standing still
    for ``start`` seconds; the commanded speed ramps up over ``ramp`` seconds. Lift-off follows the
    schedule; touchdown is the foot's contact sensor when the loop gives one (``State.contacts``).

    Every foot has a target in the base's frame, turned into joint targets by exact analytic leg
    inverse kinematics (:meth:`leg_ik`), held by the scene's joint PD:

    - touchdown: a contact sensed from ``touch_window`` of the swing on starts the stance at the foot's
      actual position (the PD then asks no horizontal force to bring it elsewhere), its height joining
      the standing height over ``load_ramp``; a foot not down at its scheduled touchdown keeps
      descending for up to ``seek_time`` before its stance starts anyway (without sensors: the
      schedule's touchdown, at the swing's end point);
    - stance: the target sweeps backwards at the commanded speed from there, ``stance_stiffness`` of the
      way from the foot's actual position (a softer horizontal spring); legs lengthen where the base
      dips (``attitude_gain``: pitch and roll);
    - swing: horizontally a cubic Hermite from the lift-off point to Raibert's landing point ``nominal +
      v_cmd T_stance / 2 + raibert_gain (v - v_cmd)`` (v: the base's filtered horizontal velocity),
      done by ``horizontal_end`` of the swing, the foot then moving with the ground; vertically
      ``lift sin(pi s)^lift_shape`` plus a parabola leaving and reaching the ground at
      ``touchdown_speed``; gains ``swing_stiffness`` times the scene's;
    - feed-forward: static equilibrium tau = g(q) - J^T lambda (as ``control.gravity_feedforward``),
      lambda vertical, the weight shared by the stance feet and moved onto a foot over ``load_ramp``
      of the cycle after touchdown and off it before lift-off (down to ``release_load``), while the
      leg's gains soften to ``liftoff_softness`` and its horizontal target joins the foot;
    - friction cone: a light leg on a sticking foot is in equilibrium, so the ground force its torques
      ask is f = -J^-T (tau - g(q)) (tau: feed-forward plus the PD at the current state); where its
      tangential part exceeds ``cone_margin`` mu f_n, a Jacobian-transpose correction of the
      feed-forward scales it down to that (:meth:`_keep_in_cone`); a lifting foot the sensor still
      finds on the ground is pulled straight up by ``release_pull`` with no tangential force, so that
      its contact opens in one step instead of sliding through a vanishing normal force.

    The nominal feet and the height are the scene's initial posture, so at t = 0 the targets are the
    initial joints: nothing jumps.
    """

    PARAMETERS = {
        "speed": (0.3, "forward speed commanded, m/s (along the base's initial heading)"),
        "period": (0.3, "gait cycle, s"),
        "duty": (0.55, "fraction of the cycle a foot is in stance (> 0.5: all four feet down around each switch)"),
        "load_ramp": (0.05, "fraction of the cycle over which the weight moves onto a foot after touchdown and off "
                      "it before lift-off"),
        "lift": (0.04, "swing foot lift, m"),
        "lift_shape": (2.0, "the swing height is lift sin(pi s)^lift_shape (s: the swing's progress; 1: the foot leaves "
                       "and reaches the ground at once, 2: with zero vertical velocity)"),
        "start": (0.5, "standing time before the first step, s"),
        "ramp": (0.5, "time over which the commanded speed rises from 0, s"),
        "raibert_gain": (0.05, "foot placement per m/s of velocity error, s"),
        "attitude_gain": (0.15, "stance foot lowering per rad of pitch or roll, m/rad"),
        "stance_stiffness": (0.5, "fraction of the way from a stance foot's position to its sweep that its "
                             "horizontal target is set (1: the sweep itself; ramps to 0 before lift-off)"),
        "liftoff_softness": (0.2, "the lowest fraction of the scene's kp, kd a stance leg softens to before lift-off "
                             "(1: never)"),
        "swing_stiffness": (2.0, "a swing leg's PD gains relative to the scene's kp, kd (stiffer: it tracks its "
                            "path and touches down at the ground's speed)"),
        "velocity_filter": (0.05, "time constant of the base velocity filter, s"),
        "feedforward": (1.0, "scale of the feed-forward torques (1: static equilibrium, 0: PD only)"),
        "contact_aware": (1.0, "1: a touchdown is the foot's contact sensor (State.contacts) from touch_window of "
                          "the swing on; 0 (or a loop without sensors): the end of the scheduled swing"),
        "touch_window": (0.5, "fraction of the swing from which a sensed contact is the foot's touchdown"),
        "seek_time": (0.03, "how long after its scheduled touchdown a swing foot that has not touched keeps "
                      "descending to find the ground before its stance starts anyway, s"),
        "seek_depth": (0.02, "how far below the ground a swing target seeking contact goes, m"),
        "horizontal_end": (0.75, "fraction of the swing by which the foot's horizontal motion relative to the "
                           "ground ends (it then descends vertically)"),
        "touchdown_speed": (0.1, "vertical speed of the swing target leaving and reaching the ground, m/s"),
        "cone_margin": (0.7, "fraction of mu within which a stance foot's ground force, as its leg's torques ask it, "
                        "is kept (0: no correction)"),
        "release_load": (0.2, "share of its weight a stance foot still carries at lift-off (then let go at once)"),
        "release_pull": (3.0, "upward force with which a lifting foot that still touches is pulled off, N (with "
                         "no tangential force)"),
    }
    LEGS = ("FL", "FR", "HL", "HR")
    PAIRS = ((0, 3), (1, 2))  # (FL, HR), (FR, HL)

    def __init__(self, scene, **parameters):
        super().__init__(scene, **parameters)
        model = scene.model
        if model.njoints < 2 or model.joints[1].shortname() != "JointModelFreeFlyer":
            raise ValueError("TrotController: the robot needs a free-flyer base")
        self.model = model
        self.data = model.createData()
        self.feet, self.legs = [], []
        for leg in self.LEGS:
            names = [f"{leg}_HAA", f"{leg}_HFE", f"{leg}_KFE"]
            missing = [n for n in names + [f"{leg}_FOOT"] if not (model.existJointName(n) or
                                                                   model.existFrame(n))]
            if missing:
                raise ValueError(f"TrotController: the robot has no {', '.join(missing)} (it needs Solo-12's "
                                 "legs FL, FR, HL, HR with joints HAA, HFE, KFE and a FOOT frame)")
            joints = [model.getJointId(n) for n in names]
            self.legs.append(joints)
            self.feet.append(model.getFrameId(f"{leg}_FOOT"))
        self.iq = np.array([[model.joints[j].idx_q for j in leg] for leg in self.legs])
        self.iv = np.array([[model.joints[j].idx_v for j in leg] for leg in self.legs])
        self._geometry()
        q0 = scene.q0
        pin.framesForwardKinematics(model, self.data, q0)
        base = self.data.oMi[1]
        # nominal feet: the initial posture's, in the base frame
        self.nominal = np.array([base.actInv(self.data.oMf[f].translation) for f in self.feet])
        self.weight = pin.computeTotalMass(model) * float(np.linalg.norm(model.gravity.linear))
        self.yaw0 = self._yaw(q0)
        self.reset()

    def _geometry(self) -> None:
        """Each leg's lengths from the model: the hip (HAA) origin in the base, the lateral offset of the
        sagittal leg plane from the HAA axis, and the thigh and shank lengths."""
        m = self.model
        self.hip, self.lateral, self.thigh, self.shank = [], [], [], []
        for leg, foot in zip(self.legs, self.feet):
            haa, hfe, kfe = leg
            self.hip.append(np.asarray(m.jointPlacements[haa].translation, dtype=float))
            p_hfe = np.asarray(m.jointPlacements[hfe].translation, dtype=float)
            p_kfe = np.asarray(m.jointPlacements[kfe].translation, dtype=float)
            p_foot = np.asarray(m.frames[foot].placement.translation, dtype=float)
            if abs(p_hfe[0]) + abs(p_hfe[2]) + abs(p_kfe[0]) + abs(p_foot[0]) > 1e-9:
                raise ValueError("TrotController: the legs must be planar in their HAA frame (Solo-12's layout)")
            self.lateral.append(p_hfe[1] + p_kfe[1] + p_foot[1])
            self.thigh.append(-p_kfe[2])
            self.shank.append(-p_foot[2])
        self.knee_sign = []  # the initial posture's knee bend (front: negative, hind: positive for Solo-12)
        for leg in self.legs:
            self.knee_sign.append(1.0 if self.scene.q0[self.model.joints[leg[2]].idx_q] >= 0 else -1.0)

    @staticmethod
    def _yaw(q: np.ndarray) -> float:
        R = pin.Quaternion(q[3:7]).normalized().matrix()
        return math.atan2(R[1, 0], R[0, 0])

    def leg_ik(self, k: int, p: np.ndarray) -> np.ndarray:
        """Joint angles (HAA, HFE, KFE) of leg k putting its foot at p (base frame), exact for the
        planar leg: HAA from the lateral offset, then the two-link planar inverse (law of cosines);
        an unreachable point is clamped to the leg's reach."""
        d = p - self.hip[k]
        ly, l1, l2 = self.lateral[k], self.thigh[k], self.shank[k]
        r2 = d[1] ** 2 + d[2] ** 2
        zs = -math.sqrt(max(r2 - ly ** 2, 1e-12))
        haa = math.atan2(d[2], d[1]) - math.atan2(zs, ly)
        xs = d[0]
        reach = math.hypot(xs, zs)
        c = (reach ** 2 - l1 ** 2 - l2 ** 2) / (2 * l1 * l2)
        kfe = self.knee_sign[k] * math.acos(min(1.0, max(-1.0, c)))
        hfe = math.atan2(-xs, -zs) - math.atan2(l2 * math.sin(kfe), l1 + l2 * math.cos(kfe))
        return np.array([haa, hfe, kfe])

    def reset(self) -> None:
        self.velocity = np.zeros(2)  # filtered horizontal base velocity (heading frame)
        self.last_t = None
        self.swing_from = self.nominal.copy()  # where each swing started (base frame)
        self.stance_from = self.nominal.copy()  # where each stance started
        self.stance_t0 = np.zeros(4)
        self.swing_t0 = np.zeros(4)
        self.in_stance = np.ones(4, dtype=bool)
        self.previous_phase = np.zeros(4)
        self.swing_velocity = np.zeros((4, 2))  # each swing's starting velocity (base frame, x y)
        self.last_targets = self.nominal.copy()  # (before the attitude correction)
        self.previous_targets = None  # the joint targets of the last call
        self.foot_frames = None  # each foot's index in the loop's ContactReading (found on first use)

    def command(self, t: float) -> float:
        p = self.parameters
        ramp = max(p["ramp"], 1e-9)
        return p["speed"] * min(1.0, max(0.0, (t - p["start"]) / ramp))

    def _touching(self, state: State) -> np.ndarray | None:
        """Each foot's contact sensor (the last step's), or None without one (or contact_aware = 0)."""
        reading = getattr(state, "contacts", None)
        if reading is None or self.parameters["contact_aware"] == 0.0:
            return None
        if self.foot_frames is None:
            names = list(reading.frame_names)
            missing = [f"{leg}_FOOT" for leg in self.LEGS if f"{leg}_FOOT" not in names]
            if missing:
                raise ValueError(f"TrotController: the contact sensors have no frame {', '.join(missing)} "
                                 f"(frames: {', '.join(names)})")
            self.foot_frames = np.array([names.index(f"{leg}_FOOT") for leg in self.LEGS])
        return np.asarray(reading.frame_in_contact, dtype=bool)[self.foot_frames]

    def __call__(self, state: State, control) -> None:
        p = self.parameters
        q, v, t = state.q, state.v, float(state.t)
        R = pin.Quaternion(q[3:7]).normalized().matrix()
        yaw = math.atan2(R[1, 0], R[0, 0])
        heading = _rot_z(yaw)
        tilt = heading.T @ R  # the base's roll and pitch (in its heading frame)
        roll, pitch = math.atan2(tilt[2, 1], tilt[2, 2]), -math.asin(max(-1.0, min(1.0, tilt[2, 0])))
        v_heading = (heading.T @ (R @ v[:3]))[:2]
        dt = 0.0 if self.last_t is None else max(0.0, t - self.last_t)
        self.last_t = t
        alpha = 1.0 if p["velocity_filter"] <= 0 else min(1.0, dt / p["velocity_filter"])
        self.velocity += alpha * (v_heading - self.velocity)
        v_cmd = self.command(t)
        touching = self._touching(state)

        pin.forwardKinematics(self.model, self.data, q)
        pin.updateFramePlacements(self.model, self.data)
        base = self.data.oMi[1]
        actual = np.array([base.actInv(self.data.oMf[f].translation) for f in self.feet])

        period, duty = p["period"], p["duty"]
        t_stance, t_swing = duty * period, (1.0 - duty) * period
        ramp = max(p["load_ramp"], 1e-9)
        targets = self.nominal.copy()
        load = np.ones(4)  # each foot's share of the weight (relative)
        softness = np.ones(4)  # each leg's PD gains relative to the scene's
        unload = np.ones(4)  # 1 until the weight starts moving off a stance foot, then down to 0 at lift-off
        for k in range(4):
            if t < p["start"]:  # standing on the initial posture
                self.in_stance[k], self.stance_from[k], self.stance_t0[k] = True, self.nominal[k], t
                self.previous_phase[k] = 0.0
                continue
            pair = 0 if k in self.PAIRS[0] else 1
            phi = ((t - p["start"]) / period + 0.5 * pair) % 1.0  # 0: touchdown, duty: lift-off (scheduled)
            crossed_liftoff = self.previous_phase[k] < duty <= phi
            self.previous_phase[k] = phi
            s = (t - self.swing_t0[k]) / t_swing  # the swing's progress (> 1: seeking the ground)
            if self.in_stance[k] and crossed_liftoff:  # lift-off: the swing starts where the stance ended
                self.in_stance[k] = False
                self.swing_from[k] = self.last_targets[k].copy()
                self.swing_velocity[k] = -self.velocity  # the ground's velocity seen from the base
                self.swing_t0[k], s = t, 0.0
            elif not self.in_stance[k]:
                if touching is None:  # the schedule alone: touchdown at the end of the swing
                    down = phi < duty
                else:  # the sensor: a contact in the swing's second half (or later, seeking) is a touchdown
                    late = phi < duty and phi * period >= p["seek_time"]  # seeking too long: stance anyway
                    down = (bool(touching[k]) and s >= p["touch_window"]) or late
                    if crossed_liftoff:  # never found the ground over a whole stance: swing again from here
                        self.swing_from[k] = self.last_targets[k].copy()
                        self.swing_velocity[k] = -self.velocity
                        self.swing_t0[k], s = t, 0.0
                if down:  # touchdown: the stance starts where the foot is (no horizontal error to push on)
                    self.in_stance[k] = True
                    if touching is not None and touching[k]:  # (its height too: it joins the standing height
                        self.stance_from[k] = actual[k].copy()  # over the load ramp)
                    else:
                        self.stance_from[k] = self.nominal[k].copy()
                        self.stance_from[k][:2] = self.last_targets[k][:2]
                    self.stance_t0[k] = t
            to_liftoff = ((duty - phi) % 1.0)  # of the cycle, to the scheduled lift-off
            if self.in_stance[k]:
                targets[k] = self.stance_from[k].copy()
                targets[k][0] -= v_cmd * (t - self.stance_t0[k])
                # the weight moves onto a foot after touchdown and off it before lift-off
                since = (t - self.stance_t0[k]) / period
                settle = min(1.0, since / ramp)
                targets[k][2] += settle * (self.nominal[k][2] - targets[k][2])
                load[k] = min(1.0, (since + 1e-9) / ramp, max(p["release_load"], to_liftoff / ramp))
                unload[k] = min(1.0, to_liftoff / ramp)
                # before lift-off the leg softens with its load: a joint PD's force is not along its error
                # (K = J^-T kp J^-1), so a stiff unloading leg pushes sideways as its normal force vanishes
                softness[k] = max(p["liftoff_softness"], min(1.0, to_liftoff / ramp))
            else:
                targets[k] = self._swing_target(k, s, v_cmd, t_stance, t_swing)
                load[k] = 0.0
                softness[k] = p["swing_stiffness"] * max(p["liftoff_softness"],
                                                         min(1.0, s * (1.0 - duty) / ramp))
        # stance feet: only a part of the way from where they are to their sweep (a softer horizontal
        # spring: the friction the stance needs stays well inside the cone), none of it at lift-off
        for k in range(4):
            if self.in_stance[k] and t >= p["start"]:
                gain = p["stance_stiffness"] * unload[k]
                targets[k][:2] = actual[k][:2] + gain * (targets[k][:2] - actual[k][:2])
        self.last_targets = targets.copy()  # (where a swing starts: the target the stance ended on)
        # level the base: legs extend where the base dips (pitch > 0 is nose down: the front ones; roll > 0
        # lifts the left side), every foot alike so that no target jumps at touchdown or lift-off
        for k in range(4):
            x, y = self.nominal[k][0], self.nominal[k][1]
            targets[k][2] += p["attitude_gain"] * (-pitch * np.sign(x) + roll * np.sign(y))
        # joint targets (the base frame of a level base: its tilt is what the stance legs correct)
        q_target, v_target = control.q_target, control.v_target
        for k in range(4):
            q_target[self.iq[k]] = self.leg_ik(k, targets[k])
        # the joint velocity of the targets (finite difference): the PD damps the error, not the motion
        joints = q_target[self.iq].ravel()
        if self.previous_targets is not None and dt > 0.0:
            v_target[self.iv.ravel()] = (joints - self.previous_targets) / dt
        else:
            v_target[self.iv.ravel()] = 0.0
        self.previous_targets = joints
        kp, kd = control.kp, control.kd
        for k in range(4):
            kp[self.iv[k]] = self.scene.kp[self.iv[k]] * softness[k]
            kd[self.iv[k]] = self.scene.kd[self.iv[k]] * softness[k]
        tau = control.tau_ff
        tau[:] = 0.0
        if p["feedforward"] != 0.0 and load.sum() > 0.0:
            # static equilibrium (as control.gravity_feedforward): tau = g(q) - J^T lambda, the legs' own
            # weight and the stance feet's shares of the robot's (vertical forces: no sideways push)
            tau[6:] = p["feedforward"] * pin.computeGeneralizedGravity(self.model, self.data, q)[6:]
            pin.computeJointJacobians(self.model, self.data, q)
            pin.updateFramePlacements(self.model, self.data)
            shares = p["feedforward"] * self.weight * load / load.sum()
            for k in np.flatnonzero(load > 0.0):
                J = pin.getFrameJacobian(self.model, self.data, self.feet[k], pin.LOCAL_WORLD_ALIGNED)
                tau[self.iv[k]] -= J[2, self.iv[k]] * shares[k]  # -J^T (0, 0, share)
        if p["cone_margin"] > 0.0 and t >= p["start"]:
            self._keep_in_cone(q, v, control, pin.computeGeneralizedGravity(self.model, self.data, q)[6:], touching)

    def _keep_in_cone(self, q, v, control, gravity, touching) -> None:
        """Each stance foot's ground force as its leg's torques ask it (a light leg on a sticking foot is
        in equilibrium: tau = g(q) - J^T f, so f = -J^-T (tau - g), tau the feed-forward plus the PD at
        the current state) is moved into ``cone_margin`` of the friction cone by a Jacobian-transpose
        correction of the feed-forward: the tangential part scaled down to cone_margin mu f_n (to 0
        where f_n <= 0, as at lift-off)."""
        p = self.parameters
        mu = float(self.scene.mu) * p["cone_margin"]
        pin.computeJointJacobians(self.model, self.data, q)
        g = np.zeros(self.model.nv)
        g[6:] = gravity
        for k in range(4):
            lifting = not self.in_stance[k]  # a swing foot the sensor still finds on the ground
            if lifting and (touching is None or not touching[k]):
                continue
            iq, iv = self.iq[k], self.iv[k]
            tau = (control.tau_ff[iv] + control.kp[iv] * (control.q_target[iq] - q[iq])
                   + control.kd[iv] * (control.v_target[iv] - v[iv]))
            J = pin.getFrameJacobian(self.model, self.data, self.feet[k], pin.LOCAL_WORLD_ALIGNED)[:3, iv]
            f = -np.linalg.solve(J.T, tau - g[iv])
            fn, ft = f[2], math.hypot(f[0], f[1])
            limit = 0.0 if lifting else mu * max(fn, 0.0)
            if lifting and p["release_pull"] > 0.0:  # let go at once: a pull straight up opens the contact
                control.tau_ff[iv] += J.T @ (f - np.array([0.0, 0.0, -p["release_pull"]]))
            elif ft > limit:
                wanted = f.copy()
                wanted[:2] *= limit / ft
                control.tau_ff[iv] += J.T @ (f - wanted)  # -J^T (wanted - f)

    def _swing_target(self, k: int, s: float, v_cmd: float, t_stance: float, t_swing: float) -> np.ndarray:
        """The swing foot's target (base frame) at progress s: horizontally a cubic Hermite over the
        first ``horizontal_end`` of the swing from the lift-off point (leaving at the ground's velocity
        seen from the base) to where the ground carries it to Raibert's landing point by s = 1, then
        moving with the ground (the foot descends vertically relative to the ground); vertically
        ``lift sin(pi s)^lift_shape`` plus a parabola leaving and reaching the ground at
        ``touchdown_speed``, and beyond s = 1 (no contact yet) descending at that speed down to
        ``seek_depth`` below it."""
        p = self.parameters
        h_end = min(1.0, max(1e-3, p["horizontal_end"]))
        land = self._swing_end(k, v_cmd, t_stance)
        ground_v = np.array([-v_cmd, 0.0])  # the ground's velocity seen from the base (commanded)
        waypoint = land[:2] - ground_v * (1.0 - h_end) * t_swing  # where the horizontal motion ends
        out = self.nominal[k].copy()
        sh = min(1.0, s / h_end)
        if sh < 1.0:
            h00, h10 = 2 * sh ** 3 - 3 * sh ** 2 + 1, sh ** 3 - 2 * sh ** 2 + sh
            h01, h11 = -2 * sh ** 3 + 3 * sh ** 2, sh ** 3 - sh ** 2
            span = h_end * t_swing
            out[:2] = (h00 * self.swing_from[k][:2] + h01 * waypoint + h10 * span * self.swing_velocity[k]
                       + h11 * span * ground_v)
        else:
            out[:2] = waypoint + ground_v * (s - h_end) * t_swing
        vt = p["touchdown_speed"] * t_swing  # per unit of s
        if s <= 1.0:
            out[2] += p["lift"] * math.sin(math.pi * s) ** p["lift_shape"] + vt * s * (1.0 - s)
        else:
            out[2] -= min(p["seek_depth"], vt * (s - 1.0))
        return out

    def _swing_end(self, k: int, v_cmd: float, t_stance: float) -> np.ndarray:
        """Raibert's landing point: half a stance's travel ahead of the nominal foot, plus a correction
        proportional to the velocity error (forward and sideways)."""
        p = self.parameters
        out = self.nominal[k].copy()
        out[0] += 0.5 * v_cmd * t_stance + p["raibert_gain"] * (self.velocity[0] - v_cmd)
        out[1] += p["raibert_gain"] * self.velocity[1]
        return out


CONTROLLERS: dict[str, type] = {"trot": TrotController}


def controller_class(name: str) -> type:
    """A bundled controller by name, or ``"module:Class"`` imported from the Python path."""
    if not isinstance(name, str):
        raise SceneError(f"controller.name = {name!r}: must be a string")
    if ":" not in name:
        if name not in CONTROLLERS:
            hint = did_you_mean(name, CONTROLLERS)
            raise SceneError(f"controller.name = {name!r}: unknown controller ({hint}bundled: "
                             f"{', '.join(CONTROLLERS)}; or \"module:Class\")")
        return CONTROLLERS[name]
    module_name, _, attr = name.partition(":")
    if not module_name or not attr:
        raise SceneError(f"controller.name = {name!r}: write \"module:Class\"")
    try:
        module = importlib.import_module(module_name)
    except ImportError as exc:
        raise SceneError(f"controller.name = {name!r}: cannot import {module_name!r} ({exc})") from None
    cls = getattr(module, attr, None)
    if cls is None or not callable(cls):
        raise SceneError(f"controller.name = {name!r}: {module_name!r} has no class {attr!r}")
    return cls


def build_controller(scene):
    """The controller a scene names (its ``[controller]`` table), or None."""
    cfg = (scene.config or {}).get("controller")
    if not cfg:
        return None
    cls = controller_class(cfg["name"])
    return cls(scene, **check_parameters(cls, cfg.get("parameters") or {}))


class SimulatorLoop:
    """The ``rollout(callback=...)`` of a stiction Simulator: the controller reads ``sim.data``'s
    q, v, t and writes into its control views."""

    def __init__(self, controller):
        self.controller = controller
        self._frames = None

    def __call__(self, sim) -> None:
        d = sim.data
        self.controller(State(d.q, d.v, d.t, self.contacts(sim)), d)

    def contacts(self, sim) -> "ContactReading | None":
        """The feet's forces and contact states after the last step (the frame totals of
        ``sim.sensors()`` without its other readings: a few microseconds); None with no step behind."""
        d = sim.data
        if not d.sensor_time == d.t:  # no step behind the current state (NaN before the first)
            return None
        if self._frames is None:
            self._frames = sim._sensor_frames()
        names, incidence = self._frames
        nc = incidence.shape[1]
        force = np.asarray(d.contact_force, dtype=float).T.reshape(nc, 3)
        closed = np.array([int(state) > 0 for state in d.states], dtype=bool)  # 1 stick, 2 slip, 3 closed
        return ContactReading(names, incidence @ force, (np.abs(incidence) * closed).sum(axis=1) > 0)


# ---------------------------------------------------------------- the same controller on MuJoCo

def stance_slip(tangential_speed: np.ndarray, in_contact: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Per contact, the largest slip of its contact point during one stance, in m: the sum of
    tangential speed times dt over each run of consecutive steps in contact, from the step after
    its touchdown step (the impact step itself is left out). tangential_speed and in_contact are
    (steps, contacts), the speed after each step; dt (steps,)."""
    speed = np.asarray(tangential_speed, dtype=float)
    touching = np.asarray(in_contact, dtype=bool)
    dt = np.asarray(dt, dtype=float)
    out = np.zeros(speed.shape[1])
    for c in range(speed.shape[1]):
        run = 0.0
        for k in range(len(dt)):
            if not touching[k, c]:
                run = 0.0
                continue
            if k > 0 and touching[k - 1, c]:  # not the touchdown step
                run += speed[k, c] * dt[k]
                out[c] = max(out[c], run)
    return out


def distance_walked(q: np.ndarray) -> float:
    """The base's displacement along its initial heading (m), first row of q to the last."""
    yaw = TrotController._yaw(q[0])
    return float((q[-1, :2] - q[0, :2]) @ np.array([math.cos(yaw), math.sin(yaw)]))


class MujocoLoop:
    """The controller driving the MuJoCo twin of a scene (``stiction.bench.mujoco_twins.mujoco_twin``):
    before each ``mj_step`` it reads qpos, qvel as Pinocchio's (q, v) and writes its control into the
    twin's PD actuators (force = kp ctrl + bias; ctrl = q_target, bias = (tau_ff + kd v_target,
    -kp, -kd)). :meth:`run` records what the summaries compare."""

    def __init__(self, scene, controller, twin=None):
        from .bench import mujoco_twins  # noqa: PLC0415 - optional (MuJoCo)

        import mujoco  # noqa: PLC0415

        self.mj = mujoco
        self.scene, self.controller = scene, controller
        self.twin = twin if twin is not None else mujoco_twins.mujoco_twin(scene)
        self.data = mujoco.MjData(self.twin.model)
        model = scene.model
        self.actuated = []  # (actuator id, idx_q, idx_v)
        for j in range(1, model.njoints):
            name = model.names[j]
            aid = mujoco.mj_name2id(self.twin.model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
            if aid >= 0:
                self.actuated.append((aid, model.joints[j].idx_q, model.joints[j].idx_v))
        self.control = SimpleNamespace(tau_ff=scene.tau_ff.copy(), q_target=scene.q_target.copy(),
                                       v_target=np.zeros(model.nv), kp=scene.kp.copy(), kd=scene.kd.copy())
        from . import sensors as _sensors  # noqa: PLC0415

        self.frame_names, self.incidence = _sensors.frame_incidence(scene)
        self.reset()

    def reset(self) -> None:
        mj, twin = self.mj, self.twin
        mj.mj_resetData(twin.model, self.data)
        self.data.qpos[:] = twin.qpos(self.scene.q0)
        self.data.qvel[:] = twin.qvel(self.scene.q0, self.scene.v0)
        self.controller.reset()
        self.stepped = False

    def contacts(self) -> "ContactReading | None":
        """stiction's ContactReading from MuJoCo's contacts after the last step: each contact geom's
        force (mj_contactForce, turned to the world frame, on the geom's own body) summed per frame;
        a frame is in contact when one of its geoms carries a positive normal force."""
        if not self.stepped:
            return None
        mj, m, d = self.mj, self.twin.model, self.data
        geoms = self.twin.contact_geoms
        nc = len(geoms)
        force, touching = np.zeros((nc, 3)), np.zeros(nc, dtype=bool)
        local = np.zeros(6)
        for i in range(d.ncon):
            con = d.contact[i]
            for sign, g in ((-1.0, con.geom1), (1.0, con.geom2)):  # the force acts on geom2, its opposite on geom1
                if g in geoms:
                    c = geoms.index(g)
                    mj.mj_contactForce(m, d, i, local)
                    force[c] += sign * (con.frame.reshape(3, 3).T @ local[:3])
                    touching[c] |= local[0] > 0.0
        return ContactReading(self.frame_names, self.incidence @ force,
                              (np.abs(self.incidence) * touching).sum(axis=1) > 0)

    def state(self) -> State:
        """(q, v, t) in Pinocchio's coordinates (free joint: world linear velocity to the base frame)."""
        d, twin = self.data, self.twin
        q = twin.q_from_qpos(d.qpos, self.scene.model.nq)[0]
        v = np.zeros(self.scene.model.nv)
        for j in twin.joints:
            if j.kind == "free":
                rotation = (j.root * pin.XYZQUATToSE3(q[j.idx_q:j.idx_q + 7])).rotation
                v[j.idx_v:j.idx_v + 3] = rotation.T @ d.qvel[j.dofadr:j.dofadr + 3]
                v[j.idx_v + 3:j.idx_v + 6] = d.qvel[j.dofadr + 3:j.dofadr + 6]
            else:
                v[j.idx_v] = d.qvel[j.dofadr]
        return State(q, v, float(d.time), self.contacts())

    def apply(self) -> None:
        m, d, c = self.twin.model, self.data, self.control
        for aid, iq, iv in self.actuated:
            m.actuator_gainprm[aid, 0] = c.kp[iv]
            m.actuator_biasprm[aid, :3] = (c.tau_ff[iv] + c.kd[iv] * c.v_target[iv], -c.kp[iv], -c.kd[iv])
            d.ctrl[aid] = c.q_target[iq]

    def run(self, duration: float) -> dict:
        """Steps for `duration` s with the controller before each: the base's q at every step, each
        foot's contact state and its contact point's tangential speed after every step, and the wall
        time (controller and mapping included)."""
        import time  # noqa: PLC0415

        mj, m, d = self.mj, self.twin.model, self.data
        n = int(round(duration / m.opt.timestep))
        geoms = list(self.twin.contact_geoms)
        nc = len(geoms)
        Q = np.zeros((n + 1, self.scene.model.nq))
        speed = np.zeros((n, nc))
        touching = np.zeros((n, nc), dtype=bool)
        jp, jr = np.zeros((3, m.nv)), np.zeros((3, m.nv))
        Q[0] = self.state().q
        start = time.perf_counter()
        for k in range(n):
            self.controller(self.state(), self.control)
            self.apply()
            mj.mj_step(m, d)
            self.stepped = True
            for i in range(d.ncon):
                con = d.contact[i]
                for g in (con.geom1, con.geom2):
                    if g in geoms:
                        c = geoms.index(g)
                        mj.mj_jac(m, d, jp, jr, con.pos, m.geom_bodyid[g])
                        u = jp @ d.qvel
                        normal = con.frame[:3]
                        touching[k, c] = True
                        speed[k, c] = float(np.linalg.norm(u - (u @ normal) * normal))
            Q[k + 1] = self.twin.q_from_qpos(d.qpos, self.scene.model.nq)[0]
        wall = time.perf_counter() - start
        return {"q": Q, "tangential_speed": speed, "in_contact": touching, "dt": np.full(n, m.opt.timestep),
                "wall_seconds": wall, "real_time_factor": n * m.opt.timestep / wall,
                "distance_walked": distance_walked(Q),
                "max_stance_slip": float(stance_slip(speed, touching, np.full(n, m.opt.timestep)).max())
                if nc else 0.0}
