"""Diagonal push (Kikuuwe & Brogliato §4.5): a cube pushed across the ground at an angle, the
exact friction cone against facetized pyramids.

The cube of ``robots/scenes/cube-slide.toml`` (m = 1 kg, side 0.1 m, mu = 0.5, four bottom
corners on the ground z = 0) starts at rest and is pushed by a constant horizontal force F at
angle phi to its x axis, through its centre (``Simulator.data.tau_ff[:3]``: for a free flyer
a force in the body frame; the cube does not yaw, so the body frame stays the world's). The
push is measured in units of the friction bound, r = F / (mu m g).

**What each law predicts.** The four contacts slide together (the cube translates), so the
total friction f = sum_i lambda_t,i lies in the set S scaled by the total normal force m g,
where S is the friction section of one contact at unit normal force: the disc of radius mu
(exact cone, eq. 58) or the N-gon of the pyramid (facet normals at 2 pi k / N, facets at
distance mu (circumscribed) or mu cos(pi/N) (inscribed); the Minkowski sum of the four
scaled sections is the section scaled by sum_i lambda_n,i = m g). Maximum dissipation
(the exact law's, and the pyramid LCP's over its polygon) makes -f the point of m g S that
maximises -f . (-v), and the dynamics m dv/dt = F + f. Starting from rest the solution is

    f = -P(F),   v(t) parallel to d = F - P(F),          P = Euclidean projection onto m g S

(d lies in the normal cone of m g S at P(F), so -P(F) maximises the dissipation for every v
parallel to d, and dv/dt is parallel to d: the motion is self-consistent from the first step).
Hence:

- **sticks** iff F is in m g S: for the disc r <= 1; for the polygon r <= rho / max_k
  cos(phi - 2 pi k / N) (rho = 1 circumscribed, cos(pi/N) inscribed). For N = 4
  circumscribed: r <= 1 / max(|cos phi|, |sin phi|), up to sqrt(2) at 45 deg.
- **direction error** of the friction against -v (rad) = the angle between P(F) and
  F - P(F). For the disc it is 0. For a polygon there are two regimes. If F projects onto a
  corner, the velocity points anywhere inside that corner's normal cone and maximum
  dissipation picks the corner nearest to -v: the error is the angle from -v to that corner.
  If F projects onto the interior of a facet (the common case), -v is exactly the facet's
  normal; then every point of the facet is maximally dissipative, and the friction sits where
  the force balance across the facet puts it: error = atan(|F_perp| / F_facet) with F_perp
  the push's component along the facet. For N = 4 circumscribed and phi in [0, 45 deg]: the
  cube slides along x with error atan(r sin phi) while r sin phi <= 1, and in the corner's
  direction (friction at the corner (-1, -1) mu m g) with error 45 deg - atan2(r sin phi - 1,
  r cos phi - 1) beyond.

**What is measured.** Each (formulation, phi, r) is a rollout of ``SETTLE`` + ``WINDOW``
seconds at dt = 1 ms from rest. *Sticks*: the base's horizontal displacement during the
window is below ``STICK_DISTANCE`` (1 um); a point at the edge of the 1 % band around the
boundary accelerates at >= 0.01 cos(pi/N) mu g and covers >= 0.5 a WINDOW^2 ~ 1e-4 m in the
window, a sticking one drifts by the solver's velocity error (at most 5.5e-11 m in the full
sweep; both extremes are checked, 100x inside the threshold).
*Direction error*: at every window step with a horizontal speed above ``SPEED_FLOOR``, the
angle between the total friction (sum of lambda_t over the loaded contacts) and minus the
mean tangential contact velocity (its median over the steps, and the max and min), and the
largest per-contact angle (for the exact cone every sliding contact must oppose its own
velocity; for a pyramid in the facet regime the split of the facet-parallel friction among
the four contacts is not determined, only the total is).

Points (``CaseStudyResult.points``): one per (formulation, phi, r):
``{formulation, facets, inscribed, phi_deg, force_ratio, sticks, predicted_sticks,
stick_bound_ratio, displacement, direction_error_rad, direction_error_max_rad,
direction_error_min_rad, predicted_direction_error_rad, contact_direction_error_max_rad,
velocity_direction_deg, predicted_velocity_direction_deg, max_yaw_rad, own_converged_fraction,
steps, unconverged_steps, window_steps_unconverged, unconverged_messages, max_exact_law_residual,
seconds}`` —
``formulation`` is the label (exact, pyramid-4, pyramid-4-inscribed, pyramid-8, pyramid-16;
``facets`` None for exact), ``stick_bound_ratio`` the formulation's boundary F / (mu m g) at
this phi, ``displacement`` in m, angles in rad (``direction_error_rad`` the median over the window's
steps, ``_max``/``_min`` the extremes; None when the cube sticks), ``velocity_direction_deg``
the median sliding direction, ``own_converged_fraction`` the fraction of steps that met the
formulation's own test (``unconverged_steps`` those that did not, ``window_steps_unconverged``
in the window, ``unconverged_messages`` their messages with counts),
``max_exact_law_residual`` the exact-law residual (for a pyramid, large where its force
leaves the cone: sticking beyond mu, or a corner force).
"""
from __future__ import annotations

