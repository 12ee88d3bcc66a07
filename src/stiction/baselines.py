"""Pinocchio 4.1's own constraint solvers (ADMM, PGS) run on a stiction ContactProblem.

These are the baselines stiction is measured against. Pinocchio solves

    K ∋ λ ⟂ u + Φ(u) ∈ K*,   u = G λ + g    (Φ: De Saxcé's shift when solve_ncp, else 0),

so for stiction's  u = A λ − b  the adapter passes  G = A,  g = −b.  Rows follow the same
convention in both libraries: each spatial contact is (t1, t2, n), normal last.

Block mapping (stiction → Pinocchio):

- ``spatial_friction(mu)``  → ``PointContactConstraintModel`` with ``setFriction(mu)``;
- ``bilateral(3)``          → ``PointAnchorConstraintModel`` (3 free impulse rows);
- ``bilateral(6)``          → ``FrameAnchorConstraintModel`` (6 free impulse rows).

The solvers use the constraint models only for their sizes and cones when the Delassus
operator is given as a dense matrix, so the models are attached to a one-joint dummy
``pin.Model`` and ``calc`` is never called (checked: λ is bit-identical with and without
``calc`` on the cube and two-cube problems of :mod:`stiction.problems`).

Every result is judged by stiction's common accuracy measure, :func:`stiction.residual`,
not by the solver's own stopping test.

Non-symmetric A (some FCLib files): Pinocchio's dense Delassus factorization reads only the
lower triangle, so ADMM converges to the problem whose A is the lower triangle mirrored, and
its residual against the stored A stays near the asymmetry (checked on Rover1039: 1e-12 on the
mirrored A, 1.2e-5 on the stored one). PGS works on (A + Aᵀ)/2.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ._core import ConstraintKind, ContactProblem, residual

# PGS symmetrizes G in an n x n buffer on the stack (alloca in pinocchio's enforceSymmetry):
# 8 n^2 bytes overflow the default 8 MiB stack, a segfault from about 1024 rows.
PGS_MAX_ROWS = 1000
# Lanczos steps ADMM spends estimating the largest Delassus eigenvalue (its initial rho).
# Pinocchio's default (INT_MAX) runs a full-size Lanczos, seconds at 1000+ rows.
ADMM_LANCZOS_SIZE = 20

_METHODS = ("admm", "pgs")


@dataclass
class BaselineResult:
    """One solve by a Pinocchio solver.

    lam:              the impulses λ (ADMM: its projected iterate y), stiction's row order.
    iterations:       iterations the solver reports.
    converged:        the solver's own claim (its stopping test), not checked here.
    seconds:          wall time of the ``solver.solve`` call alone (``time.perf_counter``);
                      building the Delassus operator and reading λ back are excluded.
    internal_seconds: the solver's own timer (``getElapsedTime``, ``measure_timings=True``).
    residual:         ``stiction.residual(problem, lam)``, the measure shared by every solver.
    """

    lam: np.ndarray
    iterations: int
    converged: bool
    seconds: float
    internal_seconds: float
    residual: float


@dataclass
class _Workspace:
    """Constraint models/datas and one solver + result object per method, for one layout."""

    models: pin.StdVec_ConstraintModel
    datas: pin.StdVec_ConstraintData
    solvers: dict
    results: dict


@functools.lru_cache(maxsize=1)
def _dummy_model() -> pin.Model:
    """A one-body model (one free-flyer joint) for the constraint models to refer to."""
    model = pin.Model()
    joint = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "root")
    model.appendBodyToJoint(joint, pin.Inertia.FromBox(1.0, 0.1, 0.1, 0.1), pin.SE3.Identity())
    return model


def _layout(problem: ContactProblem) -> tuple:
    """The problem's block structure: one (kind name, size, mu) per block. ValueError on a
    block Pinocchio's solvers cannot represent."""
    blocks = []
    for i, c in enumerate(problem.constraints):
        if c.kind == ConstraintKind.spatial_friction:
            blocks.append(("spatial_friction", 3, float(c.mu)))
        elif c.kind == ConstraintKind.bilateral and c.size in (3, 6):
            blocks.append(("bilateral", int(c.size), 0.0))
        elif c.kind == ConstraintKind.box:
            raise ValueError(f"block {i} is a box row (joint friction, effort limits): Pinocchio's solvers "
                             "take cones and anchors only; use the exact formulation")
        else:
            raise ValueError(
                f"block {i} ({c.kind.name}, {c.size} rows) has no Pinocchio counterpart; "
                "supported: spatial_friction, bilateral(3), bilateral(6)")
    return tuple(blocks)


