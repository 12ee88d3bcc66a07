"""Painlevé's paradox (Kikuuwe & Brogliato §5.3, eq. 105-121): a rod slipping on its lower end.

The rod of Fig. 5: mass m, half-length l, centre q = (q_t, q_n, theta), contact point
p = (q_t - l cos theta, q_n - l sin theta) (eq. 105), M = diag(m, m, m l^2/3) (eq. 108),
J = [[1, 0, l sin theta], [0, 1, -l cos theta]] (eq. 109), friction cone F = {|lambda_t| <= mu
lambda_n} (eq. 112). The tip is on the ground (p_n = 0, pdot_n = 0) and slips backwards
(pdot_t < 0). The relaxed law (eq. 113) gives the per-step problem (eq. 65, written as eq. 114)

    A lambda - b in -lim N_F^{U_eps}(lambda),   b = A r(delta, q, qdot)      (eq. 114-116)

with the Delassus operator A = J M^-1 J^T (eq. 117 prints J^T M^-1 J, a transposition slip:
A is the 2x2 contact-space operator) and r = r_a - (2 zeta pdot_t / delta) r_b (eq. 116 at
p_n = pdot_n = 0), r_a (eq. 118), r_b = A^-1 e_t (eq. 119). In closed form, with
c = cos theta, s = sin theta:

    A = (1/m) [[1 + 3 s^2, -3 s c], [-3 s c, 1 + 3 c^2]],   A^-1 = (m/4) [[1 + 3 c^2, 3 s c], [3 s c, 1 + 3 s^2]]
    G_B(q) = [1, -mu] r_b = (m/4)(1 + 3 c^2 - 3 mu s c)                         (eq. 120)
    G_A(q, qdot) = [0, 1] A r_a = g - l thetadot^2 s                             (eq. 121)

so G_B < 0 needs mu > min_theta (1 + 3c^2)/(3 s c) = 4/3 (at tan theta = 2), and G_A < 0 needs
the free acceleration of the tip to point up (l thetadot^2 s > g).

What this case study does (``stiction casestudy painleve``):

1. **Closed forms vs the simulator.** The rod is built as a Pinocchio model (a planar joint in
   the vertical x-z plane, inertia m l^2/3, a point contact "tip" at (-l, 0, 0), the planar
   contact model: 2 rows t, n; the same body as ``robots/scenes/painleve-rod.toml``). At every
   theta of the grid, the simulator's own Delassus operator and right-hand side
   (``_core.build_contact_problem``: crba, Cholesky, J M^-1 J^T and eq. 27) are compared with
   eq. 116-117, and G_A, G_B computed from them (G_A = b_n since pdot_n = p_n = 0;
   G_B = [1, -mu] A_sim^-1 e_t) with eq. 120-121.
2. **Regions.** Over a (theta, mu) grid at a fixed thetadot (chosen so that G_A = 0 at theta =
   45 deg) the signs of G_A, G_B classify each point: ``unique-slip`` (G_A > 0, G_B > 0),
   ``unique-detach`` (G_A < 0, G_B > 0), ``non-unique`` (G_A < 0, G_B < 0: three solutions) and
   ``no-solution`` (G_A > 0, G_B < 0: no slipping solution; the only solution of the relaxed
   problem is the stick force lambda = r, of order 1/delta: a tangential impact, "dynamic
   jamming").
3. **All solutions of eq. 114.** At every grid point the per-step problem with b from eq. 116 at
   delta = ``DELTA_ENUM`` is solved by enumeration (lambda = 0; lambda = A^-1 b inside F; lambda on
   either edge of F, where the inclusion is one linear equation), which finds every solution.
   Each is verified with the package's yardstick, ``stiction.exact_law_measures`` on a
   ``ContactProblem`` built with ``Constraint.planar_friction(mu)`` (relative natural-map
   residual), and its kind (detach / stick / slip) compared with the package's contact state.
   The count per point must be the paper's: 1, 1, 3 and 1 in the four regions (Fig. 6, 7).
4. **What the solver picks.** At one point per region the rod is simulated in the relaxed ODE
   (``Simulator``, mode rk4, delta = ``DELTA_SIM``): the force of the first solve (a probe step
   of 1e-9 delta, cold start as every first step) is matched with the enumerated solutions, the
   stand-alone solvers are asked the same question (cold start, and from the ProxQP warm start),
   and a short rollout shows what follows. In the no-solution region the rod jams: while the
   contact sticks, pdot_t decays like exp(-t/delta) under a force of order |pdot_t|/delta, and the
   impulse equals the rigid sticking impulse |pdot_t| r_b (eq. 119) plus the regular stick force
   r_a (eq. 118) times the elapsed time, up to O(delta).

Points (``CaseStudyResult.points``):

- ``{"type": "grid", theta_deg, mu, region, G_A, G_B, n_solutions,
  solutions: [{kind, lambda, residual, state}]}`` — G_A in m/s^2, G_B in kg (eq. 120-121),
  lambda = (lambda_t, lambda_n) in N, residual the relative natural-map residual of eq. 65.
- ``{"type": "simulation", theta_deg, mu, region, G_A, G_B, delta, solutions, picked,
  picked_lambda, picked_distance, picked_by: {solver: kind}, rollout: {...}}`` — one per region;
  ``picked`` is the kind of the simulator's first solve (``picked_distance``: its relative
  distance to that solution), ``picked_by`` what the stand-alone solvers return from a cold
  start (``default``, ``nsgs``, ``admm``, ``newton``) and from the ProxQP warm start
  (``default+proxqp``, ...), ``rollout`` what the next ``ROLLOUT_DURATION`` seconds did
  (``state_fractions`` of the steps per contact state, ``final_gap``, ``final_slip_velocity``,
  ``max_force``, ``impulse`` of the contact force from the centre's momentum, normal velocity
  range); the no-solution point adds the jam: ``stick_time``, ``slip_decay_rate`` (1/s),
  ``stick_impulse``, ``predicted_stick_impulse``, ``rigid_impulse`` (|pdot_t| r_b) and
  ``state_after`` (what the contact does when the stick phase ends).
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from .. import _core
from ..scene import GRAVITY, scene_from_model
from ..simulator import Simulator
from ..solve import solve
from . import CaseStudyResult, Check

NAME = "painleve"
TITLE = "Painlevé's rod: unique slip, unique detach, three solutions, no solution (Fig. 5-7)"
EQUATIONS = "105-121"

MASS = 1.0  # m [kg]
HALF_LENGTH = 0.25  # l [m] (the rod is 0.5 m long)
ZETA = 0.5
SLIP_SPEED = 1.0  # the tip slips at pdot_t = -SLIP_SPEED [m/s]
THETA_A_DEG = 45.0  # thetadot is chosen so that G_A = 0 at this angle
THETA_DOT = math.sqrt(GRAVITY / (HALF_LENGTH * math.sin(math.radians(THETA_A_DEG))))
DELTA_ENUM = 1e-4  # delta of the enumerated per-step problems [s]
DELTA_SIM = 1e-5  # delta of the simulated relaxed ODE [s]
ROLLOUT_DURATION = 0.01  # [s]
JAM_SPEED = 1e-4  # the jam ends when |pdot_t| falls below this fraction of SLIP_SPEED
PROBE_DT = 1e-9 * DELTA_SIM  # the probe step that reads the simulator's first force [s]
SOLVERS = ("default", "nsgs", "admm", "newton")
RESIDUAL_TOLERANCE = 1e-10
# one simulated point per region (theta_deg, mu)
REGION_POINTS = {
    "unique-slip": (30.0, 0.5),
    "unique-detach": (70.0, 0.5),
    "non-unique": (60.0, 2.0),
    "no-solution": (40.0, 2.5),
}
REGIONS = tuple(REGION_POINTS)
EXPECTED_SOLUTIONS = {"unique-slip": 1, "unique-detach": 1, "non-unique": 3, "no-solution": 1}
_STATE_KIND = {"open": "detach", "stick": "stick", "slip": "slip"}


# ---- the paper's closed forms (eq. 117-121)

def delassus(theta: float, m: float = MASS) -> np.ndarray:
    """A = J M^-1 J^T (eq. 117, with J of eq. 109 and M of eq. 108)."""
    s, c = math.sin(theta), math.cos(theta)
    J = np.array([[1.0, 0.0, HALF_LENGTH * s], [0.0, 1.0, -HALF_LENGTH * c]])
    Minv = np.diag([1.0 / m, 1.0 / m, 3.0 / (m * HALF_LENGTH**2)])
    return J @ Minv @ J.T


def r_a(theta: float, theta_dot: float, m: float = MASS) -> np.ndarray:
    """eq. 118: (m g/4) (3 s c, 4 - 3 c^2) - m l thetadot^2 (c, s)."""
    s, c = math.sin(theta), math.cos(theta)
    return (m * GRAVITY / 4.0) * np.array([3.0 * s * c, 4.0 - 3.0 * c * c]) \
        - m * HALF_LENGTH * theta_dot**2 * np.array([c, s])


def r_b(theta: float, m: float = MASS) -> np.ndarray:
    """eq. 119: A^-1 e_t."""
    return np.linalg.solve(delassus(theta, m), np.array([1.0, 0.0]))


def g_a(theta: float, theta_dot: float) -> float:
    """eq. 121: G_A = [0, 1] A r_a."""
    return float(delassus(theta)[1] @ r_a(theta, theta_dot))


def g_b(theta: float, mu: float) -> float:
    """eq. 120: G_B = [1, -mu] r_b."""
    return float(np.array([1.0, -mu]) @ r_b(theta))


def mu_painleve(theta: float) -> float:
    """The friction coefficient where G_B = 0 (eq. 120): (1 + 3 c^2) / (3 s c)."""
    s, c = math.sin(theta), math.cos(theta)
    return (1.0 + 3.0 * c * c) / (3.0 * s * c)


def rhs(theta: float, theta_dot: float, p_t_dot: float, delta: float, zeta: float = ZETA) -> np.ndarray:
    """b = A r (eq. 114-116) with p_n = pdot_n = 0: A r_a - (2 zeta pdot_t / delta) e_t."""
    return delassus(theta) @ r_a(theta, theta_dot) - (2.0 * zeta * p_t_dot / delta) * np.array([1.0, 0.0])


def region_of(ga: float, gb: float) -> str:
    if gb > 0:
        return "unique-slip" if ga > 0 else "unique-detach"
    return "no-solution" if ga > 0 else "non-unique"


# ---- every solution of the 2-row problem (eq. 65 / 114)

def enumerate_solutions(A: np.ndarray, b: np.ndarray, mu: float) -> list[tuple[str, np.ndarray]]:
    """All lambda with A lambda - b in -lim N_F^{U_eps}(lambda) for the planar cone F (eq. 112):

    - lambda = 0 (detach): the limit normal cone at the apex is the half-plane {w_n <= 0}
      (Fig. 2), so lambda = 0 solves iff b_n <= 0;
    - lambda in Int F (stick): A lambda = b;
    - lambda_t = sigma mu lambda_n, lambda_n > 0 (slip; sigma = +1 opposes pdot_t < 0): the limit
      normal cone is the half-line {(x, 0): sigma x >= 0}, so (A lambda - b)_n = 0 fixes lambda_n
      and sigma (A lambda - b)_t <= 0 must hold.

    These cases cover every lambda in F and each is a linear equation, so the list is complete."""
    out: list[tuple[str, np.ndarray]] = []
    if b[1] <= 0.0:
        out.append(("detach", np.zeros(2)))
    lam = np.linalg.solve(A, b)
    if lam[1] > 0.0 and abs(lam[0]) < mu * lam[1]:
        out.append(("stick", lam))
    for sigma, kind in ((1.0, "slip"), (-1.0, "slip-reversed")):
        d = np.array([sigma * mu, 1.0])
        denom = A[1] @ d
        if denom == 0.0:
            continue
        lam_n = b[1] / denom
        if lam_n <= 0.0:
            continue
        lam = lam_n * d
        if sigma * (A[0] @ lam - b[0]) <= 0.0:
            out.append((kind, lam))
    return out


def measure(A: np.ndarray, b: np.ndarray, mu: float, lam: np.ndarray) -> tuple[float, str]:
    """The package's yardstick at lam: relative natural-map residual of eq. 65 and the contact state."""
    problem = _core.ContactProblem(A, b, [_core.Constraint.planar_friction(mu)])
    m = _core.exact_law_measures(problem, lam)
    return float(m.relative_residual), str(m.states[0].name)


