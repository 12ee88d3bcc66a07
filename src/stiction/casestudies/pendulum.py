"""§3 (eq. 24-36): Baumgarte stabilisation of a bilateral constraint, and its implicit-Euler analogy.

The bundled ``rod-pendulum`` scene: a 1 kg, 0.5 m rod (free flyer, 6 DOF) whose end is held at the
world point (0, 0, 1) by a point anchor, three bilateral rows (C = R^3: eq. 65 is eq. 26, lambda =
A^-1 b). Psi_p(q) = e, the anchor's position error (world frame), and J q'' + J' q' = e''.

1. **Relaxed ODE (eq. 24-27).** With lambda = A^-1 b(delta, q, q') the constraint rows obey eq. 24
   exactly, e'' + (2 zeta/delta) e' + e/delta^2 = 0, whatever the rod does: an initial error e_0,
   e'_0 decays as the second-order system with time constant delta,
   e(t) = (delta e'_0 + 2 zeta e_0) Gamma_zeta(t/delta) + e_0 Gamma'_zeta(t/delta)
   (Gamma of eq. 98, continued to zeta >= 1). Simulated in the ODE mode (RK4, dt = delta/20) from a
   swinging rod (0.5 rad, 1 rad/s) displaced by e_0 = (1, 0.5, -0.7) mm moving at
   e'_0 = (20, 10, -5) mm/s, and compared with the closed form over 10 delta, for a grid of delta and
   zeta. From a consistent start (e = 0, e' = 0) eq. 24 keeps e = 0 analytically: what drift remains
   is the integrator's, damped by the same loop.
2. **Time stepping (§3.3, eq. 28-36).** The simulator's time step computes lambda_{k+1} =
   A(q_k)^-1 b(h, q_k, u_k) with zeta = 1/2 (eq. 36), then u_{k+1} = u_k + h M^-1 (J^T lambda -
   Phi) and q_{k+1} = q_k + h u_{k+1}: semi-implicit Euler on the relaxed ODE with delta = h,
   zeta = 1/2. Checked: (a) lambda_{k+1} against eq. 36 computed here independently (pinocchio's
   J, M, nle and the anchor point's classical acceleration J' u); (b) what eq. 34-35 then predict for
   the error: J u_{k+1} = -h H u_k - e_k/h, so the linearised Psi_p(q_{k+1}) = e_k + h J u_{k+1} +
   h^2 H u_k is exactly 0 -- an error is removed in one step (deadbeat), whereas the continuous
   relaxed ODE with the same delta = h, zeta = 1/2 still holds 0.7 of it after a time h; zeta = 1/2
   is the value that makes it deadbeat whatever e'_k (other zeta leave (1 - 2 zeta) h e'_k);
   (c) what is left each step is the part of Psi_p(q_{k+1}) that eq. 35 linearises away: for the
   rigid rod pinned at its end (pivot velocity ~ 0, so H u ~ 0) it is the centripetal term
   (h^2/2) R omega x (omega x r), of size (h^2/2) |omega|^2 |r| (r = 0.25 m): the drift is of order
   2 in h with that constant.
"""
from __future__ import annotations

import math

import numpy as np

from . import CaseStudyResult, Check

NAME = "pendulum"
TITLE = "Baumgarte stabilisation of a pinned rod and the implicit-Euler analogy (§3)"
EQUATIONS = "24-36"

SCENE = "rod-pendulum"
THETA0, OMEGA0 = 0.5, 1.0  # rad, rad/s: the swing the errors are put on
E0 = np.array([1.0e-3, 0.5e-3, -0.7e-3])  # m
EDOT0 = np.array([20e-3, 10e-3, -5e-3])  # m/s
# the time-stepping start: h |e'_0| comparable to |e_0|, so that a zeta other than 1/2 would leave
# (1 - 2 zeta) h e'_0, a visible part of the error, after the first step
E0_TS = np.array([0.1e-3, 0.05e-3, -0.07e-3])  # m
EDOT0_TS = np.array([60e-3, -80e-3, 30e-3])  # m/s
STEPS_PER_DELTA = 20
DECAY_WINDOW = 10.0  # delta
SWING = 1.2  # s, about one period of the 0.5 rad swing

