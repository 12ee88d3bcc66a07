r"""Work-precision: error against the exact answer vs wall time per simulated second, per scene
and method, sweeping the time step dt and the solver tolerance (``stiction bench work-precision``).

**Scenes and their exact answers** (error in metres, always):

The methods that update x with the new velocity (time stepping and MuJoCo: symplectic Euler) are
measured against the exact law's own discrete answer at their dt (:func:`slide_distance`), the ODE
methods against the continuous one; each reference is exact to rounding (docs/benchmarks.md, "The
references", measured).

- ``cube-slide``: 1 kg cube thrown at v0 = 1 m/s, mu = 0.5: it stops after d = v0^2 / (2 mu g)
  (continuous); symplectic Euler stops after N dt v0 - mu g dt^2 N (N + 1) / 2, N =
  floor(v0 / (mu g dt)) (it sticks on the step the velocity would cross zero), which is
  d - v0 dt / 2 + mu g dt^2 f (1 - f) / 2 with f the fractional part of v0 / (mu g dt).
  error = max(\|x(T) - x0 - d'\|, max_t \|z - z0\|, max_t \|y - y0\|) (a hop counts).
- ``cube-incline-stick`` (30 deg, mu = 0.6), ``two-cube-stack``, ``pinch`` (the cube held
  between two squeezing pads, robots/scenes/pinch.toml): nothing moves. error = the largest
  displacement of a free body's centre over the run.
- ``cube-incline-slip`` (30 deg, mu = 0.5) and ``solo12-slope-slip`` (rigid Solo-12, 20 deg,
  mu = 0.2): translation downhill at a = g (sin th - mu cos th): s(T) = a T^2 / 2 (symplectic
  Euler from rest: a dt^2 k (k + 1) / 2 = a T^2 / 2 + a dt T / 2 at T = k dt, exactly).
  error = max(\|x(T) - x0 - s(T)\|, max_t \|z - z0\|, max_t \|y - y0\|).
- ``diagonal-push``: the cube of cube-slide from rest, pushed through its centre by
  F = 1.5 mu m g at 30 deg (body frame; stiction.casestudies.diagonal_push): the exact cone
  slides it along the push at a = 0.5 mu g. error = max(\|p_xy(T) - p0 - s(T) e_phi\|, max_t \|z - z0\|).
- ``solo12-stand``: no closed form for the settling robot: a converged reference (exact law, default
  solver, tolerance 1e-11, runs at dt = 1e-5 and 2e-5 s extrapolated to dt -> 0: 2 x(1e-5) - x(2e-5),
  time stepping being first order here). error = max(\|base height(T) - reference\|, largest
  horizontal distance of a foot-sphere centre at T from the reference's).

**Methods**: the formulations (exact, ccp, nakaoka, pyramid = 4 facets circumscribed, penalty
K = 1e5, pinocchio-admm, pinocchio-pgs, pinocchio-admm-ccp; time stepping eq. 65 / 78-79 /
80-81 / 83-84), exact with the nsgs / admm / newton solvers warm-started from the previous step
and cold (``-cold``; budget 10000 iterations), the relaxed ODE (eq. 64) with RK4 steps
(``ode-rk4``) and adaptive steps (``ode-adaptive``: its ``tol`` is the local error tolerance,
``dt`` the first step, the contact solver at 1e-10), and MuJoCo 4.0 when importable
(``mujoco-default``, ``-stiff``, ``-impratio10``, ``-noslip``: bench/mujoco_scenes.py).

**Sweeps**: dt over 0.1 ... 20 ms at tolerance 1e-10, and the tolerance over 1e-4 ... 1e-10 at
dt = 1 ms (``--quick``: two points each, a few scenes and methods).

**Cost**: ``seconds_per_simulated_second`` = wall time of the rollout (stiction: the C++ loop in
chunks; MuJoCo: ``mujoco.rollout``) / simulated time.

**One yardstick, honest failure** (issue 9): every step's contact forces and post-step contact
velocities (stiction's records: J v after the step, so the stabilisation that pushes a 1e-8 m
penetration out counts, ~1e-5 on Solo-12; MuJoCo's contacts, the same quantity) are scored against the exact law (eq. 65:
Signorini, the cone, maximum dissipation) in physical units, forces / (m g) and velocities /
v_ref (m the scene's total mass, v_ref = sqrt(g L), L its body size), per contact, as a
min-map: normal max(-lam_n / (m g), min(lam_n / (m g), \|u_n\| / v_ref)); friction
min(\|u_t\| / v_ref + (\|lam_t\| - mu lam_n)+ / (m g), \|lam_t + mu lam_n u_t / \|u_t\|\| / (m g))
(sticking, or sliding with the friction opposite the slip on the cone). ``law_residual`` is
the largest over contacts and steps. A run fails (``failed``, ``failure`` the first mode) when
its state is not finite, the simulator stops, it exceeds the time limit, it penetrates more than
max(1 mm, 1 % of L), or law_residual > ``--law-tolerance`` (default 1e-2: 1 % of the weight or
of v_ref, a gross violation: accuracy is the chart's x axis) -- never by the method's own
convergence flag (recorded as ``own_unconverged_steps``). A failed run counts at the time limit
(``seconds_per_simulated_second`` = limit / duration; the measured value is kept) and is drawn as a
cross on the chart's top edge.

**Rows** (CSV columns = ``FIELDS``, in order): ``scene``, ``method``, ``dt`` (s), ``tol``; ``error``
(m; None/NaN when the run stopped); ``seconds_per_simulated_second`` (the limit's for a failed
run); ``failed``; ``failure`` (None, "exact-law residual", "penetration", "time-limit",
"non-finite", "stopped: <message>" or "error: <exception>"); ``law_residual`` (the physical
exact-law residual above); ``max_normal_velocity`` (m/s, the largest \|u_n\| of a loaded contact
sliding faster than 1 um/s: the lift-off of eq. 78-79); ``penetration`` (m); ``steps``;
``own_unconverged_steps`` (steps that missed the method's own test: reported, not judged);
``duration`` (s simulated); ``measured_seconds_per_simulated_second``; ``time_limit`` (wall s);
``law_tolerance``; ``seed`` (the cases are deterministic: 0).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import time
from pathlib import Path

import numpy as np

NAME = "work-precision"
HELP = "error against the exact answer vs wall time per simulated second, per scene and method (dt and tolerance sweeps)"
FIELDS = ("scene", "method", "dt", "tol", "error", "seconds_per_simulated_second", "failed", "failure",
          "law_residual", "max_normal_velocity", "penetration", "steps", "own_unconverged_steps", "duration",
          "measured_seconds_per_simulated_second", "time_limit", "law_tolerance", "seed")
# the judgement's parameters too: a resumed sweep never mixes rows judged by other limits
KEY_FIELDS = ("scene", "method", "dt", "tol", "duration", "time_limit", "law_tolerance")
DEFAULT_WORKERS = 1  # wall times: one case at a time

G = 9.81
DTS = (1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 1e-2, 2e-2)
TOLS = (1e-4, 1e-6, 1e-8, 1e-10)
ODE_TOLS = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
BASE_DT, BASE_TOL = 1e-3, 1e-10
QUICK_DTS, QUICK_TOLS = (1e-3, 1e-2), (1e-4, 1e-10)
QUICK_SCENES = ("cube-incline-stick", "cube-slide")
QUICK_METHODS = ("exact", "ccp", "pyramid", "penalty", "mujoco-default")
TIME_LIMIT, QUICK_TIME_LIMIT = 20.0, 10.0  # wall seconds per case (a failed run is drawn at this limit)
LAW_TOLERANCE = 1e-2
REFERENCE_DT, REFERENCE_TOL = 1e-5, 1e-11


@dataclasses.dataclass(frozen=True)
class SceneCase:
    toml: str
    kind: str  # slide | rest | slope | push | reference
    duration: float  # full sweep, s
    quick_duration: float
    size: float  # L, m


SCENES = {
    "cube-slide": SceneCase("cube-slide", "slide", 0.5, 0.3, 0.1),
    "cube-incline-stick": SceneCase("cube-incline-stick", "rest", 1.0, 0.5, 0.1),
    "cube-incline-slip": SceneCase("cube-incline-slip", "slope", 1.0, 0.5, 0.1),
    "diagonal-push": SceneCase("cube-slide", "push", 0.5, 0.3, 0.1),
    "two-cube-stack": SceneCase("two-cube-stack", "rest", 1.0, 0.5, 0.1),
    "solo12-stand": SceneCase("solo12-stand", "reference", 1.0, 0.5, 0.2),
    "solo12-slope-slip": SceneCase("solo12-slope-slip", "slope", 0.5, 0.3, 0.2),
    "pinch": SceneCase("pinch", "rest", 1.0, 0.5, 0.1),
}
PUSH_PHI_DEG, PUSH_RATIO = 30.0, 1.5

# method -> Simulator overrides (+ "warm_start": False for the cold solvers)
STICTION_METHODS = {
    "exact": {},
    "ccp": {"formulation": "ccp"},
    "nakaoka": {"formulation": "nakaoka"},
    "pyramid": {"formulation": "pyramid"},
    "penalty": {"formulation": "penalty"},
    "pinocchio-admm": {"formulation": "pinocchio-admm"},
    "pinocchio-pgs": {"formulation": "pinocchio-pgs"},
    "pinocchio-admm-ccp": {"formulation": "pinocchio-admm-ccp"},
    **{f"exact-{s}{suffix}": {"solver": s, "max_iterations": 10000, **({"warm_start": False} if suffix else {})}
       for s in ("nsgs", "admm", "newton") for suffix in ("", "-cold")},
    "ode-rk4": {"mode": "rk4"},
    "ode-adaptive": {"mode": "adaptive"},
}
MUJOCO_METHODS = {f"mujoco-{v}": v for v in ("default", "stiff", "impratio10", "noslip")}
METHODS = tuple(STICTION_METHODS) + tuple(MUJOCO_METHODS)


def _symplectic(method: str) -> bool:
    """Time stepping and MuJoCo's Euler-type integrators update x with the new velocity."""
    return method not in ("ode-rk4", "ode-adaptive")


