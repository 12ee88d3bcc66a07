"""Benchmarks that ship with the package (``stiction bench NAME``): each prints JSON rows, writes a
resumable CSV and PNG charts with ``--out`` (see :mod:`stiction.bench.sweep` for the contract).

- ``scaling``: cost per step against contact count (issue: scale);
- ``work-precision``: error against the exact answer vs wall time per simulated second, per method;
- ``profiles``: the solvers alone on problem sets (FCLib, the robot set): performance profiles;
- ``stability``: where each method fails, as maps of its first failure mode;
- ``creep``: slip of a body friction must hold (grasp, ramp, slope) against the friction margin.
"""
from __future__ import annotations

import importlib
from types import ModuleType

BENCHES = {"scaling": "scaling", "work-precision": "work_precision", "profiles": "profiles",
           "stability": "stability", "creep": "creep"}

# `stiction bench all --out DIR`: every figure of docs/benchmarks.md
ALL_RUNS = (
    ("scaling", "--sizes", "4", "16", "64", "128", "256", "512", "1024"),
    ("scaling", "--layout", "tower", "--sizes", "4", "16", "64", "128", "256", "512", "1024"),
    ("work-precision",),
    ("profiles",),
    ("stability",),
    ("creep",),
)


def available_benches() -> list[str]:
    """The bench names whose module is present."""
    names = []
    for name, mod in BENCHES.items():
        try:
            importlib.import_module(f"{__name__}.{mod}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{mod}":
                raise
            continue
        names.append(name)
    return names


def load_bench(name: str) -> ModuleType:
    if name not in BENCHES:
        raise ValueError(f"unknown bench {name!r}: one of {', '.join(BENCHES)}")
    return importlib.import_module(f"{__name__}.{BENCHES[name]}")