# tolerances (docs/casestudies/pendulum.md)
TOL_DECAY = 1e-4  # of |e_0| + delta |e'_0|: RK4 at dt = delta/20, measured <= 7e-6
TOL_CONSISTENT = 1e-10  # m: drift from a consistent start, ODE mode, delta <= 30 ms (measured ~1e-13)
TOL_EQ36 = 1e-8  # relative: the solver's tolerance is 1e-10 on the residual
TOL_DEADBEAT = 1e-2  # |e_1| / (|e_0| + h |e'_0|): the remainder of eq. 35 is O(|e_0|^2/|r| + h^2 |omega|^2 |r|)
TOL_ORDER = 0.05
TOL_CONSTANT = 0.01


def gamma01(zeta: float, tau):
    """Gamma_zeta(tau) and Gamma'_zeta(tau) (eq. 98-99): the solution of G'' + 2 zeta G' + G = 0,
    G(0) = 0, G'(0) = 1, for any zeta > 0 (eq. 98 for zeta < 1, its limits at and above 1)."""
    tau = np.asarray(tau, dtype=float)
    if zeta < 1.0:
        w = math.sqrt(1.0 - zeta * zeta)
        e = np.exp(-zeta * tau)
        return e * np.sin(w * tau) / w, e * (np.cos(w * tau) - zeta * np.sin(w * tau) / w)
    if zeta == 1.0:
        e = np.exp(-tau)
        return tau * e, (1.0 - tau) * e
    s = math.sqrt(zeta * zeta - 1.0)
    a, b = -zeta + s, -zeta - s
    return (np.exp(a * tau) - np.exp(b * tau)) / (a - b), (a * np.exp(a * tau) - b * np.exp(b * tau)) / (a - b)


def error_closed_form(t, delta: float, zeta: float, e0, edot0) -> np.ndarray:
    """eq. 24 for the position rows: e(t) = (delta e'_0 + 2 zeta e_0) Gamma(t/delta) + e_0 Gamma'(t/delta), (N, 3)."""
    g, g1 = gamma01(zeta, np.asarray(t) / delta)
    return np.outer(g, delta * np.asarray(edot0) + 2.0 * zeta * np.asarray(e0)) + np.outer(g1, e0)


class Rod:
    """The rod-pendulum scene's model and anchor, with the state builders and the anchor error."""

    def __init__(self):
        import pinocchio as pin

        from ..scene import load_scene

        self.scene = load_scene(SCENE)
        self.model = self.scene.model
        self.data = self.model.createData()
        anchor = self.scene.anchors[0]
        self.frame = int(anchor.frame)
        self.joint = int(self.model.frames[self.frame].parentJoint)
        self.point_in_joint = self.model.frames[self.frame].placement.act(np.asarray(anchor.offset, dtype=float))
        self.r = np.asarray(anchor.offset, dtype=float)  # the pivot in the rod's frame
        self.target = np.asarray(anchor.target, dtype=float)
        self._pin = pin

    def state(self, theta: float, omega: float, e0=np.zeros(3), edot0=np.zeros(3)):
        """The rod hanging from the pivot, turned by theta about the world y axis, turning at omega
        about it, with the pivot displaced by e0 and moving at edot0 (world frame)."""
        pin = self._pin
        R = pin.utils.rotate("y", math.pi / 2 - theta)  # rod x axis along -z at theta = 0
        p = self.target - R @ self.r + np.asarray(e0, dtype=float)
        w_world = np.array([0.0, -omega, 0.0])
        v_origin = np.cross(w_world, p - (self.target + np.asarray(e0, dtype=float))) + np.asarray(edot0, dtype=float)
        q = np.concatenate([p, pin.Quaternion(R).coeffs()])
        return q, np.concatenate([R.T @ v_origin, R.T @ w_world])

    def error(self, q) -> np.ndarray:
        """Psi_p(q): the anchor point's world position minus its target."""
        self._pin.forwardKinematics(self.model, self.data, q)
        return self.data.oMi[self.joint].act(self.point_in_joint) - self.target

    def errors(self, qs) -> np.ndarray:
        return np.array([self.error(q) for q in qs])

    def eq36(self, q, v, h: float, zeta: float = 0.5) -> np.ndarray:
        """lambda = A^-1 b(h, q, u) (eq. 36 = eq. 26-27 with delta = h), from pinocchio directly:
        J of the anchor point, M (crba), Phi = nle (no joint torques), H u = the point's classical
        acceleration at zero q''."""
        pin, model = self._pin, self.model
        d = model.createData()
        pin.forwardKinematics(model, d, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, d, q)
        j = self.joint
        Rj = d.oMi[j].rotation
        rw = Rj @ self.point_in_joint
        Jj = pin.getJointJacobian(model, d, j, pin.LOCAL_WORLD_ALIGNED)
        J = Jj[:3] - pin.skew(rw) @ Jj[3:]
        vel, acc = d.v[j], d.a[j]  # joint frame; acc = the bias (classical terms) at q'' = 0
        w = Rj @ vel.angular
        v_point = Rj @ vel.linear + np.cross(w, rw)
        Hu = Rj @ acc.linear + np.cross(Rj @ acc.angular, rw) + np.cross(w, v_point)
        M = pin.crba(model, d, q)
        M = np.triu(M) + np.triu(M, 1).T
        nle = pin.nonLinearEffects(model, d, q, v)
        e = d.oMi[j].act(self.point_in_joint) - self.target
        A = J @ np.linalg.solve(M, J.T)
        b = J @ np.linalg.solve(M, nle) - Hu - (2.0 * zeta / h) * (J @ v) - e / (h * h)
        return np.linalg.solve(A, b)