# ---------------------------------------------------------------- the yardstick
def law_violation(lam_n, lam_t, u_n, u_t, mu, f_ref: float, v_ref: float) -> np.ndarray:
    """Per contact, the exact law's min-map in physical units (module doc): forces (N) / f_ref,
    velocities (m/s) / v_ref; lam_t, u_t of shape (n, 2); 0 at an exact solution (eq. 65)."""
    lam_n, u_n = np.asarray(lam_n, float), np.asarray(u_n, float)
    lam_t, u_t = np.asarray(lam_t, float).reshape(-1, 2), np.asarray(u_t, float).reshape(-1, 2)
    mu = np.broadcast_to(np.asarray(mu, float), lam_n.shape)
    normal = np.maximum(np.maximum(-lam_n, 0.0) / f_ref, np.minimum(np.maximum(lam_n, 0.0) / f_ref, np.abs(u_n) / v_ref))
    speed = np.linalg.norm(u_t, axis=1)
    lt = np.linalg.norm(lam_t, axis=1)
    stick = speed / v_ref + np.maximum(lt - mu * np.maximum(lam_n, 0.0), 0.0) / f_ref
    with np.errstate(invalid="ignore", divide="ignore"):
        direction = np.where(speed[:, None] > 0, u_t / np.where(speed > 0, speed, 1.0)[:, None], 0.0)
    slip = np.where(speed > 0, np.linalg.norm(lam_t + (mu * np.maximum(lam_n, 0.0))[:, None] * direction, axis=1)
                    / f_ref, np.inf)
    return np.maximum(normal, np.minimum(stick, slip))


