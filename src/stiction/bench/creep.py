r"""Zero creep: how far a body that friction must hold slips, against the friction margin
(``stiction bench creep``, issue 25).

Three scenes where the exact law (eq. 65: inside the cone, the contact sticks) holds a body
still, each run at friction margins mu / mu_needed (MARGINS: 1.05 ... 4, and one row at 0.8,
below the limit, as a sanity check that the body then does slip):

- ``pinch`` (robots/scenes/pinch.toml): a 1 kg cube held between two finger pads, each finger's
  joint PD (kp = 2000 N/m) commanded 1 cm past the face it touches. The fingers are rigid and the
  pads stay on the faces, so each finger presses with N = kp (q_target - q0) = 20 N, shared by its
  two pads. Gravity m g is carried by the friction of both fingers, 2 mu N at most, so
  mu_needed = m g / (2 kp (q_target - q0)) = 9.81 / 40 = 0.245 (the scene's mu = 0.5 is a margin
  of 2.04). The pads' mu is what the sweep changes (the grip stays 20 N). Slip: the cube's
  displacement relative to the pads in the pads' plane (y, z: the fingers move along x only).
- ``cube-incline-stick``: the cube on a 30 deg ramp; it holds while mu >= tan 30 deg, so
  mu_needed = tan theta = 0.577. Slip: the displacement along the ramp's plane.
- ``solo12-slope-stick``: Solo-12 with its joints locked (a rigid body on four sphere feet) on
  a 15 deg slope: mu_needed = tan 15 deg = 0.268. Slip: the base's drift in the slope's plane.

A slope is tilted gravity in stiction (the ground stays z = 0, downhill is +x) and in its MuJoCo
twins, so "in the plane" is (x, y) there. Every run starts at rest in the scene's initial state
and lasts DURATION (10 s of simulated time; ``--quick``: 1 s) at dt = 1 ms; slip is measured from
t = 0 to the end (what settling into a soft contact moves counts), ``creep_rate`` over the second
half of the run only (the steady creep, to compare with mujoco#3328's 50-155 um/s of grasp creep).

Below the friction limit the exact answer is known: the cube on the ramp slides at
a = g (sin theta - mu cos theta) and symplectic Euler from rest gives s = a h^2 k (k + 1) / 2
= a T^2 / 2 (1 + h / T) after k = T / h steps (tests/test_bench_creep.py checks it).

**Methods**: stiction's formulations (FORMULATIONS; ``stiction formulations``), chosen by the
Simulator's ``formulation`` override at the default solver and tolerance 1e-10, and MuJoCo 4.0
(the optional ``bench`` extra) on the twins of :mod:`stiction.bench.mujoco_twins`
(:func:`~stiction.bench.mujoco_twins.pinch_spec`, ``boxes_spec``, ``solo12_spec`` with its
joints locked by equality constraints) with :func:`~stiction.bench.mujoco_twins.apply_options`
(``implicitfast``, tolerance 1e-10, the scene's dt and gravity) in three settings:
``mujoco-default`` (pyramidal cone, impratio 1: MuJoCo's defaults), ``mujoco-impratio10``
(elliptic cone, impratio 10: MuJoCo's advice against slip) and ``mujoco-noslip`` (10 noslip
iterations). MuJoCo's pads are soft: they sink into the cube, so its grip is kp times 1 cm minus
that depth, below the nominal 20 N the margin is computed with (measured: ``grip``, and
``effective_margin`` = margin x grip / 20 N, the margin MuJoCo's pinch actually has).

**Cost**: ``seconds_per_simulated_second`` = wall time of the rollout (stiction: the C++ loop in
ten chunks; MuJoCo: ``mujoco.rollout``) / simulated time; a failed run counts at the time limit
(the measured value is ``measured_seconds_per_simulated_second``). One case at a time by default
(timings want a core).

**Failure** (``failed``, ``failure``): the simulator refused the scene or stopped (no contact
solution, divergence), a non-finite state, MuJoCo's bad-acceleration warning (it resets the
state), or the time limit (TIME_LIMIT wall s per case). Slip is data, never a failure: the chart
shows it against the goal (exact <= 1e-9 m at every margin > 1).

**Rows** (CSV columns = ``FIELDS``): ``scene``, ``method``, ``margin``, ``slip`` (m, at the end;
None when the run stopped), ``seconds_per_simulated_second``, ``failed``, ``failure``;
``creep_rate`` (m/s over the second half); ``grip`` (pinch only: one finger's normal force in N,
the sum over its pads at t = GRIP_TIME = 0.05 s, when MuJoCo's soft pads have settled and nothing
has fallen yet; stiction's rigid pads hold the nominal kp (q_target - q0)),
``effective_margin`` (pinch: margin x grip / nominal grip; the other scenes: the margin, their
normal force being m g cos theta whatever the contact model); ``mu`` (the coefficient run), ``mu_needed``,
``duration`` (s simulated), ``dt``, ``measured_seconds_per_simulated_second``, ``time_limit``.
"""
from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

