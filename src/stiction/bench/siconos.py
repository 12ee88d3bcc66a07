"""Siconos 4.4 on FCLib problems: the one driver of every bench that runs it (``stiction bench
profiles``, ``benchmarks/bench_siconos.py``).

Siconos is Debian's ``python3-siconos`` (with ``python3-scipy``), a system Python package that is
not on PyPI: it runs in ``/usr/bin/python3`` (or the `python` given), in one helper process that
serves solves over stdin/stdout (a process per solve would cost its ~0.5 s start-up every time),
stopped and restarted when a solve overruns its deadline or the process dies.

Problems: Siconos reads the ``.dat`` files itself (its sparse-block storage); the FCLib HDF5 files
(which its Python build cannot read) are handed over as W (scipy CSR when at most 10 % nonzero,
else dense), q and mu in Siconos' (n, t1, t2) order (``q = -b``). Solvers (:data:`SOLVERS`): NSGS,
NSN Alart-Curnier and PROX through ``fc3d_driver``, at the tolerance asked, 10,000 iterations
(NSN-AC: 1,000). Each request is solved again and again, each ``fc3d_driver`` call timed in the
helper, until the :class:`Repeats` rule says enough; the answer is the last solve's, mapped back to
stiction's (t1, t2, n) order, for the caller to judge by its own measure.
"""
from __future__ import annotations

import json
import math
import os
import select
import subprocess
import tempfile
import time
from dataclasses import dataclass

import numpy as np

SYSTEM_PYTHON = "/usr/bin/python3"
SOLVERS = {"nsgs": "SICONOS_FRICTION_3D_NSGS", "nsn-ac": "SICONOS_FRICTION_3D_NSN_AC",
           "prox": "SICONOS_FRICTION_3D_PROX"}
MAX_ITERATIONS = {"nsgs": 10000, "nsn-ac": 1000, "prox": 10000}
STARTUP_SECONDS = 10.0  # the helper importing numpy, scipy and siconos, on top of a request's deadline


@dataclass(frozen=True)
class Repeats:
    """When a solver has been timed enough: `min_seconds` of solves and at least `min_solves` of
    them, or `max_seconds`, or `max_solves` solves (the same rule serves stiction's side)."""

    min_seconds: float
    min_solves: int = 1
    max_seconds: float = math.inf
    max_solves: int = 5

    def enough(self, times: list[float], spent: float) -> bool:
        return ((spent >= self.min_seconds and len(times) >= self.min_solves) or spent >= self.max_seconds
                or len(times) >= self.max_solves)


SERVER = r"""
import json, statistics, sys, time
import numpy as np
import siconos.numerics as sn
for line in sys.stdin:
    spec = json.loads(line)
    try:
        if spec["dat"]:
            problem = sn.frictionContact_new_from_filename(spec["dat"])
        else:
            data = np.load(spec["npz"])
            W = data["W"]
            if np.count_nonzero(W) <= 0.1 * W.size:
                import scipy.sparse as sp
                W = sp.csr_matrix(W)
            problem = sn.FrictionContactProblem(3, W, data["q"], data["mu"])
        n = 3 * problem.numberOfContacts
        min_seconds, min_solves, max_seconds, max_solves = spec["repeats"]
        times, out, spent = [], None, 0.0
        while True:
            so = sn.SolverOptions(getattr(sn, spec["solver_id"]))
            so.iparam[sn.SICONOS_IPARAM_MAX_ITER] = spec["max_iter"]
            so.dparam[sn.SICONOS_DPARAM_TOL] = spec["tol"]
            r, u = np.zeros(n), np.zeros(n)
            t0 = time.perf_counter()
            info = sn.fc3d_driver(problem, r, u, so)
            times.append(time.perf_counter() - t0)
            spent += times[-1]
            out = {"r": r.tolist(), "info": int(info), "own_error": float(so.dparam[sn.SICONOS_DPARAM_RESIDU]),
                   "iterations": int(so.iparam[sn.SICONOS_IPARAM_ITER_DONE])}
            if (spent >= min_seconds and len(times) >= min_solves) or spent >= max_seconds or len(times) >= max_solves:
                break
        out["seconds"] = statistics.median(times)
    except Exception as exc:
        out = {"error": f"{type(exc).__name__}: {exc}"[:120]}
    print(json.dumps(out), flush=True)
"""


