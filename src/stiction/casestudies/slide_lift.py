"""Slide and lift (Kikuuwe & Brogliato §4.5-4.6): the sliding cube under every formulation, and
whether its contacts move along the normal while they slide.

The scene ``robots/scenes/cube-slide.toml``: a 1 kg cube (side 0.1 m) launched at v0 = 1 m/s
on flat ground with mu = 0.5, time stepping at dt = 1 ms; under the exact law it slides for
v0 / (mu g) = 0.204 s without leaving the ground. At a sliding contact the exact law
(eq. 65 = De Saxce's NCP, eq. 73-77) keeps the normal velocity at zero: with lambda_t on the
cone's boundary opposite to u_t, <lambda, w> = lambda_n u_n, so u_n = 0. The alternatives
(``stiction formulations``):

- ``ccp`` (Anitescu-Tasora, eq. 78-79) drops the De Saxce term E s(u): its complementarity
  <lambda, u> = 0 with lambda on the cone's boundary forces u_n = mu ||u_t||: a sliding contact
  separates at mu times its sliding speed ([7, Fig. 1]; the paper: "small motion in the
  normal direction even during pure tangential slipping"). The lift ratio u_n / (mu ||u_t||)
  is exactly 1.
- ``nakaoka`` (eq. 80-81) drops A from the metric: friction and normal are settled per contact
  as if A were the identity, so where A couples a contact's tangential and normal rows (a
  contact off the centre of mass) the normal impulse is not the one that keeps u_n = 0.
- ``pyramid`` (§4.5, 4 facets) keeps the De Saxce term for its polygon: no lift.
- ``penalty`` (eq. 83-84, K = 1e5 N/m, beta = 1e-3 s): the normal spring carries the weight at
  a penetration m g / (4 K); u_n then contains the position term Psi / h < 0 (eq. 70).
- ``pinocchio-admm``, ``pinocchio-admm-ccp``: Pinocchio's ADMM in its NCP and CCP settings
  (a build without them raises "not built yet": they are then skipped with a note). When
  they run, the CCP setting is held to the lift ratio 1 and the NCP setting to no lift.

Measured per formulation (one rollout of the scene, 0.5 s; ``sim.data.result`` read after
every step through the rollout's callback):

- *sliding*: the records where the cube's horizontal speed exceeds ``SLIDING_SPEED``;
- ``max_normal_velocity``: max |J v|_n of the four bottom corners while sliding (m/s);
- ``airborne_fraction``: fraction of the sliding records with all four bottom corners above the
  ground by more than ``AIRBORNE_GAP`` (1 um: 1e-5 of the cube's size; the exact law keeps the
  gap at rounding level, ~1e-16 m);
- ``unloaded_fraction``: fraction of the sliding records with no normal force at all (flight);
- ``lift_ratio_median`` (and min, max, count): u_n / (mu ||u_t||) from the step's
  ``SolverResult`` (u = A P - b, rows t1, t2, n per contact) over the sliding contacts
  (||u_t|| > ``LIFT_SPEED_FLOOR`` and lambda_n > 0); the exact law gives 0, CCP 1;
- ``max_exact_law_residual`` (and ``median_exact_law_residual_sliding``): the exact law's
  relative residual of the formulation's impulses (``Trajectory.residual``);
- ``own_converged_fraction``: fraction of steps meeting the formulation's own test;
- ``us_per_step``: mean C++ time per step (the step timer's total / steps: kinematics, Delassus,
  solve, integration), ``median_us_per_step`` the median step;
- ``stop_time``, ``distance``: when the cube stopped sliding (first record after the sliding
  ones, s) and how far its base moved (m);
- ``t``, ``normal_velocity`` (the bottom corners' v_n of largest magnitude, signed),
  ``bottom_gap`` (the lowest bottom corner's gap), ``lift_ratio_t`` (median per step, None
  without a sliding contact): time series for the plot.

``bottom_contacts``: the names of the four corners on the ground at t = 0 (record 0's gaps).

Points: one row per formulation that ran, ``{formulation, max_normal_velocity,
airborne_fraction, lift_ratio_median, max_exact_law_residual, own_converged_fraction,
us_per_step, median_us_per_step, ...}``.
"""
from __future__ import annotations

import math
import time

import numpy as np
import pinocchio as pin