# ---- the rod in the simulator

def rod_model(m: float = MASS) -> pin.Model:
    """A planar joint in the world's vertical x-z plane (stiction.robots.PLANAR_ROTATION, as
    ``joint = "planar"`` scenes), a thin rod along the body x axis (inertia m l^2/3 about the
    joint axis, eq. 108) and a frame "tip" at (-l, 0, 0)."""
    from ..robots import PLANAR_ROTATION

    model = pin.Model()
    j = model.addJoint(0, pin.JointModelPlanar(), pin.SE3(PLANAR_ROTATION, np.zeros(3)), "rod_joint")
    inertia = m * HALF_LENGTH**2 / 3.0
    model.appendBodyToJoint(j, pin.Inertia(m, np.zeros(3), np.diag([0.0, inertia, inertia])), pin.SE3.Identity())
    body = model.addBodyFrame("rod", j, pin.SE3.Identity(), 0)
    model.addFrame(pin.Frame("tip", j, body, pin.SE3(np.eye(3), np.array([-HALF_LENGTH, 0.0, 0.0])),
                             pin.FrameType.OP_FRAME))
    return model


def rod_state(theta: float, theta_dot: float, p_t_dot: float) -> tuple[np.ndarray, np.ndarray]:
    """(q, v) of the planar joint with the tip on the ground (p_n = 0), pdot_n = 0 and the given
    pdot_t. q = (x, z, cos theta, sin theta); v = (vx, vy, omega) in the body frame."""
    s, c = math.sin(theta), math.cos(theta)
    q = np.array([0.0, HALF_LENGTH * s, c, s])
    qd_n = HALF_LENGTH * c * theta_dot  # pdot_n = qdot_n - l c thetadot = 0
    qd_t = p_t_dot - HALF_LENGTH * s * theta_dot  # pdot_t = qdot_t + l s thetadot
    R = np.array([[c, -s], [s, c]])
    v_body = R.T @ np.array([qd_t, qd_n])
    return q, np.array([v_body[0], v_body[1], theta_dot])


