"""Convenience entry points around the compiled solvers."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ._core import Constraint, ContactProblem, Solver, SolverResult, SolverSettings, WarmStart

_solvers: dict[str, Solver] = {}


def _as_float_array(x, name: str, ndim: int) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be numeric: {exc}") from None
    if a.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-D, got shape {a.shape}")
    return np.ascontiguousarray(a) if ndim == 1 else np.asfortranarray(a)


def spatial_problem(A, b, mu: float | Sequence[float], asymmetry_tolerance: float = 1e-9) -> ContactProblem:
    """A problem made only of spatial friction contacts (rows t1, t2, n per contact)."""
    A = _as_float_array(A, "A", 2)
    b = _as_float_array(b, "b", 1)
    if A.shape[0] % 3:
        raise ValueError(f"A has {A.shape[0]} rows, not a multiple of 3 (spatial contacts)")
    nc = A.shape[0] // 3
    mus = np.broadcast_to(np.asarray(mu, dtype=np.float64), (nc,))
    return ContactProblem(A, b, [Constraint.spatial_friction(float(m)) for m in mus], asymmetry_tolerance)


def solve(
    problem: ContactProblem,
    solver: str = "default",
    tol: float = 1e-10,
    max_iter: int = 2000,
    warm_start: str | np.ndarray | None = None,
    time_limit: float = 0.0,
) -> SolverResult:
    """Solve A lambda - b in -lim N_C^{U_eps}(lambda) (eq. 65).

    warm_start: None (lambda = 0), "proxqp" (facetized-cone QP by ProxQP), or an
    array lambda_0 (e.g. the previous step's solution).
    The solver objects (and their workspaces) are reused across calls.
    """
    settings = SolverSettings()
    settings.tolerance = float(tol)
    settings.max_iterations = int(max_iter)
    settings.time_limit = float(time_limit)
    guess = None
    if warm_start is None:
        settings.warm_start = WarmStart.none
    elif isinstance(warm_start, str):
        if warm_start != "proxqp":
            raise ValueError(f"warm_start must be None, 'proxqp' or an array, got {warm_start!r}")
        settings.warm_start = WarmStart.proxqp
    else:
        guess = _as_float_array(warm_start, "warm_start", 1)
        settings.warm_start = WarmStart.given
    if solver not in _solvers:
        _solvers[solver] = Solver(solver)
    return _solvers[solver].solve(problem, settings, guess)
