"""Python front of the C++ simulator: scenes in, trajectories and summaries out."""
from __future__ import annotations

import dataclasses
import functools
import math
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np
import pinocchio as pin

from . import _core
from . import sensors as _sensors
from ._validation import positive as _positive
from ._validation import vector as _vector
from .scene import Scene, _quaternion_check, load_scene
from .formulations import PARAMETERS as FORMULATION_PARAMETERS
from .formulations import check_name as check_formulation
from .formulations import settings_for as formulation_settings
from .scene_schema import did_you_mean

if TYPE_CHECKING:
    from .derivatives import StepDerivatives

_VECTOR_KEYS = ("t", "residual", "iterations", "converged", "dt")


def _rollout(model, data, n_steps: int, every: int = 1, initial_contacts: bool = True,
             before_step: Callable[[], object] | None = None) -> dict:
    """_core.rollout with every per-record matrix as a 2-D array (a 1-row Eigen
    matrix may come back 1-D). initial_contacts=False: record 0's contact fields are not measured
    (for a caller that drops record 0: the adaptive loop's one-step chunks). before_step: called
    with no argument before each step, in the C++ loop."""
    rec = _core.rollout(model, data, n_steps, every, initial_contacts, before_step)
    n = len(rec["t"])
    return {k: (np.asarray(v).reshape(n) if k in _VECTOR_KEYS else np.asarray(v).reshape(n, -1))
            for k, v in rec.items()}
PHASES = ("kinematics", "delassus", "solve", "integrate", "total")
NO_STATE = -1  # Trajectory.states of record 0: no solve classified the contacts


def _states(recorded: np.ndarray) -> np.ndarray:
    """The recorded contact states as int8, NaN (record 0: no solve yet) as NO_STATE."""
    s = np.asarray(recorded)
    return np.where(np.isnan(s), NO_STATE, s).astype(np.int8)



class _FrameTotals:
    """A Trajectory's frame_force and frame_states not computed yet: stiction.sensors.frame_totals of
    the recording's contact forces and states, made on the first read of either (a rollout's
    Python-side cost: 21 us a record on pile-24, ~15 % of its step, for fields most callers never read)."""

    def __init__(self, incidence: np.ndarray, contact_force: np.ndarray, states: np.ndarray):
        self.incidence, self.contact_force, self.states = incidence, contact_force, states

    def resolve(self, obj) -> None:
        force, states = _sensors.frame_totals(self.incidence, self.contact_force, self.states)
        obj.__dict__["frame_force"], obj.__dict__["frame_states"] = force, states


class _LazyFrameField:
    """A Trajectory field (frame_force, frame_states) that may hold a _FrameTotals until first read. A
    data descriptor: the value lives in the instance's __dict__ under the field's own name; reading
    it resolves a pending _FrameTotals (both fields at once). Its default (read on the class) is None."""

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, owner=None):
        if obj is None:
            return None  # (the dataclass field's default)
        value = obj.__dict__.get(self.name)
        if isinstance(value, _FrameTotals):
            value.resolve(obj)
            value = obj.__dict__[self.name]
        return value

    def __set__(self, obj, value) -> None:
        pending = obj.__dict__.get(self.name)
        if isinstance(pending, _FrameTotals):  # (the other field keeps its value: resolved first)
            pending.resolve(obj)
        obj.__dict__[self.name] = value