import math
import time

import numpy as np

from ..scene import GRAVITY, load_scene
from ..simulator import Simulator
from . import CaseStudyResult, Check

NAME = "diagonal-push"
TITLE = "Diagonal push: stick/slide boundary and friction direction, exact cone vs facetized pyramids"
EQUATIONS = "58, 65, 73-77; §4.5"

SCENE = "cube-slide"
SETTLE = 0.02  # [s] before the measuring window (20 steps: the start from rest is not measured)
WINDOW = 0.08  # [s] the window in which displacement and direction are measured
STICK_DISTANCE = 1e-6  # [m] horizontal displacement in the window below which the cube sticks
SPEED_FLOOR = 1e-6  # [m/s] below it the sliding direction is not measured
BAND = 0.01  # relative band around each boundary where the classification is not checked
EXACT_DIRECTION_TOL = 1e-6  # [rad]
PYRAMID_DIRECTION_TOL = 1e-6  # [rad] |median measured - predicted| for the pyramids
VELOCITY_DIRECTION_TOL = 1e-4  # [deg] |measured sliding direction - predicted|
YAW_TOL = 1e-7  # [rad] the push (body frame) turns with the cube: 1/10 of PYRAMID_DIRECTION_TOL

# label -> Simulator overrides
FORMULATIONS = {
    "exact": {"formulation": "exact"},
    "pyramid-4": {"formulation": "pyramid", "pyramid_facets": 4},
    "pyramid-4-inscribed": {"formulation": "pyramid", "pyramid_facets": 4, "pyramid_inscribed": True},
    "pyramid-8": {"formulation": "pyramid", "pyramid_facets": 8},
    "pyramid-16": {"formulation": "pyramid", "pyramid_facets": 16},
}


def _geometry(label: str) -> tuple[int | None, bool]:
    opts = FORMULATIONS[label]
    return opts.get("pyramid_facets"), bool(opts.get("pyramid_inscribed", False))


# ---- the geometry of the friction section (units of mu m g)

def section_corners(facets: int, inscribed: bool) -> np.ndarray:
    """Corners (N, 2) of the pyramid's section at unit normal force, in units of mu:
    facet normals at 2 pi k / N, facet distance 1 (circumscribed) or cos(pi/N) (inscribed)."""
    half = math.pi / facets
    radius = (math.cos(half) if inscribed else 1.0) / math.cos(half)
    a = 2.0 * math.pi * np.arange(facets) / facets + half
    return radius * np.column_stack([np.cos(a), np.sin(a)])


def project(F: np.ndarray, facets: int | None, inscribed: bool = False) -> np.ndarray:
    """Euclidean projection of F (units of mu m g) onto the friction section: the unit disc
    (facets None) or the pyramid's polygon."""
    F = np.asarray(F, float)
    if facets is None:
        n = float(np.linalg.norm(F))
        return F.copy() if n <= 1.0 else F / n
    rho = math.cos(math.pi / facets) if inscribed else 1.0
    normals = np.column_stack([np.cos(2 * math.pi * np.arange(facets) / facets),
                               np.sin(2 * math.pi * np.arange(facets) / facets)])
    if (normals @ F <= rho).all():
        return F.copy()
    corners = section_corners(facets, inscribed)
    best, best_d = None, math.inf
    for k in range(facets):  # edge k joins corner k-1 and corner k (facet normal k between them)
        a, b = corners[k - 1], corners[k]
        e = b - a
        s = min(1.0, max(0.0, float((F - a) @ e / (e @ e))))
        p = a + s * e
        d = float(np.linalg.norm(F - p))
        if d < best_d:
            best, best_d = p, d
    return best