def decay_run(rod: Rod, delta: float, zeta: float, e0=E0, edot0=EDOT0, window: float = DECAY_WINDOW) -> dict:
    """ODE mode from the swinging rod with an error e0, e'0: the measured e(t) against eq. 24."""
    from ..simulator import Simulator

    sim = Simulator(rod.scene, mode="rk4", delta=delta, zeta=zeta, dt=delta / STEPS_PER_DELTA)
    q, v = rod.state(THETA0, OMEGA0, e0, edot0)
    sim.set_state(q=q, v=v)
    traj = sim.rollout(window * delta)
    e = rod.errors(traj.q)
    cf = error_closed_form(traj.t, delta, zeta, e0, edot0)
    scale = np.linalg.norm(e0) + delta * np.linalg.norm(edot0)
    k3 = int(np.argmin(np.abs(traj.t - 3.0 * delta)))
    return {"t": traj.t, "e": e, "closed_form": cf, "deviation": float(np.abs(e - cf).max() / scale),
            "e3": float(np.linalg.norm(e[k3])), "e3_expected": float(np.linalg.norm(cf[k3])),
            "unconverged": int((~traj.converged[1:]).sum())}


def consistent_drift(rod: Rod, delta: float, zeta: float, dt: float = 1e-3) -> float:
    """ODE mode from a consistent state (e = 0, e' = 0): the largest |e| over the swing."""
    from ..simulator import Simulator

    sim = Simulator(rod.scene, mode="rk4", delta=delta, zeta=zeta, dt=dt)
    q, v = rod.state(THETA0, 0.0)
    sim.set_state(q=q, v=v)
    traj = sim.rollout(SWING)
    return float(np.linalg.norm(rod.errors(traj.q), axis=1).max())