# ---------------------------------------------------------------- scenes
def _scene(name: str):
    """The stiction Scene of a work-precision scene (diagonal-push: cube-slide from rest, pushed)."""
    from ..scene import load_scene  # noqa: PLC0415

    sc = load_scene(SCENES[name].toml)
    if name == "diagonal-push":
        mass = float(sum(i.mass for i in sc.model.inertias))
        tau = np.zeros(sc.model.nv)
        phi = math.radians(PUSH_PHI_DEG)
        F = PUSH_RATIO * float(sc.mu) * mass * G
        tau[:2] = F * math.cos(phi), F * math.sin(phi)
        sc = dataclasses.replace(sc, name="diagonal-push", v0=np.zeros(sc.model.nv), tau_ff=tau)
    return sc


def _free_bodies(model) -> list[int]:
    """idx_q of every free-flyer joint (the free bodies' positions)."""
    return [model.joints[j].idx_q for j in range(1, model.njoints)
            if model.joints[j].shortname() == "JointModelFreeFlyer"]


def _mass(sc) -> float:
    return float(sum(i.mass for i in sc.model.inertias))


def slide_distance(v0: float, a: float, h: float, steps: int | None = None) -> float:
    """Distance the exact law's time stepping slides a body thrown at v0 against a constant
    friction deceleration a = mu g in `steps` steps of h (None: until it stops).

    The scheme is symplectic Euler (eq. 65-70; src/cpp/include/stiction/simulator.hpp): v+ = v - a h,
    then x+ = x + h v+. While v - a h >= 0 the contact slides with the full friction mu m g; on the
    step where the velocity would cross zero the exact law needs less than the cone's edge to stop
    it (m v / h < mu m g), so it sticks: v+ = 0, and that step adds h * 0 to x. With
    N = floor(v0 / (a h)) sliding steps, v_k = v0 - k a h and, for k <= N,

        x_k = k h v0 - a h^2 k (k + 1) / 2 = v0 t - a t^2 / 2 - a h t / 2   (t = k h);

    afterwards x stays at x_N. Writing v0 / (a h) = N + f (0 <= f < 1), the stop
    x_N = v0^2 / (2 a) - v0 h / 2 + a h^2 f (1 - f) / 2: the common formula v0^2/(2a) - v0 h/2 is
    exact only when v0 / (a h) is an integer and is off by up to a h^2 / 8 otherwise."""
    if not (v0 >= 0 and a > 0 and h > 0):
        raise ValueError(f"slide_distance: needs v0 >= 0, a > 0, h > 0; got v0={v0!r}, a={a!r}, h={h!r}")
    n = math.floor(v0 / (a * h))  # x_N is continuous in v0 / (a h) at the integers: rounding there is harmless
    if steps is not None:
        if steps < 0:
            raise ValueError(f"slide_distance: steps must be >= 0, got {steps!r}")
        n = min(n, int(steps))
    return n * h * v0 - a * h * h * n * (n + 1) / 2


