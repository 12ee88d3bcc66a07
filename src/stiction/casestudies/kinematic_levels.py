"""§4.3 (eq. 64-69): as delta -> 0 the relaxed lambda reaches the position-, velocity- and
acceleration-level solutions, each in its own state.

One frictional point contact (the spatial cone, eq. 54-55): the end of a 1 kg, 0.5 m rod (free
flyer, robots/rod.urdf) on the ground, the rod rising at 40 deg and turned 30 deg about the vertical
so that A = J M^-1 J^T (eq. 22) couples all three rows. At a chosen state (q, q') the package builds
the contact problem of eq. 65 (``build_contact_problem``: A of eq. 22, b(delta) of eq. 27) for a
decreasing sequence of delta, and ``stiction.solve`` returns lambda(delta). b(delta) = b_0 -
(2 zeta/delta) J q' - [0; Psi_p]/delta^2 with b_0 = J M^-1 Phi - J' q' (the acceleration-level right
side); the references use A and b_0 computed here independently (pinocchio's J, M, nle and the
contact point's classical acceleration) and closed forms or scipy, not the package's solver.

- **position level** (Psi_p > 0, eq. 67): the end 1 mm above the ground, approaching at 0.3 m/s.
  Eq. 67 gives lambda = 0. The relaxed lambda is 0 exactly when b_n(delta) <= 0 (the singular-metric
  normal cone at 0 is the half-space z <= 0, Fig. 2), i.e. for delta below the positive root delta*
  of b0_n delta^2 - 2 zeta v_n delta - Psi_p = 0: convergence is reached at a finite delta, and above
  delta* the relaxed contact already pushes before touching.
- **velocity level** (Psi_p = 0, J q' != 0, eq. 68):
  separating (v_n > 0): eq. 68 gives lambda = 0, reached for delta <= delta* = 2 zeta v_n / b0_n;
  sliding (v_n = 0, v_t != 0): eq. 68 makes lambda_t oppose v_t on the cone's edge; the normal row
  has Psi_p = 0 and v_n = 0, so it is at the acceleration level (the first non-zero entry of the
  lexicographic triple, eq. 61-62, decides each row): lambda* = lambda_n* (-mu v_t/|v_t|, 1) with
  lambda_n* = b0_n / (A_nn - mu A_nt v_t/|v_t|). The tangential rows see (2 zeta/delta) v_t + O(1),
  so lambda(delta) -> lambda* at order 1 in delta (measured).
- **acceleration level** (Psi_p = 0, J q' = 0, eq. 69): the rod turning about its resting end.
  b(delta) = b_0 for every delta (the delta terms vanish), so lambda(delta) is the acceleration-level
  solution of A lambda - b_0 in -N(lambda) for every delta: sticking (mu = 1, A^-1 b_0 inside the
  cone) and impending slip (mu = 0.2, found with scipy's fsolve on the cone's edge). What departs is
  the state's round-off, amplified by 1/delta^2 (the gap is set to exactly 0 in the package's
  arithmetic to keep it out).
"""
from __future__ import annotations

import math

import numpy as np

from . import CaseStudyResult, Check

NAME = "kinematic-levels"
TITLE = "Position-, velocity- and acceleration-level limits of the relaxed contact as delta -> 0 (§4.3)"
EQUATIONS = "64-69"

ALPHA = math.radians(40.0)  # the rod's rise
YAW = math.radians(30.0)
END = np.array([-0.25, 0.0, 0.0])  # the contact point in the rod's frame
ZETA = 0.5
SOLVE_TOL = 1e-12

# tolerances (docs/casestudies/kinematic-levels.md)
TOL_BUILD = 1e-9  # package A, b(delta) vs the independent ones, relative
TOL_THRESHOLD = 1e-6  # delta* by bisection on the solver's answer vs the closed-form root, relative
TOL_RATE = 0.05
TOL_SLIDING = 1e-3  # relative error at the smallest delta (rate 1: ~2.5 delta / 1 s)
TOL_ACCEL = 1e-8  # relative, every delta: the solver's tolerance with round-off of the state


def rod_model():
    import pinocchio as pin

    from ..resources import robots_dir

    return pin.buildModelFromUrdf(str(robots_dir() / "rod.urdf"), pin.JointModelFreeFlyer())