def rod_simulator(mu: float, delta: float = DELTA_SIM, dt: float | None = None) -> Simulator:
    """The rod with one planar contact (rows t, n) at its tip, in the relaxed ODE (rk4)."""
    theta0 = math.radians(45.0)
    q0, _ = rod_state(theta0, 0.0, 0.0)
    scene = scene_from_model(rod_model(), q0=q0, name="painleve-rod", spheres=[("tip", 0.0)], mu=mu)
    scene.contacts[0].model = _core.ContactModel.planar
    return Simulator(scene, mode="rk4", delta=delta, dt=delta / 20.0 if dt is None else dt)


def simulator_problem(sim: Simulator, theta: float, theta_dot: float, p_t_dot: float,
                      delta: float) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's own A and b (eq. 22, 27) at the rod state: _core.build_contact_problem."""
    q, v = rod_state(theta, theta_dot, p_t_dot)
    _core.build_contact_problem(sim.model, sim.data, q, v, delta, ZETA)
    if list(sim.data.active) != [0]:
        raise RuntimeError(f"the tip contact is not active at theta = {math.degrees(theta):g} deg")
    return np.array(sim.data.A, dtype=float), np.array(sim.data.b, dtype=float)


def _closest(lam: np.ndarray, solutions: list[tuple[str, np.ndarray]], scale: float) -> tuple[str, float]:
    best, dist = "none", math.inf
    for kind, s in solutions:
        d = float(np.linalg.norm(lam - s)) / max(float(np.linalg.norm(s)), scale)
        if d < dist:
            best, dist = kind, d
    return best, dist