def _exact_motion(name: str, sc, t: float, dt: float, symplectic: bool) -> np.ndarray:
    """Displacement (3,) of the first free body at time t under the exact law (module doc).

    symplectic: the exact law's own time stepping at dt (time stepping, MuJoCo), t = k dt, the
    discrete answer of the scheme (x_k from k updates v+ = v + a dt, x+ = x + dt v+); else the
    continuous answer (the ODE methods)."""
    kind = SCENES[name].kind
    k = int(round(t / dt))
    if kind == "slide":
        v0 = float(sc.v0[0])
        a = float(sc.mu) * G
        if symplectic:
            return np.array([slide_distance(v0, a, dt, k), 0.0, 0.0])
        s = v0 * t - a * t * t / 2 if t < v0 / a else v0 * v0 / (2 * a)
        return np.array([s, 0.0, 0.0])
    if kind in ("slope", "push"):
        # from rest at a constant acceleration: sum_{j=1..k} dt (j a dt) = a dt^2 k (k + 1) / 2
        if kind == "slope":
            from ..simulator import sliding_acceleration  # noqa: PLC0415

            a = sliding_acceleration(sc)
        else:
            a = (PUSH_RATIO - 1.0) * float(sc.mu) * G
        s = a * dt * dt * k * (k + 1) / 2 if symplectic else a * t * t / 2
        if kind == "slope":
            return np.array([s, 0.0, 0.0])
        phi = math.radians(PUSH_PHI_DEG)
        return np.array([s * math.cos(phi), s * math.sin(phi), 0.0])
    return np.zeros(3)


def _motion_error(name: str, sc, positions: np.ndarray, t_end: float, dt: float, symplectic: bool) -> float:
    """positions (N, bodies, 3) of the free bodies' centres over the run (module doc)."""
    kind = SCENES[name].kind
    p0 = positions[0]
    if kind == "rest":
        return float(np.linalg.norm(positions - p0, axis=-1).max())
    d = positions[:, 0] - p0[0]
    target = _exact_motion(name, sc, t_end, dt, symplectic)
    height = float(np.abs(d[:, 2]).max())
    if kind == "push":
        return max(float(np.linalg.norm(d[-1, :2] - target[:2])), height)
    return max(abs(float(d[-1, 0] - target[0])), height, float(np.abs(d[:, 1]).max()))


def _settled(name: str, duration: float, dt: float) -> np.ndarray:
    """(base height, foot-sphere centres x y z ...) of the scene at `duration`, exact law at `dt`
    and tolerance REFERENCE_TOL."""
    from ..simulator import Simulator  # noqa: PLC0415

    sim = Simulator(_scene(name), dt=dt, tolerance=REFERENCE_TOL, max_iterations=10000)
    traj = sim.rollout(duration, record_every=int(round(duration / dt)))
    feet = np.asarray(sim.contact_centers(traj)[-1], dtype=float)
    return np.concatenate([[float(traj.q[-1, 2])], feet.ravel()])


@functools.lru_cache(maxsize=None)
def _reference(name: str, duration: float) -> tuple[float, tuple]:
    """solo12-stand's converged reference: (base height, foot centres (4, 3)) at `duration`.

    Time stepping converges at first order in dt here (measured over 1 s: runs at 5e-6 and 1e-5 s
    are 1.4e-9 m apart, at 1e-5 and 2e-5 s 2.8e-9 m), so the runs at REFERENCE_DT and 2 REFERENCE_DT
    are extrapolated (Richardson: 2 x(h) - x(2h), second order: successive extrapolations differ
    1 : 4). The plain run at 1e-5 s is 2.8e-9 m (1 s) / 6.0e-9 m (0.5 s) from the limit, the
    extrapolation ~6e-12 / ~5e-11 m (docs/benchmarks.md, "The references")."""
    fine, coarse = _settled(name, duration, REFERENCE_DT), _settled(name, duration, 2 * REFERENCE_DT)
    ref = 2 * fine - coarse
    return float(ref[0]), tuple(map(tuple, ref[1:].reshape(-1, 3)))


