"""A saved pile step (benchmarks/data/pile256-step159.hdf5, FCLib local): 342 rows in 100 independent
islands of at most 2 contacts, one of them a convex hull on the floor by an edge whose two normal rows
correlate at 0.973 in A. Gauss-Seidel improves on it all along but needs ~300 sweeps; within the
simulator's budget (200 iterations) the default must still converge to its tolerance (1e-10): its NSGS
hands over when the rate says the budget will not suffice (default_solver.cpp). Checked by an
independent natural map in numpy (De Saxce's, eq. 73-77)."""
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

import stiction
from stiction import fclib

FILE = Path(__file__).resolve().parent.parent / "benchmarks" / "data" / "pile256-step159.hdf5"
TOL = 1e-10
SIMULATOR_BUDGET = 200  # the simulator's max_iterations


def _natural_map(A, b, lam, mu):
    """De Saxce's natural map, blocks (t1, t2, n) with u = A lam - b, its norm / ||b||."""
    L, U = lam.reshape(-1, 3), (A @ lam - b).reshape(-1, 3)
    Z = L - U
    Z[:, 2] -= mu * np.linalg.norm(U[:, :2], axis=1)
    zt, zn = np.linalg.norm(Z[:, :2], axis=1), Z[:, 2]
    P = np.zeros_like(Z)
    inside, polar = (zt <= mu * zn) & (zn >= 0), mu * zt <= -zn
    mid = ~(inside | polar)
    P[inside] = Z[inside]
    s = (mu[mid] * zt[mid] + zn[mid]) / (1 + mu[mid] ** 2)
    P[mid, 2] = s
    P[mid, :2] = (mu[mid] * s / zt[mid])[:, None] * Z[mid, :2]
    return np.linalg.norm(L - P) / np.linalg.norm(b)


@pytest.fixture(scope="module")
def saved():
    return fclib.load(FILE)


def test_the_saved_step_is_many_small_islands(saved):
    blocks = sp.csr_matrix((np.abs(saved.A) > 0).reshape(saved.contacts, 3, saved.contacts, 3).any(axis=(1, 3)))
    count, labels = connected_components(blocks, directed=False)
    assert saved.A.shape == (342, 342) and count == 100 and np.bincount(labels).max() <= 2


@pytest.mark.parametrize("start", ["cold", "file guess"])
def test_default_converges_within_the_simulator_budget(saved, start):
    kw = {} if start == "cold" else {"warm_start": saved.guess}
    r = stiction.solve(saved.problem(), tol=TOL, max_iter=SIMULATOR_BUDGET, **kw)
    assert r.converged, r.message
    assert r.iterations <= SIMULATOR_BUDGET
    assert _natural_map(saved.A, saved.b, r.lam, saved.mu) <= TOL