@functools.lru_cache(maxsize=64)
def _workspace(layout: tuple) -> _Workspace:
    """Constraint models and solvers for a layout, built once and reused across calls."""
    model = _dummy_model()
    joint = model.njoints - 1
    models, datas = pin.StdVec_ConstraintModel(), pin.StdVec_ConstraintData()
    for kind, size, mu in layout:
        if kind == "spatial_friction":
            cm = pin.PointContactConstraintModel(model, joint)
            cm.setFriction(mu)
        elif size == 3:
            cm = pin.PointAnchorConstraintModel(model, joint)
        else:
            cm = pin.FrameAnchorConstraintModel(model, joint)
        models.append(cm)  # the vector stores a generic ConstraintModel (a copy)
    for cm in models:
        datas.append(cm.createData())
    n = sum(size for _, size, _ in layout)
    return _Workspace(
        models, datas,
        solvers={"admm": pin.ADMMConstraintSolver(n), "pgs": pin.PGSConstraintSolver(n)},
        results={"admm": pin.ADMMSolverResult(), "pgs": pin.PGSSolverResult()},
    )


def _settings(method: str, n: int, tol: float, max_iter: int, solve_ncp: bool):
    s = pin.ADMMSolverSettings() if method == "admm" else pin.PGSSolverSettings()
    s.max_iterations = int(max_iter)
    s.absolute_feasibility_tol = tol
    s.relative_feasibility_tol = tol
    s.absolute_complementarity_tol = tol
    s.relative_complementarity_tol = tol
    s.solve_ncp = bool(solve_ncp)
    s.measure_timings = True
    if hasattr(s, "lanczos_size"):
        s.lanczos_size = min(ADMM_LANCZOS_SIZE, n)
    return s


def pinocchio_solve(problem: ContactProblem, method: str = "admm", tol: float = 1e-10,
                    max_iter: int = 1000, lam0: np.ndarray | None = None, solve_ncp: bool = True,
                    allow_large: bool = False) -> BaselineResult:
    """Solve ``problem`` with Pinocchio's ADMM or PGS on the dense Delassus G = A, g = −b.

    tol sets all four stopping tolerances (absolute/relative feasibility and complementarity);
    Pinocchio's tests are ∞-norm tests of its own quantities, so ``converged`` may disagree with
    ``residual``. lam0 warm-starts the impulses. solve_ncp=True solves the exact Coulomb problem
    (De Saxcé correction), False its convex relaxation. PGS above 1000 rows is refused (it
    segfaults) unless allow_large=True. Raises ValueError for unsupported blocks or methods.
    """
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    n = problem.num_rows
    if method == "pgs" and n > PGS_MAX_ROWS and not allow_large:
        raise ValueError(f"Pinocchio PGS crashes on large problems; this one has {n} rows "
                         f"(> {PGS_MAX_ROWS}); pass allow_large=True to try anyway")
    ws = _workspace(_layout(problem))
    solver, result = ws.solvers[method], ws.results[method]
    settings = _settings(method, n, float(tol), max_iter, solve_ncp)
    if lam0 is None:
        result.clearConstraintImpulseGuess()
    else:
        lam0 = np.ascontiguousarray(lam0, dtype=np.float64)
        if lam0.shape != (n,):
            raise ValueError(f"lam0 must have shape ({n},), got {lam0.shape}")
        result.setConstraintImpulseGuess(lam0)
    # A fresh operator per call: ADMM adds its proximal damping to the operator it is given.
    G = pin.DelassusOperatorDense(np.asfortranarray(problem.A))
    g = -np.asarray(problem.b, dtype=np.float64)

    t0 = time.perf_counter()
    converged = solver.solve(G, g, ws.models, ws.datas, settings, result)
    seconds = time.perf_counter() - t0

    lam = np.array(result.retrieveConstraintImpulses(), dtype=np.float64)
    return BaselineResult(
        lam=lam,
        iterations=int(result.iterations),
        converged=bool(converged),
        seconds=seconds,
        internal_seconds=solver.getElapsedTime() * 1e-6,
        residual=float(residual(problem, lam)),
    )