def _reference_error(name: str, duration: float, base_z: float, feet: np.ndarray) -> float:
    ref_z, ref_feet = _reference(name, duration)
    return max(abs(base_z - ref_z), float(np.linalg.norm(feet[:, :2] - np.asarray(ref_feet)[:, :2], axis=1).max()))


# ---------------------------------------------------------------- one case
def _run_stiction(case: dict, sc) -> dict:
    method, dt, tol, duration = case["method"], case["dt"], case["tol"], case["duration"]
    overrides = {"dt": dt, **STICTION_METHODS[method]}
    if method == "ode-adaptive":
        overrides["ode_tolerance"] = tol
        overrides["tolerance"] = BASE_TOL
    else:
        overrides["tolerance"] = tol
    from ..simulator import Simulator  # noqa: PLC0415

    sim = Simulator(sc, **overrides)
    # chunks of ~0.1 s simulated: the time limit is checked between them
    chunk = max(dt, min(duration, round(0.1 / dt) * dt))
    trajs, wall, stopped = [], 0.0, None
    simulated = 0.0
    while simulated < duration - 1e-9 and stopped is None:
        span = min(chunk, duration - simulated)
        t0 = time.perf_counter()
        try:
            trajs.append(sim.rollout(span))
        except (RuntimeError, ValueError) as exc:  # no contact solution, diverged forces
            stopped = "stopped: " + str(exc).splitlines()[0][:120]
        wall += time.perf_counter() - t0
        simulated += span
        if trajs and not (np.isfinite(trajs[-1].q).all() and np.isfinite(trajs[-1].v).all()):
            stopped = "non-finite"
        elif wall > case["time_limit"] and simulated < duration - 1e-9:
            stopped = "time-limit"
    out = {"wall": wall, "stopped": stopped, "steps": 0, "own_unconverged_steps": 0, "law_residual": math.nan,
           "max_normal_velocity": math.nan, "penetration": math.nan, "error": math.nan}
    if not trajs:
        return out
    q = np.concatenate([trajs[0].q] + [t.q[1:] for t in trajs[1:]])
    free = _free_bodies(sc.model)
    positions = np.stack([q[:, i:i + 3] for i in free], axis=1) if free else None
    lam = np.concatenate([t.lam[1:] for t in trajs])
    vel = np.concatenate([t.contact_velocity[1:] for t in trajs])
    rows = np.concatenate([t.rows[1:] for t in trajs])
    gaps = np.concatenate([t.gaps[1:] for t in trajs])
    active = rows > 0
    mus = np.array([c.mu for c in sc.contacts] + [p.mu for p in sc.pairs for _ in range(p.max_contacts)])
    mu = np.broadcast_to(mus, rows.shape)[active]
    f_ref, v_ref = _mass(sc) * G, math.sqrt(G * SCENES[case["scene"]].size)
    viol = law_violation(lam[active][:, 2], lam[active][:, :2], vel[active][:, 2], vel[active][:, :2], mu, f_ref,
                         v_ref)
    sliding = active & (np.linalg.norm(vel[..., :2], axis=-1) > 1e-6) & (lam[..., 2] > 0)
    out.update({
        "steps": int(sum(len(t.t) - 1 for t in trajs)),
        "own_unconverged_steps": int(sum((~t.converged[1:]).sum() for t in trajs)),
        "law_residual": float(viol.max()) if viol.size else 0.0,
        "max_normal_velocity": float(np.abs(vel[..., 2][sliding]).max()) if sliding.any() else 0.0,
        "penetration": float(max(0.0, -np.nanmin(np.where(np.isfinite(gaps), gaps, np.nan))))
        if np.isfinite(gaps).any() else 0.0,
    })
    if stopped is not None:
        return out
    t_end = float(trajs[-1].t[-1])
    kind = SCENES[case["scene"]].kind
    if kind == "reference":
        feet = sim.contact_centers(trajs[-1])[-1]
        out["error"] = _reference_error(case["scene"], duration, float(q[-1, 2]), feet)
    else:
        out["error"] = _motion_error(case["scene"], sc, positions, t_end, dt, _symplectic(method))
    return out