NAME = "creep"
HELP = ("zero creep: slip of a held body (pinch grasp, cube on a ramp, Solo-12 on a slope) against the friction "
        "margin, stiction's formulations and MuJoCo")
FIELDS = ("scene", "method", "margin", "slip", "seconds_per_simulated_second", "failed", "failure", "creep_rate",
          "grip", "effective_margin", "mu", "mu_needed", "duration", "dt", "measured_seconds_per_simulated_second",
          "time_limit")
KEY_FIELDS = ("scene", "method", "margin", "duration", "time_limit")
DEFAULT_WORKERS = 1  # wall times: one case at a time

SCENES = ("pinch", "cube-incline-stick", "solo12-slope-stick")
MARGINS = (0.8, 1.05, 1.1, 1.25, 1.5, 2.0, 4.0)  # 0.8: below the limit, the body must slip
QUICK_MARGINS = (0.8, 1.25, 4.0)
FORMULATIONS = ("exact", "ccp", "nakaoka", "pyramid", "penalty", "pinocchio-admm", "pinocchio-pgs",
                "pinocchio-admm-ccp")
MUJOCO_METHODS = {"mujoco-default": "default", "mujoco-impratio10": "impratio10", "mujoco-noslip": "noslip"}
METHODS = tuple(FORMULATIONS) + tuple(MUJOCO_METHODS)
QUICK_METHODS = ("exact", "pyramid", "penalty", *MUJOCO_METHODS)
DURATION, QUICK_DURATION = 10.0, 1.0  # s simulated
DT = 1e-3
TOLERANCE = 1e-10  # stiction's contact solver and MuJoCo's (apply_options)
TIME_LIMIT, QUICK_TIME_LIMIT = 60.0, 20.0  # wall s per case
CHUNKS = 10  # stiction rolls out in chunks: the time limit is checked between them
GRIP_TIME = 0.05  # s: when the pinch's grip is measured (MuJoCo's soft pads have settled, nothing fell yet)


def _grip_step(n: int, dt: float) -> int:
    return max(1, min(n, round(GRIP_TIME / dt)))
GOAL = 1e-9  # m: the exact formulation's slip at every margin > 1


# ---------------------------------------------------------------- scenes and their friction limit
def _g(sc) -> float:
    return float(np.linalg.norm(sc.model.gravity.linear))


def _box_joint(sc) -> int:
    """idx_q of the scene's (first) free body."""
    model = sc.model
    for j in range(1, model.njoints):
        if model.joints[j].shortname() == "JointModelFreeFlyer":
            return model.joints[j].idx_q
    raise ValueError(f"scene {sc.name!r}: no free body")


def pinch_grip(sc) -> float:
    """The grip of one finger of the pinch (N): kp (q_target - q0) on each prismatic finger joint,
    the pads touching the cube at q0 (both fingers equal, checked)."""
    model = sc.model
    grips = []
    for j in range(1, model.njoints):
        jm = model.joints[j]
        if jm.shortname().startswith("JointModelP"):
            grips.append(abs(float(sc.kp[jm.idx_v]) * float(sc.q_target[jm.idx_q] - sc.q0[jm.idx_q])))
    if len(grips) != 2 or not math.isclose(grips[0], grips[1], rel_tol=1e-12) or grips[0] <= 0:
        raise ValueError(f"scene {sc.name!r}: expected two fingers squeezing equally, got grips {grips} N")
    return grips[0]


