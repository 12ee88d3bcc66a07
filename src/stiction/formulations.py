"""The formulations: ways to turn one step's (A, b, blocks) into impulses (docs/formulations.md).

``exact`` is the paper's (eq. 65 = De Saxcé's NCP); ``ccp`` (eq. 78-79), ``nakaoka`` (eq. 80-81),
``pyramid`` (§4.5), ``penalty`` (eq. 83-84) and Pinocchio's own solvers are the alternatives the
paper discusses, behind the same interface. Each result is judged by the exact law
(``result.residual``, ``result.converged``, :func:`stiction.exact_law_measures`) and carries the
formulation's own verdict (``result.own_converged``, ``own_residual``, ``own_law``).
"""
from __future__ import annotations

import math
import numbers

import numpy as np

from . import _core

# Parameters a formulation takes, and the formulation they belong to.
PARAMETERS = {
    "pyramid_facets": "pyramid",
    "pyramid_inscribed": "pyramid",
    "pyramid_max_fixed_point": "pyramid",
    "penalty_stiffness": "penalty",
    "penalty_damping": "penalty",
}


def formulation_infos() -> list[dict]:
    """One dict per formulation: name, equations (the paper's), summary, parameters."""
    return _core.formulation_infos()


def formulation_names() -> list[str]:
    return [f["name"] for f in _core.formulation_infos()]


def check_name(name) -> str:
    from .scene_schema import did_you_mean

    names = formulation_names()
    if not isinstance(name, str):
        raise TypeError(f"formulation must be a name (str), got {type(name).__name__}")
    if name not in names:
        raise ValueError(f"unknown formulation {name!r} ({did_you_mean(name, names)}known: {', '.join(names)})")
    return name


def settings_for(name: str, params: dict) -> "_core.FormulationSettings":
    """FormulationSettings for formulation `name` with `params` (keys of PARAMETERS, None = default).
    A parameter of another formulation is an error: it would silently change nothing."""
    fs = _core.FormulationSettings()
    for key, value in params.items():
        if value is None:
            continue
        if key not in PARAMETERS:
            raise TypeError(f"unknown formulation parameter {key!r} (known: {', '.join(PARAMETERS)})")
        owner = PARAMETERS[key]
        if owner != name:
            raise ValueError(f"{key} applies to the {owner} formulation, not to {name!r}")
        if key in ("pyramid_facets", "pyramid_max_fixed_point"):
            low, high = (3, _core.MAX_FACETS) if key == "pyramid_facets" else (1, None)
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Integral, np.integer)):
                raise TypeError(f"{key} must be an integer, got {type(value).__name__} {value!r}")
            if value < low or (high is not None and value > high):
                # (facets: an N-facet pyramid is within pi^2 / (2 N^2) of the cone, 4.7e-6 of mu at 1024,
                # and each facet is a dense QP row per contact: more buy nothing and exhaust memory)
                raise ValueError(f"{key} must be an integer " + (f">= {low}" if high is None else f"between {low} and {high}")
                                 + f", got {value!r}")
            value = int(value)
        elif key == "pyramid_inscribed":
            if not isinstance(value, (bool, np.bool_)):
                raise TypeError(f"pyramid_inscribed must be True or False, got {value!r}")
            value = bool(value)
        else:
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
                raise TypeError(f"{key} must be a number, got {type(value).__name__}")
            value = float(value)
            if not math.isfinite(value) or value < 0 or (value == 0 and key == "penalty_stiffness"):
                raise ValueError(f"{key} must be a finite number {'>' if key == 'penalty_stiffness' else '>='} 0, "
                                 f"got {value!r}")
        setattr(fs, key, value)
    return fs