def _mujoco_model(case: dict, sc):
    """(model, initial state, bodies to follow, geoms to follow) of the scene's MuJoCo twin."""
    import mujoco  # noqa: PLC0415

    from . import mujoco_scenes as ms  # noqa: PLC0415

    name, variant = case["scene"], MUJOCO_METHODS[case["method"]]
    kind = SCENES[name].kind
    feet = ()
    if name.startswith("solo12"):
        lock = name == "solo12-slope-slip"
        spec = ms.solo12_spec(sc, lock_joints=lock)
        robot_q0 = ms._solo12_q0()
        q0 = np.concatenate([sc.q0[:7], robot_q0[7:]]) if lock else sc.q0
        bodies, feet = ["base_link"], ["FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"]
    elif name == "pinch":
        spec = ms.pinch_spec(sc)
        bodies = ["box0"]
    elif name == "two-cube-stack":
        spec = ms.boxes_spec(sc, [(0, 0, 0.05), (0, 0, 0.15)], float(sc.mu))
        bodies = ["box0", "box1"]
    else:
        push = None
        if kind == "push":
            push = tuple(float(x) for x in sc.tau_ff[:2])
        spec = ms.boxes_spec(sc, [(0, 0, 0.05)], float(sc.mu), push=push)
        bodies = ["box0"]
    ms.apply_options(spec, sc, case["dt"], case["tol"], variant)
    model = spec.compile()
    data = mujoco.MjData(model)
    if name.startswith("solo12"):
        state = ms.solo12_state(model, q0, None if name == "solo12-slope-slip" else sc.q_target)
    else:
        if name == "pinch":
            data.ctrl[:] = [float(sc.q_target[0]), float(sc.q_target[1])]
        elif kind == "push":
            data.ctrl[:] = 1.0
        if kind == "slide":
            data.qvel[:6] = sc.v0[:6]
        state = ms.state_of(model, data)
    return model, state, bodies, list(feet)


def _run_mujoco(case: dict, sc) -> dict:
    from . import mujoco_scenes as ms  # noqa: PLC0415

    dt, duration = case["dt"], case["duration"]
    model, state, bodies, feet = _mujoco_model(case, sc)
    n = int(round(duration / dt))
    wall = ms.timed_rollout(model, state, n)
    rec = ms.record(model, state, n, bodies, feet, time_limit=case["time_limit"])
    f_ref, v_ref = _mass(sc) * G, math.sqrt(G * SCENES[case["scene"]].size)
    mu = float(sc.mu) if case["scene"] != "pinch" else 0.5
    viol = law_violation(rec["lam_n"], rec["lam_t"], rec["u_n"], rec["u_t"], mu, f_ref, v_ref)
    sliding = (np.linalg.norm(rec["u_t"], axis=1) > 1e-6) & (rec["lam_n"] > 0)
    out = {"wall": wall, "stopped": rec["stopped"], "steps": rec["steps"], "own_unconverged_steps": 0,
           "law_residual": float(viol.max()) if viol.size else 0.0,
           "max_normal_velocity": float(np.abs(rec["u_n"][sliding]).max()) if sliding.any() else 0.0,
           "penetration": rec["penetration"], "error": math.nan}
    if rec["stopped"] is None:
        pos = rec["positions"]
        if SCENES[case["scene"]].kind == "reference":
            out["error"] = _reference_error(case["scene"], duration, float(pos[-1, 0, 2]), rec["centres"][-1])
        else:
            out["error"] = _motion_error(case["scene"], sc, pos, n * dt, dt, True)
    return out


def evaluate(case: dict) -> dict:
    """One (scene, method, dt, tol): run, score, classify (module doc). Never raises for a
    failing method: the failure is the row's ``failure``."""
    name, method = case["scene"], case["method"]
    if name not in SCENES:
        raise ValueError(f"work-precision: unknown scene {name!r} (known: {', '.join(SCENES)})")
    if method not in METHODS:
        raise ValueError(f"work-precision: unknown method {method!r} (known: {', '.join(METHODS)})")
    sc = _scene(name)
    try:
        res = _run_mujoco(case, sc) if method in MUJOCO_METHODS else _run_stiction(case, sc)
    except Exception as exc:  # noqa: BLE001 - a failing method is data
        res = {"wall": math.nan, "stopped": f"error: {type(exc).__name__}: {str(exc).splitlines()[0][:120]}",
               "steps": 0, "own_unconverged_steps": 0, "law_residual": math.nan, "max_normal_velocity": math.nan,
               "penetration": math.nan, "error": math.nan}
    duration = case["duration"]
    failure = res["stopped"]
    if failure is None and not math.isfinite(res["error"]):
        failure = "non-finite"
    if failure is None and res["penetration"] > max(1e-3, 0.01 * SCENES[name].size):
        failure = "penetration"
    if failure is None and not res["law_residual"] <= case["law_tolerance"]:
        failure = "exact-law residual"
    measured = res["wall"] / duration
    return {
        "scene": name, "method": method, "dt": case["dt"], "tol": case["tol"], "error": res["error"],
        "seconds_per_simulated_second": case["time_limit"] / duration if failure else measured,
        "failed": failure is not None, "failure": failure, "law_residual": res["law_residual"],
        "max_normal_velocity": res["max_normal_velocity"], "penetration": res["penetration"],
        "steps": res["steps"], "own_unconverged_steps": res["own_unconverged_steps"], "duration": duration,
        "measured_seconds_per_simulated_second": measured, "time_limit": case["time_limit"],
        "law_tolerance": case["law_tolerance"], "seed": case["seed"],
    }


