#!/usr/bin/env python
"""Benchmark: stiction's default solver against Siconos 4.4 (NSGS, NSN Alart-Curnier, PROX) on the
bundled FCLib problems, every answer judged by one measure.

    python benchmarks/bench_siconos.py [--tol 1e-8] [--out docs/siconos-table.md] [--only NAME ...]

Siconos is Debian's ``python3-siconos`` (with ``python3-scipy``), a system Python package: it is run
by ``/usr/bin/python3`` (``--siconos-python``) in one helper process that times its own solve calls
(:mod:`stiction.bench.siconos`, the driver ``stiction bench profiles`` uses too, which says how the
problems are handed over); stiction runs in this process. Without Siconos the script says so and
exits 0.

Measure: the relative natural-map residual of the De Saxce problem on the W as stored
(||lambda - P_K(lambda - (u + E s(u)))|| / ||q||, Siconos' own scaling), computed here by stiction
for every solver's answer; "solved" means <= 1e-8 by that measure, whatever the solver claims.
Time: the median over repeats (until 0.5 s are spent and at least 3 solves done, or 2 s; at most
20,000 solves: ``ENOUGH``) of one solve call's wall time from Python, its Python wrapper included,
on both sides alike (Siconos exposes no timer of its own; ``time.perf_counter`` around the call in
both): stiction's ``Solver("default").solve(problem, settings)`` binding call in this process, its
settings built once as Siconos' options are built outside its timed call (``stiction.solve``'s
argument checks add ~1 us more), each after an untimed solve of the problem with A and b scaled by
4, so that no factorization carries over from the previous solve of the same problem; Siconos'
``fc3d_driver(problem, r, u, options)`` call in its helper process. stiction's own C++ timer
(``result.seconds``, the solve and its verdict without the binding) is reported beside it (tables
before 2026-12-08 compared that C++ time with Siconos' wrapped call); at most ``--time-limit`` seconds per solve (Siconos:
the helper process is stopped when a request takes 6 times that, at least 5 s). Problems of at
most 64 rows are timed in 5 rounds, each stiction then every Siconos solver; the reported ratio is
the median of the rounds' ratios. Settings: tolerance ``--tol`` for every solver, 10,000
iterations (NSN-AC: 1,000).
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import platform
import shutil
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import stiction
from stiction import _core, fclib
from stiction.bench import siconos
from stiction.bench.profiles import fclib_problem_set

SOLVERS = {name.upper(): name for name in siconos.SOLVERS}  # column name: the driver's solver

# When a solver has been timed enough (the same rule on both sides): 0.5 s of solves and at least 3
# of them, or 2 s (solves that take seconds), or 20,000 solves. The median of a few-microsecond
# solve needs hundreds of samples: with at most 5 (the first of them cold) the ratios of the 3-27-row
# problems moved by up to 3x between runs.
ENOUGH = siconos.Repeats(min_seconds=0.5, min_solves=3, max_seconds=2.0, max_solves=20000)


def relative_residual(problem, lam, b) -> float:
    """Natural map / ||q|| on the stored W (stiction's residual is natural map / (1 + ||b||))."""
    nb = float(np.linalg.norm(b))
    return float(_core.residual(problem, lam)) * (1.0 + nb) / nb if nb > 0 else float(_core.residual(problem, lam))


def run_stiction(solver, settings, problem, decoy):
    # the solve call's wall time from Python, its binding included, as Siconos' fc3d_driver call is
    # timed in its helper (the binding's ~1 us matters on the 3-15-row problems); the C++ timer
    # (result.seconds) beside it. Before each timed solve, an untimed one of the decoy (the
    # same problem with A and b times 4): the default solver keeps its sticking step's factor from
    # one call to the next while A's diagonal stays (a simulation's next step), which on the same
    # problem solved again would time a cached factorization (the all-stick CubesH8 problems: 0.8 us
    # against 8 us) that Siconos does not keep
    times, cpp_times, wall, res = [], [], 0.0, None
    while True:
        solver.solve(decoy, settings)
        t0 = time.perf_counter()
        res = solver.solve(problem, settings)
        times.append(time.perf_counter() - t0)
        wall += times[-1]
        cpp_times.append(res.seconds)
        if ENOUGH.enough(times, wall):
            break
    return statistics.median(times), statistics.median(cpp_times), res


ROUNDS = 5  # rounds of timing for problems of at most SMALL_ROWS rows
SMALL_ROWS = 64


def run_siconos(server, path, P, solver, tol, time_limit):
    rec = server.solve(path, P, SOLVERS[solver], tol, ENOUGH, timeout=max(5.0, 6 * time_limit))
    if "error" in rec:
        return {"seconds": None, "failure": rec["error"][:80]}
    return rec


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tol", type=float, default=1e-8)
    ap.add_argument("--time-limit", type=float, default=20.0)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--only", nargs="+", help="file names (or prefixes) to run")
    ap.add_argument("--siconos-python", default="/usr/bin/python3")
    args = ap.parse_args()
    python = shutil.which(args.siconos_python) or args.siconos_python
    if not siconos.usable(python):
        print(f"Siconos is not importable by {args.siconos_python} (apt install python3-siconos python3-scipy); "
              "nothing to compare", file=sys.stderr)
        return 0
    files = [Path(r["path"]) for r in fclib_problem_set()]  # every bundled FCLib problem, sorted
    if args.only:
        files = [f for f in files if any(f.name.startswith(o) for o in args.only)]
    rows, load_start = [], os.getloadavg()
    default_solver, settings = stiction.Solver("default"), stiction.SolverSettings()
    settings.tolerance, settings.max_iterations, settings.time_limit = args.tol, 10000, args.time_limit
    with siconos.Server(python) as server:
        for path in files:
            P = fclib.load(path)
            problem = P.problem()
            decoy = dataclasses.replace(P, A=4.0 * P.A, b=4.0 * P.b).problem()
            # Small problems (a few microseconds a solve, where the shared machine's state alone moved
            # a median by 1.5x from one second to the next): ROUNDS rounds, each timing stiction and
            # then every Siconos solver; the ratio is taken within each round and its median reported.
            rounds = ROUNDS if 3 * P.contacts <= SMALL_ROWS else 1
            row = {"problem": path.name, "rows": 3 * P.contacts, "round_ratios": []}
            per_round = {name: [] for name in ["stiction", *SOLVERS]}
            cpp_rounds = []
            for _ in range(rounds):
                seconds, cpp_seconds, res = run_stiction(default_solver, settings, problem, decoy)
                per_round["stiction"].append(seconds)
                cpp_rounds.append(cpp_seconds)
                row["stiction"] = {"residual": relative_residual(problem, np.asarray(res.lam), P.b),
                                   "claimed": bool(res.converged)}
                for solver in SOLVERS:
                    rec = run_siconos(server, path, P, solver, args.tol, args.time_limit)
                    if rec.get("seconds") is None:
                        row[solver] = {"residual": None, "claimed": False, "failure": rec["failure"]}
                        per_round[solver].append(None)
                    else:
                        row[solver] = {"residual": relative_residual(problem, rec["lam"], P.b),
                                       "claimed": rec["info"] == 0, "iterations": rec["iterations"]}
                        per_round[solver].append(rec["seconds"])
                best = [per_round[n][-1] for n in SOLVERS if per_round[n][-1] is not None and solved(row[n])]
                if best and solved(row["stiction"]):
                    row["round_ratios"].append(per_round["stiction"][-1] / min(best))
            for name, times in per_round.items():
                done = [t for t in times if t is not None]
                row[name]["seconds"] = statistics.median(done) if len(done) == len(times) else None
            row["stiction"]["cpp_seconds"] = statistics.median(cpp_rounds)
            rows.append(row)
            cells = "  ".join(
                f"{k} {v['seconds'] * 1e3 if v['seconds'] is not None else float('nan'):9.2f} ms "
                f"{v['residual'] if v['residual'] is not None else float('nan'):8.1e}"
                for k, v in row.items() if isinstance(v, dict))
            print(f"{path.name[:44]:44s} {cells}", file=sys.stderr, flush=True)
    text = markdown(rows, args.tol, (load_start[0], os.getloadavg()[0]))
    if args.out:
        args.out.write_text(text)
    print(text)
    return 0


def duration(seconds) -> str:
    """Milliseconds, or microseconds below 0.1 ms (the small problems' solves take 1-30 us)."""
    return f"{seconds * 1e3:,.2f} ms" if seconds >= 1e-4 else f"{seconds * 1e6:.1f} µs"


def solved(v, tol=1e-8) -> bool:
    return v["residual"] is not None and v["residual"] <= tol


def markdown(rows, tol, load=None) -> str:
    cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), "?")
    names = ["stiction"] + list(SOLVERS)
    lines = [
        f"Measured {datetime.date.today()} on {platform.machine()} ({cpu}), "
        + (f"load average {load[0]:.2f} at the start and {load[1]:.2f} at the end, " if load else "")
        + f"stiction {stiction.__version__} (default solver) against Siconos 4.4 (Debian python3-siconos), tolerance {tol:g} for every solver; "
        "`python benchmarks/bench_siconos.py`. Cell: median time / relative residual on the stored W "
        "(computed by stiction for every answer); **bold**: solved (<= 1e-8); ✗: the solver claimed "
        "convergence without it. Time: one solve call's wall time from Python, its wrapper included, on "
        "both sides alike (Siconos has no timer of its own): stiction's `Solver.solve(problem, settings)` in "
        "the bench's process, Siconos' `fc3d_driver(problem, r, u, options)` in its helper process, the "
        "settings and options built outside the timed call; stiction's C++ solve timer alone in parentheses "
        "(tables before 2026-12-08 compared that C++ time with Siconos' wrapped call). "
        "Ratio: stiction's time over the fastest solving Siconos solver's; for "
        f"problems of at most {SMALL_ROWS} rows the median of {ROUNDS} rounds, each timing both sides back "
        "to back (in parentheses: the rounds' range).",
        "",
        "| problem | rows | " + " | ".join(names) + " | stiction / best solving Siconos |",
        "|---|---:|" + "---|" * len(names) + "---:|",
    ]
    ratios, wins, false_claims = [], 0, {n: 0 for n in names}
    for r in rows:
        cells = []
        for n in names:
            v = r[n]
            if v["seconds"] is None:
                cells.append(v.get("failure", "—"))
                continue
            txt = f"{duration(v['seconds'])} / {v['residual']:.1e}"
            if "cpp_seconds" in v:  # (stiction: its C++ timer, the wrapper left out)
                txt = f"{duration(v['seconds'])} ({duration(v['cpp_seconds'])}) / {v['residual']:.1e}"
            if solved(v):
                txt = f"**{txt}**"
            elif v["claimed"]:
                txt += " ✗"
                false_claims[n] += 1
            cells.append(txt)
        best = [r[n]["seconds"] for n in SOLVERS if r[n]["seconds"] is not None and solved(r[n])]
        ratio = statistics.median(r["round_ratios"]) if r["round_ratios"] else None
        if ratio is not None:
            ratios.append(ratio)
            wins += ratio <= 1.0
        spread = (f" ({min(r['round_ratios']):.2f}–{max(r['round_ratios']):.2f})"
                  if len(r["round_ratios"]) > 1 else "")
        cells.append(f"{ratio:.2f}{spread}" if ratio is not None
                     else ("no Siconos solver solves it" if not best else "—"))
        lines.append(f"| {r['problem']} | {r['rows']} | " + " | ".join(cells) + " |")
    lines += ["", "Solved (<= 1e-8): " + ", ".join(f"{n} {sum(solved(r[n]) for r in rows)}/{len(rows)}" for n in names)
              + ". Claims of convergence that the residual contradicts: "
              + ", ".join(f"{n} {false_claims[n]}" for n in names) + "."]
    if ratios:
        lines.append(f"Where both stiction and a Siconos solver solve the problem ({len(ratios)}): stiction at most "
                     f"as fast as the best of them on {wins}; median time ratio {statistics.median(ratios):.2f}, "
                     f"largest {max(ratios):.1f}.")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