def _simulate(region: str, theta_deg: float, mu: float) -> dict:
    theta = math.radians(theta_deg)
    ga, gb = g_a(theta, THETA_DOT), g_b(theta, mu)
    q0, v0 = rod_state(theta, THETA_DOT, -SLIP_SPEED)
    # the problem of the first solve and all its solutions
    probe = rod_simulator(mu, DELTA_SIM, dt=PROBE_DT)
    A, b = simulator_problem(probe, theta, THETA_DOT, -SLIP_SPEED, DELTA_SIM)
    sols = enumerate_solutions(A, b, mu)
    scale = float(np.linalg.norm(np.linalg.solve(A, b)))
    # the simulator's pick: one probe step of PROBE_DT from the cold start every first step has
    # (the force it records is the last RK4 stage's, PROBE_DT later: ~PROBE_DT/delta relative apart)
    probe.set_state(q=q0, v=v0, t=0.0)
    probe.step()
    slots = np.asarray(probe.data.candidate_lambda, dtype=float).reshape(3, -1)  # (t1, t2, n) per contact
    lam_sim = slots[[0, 2], 0]  # planar contact: (t, n)
    picked, dist = _closest(lam_sim, sols, scale)
    picked_by = {}
    problem = _core.ContactProblem(A, b, [_core.Constraint.planar_friction(mu)])
    for name in SOLVERS:
        for start in (None, "proxqp"):
            res = solve(problem, name, tol=1e-10, warm_start=start)
            key = name if start is None else f"{name}+{start}"
            picked_by[key] = _closest(np.asarray(res.lam), sols, scale)[0] if res.converged else \
                f"not converged ({res.message})"
    # what follows
    sim = rod_simulator(mu, DELTA_SIM)
    sim.set_state(q=q0, v=v0, t=0.0)
    traj = sim.rollout(ROLLOUT_DURATION)
    states = traj.states[1:, 0]
    names = {0: "open", 1: "stick", 2: "slip", 3: "closed"}
    fractions = {names[k]: float(np.mean(states == k)) for k in names}
    lam_t, lam_n = traj.lam[1:, 0, 0], traj.lam[1:, 0, 2]  # (record 0: no step, NaN)
    # impulse of the contact force from the centre's momentum: m (vdot_com) = lambda + m g
    vcom = np.array([_world_velocity(q, v) for q, v in zip(traj.q, traj.v)])
    T = traj.t[-1] - traj.t[0]
    impulse = MASS * (vcom[-1] - vcom[0]) + np.array([0.0, MASS * GRAVITY * T])
    rollout = {
        "duration": float(T), "steps": int(len(traj.t) - 1), "all_converged": bool(traj.converged[1:].all()),
        "state_fractions": fractions,
        "final_gap": float(traj.gaps[-1, 0]), "final_slip_velocity": float(traj.contact_velocity[-1, 0, 0]),
        "max_force": float(np.max(np.hypot(lam_t, lam_n))), "impulse": impulse.tolist(),
        "min_normal_velocity": float(traj.contact_velocity[1:, 0, 2].min()),
        "max_normal_velocity": float(traj.contact_velocity[1:, 0, 2].max()),
    }
    if region == "no-solution":
        rollout.update(_jam(traj, theta, vcom))
    return {"type": "simulation", "theta_deg": theta_deg, "mu": mu, "region": region, "G_A": ga, "G_B": gb,
            "delta": DELTA_SIM, "solutions": [{"kind": k, "lambda": s} for k, s in sols], "picked": picked,
            "picked_lambda": lam_sim, "picked_distance": dist, "picked_by": picked_by, "rollout": rollout}


