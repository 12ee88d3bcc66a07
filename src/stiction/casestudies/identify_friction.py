"""Identify friction and mass from a recorded trajectory (issue 26, "Used"): Gauss-Newton on the
trajectory error, the friction coefficient's sensitivity chained through the step's Jacobians.

Two experiments, each recorded with known parameters and Gaussian noise on the measured state
(σ_q = 1e-5 in q's tangent coordinates, m or rad; σ_v = 1e-4 m/s or rad/s: motion capture), then identified from
a wrong start:

- ``cube``: the 1 kg cube of ``cube-slide`` (μ = 0.5) launched at 1.5 m/s and pushed along its
  slide by a known force F(t) = 2 + 4 sin(2π t / 0.3) N (a free slide decelerates at μ g whatever
  the mass: without a known force the mass is not identifiable); unknowns μ and the cube's mass
  (its inertia scaled with it, a uniform density); start μ = 0.3, m = 1.5 kg.
- ``solo12``: Solo-12 with its joints locked (``solo12-slope-slip``: one rigid body of 2.5 kg on
  its four feet, 20° slope) carrying a payload of 0.5 kg on its base (a 10 cm cube at the base's
  origin), μ = 0.2, slipping down the slope while a known force pushes its base along the slope
  (8 sin(2π t / 0.2) N, body x); unknowns μ and the payload's mass; start μ = 0.1, payload 0.25 kg.

The model: x_{k+1} = f(x_k, τ_k; μ, m), x = (q, v), one time step (eq. 70) solved to 1e-14
without warm start, so that the recorded model and the sensitivities are the same function. The
residual r stacks (q_k ⊖ q̂_k) / σ_q and (v_k - v̂_k) / σ_v over the records. Its Jacobian:

- μ (scene-wide, every contact): dx_{k+1}/dμ = F_k dx_k/dμ + f_μ,k, F_k the step's state Jacobian
  and f_μ,k the sum of its μ columns (``StepDerivatives``), from ``Simulator.step_derivatives()``
  (``derivatives="analytic"``) or, without it, by central differences of the step along the
  direction (dx_k/dμ, 1) (``derivatives="fd"``: the same product F_k s + f_μ, two steps per step
  instead of the 2 (3 nv + nc) of the full finite-difference Jacobians);
- the mass: not a column of ``StepDerivatives`` (the step is differentiated in q, v, τ, μ), so it is
  obtained by central differences of the whole trajectory over the mass (two extra rollouts per
  iteration, δm = 1e-4 × m).

Gauss-Newton then solves (JᵀJ) δ = -Jᵀr (its step halved while it does not lower ‖r‖), until the
step is below 1e-10 relative or 50 iterations. Checks per experiment: μ and the mass recovered to
a relative error ≤ 1e-3, in ≤ 50 iterations. Points: per experiment and iteration, the parameters
and the cost ½‖r‖².
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pinocchio as pin

from . import CaseStudyResult, Check

NAME = "identify-friction"
TITLE = "Identify friction and mass from a noisy sliding trajectory by Gauss-Newton through the step's derivatives"
EQUATIONS = "70"

SIGMA_Q = 1e-5  # noise on the measured configuration (tangent coordinates)
SIGMA_V = 1e-4  # noise on the measured velocity
MAX_ITERATIONS = 50
RELATIVE_GOAL = 1e-3
STEP_TOLERANCE = 1e-10  # Gauss-Newton stops when its step is below this, relative to the parameters
SOLVER_TOLERANCE = 1e-14
DERIVATIVES = ("analytic", "fd")


@dataclass
class Experiment:
    """A scene, the body whose mass is identified, a known input and the true parameters."""

    name: str
    scene_name: str
    steps: int
    mu: float              # true friction coefficient
    mass: float            # true mass parameter (the cube's mass, or the payload's)
    mu_start: float
    mass_start: float
    payload: bool          # mass = a payload added to the body (True) or the body's own mass, inertia scaled
    force: Callable[[float], np.ndarray]  # t -> tau_ff (nv), the known input
    q0: np.ndarray | None = None
    v0: np.ndarray | None = None

    def scene(self, mass: float):
        """The scene with the mass parameter set (joint 1's body: the cube, or Solo-12's locked body)."""
        base = _base_scene(self.scene_name)
        model = pin.Model(base.model)
        inertia = base.model.inertias[1]
        if self.payload:
            side = 0.1  # a 10 cm cube of payload at the body's origin
            model.inertias[1] = inertia + pin.Inertia(mass, np.zeros(3), np.eye(3) * mass * side * side / 6.0)
        else:
            model.inertias[1] = pin.Inertia(mass, inertia.lever, inertia.inertia * (mass / inertia.mass))
        return dataclasses.replace(base, model=model)


_SCENES: dict = {}


def _base_scene(name: str):
    from ..scene import load_scene  # noqa: PLC0415

    if name not in _SCENES:
        _SCENES[name] = load_scene(name)
    return _SCENES[name]


def experiments(quick: bool = False) -> list[Experiment]:
    cube_force = lambda t: np.array([2.0 + 4.0 * math.sin(2 * math.pi * t / 0.3), 0, 0, 0, 0, 0])  # noqa: E731
    solo_force = lambda t: np.array([8.0 * math.sin(2 * math.pi * t / 0.2), 0, 0, 0, 0, 0])  # noqa: E731
    return [
        Experiment("cube", "cube-slide", 150 if quick else 300, mu=0.5, mass=1.0, mu_start=0.3, mass_start=1.5,
                   payload=False, force=cube_force, v0=np.array([1.5, 0, 0, 0, 0, 0])),
        Experiment("solo12", "solo12-slope-slip", 300, mu=0.2, mass=0.5, mu_start=0.1,
                   mass_start=0.25, payload=True, force=solo_force),
    ]


def _simulator(exp: Experiment, mu: float, mass: float):
    from ..simulator import Simulator  # noqa: PLC0415

    sim = Simulator(exp.scene(mass), mu=mu, tolerance=SOLVER_TOLERANCE, max_iterations=1000, warm_start=False)
    sim.controller = None
    if exp.q0 is not None:
        sim.set_state(q=exp.q0)
    if exp.v0 is not None:
        sim.set_state(v=exp.v0)
    return sim


def simulate(exp: Experiment, mu: float, mass: float, sensitivity: str | None = None):
    """The trajectory (q (N+1, nq), v (N+1, nv)) at (mu, mass), and with `sensitivity` ("analytic" or
    "fd") its μ sensitivity S (N+1, 2 nv): dx_k/dμ, q in tangent coordinates at q_k."""
    from ..derivatives import _ReferenceStepper  # noqa: PLC0415

    if sensitivity not in (None, *DERIVATIVES):
        raise ValueError(f"sensitivity must be None or one of {', '.join(DERIVATIVES)}, got {sensitivity!r}")
    sim = _simulator(exp, mu, mass)
    model = sim.scene.model
    nv = model.nv
    h = sim.dt
    qs, vs = [sim.data.q.copy()], [sim.data.v.copy()]
    S = np.zeros(2 * nv)
    sens = [S.copy()]
    if sensitivity == "fd":  # the step at mu +- step_mu: a model each
        step_mu = 1e-6
        plus = _ReferenceStepper(_simulator(exp, mu + step_mu, mass), SOLVER_TOLERANCE, 1000)
        minus = _ReferenceStepper(_simulator(exp, mu - step_mu, mass), SOLVER_TOLERANCE, 1000)
    for k in range(exp.steps):
        tau = exp.force(k * h)
        sim.data.tau_ff[:] = tau
        q, v = sim.data.q.copy(), sim.data.v.copy()
        if sensitivity == "analytic":
            d = sim.step_derivatives()
            S = d.state_jacobian() @ S + np.concatenate([d.dq_dmu.sum(axis=1), d.dv_dmu.sum(axis=1)])
        elif sensitivity == "fd":
            # central differences along (S, 1): F S + f_mu, x perturbed by +-step_mu S and mu by +-step_mu
            outs = [stepper.step(pin.integrate(model, q, sign * step_mu * S[:nv]), v + sign * step_mu * S[nv:], tau)
                    for sign, stepper in ((1.0, plus), (-1.0, minus))]
        sim.step()
        if sensitivity == "fd":  # q+ in tangent coordinates at the nominal step's q+
            q1 = sim.data.q
            S = np.concatenate([pin.difference(model, q1, outs[0][0]) - pin.difference(model, q1, outs[1][0]),
                                outs[0][1] - outs[1][1]]) / (2 * step_mu)
        qs.append(sim.data.q.copy())
        vs.append(sim.data.v.copy())
        sens.append(S.copy())
    return np.array(qs), np.array(vs), (np.array(sens) if sensitivity else None), model


def record(exp: Experiment, seed: int = 0):
    """The measured trajectory: the true parameters' trajectory plus Gaussian noise (q through its
    tangent space, q̂ = q ⊕ σ_q n)."""
    qs, vs, _, model = simulate(exp, exp.mu, exp.mass)
    rng = np.random.default_rng(seed)
    q_meas = np.array([pin.integrate(model, q, SIGMA_Q * rng.standard_normal(model.nv)) for q in qs])
    v_meas = vs + SIGMA_V * rng.standard_normal(vs.shape)
    return q_meas, v_meas


def residual(model, qs, vs, q_meas, v_meas) -> np.ndarray:
    rq = np.array([pin.difference(model, qm, q) for q, qm in zip(qs[1:], q_meas[1:])]) / SIGMA_Q
    rv = (vs[1:] - v_meas[1:]) / SIGMA_V
    return np.concatenate([rq, rv], axis=1).ravel()


def _residual_mu_column(model, qs, sens, q_meas) -> np.ndarray:
    nv = model.nv
    cols = []
    for q, qm, s in zip(qs[1:], q_meas[1:], sens[1:]):
        jq = pin.dDifference(model, qm, q, pin.ARG1) @ s[:nv] / SIGMA_Q
        cols.append(np.concatenate([jq, s[nv:] / SIGMA_V]))
    return np.concatenate(cols)


def identify(exp: Experiment, q_meas, v_meas, derivatives: str = "fd"):
    """Gauss-Newton from (mu_start, mass_start); returns (mu, mass, iterations, history)."""
    if derivatives not in DERIVATIVES:
        raise ValueError(f"derivatives must be one of {', '.join(DERIVATIVES)}, got {derivatives!r}")
    theta = np.array([exp.mu_start, exp.mass_start], dtype=float)
    history = []

    def evaluate(th, sensitivity=None):
        qs, vs, sens, model = simulate(exp, th[0], th[1], sensitivity)
        return residual(model, qs, vs, q_meas, v_meas), qs, sens, model

    r, qs, sens, model = evaluate(theta, derivatives)
    iterations = 0
    for iterations in range(1, MAX_ITERATIONS + 1):
        cost = 0.5 * float(r @ r)
        history.append({"experiment": exp.name, "iteration": iterations - 1, "mu": theta[0], "mass": theta[1],
                        "cost": cost})
        j_mu = _residual_mu_column(model, qs, sens, q_meas)
        dm = 1e-4 * max(abs(theta[1]), 0.1)
        j_m = (evaluate(theta + [0, dm])[0] - evaluate(theta - [0, dm])[0]) / (2 * dm)
        J = np.stack([j_mu, j_m], axis=1)
        delta = np.linalg.lstsq(J, -r, rcond=None)[0]
        t = 1.0
        while True:
            trial = theta + t * delta
            trial = np.maximum(trial, 1e-3)  # mu and the mass stay positive (the mass column's differences too)
            r_trial, qs_t, sens_t, model_t = evaluate(trial, derivatives)
            if 0.5 * float(r_trial @ r_trial) <= cost or t < 1e-3:
                break
            t *= 0.5
        step = np.abs(trial - theta).max() / max(np.abs(theta).max(), 1e-12)
        theta, r, qs, sens, model = trial, r_trial, qs_t, sens_t, model_t
        if step < STEP_TOLERANCE:
            break
    history.append({"experiment": exp.name, "iteration": iterations, "mu": theta[0], "mass": theta[1],
                    "cost": 0.5 * float(r @ r)})
    return float(theta[0]), float(theta[1]), iterations, history


def default_derivatives() -> str:
    from ..simulator import Simulator  # noqa: PLC0415

    return "analytic" if hasattr(Simulator, "step_derivatives") else "fd"


def run(quick: bool = False, derivatives: str | None = None) -> CaseStudyResult:
    derivatives = default_derivatives() if derivatives is None else derivatives
    checks, points, notes = [], [], []
    notes.append(f"step derivatives: {derivatives} ("
                 + ("Simulator.step_derivatives, chained F_k s_k + f_mu" if derivatives == "analytic" else
                    "central differences of the step along (s_k, 1): the same product, two steps per step")
                 + "); the mass by central differences of the whole trajectory (not a column of StepDerivatives)")
    notes.append(f"noise: sigma_q = {SIGMA_Q:g}, sigma_v = {SIGMA_V:g}; solver tolerance {SOLVER_TOLERANCE:g}, "
                 "no warm start")
    for exp in experiments(quick):
        start = time.perf_counter()
        q_meas, v_meas = record(exp)
        mu, mass, iterations, history = identify(exp, q_meas, v_meas, derivatives)
        seconds = time.perf_counter() - start
        points += history
        mass_label = "payload mass" if exp.payload else "mass"
        checks.append(Check(f"{exp.name}: mu recovered (true {exp.mu:g}, start {exp.mu_start:g}): relative error",
                            abs(mu - exp.mu) / exp.mu, 0.0, RELATIVE_GOAL, kind="<="))
        checks.append(Check(f"{exp.name}: {mass_label} recovered (true {exp.mass:g} kg, start {exp.mass_start:g} kg): "
                            "relative error", abs(mass - exp.mass) / exp.mass, 0.0, RELATIVE_GOAL, kind="<="))
        checks.append(Check(f"{exp.name}: Gauss-Newton iterations", iterations, MAX_ITERATIONS, 0.0, kind="<="))
        notes.append(f"{exp.name}: mu = {mu:.8g} (true {exp.mu:g}), {mass_label} = {mass:.8g} kg (true {exp.mass:g}), "
                     f"{iterations} iterations, {exp.steps} steps, {seconds:.1f} s")
    return CaseStudyResult(NAME, TITLE, EQUATIONS, checks, points, notes)


def plot(result: CaseStudyResult, path) -> None:
    """The parameters' relative error per Gauss-Newton iteration, one line per experiment and parameter."""
    from .._optional import require  # noqa: PLC0415

    matplotlib = require("matplotlib", "plot", "plots")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    truth = {e.name: (e.mu, e.mass) for e in experiments()}
    fig, ax = plt.subplots(figsize=(6, 4))
    for name in truth:
        rows = [p for p in result.points if p["experiment"] == name]
        it = [p["iteration"] for p in rows]
        ax.semilogy(it, [max(abs(p["mu"] - truth[name][0]) / truth[name][0], 1e-16) for p in rows], "o-",
                    label=f"{name}: mu")
        ax.semilogy(it, [max(abs(p["mass"] - truth[name][1]) / truth[name][1], 1e-16) for p in rows], "s--",
                    label=f"{name}: mass")
    ax.axhline(RELATIVE_GOAL, color="k", lw=0.8)
    ax.set_xlabel("Gauss-Newton iteration")
    ax.set_ylabel("relative error")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
