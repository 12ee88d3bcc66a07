"""When does a warm start pay off? Cold start vs ProxQP (facetized-cone QP) vs the previous step's λ.

For each problem and solver, in one run: median wall time of the whole solve (warm start
included), iterations, ProxQP's own time and iterations, and the final residual. "previous λ"
solves a neighbouring problem (b perturbed by 1 %, as between two time steps) from the
solution of the unperturbed one.

    python benchmarks/bench_warm_start.py [--out docs/warm-start-table.md] [--quick]
"""
from __future__ import annotations

import argparse
import datetime
import platform
import statistics
import time
from pathlib import Path

import numpy as np

import stiction
from stiction import fclib
from stiction.problems import cube_on_ground, random_problem, two_cube_stack

ROOT = Path(__file__).resolve().parents[1]


def problems(quick: bool):
    rng = np.random.default_rng(7)
    yield "easy", "cube resting (rank 6/12)", cube_on_ground(mu=0.5).problem
    yield "easy", "cube sliding 0.5 m/s", cube_on_ground(mu=0.3, velocity=(0.5, 0, 0)).problem
    yield "easy", "random 6 contacts, full rank", random_problem(rng, ["spatial"] * 6, 24, (0.1, 0.5))
    yield "easy", "Rover4493 (FCLib)", fclib.load(ROOT / "benchmarks/fclib/Rover--Rover4493.dat").problem()
    yield "ill-conditioned", "two-cube stack 1e4 resting", two_cube_stack(1e4, 0.3).problem
    yield "ill-conditioned", "two-cube stack 1e4 sliding", two_cube_stack(1e4, 0.3, (0.5, 0, 0)).problem
    yield "ill-conditioned", "random 12 contacts, rank 18/36", random_problem(rng, ["spatial"] * 12, 18, (0.3, 0.8))
    yield "ill-conditioned", "BoxesStack1 (FCLib, 52 contacts)", fclib.load(
        ROOT / "benchmarks/fclib/BoxesStack--BoxesStack1-i100000-32.hdf5.dat").problem()
    if not quick:
        yield "ill-conditioned", "PerioBox (FCLib, 60 contacts)", fclib.load(
            ROOT / "benchmarks/fclib/PerioBox--LMGC_100_PR_PerioBox-i00361-60-03000.hdf5").problem()


def perturbed(problem, rng):
    b = problem.b * (1.0 + 0.01 * rng.standard_normal(problem.b.size))
    return stiction.ContactProblem(problem.A, b, problem.constraints, max(1e-9, 1.01 * problem.asymmetry))


def measure(problem, solver, warm, repeats):
    times, last = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        last = stiction.solve(problem, solver=solver, tol=1e-10, max_iter=20000, warm_start=warm)
        times.append(time.perf_counter() - t0)
    return statistics.median(times), last


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    repeats = 5 if args.quick else 15
    rng = np.random.default_rng(11)
    cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), "?")
    lines = [
        f"Measured {datetime.date.today()} on {platform.machine()} ({cpu}), stiction {stiction.__version__}, "
        f"median of {repeats} solves, tol 1e-10 on the common residual.",
        "",
        "| class | problem | solver | cold µs / it | ProxQP µs / it (QP µs, QP it) | previous λ µs / it | residuals cold / ProxQP / prev |",
        "|---|---|---|---|---|---|---|",
    ]
    for cls, name, p in problems(args.quick):
        neighbour = perturbed(p, rng)
        for solver in ("default", "nsgs", "newton", "admm"):
            t_cold, r_cold = measure(neighbour, solver, None, repeats)
            t_qp, r_qp = measure(neighbour, solver, "proxqp", repeats)
            prev = stiction.solve(p, solver=solver, tol=1e-10, max_iter=20000).lam
            t_prev, r_prev = measure(neighbour, solver, prev, repeats)
            lines.append(
                f"| {cls} | {name} | {solver} | {t_cold * 1e6:.0f} / {r_cold.iterations} | "
                f"{t_qp * 1e6:.0f} / {r_qp.iterations} ({r_qp.warm_start_seconds * 1e6:.0f}, {r_qp.warm_start_iterations}) | "
                f"{t_prev * 1e6:.0f} / {r_prev.iterations} | "
                f"{r_cold.residual:.0e} / {r_qp.residual:.0e} / {r_prev.residual:.0e} |")
            print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    if args.out:
        args.out.write_text(text)
    else:
        print()
        print(text)


if __name__ == "__main__":
    main()
