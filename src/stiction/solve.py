"""Convenience entry points around the compiled solvers."""
from __future__ import annotations

import math
import numbers
import threading
from typing import Sequence

import numpy as np

from ._core import (Constraint, ContactProblem, Formulation, Solver, SolverResult, SolverSettings, WarmStart,
                    solver_names)

class _PerThread(threading.local):
    """Solver and Formulation objects hold workspaces and run with the GIL released: each thread
    keeps its own, so stiction.solve may be called from several threads at once. This is hidden
    state (reset_solvers() drops it): see solve()'s docstring."""

    def __init__(self):
        self.solvers: dict[str, Solver] = {}
        self.formulations: dict[tuple, Formulation] = {}


_cache = _PerThread()


def reset_solvers() -> None:
    """Drop the Solver and Formulation objects that :func:`solve` keeps for the calling thread.

    What they keep between calls is the only state one solve passes to the next: their
    workspaces, and the default solver's held sticking factor (the factorization of A + rho I of
    an earlier call, tried first while A's diagonal stays within 1e-3 of it: a simulation's next
    step; docs/solvers.md). It can change which stage converges and the last bits of the result.
    After reset_solvers() the next solve on this thread gives what it gives in a fresh process.
    (The verdict's cache lives for one solve only; settings are never cached by value that
    matters: every call passes all of its settings.) Other threads keep theirs.
    """
    _cache.solvers.clear()
    _cache.formulations.clear()


def _type_name(x) -> str:
    if isinstance(x, np.ndarray):
        return f"{x.dtype} ndarray of shape {x.shape}"
    return type(x).__name__


def _as_float_array(x, name: str, ndim: int) -> np.ndarray:
    """x as a float64 array of `ndim` dimensions: TypeError for None, str, complex or
    non-numeric entries, ValueError for the wrong number of dimensions."""
    if x is None or isinstance(x, (str, bytes)):
        raise TypeError(f"{name} must be a {ndim}-D array of floats, got {_type_name(x)}")
    try:
        a = np.asarray(x)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a {ndim}-D array of floats: {exc}") from None
    if np.iscomplexobj(a):
        raise TypeError(f"{name} must be real, got a complex array")
    if a.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be numeric, got {_type_name(x)} (dtype {a.dtype})")
    if a.ndim != ndim:
        raise ValueError(f"{name} must be {ndim}-D, got shape {a.shape}")
    a = a.astype(np.float64, copy=False)
    return np.ascontiguousarray(a) if ndim == 1 else np.asfortranarray(a)


def _real(x, name: str) -> float:
    """A real number: int, float or a numpy real scalar; not bool, None, str or complex."""
    if type(x) is float or type(x) is int:  # the common case, checked first (solve() is called per step)
        return float(x)
    if not isinstance(x, (bool, np.bool_)):
        if isinstance(x, (numbers.Real, np.floating, np.integer)):
            return float(x)
        if isinstance(x, np.ndarray) and x.ndim == 0 and x.dtype.kind in "iuf":
            return float(x)
    raise TypeError(f"{name} must be a real number, got {_type_name(x)}")


def _integer(x, name: str) -> int:
    if type(x) is int:
        return x
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, (numbers.Integral, np.integer)):
        raise TypeError(f"{name} must be an integer, got {_type_name(x)}"
                        + (f" {x!r}" if isinstance(x, float) else ""))
    return int(x)


def spatial_problem(A, b, mu: float | Sequence[float], asymmetry_tolerance: float = 1e-9) -> ContactProblem:
    """A problem made only of spatial friction contacts (rows t1, t2, n per contact)."""
    A = _as_float_array(A, "A", 2)
    b = _as_float_array(b, "b", 1)
    if A.shape[0] % 3:
        raise ValueError(f"A has {A.shape[0]} rows, not a multiple of 3 (spatial contacts)")
    nc = A.shape[0] // 3
    mus = np.asarray(mu)
    if np.iscomplexobj(mus) or mus.dtype.kind not in "biuf":
        raise TypeError(f"mu must be a real number or one per contact, got {_type_name(mu)}")
    try:
        mus = np.broadcast_to(mus.astype(np.float64), (nc,))
    except ValueError:
        raise ValueError(f"mu must be one number or {nc} (one per contact), got shape {mus.shape}") from None
    return ContactProblem(A, b, [Constraint.spatial_friction(float(m)) for m in mus], asymmetry_tolerance)