def timestep_first_steps(rod: Rod, h: float, steps: int = 20) -> dict:
    """Time stepping from the swinging rod with the error E0_TS, EDOT0_TS: each step's anchor lambda
    against eq. 36, and the errors e_k."""
    from ..simulator import Simulator

    sim = Simulator(rod.scene, mode="timestep", dt=h)
    q, v = rod.state(THETA0, OMEGA0, E0_TS, EDOT0_TS)
    sim.set_state(q=q, v=v)
    errs, lam_dev, lam_dev_zeta1 = [rod.error(q)], [], []
    for _ in range(steps):
        qk, vk = sim.data.q, sim.data.v
        ref = rod.eq36(qk, vk, h)
        other = rod.eq36(qk, vk, h, zeta=1.0)  # eq. 27 with another zeta: not what time stepping does
        sim.step()
        lam = np.asarray(sim.data.anchor_lambda).reshape(-1)
        lam_dev.append(float(np.linalg.norm(lam - ref) / np.linalg.norm(ref)))
        lam_dev_zeta1.append(float(np.linalg.norm(lam - other) / np.linalg.norm(other)))
        errs.append(rod.error(sim.data.q))
    return {"e": np.array(errs), "lambda_deviation": max(lam_dev), "lambda_deviation_zeta1": min(lam_dev_zeta1)}


def timestep_drift(rod: Rod, h: float) -> dict:
    """Time stepping from a consistent swing: max |e_k| and max (h^2/2) |omega_k|^2 |r|."""
    from ..simulator import Simulator

    sim = Simulator(rod.scene, mode="timestep", dt=h)
    q, v = rod.state(THETA0, 0.0)
    sim.set_state(q=q, v=v)
    traj = sim.rollout(SWING)
    e = np.linalg.norm(rod.errors(traj.q), axis=1)
    omega2 = np.sum(traj.v[:, 3:] ** 2, axis=1)
    predicted = 0.5 * h * h * omega2 * np.linalg.norm(rod.r)
    return {"max_error": float(e.max()), "predicted": float(predicted.max()),
            "unconverged": int((~traj.converged[1:]).sum())}


