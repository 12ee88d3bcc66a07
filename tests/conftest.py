import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import stiction  # noqa: F401  (loads pinocchio + the compiled core once)

ROOT = Path(__file__).resolve().parents[1]
FCLIB_DIR = ROOT / "benchmarks" / "fclib"
FCLIB_FILES = sorted(p.name for p in FCLIB_DIR.iterdir() if p.suffix in (".hdf5", ".dat"))
SOLVERS = ["default", "nsgs", "newton", "admm"]


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


def spd(rng, n, cond=10.0):
    """A random SPD matrix with the given condition number."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.geomspace(1.0, 1.0 / cond, n)) @ Q.T


def run_with_kernels(code, kernels, *args):
    """Run a Python snippet in a fresh process with STICTION_VECTOR_KERNELS set ("0": the portable
    loops, "1": the AVX2/FMA kernels where the processor has them); its stdout, after checking it
    exited cleanly."""
    env = dict(os.environ, STICTION_VECTOR_KERNELS=kernels)
    out = subprocess.run([sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr
    return out.stdout