def _jam(traj, theta: float, vcom: np.ndarray) -> dict:
    """The jam (tangential impact) of the no-solution region: the stick phase the rollout starts
    with. While sticking, A lambda = b (eq. 65 with lambda in Int F), whose tangential row is
    pddot_t + pdot_t / delta = 0 (zeta = 1/2): pdot_t decays like exp(-t / delta), with a force
    of order |pdot_t| / delta. Integrated, A P = |pdot_t0| (1 - pdot_t(t_s) / pdot_t0) e_t +
    (regular part) t_s, i.e. the impulse P = |pdot_t0| (1 - ...) r_b + r_a t_s (eq. 118-119,
    at the initial state; the rod turns by thetadot t_s meanwhile, an O(delta) error)."""
    states = traj.states[1:, 0]
    k = 0
    while k < len(states) and states[k] == 1:  # the leading run of stick records
        k += 1
    if k < 3:
        return {"stick_time": 0.0}
    idx = np.arange(1, k + 1)  # records 1..k stick
    t = traj.t[idx] - traj.t[0]
    slip = traj.contact_velocity[idx, 0, 0]
    rate = -np.polyfit(t, np.log(np.abs(slip)), 1)[0]
    t_s = float(t[-1])
    P = MASS * (vcom[k] - vcom[0]) + np.array([0.0, MASS * GRAVITY * t_s])
    fraction = 1.0 - slip[-1] / -SLIP_SPEED
    predicted = SLIP_SPEED * fraction * r_b(theta) + r_a(theta, THETA_DOT) * t_s
    after = traj.states[k + 1:, 0]
    return {"stick_time": t_s, "slip_decay_rate": float(rate), "slip_velocity_at_end": float(slip[-1]),
            "stick_impulse": P.tolist(), "predicted_stick_impulse": predicted.tolist(),
            "rigid_impulse": (SLIP_SPEED * r_b(theta)).tolist(),
            "state_after": {0: "open", 1: "stick", 2: "slip", 3: "closed"}[int(after[0])] if len(after) else None,
            "max_force": float(np.max(np.hypot(traj.lam[idx, 0, 0], traj.lam[idx, 0, 2])))}