def run(quick: bool = False) -> CaseStudyResult:
    rod = Rod()
    deltas = [1e-3, 3e-2] if quick else [1e-3, 3e-3, 1e-2, 3e-2]
    zetas = [0.5, 1.0] if quick else [0.2, 0.5, 0.7, 1.0, 2.0]
    hs = [4e-3, 2e-3, 1e-3] if quick else [4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4]
    consistent_deltas = [3e-3, 3e-2] if quick else [3e-3, 1e-2, 3e-2, 0.1, 1.0, 10.0]
    points, unconverged = [], 0
    decay = {}
    for delta in deltas:
        for zeta in zetas:
            r = decay_run(rod, delta, zeta)
            decay[(delta, zeta)] = r
            unconverged += r["unconverged"]
            points.append({"experiment": "ode-decay", "delta": delta, "zeta": zeta,
                           "max_deviation_from_eq24": r["deviation"], "error_at_3delta": r["e3"],
                           "expected_error_at_3delta": r["e3_expected"]})
    for delta in consistent_deltas:
        for zeta in (0.5, 1.0):
            points.append({"experiment": "ode-consistent", "delta": delta, "zeta": zeta,
                           "max_drift": consistent_drift(rod, delta, zeta), "dt": 1e-3})
    # time stepping against eq. 36, and the relaxed ODE at delta = h, zeta = 1/2 from the same start
    h = 1e-3
    ts = timestep_first_steps(rod, h)
    ode_h = decay_run(rod, h, 0.5, E0_TS, EDOT0_TS, window=3.0)
    unconverged += ode_h["unconverged"]
    k1 = int(np.argmin(np.abs(ode_h["t"] - h)))
    scale = np.linalg.norm(E0_TS) + h * np.linalg.norm(EDOT0_TS)
    e1_ts = float(np.linalg.norm(ts["e"][1]))
    for k, ek in enumerate(ts["e"][:4]):
        kk = int(np.argmin(np.abs(ode_h["t"] - k * h)))
        points.append({"experiment": "timestep-vs-ode", "h": h, "step": k, "timestep_error": float(np.linalg.norm(ek)),
                       "ode_error": float(np.linalg.norm(ode_h["e"][kk])),
                       "ode_expected_error": float(np.linalg.norm(ode_h["closed_form"][kk]))})
    drifts = []
    for hh in hs:
        r = timestep_drift(rod, hh)
        unconverged += r["unconverged"]
        drifts.append(r)
        points.append({"experiment": "timestep-drift", "h": hh, "max_error": r["max_error"],
                       "expected_max_error": r["predicted"]})
    order = float(np.polyfit(np.log(hs), np.log([r["max_error"] for r in drifts]), 1)[0])
    worst_decay = max(decay.values(), key=lambda r: r["deviation"])
    consistent = [p["max_drift"] for p in points if p["experiment"] == "ode-consistent" and p["delta"] <= 0.03]
    checks = [
        Check(f"eq. 24: worst max_t |e - closed form| / (|e_0| + delta |e'_0|) over {len(decay)} (delta, zeta), "
              f"delta {deltas[0]:g}-{deltas[-1]:g} s, zeta {zetas[0]:g}-{zetas[-1]:g}",
              worst_decay["deviation"], TOL_DECAY, 0.0, "<="),
        Check(f"eq. 24, relaxed ODE at delta = h = {h:g} s, zeta = 1/2: |e(h)| / |e_0| (closed form expected)",
              float(np.linalg.norm(ode_h["e"][k1])) / np.linalg.norm(E0_TS),
              float(np.linalg.norm(ode_h["closed_form"][k1])) / np.linalg.norm(E0_TS),
              TOL_DECAY * scale / np.linalg.norm(E0_TS)),
        Check("relaxed ODE from a consistent start: max anchor drift over a 1.2 s swing (m), delta <= 30 ms",
              max(consistent), TOL_CONSISTENT, 0.0, "<="),
        Check(f"eq. 36: time-stepping lambda_(k+1) vs A^-1 b(h, q_k, u_k) at zeta = 1/2, worst relative "
              f"difference over 20 steps (h = {h:g} s)", ts["lambda_deviation"], TOL_EQ36, 0.0, "<="),
        Check(f"eq. 34-36 (deadbeat): time stepping |e_1| / (|e_0| + h |e'_0|) (a relaxed form with zeta != 1/2 "
              "would leave |1 - 2 zeta| h |e'_0|)", e1_ts / scale, TOL_DEADBEAT, 0.0, "<="),
        Check(f"eq. 35 remainder: order in h of the time-stepping drift, h {hs[-1]:g}-{hs[0]:g} s", order, 2.0,
              TOL_ORDER),
        Check(f"eq. 35 remainder: max |e| / max (h^2/2) |omega|^2 |r| at h = {hs[-1]:g} s",
              drifts[-1]["max_error"] / drifts[-1]["predicted"], 1.0, TOL_CONSTANT),
        Check("steps whose contact solve did not converge", unconverged, 0, 0),
    ]
    notes = [
        "worst eq. 24 deviation at (delta, zeta) = " + str([k for k, r in decay.items() if r is worst_decay][0]),
        f"time stepping keeps {e1_ts / np.linalg.norm(E0_TS):.2e} of the initial error after one step (zeta = 1 "
        f"would keep h |e'_0| / |e_0| = {h * np.linalg.norm(EDOT0_TS) / np.linalg.norm(E0_TS):.2f}); the relaxed "
        f"ODE at delta = h, zeta = 1/2 keeps {np.linalg.norm(ode_h['e'][k1]) / np.linalg.norm(E0_TS):.3f}: the analogy "
        "of §3.3 is one of the lambda formula (eq. 36 = eq. 27 at delta = h, zeta = 1/2), the time step being "
        "semi-implicit Euler on the relaxed ODE with step = delta",
        f"eq. 27 with zeta = 1 differs from the time-stepping lambda by at least {ts['lambda_deviation_zeta1']:.2g} "
        "(relative) over the 20 steps: the eq. 36 check discriminates zeta",
    ]
    result = CaseStudyResult(NAME, TITLE, EQUATIONS, checks, points, notes)
    result.curves = {"decay": {f"{d:g}|{z:g}": {"t": r["t"] / d, "e": np.linalg.norm(r["e"], axis=1),
                                                 "closed_form": np.linalg.norm(r["closed_form"], axis=1)}
                               for (d, z), r in decay.items()},
                     "timestep_e": np.linalg.norm(ts["e"], axis=1), "h": h,
                     "ode_h": {"t": ode_h["t"] / h, "e": np.linalg.norm(ode_h["e"], axis=1),
                               "closed_form": np.linalg.norm(ode_h["closed_form"], axis=1)}}
    return result


