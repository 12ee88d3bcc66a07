#!/usr/bin/env python
"""Time to relative residual 1e-8 on every bundled FCLib problem: the default solver against the
single algorithms and Pinocchio 4.1's ADMM, on the stored and on the symmetrised matrix, for one
or several builds of stiction — the measurements behind the default solver's rule (docs/solvers.md,
"The default's rule").

    python benchmarks/bench_default.py [--filter SUBSTR,...] [--rounds 3] [--json FILE] [--out FILE]
        [--build NAME=PYTHONPATH ...] [--solvers default,admm,newton,nsgs] [--warm-start]
        [--no-pinocchio]

Every measurement runs in a fresh worker process (`--worker`), so builds can be compared in one
run: `--build before=/path/to/old/src --build after=src` alternates the builds problem by
problem, round by round (the machine is shared and noisy; alternating spreads its load over
both), and reports the median over rounds of each run's median. Without --build the
interpreter's own stiction is the only build. The first build's first round runs every solver
(and Pinocchio on the symmetrised matrix; with --warm-start every solver again from ProxQP's
facetized-cone solution, "solver@proxqp"); later rounds and other builds run the default and ADMM.

Per run: median wall time of the solve call (at least 3 runs, ~0.6 s of runs for fast solves,
3 above 0.2 s, one above 3 s), relative residual (natural map / ‖b‖, Siconos' measure) of the
first run, iterations and the stages of the default. stiction runs at tol = 1e-8, 5000
iterations, 30 s (RockPile: 10 s). "symmetrised" solves (A + Aᵀ)/2, the matrix Pinocchio's ADMM
needs (its Cholesky reads one triangle). Pinocchio's ADMM stops on its own tests, which claim
convergence early (docs/benchmark-pinocchio.md), so it runs at solver tolerances 1e-8, 1e-10,
1e-12 (10000 iterations) and its time is that of the first whose λ reaches relative residual 1e-8.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

FCLIB_DIR = Path(__file__).resolve().parent / "fclib"
TARGET = 1e-8


def worker(name: str, matrix: str, configs: list[str]) -> dict:
    import numpy as np

    import stiction
    from stiction import fclib

    P = fclib.load(FCLIB_DIR / name)
    if matrix == "stored":
        problem = P.problem()
    else:
        problem = stiction.spatial_problem(0.5 * (P.A + P.A.T), P.b, P.mu)
    limit = 10.0 if "RockPile" in name else 30.0
    out: dict = {"core": stiction._core.__file__, "rows": problem.num_rows,
                 "density": float(np.count_nonzero(P.A) / P.A.size)}

    def repeated(run):
        seconds, first = run()
        times = [seconds]
        n = 1 if seconds > 3.0 else (3 if seconds > 0.2 else int(min(15, max(3, 0.6 / max(seconds, 1e-9)))))
        for _ in range(n - 1):
            times.append(run()[0])
        return statistics.median(times), first

    for config in configs:
        if config == "pinocchio-admm":
            from stiction.baselines import pinocchio_solve

            best = None
            for tol in (1e-8, 1e-10, 1e-12):
                def run():
                    r = pinocchio_solve(problem, "admm", tol=tol, max_iter=10000)
                    return r.seconds, r

                seconds, r = repeated(run)
                rel = float(stiction.solve(problem, warm_start=r.lam, max_iter=0).relative_residual)
                entry = {"seconds": seconds, "relative_residual": rel, "solved": rel <= TARGET,
                         "iterations": int(r.iterations), "tol": tol}
                if best is None or (entry["solved"] and not best["solved"]) or (
                        not best["solved"] and rel < best["relative_residual"]):
                    best = entry
                if entry["solved"]:
                    break
            out[config] = best
            continue

        solver, _, start = config.partition("@")

        def run():
            t0 = time.perf_counter()
            r = stiction.solve(problem, solver=solver, tol=TARGET, max_iter=5000, time_limit=limit,
                               warm_start=start or None)
            return time.perf_counter() - t0, r

        seconds, r = repeated(run)
        out[config] = {"seconds": seconds, "relative_residual": float(r.relative_residual),
                       "solved": bool(r.relative_residual <= TARGET), "iterations": int(r.iterations),
                       "stages": [[s.name, int(s.iterations), float(s.seconds), s.outcome] for s in r.stages]}
    return out


def spawn(pythonpath: str | None, name: str, matrix: str, configs: list[str]) -> dict:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    if pythonpath is not None:
        env["PYTHONPATH"] = pythonpath
    p = subprocess.run([sys.executable, __file__, "--worker", name, matrix, ",".join(configs)],
                       env=env, capture_output=True, text=True)
    if p.returncode:
        print(f"{name} {matrix}: worker failed\n{p.stderr[-2000:]}", file=sys.stderr)
        return {}
    return json.loads(p.stdout.strip().splitlines()[-1])


def median_of(runs: list[dict], config: str, key: str = "seconds"):
    values = [r[config][key] for r in runs if config in r]
    return statistics.median(values) if values else None


def markdown(results: dict, builds: list[str]) -> str:
    lines = ["| problem | rows | nonzero | matrix | " + " | ".join(f"{b}: default ms" for b in builds)
             + f" | {builds[-1]}: stages | Pinocchio ADMM ms |", "|---|---:|---:|---|" + "---:|" * len(builds) + "---|---:|"]
    for key, entry in results.items():
        name, matrix = key.split("|")
        runs = entry["runs"]
        first = next((r for b in builds for r in runs[b] if r), {})
        cells = []
        for b in builds:
            t = median_of(runs[b], "default")
            solved = all(r["default"]["solved"] for r in runs[b] if r)
            cells.append("–" if t is None else f"{t * 1e3:.3g}{'' if solved else ' ✗'}")
        last = next((r for r in runs[builds[-1]] if r), {})
        stages = " → ".join(f"{s[0]} {s[1]}" for s in last.get("default", {}).get("stages", []))
        pin = [r["pinocchio-admm"] for b in builds for r in runs[b] if r and "pinocchio-admm" in r]
        pin_cell = "–" if not pin else f"{pin[0]['seconds'] * 1e3:.3g}{'' if pin[0]['solved'] else ' ✗'}"
        lines.append(f"| {name} | {first.get('rows', '')} | {first.get('density', 0):.1%} | {matrix} | "
                     + " | ".join(cells) + f" | {stages} | {pin_cell} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worker", nargs=3, metavar=("FILE", "MATRIX", "CONFIGS"), help=argparse.SUPPRESS)
    ap.add_argument("--filter", help="comma-separated substrings of file names")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--build", action="append", default=[], metavar="NAME=PYTHONPATH")
    ap.add_argument("--solvers", default="default,admm,newton,nsgs")
    ap.add_argument("--warm-start", action="store_true", help="also every solver from ProxQP's solution")
    ap.add_argument("--no-pinocchio", action="store_true")
    ap.add_argument("--json", type=Path, help="write (and resume from) every measurement here")
    ap.add_argument("--out", type=Path, help="write the Markdown summary here")
    args = ap.parse_args(argv)
    if args.worker:
        name, matrix, configs = args.worker
        print(json.dumps(worker(name, matrix, configs.split(","))))
        return 0
    builds = dict(b.split("=", 1) for b in args.build) or {"current": None}
    files = sorted(p.name for p in FCLIB_DIR.iterdir() if p.suffix in (".hdf5", ".dat"))
    if args.filter:
        files = [f for f in files if any(s.lower() in f.lower() for s in args.filter.split(","))]
    results = json.loads(args.json.read_text()) if args.json and args.json.exists() else {}
    all_configs = args.solvers.split(",")
    if args.warm_start:
        all_configs += [f"{s}@proxqp" for s in all_configs]
    for name in files:
        for matrix in ("symmetrised", "stored"):
            key = f"{name}|{matrix}"
            if key in results:
                continue
            runs: dict = {b: [] for b in builds}
            for k in range(args.rounds):
                for i, (build, path) in enumerate(builds.items()):
                    configs = all_configs if (k == 0 and i == 0) else ["default", "admm"]
                    if k == 0 and i == 0 and matrix == "symmetrised" and not args.no_pinocchio:
                        configs = configs + ["pinocchio-admm"]
                    runs[build].append(spawn(path, name, matrix, configs))
            results[key] = {"runs": runs}
            if args.json:
                args.json.write_text(json.dumps(results, indent=1))
            print(f"{name[:40]:40s} {matrix:11s} " + "  ".join(
                f"{b} {median_of(runs[b], 'default') * 1e3:9.2f} ms" for b in builds if median_of(runs[b], "default")
            ), file=sys.stderr, flush=True)
    text = markdown(results, list(builds))
    if args.out:
        args.out.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