def _world_velocity(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(qdot_t, qdot_n) of the rod's centre from the planar joint's body-frame velocity."""
    c, s = q[2], q[3]
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


# ---- the case study

def run(quick: bool = False) -> CaseStudyResult:
    if quick:
        thetas = np.arange(4.0, 90.0, 8.0)  # not 45 deg, where G_A = 0 (a boundary)
        mus = np.round(np.arange(0.25, 3.001, 0.25), 10)
    else:
        thetas = np.arange(2.0, 90.0, 2.0)  # not 45 deg, where G_A = 0 (a boundary)
        mus = np.round(np.arange(0.05, 3.001, 0.05), 10)
    sim = rod_simulator(1.0, DELTA_ENUM)  # A and b do not depend on mu (mu > 0: 2 rows)
    points: list[dict] = []
    err_A = err_b = err_ga = err_gb = 0.0
    worst_residual = 0.0
    count_mismatch = kind_mismatch = 0
    n_region = {r: 0 for r in REGIONS}
    for theta_deg in thetas:
        theta = math.radians(theta_deg)
        A_sim, b_sim = simulator_problem(sim, theta, THETA_DOT, -SLIP_SPEED, DELTA_ENUM)
        A = delassus(theta)
        b = rhs(theta, THETA_DOT, -SLIP_SPEED, DELTA_ENUM)
        err_A = max(err_A, float(np.abs(A_sim - A).max() / np.abs(A).max()))
        err_b = max(err_b, float(np.abs(b_sim - b).max() / np.abs(b).max()))
        ga = g_a(theta, THETA_DOT)
        ga_sim = float(b_sim[1])  # p_n = pdot_n = 0: b_n = [0, 1] A r_a = G_A
        err_ga = max(err_ga, abs(ga_sim - ga) / GRAVITY)
        rb_sim = np.linalg.solve(A_sim, np.array([1.0, 0.0]))
        for mu in mus:
            gb = g_b(theta, mu)
            gb_sim = float(rb_sim[0] - mu * rb_sim[1])
            err_gb = max(err_gb, abs(gb_sim - gb) / (MASS * (1.0 + mu)))
            region = region_of(ga, gb)
            n_region[region] += 1
            sols = []
            for kind, lam in enumerate_solutions(A, b, mu):
                res, state = measure(A, b, mu, lam)
                worst_residual = max(worst_residual, res)
                kind_mismatch += _STATE_KIND.get(state) != kind
                sols.append({"kind": kind, "lambda": lam, "residual": res, "state": state})
            count_mismatch += len(sols) != EXPECTED_SOLUTIONS[region]
            points.append({"type": "grid", "theta_deg": float(theta_deg), "mu": float(mu), "region": region,
                           "G_A": ga, "G_B": gb, "n_solutions": len(sols), "solutions": sols})

    # the smallest mu with G_B < 0, from the simulator's A on a fine theta scan (closed form: 4/3)
    fine = np.radians(np.linspace(30.0, 85.0, 56 if quick else 221))
    mu_b = []
    for th in fine:
        A_sim, _ = simulator_problem(sim, th, 0.0, 0.0, DELTA_ENUM)
        rb = np.linalg.solve(A_sim, np.array([1.0, 0.0]))
        mu_b.append(rb[0] / rb[1])
    k = int(np.argmin(mu_b))
    lo, hi = fine[max(k - 1, 0)], fine[min(k + 1, len(fine) - 1)]
    from scipy.optimize import minimize_scalar

    def mu_b_sim(th):
        A_sim, _ = simulator_problem(sim, th, 0.0, 0.0, DELTA_ENUM)
        rb = np.linalg.solve(A_sim, np.array([1.0, 0.0]))
        return rb[0] / rb[1]

    best = minimize_scalar(mu_b_sim, bounds=(lo, hi), method="bounded", options={"xatol": 1e-10})

    sims = [_simulate(region, *REGION_POINTS[region]) for region in REGIONS]
    points += sims
    by = {p["region"]: p for p in sims}

    checks = [
        Check("simulator Delassus operator vs eq. 117 (max relative entry difference)", err_A, 0.0, 1e-12),
        Check("simulator right-hand side b vs eq. 116 at delta (max relative difference)", err_b, 0.0, 1e-12),
        # b_n carries (2 zeta / delta) x the rounding of pdot_n = 0 (~1e4 x 1e-16 at delta = 1e-4)
        Check("G_A from the simulator (b_n) vs eq. 121 (max difference / g)", err_ga, 0.0, 1e-11),
        Check("G_B from the simulator's A vs eq. 120 (max difference / (m (1 + mu)))", err_gb, 0.0, 1e-12),
        Check("smallest mu with G_B < 0 (simulator's A, minimised over theta)", float(best.fun), 4.0 / 3.0, 1e-9),
        Check("theta of the smallest such mu [deg] (closed form atan 2)", math.degrees(best.x),
              math.degrees(math.atan(2.0)), 1e-3),
        Check("every enumerated solution satisfies eq. 65 (max relative residual, exact_law_measures)",
              worst_residual, RESIDUAL_TOLERANCE, 0.0, "<="),
        Check("grid points whose number of solutions is not the region's (1 slip, 1 detach, 3, 1 stick)",
              count_mismatch, 0, 0),
        Check("solutions whose kind differs from the package's contact state", kind_mismatch, 0, 0),
        Check("grid points in the non-unique region (G_A < 0, G_B < 0)", n_region["non-unique"], 1, 0, ">="),
        Check("grid points in the no-solution region (G_A > 0, G_B < 0)", n_region["no-solution"], 1, 0, ">="),
        Check("unique-slip: the simulator's first force is the slip solution (relative distance)",
              by["unique-slip"]["picked_distance"] if by["unique-slip"]["picked"] == "slip" else math.inf,
              0.0, 1e-7),
        Check("unique-detach: the simulator's first force is lambda = 0 (relative distance)",
              by["unique-detach"]["picked_distance"] if by["unique-detach"]["picked"] == "detach" else math.inf,
              0.0, 1e-7),
        Check("no-solution: the simulator's first force is the stick solution r (relative distance)",
              by["no-solution"]["picked_distance"] if by["no-solution"]["picked"] == "stick" else math.inf,
              0.0, 1e-7),
        Check("non-unique: the simulator's first force is one of the three solutions (relative distance)",
              by["non-unique"]["picked_distance"], 0.0, 1e-7),
    ]
    jam = by["no-solution"]["rollout"]
    if jam["stick_time"] > 0:
        measured, predicted = np.array(jam["stick_impulse"]), np.array(jam["predicted_stick_impulse"])
        impulse_error = float(np.linalg.norm(measured - predicted) / np.linalg.norm(predicted))
        rate = jam["slip_decay_rate"] * DELTA_SIM
    else:
        impulse_error = rate = math.inf
    checks += [
        Check("no-solution: the rod jams: stick phase at the start [s]", jam["stick_time"], 2 * DELTA_SIM, 0.0, ">="),
        Check("no-solution: slip velocity decay rate while jammed x delta (stick: pddot_t + pdot_t/delta = 0)",
              rate, 1.0, 1e-6),
        # the prediction holds the configuration of t = 0: the rod turns by thetadot t_s ~ 6e-4 rad
        # during the jam (error O(delta): 5.3e-3 at delta = 1e-4, 7.6e-4 at 1e-5)
        Check("no-solution: jam impulse vs |pdot_t| r_b (1 - e^(-t/delta)) + r_a t (eq. 118-119; relative)",
              impulse_error, 0.0, 2e-3),
        Check("every rollout converged (all steps, all regions)",
              float(all(p["rollout"]["all_converged"] for p in sims)), 1.0, 0.0),
    ]
    nonunique = by["non-unique"]
    notes = [
        f"thetadot = {THETA_DOT:.6g} rad/s (G_A = 0 at theta = {THETA_A_DEG:g} deg), pdot_t = {-SLIP_SPEED:g} m/s, "
        f"m = {MASS:g} kg, l = {HALF_LENGTH:g} m; enumerated problems at delta = {DELTA_ENUM:g} s, "
        f"simulation at delta = {DELTA_SIM:g} s (rk4, dt = delta/20).",
        "eq. 117 prints A = J^T M^-1 J; the 2x2 Delassus operator is J M^-1 J^T (the simulator's matches it).",
        f"non-unique point (theta {nonunique['theta_deg']:g} deg, mu {nonunique['mu']:g}): the simulator's cold "
        f"first solve picks '{nonunique['picked']}'; stand-alone solvers: "
        + ", ".join(f"{k} -> {v}" for k, v in nonunique["picked_by"].items()) + ".",
        "grid points per region: " + ", ".join(f"{r} {n}" for r, n in n_region.items()) + ".",
    ]
    return CaseStudyResult(NAME, TITLE, EQUATIONS, checks, points, notes)


def plot(result: CaseStudyResult, path) -> None:
    """The regions in the (theta, mu) plane at the case study's thetadot, the boundary G_B = 0
    (eq. 120) and G_A = 0 (eq. 121), and the simulated points with the solution the solver picked."""
    from .._optional import require

    matplotlib = require("matplotlib", "plot", "plots")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    grid = [p for p in result.points if p.get("type") == "grid"]
    sims = [p for p in result.points if p.get("type") == "simulation"]
    thetas = sorted({p["theta_deg"] for p in grid})
    mus = sorted({p["mu"] for p in grid})
    colors = {"unique-slip": "#9ecae1", "unique-detach": "#c7e9c0", "non-unique": "#fdae6b", "no-solution": "#bcbddc"}
    index = {r: k for k, r in enumerate(REGIONS)}
    Z = np.full((len(mus), len(thetas)), np.nan)
    for p in grid:
        Z[mus.index(p["mu"]), thetas.index(p["theta_deg"])] = index[p["region"]]
    fig, ax = plt.subplots(figsize=(8.5, 7))
    dth = (thetas[1] - thetas[0]) / 2 if len(thetas) > 1 else 1.0
    dmu = (mus[1] - mus[0]) / 2 if len(mus) > 1 else 0.1
    ax.imshow(Z, origin="lower", aspect="auto", interpolation="nearest",
              extent=(thetas[0] - dth, thetas[-1] + dth, mus[0] - dmu, mus[-1] + dmu),
              cmap=ListedColormap([colors[r] for r in REGIONS]), vmin=-0.5, vmax=len(REGIONS) - 0.5)
    th = np.linspace(1.0, 89.0, 500)
    mu_b = np.array([mu_painleve(math.radians(t)) for t in th])
    ax.plot(th, mu_b, "k-", lw=1.8, label="G_B = 0 (eq. 120): mu = (1 + 3 cos²θ) / (3 sin θ cos θ)")
    ax.axvline(THETA_A_DEG, color="k", ls="--", lw=1.2, label=f"G_A = 0 (eq. 121) at θ̇ = {THETA_DOT:.3g} rad/s")
    ax.plot([math.degrees(math.atan(2.0))], [4.0 / 3.0], "k.", ms=8)
    ax.annotate("μ = 4/3 at tan θ = 2", (math.degrees(math.atan(2.0)), 4.0 / 3.0), xytext=(6, -14),
                textcoords="offset points", fontsize=8)
    for p in sims:
        ax.plot(p["theta_deg"], p["mu"], "o", mfc="white", mec="k", ms=8)
        ax.annotate(f"picked: {p['picked']}", (p["theta_deg"], p["mu"]), xytext=(7, 4), textcoords="offset points",
                    fontsize=8)
    ax.set_xlim(thetas[0] - dth, thetas[-1] + dth)
    ax.set_ylim(mus[0] - dmu, mus[-1] + dmu)
    ax.set_xlabel("θ [deg] (rod angle to the ground)")
    ax.set_ylabel("μ")
    ax.set_title(f"Painlevé's rod (§5.3): solutions of eq. 114 with the tip slipping at {SLIP_SPEED:g} m/s",
                 fontsize=10)
    handles: list = [Patch(color=colors[r], label=f"{r} ({EXPECTED_SOLUTIONS[r]} solution"
                           f"{'s' if EXPECTED_SOLUTIONS[r] > 1 else ''})") for r in REGIONS]
    handles += ax.get_legend_handles_labels()[0]
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.11), ncol=2, fontsize=8, frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