def simulator(model, mu: float):
    """The package's simulator of the rod with the point contact at its end (mu: spatial cone)."""
    from ..scene import scene_from_model
    from ..simulator import Simulator

    scene = scene_from_model(model, spheres=[("rod", 0.0, tuple(END))], mu=mu, place_on_ground=False,
                             name="rod-end-contact")
    return Simulator(scene, mode="rk4", delta=1e-2, zeta=ZETA)


def pose(height: float):
    """q with the rod's end at (0, 0, height); and the rotation."""
    import pinocchio as pin

    R = pin.utils.rotate("z", YAW) @ pin.utils.rotate("y", -ALPHA)  # the end (-x) is the low one
    p = np.array([0.0, 0.0, height]) - R @ END
    return np.concatenate([p, pin.Quaternion(R).coeffs()]), R


def velocity(R, v_end, omega) -> np.ndarray:
    """The free flyer's velocity (body frame) giving the end the world velocity v_end while the
    rod turns at omega (world)."""
    rw = R @ END
    v_origin = np.asarray(v_end, dtype=float) - np.cross(omega, rw)
    return np.concatenate([R.T @ v_origin, R.T @ np.asarray(omega, dtype=float)])


def reference_terms(model, q, v):
    """Independently of the package: A = J M^-1 J^T (eq. 22), b_0 = J M^-1 Phi - J' q' (eq. 27
    without its delta terms), J q' and Psi_p (the end's height), rows (t1, t2, n) = (x, y, z)."""
    import pinocchio as pin

    d = model.createData()
    pin.forwardKinematics(model, d, q, v, np.zeros(model.nv))
    pin.computeJointJacobians(model, d, q)
    j = 1
    R = d.oMi[j].rotation
    rw = R @ END
    Jj = pin.getJointJacobian(model, d, j, pin.LOCAL_WORLD_ALIGNED)
    J = Jj[:3] - pin.skew(rw) @ Jj[3:]
    w = R @ d.v[j].angular
    v_point = R @ d.v[j].linear + np.cross(w, rw)
    Jdot_v = R @ d.a[j].linear + np.cross(R @ d.a[j].angular, rw) + np.cross(w, v_point)
    M = pin.crba(model, d, q)
    M = np.triu(M) + np.triu(M, 1).T
    nle = pin.nonLinearEffects(model, d, q, v)
    A = J @ np.linalg.solve(M, J.T)
    b0 = J @ np.linalg.solve(M, nle) - Jdot_v
    return A, b0, J @ v, float(d.oMi[j].act(END)[2])


class Levels:
    """lambda(delta) from the package at a state: build_contact_problem + stiction.solve."""

    def __init__(self, model, mu: float):
        from .. import _core

        self.mu = mu
        self.sim = simulator(model, mu)
        self.data = _core.SimulatorData(self.sim.model)
        self._core = _core

    def exact_contact(self, q, v):
        """q with its height nudged until the package's gap is exactly 0.0 (round-off of the pose
        would otherwise enter b as Psi/delta^2)."""
        q = np.array(q, dtype=float)
        for _ in range(8):
            self._core.build_contact_problem(self.sim.model, self.data, q, v, 1.0, ZETA)
            gap = float(np.asarray(self.data.gaps)[0])
            if gap == 0.0:
                break
            q[2] -= gap
        return q

    def build(self, q, v, delta: float, zeta: float = ZETA):
        self._core.build_contact_problem(self.sim.model, self.data, q, v, delta, zeta)
        return np.asarray(self.data.A).copy(), np.asarray(self.data.b).copy(), float(np.asarray(self.data.gaps)[0])

    def solve(self, q, v, delta: float, zeta: float = ZETA):
        import stiction

        A, b, _ = self.build(q, v, delta, zeta)
        if b.size != 3:
            raise RuntimeError(f"the contact is not in the problem at delta = {delta} (rows: {b.size})")
        res = stiction.solve(stiction.spatial_problem(A, b, self.mu), tol=SOLVE_TOL)
        return np.asarray(res.lam).copy(), bool(res.converged)