# ---------------------------------------------------------------- the bench contract
def add_arguments(parser) -> None:
    parser.add_argument("--scenes", nargs="+", choices=list(SCENES), default=None,
                        help=f"scenes (default: all; --quick: {', '.join(QUICK_SCENES)})")
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=None,
                        help=f"methods (default: all, MuJoCo's when importable; --quick: {', '.join(QUICK_METHODS)})")
    parser.add_argument("--time-limit", type=float, default=None,
                        help=f"wall seconds per case (default {TIME_LIMIT:g}, --quick {QUICK_TIME_LIMIT:g})")
    parser.add_argument("--law-tolerance", type=float, default=LAW_TOLERANCE,
                        help=f"physical exact-law residual above which a run fails (default {LAW_TOLERANCE:g})")


def cases(args) -> list[dict]:
    from . import mujoco_scenes as ms  # noqa: PLC0415

    quick = bool(getattr(args, "quick", False))
    scenes, methods = getattr(args, "scenes", None), getattr(args, "methods", None)
    # an option given empty is an error naming it, never the default
    for flag, given in (("--scenes", scenes), ("--methods", methods)):
        if given is not None and not len(given):
            raise ValueError(f"work-precision: {flag}: empty list")
    scenes = scenes if scenes is not None else (QUICK_SCENES if quick else tuple(SCENES))
    methods = methods if methods is not None else (QUICK_METHODS if quick else METHODS)
    for s in scenes:
        if s not in SCENES:
            raise ValueError(f"work-precision: unknown scene {s!r} (known: {', '.join(SCENES)})")
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"work-precision: unknown method {m!r} (known: {', '.join(METHODS)})")
    if not ms.available():
        asked = [m for m in (getattr(args, "methods", None) or ()) if m in MUJOCO_METHODS]
        if asked:
            raise ValueError(f"work-precision: {', '.join(asked)} need MuJoCo (the optional `bench` extra: "
                             "pip install 'mujoco==4.0.*'), which is not importable")
        methods = [m for m in methods if m not in MUJOCO_METHODS]  # the default set: MuJoCo when installed
    limit = getattr(args, "time_limit", None) or (QUICK_TIME_LIMIT if quick else TIME_LIMIT)
    law = getattr(args, "law_tolerance", LAW_TOLERANCE)
    if not (limit > 0 and math.isfinite(limit)):
        raise ValueError(f"work-precision: --time-limit must be a positive number of seconds, got {limit!r}")
    if not (law > 0 and math.isfinite(law)):
        raise ValueError(f"work-precision: --law-tolerance must be positive, got {law!r}")
    dts, tols = (QUICK_DTS, QUICK_TOLS) if quick else (DTS, TOLS)
    out = []
    for s in scenes:
        duration = SCENES[s].quick_duration if quick else SCENES[s].duration
        for m in methods:
            if m == "ode-adaptive":
                points = [(BASE_DT, t) for t in ((1e-3, 1e-5) if quick else ODE_TOLS)]
            else:
                points = [(dt, BASE_TOL) for dt in dts] + [(BASE_DT, t) for t in tols if t != BASE_TOL]
            for dt, tol in points:
                out.append({"scene": s, "method": m, "dt": dt, "tol": tol, "duration": duration,
                            "time_limit": float(limit), "law_tolerance": float(law), "seed": 0})
    return out


