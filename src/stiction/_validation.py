"""Checks of user input shared by several modules (the scene loader, the simulator front, the CLI and
the benches). It imports nothing of the package, so any module may import it at its top: these
checks used to live in cli.py and simulator.py, and their users imported them inside functions to
dodge import circles (bench/sweep.py <-> cli.py, scene.py <-> simulator.py)."""
from __future__ import annotations

import argparse
import math

import numpy as np


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1 (--max-iter, --workers, --pyramid-facets, ...)."""
    try:
        x = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if x < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: must be >= 1")
    return x


def positive(name: str, value, allow_zero: bool = False) -> float:
    """A finite real number > 0 (>= 0 with allow_zero) as a float: TypeError for a non-number (bool,
    str, None), ValueError for NaN, infinity or a value out of range, naming `name`."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise TypeError(f"{name} must be a number, got {type(value).__name__} {value!r}")
    x = float(value)
    if not math.isfinite(x) or x < 0 or (x == 0 and not allow_zero):
        raise ValueError(f"{name} must be a finite number {'>=' if allow_zero else '>'} 0, got {value!r}")
    return x


def vector(name: str, x, n: int) -> np.ndarray:
    """x as a float64 array of shape (n,) with finite entries: TypeError for None, str or a
    non-real dtype, ValueError for another shape or a NaN / infinite entry, naming `name`."""
    if x is None or isinstance(x, (str, bytes)):
        raise TypeError(f"{name} must be an array of {n} numbers, got {type(x).__name__}")
    a = np.asarray(x)
    if a.dtype.kind not in "biuf":
        raise TypeError(f"{name} must be an array of {n} real numbers, got dtype {a.dtype}")
    a = a.astype(np.float64).reshape(-1) if a.ndim <= 1 else a
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {np.shape(x)}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} has NaN or infinite entries")
    return a