from ..formulations import formulation_names
from ..scene import GRAVITY, load_scene
from ..simulator import Simulator
from . import CaseStudyResult, Check

NAME = "slide-lift"
TITLE = "Slide and lift: normal motion of a sliding cube under exact, CCP, Nakaoka, pyramid, penalty"
EQUATIONS = "65, 73-84"

SCENE = "cube-slide"
FORMULATIONS = ("exact", "ccp", "nakaoka", "pyramid", "penalty", "pinocchio-admm", "pinocchio-admm-ccp")
V0, MU, DT = 1.0, 0.5, 1e-3  # the scene's launch speed [m/s], friction and step [s] (checked in run)
SLIDING_SPEED = 1e-3  # [m/s] horizontal speed of the cube above which it slides (0.1 % of v0)
AIRBORNE_GAP = 1e-6  # [m] every bottom corner above the ground by more than this: airborne
LIFT_SPEED_FLOOR = 1e-4  # [m/s] ||u_t|| of a contact above which its lift ratio is taken
EXACT_NORMAL_VELOCITY = 1e-9  # [m/s]
EXACT_RESIDUAL = 1e-10
CCP_LIFT_TOL = 1e-7  # relative: CCP's u_n = mu ||u_t|| holds to the solves' tolerance (measured 7e-10)
NAKAOKA_RESIDUAL_FLOOR = 1e-3  # "far from 0": at least 1e7 times the exact bound


def _lift_ratios(result, mu: float) -> list[float]:
    """u_n / (mu ||u_t||) of the sliding spatial contacts of one step's SolverResult."""
    u = np.asarray(result.u, float)
    lam = np.asarray(result.lam, float)
    if u.size == 0 or u.size % 3:
        return []
    out = []
    for ui, li in zip(u.reshape(-1, 3), lam.reshape(-1, 3)):
        ut = math.hypot(ui[0], ui[1])
        if ut > LIFT_SPEED_FLOOR and li[2] > 0.0:
            out.append(ui[2] / (mu * ut))
    return out


def slide_run(formulation: str) -> dict:
    """One rollout of the scene under `formulation` (Simulator raises if it is not available)."""
    scene = load_scene(SCENE)
    sim = Simulator(scene, formulation=formulation)
    mu = float(scene.mu)
    per_step: list[list[float]] = []

    def collect(s):  # runs before every step: the result of the previous one
        if s.data.t > 0.0:
            per_step.append(_lift_ratios(s.data.result, mu))

    t0 = time.perf_counter()
    traj = sim.rollout(callback=collect)
    per_step.append(_lift_ratios(sim.data.result, mu))
    seconds = time.perf_counter() - t0
    # per_step[k] belongs to record k + 1
    bottom = np.abs(traj.gaps[0]) <= 1e-9  # the four corners resting on the ground at t = 0
    if bottom.sum() != 4:
        raise RuntimeError(f"{SCENE}: {bottom.sum()} corners on the ground at t = 0, not 4")
    # horizontal speed in the world (a free flyer's v is in its body frame: rotate it)
    v_world = np.array([pin.Quaternion(q[3:7]).matrix() @ v[:3] for q, v in zip(traj.q, traj.v)])
    speed = np.hypot(v_world[:, 0], v_world[:, 1])
    sliding = speed > SLIDING_SPEED
    sliding[0] = False  # the initial state is not a step
    vn = traj.contact_velocity[:, bottom, 2]
    signed_vn = vn[np.arange(len(vn)), np.argmax(np.abs(vn), axis=1)]
    gap = traj.gaps[:, bottom].min(axis=1)
    loaded = (traj.lam[:, bottom, 2] > 0.0).any(axis=1)
    ratios = [r for k, rs in enumerate(per_step, start=1) if sliding[k] for r in rs]
    ratio_t = [float(np.median(rs)) if rs else None for rs in per_step]
    stopped = np.nonzero(~sliding[1:])[0] + 1  # records after the start that do not slide
    after = stopped[stopped > (np.nonzero(sliding)[0].max() if sliding.any() else 0)]
    stop_time = float(traj.t[after[0]]) if after.size else math.nan
    return {
        "formulation": formulation,
        "bottom_contacts": [name for name, b in zip(traj.contact_names, bottom) if b],
        "max_normal_velocity": float(np.abs(vn[sliding]).max()) if sliding.any() else 0.0,
        "airborne_fraction": float((gap[sliding] > AIRBORNE_GAP).mean()) if sliding.any() else 0.0,
        "unloaded_fraction": float((~loaded[sliding]).mean()) if sliding.any() else 0.0,
        "max_bottom_gap": float(gap[sliding].max()) if sliding.any() else 0.0,
        "min_bottom_gap": float(gap[sliding].min()) if sliding.any() else 0.0,
        "lift_ratio_median": float(np.median(ratios)) if ratios else None,
        "lift_ratio_min": float(np.min(ratios)) if ratios else None,
        "lift_ratio_max": float(np.max(ratios)) if ratios else None,
        "lift_ratio_count": len(ratios),
        "max_exact_law_residual": float(traj.residual[1:].max()),
        "median_exact_law_residual_sliding": float(np.median(traj.residual[sliding])) if sliding.any() else 0.0,
        "own_converged_fraction": float(traj.converged[1:].mean()),
        "us_per_step": float(traj.timings[1:, 4].mean()),
        "median_us_per_step": float(np.median(traj.timings[1:, 4])),
        "stop_time": stop_time,
        "distance": float(np.linalg.norm(traj.q[-1, :2] - traj.q[0, :2])),
        "seconds": seconds,
        "t": traj.t, "normal_velocity": signed_vn, "bottom_gap": gap,
        "lift_ratio_t": [None] + ratio_t,
    }


