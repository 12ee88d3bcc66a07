"""Derivatives of one time step (issue 26): the result type shared by the analytic derivatives
(implicit function theorem at the converged impulse, mode by mode; ``Simulator.step_derivatives``)
and their finite-difference reference.

Conventions (Pinocchio's): a configuration change is a tangent vector dq (nv), q' = q ⊕ dq
(``pinocchio.integrate``), and the step's output configuration is read as q⁺ ⊖ q⁺₀
(``pinocchio.difference``), so every block is nv × nv. τ is the joint-space generalized force
added to the step (``sim.data.tau_ff``). μ columns: one per candidate contact
(``Simulator.contact_names``), so a scene-wide μ is the sum of the columns.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["StepDerivatives", "FiniteDifferenceReport", "finite_difference_step_derivatives",
           "finite_difference_step_jvp", "finite_difference_shared_mu_column", "candidate_mus"]


@dataclass(frozen=True)
class StepDerivatives:
    """The Jacobians of one time step (q, v, τ, μ) -> (q⁺, v⁺) at the simulator's current state.

    ``dq_dq, dq_dv, dq_dtau, dv_dq, dv_dv, dv_dtau``: (nv, nv); ``dq_dmu, dv_dmu``: (nv, number of
    candidate contacts). ``modes``: per candidate contact, "none" (not in the step's problem),
    "open", "stick" or "slide" (the converged impulse's mode the derivative was taken in).
    ``boundary``: per candidate contact, True where the contact sat on a mode boundary (λ_n = 0
    with u_n = 0, or a sticking impulse on the cone's edge), where the derivative is one-sided:
    the one of the mode in ``modes`` (also set where the modes' equations have no exact solution or
    the step's velocity is not unique: docs/simulator.md, "Derivatives of a step").
    ``contact_names``: the μ columns' contacts.
    ``mu_indeterminate``: per candidate contact, True where the contact belongs to a statically
    indeterminate set (the kernel of the modes' equations touches its rows: a cube's four coplanar
    corners). Its normal impulse is then not unique, and neither is its own μ column: it is the
    derivative at the solver's split of the load (∂P_t/∂μ_i = P_n,i s, eq. 65's sliding rows), and
    another equally valid split gives another column. Only their sum over the flagged contacts (a
    μ shared by the set, e.g. a scene-wide μ) and the (q, v, τ) blocks are unique; compare and use
    those (docs/derivatives.md). The finite-difference reference leaves it all False (it does not
    see the kernel).
    """

    dq_dq: np.ndarray
    dq_dv: np.ndarray
    dq_dtau: np.ndarray
    dv_dq: np.ndarray
    dv_dv: np.ndarray
    dv_dtau: np.ndarray
    dq_dmu: np.ndarray
    dv_dmu: np.ndarray
    modes: tuple[str, ...] = ()
    boundary: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))
    contact_names: tuple[str, ...] = ()
    mu_indeterminate: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def state_jacobian(self) -> np.ndarray:
        """The (2 nv, 2 nv) Jacobian of (q⁺, v⁺) with respect to (q, v), for chaining along a
        trajectory: d x_{k+1} = F d x_k with x = (q in tangent coordinates, v)."""
        return np.block([[self.dq_dq, self.dq_dv], [self.dv_dq, self.dv_dv]])


# ---------------------------------------------------------------------------------------------------
# The finite-difference reference (issue 26, "Checked"): the step run twice per direction.
# ---------------------------------------------------------------------------------------------------

FD_TOLERANCE = 1e-14  # the contact solver's relative residual for the reference's steps
FD_MAX_ITERATIONS = 1000
FD_SCHEMES = ("central", "forward", "backward")
# A contact's mode in the StepDerivatives sense, from the C++ ContactState (0 open, 1 stick, 2 slip,
# 3 closed: a 1-row frictionless or mu = 0 contact in compression, whose normal row is an equality as a
# sticking contact's rows are).
_MODE_OF_STATE = {0: "open", 1: "stick", 2: "slide", 3: "stick"}
# Mode-boundary thresholds of the unperturbed step (relative to the step's largest force and speed)
_BOUNDARY_CONE = 1e-7      # a sticking force within this fraction of the cone's edge
_BOUNDARY_RELATIVE = 1e-9  # lambda_n = 0 with u_n = 0, or a slip speed of 0


@dataclass(frozen=True)
class FiniteDifferenceReport:
    """What the finite-difference reference saw (``details=True``).

    ``mode_stable``: every perturbed step kept the unperturbed step's contact modes (the derivative is
    then the one of that mode, not a chord across a kink). ``changed``: the perturbations (``"q[3]+"``,
    ``"mu[FL_FOOT]-"``, ...) after which some contact's mode differed, and ``changed_contacts`` those
    contacts' indices. ``max_residual``: the largest contact-solver residual over the steps run.
    ``steps``: how many steps were run. ``mu_notes``: μ columns not obtained by central differences and why.
    """

    mode_stable: bool
    changed: tuple[str, ...]
    changed_contacts: tuple[int, ...]
    max_residual: float
    steps: int
    mu_notes: tuple[str, ...] = ()


def _copy_settings(settings, **changes):
    """A new SimulatorSettings with every field of `settings` (the bound properties), then `changes`."""
    from . import _core  # noqa: PLC0415

    out = _core.SimulatorSettings()
    for name in dir(type(settings)):
        attr = getattr(type(settings), name, None)
        if name.startswith("_") or not isinstance(attr, property) or attr.fset is None:
            continue
        setattr(out, name, getattr(settings, name))
    for name, value in changes.items():
        setattr(out, name, value)
    return out


def _copy_item(item, **changes):
    """A copy of a SphereContact or GeometryPairContact (every bound field), then `changes`."""
    out = type(item)()
    for name in dir(type(item)):
        attr = getattr(type(item), name, None)
        if name.startswith("_") or name == "planar" or not isinstance(attr, property) or attr.fset is None:
            continue
        setattr(out, name, getattr(item, name))
    for name, value in changes.items():
        setattr(out, name, value)
    return out


class _ReferenceStepper:
    """One step of a Simulator's scene from a given (q, v, τ), with its own C++ model (the simulator's
    settings, the solver's tolerance tightened, no warm start) and a fresh SimulatorData per step: the
    simulator itself is never touched, and no step's answer depends on the one before (the warm start,
    the locked-joints guess and coal's GJK cache live in the data)."""

    def __init__(self, sim, tolerance: float, max_iterations: int):
        from . import _core  # noqa: PLC0415

        self._core = _core
        self.sim = sim
        self.scene = sim.scene
        self.settings = _copy_settings(sim.model.settings, tolerance=float(tolerance),
                                       max_iterations=int(max_iterations), warm_start=False,
                                       time_limit=0.0)
        self.base = self._model(self.scene.contacts, self.scene.pairs)
        d = sim.data
        self.control = {k: np.array(getattr(d, k), dtype=float) for k in ("kp", "kd", "q_target", "v_target", "tau_ff")}
        self.t = float(d.t)
        self.steps = 0
        self.max_residual = 0.0

    def _model(self, contacts, pairs):
        sc = self.scene
        return self._core.SimulatorModel(sc.model, sc.halfspaces, list(contacts), sc.anchors, self.settings,
                                         sc.geometry, list(pairs))

    def model_with_mu(self, candidate: int, mu: float):
        """The model with candidate `candidate`'s friction coefficient set to `mu` (a coal pair: the
        whole pair's, every slot of it)."""
        contacts, pairs = list(self.scene.contacts), list(self.scene.pairs)
        if candidate < len(contacts):
            contacts[candidate] = _copy_item(contacts[candidate], mu=float(mu))
        else:
            p = _pair_of_slot(self.scene, candidate)
            pairs[p] = _copy_item(pairs[p], mu=float(mu))
        return self._model(contacts, pairs)

    def step(self, q, v, tau_ff, model=None):
        """(q⁺, v⁺, modes, data) of one step from (q, v) with tau_ff."""
        model = self.base if model is None else model
        data = self._core.SimulatorData(model)
        data.q, data.v, data.t = q, v, self.t
        for k, x in self.control.items():
            setattr(data, k, x)
        data.tau_ff = tau_ff
        self._core.step(model, data)
        self.steps += 1
        if len(data.active):
            self.max_residual = max(self.max_residual, float(data.result.residual))
        return np.array(data.q), np.array(data.v), _modes(data), data


def _pair_of_slot(scene, candidate: int) -> int:
    k = candidate - len(scene.contacts)
    for p, pair in enumerate(scene.pairs):
        if k < pair.max_contacts:
            return p
        k -= pair.max_contacts
    raise IndexError(f"candidate {candidate} out of range")


def _modes(data) -> tuple[str, ...]:
    """Per candidate: "none" (not in the step's problem) or its mode in the step."""
    active = set(int(i) for i in data.active)
    return tuple(_MODE_OF_STATE[int(s)] if i in active else "none" for i, s in enumerate(data.states))


def _boundary(sim_like_data, modes, mus, h: float) -> np.ndarray:
    """Per candidate: True where the unperturbed step's contact sits on a mode boundary (thresholds
    _BOUNDARY_CONE, _BOUNDARY_RELATIVE relative to the step's largest force and contact speed)."""
    nc = len(modes)
    lam = np.asarray(sim_like_data.candidate_lambda, dtype=float).reshape(3, nc)  # (t1, t2, n) forces
    u = np.asarray(sim_like_data.contact_velocity, dtype=float).reshape(3, nc)    # J v+
    gaps = np.asarray(sim_like_data.gaps, dtype=float).reshape(nc)
    force_scale = max(float(np.abs(lam).max()) if lam.size else 0.0, 1e-300)
    speed_scale = max(float(np.abs(u).max()) if u.size else 0.0, 9.81 * h)
    out = np.zeros(len(modes), dtype=bool)
    for i, mode in enumerate(modes):
        if mode == "none":
            continue
        lam_t, lam_n = np.linalg.norm(lam[:2, i]), lam[2, i]
        # the normal complementarity variable: J_n v+ + gap / h (eq. 70's position term, delta = h)
        w_n = u[2, i] + (gaps[i] / h if np.isfinite(gaps[i]) else 0.0)
        if mode == "open":
            out[i] = abs(w_n) <= _BOUNDARY_RELATIVE * speed_scale
        elif mode == "stick":
            out[i] = lam_n <= _BOUNDARY_RELATIVE * force_scale or \
                (mus[i] > 0 and lam_t >= (1.0 - _BOUNDARY_CONE) * mus[i] * lam_n)
        else:  # slide
            out[i] = lam_n <= _BOUNDARY_RELATIVE * force_scale or \
                np.linalg.norm(u[:2, i]) <= _BOUNDARY_RELATIVE * speed_scale
    return out


def candidate_mus(sim) -> np.ndarray:
    """Each candidate contact's friction coefficient (a coal pair's slots: the pair's)."""
    sc = sim.scene
    mus = [float(c.mu) for c in sc.contacts]
    for p in sc.pairs:
        mus += [float(p.mu)] * int(p.max_contacts)
    return np.array(mus)


def finite_difference_step_derivatives(sim, eps: float = 1e-6, scheme: str = "central", *,
                                       tolerance: float = FD_TOLERANCE, mu: bool = True,
                                       details: bool = False):
    """The Jacobians of one time step by finite differences: the reference the analytic
    ``Simulator.step_derivatives`` is checked against (issue 26). Returns a :class:`StepDerivatives`
    (and a :class:`FiniteDifferenceReport` with ``details=True``).

    Each input is perturbed by ±ε (``scheme``: "central" (f(x+ε) - f(x-ε)) / 2ε; "forward" or
    "backward": one-sided, e.g. the one-sided derivatives at a mode boundary) and the step is run from
    the perturbed input: q in the tangent space (q ⊕ ε e_k, ``pinocchio.integrate``), v, τ (every
    coordinate of ``sim.data.tau_ff``: the C++ step adds tau_ff to the joint-space force on all nv
    coordinates, a free flyer's too, as a wrench in its frame; the PD gains only act where kp, kd are
    set), and each candidate contact's μ (its own SphereContact's μ, which the C++ model reads at every
    step; the model is immutable, so a perturbed model is built per contact and sign). The output q⁺ is
    read as ``pinocchio.difference(model, q⁺₀, q⁺)``. ε is `eps` on q and v; on τ_k it is
    eps / (h (M⁻¹)_kk) and on μ eps / (‖g‖ h), so that every perturbation moves v⁺ by about `eps` (with
    `eps` on τ, dq⁺/dτ ~ h² M⁻¹ was at the rounding of q⁺). The default 1e-6 stays below the open /
    closed boundary of a body resting on the ground (a lift of g h² ≈ 1e-5 m at h = 1 ms opens it).

    The steps run on a model of their own (the simulator's settings with the solver's `tolerance`,
    1000 iterations and no warm start) and a fresh SimulatorData each, so that no answer depends on the
    previous step's impulses and `sim` is not changed at all (state, warm start, outputs). Controllers
    (``sim.controller``) are not run: the step is ``_core.step`` with the data's current control.
    ``modes`` and ``boundary`` are those of the unperturbed step (boundary: the thresholds of
    ``_boundary``, or a contact whose mode changed under some perturbation).

    μ columns (``mu=False`` leaves them NaN and saves 2 nc steps): a contact with μ = 0 by a forward
    difference (μ cannot go below 0; its rows go from 1 to 3); a coal pair has one μ for all its slots,
    so its column goes to its one slot that is in the problem, and is NaN when several are (the
    report's ``mu_notes`` says which). With ``scheme`` one-sided, all of them one-sided.

    Time stepping only (eq. 70): the ODE modes' step is an integrator's, not one solve.
    """
    import pinocchio as pin  # noqa: PLC0415

    from . import _core  # noqa: PLC0415

    if scheme not in FD_SCHEMES:
        raise ValueError(f"scheme must be one of {', '.join(FD_SCHEMES)}, got {scheme!r}")
    if not (isinstance(eps, (float, int)) and np.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be a finite number > 0, got {eps!r}")
    if sim.model.settings.mode != _core.IntegrationMode.timestep:
        raise ValueError("finite_difference_step_derivatives: the simulator must use mode 'timestep' (eq. 70)")
    if sim.model.settings.formulation == "penalty":
        raise ValueError("finite_difference_step_derivatives: the penalty formulation's springs are a state "
                         "beyond (q, v); use a formulation without one (default exact)")
    stepper = _ReferenceStepper(sim, tolerance, FD_MAX_ITERATIONS)
    model = sim.scene.model
    nv = model.nv
    h = float(sim.model.settings.dt)
    q0, v0 = np.array(sim.data.q), np.array(sim.data.v)
    tau0 = stepper.control["tau_ff"].copy()
    q_plus0, v_plus0, modes0, data0 = stepper.step(q0, v0, tau0)
    mus = candidate_mus(sim)
    nc = len(mus)
    changed: list[str] = []
    changed_contacts: set[int] = set()

    def outputs(label, q, v, tau, step_model=None):
        qp, vp, modes, _ = stepper.step(q, v, tau, step_model)
        if modes != modes0:
            changed.append(label)
            changed_contacts.update(i for i, (a, b) in enumerate(zip(modes, modes0)) if a != b)
        return pin.difference(model, q_plus0, qp), vp

    signs = {"central": (1.0, -1.0), "forward": (1.0,), "backward": (-1.0,)}[scheme]
    # step sizes: eps on q and v; on tau_k eps / (h (M^-1)_kk) and on mu eps / (|g| h), so that each moves
    # v+ by about eps (a force's effect h M^-1 tau is ~1e-3 of tau's: the same eps on tau left dq+/dtau at
    # the rounding of q+)
    inverse_mass = pin.computeMinverse(model, model.createData(), q0)
    tau_steps = eps / (h * np.maximum(np.diag(inverse_mass), 1e-300))
    gravity = max(float(np.linalg.norm(model.gravity.linear)), 1.0)
    mu_step = eps / (gravity * h)

    def column(label, perturbed, signs_here=signs, step=eps):
        step = float(step)
        outs = [outputs(f"{label}{'+' if s > 0 else '-'}", *perturbed(s * step)) for s in signs_here]
        if len(outs) == 2:
            return (outs[0][0] - outs[1][0]) / (2 * step), (outs[0][1] - outs[1][1]) / (2 * step)
        s = signs_here[0]
        return (outs[0][0] - 0.0) / (s * step), (outs[0][1] - v_plus0) / (s * step)

    blocks = {k: np.zeros((nv, nv)) for k in ("dq_dq", "dv_dq", "dq_dv", "dv_dv", "dq_dtau", "dv_dtau")}
    for k in range(nv):
        e = np.zeros(nv)
        e[k] = 1.0
        blocks["dq_dq"][:, k], blocks["dv_dq"][:, k] = column(
            f"q[{k}]", lambda d: (pin.integrate(model, q0, d * e), v0, tau0))
        blocks["dq_dv"][:, k], blocks["dv_dv"][:, k] = column(f"v[{k}]", lambda d: (q0, v0 + d * e, tau0))
        blocks["dq_dtau"][:, k], blocks["dv_dtau"][:, k] = column(f"tau[{k}]", lambda d: (q0, v0, tau0 + d * e),
                                                                  step=tau_steps[k])
    dq_dmu, dv_dmu = np.full((nv, nc), np.nan), np.full((nv, nc), np.nan)
    notes: list[str] = []
    if mu:
        names = sim.contact_names
        done_pairs: set[int] = set()
        for i in range(nc):
            if i >= len(sim.scene.contacts):
                p = _pair_of_slot(sim.scene, i)
                if p in done_pairs:
                    continue
                done_pairs.add(p)
                first = len(sim.scene.contacts) + sum(x.max_contacts for x in sim.scene.pairs[:p])
                slots = list(range(first, first + sim.scene.pairs[p].max_contacts))
            else:
                slots = [i]
            if mus[i] == 0.0 and scheme != "forward":
                notes.append(f"{names[i]}: mu = 0, forward difference")
                signs_here = (1.0,)
            else:
                signs_here = signs
            col = column(f"mu[{names[i]}]",
                         lambda d, i=i: (q0, v0, tau0, stepper.model_with_mu(i, mus[i] + d)), signs_here,
                         step=min(mu_step, 0.5 * mus[i]) if mus[i] > 0 else mu_step)
            in_problem = [s for s in slots if modes0[s] != "none"]
            for s in slots:
                dq_dmu[:, s] = dv_dmu[:, s] = 0.0
            if len(slots) == 1 or len(in_problem) <= 1:
                target = in_problem[0] if in_problem else slots[0]
                dq_dmu[:, target], dv_dmu[:, target] = col
            else:
                for s in in_problem:
                    dq_dmu[:, s] = dv_dmu[:, s] = np.nan
                notes.append(f"pair {sim.scene.pairs[_pair_of_slot(sim.scene, i)].name}: one mu for "
                             f"{len(in_problem)} slots in the problem, columns NaN")
    boundary = _boundary(data0, modes0, mus, h)
    boundary[sorted(changed_contacts)] = True
    result = StepDerivatives(dq_dmu=dq_dmu, dv_dmu=dv_dmu, modes=modes0, boundary=boundary,
                             contact_names=tuple(sim.contact_names), **blocks)
    if not details:
        return result
    report = FiniteDifferenceReport(mode_stable=not changed, changed=tuple(changed),
                                    changed_contacts=tuple(sorted(changed_contacts)),
                                    max_residual=stepper.max_residual, steps=stepper.steps,
                                    mu_notes=tuple(notes))
    return result, report


def finite_difference_step_jvp(sim, dq, dv, dtau=None, eps: float = 1e-6, *,
                               tolerance: float = FD_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """The step's Jacobian applied to one direction, by central differences: (dq⁺, dv⁺) =
    (∂q⁺/∂q dq + ∂q⁺/∂v dv + ∂q⁺/∂τ dτ, the same for v⁺), q in tangent coordinates as in
    :class:`StepDerivatives`. Three steps (±, and the nominal one as q⁺'s origin) instead of the
    2 (3 nv + nc) + 1 of :func:`finite_difference_step_derivatives` (the same steps: the simulator's settings with the
    solver's `tolerance`, no warm start, a fresh SimulatorData each; `sim` is not changed). The inputs
    move by `eps` times the direction, scaled down when the direction is longer than 1 (its max norm)."""
    import pinocchio as pin  # noqa: PLC0415

    model = sim.scene.model
    nv = model.nv
    dq = np.asarray(dq, dtype=float).reshape(nv)
    dv = np.asarray(dv, dtype=float).reshape(nv)
    dtau = np.zeros(nv) if dtau is None else np.asarray(dtau, dtype=float).reshape(nv)
    if not (np.isfinite(dq).all() and np.isfinite(dv).all() and np.isfinite(dtau).all()):
        raise ValueError("finite_difference_step_jvp: the direction (dq, dv, dtau) must be finite")
    stepper = _ReferenceStepper(sim, tolerance, FD_MAX_ITERATIONS)
    size = max(1.0, float(np.abs(np.concatenate([dq, dv, dtau])).max()))
    step = eps / size
    q0, v0, tau0 = np.array(sim.data.q), np.array(sim.data.v), stepper.control["tau_ff"]
    plus = stepper.step(pin.integrate(model, q0, step * dq), v0 + step * dv, tau0 + step * dtau)
    minus = stepper.step(pin.integrate(model, q0, -step * dq), v0 - step * dv, tau0 - step * dtau)
    q_plus0 = stepper.step(q0, v0, tau0)[0]
    dq_plus = (pin.difference(model, q_plus0, plus[0]) - pin.difference(model, q_plus0, minus[0])) / (2 * step)
    return dq_plus, (plus[1] - minus[1]) / (2 * step)


def finite_difference_shared_mu_column(sim, candidates, eps: float = 1e-6, *,
                                       tolerance: float = FD_TOLERANCE) -> tuple[np.ndarray, np.ndarray]:
    """(dq⁺/dμ, dv⁺/dμ) for one μ shared by the sphere contacts `candidates` (indices into
    ``sim.contact_names``), by central differences: all their μ moved together in the same run. This is
    the reference for the sum of the μ columns of a statically indeterminate set
    (``StepDerivatives.mu_indeterminate``); the sum of the per-contact columns of
    :func:`finite_difference_step_derivatives` is not, since each column comes from runs that pick
    their own split of the load. Same steps and μ step (eps / (‖g‖ h)) as that function."""
    import pinocchio as pin  # noqa: PLC0415

    candidates = [int(i) for i in candidates]
    if any(i < 0 or i >= len(sim.scene.contacts) for i in candidates):
        raise ValueError(f"finite_difference_shared_mu_column: candidates must be sphere contacts "
                         f"0..{len(sim.scene.contacts) - 1}, got {candidates}")
    stepper = _ReferenceStepper(sim, tolerance, FD_MAX_ITERATIONS)
    model = sim.scene.model
    h = float(sim.model.settings.dt)
    step = eps / (max(float(np.linalg.norm(model.gravity.linear)), 1.0) * h)
    q0, v0, tau0 = np.array(sim.data.q), np.array(sim.data.v), stepper.control["tau_ff"]
    q_plus0 = stepper.step(q0, v0, tau0)[0]
    outs = []
    for sign in (1.0, -1.0):
        contacts = list(sim.scene.contacts)
        for i in candidates:
            contacts[i] = _copy_item(contacts[i], mu=float(contacts[i].mu) + sign * step)
        qp, vp, _, _ = stepper.step(q0, v0, tau0, stepper._model(contacts, sim.scene.pairs))
        outs.append((pin.difference(model, q_plus0, qp), vp))
    return (outs[0][0] - outs[1][0]) / (2 * step), (outs[0][1] - outs[1][1]) / (2 * step)


def _from_core(out: dict, contact_names) -> StepDerivatives:
    """A StepDerivatives from ``_core.step_derivatives``'s dict (read-only arrays)."""
    def frozen(x):
        a = np.array(x, dtype=float)
        a.setflags(write=False)
        return a

    boundary = np.array(out["boundary"], dtype=bool)
    boundary.setflags(write=False)
    mu_indeterminate = np.array(out["mu_indeterminate"], dtype=bool)
    mu_indeterminate.setflags(write=False)
    return StepDerivatives(
        **{k: frozen(out[k]) for k in ("dq_dq", "dq_dv", "dq_dtau", "dv_dq", "dv_dv", "dv_dtau", "dq_dmu", "dv_dmu")},
        modes=tuple(out["modes"]), boundary=boundary, contact_names=tuple(contact_names),
        mu_indeterminate=mu_indeterminate)