def threshold(levels: Levels, q, v, lo: float, hi: float, zeta: float = ZETA) -> float:
    """The delta where the package's lambda turns from 0 (below) to a force (above), by bisection
    in log delta between lo (lambda = 0) and hi (lambda != 0)."""
    if levels.solve(q, v, lo, zeta)[0].any() or not levels.solve(q, v, hi, zeta)[0].any():
        raise RuntimeError(f"threshold: lambda is not 0 at delta = {lo:g} and a force at {hi:g}")
    for _ in range(100):
        mid = math.sqrt(lo * hi)
        if levels.solve(q, v, mid, zeta)[0].any():
            hi = mid
        else:
            lo = mid
        if hi / lo - 1.0 < 1e-13:
            break
    return math.sqrt(lo * hi)


def positive_root(a: float, b: float, c: float) -> float:
    """The positive root of a x^2 + b x + c = 0 (a > 0, c <= 0), without cancellation."""
    disc = math.sqrt(b * b - 4.0 * a * c)
    return (-b + disc) / (2.0 * a) if b <= 0 else (-2.0 * c) / (b + disc)


def acceleration_reference(A, b0, mu: float):
    """Eq. 69 with the singular metric: A lambda - b_0 in -lim N(lambda). Inside the cone:
    A^-1 b_0. Otherwise on the edge, lambda = l_n (mu cos p, mu sin p, 1) with the normal row
    (A lambda - b_0)_n = 0 and the tangential part of A lambda - b_0 opposite to lambda_t (scipy)."""
    from scipy.optimize import fsolve

    inside = np.linalg.solve(A, b0)
    if np.hypot(inside[0], inside[1]) <= mu * inside[2]:
        return inside, "stick"

    def edge(x):
        ln, p = x
        d = np.array([math.cos(p), math.sin(p)])
        w = A @ (ln * np.array([mu * d[0], mu * d[1], 1.0])) - b0
        return [w[2], w[0] * d[1] - w[1] * d[0]]

    ln, p = fsolve(edge, [inside[2], math.atan2(inside[1], inside[0])], xtol=1e-15)
    lam = ln * np.array([mu * math.cos(p), mu * math.sin(p), 1.0])
    w = A @ lam - b0
    if not (ln > 0 and w[:2] @ lam[:2] < 0 and abs(w[2]) < 1e-10 * np.abs(b0).max()):
        raise RuntimeError("acceleration-level reference: no edge solution found")
    return lam, "slip"