def summarize(rows: list[dict]) -> dict:
    """Per scene and method: the error floor (smallest error of a run that did not fail) and
    the cheapest run within 10x of it."""
    floors: dict = {}
    for r in rows:
        if r["failed"] or not _finite(r["error"]):
            continue
        key = f"{r['scene']}/{r['method']}"
        best = floors.get(key)
        if best is None or r["error"] < best["error"]:
            floors[key] = {"error": r["error"], "dt": r["dt"], "tol": r["tol"],
                           "seconds_per_simulated_second": r["seconds_per_simulated_second"]}
    failed = sum(bool(r["failed"]) for r in rows)
    return {"error_floors": floors, "failed_runs": failed}


def _finite(x) -> bool:
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def plot(rows: list[dict], out_dir: Path, stamp: dict) -> list[Path]:
    """One log-log chart per scene: x = error (m), y = wall s per simulated s, a line per method
    (its dt sweep solid, its tolerance sweep dotted), each method's error floor a short vertical
    tick, failed runs a cross on the top edge (the time limit) at their error (or the right edge)."""
    from .._optional import require  # noqa: PLC0415
    from . import sweep  # noqa: PLC0415

    matplotlib = require("matplotlib", "plot", "the work-precision charts")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for scene in [s for s in SCENES if any(r["scene"] == s for r in rows)]:
        mine = [r for r in rows if r["scene"] == scene]
        methods = [m for m in METHODS if any(r["method"] == m for r in mine)]
        ok = [r for r in mine if not _bool(r["failed"]) and _finite(r["error"])]
        errs = [max(float(r["error"]), 1e-17) for r in ok]
        xmin = min(errs, default=1e-16) / 3
        xmax = max(errs + [float(r["error"]) for r in mine if _finite(r["error"]) and float(r["error"]) > 0],
                   default=1.0) * 3
        limit = max(float(r["time_limit"]) / float(r["duration"]) for r in mine)
        fig, ax = plt.subplots(figsize=(9, 6))
        for i, m in enumerate(methods):
            color, marker = plt.get_cmap("tab20")(i % 20), "osD^v<>ph*"[i % 10]
            good = [r for r in ok if r["method"] == m]
            if m == "ode-adaptive":  # its sweep is the local error tolerance, at one first step
                dt_sweep = sorted(good, key=lambda r: -float(r["tol"]))
            else:
                dt_sweep = sorted((r for r in good if float(r["tol"]) == BASE_TOL), key=lambda r: float(r["dt"]))
            tol_sweep = sorted((r for r in good if float(r["dt"]) == BASE_DT), key=lambda r: float(r["tol"]))
            label = m
            if dt_sweep:
                ax.loglog([max(float(r["error"]), 1e-17) for r in dt_sweep],
                          [float(r["seconds_per_simulated_second"]) for r in dt_sweep], "-" + marker, color=color,
                          ms=4, label=label)
                label = None
            if len(tol_sweep) > 1 and m != "ode-adaptive":
                ax.loglog([max(float(r["error"]), 1e-17) for r in tol_sweep],
                          [float(r["seconds_per_simulated_second"]) for r in tol_sweep], ":" + marker, color=color,
                          ms=3, mfc="none", label=label)
            if good:
                floor = min(max(float(r["error"]), 1e-17) for r in good)
                ax.axvline(floor, ymin=0.0, ymax=0.04, color=color, lw=2)
            bad = [r for r in mine if r["method"] == m and _bool(r["failed"])]
            if bad:
                xs = [float(r["error"]) if _finite(r["error"]) and float(r["error"]) > 0 else xmax for r in bad]
                ax.plot([min(max(x, xmin), xmax) for x in xs], [limit] * len(bad), "x", color=color, ms=8, mew=2,
                        label=None if good else f"{m} (failed)")
        ax.axhline(limit, color="0.5", lw=0.8, ls="--")
        ax.text(xmin * 1.1, limit * 1.05, "time limit: failed runs (x)", fontsize=7, color="0.4")
        ax.set_xlim(xmin, xmax)
        ax.set_xlabel(f"error against the exact answer [m] ({SCENES[scene].kind}; 0 drawn at 1e-17)", fontsize=9)
        ax.set_ylabel("wall seconds per simulated second")
        ax.set_title(f"work-precision: {scene} (dt sweep solid, tolerance sweep dotted; ticks: error floors)",
                     fontsize=10)
        ax.grid(True, which="both", alpha=0.25)
        ax.legend(fontsize=7, ncol=2, loc="center left", bbox_to_anchor=(1.01, 0.5))
        fig.tight_layout()
        sweep.stamp_figure(fig, stamp)
        path = out_dir / f"work-precision-{scene}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def _bool(x) -> bool:
    """A CSV round trip turns booleans into strings."""
    return x is True or (isinstance(x, str) and x.strip().lower() == "true") or (isinstance(x, (int, np.integer))
                                                                             and not isinstance(x, bool) and x == 1)
