"""Solve every bundled FCLib problem with each stiction solver; write a Markdown table.

    python benchmarks/fclib_table.py [--out docs/fclib-table.md] [--solvers default,nsgs,newton,admm]

Per file and solver: the relative residual (natural map / ||q||, Siconos' measure), iterations
and the median wall time of the solve over a few repeats (one repeat above 0.5 s).
"""
from __future__ import annotations

import argparse
import datetime
import platform
import statistics
import time
from pathlib import Path

import stiction
from stiction import fclib
from stiction.bench.profiles import fclib_problem_set



def timed_solve(problem, solver, tol, time_limit):
    times, res = [], None
    for _ in range(5):
        t0 = time.perf_counter()
        res = stiction.solve(problem, solver=solver, tol=tol, max_iter=5000, time_limit=time_limit)
        times.append(time.perf_counter() - t0)
        if sum(times) > 0.5:
            break
    return statistics.median(times), res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--solvers", default="default,nsgs,newton,admm")
    ap.add_argument("--tol", type=float, default=1e-10)
    ap.add_argument("--time-limit", type=float, default=30.0)
    args = ap.parse_args()
    solvers = args.solvers.split(",")
    files = [Path(r["path"]) for r in fclib_problem_set()]  # every bundled FCLib problem, sorted
    cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), "?")
    head = "| file | contacts | " + " | ".join(f"{s}: rel. residual / it / ms" for s in solvers) + " |"
    lines = [
        f"Measured {datetime.date.today()} on {platform.machine()} ({cpu}), 2 cores, stiction "
        f"{stiction.__version__}; tol {args.tol:g} on the relative residual, at most 5000 iterations and "
        f"{args.time_limit:g} s per solve; time = median wall time of the solve call.",
        "",
        head,
        "|---|---:|" + "---|" * len(solvers),
    ]
    solved = {s: 0 for s in solvers}
    for path in files:
        P = fclib.load(path)
        problem = P.problem()
        cells = []
        for s in solvers:
            t, r = timed_solve(problem, s, args.tol, args.time_limit)
            ok = r.relative_residual <= 1e-8
            solved[s] += ok
            cells.append(f"{r.relative_residual:.1e}{'' if ok else ' ✗'} / {r.iterations} / {t * 1e3:.2f}")
        lines.append(f"| {P.name} | {P.contacts} | " + " | ".join(cells) + " |")
        print(lines[-1], flush=True)
    lines += ["", "Files brought to a relative residual ≤ 1e-8: " +
              ", ".join(f"{s} {solved[s]}/{len(files)}" for s in solvers) + ". ✗ marks a miss."]
    text = "\n".join(lines) + "\n"
    if args.out:
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