def mu_needed(name: str, sc) -> float:
    """The smallest mu that holds the body (module doc): tan theta on a slope; m g / (2 N) for the
    pinch (N = one finger's grip, :func:`pinch_grip`; m the cube's mass)."""
    if name == "pinch":
        mass = float(sc.model.inertias[_box_joint_id(sc)].mass)  # (inertias are indexed by joint)
        return mass * _g(sc) / (2.0 * pinch_grip(sc))
    if sc.slope_deg <= 0:
        raise ValueError(f"scene {sc.name!r}: no slope, no friction angle")
    return math.tan(math.radians(sc.slope_deg))


def _box_joint_id(sc) -> int:
    model = sc.model
    return next(j for j in range(1, model.njoints) if model.joints[j].shortname() == "JointModelFreeFlyer")


def scene_at(name: str, margin: float):
    """(scene with every contact's mu = margin * mu_needed, mu, mu_needed)."""
    from ..scene import load_scene  # noqa: PLC0415
    from ..simulator import _with_friction  # noqa: PLC0415

    if name not in SCENES:
        raise ValueError(f"creep: unknown scene {name!r} (known: {', '.join(SCENES)})")
    if not (margin > 0 and math.isfinite(margin)):
        raise ValueError(f"creep: margin must be a finite number > 0, got {margin!r}")
    sc = load_scene(name)
    need = mu_needed(name, sc)
    mu = margin * need
    return _with_friction(sc, mu), mu, need


def _tangential(name: str, d: np.ndarray) -> np.ndarray:
    """The slip part of a displacement (..., 3): the pads' plane (y, z) for the pinch, else the
    ground's plane (x, y)."""
    return d[..., 1:] if name == "pinch" else d[..., :2]


# ---------------------------------------------------------------- one run
def _run_stiction(case: dict, sc) -> dict:
    from ..simulator import Simulator  # noqa: PLC0415

    duration, dt = case["duration"], case["dt"]
    out = {"wall": 0.0, "failure": None, "positions": None, "grip": None}
    try:
        sim = Simulator(sc, dt=dt, tolerance=TOLERANCE, formulation=case["method"])
    except (ValueError, RuntimeError) as exc:
        out["failure"] = "refused: " + str(exc).splitlines()[0][:160]
        return out
    i = _box_joint(sc)
    pads = [k for k, c in enumerate(sc.contacts) if "pad" in c.name] if case["scene"] == "pinch" else []
    n = int(round(duration / dt))
    regular = [round(n * k / CHUNKS) for k in range(CHUNKS + 1)]
    grip_step = _grip_step(n, dt)
    bounds = sorted(set(regular) | ({grip_step} if pads else set()))
    positions = [np.array(sim.data.q[i:i + 3])]
    for a, b in zip(bounds[:-1], bounds[1:]):
        if b == a:
            continue
        t0 = time.perf_counter()
        try:
            tr = sim.rollout((b - a) * dt, record_every=b - a)
        except (RuntimeError, ValueError) as exc:
            out["wall"] += time.perf_counter() - t0
            out["failure"] = "stopped: " + str(exc).splitlines()[0][:160]
            return out
        out["wall"] += time.perf_counter() - t0
        if not (np.isfinite(tr.q).all() and np.isfinite(tr.v).all()):
            out["failure"] = "non-finite"
            return out
        if b in regular:
            positions.append(np.array(tr.q[-1, i:i + 3]))
        if pads and b == grip_step:  # the grip: each finger's pads' normal forces
            out["grip"] = float(np.nansum(tr.lam[-1, pads, 2])) / 2.0
        if out["wall"] > case["time_limit"] and b < n:
            out["failure"] = f"time-limit: stopped after {b} of {n} steps"
            return out
    out["positions"] = np.array(positions)  # at t = 0, T/10, ..., T
    return out