def run(quick: bool = False) -> CaseStudyResult:
    model = rod_model()
    deltas = 10.0 ** -np.arange(1.0, 5.0) if quick else 10.0 ** -np.arange(1.0, 5.25, 0.25)
    zetas_sliding = (ZETA,) if quick else (0.25, ZETA, 1.0)
    points, checks, build_dev, unconverged = [], [], 0.0, 0

    def sweep(level, levels, q, v, reference, zeta=ZETA, **extra):
        nonlocal build_dev, unconverged
        A_ref, b0, Jv, psi = reference_terms(model, q, v)
        out = []
        for delta in deltas:
            A, b, _ = levels.build(q, v, delta, zeta)
            b_ref = b0 - (2.0 * zeta / delta) * Jv - np.array([0.0, 0.0, psi]) / delta**2
            build_dev = max(build_dev, np.abs(A - A_ref).max() / np.abs(A_ref).max(),
                            np.abs(b - b_ref).max() / np.abs(b_ref).max())
            lam, converged = levels.solve(q, v, delta, zeta)
            unconverged += not converged
            scale = max(np.linalg.norm(reference), 1.0)  # lambda* = 0: absolute, in N
            err = float(np.linalg.norm(lam - reference) / scale)
            points.append({"level": level, "delta": float(delta), "zeta": zeta, "lam": lam,
                           "reference": np.asarray(reference, dtype=float), "error": err, **extra})
            out.append(err)
        return np.array(out)

    # position level: Psi_p = 1 mm, approaching
    lv = Levels(model, mu=0.5)
    q, R = pose(1e-3)
    v = velocity(R, [0.2, 0.1, -0.3], [0.0, 0.4, 0.0])
    _, b0, Jv, psi = reference_terms(model, q, v)
    d_star = positive_root(b0[2], -2.0 * ZETA * Jv[2], -psi)
    sweep("position", lv, q, v, np.zeros(3), delta_star=d_star)
    below = [p for p in points if p["level"] == "position" and p["delta"] < d_star]
    above = [p for p in points if p["level"] == "position" and p["delta"] > d_star]
    d_meas = threshold(lv, q, v, d_star / 10.0, d_star * 10.0)
    checks += [
        Check(f"eq. 67 (Psi_p = 1 mm, v_n = -0.3 m/s): max |lambda| (N) over the {len(below)} delta below delta*",
              max(np.linalg.norm(p["lam"]) for p in below), 0.0, 0.0),
        Check("eq. 67: delta* where lambda turns 0 (bisection on the solver) vs root of b_n(delta) = 0, relative",
              d_meas / d_star, 1.0, TOL_THRESHOLD),
    ]
    pos_extra = (d_star, d_meas, min(np.linalg.norm(p["lam"]) for p in above) if above else math.nan)

    # velocity level, separating: Psi_p = 0, v_n = +0.05 m/s
    q, R = pose(0.0)
    q = lv.exact_contact(q, np.zeros(model.nv))
    v = velocity(R, [0.2, 0.1, 0.05], [0.0, 0.4, 0.0])
    _, b0, Jv, psi = reference_terms(model, q, v)
    d_sep = 2.0 * ZETA * Jv[2] / b0[2]
    sweep("velocity-separating", lv, q, v, np.zeros(3), delta_star=d_sep)
    below = [p for p in points if p["level"] == "velocity-separating" and p["delta"] < d_sep]
    d_meas_sep = threshold(lv, q, v, d_sep / 10.0, d_sep * 10.0)
    checks += [
        Check(f"eq. 68 (Psi_p = 0, v_n = +0.05 m/s): max |lambda| (N) over the {len(below)} delta below delta*",
              max(np.linalg.norm(p["lam"]) for p in below), 0.0, 0.0),
        Check("eq. 68: delta* = 2 zeta v_n / b0_n vs bisection on the solver, relative", d_meas_sep / d_sep, 1.0,
              TOL_THRESHOLD),
    ]

    # velocity level, sliding: Psi_p = 0, v_n = 0, v_t at 100 deg, the rod spinning about z
    mu = 0.3
    ls = Levels(model, mu=mu)
    q, R = pose(0.0)
    q = ls.exact_contact(q, np.zeros(model.nv))
    phi = math.radians(100.0)
    v = velocity(R, [0.5 * math.cos(phi), 0.5 * math.sin(phi), 0.0], [0.0, 0.0, 1.0])
    A0, b0, Jv, _ = reference_terms(model, q, v)
    vt = Jv[:2] / np.linalg.norm(Jv[:2])
    ln = b0[2] / (A0[2, 2] - mu * A0[2, :2] @ vt)
    sliding_ref = ln * np.array([-mu * vt[0], -mu * vt[1], 1.0])
    rates, finals = {}, {}
    for zeta in zetas_sliding:
        errs = sweep("velocity-sliding", ls, q, v, sliding_ref, zeta=zeta)
        fit = deltas <= 1e-2 + 1e-15
        rates[zeta] = float(np.polyfit(np.log(deltas[fit]), np.log(errs[fit]), 1)[0])
        finals[zeta] = float(errs[-1])
    checks += [
        Check(f"eq. 68-69 sliding (v_t = 0.5 m/s, mu = {mu}): convergence order in delta of |lambda - lambda*| "
              f"(delta <= 1e-2, worst over zeta {', '.join(f'{z:g}' for z in zetas_sliding)})",
              min(rates.values(), key=lambda r: -abs(r - 1.0)), 1.0, TOL_RATE),
        Check(f"eq. 68-69 sliding: |lambda - lambda*| / |lambda*| at delta = {deltas[-1]:.1e}, worst over zeta",
              max(finals.values()), TOL_SLIDING, 0.0, "<="),
    ]

    # acceleration level: Psi_p = 0, J q' = 0 (turning about the resting end)
    for mu, label in ((1.0, "acceleration-stick"), (0.2, "acceleration-slip")):
        la = Levels(model, mu=mu)
        q, R = pose(0.0)
        q = la.exact_contact(q, np.zeros(model.nv))
        v = velocity(R, [0.0, 0.0, 0.0], [0.3, -0.5, 0.8])
        A0, b0, Jv, _ = reference_terms(model, q, v)
        ref, kind = acceleration_reference(A0, b0, mu)
        errs = sweep(label, la, q, v, ref, mode=kind, state_roundoff_Jv=float(np.abs(Jv).max()))
        checks.append(Check(f"eq. 69 ({kind}, mu = {mu}): max over {len(deltas)} delta of |lambda - lambda_acc| / "
                            "|lambda_acc| (b(delta) = b_0 for every delta)", float(errs.max()), TOL_ACCEL, 0.0, "<="))
    checks += [
        Check("eq. 22, 27: package A, b(delta) vs the independent ones, worst relative difference", build_dev,
              TOL_BUILD, 0.0, "<="),
        Check("solves that did not converge", unconverged, 0, 0),
    ]
    notes = [
        f"position level: delta* = {pos_extra[0]:.6g} s (closed form), {pos_extra[1]:.6g} s (bisection); above it "
        f"the relaxed contact pushes before touching (smallest |lambda| above: {pos_extra[2]:.3g} N)",
        f"velocity-separating: delta* = {d_sep:.6g} s",
        "sliding orders: " + ", ".join(f"zeta {z:g}: {r:.3f}" for z, r in rates.items()),
        "errors are relative to |lambda_ref| (absolute in N where lambda_ref = 0)",
    ]
    return CaseStudyResult(NAME, TITLE, EQUATIONS, checks, points, notes)