def solve(
    problem: ContactProblem,
    solver: str = "default",
    tol: float = 1e-10,
    max_iter: int = 2000,
    warm_start: str | np.ndarray | None = None,
    time_limit: float = 0.0,
    formulation: str = "exact",
    h: float | None = None,
    position_error=None,
    **formulation_parameters,
) -> SolverResult:
    """Solve A lambda - b in -lim N_C^{U_eps}(lambda) (eq. 65), or resolve the problem by another
    formulation (docs/formulations.md).

    tol: on the relative natural map plus its rounding bound (result.converged means the
    exact natural map at result.lam is within tol * ||b||; docs/solvers.md).
    warm_start: None (lambda = 0), "proxqp" (facetized-cone QP by ProxQP), or an
    array lambda_0 (e.g. the previous step's solution).
    time_limit: seconds for the whole solve, every stage included (0: none); every formulation
    keeps it, Pinocchio's solvers by running in chunks of iterations.

    Hidden state: the solver objects (and their workspaces) are reused across calls, one set per
    thread (the solve runs with the GIL released, so threads solve in parallel). The default
    solver keeps its sticking step's factor between calls and tries it first on the next problem
    whose A has nearly the same diagonal, so a call may end differently (another stage, other last
    bits) after an earlier call than in a fresh process. ``stiction.reset_solvers()`` drops this
    thread's objects; a caller who wants the state in its own hands uses its own
    ``stiction.Solver(name)`` / ``stiction.Formulation(name, settings)`` objects (each with
    ``reset()``) instead of this function. Every setting is passed whole at every call: none is
    remembered from an earlier one.
    Wrong kinds of argument raise TypeError, wrong values ValueError, naming the argument.

    formulation: "exact" (default; `solver` picks the algorithm) or ccp, nakaoka, pyramid, penalty,
    pinocchio-admm, pinocchio-pgs, pinocchio-admm-ccp (stiction.formulation_names()).
    Whatever the formulation, result.residual / converged / status judge lambda by the exact law;
    result.own_converged / own_residual / own_law are the formulation's own verdict.
    formulation_parameters: pyramid_facets (3 .. 1024), pyramid_inscribed, pyramid_max_fixed_point
    (pyramid), penalty_stiffness, penalty_damping (penalty). h: the step the impulses span (penalty needs it: its springs have
    units); position_error: Psi per row (penalty: the gaps, which u = A P - b contains as Psi / h).
    """
    if not isinstance(problem, ContactProblem):
        raise TypeError(f"solve: problem must be a stiction.ContactProblem, got {_type_name(problem)}")
    if not isinstance(solver, str):
        raise TypeError(f"solve: solver must be a name (str), got {_type_name(solver)}")
    if solver not in _cache.solvers and solver not in solver_names():
        raise ValueError(f"unknown solver '{solver}' (known: {', '.join(solver_names())})")
    tol = _real(tol, "solve: tol")
    if not (tol > 0 and math.isfinite(tol)):
        raise ValueError(f"solve: tol (the tolerance) must be a positive finite number, got {tol}")
    max_iter = _integer(max_iter, "solve: max_iter")
    if max_iter < 0:
        raise ValueError(f"solve: max_iter must be >= 0, got {max_iter}")
    time_limit = _real(time_limit, "solve: time_limit")
    if not (time_limit >= 0 and math.isfinite(time_limit)):
        raise ValueError(f"solve: time_limit must be a finite number of seconds >= 0 (0: none), got {time_limit}")
    guess = None
    if warm_start is None:
        start = WarmStart.none
    elif isinstance(warm_start, str):
        if warm_start != "proxqp":
            raise ValueError(f"solve: warm_start must be None, 'proxqp' or an array, got {warm_start!r}")
        start = WarmStart.proxqp
    else:
        guess = _as_float_array(warm_start, "solve: warm_start (initial lambda)", 1)
        if guess.shape[0] != problem.num_rows:
            raise ValueError(f"solve: warm_start: initial lambda has {guess.shape[0]} entries, "
                             f"the problem has {problem.num_rows} rows")
        start = WarmStart.given
    settings = _settings(tol, max_iter, time_limit, start)
    if formulation != "exact" or formulation_parameters or h is not None or position_error is not None:
        return _solve_formulation(problem, solver, settings, guess, formulation, h, position_error,
                                  formulation_parameters)
    solvers = _cache.solvers
    if solver not in solvers:
        solvers[solver] = Solver(solver)
    return solvers[solver].solve(problem, settings, guess)


_settings_cache: dict[tuple, SolverSettings] = {}


def _settings(tol: float, max_iter: int, time_limit: float, start) -> SolverSettings:
    """SolverSettings for these values, built once and reused (the C++ solve takes a copy; building
    and filling one through the bindings costs ~5 µs, as much as solving a small problem)."""
    key = (tol, max_iter, time_limit, int(start))
    settings = _settings_cache.get(key)
    if settings is None:
        if len(_settings_cache) > 256:
            _settings_cache.clear()
        settings = SolverSettings()
        settings.tolerance = tol
        settings.max_iterations = max_iter
        settings.time_limit = time_limit
        settings.warm_start = start
        _settings_cache[key] = settings
    return settings


def _solve_formulation(problem, solver, settings, guess, formulation, h, position_error, params) -> SolverResult:
    from .formulations import check_name, settings_for

    formulation = check_name(formulation)
    fs = settings_for(formulation, params)
    if formulation == "exact":
        fs.exact_solver = solver
    elif solver != "default":
        raise ValueError(f"solve: solver={solver!r} picks the exact law's algorithm; the {formulation} "
                         "formulation has its own")
    if h is None:
        if formulation == "penalty":
            raise ValueError("solve: the penalty formulation needs h, the step the impulses span (its spring "
                             "stiffness K and damping beta have units)")
        h = 1.0
    h = _real(h, "solve: h")
    if not (h > 0 and math.isfinite(h)):
        raise ValueError(f"solve: h must be a positive finite number of seconds, got {h}")
    if position_error is not None:
        position_error = _as_float_array(position_error, "solve: position_error", 1)
        if position_error.shape[0] != problem.num_rows:
            raise ValueError(f"solve: position_error has {position_error.shape[0]} entries, the problem has "
                             f"{problem.num_rows} rows")
        if not np.isfinite(position_error).all():
            raise ValueError("solve: position_error has NaN or infinite entries")
    key = (formulation, solver, tuple(sorted((k, v) for k, v in params.items() if v is not None)))
    cache = _cache.formulations
    f = cache.get(key)
    if f is None:
        if len(cache) > 64:
            cache.clear()
        f = cache[key] = Formulation(formulation, fs)
    return f.solve(problem, settings, guess, h, position_error)