def _mujoco_model(name: str, sc, mu: float, variant: str):
    """(compiled model, initial mjSTATE_INTEGRATION state, the held body's name)."""
    import mujoco  # noqa: PLC0415

    from . import mujoco_twins as ms  # noqa: PLC0415

    if name == "pinch":
        spec, body = ms.pinch_spec(sc, pad_mu=mu), "box0"
    elif name == "cube-incline-stick":
        spec, body = ms.boxes_spec(sc, [(0.0, 0.0, 0.05)], mu), "box0"
    else:
        spec, body = ms.solo12_spec(dataclasses.replace(sc, mu=mu), lock_joints=True), "base_link"
    ms.apply_options(spec, sc, DT, TOLERANCE, variant)
    model = spec.compile()
    data = mujoco.MjData(model)
    if name == "solo12-slope-stick":
        q0 = np.concatenate([sc.q0[:7], ms._solo12_q0()[7:]])  # the locked joints at the robot's q0
        state = ms.solo12_state(model, q0)
    else:
        if name == "pinch":
            data.ctrl[:] = [float(sc.q_target[0]), float(sc.q_target[1])]
        state = ms.state_of(model, data)
    return model, state, body


def _run_mujoco(case: dict, name: str, sc, mu: float) -> dict:
    import mujoco  # noqa: PLC0415

    from . import mujoco_twins as ms  # noqa: PLC0415

    out = {"wall": 0.0, "failure": None, "positions": None, "grip": None}
    model, state0, body = _mujoco_model(name, sc, mu, MUJOCO_METHODS[case["method"]])
    model.opt.timestep = case["dt"]
    n = int(round(case["duration"] / case["dt"]))
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, state0, mujoco.mjtState.mjSTATE_INTEGRATION)
    physics = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.empty(mujoco.mj_stateSize(model, physics))
    mujoco.mj_getState(model, data, initial, physics)
    control = data.ctrl.copy().reshape(1, 1, -1) if model.nu else None
    wall, _, states = ms.rollout(model, data, initial, control, n)
    out["wall"] = wall
    if not np.isfinite(states).all():
        out["failure"] = "non-finite"
        return out
    if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > 0:
        out["failure"] = "stopped: bad acceleration (MuJoCo reset the state)"
        return out
    bid = model.body(body).id
    positions = []
    for k in [round(n * j / CHUNKS) for j in range(CHUNKS + 1)]:
        mujoco.mj_setState(model, data, initial if k == 0 else states[0, k - 1], physics)
        mujoco.mj_kinematics(model, data)
        positions.append(np.array(data.xpos[bid]))
    if name == "pinch":  # the grip: the normal forces of the pads (the finger geoms' contacts)
        mujoco.mj_setState(model, data, states[0, _grip_step(n, case["dt"]) - 1], physics)
        mujoco.mj_forward(model, data)
        fingers = {model.body(f"{side}_finger").id for side in ("left", "right")}
        f6, total = np.zeros(6), 0.0
        for c in range(data.ncon):
            con = data.contact[c]
            if {int(model.geom_bodyid[con.geom1]), int(model.geom_bodyid[con.geom2])} & fingers:
                mujoco.mj_contactForce(model, data, c, f6)
                total += float(f6[0])
        out["grip"] = total / 2.0
    out["positions"] = np.array(positions)
    return out


def evaluate(case: dict) -> dict:
    """One (scene, method, margin): run, measure the slip. Never raises for a failing method."""
    name, method, margin = case["scene"], case["method"], float(case["margin"])
    if method not in METHODS:
        raise ValueError(f"creep: unknown method {method!r} (known: {', '.join(METHODS)})")
    sc, mu, need = scene_at(name, margin)
    try:
        res = _run_mujoco(case, name, sc, mu) if method in MUJOCO_METHODS else _run_stiction(case, sc)
    except Exception as exc:  # noqa: BLE001 - a failing method is data
        res = {"wall": math.nan, "failure": f"error: {type(exc).__name__}: {str(exc).splitlines()[0][:160]}",
               "positions": None, "grip": None}
    slip = creep = None
    if res["failure"] is None:
        d = _tangential(name, res["positions"] - res["positions"][0])
        slip = float(np.linalg.norm(d[-1]))
        half = len(d) // 2
        creep = float(np.linalg.norm(d[-1] - d[half])) / (case["duration"] * (len(d) - 1 - half) / (len(d) - 1))
    measured = res["wall"] / case["duration"]
    grip = res["grip"]
    effective = margin if name != "pinch" else (margin * grip / pinch_grip(sc) if _finite(grip) else None)
    failed = res["failure"] is not None
    return {"scene": name, "method": method, "margin": case["margin"], "slip": slip,
            "seconds_per_simulated_second": case["time_limit"] / case["duration"] if failed else measured,
            "failed": failed, "failure": res["failure"], "creep_rate": creep, "grip": grip,
            "effective_margin": effective, "mu": mu, "mu_needed": need,
            "duration": case["duration"], "dt": case["dt"], "measured_seconds_per_simulated_second": measured,
            "time_limit": case["time_limit"]}