def plot(result: CaseStudyResult, path) -> None:
    """(a) |lambda(delta) - lambda_ref| / |lambda_ref| vs delta (sliding: order 1; acceleration
    level: round-off for every delta); (b) |lambda(delta)| vs delta/delta* for the position-level and
    separating states (0 below delta*)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12.0, 4.8))
    styles = {"acceleration-stick": ("C2", "^"), "acceleration-slip": ("C4", "v")}
    sliding = [p for p in result.points if p["level"] == "velocity-sliding"]
    zetas = sorted({p["zeta"] for p in sliding})
    for i, z in enumerate(zetas):
        pts = [p for p in sliding if p["zeta"] == z]
        ax.loglog([p["delta"] for p in pts], [p["error"] for p in pts], "o-", color=plt.cm.autumn(0.7 * i / max(1, len(zetas) - 1)),
                  ms=4, label=f"velocity level, sliding (eq. 68-69), ζ = {z:g}")
    for level, (col, marker) in styles.items():
        pts = [p for p in result.points if p["level"] == level]
        if pts:
            ax.loglog([p["delta"] for p in pts], [max(p["error"], 1e-17) for p in pts], marker + "-", color=col, ms=4,
                      label=f"acceleration level (eq. 69), {level.split('-')[1]}")
    d = np.array(sorted({p["delta"] for p in sliding}))
    if len(d):
        ref = [p for p in sliding if p["zeta"] == zetas[len(zetas) // 2]]
        c = ref[-1]["error"] / ref[-1]["delta"]
        ax.loglog(d, c * d, "k:", lw=1, label="order 1")
    ax.set_xlabel("δ (s)")
    ax.set_ylabel("|λ(δ) − λ_ref| / |λ_ref|")
    ax.set_title("(a) relaxed λ (eq. 65, package solver) → level solutions", fontsize=10)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    for level, col in (("position", "C0"), ("velocity-separating", "C1")):
        pts = [p for p in result.points if p["level"] == level]
        if pts:
            ds = pts[0]["delta_star"]
            ax2.semilogx([p["delta"] / ds for p in pts], [p["lam"][2] for p in pts], "o-", color=col, ms=4,
                         label=f"{level} (eq. {'67' if level == 'position' else '68'}): δ* = {ds * 1e3:.3g} ms")
    ax2.axvline(1.0, color="k", lw=0.8, ls=":")
    ax2.set_xlabel("δ / δ*  (δ* closed form: b_n(δ*) = 0)")
    ax2.set_ylabel("λ_n (N)")
    ax2.set_title("(b) open or separating contact: λ = 0 exactly for δ < δ*", fontsize=10)
    ax2.grid(alpha=0.3, which="both")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)
