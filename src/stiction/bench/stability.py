"""Where each method breaks: stability maps (``stiction bench stability``).

Each map sweeps two parameters of one scene family and runs every method at every point; a cell's
colour is the *first* failure mode that our own measures find, in this order (FAILURE_MODES):

1. ``non-finite`` (X): NaN/inf, or the simulator stopped the run as a blow-up;
2. ``time-limit``: the case did not finish within TIME_LIMIT seconds of wall time;
3. ``own-solver-failed``: the formulation missed its own stopping test on some step (or refused
   the problem);
4. ``residual``: the exact-law residual (natural map of eq. 65 / (1 + ||b||)) above 1e-6;
5. ``penetration``: deeper than max(1 mm, 1 % of the body's size);
6. ``energy-gain``: kinetic + potential energy rose by more than 1 % of its initial value (every
   scene here is passive);
7. ``stiction-violated``: where the exact law sticks, a drift above 10 µm per 2 s;
8. ``sliding-wrong``: where it slides, acceleration off by more than 1 % or direction by more than 1°;
9. ``structure-lost``: a body tilts by more than 5° or a stacked body leaves the one below.

Every mode that fired is kept in ``failures`` (the colour shows only the first).

Maps (x × y):

- ``stack-rest``: mass ratio m_top/m_bottom (bottom 1 kg) × dt on the two-cube stack (μ 0.5), at
  rest: both cubes must stick;
- ``stack-slide``: the same stack launched at 0.5 m/s along x, μ 0.2 on the ground and 0.5 between
  the cubes: both decelerate at 0.2 g, the top one sticks on the bottom one (a margin of 2.5 in
  friction; and a · h_com < g · half width, so the stack does not tip, whatever the ratio);
- ``incline``: slope angle × μ for the cube on an incline; the true boundary tan θ = μ: below it
  the cube sticks, above it slides at g (sin θ − μ cos θ) (eq. 65's two regimes);
- ``tower``: contacts (a tower of n cubes, 4n contacts) × solver tolerance, at rest;
- ``pile``: contacts × solver tolerance on a pile (:func:`pile_scene`: layers of n, n−1, ..., 1
  cubes, each upper cube bridging two below; 12, 24, 40, 60 contacts), at rest. The package has no
  pile scene file (the array layouts are grid and tower): the bench builds it from a tower's bodies;
- ``penalty``: K × dt for the penalty formulation (eq. 83-84) on the cube at rest on a 30° slope
  (μ 0.6). The explicit limit drawn is symplectic Euler's on the stiffest contact mode: with
  springs K and dampers K β on every contact row, the modes of M⁻¹ K Jᵀ J are ω² = K λ(A)
  (A = J M⁻¹ Jᵀ, eq. 22) with damping β ω², and the scheme on ẍ + β ω² ẋ + ω² x = 0 is stable
  while h² ω² + 2 h β ω² < 4, i.e. h < −β + sqrt(β² + 4 / (K λ_max(A))) (for β = 0 and one
  spring on a point mass: 2 sqrt(m/K)). The formulation itself is implicit (Kikuuwe–Fujimoto),
  so the line shows where an explicit penalty would stop, not where this one must;
- ``ode``: δ × ζ for the relaxed ODE (eq. 64, mode rk4) on the sliding cube (cube-slide, v0 = 1
  m/s, μ 0.5): dt = min(1 ms, half the largest stable RK4 step), so what fails is the relaxation,
  not RK4. The relaxation term −(2ζ/δ) J v of b (eq. 27) acts on the tangential rows too: the
  relaxed law "sticks" (a_t = −(2ζ/δ) v_t, an exponential decay) while friction can supply it,
  i.e. below the speed μ g δ / (2ζ). The line drawn is μ g δ / (2ζ) = v0: under it the cube never
  slides; above it, the deceleration is wrong over the part of the run slower than that speed.

Rows (FIELDS, the CSV's columns): ``map, method, x, y, failure`` (the issue's schema: failure None
or the first mode's name), then ``failures`` (every mode, "|"-separated), ``x_name, y_name, scene,
dt, tolerance, steps``, the measures ``residual`` (largest exact-law residual of a step),
``penetration`` (m), ``energy_gain`` (relative), ``drift`` and ``drift_limit`` (m, where the exact
law sticks), ``accel_error`` (relative) and ``direction_error_deg`` (where it slides), ``tilt_deg``,
``unconverged_steps`` (the formulation's own test missed), ``boundary`` (incline: tan θ, to compare
with μ; penalty: the explicit dt limit at that K; ode: the largest dt the simulator accepts for RK4,
``_core.rk4_stable_step``), ``seconds`` (wall time of the case) and ``error`` (why a run stopped).
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

NAME = "stability"
HELP = ("stability maps: where each method fails (mass ratio x dt, mu x slope, contacts x tolerance on towers "
        "and piles, K x dt, delta x zeta)")
FIELDS = ("map", "method", "x", "y", "failure", "failures", "x_name", "y_name", "scene", "dt", "tolerance",
          "steps", "residual", "penetration", "energy_gain", "drift", "drift_limit", "accel_error",
          "direction_error_deg", "tilt_deg", "unconverged_steps", "boundary", "seconds", "error")
KEY_FIELDS = ("map", "method", "x", "y")
DEFAULT_WORKERS = None

FAILURE_MODES = ("non-finite", "time-limit", "own-solver-failed", "residual", "penetration", "energy-gain",
                 "stiction-violated", "sliding-wrong", "structure-lost")
MAPS = ("stack-rest", "stack-slide", "incline", "tower", "pile", "penalty", "ode")
METHODS = ("exact", "ccp", "nakaoka", "pyramid", "penalty", "pinocchio-admm", "pinocchio-pgs")
QUICK_METHODS = ("exact", "ccp", "penalty")

RESIDUAL_LIMIT = 1e-6
PENETRATION_LIMIT = 1e-3  # m, or 1 % of the body's size if larger
ENERGY_GAIN_LIMIT = 0.01
DRIFT_RATE_LIMIT = 10e-6 / 2.0  # m/s: 10 µm per 2 s
ACCEL_LIMIT = 0.01
DIRECTION_LIMIT_DEG = 1.0
TILT_LIMIT_DEG = 5.0
TIME_LIMIT = 120.0  # s of wall time per case
SOLVER_TOLERANCE = 1e-8  # per-step tolerance (100x below the residual limit) except on the tower map
PENALTY_BETA = 1e-3  # s: the penalty formulation's default damping time

STACK_MU, STACK_SLIDE_MU, STACK_V0 = 0.5, 0.2, 0.5
CUBE = 0.1  # m: the cubes' side
G = 9.81

# (x values, y values) per map: full and --quick (two points per axis)
GRIDS = {
    "stack-rest": ([1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6], [1e-4, 3e-4, 1e-3, 3e-3, 1e-2]),
    "stack-slide": ([1.0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6], [1e-4, 3e-4, 1e-3, 3e-3, 1e-2]),
    "incline": ([10.0, 20.0, 25.0, 28.0, 32.0, 35.0, 40.0], [0.2, 0.4, 0.5, 0.6, 0.7, 0.8, 1.0]),
    "tower": ([8.0, 16.0, 32.0, 64.0], [1e-4, 1e-6, 1e-8, 1e-10]),
    "pile": ([12.0, 24.0, 40.0, 60.0], [1e-4, 1e-6, 1e-8, 1e-10]),
    "penalty": ([1e3, 1e4, 1e5, 1e6, 1e7], [1e-4, 3e-4, 1e-3, 3e-3, 1e-2]),
    "ode": ([1e-4, 1e-3, 1e-2, 3e-2, 1e-1], [0.1, 0.3, 1.0, 3.0, 10.0]),
}
QUICK_GRIDS = {
    "stack-rest": ([1.0, 1e6], [1e-3, 1e-2]),
    "stack-slide": ([1.0, 1e6], [1e-3, 1e-2]),
    "incline": ([20.0, 35.0], [0.5, 0.6]),
    "tower": ([8.0, 32.0], [1e-4, 1e-8]),
    "pile": ([12.0, 24.0], [1e-4, 1e-8]),
    "penalty": ([1e4, 1e6], [1e-3, 1e-2]),
    "ode": ([1e-3, 1e-1], [0.1, 1.0]),
}
AXES = {  # (x name, y name, x log?, y log?)
    "stack-rest": ("mass ratio m_top/m_bottom", "dt (s)", True, True),
    "stack-slide": ("mass ratio m_top/m_bottom", "dt (s)", True, True),
    "incline": ("slope angle (deg)", "mu", False, False),
    "tower": ("contacts (tower of contacts/4 cubes)", "solver tolerance", True, True),
    "pile": ("contacts (pile: layers of n, n-1, ..., 1 cubes)", "solver tolerance", True, True),
    "penalty": ("penalty stiffness K (N/m)", "dt (s)", True, True),
    "ode": ("delta (s)", "zeta", True, True),
}
ODE_V0, ODE_MU = 1.0, 0.5  # cube-slide's launch speed and friction (checked against the scene in _setup)
DURATION = {"stack-rest": 2.0, "stack-slide": 0.4, "incline": 2.0, "tower": 0.5, "pile": 0.5, "penalty": 2.0,
            "ode": 0.4}
PILE_SPACING = 0.15  # m between neighbouring centres in a layer: a 5 cm gap; each upper cube spans two


def add_arguments(parser) -> None:
    parser.add_argument("--maps", default=",".join(MAPS),
                        help=f"comma-separated maps (default: all): {', '.join(MAPS)}")
    parser.add_argument("--methods", default=None,
                        help=f"comma-separated formulations (default: {', '.join(METHODS)}; "
                             f"--quick: {', '.join(QUICK_METHODS)})")


def _split(text, known, what):
    items = [s.strip() for s in str(text).split(",") if s.strip()]
    if not items:
        raise ValueError(f"--{what}: empty list (name at least one of {', '.join(known)})")
    for s in items:
        if s not in known:
            raise ValueError(f"--{what}: unknown {what[:-1]} {s!r} (known: {', '.join(known)})")
    return items


def cases(args) -> list[dict]:
    """Every (map, method, x, y); deterministic (no randomness: the scenes are fixed)."""
    quick = bool(getattr(args, "quick", False))
    maps_arg, methods_arg = getattr(args, "maps", None), getattr(args, "methods", None)
    # an option given empty is an error naming it, never the default
    maps = _split(maps_arg, MAPS, "maps") if maps_arg is not None else list(MAPS)
    methods = _split(methods_arg, METHODS, "methods") if methods_arg is not None else \
        list(QUICK_METHODS if quick else METHODS)
    grids = QUICK_GRIDS if quick else GRIDS
    out = []
    for m in maps:
        if m == "penalty":
            ms = ["penalty"]
        elif m == "ode":
            ms = ["exact-rk4"]
        else:
            ms = methods
        xs, ys = grids[m]
        for method in ms:
            for x in xs:
                for y in ys:
                    out.append({"map": m, "method": method, "x": float(x), "y": float(y)})
    return out


# ---- scenes -------------------------------------------------------------------------------------

def stack_scene(ratio: float, slide: bool):
    """The two-cube stack (mu = STACK_MU) with the top cube `ratio` times heavier (inertia scaled
    alike). slide: both cubes launched at STACK_V0 along x and the ground's friction lowered to
    STACK_SLIDE_MU, so the top one must stick while the stack slides (a margin, not the limit:
    at mu 0.5 on the ground a stack decelerating at 0.5 g sits exactly at its tipping limit)."""
    import pinocchio as pin

    from ..scene import build_scene

    if not (ratio > 0 and math.isfinite(ratio)):
        raise ValueError(f"mass ratio must be a finite number > 0, got {ratio!r}")
    sc = build_scene({"name": f"two-cube-stack-ratio-{ratio:g}", "bodies": ["cube.urdf", "cube.urdf"],
                      "ground": {"mu": STACK_MU}})
    top = sc.model.inertias[2]
    sc.model.inertias[2] = pin.Inertia(top.mass * ratio, top.lever, top.inertia * ratio)
    v0 = sc.v0.copy()
    if slide:
        v0[0] = v0[6] = STACK_V0
        for c in sc.contacts:
            if c.halfspace == 0:
                c.mu = STACK_SLIDE_MU
    return dataclasses.replace(sc, v0=v0)


def incline_scene(slope_deg: float, mu: float):
    from ..scene import build_scene

    return build_scene({"name": f"cube-incline-{slope_deg:g}deg-mu{mu:g}", "urdf": "cube.urdf",
                        "ground": {"slope_deg": slope_deg, "mu": mu}, "contacts": {"box_corners": True}})


def tower_scene(contacts: int):
    from ..scene import build_scene

    if contacts < 4 or contacts % 4:
        raise ValueError(f"tower contacts must be a positive multiple of 4 (4 corners per cube), got {contacts}")
    return build_scene({"name": f"box-tower-{contacts // 4}", "array": {"layout": "tower", "count": contacts // 4},
                        "ground": {"mu": 0.5}})


def pile_scene(contacts: int):
    """A pile: layers of n, n-1, ..., 1 cubes in the x-z plane, neighbours PILE_SPACING apart, each
    upper cube resting on the two below it (two corners on each one's top face), n >= 2. Returns
    (scene, cubes per layer). 4 contacts per cube: n(n+1)/2 cubes, 2n(n+1) contacts (12, 24, 40, 60).
    Every contact face is horizontal, so the pile stands without friction; what it adds to a tower
    is contacts that couple three bodies (each upper cube bridges two)."""
    from ..scene import _corners, _halfspace, _sphere, build_scene

    n = next((k for k in range(2, 40) if 2 * k * (k + 1) == contacts), None)
    if n is None:
        raise ValueError(f"pile contacts must be 2 n (n + 1) for n >= 2 layers (12, 24, 40, 60, ...), "
                         f"got {contacts}")
    layers = [n - layer for layer in range(n)]
    base = build_scene({"name": f"pile-{n}-layers", "array": {"layout": "tower", "count": sum(layers)},
                        "ground": {"mu": 0.5}})
    frames = [c.frame for c in base.contacts[::4]]  # each cube's body frame, in order
    half = np.array([CUBE / 2] * 3)
    halfspaces, contacts_out, q0 = [_halfspace("ground", (0, 0, 1), 0.0)], [], []
    top_of: dict[int, int] = {}
    k = 0
    index: list[list[int]] = []  # index[layer][i] = cube number
    for layer, count in enumerate(layers):
        index.append([])
        for i in range(count):
            x = (i - (count - 1) / 2) * PILE_SPACING
            q0.append([x, 0.0, (2 * layer + 1) * half[2], 0.0, 0.0, 0.0, 1.0])
            for c, corner in enumerate(_corners(half, z_sign=-1)):
                if layer == 0:
                    target = 0
                else:
                    below = index[layer - 1][i + (1 if corner[0] > 0 else 0)]
                    if below not in top_of:
                        halfspaces.append(_halfspace(f"top of body{below}", (0, 0, 1), float(half[2]),
                                                     frames[below]))
                        top_of[below] = len(halfspaces) - 1
                    target = top_of[below]
                contacts_out.append(_sphere(f"body{k}-corner{c}", frames[k], corner, 0.0, target, 0.5))
            index[layer].append(k)
            k += 1
    return dataclasses.replace(base, name=f"pile-{n}-layers", q0=np.concatenate(q0), halfspaces=halfspaces,
                               contacts=contacts_out), layers


def penalty_explicit_limit(stiffness, lambda_max: float, beta: float = PENALTY_BETA):
    """Largest dt symplectic (explicit) Euler is stable for springs K, dampers K beta on every row:
    h < -beta + sqrt(beta^2 + 4 / (K lambda_max(A))) (derived in the module docstring; eq. 83-84)."""
    k = np.asarray(stiffness, dtype=float)
    return -beta + np.sqrt(beta ** 2 + 4.0 / (k * lambda_max))


def delassus_lambda_max(scene) -> float:
    """Largest eigenvalue of A = J M^-1 J^T (eq. 22) at the scene's first step."""
    from ..simulator import Simulator

    sim = Simulator(scene)
    sim.step()
    return float(np.linalg.eigvalsh(np.asarray(sim.data.A)).max())


# ---- one case -------------------------------------------------------------------------------------

def _setup(case: dict):
    """(scene, overrides, checks) for one case; checks says what the exact law does there."""
    from .. import _core
    from ..scene import load_scene

    m, method, x, y = case["map"], case["method"], case["x"], case["y"]
    ov: dict[str, Any] = {"duration": DURATION[m]}
    if method not in ("exact-rk4",):
        ov["formulation"] = method
    checks: dict[str, Any] = {"anchored": False, "stick": [], "stick_relative": None, "slide": None,
                              "stacked": False, "boundary": None}
    if m in ("stack-rest", "stack-slide"):
        scene = stack_scene(x, m == "stack-slide")
        ov.update(dt=y, tolerance=SOLVER_TOLERANCE)
        checks["stacked"] = True
        if m == "stack-rest":
            checks["stick"] = [0, 1]
        else:
            checks["stick_relative"] = (0, 1)
            checks["slide"] = {"bodies": [0, 1], "accel": np.array([-STACK_SLIDE_MU * G, 0.0, 0.0]), "v0": STACK_V0}
    elif m == "incline":
        scene = incline_scene(x, y)
        ov.update(dt=1e-3, tolerance=SOLVER_TOLERANCE)
        th = math.radians(x)
        checks["boundary"] = math.tan(th)
        if math.tan(th) < y:
            checks["stick"] = [0]
        else:
            checks["slide"] = {"bodies": [0], "accel": np.array([G * (math.sin(th) - y * math.cos(th)), 0.0, 0.0]),
                               "v0": 0.0}
    elif m == "pile":
        scene, layers = pile_scene(int(round(x)))
        ov.update(dt=1e-3, tolerance=y)
        checks["stick"] = list(range(sum(layers)))
        checks["anchored"] = True
    elif m == "tower":
        scene = tower_scene(int(round(x)))
        ov.update(dt=1e-3, tolerance=y)
        checks["stick"] = list(range(int(round(x)) // 4))
        checks["stacked"] = True
    elif m == "penalty":
        scene = load_scene("cube-incline-stick")
        ov.update(dt=y, tolerance=SOLVER_TOLERANCE, penalty_stiffness=x)
        checks["stick"] = [0]
        checks["boundary"] = float(penalty_explicit_limit(x, delassus_lambda_max(scene)))
    elif m == "ode":
        scene = load_scene("cube-slide")
        limit = float(_core.rk4_stable_step(x, y))
        ov.update(mode="rk4", delta=x, zeta=y, dt=min(1e-3, 0.5 * limit), tolerance=SOLVER_TOLERANCE)
        checks["boundary"] = limit
        v0 = float(scene.v0[0])
        if (v0, scene.mu) != (ODE_V0, ODE_MU):
            raise RuntimeError(f"cube-slide changed (v0 {v0}, mu {scene.mu}): update ODE_V0, ODE_MU")
        checks["slide"] = {"bodies": [0], "accel": np.array([-scene.mu * G, 0.0, 0.0]), "v0": v0}
    else:
        raise ValueError(f"unknown map {m!r} (known: {', '.join(MAPS)})")
    return scene, ov, checks


def _free_bodies(model):
    """(idx_q, idx_v, mass, lever, inertia about the centre of mass) of every free-flyer joint."""
    out = []
    for j in range(1, model.njoints):
        if model.joints[j].shortname() == "JointModelFreeFlyer":
            I = model.inertias[j]
            out.append((model.joints[j].idx_q, model.joints[j].idx_v, float(I.mass), np.array(I.lever),
                        np.array(I.inertia)))
    return out


def _rotations(quat: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotation matrices of (N, 4) quaternions (x, y, z, w), normalised."""
    q = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    x, y, z, w = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], 1)


def energy_gain(energy) -> float:
    """The largest rise of the total energy (kinetic + potential) over its initial value, relative
    to ``abs(E0)`` (absolute when E0 = 0): the energy-gain mode fires above ENERGY_GAIN_LIMIT."""
    energy = np.asarray(energy, dtype=float)
    e0 = energy[0]
    return float((energy.max() - e0) / abs(e0)) if e0 != 0 else float(energy.max() - e0)


def drift_limit(duration: float) -> float:
    """The stiction-violated threshold over a run of `duration` s: DRIFT_RATE_LIMIT (10 µm per 2 s)."""
    return DRIFT_RATE_LIMIT * duration


def direction_error_deg(displacement, expected) -> float:
    """Angle (degrees) between a body's horizontal displacement (x, y; z dropped) and the
    direction it should slide; 180 when it did not move horizontally."""
    horiz = np.array([displacement[0], displacement[1], 0.0], dtype=float)
    nrm = np.linalg.norm(horiz)
    if not nrm > 0:
        return 180.0
    unit = np.asarray(expected, dtype=float) / np.linalg.norm(expected)
    return float(np.degrees(np.arccos(np.clip(horiz @ unit / nrm, -1.0, 1.0))))


def measures(scene, traj, checks: dict, duration: float) -> dict:
    """Every measured quantity the failure modes need, from a finished trajectory."""
    gravity = np.array(scene.model.gravity.linear)
    bodies = _free_bodies(scene.model)
    t = traj.t
    energy = np.zeros(len(t))
    pos, vel, rot = [], [], []
    for iq, iv, mass, c, inertia in bodies:
        R = _rotations(traj.q[:, iq + 3:iq + 7])
        p = traj.q[:, iq:iq + 3]
        v_lin, w = traj.v[:, iv:iv + 3], traj.v[:, iv + 3:iv + 6]  # local frame
        v_com_local = v_lin + np.cross(w, c)
        energy += 0.5 * mass * np.einsum("ni,ni->n", v_com_local, v_com_local)
        energy += 0.5 * np.einsum("ni,ij,nj->n", w, inertia, w)
        com = p + np.einsum("nij,j->ni", R, c)
        energy -= mass * com @ gravity
        pos.append(com)
        vel.append(np.einsum("nij,nj->ni", R, v_com_local))  # world-frame velocity of the centre of mass
        rot.append(R)
    out: dict[str, Any] = {"energy_gain": energy_gain(energy)}
    # tilt: the largest rotation of any body away from its initial orientation
    tilt = 0.0
    for R in rot:
        rel = np.einsum("ji,njk->nik", R[0], R)
        cosang = np.clip((np.trace(rel, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
        tilt = max(tilt, float(np.degrees(np.arccos(cosang)).max()))
    out["tilt_deg"] = tilt
    fell = False
    if checks["stacked"]:
        for k in range(1, len(pos)):
            offset = np.linalg.norm((pos[k] - pos[k - 1])[:, :2], axis=1).max()
            fell = fell or offset > CUBE / 2
    if checks.get("anchored"):  # a pile: no body may move by half its width
        for p in pos:
            fell = fell or np.linalg.norm((p - p[0])[:, :2], axis=1).max() > CUBE / 2
    out["fell"] = fell
    # stiction: the tangential drift (x, y: the ground's plane) of the bodies, or of one relative to
    # another, that the exact law holds (normal motion is penetration's business)
    drift = None
    for b in checks["stick"]:
        d = float(np.linalg.norm((pos[b] - pos[b][0])[:, :2], axis=1).max())
        drift = d if drift is None else max(drift, d)
    if checks["stick_relative"] is not None:
        a, b = checks["stick_relative"]
        rel = (pos[b] - pos[a])[:, :2]
        drift = float(np.linalg.norm(rel - rel[0], axis=1).max())
    out["drift"] = drift
    out["drift_limit"] = drift_limit(duration) if drift is not None else None
    # sliding: acceleration (least squares over the sliding interval) and direction of the motion
    accel_err: float | None = None
    direction: float | None = None
    s = checks["slide"]
    if s is not None:
        a_exp = s["accel"]
        n_exp = a_exp / np.linalg.norm(a_exp)
        errs, dirs = [], []
        for b in s["bodies"]:
            v = vel[b]
            if s["v0"] > 0:  # decelerating from v0: the records while 0.2 v0 < speed < 0.9 v0
                speed = v @ (-n_exp)
                window = (speed > 0.2 * s["v0"]) & (speed < 0.9 * s["v0"])
            else:  # accelerating from rest: after the first 20 % of the run
                window = t >= 0.2 * duration
            idx = np.flatnonzero(window)
            if len(idx) < 2:
                idx = np.arange(min(len(t), 2))
            if len(idx) >= 3:
                a_meas = np.array([np.polyfit(t[idx], v[idx, k], 1)[0] for k in range(3)])
            else:
                a_meas = (v[idx[-1]] - v[idx[0]]) / max(t[idx[-1]] - t[idx[0]], 1e-300)
            errs.append(float(np.linalg.norm(a_meas - a_exp) / np.linalg.norm(a_exp)))
            along = np.sign(a_exp[0]) if s["v0"] == 0 else -np.sign(a_exp[0])  # the direction it should move
            dirs.append(direction_error_deg(pos[b][-1] - pos[b][0], np.array([along, 0.0, 0.0])))
        accel_err, direction = max(errs), max(dirs)
    out["accel_error"], out["direction_error_deg"] = accel_err, direction
    return out


def classify(row: dict) -> list[str]:
    """Every failure mode a row shows, in FAILURE_MODES order (the first is the cell's colour)."""
    fails = []
    if row["error"] is not None and row.get("_kind") == "non-finite":
        fails.append("non-finite")
    if row.get("_kind") == "time-limit":
        fails.append("time-limit")
    if row.get("_kind") == "refused" or (row["unconverged_steps"] or 0) > 0:
        fails.append("own-solver-failed")
    if row.get("_kind") in ("non-finite", "time-limit", "refused"):
        return fails
    if row["residual"] is None or not row["residual"] <= RESIDUAL_LIMIT:
        fails.append("residual")
    if row["penetration"] > max(PENETRATION_LIMIT, 0.01 * CUBE):
        fails.append("penetration")
    if row["energy_gain"] > ENERGY_GAIN_LIMIT:
        fails.append("energy-gain")
    if row["drift"] is not None and row["drift"] > row["drift_limit"]:
        fails.append("stiction-violated")
    if row["accel_error"] is not None and (row["accel_error"] > ACCEL_LIMIT
                                           or row["direction_error_deg"] > DIRECTION_LIMIT_DEG):
        fails.append("sliding-wrong")
    if row["tilt_deg"] > TILT_LIMIT_DEG or row.get("_fell"):
        fails.append("structure-lost")
    return fails


def evaluate(case: dict) -> dict:
    """One case: build, roll out in chunks (so the time limit holds), measure, classify. Never
    raises for a failing method: a blow-up, a refusal or a timeout is a failure mode."""
    from ..simulator import Simulator

    t_start = time.perf_counter()
    m = case["map"]
    scene, ov, checks = _setup(case)
    x_name, y_name = AXES[m][:2]
    row: dict[str, Any] = {
           "map": m, "method": case["method"], "x": case["x"], "y": case["y"], "failure": None, "failures": "",
           "x_name": x_name, "y_name": y_name, "scene": scene.name, "dt": ov.get("dt"),
           "tolerance": ov.get("tolerance"), "steps": 0, "residual": None, "penetration": None,
           "energy_gain": None, "drift": None, "drift_limit": None, "accel_error": None,
           "direction_error_deg": None, "tilt_deg": None, "unconverged_steps": None,
           "boundary": checks["boundary"], "seconds": None, "error": None}
    duration = ov["duration"]
    kind = None
    try:
        sim = Simulator(scene, **ov)
    except (ValueError, RuntimeError) as exc:
        sim, kind, row["error"] = None, "refused", str(exc).splitlines()[0][:300]
    trajs = []
    if sim is not None:
        total = int(round(duration / sim.dt))
        chunk = max(1, total // 10)
        done = 0
        while done < total:
            n = min(chunk, total - done)
            try:
                tr = sim.rollout(n * sim.dt)
            except (RuntimeError, ValueError) as exc:
                kind, row["error"] = "non-finite", str(exc).splitlines()[0][:300]
                break
            trajs.append(tr)
            done += n
            if time.perf_counter() - t_start > TIME_LIMIT and done < total:
                kind, row["error"] = "time-limit", f"stopped after {done} of {total} steps ({TIME_LIMIT:g} s)"
                break
    if trajs:
        t0 = trajs[0]
        cat: dict[str, Any] = {k: np.concatenate([getattr(t0, k)] + [getattr(t, k)[1:] for t in trajs[1:]])
               for k in ("t", "q", "v", "gaps", "residual", "converged")}
        traj = dataclasses.replace(t0, **{k: cat[k] for k in cat})
        row["steps"] = int(len(traj.t) - 1)
        finite = np.isfinite(traj.q).all() and np.isfinite(traj.v).all()
        if not finite and kind is None:
            kind, row["error"] = "non-finite", "NaN or inf in the state"
        row["unconverged_steps"] = int((~traj.converged[1:]).sum())
        res = traj.residual[1:]
        row["residual"] = float(np.nanmax(res)) if np.isfinite(res).any() else None
        gaps = traj.gaps[np.isfinite(traj.gaps)]
        row["penetration"] = float(max(0.0, -gaps.min())) if gaps.size else 0.0
        if finite:
            meas = measures(scene, traj, checks, float(traj.t[-1] - traj.t[0]))
            row["_fell"] = meas.pop("fell")
            row.update(meas)
    elif kind is None:
        kind, row["error"] = "non-finite", "no step completed"
    row["_kind"] = kind
    fails = classify(row)
    row.pop("_kind")
    row.pop("_fell", None)
    row["failures"] = "|".join(fails)
    row["failure"] = fails[0] if fails else None
    row["seconds"] = time.perf_counter() - t_start
    return row


# ---- summary and charts -----------------------------------------------------------------------------

def summarize(rows: list[dict]) -> dict:
    """Per map and method: cells, failed cells and the count of each first failure mode."""
    out: dict = {}
    for r in rows:
        d = out.setdefault(r["map"], {}).setdefault(r["method"], {"cells": 0, "failed": 0, "modes": {}})
        d["cells"] += 1
        if r["failure"]:
            d["failed"] += 1
            d["modes"][r["failure"]] = d["modes"].get(r["failure"], 0) + 1
    return {"failure_modes": list(FAILURE_MODES), "maps": out}


COLORS = {None: "#b8e0b0", "non-finite": "#000000", "time-limit": "#7f7f7f", "own-solver-failed": "#9467bd",
          "residual": "#d62728", "penetration": "#8c564b", "energy-gain": "#ff7f0e",
          "stiction-violated": "#1f77b4", "sliding-wrong": "#e377c2", "structure-lost": "#bcbd22"}
SHORT = {"non-finite": "X", "time-limit": "T", "own-solver-failed": "O", "residual": "R", "penetration": "P",
         "energy-gain": "E", "stiction-violated": "S", "sliding-wrong": "W", "structure-lost": "L"}


def _edges(values, log):
    v = np.asarray(sorted(values), dtype=float)
    if len(v) == 1:
        return (np.array([v[0] / 2, v[0] * 2]) if log else np.array([v[0] - 0.5, v[0] + 0.5]))
    t = np.log(v) if log else v
    mid = (t[1:] + t[:-1]) / 2
    e = np.concatenate([[t[0] - (mid[0] - t[0])], mid, [t[-1] + (t[-1] - mid[-1])]])
    return np.exp(e) if log else e


def _boundary(ax, m, xs, ys, rows):
    """The true (or reference) boundary of a map, drawn in data coordinates."""
    if m == "incline":
        th = np.linspace(min(xs) - 3, max(xs) + 3, 200)
        ax.plot(th, np.tan(np.radians(th)), "k--", lw=1.2, label="tan θ = μ")
    elif m == "penalty":
        from ..scene import load_scene

        lam = delassus_lambda_max(load_scene("cube-incline-stick"))
        k = np.geomspace(min(xs) / 3, max(xs) * 3, 200)
        ax.plot(k, penalty_explicit_limit(k, lam), "k--", lw=1.2, label="explicit limit")
    elif m == "ode":
        d = np.geomspace(min(xs) / 3, max(xs) * 3, 200)
        v0 = ODE_V0
        ax.plot(d, ODE_MU * G * d / (2.0 * v0), "k--", lw=1.2, label="μgδ/(2ζ) = v0")


def plot(rows: list[dict], out_dir: Path, stamp: dict) -> list[Path]:
    """One figure per map: a heat-map panel per method, colour = first failure mode, letters = every
    mode that fired; the true boundaries drawn; the stamp on every figure."""
    from .._optional import require

    require("matplotlib", "plot", "the stability maps")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch
    from matplotlib.ticker import FixedFormatter, FixedLocator, NullLocator

    from .sweep import stamp_figure

    out_dir = Path(out_dir)
    files = []
    order = [None, *FAILURE_MODES]
    cmap = ListedColormap([COLORS[k] for k in order])
    for m in MAPS:
        mrows = [r for r in rows if r["map"] == m]
        if not mrows:
            continue
        methods = list(dict.fromkeys(r["method"] for r in mrows))
        xs = sorted({r["x"] for r in mrows})
        ys = sorted({r["y"] for r in mrows})
        xlabel, ylabel, xlog, ylog = AXES[m]
        ncol = min(4, len(methods))
        nrow = math.ceil(len(methods) / ncol)
        fig, axes = plt.subplots(nrow, ncol, figsize=(max(9.0, 3.3 * ncol + 0.5), 3.0 * nrow + 1.7), squeeze=False)
        xe, ye = _edges(xs, xlog), _edges(ys, ylog)
        for k, method in enumerate(methods):
            ax = axes[k // ncol][k % ncol]
            prow = [r for r in mrows if r["method"] == method]
            fails = {id(r): [f for f in (r["failures"] or "").split("|") if f] for r in prow}
            # a mode that fires in every cell says nothing about the map's axes: it is named in the
            # title and a cell's colour is its first *other* mode, if any (the letters show them all)
            everywhere = [f for f in FAILURE_MODES if all(f in fl for fl in fails.values())]
            everywhere = everywhere if any(set(fl) - set(everywhere) for fl in fails.values()) else []
            grid = np.full((len(ys), len(xs)), np.nan)
            for r in prow:
                i, j = ys.index(r["y"]), xs.index(r["x"])
                shown = [f for f in fails[id(r)] if f not in everywhere] or fails[id(r)]
                first = shown[0] if shown else None
                grid[i, j] = order.index(first)
                codes = "".join(SHORT[f] for f in fails[id(r)])
                ax.text(np.sqrt(xe[j] * xe[j + 1]) if xlog else (xe[j] + xe[j + 1]) / 2,
                        np.sqrt(ye[i] * ye[i + 1]) if ylog else (ye[i] + ye[i + 1]) / 2,
                        codes, ha="center", va="center", fontsize=6,
                        color="white" if first in ("non-finite", "residual", "own-solver-failed") else "black")
            ax.pcolormesh(xe, ye, np.ma.masked_invalid(grid), cmap=cmap, vmin=-0.5, vmax=len(order) - 0.5,
                          edgecolors="white", linewidth=0.5)
            _boundary(ax, m, xs, ys, mrows)
            if xlog:
                ax.set_xscale("log")
            if ylog:
                ax.set_yscale("log")
            ax.set_xlim(xe[0], xe[-1])
            ax.set_ylim(ye[0], ye[-1])
            # ticks at the grid's values (log axes of powers of 2 or 3 would otherwise be unlabelled)
            ax.xaxis.set_major_locator(FixedLocator(xs))
            ax.xaxis.set_minor_locator(NullLocator())
            ax.xaxis.set_major_formatter(FixedFormatter([f"{v:g}" for v in xs]))
            ax.yaxis.set_major_locator(FixedLocator(ys))
            ax.yaxis.set_minor_locator(NullLocator())
            ax.yaxis.set_major_formatter(FixedFormatter([f"{v:g}" for v in ys]))
            ax.set_title(method + (f"  (every cell: {', '.join(everywhere)})" if everywhere else ""), fontsize=8)
            ax.set_xlabel(xlabel, fontsize=7)
            ax.set_ylabel(ylabel, fontsize=7)
            ax.tick_params(labelsize=6)
            ax.tick_params(axis="x", labelrotation=45 if len(xs) > 5 else 0)
            if ax.get_legend_handles_labels()[0]:
                ax.legend(fontsize=6, loc="upper left")
        for k in range(len(methods), nrow * ncol):
            axes[k // ncol][k % ncol].axis("off")
        handles = [Patch(color=COLORS[k], label=("passes" if k is None else f"{k} ({SHORT[k]})")) for k in order]
        fig.suptitle(f"stability map: {m} (colour = first failure mode; letters = every mode that fired)",
                     fontsize=9, y=0.995)
        fig.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, 0.965), ncol=5, fontsize=7,
                   frameon=False)
        h = fig.get_figheight()
        fig.subplots_adjust(left=0.07, right=0.98, top=1.0 - 0.95 / h, bottom=0.75 / h, wspace=0.3,
                            hspace=0.75 / 3.0 * 1.6)
        stamp_figure(fig, stamp)
        path = out_dir / f"stability-{m}.png"
        fig.savefig(path, dpi=130)
        plt.close(fig)
        files.append(path)
    return files