# ---------------------------------------------------------------- the bench contract
def add_arguments(parser) -> None:
    parser.add_argument("--scenes", nargs="+", choices=list(SCENES), default=None,
                        help=f"scenes (default: {', '.join(SCENES)})")
    parser.add_argument("--methods", nargs="+", choices=list(METHODS), default=None,
                        help=f"methods (default: all, MuJoCo's when importable; --quick: {', '.join(QUICK_METHODS)})")
    parser.add_argument("--margins", nargs="+", type=float, default=None,
                        help=f"friction margins mu / mu_needed (default: {' '.join(f'{m:g}' for m in MARGINS)}; "
                             f"--quick: {' '.join(f'{m:g}' for m in QUICK_MARGINS)})")
    parser.add_argument("--duration", type=float, default=None,
                        help=f"simulated seconds per run (default {DURATION:g}, --quick {QUICK_DURATION:g})")
    parser.add_argument("--time-limit", type=float, default=None,
                        help=f"wall seconds per case (default {TIME_LIMIT:g}, --quick {QUICK_TIME_LIMIT:g})")


def cases(args) -> list[dict]:
    from . import mujoco_twins as ms  # noqa: PLC0415

    quick = bool(getattr(args, "quick", False))
    scenes, methods, margins = (getattr(args, k, None) for k in ("scenes", "methods", "margins"))
    for flag, given in (("--scenes", scenes), ("--methods", methods), ("--margins", margins)):
        if given is not None and not len(given):
            raise ValueError(f"creep: {flag}: empty list")
    scenes = list(scenes) if scenes is not None else list(SCENES)
    methods = list(methods) if methods is not None else list(QUICK_METHODS if quick else METHODS)
    margins = [float(m) for m in margins] if margins is not None else list(QUICK_MARGINS if quick else MARGINS)
    for s in scenes:
        if s not in SCENES:
            raise ValueError(f"creep: unknown scene {s!r} (known: {', '.join(SCENES)})")
    for m in methods:
        if m not in METHODS:
            raise ValueError(f"creep: unknown method {m!r} (known: {', '.join(METHODS)})")
    for m in margins:
        if not (m > 0 and math.isfinite(m)):
            raise ValueError(f"creep: --margins: each margin must be a finite number > 0, got {m!r}")
    if not ms.available():
        asked = [m for m in (getattr(args, "methods", None) or ()) if m in MUJOCO_METHODS]
        if asked:
            raise ValueError(f"creep: {', '.join(asked)} need MuJoCo (the optional `bench` extra: "
                             "pip install 'mujoco==4.0.*'), which is not importable")
        methods = [m for m in methods if m not in MUJOCO_METHODS]
    duration = getattr(args, "duration", None) or (QUICK_DURATION if quick else DURATION)
    limit = getattr(args, "time_limit", None) or (QUICK_TIME_LIMIT if quick else TIME_LIMIT)
    for flag, value in (("--duration", duration), ("--time-limit", limit)):
        if not (value > 0 and math.isfinite(value)):
            raise ValueError(f"creep: {flag} must be a positive number of seconds, got {value!r}")
    if round(duration / DT) < CHUNKS:
        raise ValueError(f"creep: --duration {duration:g} s is fewer than {CHUNKS} steps of {DT:g} s")
    return [{"scene": s, "method": m, "margin": g, "duration": float(duration), "dt": DT,
             "time_limit": float(limit)} for s in scenes for m in methods for g in margins]


def _finite(x) -> bool:
    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def _bool(x) -> bool:
    return x is True or (isinstance(x, str) and x.strip().lower() == "true")