def usable(python: str = SYSTEM_PYTHON) -> bool:
    """Siconos (with scipy) importable by `python` (Debian's python3-siconos, python3-scipy)."""
    if not os.path.exists(python):
        return False
    try:
        out = subprocess.run([python, "-c", "import siconos.numerics, scipy"], capture_output=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return False
    return out.returncode == 0


class Server:
    """The helper process serving Siconos solves (module doc); :meth:`stop` ends it."""

    def __init__(self, python: str = SYSTEM_PYTHON):
        self.python, self.proc = python, None
        self.tmp = tempfile.TemporaryDirectory(prefix="stiction-siconos-")

    def _start(self):
        self.proc = subprocess.Popen([self.python, "-c", SERVER], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, bufsize=1)

    def stop(self):
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()

    def solve(self, path: str | os.PathLike, P, solver: str, tol: float, repeats: Repeats, timeout: float) -> dict:
        """Solve the FCLib problem at `path` (loaded as `P` by :func:`stiction.fclib.load`) with the
        Siconos `solver` (a key of :data:`SOLVERS`) to `tol`, repeated by `repeats`; the helper is
        stopped (a ``time limit`` answer) when it has not answered within `timeout` seconds (plus
        ``STARTUP_SECONDS`` when it has just started).

        Returns ``lam`` (the last solve's answer, stiction's order), ``info`` (Siconos' status:
        0 is its claim of convergence), ``iterations``, ``own_error`` (its own residual) and
        ``seconds`` (the median ``fc3d_driver`` time); or only ``error`` (the exception Siconos
        raised, ``crashed`` or ``time limit``)."""
        from .. import fclib

        if solver not in SOLVERS:
            raise ValueError(f"unknown Siconos solver {solver!r} (known: {', '.join(SOLVERS)})")
        path = str(path)
        spec = {"solver_id": SOLVERS[solver], "tol": float(tol), "max_iter": MAX_ITERATIONS[solver],
                "repeats": [repeats.min_seconds, repeats.min_solves, repeats.max_seconds, repeats.max_solves],
                "dat": path if path.endswith(".dat") else None, "npz": None}
        p = fclib._to_stiction_order(P.contacts)  # ours[i] = siconos[p[i]]
        if spec["dat"] is None:
            inv = np.argsort(p)
            npz = os.path.join(self.tmp.name, f"{abs(hash(path))}.npz")
            if not os.path.exists(npz):
                np.savez(npz, W=P.A[np.ix_(inv, inv)], q=-P.b[inv], mu=P.mu)
            spec["npz"] = npz
        startup = 0.0
        if self.proc is None or self.proc.poll() is not None:
            self._start()
            startup = STARTUP_SECONDS
        self.proc.stdin.write(json.dumps(spec) + "\n")
        self.proc.stdin.flush()
        deadline = time.monotonic() + timeout + startup
        line, closed = "", False
        while time.monotonic() < deadline:
            ready, _, _ = select.select([self.proc.stdout], [], [], max(0.0, deadline - time.monotonic()))
            if ready:
                line = self.proc.stdout.readline()
                closed = not line  # end of file: the helper has exited (or is exiting)
                break
        if not line:
            # A closed pipe is a crash even before the exit can be seen (poll() may still say
            # running for a moment after the process closed its stdout; seen on a loaded machine).
            crashed = closed or self.proc.poll() is not None
            self.stop()
            return {"error": "crashed" if crashed else "time limit"}
        out = json.loads(line)
        if "error" not in out:
            out["lam"] = np.asarray(out.pop("r"))[p]
        return out
