"""The paper's case studies (Kikuuwe & Brogliato §3-§5) as runnable, checked experiments.

Each case study is a module of this package with

- ``NAME`` (the CLI name), ``TITLE``, ``EQUATIONS`` (the paper's equation numbers, e.g. "94-104"),
- ``run(quick: bool = False) -> CaseStudyResult``: the sweep, its points and its checks, each
  check a measured number against the expected one (closed form, or the paper's claim) with a
  tolerance; ``quick`` runs a smaller sweep with the same checks (used by the tests),
- ``plot(result, path)``: the figure (matplotlib, the ``plot`` extra).

``stiction casestudy NAME [--plot FILE.png] [--json] [--quick]`` runs one; the exit code is 1
when a check fails. The JSON is ``CaseStudyResult.to_json()``:
``{name, title, equations, passed, checks: [{quantity, measured, expected, error, tolerance,
passed}], points: [...], notes}``. docs/casestudies/ has a page per case study (its points,
measured numbers, figure) and an index (README.md).
"""
from __future__ import annotations

import importlib
import math
from dataclasses import asdict, dataclass, field
from typing import Any

# CLI name -> module of this package. Adding a case study: a module and a line here.
_MODULES = {
    "planar-friction": "planar_friction",
    "restitution": "restitution",
    "painleve": "painleve",
    "pendulum": "pendulum",
    "kinematic-levels": "kinematic_levels",
    "diagonal-push": "diagonal_push",
    "slide-lift": "slide_lift",
    "identify-friction": "identify_friction",
}


@dataclass
class Check:
    """One number the case study promises: |measured - expected| <= tolerance (or a bound).

    ``error`` is |measured - expected| unless the check is a bound (``kind`` "<=" or ">="),
    where it is how far measured is past expected (0 when the bound holds)."""

    quantity: str
    measured: float
    expected: float
    tolerance: float
    kind: str = "=="  # "==": |measured - expected| <= tolerance; "<=", ">=": a bound (tolerance: slack)
    error: float = field(default=math.nan)
    passed: bool = field(default=False)

    def __post_init__(self):
        m, e, tol = float(self.measured), float(self.expected), float(self.tolerance)
        self.measured, self.expected, self.tolerance = m, e, tol
        if self.kind == "==":
            self.error = abs(m - e)
        elif self.kind == "<=":
            self.error = max(0.0, m - e)
        elif self.kind == ">=":
            self.error = max(0.0, e - m)
        else:
            raise ValueError(f"check {self.quantity!r}: unknown kind {self.kind!r} (==, <=, >=)")
        self.passed = bool(math.isfinite(m) and self.error <= tol)


@dataclass
class CaseStudyResult:
    name: str
    title: str
    equations: str
    checks: list[Check]
    points: list[dict[str, Any]]
    notes: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return bool(self.checks) and all(c.passed for c in self.checks)

    def to_json(self) -> dict:
        return {
            "name": self.name,
            "title": self.title,
            "equations": self.equations,
            "passed": self.passed,
            "checks": [asdict(c) for c in self.checks],
            "points": [_plain(p) for p in self.points],
            "notes": list(self.notes),
        }


def _plain(x):
    """numpy scalars and arrays -> JSON types; non-finite floats -> None."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if hasattr(x, "tolist"):
        return _plain(x.tolist())
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    return x


def names() -> list[str]:
    return list(_MODULES)


def module(name: str):
    """The module of case study `name`; ValueError naming the known ones (and the closest)."""
    if name not in _MODULES:
        from ..scene_schema import did_you_mean

        raise ValueError(f"unknown case study {name!r} ({did_you_mean(name, _MODULES)}"
                         f"known: {', '.join(_MODULES)})")
    return importlib.import_module(f"{__name__}.{_MODULES[name]}")


def run(name: str, quick: bool = False) -> CaseStudyResult:
    return module(name).run(quick=quick)