def summarize(rows: list[dict]) -> dict:
    """Per scene and method: the largest slip and creep rate over the margins > 1 (runs that did
    not fail) and how many runs failed; ``goal_met``: the exact formulation's slip <= GOAL at every
    margin > 1 it ran (None when it did not run)."""
    out: dict = {}
    for r in rows:
        d = out.setdefault(r["scene"], {}).setdefault(r["method"], {"worst_slip": None, "worst_creep_rate": None,
                                                                   "failed": 0})
        if _bool(r["failed"]):
            d["failed"] += 1
            continue
        if float(r["margin"]) > 1 and _finite(r["slip"]):
            d["worst_slip"] = max(float(r["slip"]), d["worst_slip"] or 0.0)
            d["worst_creep_rate"] = max(float(r["creep_rate"]), d["worst_creep_rate"] or 0.0)
    exact = [r for r in rows if r["method"] == "exact" and float(r["margin"]) > 1]
    goal = None if not exact else all(not _bool(r["failed"]) and _finite(r["slip"]) and float(r["slip"]) <= GOAL
                                      for r in exact)
    return {"goal": GOAL, "goal_met": goal, "slip_above_limit": out}


FLOOR = 1e-17  # m: a slip of 0 is drawn here on the log axis
# one colour per method (METHODS order): the formulations, then MuJoCo's three settings (dashed)
COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
          "#000000", "#17becf", "#bcbd22")


def plot(rows: list[dict], out_dir: Path, stamp: dict) -> list[Path]:
    """One figure, a panel per scene: log slip against the margin, a line per method (MuJoCo's
    dashed), failed runs a cross on the top edge, the goal (1e-9 m) and the friction limit
    (margin 1) drawn."""
    from .._optional import require  # noqa: PLC0415
    from . import sweep  # noqa: PLC0415

    matplotlib = require("matplotlib", "plot", "the creep chart")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scenes = [s for s in SCENES if any(r["scene"] == s for r in rows)]
    if not scenes:
        return []
    slips = [float(r["slip"]) for r in rows if not _bool(r["failed"]) and _finite(r["slip"])]
    top = max(slips + [1e-3]) * 30
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.6 * len(scenes) + 1.8, 4.8), squeeze=False, sharey=True)
    for ax, scene in zip(axes[0], scenes):
        mine = [r for r in rows if r["scene"] == scene]
        methods = [m for m in METHODS if any(r["method"] == m for r in mine)]
        for m in methods:
            i = METHODS.index(m)
            color = COLORS[i % len(COLORS)]
            style = "--" if m in MUJOCO_METHODS else "-"
            good = sorted((r for r in mine if r["method"] == m and not _bool(r["failed"]) and _finite(r["slip"])),
                          key=lambda r: float(r["margin"]))
            ax.semilogy([float(r["margin"]) for r in good], [max(float(r["slip"]), FLOOR) for r in good],
                        style + "osD^v<>ph*"[i % 10], color=color, ms=4, label=m)
            bad = [r for r in mine if r["method"] == m and _bool(r["failed"])]
            if bad:
                ax.plot([float(r["margin"]) for r in bad], [top / 3] * len(bad), "x", color=color, ms=8, mew=2)
        ax.axhline(GOAL, color="k", lw=0.8, ls=":")
        ax.text(1.02, GOAL * 1.6, "goal 1e-9 m", fontsize=7)
        ax.axvline(1.0, color="0.5", lw=0.8)
        ax.set_xscale("log")
        margins = sorted({float(r["margin"]) for r in mine})
        ax.set_xticks(margins)
        ax.set_xticklabels([f"{m:g}" for m in margins], fontsize=7, rotation=90)
        ax.minorticks_off()
        ax.set_ylim(FLOOR / 3, top)
        duration = max(float(r["duration"]) for r in mine)
        need = float(mine[0]["mu_needed"])
        ax.set_title(f"{scene} (mu_needed {need:.3g}, {duration:g} s)", fontsize=9)
        ax.set_xlabel("friction margin mu / mu_needed (< 1: must slip)", fontsize=8)
        ax.grid(True, which="major", alpha=0.25)
    axes[0][0].set_ylabel(f"slip after the run [m] (0 drawn at {FLOOR:g}; x = failed)")
    handles, labels = [], []
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, fontsize=7, loc="center right")
    fig.suptitle("zero creep: slip of a held body against the friction margin (exact law: eq. 65)", fontsize=10)
    fig.tight_layout(rect=(0, 0.02, 1.0 - 1.6 / fig.get_figwidth(), 0.96))
    sweep.stamp_figure(fig, stamp)
    path = out_dir / "creep.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