@dataclass
class Trajectory:
    """A recorded rollout. Shapes: N records, nc candidate contacts.

    t (N,), q (N, nq), v (N, nv); lam (N, nc, 3) contact forces (t1, t2, n) in N (time stepping:
    the step's impulse / h, eq. 70), each in its contact's frame (world: contact_force);
    contact_velocity (N, nc, 3) J v after each step; gaps (N, nc) signed distances (of the
    configuration the step's contact problem was built at: the step's start in time stepping);
    states (N, nc) 0 open / 1 stick / 2 slip / 3 closed; residual (N,) the largest solver
    residual of the step; iterations (N,); converged (N,); dt (N,) the step taken;
    timings (N, 5) µs per phase: kinematics+collision, Delassus, solve, integrate, total;
    rows (N, nc) rows each contact used in the step (3 spatial, 2 planar, 1 frictionless or
    mu = 0, 0 inactive; None in files saved before it was recorded).
    The joints (docs/joint-rows.md): tau (N, nv) the actuator torque applied over the step
    (feed-forward + PD, the implicit PD's at the step's end, after the effort limit: abs(tau) never
    exceeds it); joint_friction (N, nv) the joints' dry friction torque and limit_torque (N, nv) the
    position limits' torque, 0 where the joint had no such row (all three NaN in record 0; None in
    files saved before they were recorded).
    Sensors (docs/simulator.md, "Sensors"; stiction.sensors): contact_force (N, nc, 3) each
    candidate's force in the world frame, N (lam turned by the contact frame of the step's problem:
    the force on the contact's own body); frame_names, the frames carrying contacts, frame_incidence
    (nf, nc) int8 (+1: the contact's force acts on the frame, -1: its opposite), frame_force (N, nf, 3)
    their total world force and frame_states (N, nf) one state per frame (2 slip if a contact slips,
    1 stick, 3 closed, 0 open, -1 no step); accelerometer (N, 3) and gyro (N, 3) the IMU at the first
    root free flyer's origin in its frame (proper acceleration R0^T (a - g) of the step, m/s^2; angular
    velocity of the record's state, rad/s; None without a free flyer). Look forces up by name with
    contact_force_of(name) and frame_force_of(name). Record 0: NaN (states -1) but the gyro, which is
    its state's. All None in files saved before they were recorded.

    Record 0 is the state the rollout started from, before any step: its gaps are that state's
    signed distances, its rows the rows each contact would have there, its contact_velocity
    J v of that state (0 for candidates beyond the activation distance, as in every record);
    no force acted and no solve classified the contacts, so lam[0] is NaN and states[0] is -1
    (NO_STATE). residual, iterations, converged, dt and timings of record 0 are those of the
    step before the rollout, if any (a fresh simulator's: 0, 0, True, 0, 0): read the steps'
    from record 1 on. Files saved by earlier versions hold zeros in record 0's contact fields
    (its gaps too).
    """

    scene: str
    contact_names: list[str]
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    lam: np.ndarray
    contact_velocity: np.ndarray
    gaps: np.ndarray
    states: np.ndarray
    residual: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    dt: np.ndarray
    timings: np.ndarray
    rows: np.ndarray | None = None
    tau: np.ndarray | None = None
    joint_friction: np.ndarray | None = None
    limit_torque: np.ndarray | None = None
    contact_force: np.ndarray | None = None
    frame_names: list[str] | None = None
    frame_incidence: np.ndarray | None = None
    frame_force: np.ndarray | None = _LazyFrameField()  # (computed on first read: _FrameTotals)
    frame_states: np.ndarray | None = _LazyFrameField()
    accelerometer: np.ndarray | None = None
    gyro: np.ndarray | None = None

    def save(self, path: str | Path) -> None:
        arrays = {k: v for k, v in asdict(self).items() if isinstance(v, np.ndarray)}
        names = {} if self.frame_names is None else {"frame_names": np.array(self.frame_names, dtype=str)}
        np.savez_compressed(path, scene=self.scene, contact_names=np.array(self.contact_names), **names, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "Trajectory":
        with np.load(path, allow_pickle=False) as f:
            kw = {k: f[k] for k in f.files}
        kw["scene"] = str(kw["scene"])
        kw["contact_names"] = [str(x) for x in kw["contact_names"]]
        if "frame_names" in kw:
            kw["frame_names"] = [str(x) for x in kw["frame_names"]]
        return cls(**kw)

    def contact_force_of(self, name: str) -> np.ndarray:
        """The world force (N, 3) of the contact named `name` (a coal pair slot: ``pair#k``)."""
        if self.contact_force is None:
            raise ValueError("this trajectory has no contact_force (saved before sensors were recorded)")
        return self.contact_force[:, _sensors.lookup(self.contact_names, name, "contact")]

    def frame_force_of(self, name: str) -> np.ndarray:
        """The total world force (N, 3) on the frame named `name` (e.g. a foot: docs/simulator.md, "Sensors")."""
        if self.frame_force is None or self.frame_names is None:
            raise ValueError("this trajectory has no frame_force (saved before sensors were recorded)")
        return self.frame_force[:, _sensors.lookup(self.frame_names, name, "contact frame")]

    @property
    def frame_in_contact(self) -> np.ndarray | None:
        """(N, nf) bool: some contact of the frame carries a force in the step (stick, slip or closed)."""
        return None if self.frame_states is None else self.frame_states > 0


# Every override Simulator(scene, **overrides) accepts, and what it sets.
OVERRIDES = {
    "dt": "time step in s (time stepping and rk4; the adaptive mode's first step)",
    "duration": "default rollout duration in s",
    "mode": "timestep | rk4 | ode (= rk4) | adaptive",
    "delta": "ODE modes: Baumgarte delta in s (eq. 64; 0 = dt)",
    "zeta": "ODE modes: Baumgarte zeta (eq. 64)",
    "mu": "friction coefficient of every contact (ground, walls, coal pairs)",
    "tolerance": "contact solver tolerance on the relative residual",
    "max_iterations": "contact solver iteration budget per solve",
    "solver": "contact solver name (stiction.solver_names())",
    "warm_start": "start each step's solve from the previous step's impulses (default True; False: from zero)",
    "ode_tolerance": "adaptive mode: local error tolerance",
    "formulation": "how each step's problem is resolved (stiction.formulation_names(); default exact)",
    "pyramid_facets": "pyramid formulation: facets per friction cone (3 .. 1024, default 4)",
    "pyramid_inscribed": "pyramid formulation: corners on the cone (True) or facets tangent to it (False, default)",
    "penalty_stiffness": "penalty formulation: K in N/m per contact (default 1e5)",
    "penalty_damping": "penalty formulation: beta in s, damping K beta (default 1e-3)",
    "rigid_body_passes": "fused (default: one pass per robot, a speed choice) | pinocchio (Pinocchio's own "
                         "kinematics, crba, rnea, Cholesky and integrate: the reference)",
    "joint_limits": "1-dof joints' position limits as unilateral rows (default: the scene's [joints] limits, true)",
    "joint_friction": "joints' dry friction as box rows (default: the scene's [joints] friction, true)",
    "joint_damping": "joints' viscous damping, implicit (default: the scene's [joints] damping, true)",
    "effort_limits": "actuator effort limits (default: the scene's [joints] effort_limits, true)",
}
# The [joints] switches and the settings (and overrides) they set.
_JOINT_SWITCHES = {"joint_limits": "limits", "joint_friction": "friction", "joint_damping": "damping",
                   "effort_limits": "effort_limits"}
RIGID_BODY_PASSES = ("fused", "pinocchio")


def joint_switches(scene: Scene, overrides: dict) -> dict[str, bool]:
    """Which joint rows a run of `scene` has (joint_limits, joint_friction, joint_damping, effort_limits):
    each override given, else the scene's [joints] switch, else on. Shared by the Simulator and the
    MuJoCo twin (stiction.bench.mujoco_twins), so both apply the same ones."""
    joints_cfg = (scene.config or {}).get("joints") or {}
    out = {}
    for setting, key in _JOINT_SWITCHES.items():
        value = overrides.get(setting, joints_cfg.get(key, True))
        if not isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{setting} must be True or False, got {value!r}")
        out[setting] = bool(value)
    return out

_MODES = {"timestep": 0, "rk4": 1, "ode": 1, "adaptive": 2}
MAX_RECORD_BYTES = 4e9  # a trajectory larger than this is refused before simulating
MAX_STEPS = 1e9  # steps in one rollout (a C++ int counts them; a typo'd dt must not hang or overflow)


class _ReadOnly:
    """A read-only view of the C++ settings: they are fixed when the Simulator is built (the
    model is immutable), so assigning to them is an error instead of a silent no-op."""

    def __init__(self, settings):
        object.__setattr__(self, "_settings", settings)

    def __getattr__(self, name):
        return getattr(self._settings, name)

    def __setattr__(self, name, value):
        raise AttributeError(f"Simulator settings are read-only (cannot set {name!r}); "
                             f"build a new Simulator(scene, {name}=...) instead")

    def __repr__(self) -> str:
        keys = ("dt", "mode", "delta", "zeta", "tolerance", "max_iterations", "solver", "formulation",
                "ode_tolerance", "rigid_body_passes")
        return "SimulatorSettings(" + ", ".join(f"{k}={getattr(self._settings, k)!r}" for k in keys) + ")"


class Simulator:
    """A scene (name, TOML path or Scene) with its C++ model (immutable) and data (state).

    Overrides (keyword arguments; anything else is an error): see ``OVERRIDES`` —
    dt, duration, mode, delta, zeta, mu, tolerance, max_iterations, solver, ode_tolerance,
    formulation (exact, ccp, nakaoka, pyramid, penalty, pinocchio-admm, ...: docs/formulations.md)
    and its parameters pyramid_facets, pyramid_inscribed, penalty_stiffness, penalty_damping,
    rigid_body_passes (fused, the default, or pinocchio: Pinocchio's own passes, the reference).
    With another formulation than exact, ``converged`` (per step) is the formulation's own
    stopping test and ``residual`` stays the exact law's, the same yardstick for all.

    Control: ``sim.data.kp``, ``.kd``, ``.q_target``, ``.v_target``, ``.tau_ff`` read as numpy
    *views* on the simulator's data: ``sim.data.tau_ff[:] = u`` (or ``[i] = x``) takes effect at the
    next step, as does assigning a whole array (``sim.data.tau_ff = u``: shape, dtype and
    finiteness checked, and gains >= 0). An in-place write is checked by the next step, before it
    moves anything: a NaN, an infinity or a negative gain raises ValueError naming the field and
    index. State and outputs: ``sim.data.q``, ``.v`` and every array the last step left (``A``,
    ``b``, ``gaps``, ``candidate_lambda``, ...) read as *read-only copies*, ``.active`` and
    ``.states`` as tuples, ``.timings`` as a read-only mapping, ``.result`` as a copy with read-only
    attributes and arrays: writing into one raises. The supported way to set the state is :meth:`set_state`, which also
    normalises quaternions; :meth:`reset` returns to the scene's initial state and control (into
    the same data: views taken before stay valid). ``sim.data`` is the same object for the
    simulator's life (it cannot be replaced).
    """

    def __init__(self, scene: Scene | str | os.PathLike, **overrides):
        for key in overrides:
            if key not in OVERRIDES:
                hint = did_you_mean(key, OVERRIDES)
                raise TypeError(f"Simulator: unknown override {key!r} ({hint}valid: {', '.join(OVERRIDES)})")
        if isinstance(scene, Scene):
            sc = scene
        elif isinstance(scene, (str, os.PathLike)):
            sc = load_scene(scene)
        else:
            raise TypeError(f"Simulator: scene must be a Scene, a scene name or a TOML path, "
                            f"got {type(scene).__name__}")
        if "mu" in overrides:
            sc = _with_friction(sc, _positive("mu", overrides["mu"], allow_zero=True))
        self.scene = sc
        self.duration = _positive("duration", overrides.get("duration", sc.duration))
        settings = self._settings_from(sc, overrides)
        self.model = _core.SimulatorModel(sc.model, sc.halfspaces, sc.contacts, sc.anchors, settings,
                                          sc.geometry, sc.pairs)
        self._data = _core.SimulatorData(self.model)
        from .controllers import build_controller  # noqa: PLC0415

        self._controller_loop = None
        self.controller = build_controller(sc)
        self.reset()

    @staticmethod
    def _settings_from(sc: Scene, overrides: dict) -> "_core.SimulatorSettings":
        s = _core.SimulatorSettings()
        s.dt = _positive("dt", overrides.get("dt", sc.dt))
        mode = overrides.get("mode", sc.mode)
        if mode not in _MODES:
            raise ValueError(f"mode must be one of {', '.join(_MODES)}, got {mode!r}")
        s.mode = _core.IntegrationMode.values[_MODES[mode]]
        if mode == "timestep":
            for key in ("delta", "zeta", "ode_tolerance"):
                if key in overrides:
                    raise ValueError(f"{key} applies to the ODE modes (mode rk4, ode or adaptive), not to time stepping")
        s.delta = _positive("delta", overrides.get("delta", sc.delta), allow_zero=True)
        s.zeta = _positive("zeta", overrides.get("zeta", sc.zeta))
        s.tolerance = _positive("tolerance", overrides.get("tolerance", 1e-10))
        max_it = overrides.get("max_iterations", 200)
        if isinstance(max_it, bool) or not isinstance(max_it, (int, np.integer)) or max_it < 1:
            raise ValueError(f"max_iterations must be an integer >= 1, got {max_it!r}")
        s.max_iterations = int(max_it)
        solver = overrides.get("solver", "default")
        if solver not in _core.solver_names():
            raise ValueError(f"solver must be one of {', '.join(_core.solver_names())}, got {solver!r}")
        s.solver = solver
        warm = overrides.get("warm_start", True)
        if not isinstance(warm, (bool, np.bool_)):
            raise ValueError(f"warm_start must be True or False, got {warm!r}")
        s.warm_start = bool(warm)
        formulation = check_formulation(overrides.get("formulation", "exact"))
        if formulation != "exact" and solver != "default":  # as stiction.solve: nothing would use it
            raise ValueError(f"solver={solver!r} picks the exact law's algorithm; the {formulation} formulation "
                             "has its own (drop the solver, or use formulation 'exact')")
        s.formulation = formulation
        fs = formulation_settings(formulation, {k: overrides[k] for k in FORMULATION_PARAMETERS if k in overrides})
        s.formulation_settings = fs
        if formulation == "penalty" and mode != "timestep":
            raise ValueError("the penalty formulation integrates its springs by implicit Euler over the time "
                             "step (eq. 83-84, Kikuuwe-Fujimoto): it needs mode 'timestep'")
        if "ode_tolerance" in overrides:
            s.ode_tolerance = _positive("ode_tolerance", overrides["ode_tolerance"])
        passes = overrides.get("rigid_body_passes", "fused")
        if not isinstance(passes, str) or passes not in RIGID_BODY_PASSES:
            raise ValueError(f"rigid_body_passes must be one of {', '.join(RIGID_BODY_PASSES)}, got {passes!r}")
        s.rigid_body_passes = passes
        for setting, value in joint_switches(sc, overrides).items():
            setattr(s, setting, value)
        s.joint_limit_margin = float(((sc.config or {}).get("joints") or {}).get("limit_margin", 0.02))
        return s

    @property
    def data(self) -> _core.SimulatorData:
        """The state, control and last step's outputs (one object for the simulator's life, so the
        control views taken from it stay bound to this simulator)."""
        return self._data

    @data.setter
    def data(self, value) -> None:
        raise AttributeError("Simulator.data cannot be replaced (views of its control arrays would be left "
                             "pointing at the old one); set the state with set_state(q, v, t), the control "
                             "through sim.data.tau_ff etc., or reset()")

    @property
    def settings(self) -> _ReadOnly:
        """The settings the C++ model was built with (read-only)."""
        return _ReadOnly(self.model.settings)

    @property
    def dt(self) -> float:
        """The time step (read-only: build a new Simulator(scene, dt=...) to change it)."""
        return float(self.model.settings.dt)

    @property
    def contact_names(self) -> list[str]:
        """Candidates: the sphere/point contacts, then max_contacts slots per coal pair."""
        names = [c.name for c in self.scene.contacts]
        for p in self.scene.pairs:
            names += [f"{p.name}#{k}" for k in range(p.max_contacts)]
        return names

    def reset(self) -> None:
        """Back to the scene's initial state, time 0 and control (v_target 0). Written into the
        same data: views of the control arrays stay valid and show the scene's values."""
        sc, d = self.scene, self.data
        d.q, d.v, d.t = sc.q0, sc.v0, 0.0
        d.kp, d.kd, d.q_target, d.tau_ff = sc.kp, sc.kd, sc.q_target, sc.tau_ff
        d.v_target = np.zeros(sc.model.nv)
        reset = getattr(getattr(self, "controller", None), "reset", None)
        if callable(reset):  # (a plain function as controller has no state to forget)
            reset()

    def set_state(self, q=None, v=None, t: float | None = None) -> None:
        """Set the configuration q (nq), velocity v (nv) and/or time t. Arrays are checked for
        size and finiteness; quaternions (free-flyer and spherical joints) are normalised and a
        zero quaternion is an error."""
        model = self.scene.model
        if q is not None:
            qa = _vector("q", q, model.nq)
            self.data.q = _normalized_configuration(model, qa)
        if v is not None:
            self.data.v = _vector("v", v, model.nv)
        if t is not None:
            self.data.t = _positive("t", t, allow_zero=True)

    @property
    def controller(self):
        """The controller step() and rollout() run before each step: the scene's ``[controller]``
        (stiction.controllers), None without one. Set it to another (called as
        ``controller(State, sim.data)``) or to None to drive the robot yourself."""
        return self._controller

    @controller.setter
    def controller(self, controller) -> None:
        from .controllers import SimulatorLoop  # noqa: PLC0415

        if controller is not None and not callable(controller):
            raise TypeError(f"Simulator.controller must be callable (controller(state, data)) or None, "
                            f"got {type(controller).__name__}")
        self._controller = controller
        self._controller_loop = SimulatorLoop(controller) if controller is not None else None

    def step(self) -> None:
        """One step (time stepping: dt; the ODE modes: one step of their integrator). A scene with a
        ``[controller]`` runs it first, as rollout() does (a loop of step() and a rollout take the same
        steps); to drive such a scene yourself, set ``sim.controller = None``."""
        if self._controller_loop is not None:
            self._controller_loop(self)
        _core.step(self.model, self._data)

    def step_derivatives(self, wrt_q: bool = True) -> "StepDerivatives":
        """The analytic Jacobians of one time step from the current state (issue 26; eq. 70, exact
        formulation): a :class:`stiction.derivatives.StepDerivatives`. The step is run on a scratch
        data of this simulator: ``sim.data`` (state, control, outputs) is not changed, and the
        scene's controller is not run (the control in ``sim.data`` is the step's). The implicit
        function theorem at the converged impulse, contact by contact in its mode (open: λ = 0;
        stick: u = 0; slide: u_n = 0 and λ_t = -μ λ_n u_t / ‖u_t‖); ``modes`` and ``boundary`` say
        which, and where the derivative is one-sided (docs/simulator.md, "Derivatives of a step").

        ``wrt_q=False`` skips the derivatives with respect to q (``dq_dq``, ``dv_dq`` are then NaN):
        they are implemented for sphere and point contacts on half-spaces (fixed or on a body) and
        for anchors, and raise NotImplementedError for a coal pair's contact. Raises ValueError in the ODE modes or another formulation than exact, and
        NotImplementedError for a step with joint rows (limits, joint friction, effort limits)."""
        from .derivatives import _from_core  # noqa: PLC0415

        if getattr(self, "_derivative_data", None) is None:
            self._derivative_data = _core.SimulatorData(self.model)
        out = _core.step_derivatives(self.model, self._data, self._derivative_data, bool(wrt_q))
        return _from_core(out, self.contact_names)

    def _record_bytes(self, steps: int, record_every: int) -> int:
        """Bytes of the trajectory a rollout of `steps` steps recording every `record_every`-th makes."""
        nc = self.model.num_candidates
        # per record: the C++ recording's arrays (rollout.cpp: t, q, v, lam, contact_velocity, gaps, states,
        # rows, anchor_lam, tau, joint_friction, limit_torque, residual, iterations, converged, dt, timings,
        # contact_force, accelerometer) and the per-frame totals made from them (at most one frame per
        # candidate: a force and a state)
        per_record = self.model.nq + 4 * self.model.nv + 12 * nc + 3 * self.model.num_anchors + 13 + 4 * nc
        return (-(-steps // record_every) + 1) * per_record * 8

    def rollout(self, duration: float | None = None, record_every: int = 1,
                callback: Callable[["Simulator"], None] | None = None) -> Trajectory:
        """Simulate `duration` seconds (default: the scene's, or the `duration` override) from the
        current state. The loop runs in C++; a `callback(simulator)`, if given, is called from it
        before every step (e.g. to set data.tau_ff or data.q_target: the writes act on that step),
        with the GIL held. An exception it raises stops the rollout and propagates as raised, the
        simulator left after the steps done (no trajectory is returned). The callback must not step
        the simulator itself. In the adaptive mode the loop is Python's, one step at a time. A duration shorter
        than one step is refused (one that rounds to 0 steps too: 0.5 dt rounds to 0); otherwise
        round(duration / dt) steps are taken. The trajectory records the start, every
        `record_every`-th step and the final state: when the step count is not a multiple of
        `record_every`, its last record follows fewer steps than the others (its `dt` is the step's,
        so the summary's `steps` and `duration` still count the whole rollout). A scene with a
        ``[controller]`` runs it as the callback unless another is given (``self.controller``)."""
        if callback is None:
            callback = self._controller_loop
        duration = self.duration if duration is None else _positive("duration", duration)
        if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1:
            raise ValueError(f"record_every must be an integer >= 1, got {record_every!r}")
        if callback is not None and not callable(callback):
            raise TypeError(f"callback must be callable, got {type(callback).__name__}")
        settings = self.model.settings
        if settings.mode == _core.IntegrationMode.adaptive:
            return self._rollout_adaptive(duration, callback)
        steps = duration / settings.dt
        if round(steps) < 1:  # (not steps < 0.5: Python rounds 0.5 to 0, which ran 0 steps)
            raise ValueError(f"duration {duration:g} s is shorter than one step (dt = {settings.dt:g} s)")
        if steps > MAX_STEPS:
            raise ValueError(f"duration {duration:g} s at dt = {settings.dt:g} s is {steps:.3g} steps, more than "
                             f"one rollout takes ({MAX_STEPS:.0e}); use a larger dt or a shorter duration")
        n = int(round(steps))
        nc = self.model.num_candidates
        record_bytes = self._record_bytes(n, record_every)
        if record_bytes > MAX_RECORD_BYTES:
            raise ValueError(f"recording {n} steps every {record_every} would take {record_bytes / 1e9:.1f} GB; "
                             f"record less often (record_every = {math.ceil(record_bytes / MAX_RECORD_BYTES * record_every)}"
                             " or more) or simulate less")
        # the callback runs in the C++ loop, before each step (the GIL held): the same records as without
        # one, at ~0.1 us a step beyond the callback's own work (a Python loop of one-step rollouts: ~60 us)
        before_step = None if callback is None else functools.partial(callback, self)
        return self._trajectory(_rollout(self.model, self._data, n, record_every, before_step=before_step))

    def _rollout_adaptive(self, duration, callback) -> Trajectory:
        chunks = [_rollout(self.model, self.data, 0, 1)]
        end = self.data.t + duration
        while self.data.t < end - 1e-12:
            if callback is not None:
                callback(self)
            r = _rollout(self.model, self.data, 1, 1, initial_contacts=False)  # (its record 0 dropped)
            chunks.append({key: val[1:] for key, val in r.items()})
        rec = {key: np.concatenate([c[key] for c in chunks]) for key in chunks[0]}
        return self._trajectory(rec)

    def _trajectory(self, rec: dict) -> Trajectory:
        nc = self.model.num_candidates
        n = len(rec["t"])
        return Trajectory(
            scene=self.scene.name, contact_names=self.contact_names, t=rec["t"], q=rec["q"], v=rec["v"],
            lam=rec["lam"].reshape(n, nc, 3), contact_velocity=rec["contact_velocity"].reshape(n, nc, 3),
            gaps=rec["gaps"].reshape(n, nc), states=_states(rec["states"]).reshape(n, nc),
            residual=rec["residual"], iterations=rec["iterations"].astype(np.int32),
            converged=rec["converged"].astype(bool), dt=rec["dt"], timings=rec["timings"],
            rows=rec["rows"].astype(np.int8).reshape(n, nc), tau=rec["tau"], joint_friction=rec["joint_friction"],
            limit_torque=rec["limit_torque"], **self._sensor_fields(rec, n, nc))

    def _sensor_frames(self) -> tuple[list[str], np.ndarray]:
        """The frames carrying contacts and their incidence matrix (stiction.sensors.frame_incidence)."""
        if getattr(self, "_frames_cache", None) is None:
            self._frames_cache = _sensors.frame_incidence(self.scene)
        return self._frames_cache

    def _sensor_fields(self, rec: dict, n: int, nc: int) -> dict:
        """The Trajectory's sensor fields from a recording (docs/simulator.md, "Sensors")."""
        model = self.scene.model
        contact_force = rec["contact_force"].reshape(n, nc, 3)
        names, incidence = self._sensor_frames()
        # (the per-frame totals on the first read of either: most callers never read them)
        # (copies: an in-place change of contact_force or states before that read must not change them)
        frame_force = frame_states = _FrameTotals(incidence.copy(), contact_force.copy(),
                                                  _states(rec["states"]).reshape(n, nc))
        j = _sensors.imu_joint(model)
        iv = model.joints[j].idx_v if j else 0
        return {"contact_force": contact_force, "frame_names": list(names), "frame_incidence": incidence.copy(),
                "frame_force": frame_force, "frame_states": frame_states,
                "accelerometer": rec["accelerometer"].reshape(n, 3) if j else None,
                "gyro": rec["v"][:, iv + 3:iv + 6].copy() if j else None}

    def sensors(self) -> "_sensors.Sensors":
        """The sensors after the last step, as a Trajectory records them per step (docs/simulator.md,
        "Sensors"): contact forces in the world frame and by name, per-frame totals and states, the base's
        IMU and the applied joint torques. NaN (states -1) when no step is behind the current state (a
        fresh or reset simulator, or its time set since); the gyro is always the current state's."""
        return _sensors.read(self)

    def batch_rollout(self, states=None, duration: float | None = None, record_every: int = 1,
                      threads: int | None = None) -> "Batch":
        """Simulate several initial states of this scene at once on a pool of C++ threads (see
        :func:`batch_rollout`). `states`: a list of (q, v) pairs (either may be None: the scene's),
        or an int n for n copies of the current state. The simulator's own state is unchanged."""
        if self.controller is not None:
            raise ValueError(f"batch_rollout: scene {self.scene.name!r} has a controller, which runs in Python "
                             "before every step; roll it out with rollout()")
        if states is None:
            states = 1
        if isinstance(states, (int, np.integer)) and not isinstance(states, bool):
            if states < 1:
                raise ValueError(f"batch_rollout: states must be >= 1 copies, got {states}")
            states = [(None, None)] * int(states)
        sims = []
        for k, pair in enumerate(states):
            try:
                q, v = pair
            except (TypeError, ValueError):
                raise TypeError(f"batch_rollout: states[{k}] must be a (q, v) pair") from None
            clone = Simulator.__new__(Simulator)
            clone.scene, clone.duration, clone.model = self.scene, self.duration, self.model
            clone._data = _core.SimulatorData(self.model)
            clone.data.q, clone.data.v, clone.data.t = self.data.q, self.data.v, self.data.t
            clone.data.kp, clone.data.kd = self.data.kp, self.data.kd
            clone.data.q_target, clone.data.v_target, clone.data.tau_ff = (self.data.q_target, self.data.v_target,
                                                                           self.data.tau_ff)
            clone.set_state(q, v)
            sims.append(clone)
        return batch_rollout(sims, duration, record_every, threads)

    # ---- post-processing
    def contact_centers(self, traj: Trajectory) -> np.ndarray:
        """World position of every candidate sphere centre (points: the point), (N, nc, 3).
        Computed part by part in C++ (a Pinocchio Data of a world of many bodies would not fit)."""
        Q = np.atleast_2d(np.asarray(traj.q, dtype=float))
        return np.asarray(_core.contact_centers(self.model, Q)).reshape(len(Q), len(self.scene.contacts), 3)

    def joint_placements(self, Q) -> np.ndarray:
        """World placement of every joint at each configuration (a row of Q), (N, njoints, 4, 4)
        homogeneous matrices. Computed part by part in C++ (no world pinocchio.Data)."""
        Q = np.atleast_2d(np.asarray(Q, dtype=float))
        raw = np.asarray(_core.joint_placements(self.model, Q)).reshape(len(Q), self.scene.model.njoints, 4, 3)
        out = np.zeros((len(Q), self.scene.model.njoints, 4, 4))
        out[..., :3, :3] = raw[..., :3, :].transpose(0, 1, 3, 2)  # stored column by column
        out[..., :3, 3] = raw[..., 3, :]
        out[..., 3, 3] = 1.0
        return out

    def summary(self, traj: Trajectory) -> dict:
        """The numbers `stiction simulate --json` prints. The drift, slip and acceleration measures
        are taken over the records from the scene's settle_time on: a trajectory that does not go
        past settle_time is refused (ValueError) rather than reported as 0 drift. Timing: us_per_step and
        us_per_phase are the C++ step timer's means over the recorded steps (every step unless
        record_every > 1: the total time / steps), median_us_per_step and median_us_per_phase the medians."""
        sc = self.scene
        after = traj.t >= sc.settle_time - 1e-12
        if after.sum() < 2:
            raise ValueError(f"settle_time = {sc.settle_time:g} s (scene {sc.name!r}): the trajectory ends at t = "
                             f"{traj.t[-1]:g} s, with no record after settling to measure drift and slip on; "
                             "simulate longer than settle_time")
        free = sc.model.njoints > 1 and sc.model.joints[1].shortname() == "JointModelFreeFlyer"
        base = traj.q[:, :3] if free else np.zeros((len(traj.t), 3))
        i0 = int(np.argmax(after))
        base_drift = float(np.linalg.norm(base[-1] - base[i0])) if free else 0.0
        slipping = traj.states == 2
        vn = np.abs(traj.contact_velocity[..., 2])
        max_vn_slip = float(vn[slipping].max()) if slipping.any() else 0.0
        # acceleration along the slope (+x downhill): least-squares slope of the base's
        # world-frame x velocity (a free flyer's v is in its body frame: rotate it)
        accel = 0.0
        if free and after.sum() >= 3:
            vx = [pin.Quaternion(q[3:7]).matrix()[0] @ v[:3] for q, v in zip(traj.q[after], traj.v[after])]
            accel = float(np.polyfit(traj.t[after], vx, 1)[0])
        ns = len(sc.contacts)  # sphere/point contacts (centres known); coal slots follow
        # foot slip after settling, for the contacts that stay closed: the distance the
        # contact point slid (integral of the tangential contact velocity: rolling is
        # not slip), and the horizontal displacement of the sphere centre (the peers'
        # measure, which includes rolling).
        closed = (traj.gaps[after] <= 1e-4).all(axis=0)
        slip = displacement = 0.0
        if closed.any():
            speed = np.linalg.norm(traj.contact_velocity[after][:, closed, :2], axis=-1)
            slip = float((speed[1:] * traj.dt[after][1:, None]).sum(axis=0).max())
            sphere_closed = closed[:ns]
            if sphere_closed.any():
                centers = self.contact_centers(traj)
                disp = centers[after][:, sphere_closed, :2] - centers[i0][sphere_closed, :2]
                displacement = float(np.linalg.norm(disp, axis=-1).max())
        # rows per candidate contact: the most any recorded step used (0: never active)
        if traj.rows is not None and len(traj.t) > 1:
            rows_per_contact = [int(x) for x in traj.rows[1:].max(axis=0)]
            contact_rows = int(traj.rows[1:].sum(axis=1).max())
        else:
            rows_per_contact, contact_rows = [0] * traj.gaps.shape[1], 0
        # every free body's largest displacement from where it was after settling
        body_drift = 0.0
        for j in range(1, sc.model.njoints):
            if sc.model.joints[j].shortname() == "JointModelFreeFlyer":
                iq = sc.model.joints[j].idx_q
                d = np.linalg.norm(traj.q[after][:, iq:iq + 3] - traj.q[i0, iq:iq + 3], axis=1).max()
                body_drift = max(body_drift, float(d))
        base_speed, base_sway, settled = _rest_measures(sc.model, traj)
        joint_measures = _joint_measures(sc.model, self.settings, traj, i0)
        # the C++ step timer (kinematics, Delassus, solve, integrate, total) of every recorded step: the mean
        # is the total time / steps (a summary's cost: slow steps count in full), the median a typical step
        # (on pile-24 the median was 141 us against a mean of 238-349 us: half the time is in the slow steps)
        timed = traj.timings[1:] if len(traj.t) > 1 else np.zeros((1, 5))
        tim, tim_median = timed.mean(axis=0), np.median(timed, axis=0)
        # steps taken, not records: rollout(record_every=k) records every k-th step, each record
        # with the step dt that led to it (the adaptive mode records every step)
        steps = int(np.rint(np.diff(traj.t) / traj.dt[1:]).sum()) if len(traj.t) > 1 else 0
        out = {
            "scene": sc.name,
            "mode": {0: "timestep", 1: "rk4", 2: "adaptive"}[int(self.settings.mode)],
            "formulation": self.settings.formulation,
            "dt": self.settings.dt,
            "duration": float(traj.t[-1] - traj.t[0]),
            "steps": steps,
            "recorded_steps": int(len(traj.t) - 1),  # the convergence keys count these
            "contacts": len(sc.contacts),
            "max_body_drift": body_drift,
            "us_per_step": float(tim[4]),
            "median_us_per_step": float(tim_median[4]),
            "us_per_phase": {p: float(x) for p, x in zip(PHASES[:4], tim[:4])},
            "median_us_per_phase": {p: float(x) for p, x in zip(PHASES[:4], tim_median[:4])},
            "max_penetration": float(max(0.0, -np.nanmin(np.where(np.isfinite(traj.gaps), traj.gaps, np.nan))))
            if np.isfinite(traj.gaps).any() else 0.0,
            "max_residual": float(traj.residual.max()),
            "all_converged": bool(traj.converged[1:].all()),
            "unconverged_steps": int((~traj.converged[1:]).sum()),
            "first_unconverged_t": float(traj.t[1:][~traj.converged[1:]][0]) if not traj.converged[1:].all()
            else None,
            "settle_time": sc.settle_time,
            "base_drift": base_drift,
            "max_normal_velocity_while_sliding": max_vn_slip,
            "mean_acceleration_along_slope": accel,
            "expected_sliding_acceleration": sliding_acceleration(sc),
            "max_foot_slip": slip,
            "max_foot_displacement": displacement,
            "rows_per_contact": rows_per_contact,
            "contact_rows": contact_rows,
            "final_base_speed": base_speed,
            "final_base_sway": base_sway,
            "settled": settled,
            **joint_measures,
        }
        # a robot holding a posture whose contacts stick but whose base still moves sways (PD too soft
        # or a start posture off the settled one); one that slides or falls is not warned about
        window = traj.t >= traj.t[-1] - SETTLED_WINDOW - 1e-12
        actuated = bool((self.data.kp != 0).any() or (self.data.kd != 0).any())
        sticking = bool((traj.states[window] == 1).any() and not (traj.states[window] == 2).any())
        out["warnings"] = _warnings(out, swaying=out["settled"] is False and actuated and sticking)
        if getattr(self, "controller", None) is not None:
            out.update(_walking_measures(traj, free))
        return out


def _walking_measures(traj: Trajectory, free: bool) -> dict:
    """A controlled robot's measures (summary keys of scenes with a [controller]):
    distance_walked, the base's displacement along its initial heading (m, first record to last;
    None without a free-flyer base), and max_stance_slip, the largest slip of a contact point during
    one stance (a run of steps in which the contact sticks or slips), from the step after its
    touchdown step: the sum of the norm of the tangential contact velocity times dt (a sphere foot
    rolling as the leg pivots is not slip). Needs every step recorded (record_every = 1)."""
    from .controllers import distance_walked, stance_slip  # noqa: PLC0415

    speed = np.linalg.norm(traj.contact_velocity[..., :2], axis=-1)
    in_contact = (traj.states == 1) | (traj.states == 2)
    slip = stance_slip(speed[1:], in_contact[1:], traj.dt[1:]) if len(traj.t) > 1 else np.zeros(0)
    return {"distance_walked": distance_walked(traj.q) if free else None,
            "max_stance_slip": float(slip.max()) if slip.size else 0.0,
            "stance_slip_per_contact": [float(x) for x in slip]}


def _joint_measures(model: pin.Model, settings, traj: Trajectory, settled_from: int) -> dict:
    """The joints' measures of a summary (docs/joint-rows.md): max_limit_overshoot, the farthest a 1-dof
    joint went past a position limit (rad or m, over every record; 0 with joint_limits off: nothing
    enforced them); max_joint_drift, the largest motion of a 1-dof joint from where it was at settle_time;
    max_effort_ratio, the largest abs(tau) / effort limit of an actuator over the steps (<= 1: the limit holds;
    None without effort limits); saturated_steps, the steps in which some actuator sat at its limit."""
    overshoot, drift = 0.0, 0.0
    effort = np.asarray(model.effortLimit, dtype=float)
    for j in range(1, model.njoints):
        joint = model.joints[j]
        if joint.nq != 1 or joint.nv != 1:
            continue
        q = traj.q[:, joint.idx_q]
        drift = max(drift, float(np.abs(q[settled_from:] - q[settled_from]).max()))
        if settings.joint_limits:
            lower, upper = model.lowerPositionLimit[joint.idx_q], model.upperPositionLimit[joint.idx_q]
            overshoot = max(overshoot, float(max(0.0, (lower - q).max(), (q - upper).max())))
    limited = (effort > 0) & (effort < np.finfo(float).max) if settings.effort_limits else np.zeros(model.nv, bool)
    ratio, saturated = None, 0
    if limited.any() and traj.tau is not None and len(traj.t) > 1:
        r = np.abs(traj.tau[1:, limited]) / effort[limited]
        ratio = float(r.max())
        saturated = int((r >= 1.0).any(axis=1).sum())
    return {"max_limit_overshoot": overshoot, "max_joint_drift": drift, "max_effort_ratio": ratio,
            "saturated_steps": saturated}


def _normalized_configuration(model, q: np.ndarray) -> np.ndarray:
    return _quaternion_check(model, q, "q", strict=False)


def _contact_fields(cls) -> list[str]:
    """Every settable field of a bound contact type (its properties but the `planar` alias of
    `model`), so that a copy cannot drop one added later."""
    return [n for n in dir(cls) if not n.startswith("_") and n != "planar" and isinstance(getattr(cls, n), property)]


def _with_friction(scene: Scene, mu: float) -> Scene:
    """A copy of the scene with every contact's friction coefficient set to mu."""

    def copy_contact(c, cls):
        out = cls()
        for f in _contact_fields(cls):
            setattr(out, f, getattr(c, f))
        out.mu = mu
        return out

    contacts = [copy_contact(c, _core.SphereContact) for c in scene.contacts]
    pairs = [copy_contact(p, _core.GeometryPairContact) for p in scene.pairs]
    return dataclasses.replace(scene, contacts=contacts, pairs=pairs, mu=mu)


# `settled` (Simulator.summary): every floating base (free flyer or planar root: a robot's base, a
# free body) moves slower than SETTLED_SPEED at the end and stayed within SETTLED_SWAY of its final
# position over the final SETTLED_WINDOW of the run (the whole run when shorter).
SETTLED_SPEED = 1e-3  # m/s
SETTLED_SWAY = 1e-3  # m
SETTLED_WINDOW = 0.5  # s


def _floating_roots(model: pin.Model) -> list[tuple[int, int, int]]:
    """(joint, first q index of its position, first v index) of every free-flyer or planar root."""
    out = []
    for j in range(1, model.njoints):
        kind = model.joints[j].shortname()
        if model.parents[j] == 0 and kind in ("JointModelFreeFlyer", "JointModelPlanar"):
            out.append((j, model.joints[j].idx_q, model.joints[j].idx_v))
    return out


def _rest_measures(model: pin.Model, traj: Trajectory) -> tuple:
    """(final_base_speed, final_base_sway, settled): the largest speed of a floating base's origin at
    the last record, the largest distance of a base's origin from its final position over the final
    SETTLED_WINDOW, and whether both are below SETTLED_SPEED and SETTLED_SWAY; (None, None, None)
    without a floating base (a fixed-base robot)."""
    roots = _floating_roots(model)
    if not roots:
        return None, None, None
    window = traj.t >= traj.t[-1] - SETTLED_WINDOW - 1e-12
    speed = sway = 0.0
    for j, iq, iv in roots:
        if model.joints[j].shortname() == "JointModelFreeFlyer":
            # v[:3] is the origin's velocity in the base frame: its norm is the world speed
            position, velocity = traj.q[:, iq:iq + 3], traj.v[-1, iv:iv + 3]
        else:  # planar: (x, y) in the joint's plane, v = (vx, vy) in the body frame
            position, velocity = traj.q[:, iq:iq + 2], traj.v[-1, iv:iv + 2]
        speed = max(speed, float(np.linalg.norm(velocity)))
        sway = max(sway, float(np.linalg.norm(position[window] - position[-1], axis=1).max()))
    return speed, sway, bool(speed < SETTLED_SPEED and sway < SETTLED_SWAY)


PENETRATION_WARNING = 1e-3  # m


def _warnings(summary: dict, swaying: bool = False) -> list[str]:
    """What a reader of the summary should not miss (also printed by `stiction simulate`)."""
    out = []
    if summary["max_penetration"] > PENETRATION_WARNING:
        out.append(f"max penetration {summary['max_penetration']:.3g} m exceeds {PENETRATION_WARNING:g} m: the step "
                   f"dt = {summary['dt']:g} s is too coarse for the impact speeds (contacts are detected once per step)")
    if swaying:
        out.append(f"the robot has not settled: its base moves at {summary['final_base_speed']:.3g} m/s at the end "
                   f"and swayed {summary['final_base_sway']:.3g} m over the final {SETTLED_WINDOW:g} s (settled: "
                   f"< {SETTLED_SPEED:g} m/s and < {SETTLED_SWAY:g} m) while its contacts stick")
    if not summary["all_converged"]:
        of = f"{summary['steps']}" if summary["recorded_steps"] == summary["steps"] else \
            f"the {summary['recorded_steps']} recorded (of {summary['steps']})"
        out.append(f"{summary['unconverged_steps']} of {of} steps did not solve the contact problem "
                   f"to the tolerance (first at t = {summary['first_unconverged_t']:.6g} s)")
    return out


def sliding_acceleration(scene: Scene) -> float:
    """g (sin θ - μ cos θ) when that is positive (a rigid body slides), else 0; μ = 0 when every
    contact is frictionless (model frictionless or μ = 0)."""
    th = math.radians(scene.slope_deg)
    items = list(scene.contacts) + list(scene.pairs)
    frictionless = bool(items) and all(c.mu == 0.0 or c.model == _core.ContactModel.frictionless for c in items)
    a = 9.81 * (math.sin(th) - (0.0 if frictionless else scene.mu) * math.cos(th))
    return a if a > 0 else 0.0


@dataclass
class Batch:
    """Independent rollouts run together (:func:`batch_rollout`): one Trajectory per simulation
    and, for a simulation that stopped early (diverged, no contact solution), its error message
    (its trajectory then ends at the last state reached)."""

    trajectories: list[Trajectory]
    errors: list[str | None]
    seconds: float  # wall time of the whole batch

    def stacked(self, key: str) -> np.ndarray:
        """One field of every trajectory stacked along a new first axis, e.g. stacked("q") has shape
        (simulations, records, nq). ValueError when the shapes differ (different scenes, or a
        simulation that stopped early)."""
        arrays = [getattr(t, key) for t in self.trajectories]
        shapes = {a.shape for a in arrays}
        if len(shapes) > 1:
            raise ValueError(f"Batch.stacked({key!r}): the trajectories differ in shape {sorted(shapes)}")
        return np.stack(arrays)


def batch_rollout(simulators: list[Simulator], duration: float | None = None, record_every: int = 1,
                  threads: int | None = None) -> Batch:
    """Roll out several simulators at once on a pool of C++ threads (threads: None = one per
    core), the GIL released. Each simulator advances from its own state by round(duration / dt)
    steps (duration: None = the first simulator's). The simulators may differ (scenes, settings,
    formulations) but must be distinct objects; time stepping and rk4 modes (adaptive steps
    differ per simulation: roll those out one by one)."""
    import time as _time

    sims = list(simulators)
    if not sims:
        raise ValueError("batch_rollout: no simulators given")
    for k, s in enumerate(sims):
        if not isinstance(s, Simulator):
            raise TypeError(f"batch_rollout: simulators[{k}] is a {type(s).__name__}, not a Simulator")
        if s.model.settings.mode == _core.IntegrationMode.adaptive:
            raise ValueError(f"batch_rollout: simulators[{k}] uses adaptive steps; roll it out alone")
        if getattr(s, "controller", None) is not None:
            raise ValueError(f"batch_rollout: simulators[{k}] has a controller (scene {s.scene.name!r}), which runs "
                             "in Python before every step; roll it out alone (rollout())")
    if len({id(s.data) for s in sims}) != len(sims):
        raise ValueError("batch_rollout: a simulator appears twice (each simulation needs its own)")
    duration = sims[0].duration if duration is None else _positive("duration", duration)
    dts = {s.model.settings.dt for s in sims}
    if len(dts) > 1:
        raise ValueError(f"batch_rollout: the simulators have different time steps {sorted(dts)}")
    n = int(round(duration / dts.pop()))
    if n < 1:
        raise ValueError(f"batch_rollout: duration {duration:g} s is shorter than one step")
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1:
        raise ValueError(f"record_every must be an integer >= 1, got {record_every!r}")
    if threads is None:
        threads = 0
    elif isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 1:
        raise ValueError(f"batch_rollout: threads must be an integer >= 1 (or None: one per core), got {threads!r}")
    t0 = _time.perf_counter()
    recs = _core.batch_rollout([s.model for s in sims], [s.data for s in sims], n, int(record_every), int(threads))
    seconds = _time.perf_counter() - t0
    trajs, errors = [], []
    for s, rec in zip(sims, recs):
        errors.append(rec.pop("error"))
        m = len(rec["t"])
        rec = {k: (np.asarray(v).reshape(m) if k in _VECTOR_KEYS else np.asarray(v).reshape(m, -1))
               for k, v in rec.items()}
        trajs.append(s._trajectory(rec))
    return Batch(trajs, errors, seconds)
