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

__all__ = ["StepDerivatives"]


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

    def state_jacobian(self) -> np.ndarray:
        """The (2 nv, 2 nv) Jacobian of (q⁺, v⁺) with respect to (q, v), for chaining along a
        trajectory: d x_{k+1} = F d x_k with x = (q in tangent coordinates, v)."""
        return np.block([[self.dq_dq, self.dq_dv], [self.dv_dq, self.dv_dv]])


def _from_core(out: dict, contact_names) -> StepDerivatives:
    """A StepDerivatives from ``_core.step_derivatives``'s dict (read-only arrays)."""
    def frozen(x):
        a = np.array(x, dtype=float)
        a.setflags(write=False)
        return a

    boundary = np.array(out["boundary"], dtype=bool)
    boundary.setflags(write=False)
    return StepDerivatives(
        **{k: frozen(out[k]) for k in ("dq_dq", "dq_dv", "dq_dtau", "dv_dq", "dv_dv", "dv_dtau", "dq_dmu", "dv_dmu")},
        modes=tuple(out["modes"]), boundary=boundary, contact_names=tuple(contact_names))