def stick_bound(phi: float, facets: int | None, inscribed: bool = False) -> float:
    """The largest r = F / (mu m g) at angle phi (rad) inside the section (the boundary)."""
    if facets is None:
        return 1.0
    rho = math.cos(math.pi / facets) if inscribed else 1.0
    k = np.arange(facets)
    return rho / float(np.max(np.cos(phi - 2 * math.pi * k / facets)))


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between 2-vectors a and b in [0, pi] (atan2 of cross and dot: no cancellation)."""
    return math.atan2(abs(a[0] * b[1] - a[1] * b[0]), float(a @ b))


def predict(phi: float, ratio: float, facets: int | None, inscribed: bool = False) -> dict:
    """Stick or slide, friction direction error and sliding direction from rest (module doc)."""
    F = ratio * np.array([math.cos(phi), math.sin(phi)])
    P = project(F, facets, inscribed)
    d = F - P
    bound = stick_bound(phi, facets, inscribed)
    if float(np.linalg.norm(d)) <= 1e-14 * max(1.0, ratio):
        return {"sticks": True, "bound": bound, "error": None, "velocity_deg": None}
    # friction -P against -v = -d: the angle between P and d
    return {"sticks": False, "bound": bound, "error": _angle(P, d),
            "velocity_deg": math.degrees(math.atan2(d[1], d[0]))}


# ---- the simulation

def push_run(label: str, phi_deg: float, ratio: float) -> dict:
    """The cube from rest under F = ratio mu m g at phi_deg (module doc: What is measured)."""
    scene = load_scene(SCENE)
    mass = float(sum(inertia.mass for inertia in scene.model.inertias))
    mu = float(scene.mu)
    sim = Simulator(scene, **FORMULATIONS[label])
    sim.set_state(v=np.zeros(scene.model.nv))
    phi = math.radians(phi_deg)
    F = ratio * mu * mass * GRAVITY
    tau = np.zeros(scene.model.nv)
    tau[:2] = F * math.cos(phi), F * math.sin(phi)
    sim.data.tau_ff = tau
    failures: dict[str, int] = {}  # the formulation's message for each step that missed its own test

    def note_failure(result):
        if not result.own_converged:
            key = result.message.split(";")[0]
            failures[key] = failures.get(key, 0) + 1

    def collect(s):  # runs before every step: the result of the previous one
        if s.data.t > 0.0:
            note_failure(s.data.result)

    t0 = time.perf_counter()
    traj = sim.rollout(SETTLE + WINDOW, callback=collect)
    note_failure(sim.data.result)
    seconds = time.perf_counter() - t0
    window = traj.t >= SETTLE - 1e-12
    i0 = int(np.argmax(window))
    displacement = float(np.linalg.norm(traj.q[-1, :2] - traj.q[i0, :2]))
    sticks = displacement < STICK_DISTANCE

    errors, contact_errors, directions = [], [], []
    unconverged = 0
    for k in np.nonzero(window)[0]:
        unconverged += int(not traj.converged[k])
        loaded = traj.lam[k, :, 2] > 0.0
        if not loaded.any():
            continue
        lt = traj.lam[k, loaded, :2]
        vt = traj.contact_velocity[k, loaded, :2]
        v_mean = vt.mean(axis=0)
        if float(np.linalg.norm(v_mean)) <= SPEED_FLOOR:
            continue
        errors.append(_angle(lt.sum(axis=0), -v_mean))
        directions.append(math.degrees(math.atan2(v_mean[1], v_mean[0])))
        for li, vi in zip(lt, vt):
            if float(np.linalg.norm(vi)) > SPEED_FLOOR:
                contact_errors.append(_angle(li, -vi))
    # yaw of the base (rotation about z; the quaternion is (x, y, z, w))
    quat = traj.q[:, 3:7]
    yaw = np.arctan2(2 * (quat[:, 3] * quat[:, 2] + quat[:, 0] * quat[:, 1]),
                     1 - 2 * (quat[:, 1] ** 2 + quat[:, 2] ** 2))
    facets, inscribed = _geometry(label)
    pred = predict(phi, ratio, facets, inscribed)
    sliding = not sticks and bool(errors)
    return {
        "formulation": label, "facets": facets, "inscribed": inscribed,
        "phi_deg": float(phi_deg), "force_ratio": float(ratio),
        "sticks": bool(sticks), "predicted_sticks": pred["sticks"], "stick_bound_ratio": pred["bound"],
        "displacement": displacement,
        "direction_error_rad": float(np.median(errors)) if sliding else None,
        "direction_error_max_rad": float(max(errors)) if sliding else None,
        "direction_error_min_rad": float(min(errors)) if sliding else None,
        "predicted_direction_error_rad": pred["error"],
        "contact_direction_error_max_rad": float(max(contact_errors)) if sliding and contact_errors else None,
        "velocity_direction_deg": float(np.median(directions)) if sliding else None,
        "predicted_velocity_direction_deg": pred["velocity_deg"],
        "max_yaw_rad": float(np.abs(yaw).max()),
        "own_converged_fraction": float(traj.converged[1:].mean()),
        "steps": int(len(traj.t) - 1),
        "unconverged_steps": int((~traj.converged[1:]).sum()),
        "window_steps_unconverged": unconverged,
        "unconverged_messages": failures,
        "max_exact_law_residual": float(traj.residual[1:].max()),
        "seconds": seconds,
    }


def _grid(quick: bool) -> dict[str, list[tuple[float, float]]]:
    """(phi_deg, ratio) per formulation label."""
    if quick:
        # exact: a stick and a slide on either side of r = 1; pyramid-4: the facet regime (x-slide
        # at 30 deg), the corner regime (42.5 deg, r = 1.5), stuck at 45 deg beyond r = 1;
        # inscribed: stuck and sliding below r = 1; 8 facets: a stick and a slide (facet regime);
        # 16 facets: a stick (its sliding runs take ~4-6 s each: see the docs page).
        base = [(0.0, 0.8), (0.0, 1.1), (30.0, 1.1), (30.0, 1.3), (42.5, 1.5), (45.0, 1.3)]
        return {"exact": base, "pyramid-4": base,
                "pyramid-4-inscribed": [(0.0, 0.6), (0.0, 0.8), (30.0, 0.8), (45.0, 0.8), (20.0, 1.2)],
                "pyramid-8": [(20.0, 0.9), (40.0, 1.4)], "pyramid-16": [(20.0, 0.9)]}
    phis = [float(x) for x in np.arange(0.0, 45.0 + 1e-9, 2.5)]
    ratios = [round(float(x), 2) for x in np.arange(0.6, 1.5 + 1e-9, 0.05)]
    fine = [(p, r) for p in phis for r in ratios]
    coarse_phis = [float(x) for x in np.arange(0.0, 45.0 + 1e-9, 5.0)]
    # 1.02 and 1.05: between mu m g and the 8-facet boundary (up to 1 / cos(22.5 deg) = 1.082)
    coarse_ratios = sorted([round(float(x), 2) for x in np.arange(0.6, 1.5 + 1e-9, 0.1)] + [1.02, 1.05])
    coarse = [(p, r) for p in coarse_phis for r in coarse_ratios]
    return {"exact": fine, "pyramid-4": fine, "pyramid-4-inscribed": fine, "pyramid-8": coarse,
            "pyramid-16": coarse}


def _outside_band(p: dict) -> bool:
    return abs(p["force_ratio"] / p["stick_bound_ratio"] - 1.0) > BAND


def run(quick: bool = False) -> CaseStudyResult:
    grid = _grid(quick)
    points = [push_run(label, phi, r) for label, cells in grid.items() for phi, r in cells]
    checks = []
    for label in FORMULATIONS:
        mine = [p for p in points if p["formulation"] == label]
        if not mine:
            continue
        judged = [p for p in mine if _outside_band(p)]
        wrong = [p for p in judged if p["sticks"] != p["predicted_sticks"]]
        boundary = ("F <= mu m g" if label == "exact" else
                    "F <= rho mu m g / max_k cos(phi - 2 pi k / N)")
        checks.append(Check(f"{label}: points misclassified (stick vs slide; sticks iff {boundary}) outside the "
                            f"{BAND:.0%} band, of {len(judged)}", len(wrong), 0.0, 0.0))
        slid = [p for p in judged if not p["sticks"] and not p["predicted_sticks"]
                and p["direction_error_rad"] is not None]
        if not slid:
            continue
        if label == "exact":
            checks.append(Check(f"exact: largest friction direction error (total force, every window step) while "
                                f"sliding [rad], {len(slid)} runs", max(p["direction_error_max_rad"] for p in slid),
                                0.0, EXACT_DIRECTION_TOL, "<="))
            checks.append(Check("exact: largest per-contact friction direction error while sliding [rad]",
                                max(p["contact_direction_error_max_rad"] for p in slid), 0.0,
                                EXACT_DIRECTION_TOL, "<="))
        else:
            dev = max(abs(p["direction_error_rad"] - p["predicted_direction_error_rad"]) for p in slid)
            worst = max(p["predicted_direction_error_rad"] for p in slid)
            checks.append(Check(f"{label}: max |direction error (median over the window) - geometry's prediction| "
                                f"[rad], {len(slid)} sliding runs (predicted up to {worst:.4f} rad)", dev, 0.0,
                                PYRAMID_DIRECTION_TOL))
        vdev = max(abs(p["velocity_direction_deg"] - p["predicted_velocity_direction_deg"]) for p in slid)
        checks.append(Check(f"{label}: max |sliding direction - direction of F - P(F)| [deg]", vdev, 0.0,
                            VELOCITY_DIRECTION_TOL))
    stuck = [p["displacement"] for p in points if p["sticks"]]
    moved = [p["displacement"] for p in points if not p["sticks"] and _outside_band(p)]
    if stuck:
        checks.append(Check(f"largest window displacement of a sticking run [m] (threshold {STICK_DISTANCE:g} m, "
                            "checked 100x below it)", max(stuck), 0.0, STICK_DISTANCE / 100, "<="))
    if moved:
        checks.append(Check(f"smallest window displacement of a sliding run outside the band [m] (checked 100x "
                            f"above {STICK_DISTANCE:g} m)", min(moved), 100 * STICK_DISTANCE, 0.0, ">="))
    checks.append(Check("largest yaw of the cube [rad] (the body-frame push stays the world's to 1/10 of the "
                        "direction tolerance)", max(p["max_yaw_rad"] for p in points), 0.0,
                        YAW_TOL, "<="))
    notes = [
        f"cube-slide's cube (m = 1 kg, side 0.1 m, mu = 0.5) from rest, dt = 1 ms, {SETTLE:g} s + {WINDOW:g} s window; "
        f"F = r mu m g at phi through the centre (data.tau_ff). No tipping: the largest friction, "
        f"mu sqrt(2) m g = 6.9 N at the pyramid-4 corner, is below the m g = 9.8 N that tips the cube "
        f"(half-width = half-height).",
        "direction error: of the total friction (sum over the four contacts) against -v; per contact only the exact "
        "cone determines it (a pyramid's facet-parallel friction may be split in any way among the contacts).",
        "grid: " + ", ".join(f"{k}: {len(v)} points" for k, v in grid.items()) + ".",
    ]
    for label in FORMULATIONS:
        bad = [p for p in points if p["formulation"] == label and p["own_converged_fraction"] < 1.0]
        if not bad:
            continue
        slid = [p for p in bad if p["direction_error_max_rad"] is not None and p["predicted_direction_error_rad"]
                is not None]
        worst = max((max(abs(p["direction_error_max_rad"] - p["predicted_direction_error_rad"]),
                         abs(p["direction_error_min_rad"] - p["predicted_direction_error_rad"])) for p in slid),
                    default=0.0)
        messages: dict[str, int] = {}
        for p in bad:
            for k, v in p["unconverged_messages"].items():
                messages[k] = messages.get(k, 0) + v
        slowest = max(bad, key=lambda p: p["seconds"])
        notes.append(f"{label}: {len(bad)} of {sum(p['formulation'] == label for p in points)} runs have steps that "
                     f"missed the formulation's own test ({sum(p['unconverged_steps'] for p in bad)} steps: "
                     + "; ".join(f"{v}x '{k}'" for k, v in sorted(messages.items(), key=lambda kv: -kv[1]))
                     + f"); around those steps the friction direction deviates from the prediction by up to "
                     f"{worst:.3g} rad (the window medians are checked); the slowest such run took "
                     f"{slowest['seconds']:.1f} s for {slowest['steps']} steps "
                     f"(phi {slowest['phi_deg']:g} deg, r {slowest['force_ratio']:g}).")
    return CaseStudyResult(NAME, TITLE, EQUATIONS, checks, points, notes)


def plot(result: CaseStudyResult, path) -> None:
    """Stick/slide maps in the (phi, F / (mu m g)) plane per formulation with the true cone's
    boundary (r = 1) and the formulation's own; friction direction error vs phi at the largest r."""
    from .._optional import require

    matplotlib = require("matplotlib", "plot", "plots")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labels = [lab for lab in FORMULATIONS if any(p["formulation"] == lab for p in result.points)]
    n = len(labels)
    ncols = 3
    nrows = -(-(n + 1) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(5.0 * ncols, 4.3 * nrows))
    axes = np.atleast_1d(axes).ravel()
    phi_line = np.linspace(0.0, 45.0, 451)
    for ax, lab in zip(axes, labels):
        pts = [p for p in result.points if p["formulation"] == lab]
        facets, inscribed = _geometry(lab)
        st = [p for p in pts if p["sticks"]]
        sl = [p for p in pts if not p["sticks"]]
        ax.plot([p["phi_deg"] for p in st], [p["force_ratio"] for p in st], "s", color="C0", ms=5, label="sticks")
        ax.plot([p["phi_deg"] for p in sl], [p["force_ratio"] for p in sl], "o", color="C3", ms=4,
                mfc="none", label="slides")
        wrong = [p for p in pts if p["sticks"] != p["predicted_sticks"]]
        if wrong:
            ax.plot([p["phi_deg"] for p in wrong], [p["force_ratio"] for p in wrong], "kx", ms=8,
                    label="≠ own geometry")
        ax.plot(phi_line, np.ones_like(phi_line), "k-", lw=1.5, label="true cone: F = μmg")
        if facets is not None:
            ax.plot(phi_line, [stick_bound(math.radians(x), facets, inscribed) for x in phi_line], "--", color="C2",
                    lw=1.5, label="pyramid's boundary")
        ax.set_xlim(-2, 47)
        ax.set_ylim(0.55, 1.78)  # the legend goes above the grid (r <= 1.5)
        ax.set_xlabel("φ [deg]")
        ax.set_ylabel("F / (μ m g)")
        ax.set_title(lab, fontsize=10)
        ax.legend(fontsize=7, loc="upper left", ncol=2)
    for ax in axes[n:-1]:
        ax.axis("off")
    ax = axes[-1]
    r_max = max(p["force_ratio"] for p in result.points)
    for i, lab in enumerate(labels):
        pts = sorted((p for p in result.points if p["formulation"] == lab and p["force_ratio"] == r_max
                      and p["direction_error_rad"] is not None), key=lambda p: p["phi_deg"])
        facets, inscribed = _geometry(lab)
        pred = [predict(math.radians(x), r_max, facets, inscribed)["error"] for x in phi_line]
        ax.plot(phi_line, [np.nan if e is None else math.degrees(e) for e in pred], "-", color=f"C{i}", lw=1,
                alpha=0.7, label=f"{lab}: geometry")
        if pts:
            ax.plot([p["phi_deg"] for p in pts], [math.degrees(p["direction_error_rad"]) for p in pts], "o",
                    color=f"C{i}", ms=4, label=f"{lab}: measured")
    ax.set_xlabel("φ [deg]")
    ax.set_ylabel("∠(friction, −v) [deg]")
    ax.set_title(f"friction direction error at F = {r_max:g} μmg", fontsize=10)
    ax.set_ylim(-2, 68)
    ax.legend(fontsize=6, ncol=2, loc="upper left")
    fig.suptitle("Diagonal push from rest: stick/slide and friction direction (exact cone vs pyramids)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