def plot(result: CaseStudyResult, path) -> None:
    """(a) the anchor error decaying as eq. 24 predicts; (b) time stepping removes it in one step
    where the relaxed ODE at delta = h, zeta = 1/2 takes several; (c) time-stepping drift vs h
    against the eq. 35 remainder; (d) the relaxed ODE's drift from a consistent start vs delta."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401  (matplotlib.ticker below)

    curves = getattr(result, "curves", None)
    fig, axes = plt.subplots(2, 2, figsize=(11.5, 8.0))
    ax = axes[0, 0]
    if curves:
        deltas = sorted({float(k.split("|")[0]) for k in curves["decay"]})
        delta_pick = min(deltas, key=lambda d: abs(math.log(d / 1e-2)))  # 10 ms, or the closest
        picked = [k for k in curves["decay"] if float(k.split("|")[0]) == delta_pick]
        colors = plt.cm.viridis(np.linspace(0.0, 0.85, len(picked)))
        for col, k in zip(colors, picked):
            c = curves["decay"][k]
            ax.plot(c["t"], c["closed_form"] * 1e3, "-", color=col, lw=1.2, label=f"eq. 24, ζ = {k.split('|')[1]}")
            ax.plot(c["t"][::4], c["e"][::4] * 1e3, "o", color=col, ms=3)
        ax.set_title(f"(a) relaxed ODE, δ = {float(delta_pick) * 1e3:g} ms: anchor error |e| (markers: simulated)",
                     fontsize=9)
        ax.legend(fontsize=8)
    ax.set_xlabel("t / δ")
    ax.set_ylabel("|e| (mm)")
    ax.grid(alpha=0.3)

    ax = axes[0, 1]
    if curves:
        h = curves["h"]
        e_ts = curves["timestep_e"]
        ax.semilogy(np.arange(len(e_ts)), e_ts * 1e3, "s-", color="C3", ms=4, label=f"time stepping, h = {h * 1e3:g} ms")
        o = curves["ode_h"]
        ax.semilogy(o["t"], o["closed_form"] * 1e3, "-", color="C0", lw=1.2, label="relaxed ODE δ = h, ζ = ½: eq. 24")
        ax.semilogy(o["t"][::2], o["e"][::2] * 1e3, "o", color="C0", ms=3, label="relaxed ODE, simulated")
        ax.set_xlim(0, 3)
    ax.set_title("(b) same initial error: the time step is deadbeat (eq. 34-36)", fontsize=9)
    ax.set_xlabel("t / h")
    ax.set_ylabel("|e| (mm)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)

    ax = axes[1, 0]
    pts = [p for p in result.points if p["experiment"] == "timestep-drift"]
    hs = np.array([p["h"] for p in pts])
    ax.loglog(hs * 1e3, [p["max_error"] for p in pts], "s", color="C3", label="time stepping: max |e| over 1.2 s")
    ax.loglog(hs * 1e3, [p["expected_max_error"] for p in pts], "-", color="k", lw=1,
              label="eq. 35 remainder: max (h²/2) |ω|² |r|")
    ax.set_xticks(hs * 1e3, [f"{x * 1e3:g}" for x in hs])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel("h (ms)")
    ax.set_ylabel("max |e| (m)")
    ax.set_title("(c) time-stepping drift: order 2 in h", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)

    ax = axes[1, 1]
    for zeta, col in ((0.5, "C0"), (1.0, "C2")):
        pts = [p for p in result.points if p["experiment"] == "ode-consistent" and p["zeta"] == zeta]
        ax.loglog([p["delta"] for p in pts], [max(p["max_drift"], 1e-17) for p in pts], "o-", color=col,
                  label=f"relaxed ODE (RK4, dt = 1 ms), ζ = {zeta:g}")
    ax.set_xlabel("δ (s)")
    ax.set_ylabel("max |e| (m)")
    ax.set_title("(d) consistent start: the drift left by the integrator, vs δ", fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.suptitle("Pinned rod (rod-pendulum): Baumgarte stabilisation, eq. 24-36", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