def run(quick: bool = False) -> CaseStudyResult:
    """The same rollouts either way (seven of 0.5 s take ~1 s): `quick` changes nothing."""
    scene = load_scene(SCENE)
    if float(scene.v0[0]) != V0 or float(scene.mu) != MU or float(scene.dt) != DT:
        raise RuntimeError(f"{SCENE} changed (v0, mu, dt): update slide_lift's constants")
    points, notes, checks = [], [], []
    known = formulation_names()
    for name in FORMULATIONS:
        if name not in known:
            notes.append(f"{name}: skipped (not a formulation of this build: {', '.join(known)}).")
            continue
        try:
            points.append(slide_run(name))
        except Exception as e:  # noqa: BLE001 - a formulation that cannot run is reported, not fatal
            msg = str(e)
            if "not built yet" in msg:
                notes.append(f"{name}: skipped ({msg}).")
            else:
                notes.append(f"{name}: failed: {type(e).__name__}: {msg}")
                checks.append(Check(f"{name} runs the scene (1 = ran)", 0.0, 1.0, 0.0))
    by = {p["formulation"]: p for p in points}
    ex, ccp, nak = by.get("exact"), by.get("ccp"), by.get("nakaoka")
    if ex:
        checks += [
            Check("exact: max |v_n| of the bottom corners while sliding [m/s]", ex["max_normal_velocity"], 0.0,
                  EXACT_NORMAL_VELOCITY, "<="),
            Check("exact: airborne fraction of the sliding time", ex["airborne_fraction"], 0.0, 0.0),
            Check("exact: max exact-law residual", ex["max_exact_law_residual"], 0.0, EXACT_RESIDUAL, "<="),
            Check("exact: stop time [s] (first record below the sliding speed) vs v0 / (mu g), to one step",
                  ex["stop_time"], V0 / (MU * GRAVITY), DT),
        ]
    if ccp and ccp["lift_ratio_count"]:
        checks += [
            Check(f"ccp: median lift ratio u_n / (mu ||u_t||) on sliding contacts ({ccp['lift_ratio_count']} "
                  "contact-steps; the paper: 1)", ccp["lift_ratio_median"], 1.0, CCP_LIFT_TOL),
            Check("ccp: largest |lift ratio - 1| on any sliding contact-step",
                  max(abs(ccp["lift_ratio_max"] - 1.0), abs(ccp["lift_ratio_min"] - 1.0)), 0.0, CCP_LIFT_TOL),
        ]
    pin_ccp, pin_ncp = by.get("pinocchio-admm-ccp"), by.get("pinocchio-admm")
    if pin_ccp and pin_ccp["lift_ratio_count"]:
        checks.append(Check(f"pinocchio-admm-ccp: median lift ratio on sliding contacts ({pin_ccp['lift_ratio_count']} "
                            "contact-steps; CCP: 1)", pin_ccp["lift_ratio_median"], 1.0, CCP_LIFT_TOL))
    if pin_ncp and pin_ncp["lift_ratio_count"]:
        checks.append(Check("pinocchio-admm (NCP): |median lift ratio| on sliding contacts (exact law: 0)",
                            abs(pin_ncp["lift_ratio_median"]), 0.0, CCP_LIFT_TOL, "<="))
    if nak:
        checks.append(Check(f"nakaoka: max exact-law residual (far from 0: >= {NAKAOKA_RESIDUAL_FLOOR:g}, exact's "
                            f"<= {EXACT_RESIDUAL:g})", nak["max_exact_law_residual"], NAKAOKA_RESIDUAL_FLOOR, 0.0,
                            ">="))
    notes.insert(0, f"{SCENE}: v0 = 1 m/s, mu = 0.5, dt = 1 ms, 0.5 s; sliding = horizontal speed > "
                    f"{SLIDING_SPEED:g} m/s; airborne = every bottom corner above {AIRBORNE_GAP:g} m; lift ratio over "
                    f"contacts with ||u_t|| > {LIFT_SPEED_FLOOR:g} m/s and lambda_n > 0.")
    if ccp:
        notes.append(f"ccp: the first step lifts the cube at mu ||v_t|| = {ccp['max_normal_velocity']:.3f} m/s "
                     f"(u_n = mu ||u_t|| with the gap 0); it flies, lands, and then slides at a gap of "
                     f"h (u_n - v_n) ~ h mu ||v_t|| (the position term Psi / h of u_n): airborne "
                     f"{ccp['airborne_fraction']:.1%} of the sliding time, in flight (no load) "
                     f"{ccp['unloaded_fraction']:.1%}. The friction impulse is mu times the normal impulse, which "
                     f"over the whole slide is m g T: it still stops at {ccp['stop_time']:.3f} s.")
    return CaseStudyResult(NAME, TITLE, EQUATIONS, checks, points, notes)


