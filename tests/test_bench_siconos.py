"""The Siconos driver (stiction.bench.siconos), shared by ``stiction bench profiles`` and
benchmarks/bench_siconos.py, against a stand-in ``siconos.numerics`` (Siconos is a Debian package,
not on PyPI): what it hands Siconos is in Siconos' (n, t1, t2) order with q = -b, what it returns is
in stiction's (t1, t2, n) order, its repeat rule and its failures."""
from __future__ import annotations

import math
import sys
import textwrap

import numpy as np
import pytest

from conftest import FCLIB_DIR
from stiction import fclib
from stiction.bench import siconos

# NSGS echoes q, NSN-AC labels each contact's components by Siconos' layout (n = 1, t1 = 2, t2 = 3),
# PROX never returns (time limit); a tolerance of 0.5 kills the process (crash). The iteration count
# is the number of solves of this request.
FAKE = '''
import os, time
import numpy as np
SICONOS_FRICTION_3D_NSGS, SICONOS_FRICTION_3D_NSN_AC, SICONOS_FRICTION_3D_PROX = 0, 1, 2
SICONOS_IPARAM_MAX_ITER, SICONOS_IPARAM_ITER_DONE, SICONOS_DPARAM_TOL, SICONOS_DPARAM_RESIDU = 0, 1, 0, 1
CALLS = {}

class FrictionContactProblem:
    def __init__(self, dim, W, q, mu):
        self.W, self.q, self.mu, self.numberOfContacts = W, np.asarray(q), np.asarray(mu), len(mu)
        CALLS[id(self)] = 0

def frictionContact_new_from_filename(path):  # only its size matters here
    from stiction import fclib
    nc = fclib.load(path).contacts
    return FrictionContactProblem(3, None, np.zeros(3 * nc), np.zeros(nc))

class SolverOptions:
    def __init__(self, sid):
        self.sid, self.iparam, self.dparam = sid, np.zeros(4, dtype=int), np.zeros(4)

def fc3d_driver(problem, r, u, so):
    CALLS[id(problem)] += 1
    if so.dparam[SICONOS_DPARAM_TOL] == 0.5:
        os._exit(3)
    if so.sid == SICONOS_FRICTION_3D_PROX:
        time.sleep(3600)
    r[:] = problem.q if so.sid == SICONOS_FRICTION_3D_NSGS else np.tile([1.0, 2.0, 3.0], len(r) // 3)
    so.iparam[SICONOS_IPARAM_ITER_DONE] = CALLS[id(problem)]
    return 0
'''


@pytest.fixture
def server(tmp_path):
    (tmp_path / "siconos").mkdir()
    (tmp_path / "siconos" / "__init__.py").write_text("")
    (tmp_path / "siconos" / "numerics.py").write_text(FAKE)
    python = tmp_path / "python"
    python.write_text(textwrap.dedent(f"""\
        #!/bin/sh
        PYTHONPATH={tmp_path} exec {sys.executable} "$@"
        """))
    python.chmod(0o755)
    assert siconos.usable(str(python)) and not siconos.usable(str(tmp_path / "missing"))
    with siconos.Server(str(python)) as s:
        yield s


def test_orders_both_ways_repeats_and_failures(server):
    path = FCLIB_DIR / "CubesH8--LMGC_GlobalFrictionContactProblem00046.hdf5"  # HDF5: handed over as W, q, mu
    P = fclib.load(path)
    nc = P.contacts
    echo = server.solve(path, P, "nsgs", 1e-8, siconos.Repeats(min_seconds=math.inf, max_solves=7), timeout=30)
    labels = server.solve(path, P, "nsn-ac", 1e-8, siconos.Repeats(min_seconds=0.0), timeout=30)
    # Siconos' (n, t1, t2) is stiction's (t1, t2, n): each contact's labels come back as (2, 3, 1)
    np.testing.assert_array_equal(labels["lam"], np.tile([2.0, 3.0, 1.0], nc))
    # so the q Siconos received, returned as its answer, is -b in stiction's order
    np.testing.assert_array_equal(echo["lam"], -P.b)
    assert (echo["iterations"], labels["iterations"]) == (7, 1)  # the repeat rule: 7 solves, then 1
    assert echo["info"] == 0 and echo["seconds"] >= 0.0
    dat = FCLIB_DIR / "Rover--Rover1039.dat"  # read by Siconos itself
    rover = fclib.load(dat)
    out = server.solve(dat, rover, "nsn-ac", 1e-8, siconos.Repeats(min_seconds=0.0), timeout=30)
    np.testing.assert_array_equal(out["lam"], np.tile([2.0, 3.0, 1.0], rover.contacts))
    assert server.solve(path, P, "prox", 1e-8, siconos.Repeats(min_seconds=0.0), timeout=1.0) == {"error": "time limit"}
    assert server.solve(path, P, "nsgs", 0.5, siconos.Repeats(min_seconds=0.0), timeout=30) == {"error": "crashed"}
    again = server.solve(path, P, "nsgs", 1e-8, siconos.Repeats(min_seconds=0.0), timeout=30)  # restarted
    np.testing.assert_array_equal(again["lam"], -P.b)
    with pytest.raises(ValueError, match="unknown Siconos solver 'pgs'"):
        server.solve(path, P, "pgs", 1e-8, siconos.Repeats(min_seconds=0.0), timeout=30)


def test_repeat_rule():
    rule = siconos.Repeats(min_seconds=0.5, min_solves=3, max_seconds=2.0, max_solves=20000)
    assert not rule.enough([0.3, 0.3], 0.6)  # 0.5 s spent but only 2 solves
    assert rule.enough([0.2, 0.2, 0.2], 0.6)
    assert rule.enough([2.5], 2.5)  # one long solve
    assert rule.enough([1e-6] * 20000, 0.02)
