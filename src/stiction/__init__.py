"""stiction: exact Coulomb contact for robots (Kikuuwe & Brogliato's eq. 65), on Pinocchio.

The compiled core (``stiction._core``) holds the contact problem and its solvers;
this package adds the Python conveniences: :func:`solve`, FCLib I/O and the CLI.
"""
# Pinocchio first: it loads eigenpy and Boost.Python, whose converters the core shares.
import pinocchio as _pinocchio  # noqa: F401

from ._core import (  # noqa: F401
    Constraint,
    ConstraintKind,
    ContactProblem,
    ContactState,
    ExactLawMeasures,
    Formulation,
    FormulationSettings,
    SolveStatus,
    Solver,
    SolverResult,
    SolverSettings,
    StageReport,
    WarmStart,
    exact_law_measures,
    residual,
    rk4_stable_step,
    solver_names,
)
from .formulations import formulation_infos, formulation_names  # noqa: F401
from .solve import reset_solvers, solve, spatial_problem  # noqa: F401

__version__ = "0.1.0"