def plot(result: CaseStudyResult, path) -> None:
    """Normal velocity of the bottom corners, height of the lowest one and the lift ratio vs
    time, one line per formulation."""
    from .._optional import require

    matplotlib = require("matplotlib", "plot", "plots")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2, ax3) = plt.subplots(3, 1, figsize=(10, 11), sharex=True)
    for i, p in enumerate(result.points):
        t = np.asarray(p["t"], float)
        c = f"C{i}"
        ls, mk = ("--", "x") if p["formulation"].startswith("pinocchio") else ("-", ".")  # over ours
        ax1.plot(t, np.asarray(p["normal_velocity"], float), ls, color=c, lw=1.3,
                 label=f"{p['formulation']}: max |v_n| = {p['max_normal_velocity']:.2g} m/s")
        ax2.plot(t, np.asarray(p["bottom_gap"], float) * 1e3, ls, color=c, lw=1.3,
                 label=f"{p['formulation']}: airborne {p['airborne_fraction']:.1%}")
        lr = np.array([np.nan if x is None else x for x in p["lift_ratio_t"]], float)
        med = p["lift_ratio_median"]
        ax3.plot(t, lr, mk, color=c, ms=3,
                 label=f"{p['formulation']}: median {'—' if med is None else f'{med:.3g}'}")
    ax1.set_yscale("symlog", linthresh=1e-9)
    ax1.set_ylabel("v_n of the bottom corners [m/s]\n(largest magnitude, signed)")
    ax1.set_title("Sliding cube (v0 = 1 m/s, μ = 0.5, h = 1 ms): normal velocity of the contacts", fontsize=10)
    ax1.legend(fontsize=7, loc="upper right")
    ax2.set_yscale("symlog", linthresh=1e-3)
    ax2.set_ylabel("lowest bottom corner's gap [mm]")
    ax2.legend(fontsize=7, loc="upper right")
    ax3.set_yscale("symlog", linthresh=1e-2)
    ax3.axhline(1.0, color="k", lw=0.8, ls=":")
    ax3.set_ylabel("lift ratio u_n / (μ ||u_t||)\n(median over sliding contacts)")
    ax3.set_xlabel("t [s]")
    stops = [p["stop_time"] for p in result.points if p["stop_time"] is not None and math.isfinite(p["stop_time"])]
    if stops:  # nothing moves after the last stop
        ax3.set_xlim(0.0, max(stops) + 0.05)
    ax3.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
