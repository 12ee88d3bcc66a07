#!/usr/bin/env python
"""Benchmark: stiction's solvers against Pinocchio 4.1's ADMM and PGS on the same problems.

Usage:  python benchmarks/bench_solvers.py [--quick] [--filter SUBSTRING] [--out FILE]

Problems: the 36 FCLib files of benchmarks/fclib; a cube on the ground (resting, sliding at
0.5 m/s); two stacked cubes with top/bottom mass ratio 1, 1e2, 1e4, 1e6 (top resting, top
sliding at 0.5 m/s); μ = 0.3 for the built problems.

Solver configurations (all on the same ContactProblem, A as stored):

- stiction "default", "nsgs", "newton" at tolerance 1e-10 and 1e-8 (max 2000 iterations,
  20 s time limit);
- Pinocchio ADMM and PGS through :func:`stiction.baselines.pinocchio_solve` (exact NCP,
  solve_ncp=True), at (tolerance 1e-8, 1000 iterations) and (1e-12, 10000 iterations).
  PGS is skipped above 1000 rows (it segfaults); a 10000-iteration run is skipped when its
  predicted time (per-iteration time of the 1000-iteration run, if that ran ≥ 100 iterations,
  × 10000) exceeds 60 s.

What is measured, per problem and configuration:

- time: MEDIAN wall time (``time.perf_counter``) of the solve call alone: the settings, the
  Delassus operator and the solver objects are built before the clock starts. Each solve is
  repeated adaptively: ~1 s of repeats, at least 3 and at most 21 (quick: 0.2 s, at most 5);
  a solve longer than 2 s runs once. Medians only: the machine is noisy.
- residual: ``stiction.residual(problem, λ)`` (natural map of the De Saxcé problem / (1 + ‖b‖))
  of the first run's λ, the same measure for every solver. "Solved" means residual ≤ 1e-8.
- claim: the solver's own converged flag.

Output: Markdown on stdout (and in --out FILE): a headline table, per-configuration detail
tables and a summary. Progress goes to stderr.
"""
from __future__ import annotations

import argparse
import datetime
import platform
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

import stiction
from stiction import fclib
from stiction.baselines import PGS_MAX_ROWS, pinocchio_solve
from stiction.problems import cube_on_ground, two_cube_stack

FCLIB_DIR = Path(__file__).resolve().parent / "fclib"
SOLVED = 1e-8  # residual threshold for "solved"
SYMMETRIC = 1e-10  # max|A - Aᵀ| / max|A| below this counts as symmetric
STICTION_MAX_ITER = 2000
STICTION_TIME_LIMIT = 20.0  # s, stiction's own per-solve cap
SINGLE_RUN_ABOVE = 2.0  # s: a solve this long is not repeated
PINOCCHIO_BUDGET = 60.0  # s: predicted longest Pinocchio solve we are willing to run
RATE_MIN_ITERATIONS = 100  # a per-iteration time needs this many iterations to amortize the setup
QUICK_MAX_ROWS = 200


@dataclass(frozen=True)
class Config:
    """One solver configuration; `library` is "stiction" or "pinocchio"."""

    library: str
    method: str
    tol: float
    max_iter: int

    @property
    def label(self) -> str:
        if self.library == "stiction":
            return f"stiction {self.method} ε={self.tol:.0e}"
        return f"{self.method.upper()} ε={self.tol:.0e}/{self.max_iter}"


STICTION_CONFIGS = [Config("stiction", m, tol, STICTION_MAX_ITER)
                    for tol in (1e-10, 1e-8) for m in ("default", "nsgs", "newton")]
PINOCCHIO_CONFIGS = [Config("pinocchio", m, tol, it)
                     for m in ("admm", "pgs") for tol, it in ((1e-8, 1000), (1e-12, 10000))]
HEADLINE_STICTION = STICTION_CONFIGS[0]  # stiction default at 1e-10


@dataclass
class Case:
    name: str
    problem: stiction.ContactProblem
    asymmetry: float  # max|A - Aᵀ| / max|A|


@dataclass
class Measurement:
    """Median time and accuracy of one configuration on one case (or why it was skipped)."""

    config: Config
    runs: int = 0
    median_s: float = float("nan")
    iterations: int = 0
    residual: float = float("nan")
    claimed: bool = False
    skipped: str = ""

    @property
    def solved(self) -> bool:
        return not self.skipped and self.residual <= SOLVED

    @property
    def false_claim(self) -> bool:
        return not self.skipped and self.claimed and not self.residual <= SOLVED


# ----------------------------------------------------------------------------- problems

def _asymmetry(A: np.ndarray) -> float:
    scale = np.abs(A).max()
    return float(np.abs(A - A.T).max() / scale) if scale > 0 else 0.0


def load_cases(quick: bool, pattern: str | None) -> list[Case]:
    """FCLib files, then the built cube problems; --quick keeps ≤ 200 rows, --filter by name."""
    built = [("cube_on_ground rest", cube_on_ground(mu=0.3)),
             ("cube_on_ground slide 0.5", cube_on_ground(mu=0.3, velocity=(0.5, 0.0, 0.0)))]
    for ratio in (1.0, 1e2, 1e4, 1e6):
        for state, v in (("rest", (0.0, 0.0, 0.0)), ("slide 0.5", (0.5, 0.0, 0.0))):
            built.append((f"two_cube_stack {ratio:.0e} {state}",
                          two_cube_stack(ratio, 0.3, top_velocity=v)))
    named = [(path.name, path) for path in sorted(FCLIB_DIR.iterdir())
             if path.suffix in (".dat", ".hdf5")] + built
    cases = []
    for name, source in named:
        if pattern and pattern.lower() not in name.lower():
            continue
        problem = fclib.load(source).problem() if isinstance(source, Path) else source.problem
        if quick and problem.num_rows > QUICK_MAX_ROWS:
            continue
        cases.append(Case(name, problem, _asymmetry(problem.A)))
    return cases


# ----------------------------------------------------------------------------- timing

def repeat_count(first_seconds: float, quick: bool) -> int:
    """How many runs in total, given the first one's time."""
    if first_seconds > SINGLE_RUN_ABOVE:
        return 1
    budget, most = (0.2, 5) if quick else (1.0, 21)
    return int(min(most, max(3, budget / max(first_seconds, 1e-9))))


def timed(run, quick: bool) -> tuple[float, int, object]:
    """Call ``run() -> (seconds, result)`` adaptively; return (median seconds, runs, first result)."""
    seconds, first = run()
    times = [seconds]
    for _ in range(repeat_count(seconds, quick) - 1):
        times.append(run()[0])
    return statistics.median(times), len(times), first


_stiction_solvers: dict[str, stiction.Solver] = {}


def run_stiction(problem: stiction.ContactProblem, config: Config, quick: bool) -> Measurement:
    """Time ``Solver.solve`` alone (the call ``stiction.solve`` makes), cold start."""
    solver = _stiction_solvers.setdefault(config.method, stiction.Solver(config.method))
    settings = stiction.SolverSettings()
    settings.tolerance = config.tol
    settings.max_iterations = config.max_iter
    settings.time_limit = STICTION_TIME_LIMIT
    settings.warm_start = stiction.WarmStart.none

    def run():
        t0 = time.perf_counter()
        result = solver.solve(problem, settings)
        return time.perf_counter() - t0, result

    median, runs, first = timed(run, quick)
    return Measurement(config, runs, median, int(first.iterations),
                       float(stiction.residual(problem, first.lam)), bool(first.converged))


def run_pinocchio(problem: stiction.ContactProblem, config: Config, quick: bool) -> Measurement:
    """Time Pinocchio's ``solver.solve`` alone (as measured by ``pinocchio_solve``), cold start."""

    def run():
        result = pinocchio_solve(problem, config.method, tol=config.tol, max_iter=config.max_iter)
        return result.seconds, result

    median, runs, first = timed(run, quick)
    return Measurement(config, runs, median, first.iterations, first.residual, first.converged)


def measure_case(case: Case, quick: bool) -> dict[Config, Measurement]:
    out: dict[Config, Measurement] = {}
    for config in STICTION_CONFIGS:
        out[config] = run_stiction(case.problem, config, quick)
    for config in PINOCCHIO_CONFIGS:
        if config.method == "pgs" and case.problem.num_rows > PGS_MAX_ROWS:
            out[config] = Measurement(config, skipped=f"PGS > {PGS_MAX_ROWS} rows (segfaults)")
            continue
        # The same method's cheaper configuration (measured first) predicts this one's cost,
        # if it ran long enough for its per-iteration time to exclude the setup (factorization).
        cheaper = next((m for c, m in out.items()
                        if c.library == "pinocchio" and c.method == config.method), None)
        if cheaper is not None and cheaper.iterations >= RATE_MIN_ITERATIONS:
            predicted = cheaper.median_s / cheaper.iterations * config.max_iter
            if predicted > PINOCCHIO_BUDGET:
                out[config] = Measurement(config, skipped=f"predicted {predicted:.0f} s > budget")
                continue
        out[config] = run_pinocchio(case.problem, config, quick)
    return out


# ----------------------------------------------------------------------------- report

def best_of(measurements: list[Measurement]) -> Measurement | None:
    """The fastest run that solved the problem, else the one with the lowest residual."""
    ran = [m for m in measurements if not m.skipped]
    if not ran:
        return None
    solved = [m for m in ran if m.solved]
    if solved:
        return min(solved, key=lambda m: m.median_s)
    return min(ran, key=lambda m: m.residual if np.isfinite(m.residual) else np.inf)


def fmt_us(seconds: float) -> str:
    return f"{seconds * 1e6:,.0f}" if seconds >= 1e-5 else f"{seconds * 1e6:.1f}"


def fmt_res(residual: float) -> str:
    return f"{residual:.1e}"


def fmt_claim(m: Measurement) -> str:
    return "yes" if m.claimed else "no"


def header_lines(args, started: datetime.datetime) -> list[str]:
    cpu = "unknown"
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    try:
        commit = subprocess.run(["git", "-C", str(FCLIB_DIR), "describe", "--always", "--dirty"],
                                capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    core = Path(stiction._core.__file__)
    built = datetime.datetime.fromtimestamp(core.stat().st_mtime).astimezone()
    mode = "quick" if args.quick else "full"
    return [
        "# stiction vs Pinocchio solvers",
        "",
        f"{started.isoformat(timespec='seconds')} · "
        f"{platform.machine()} · {cpu} · pin {pin.__version__} · stiction {stiction.__version__} "
        f"(git {commit}, core built {built.isoformat(timespec='seconds')}) · "
        f"numpy {np.__version__} · Python {platform.python_version()} · "
        f"mode {mode}" + (f" · filter '{args.filter}'" if args.filter else ""),
        "",
        "Times: median wall time (µs) of the solve call alone, cold start, over the runs shown in "
        "the detail tables. Residual: `stiction.residual` (natural map / (1 + ‖b‖)) for every "
        f"solver; solved = residual ≤ {SOLVED:.0e}. Claim: the solver's own converged flag. "
        "asym = max|A − Aᵀ| / max|A| as stored (Pinocchio ADMM solves with the lower triangle "
        "mirrored, PGS with (A + Aᵀ)/2, so both are limited by it).",
        "",
    ]


def headline_table(cases: list[Case], results: dict[str, dict[Config, Measurement]]) -> list[str]:
    lines = [
        "## Headline",
        "",
        "stiction: `default` at ε=1e-10. ADMM, PGS: the faster of their two configurations that "
        "solves the problem, else the more accurate one (ε column). Ratio: stiction / ADMM time, "
        "only where both solve.",
        "",
        "| problem | rows | asym | stiction µs | residual | ADMM ε | ADMM µs | residual | claim "
        "| PGS ε | PGS µs | residual | claim | stiction/ADMM |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---|---|",
    ]
    for case in cases:
        r = results[case.name]
        s = r[HEADLINE_STICTION]
        cells = [case.name, str(case.problem.num_rows), f"{case.asymmetry:.0e}",
                 fmt_us(s.median_s), fmt_res(s.residual)]
        bests = {}
        for method in ("admm", "pgs"):
            b = best_of([m for c, m in r.items() if c.method == method and c.library == "pinocchio"])
            bests[method] = b
            if b is None:
                reason = next(m.skipped for c, m in r.items() if c.method == method)
                cells += ["–", f"skipped: {reason}", "–", "–"]
            else:
                cells += [f"{b.config.tol:.0e}", fmt_us(b.median_s), fmt_res(b.residual), fmt_claim(b)]
        a = bests["admm"]
        if s.solved and a is not None and a.solved:
            ratio = f"{s.median_s / a.median_s:.2g}"
        else:
            failed = [name for name, m in (("stiction", s), ("ADMM", a)) if m is None or not m.solved]
            ratio = " and ".join(failed) + " failed"
        lines.append("| " + " | ".join(cells + [ratio]) + " |")
    return lines + [""]


def detail_table(title: str, configs: list[Config], cases: list[Case],
                 results: dict[str, dict[Config, Measurement]]) -> list[str]:
    lines = [f"## {title}", "",
             "Each cell: median µs / residual / iterations / claimed converged (y/n) / runs.", "",
             "| problem | " + " | ".join(c.label for c in configs) + " |",
             "|---|" + "---|" * len(configs)]
    for case in cases:
        cells = []
        for c in configs:
            m = results[case.name][c]
            if m.skipped:
                cells.append(f"skipped: {m.skipped}")
            else:
                mark = "**" if m.solved else ""
                cells.append(f"{mark}{fmt_us(m.median_s)} / {fmt_res(m.residual)}{mark} / "
                             f"{m.iterations} / {'y' if m.claimed else 'n'} / {m.runs}")
        lines.append(f"| {case.name} | " + " | ".join(cells) + " |")
    return lines + ["", "Bold: solved (residual ≤ 1e-8).", ""]


def summary(cases: list[Case], results: dict[str, dict[Config, Measurement]]) -> list[str]:
    n = len(cases)
    symmetric = [c for c in cases if c.asymmetry <= SYMMETRIC]
    lines = ["## Summary", "",
             f"{n} problems ({len(symmetric)} with a symmetric A).", "",
             "| solver | solved (≤ 1e-8) | on symmetric A | claims converged | false claims "
             "| skipped | median µs on solved |",
             "|---|---:|---:|---:|---:|---:|---:|"]

    def row(label: str, per_case: dict[str, Measurement | None]) -> str:
        ms = [m for m in per_case.values() if m is not None]
        solved = [m for m in ms if m.solved]
        sym_solved = sum(1 for c in symmetric if per_case[c.name] is not None and per_case[c.name].solved)
        med = fmt_us(statistics.median(m.median_s for m in solved)) if solved else "–"
        return (f"| {label} | {len(solved)}/{n} | {sym_solved}/{len(symmetric)} "
                f"| {sum(m.claimed for m in ms if not m.skipped)} | {sum(m.false_claim for m in ms)} "
                f"| {n - sum(1 for m in ms if not m.skipped)} | {med} |")

    for c in STICTION_CONFIGS + PINOCCHIO_CONFIGS:
        lines.append(row(c.label, {k: r[c] for k, r in results.items()}))
    best = {}
    for method in ("admm", "pgs"):
        best[method] = {
            k: best_of([m for c, m in r.items() if c.library == "pinocchio" and c.method == method])
            for k, r in results.items()}
        lines.append(row(f"{method.upper()} best of its 2 configurations", best[method]))
    lines.append("")

    lines.append("Time ratio stiction / ADMM (ADMM: its faster solving configuration), median over "
                 "the problems both solve:")
    lines.append("")
    for sc in (STICTION_CONFIGS[0], STICTION_CONFIGS[3]):
        ratios = [results[c.name][sc].median_s / best["admm"][c.name].median_s for c in cases
                  if results[c.name][sc].solved and best["admm"][c.name] is not None
                  and best["admm"][c.name].solved]
        text = (f"{statistics.median(ratios):.2g} over {len(ratios)} problems "
                f"(min {min(ratios):.2g}, max {max(ratios):.2g})") if ratios else "no common problem"
        lines.append(f"- {sc.label}: {text}")
    lines.append("")

    lines.append(f"Claims of convergence with residual > {SOLVED:.0e}:")
    lines.append("")
    false = [(case.name, m) for case in cases for m in results[case.name].values() if m.false_claim]
    lines += [f"- {name}: {m.config.label}, residual {fmt_res(m.residual)}"
              for name, m in false] or ["- none"]
    lines.append("")

    unsolved = [c.name for c in cases if not any(m.solved for m in results[c.name].values())]
    lines.append("Solved by no configuration: " + (", ".join(unsolved) if unsolved else "none") + ".")
    lines.append("")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help=f"problems of at most {QUICK_MAX_ROWS} rows, fewer repeats")
    parser.add_argument("--filter", help="only problems whose name contains this (case-insensitive)")
    parser.add_argument("--out", help="also write the Markdown report to this file")
    args = parser.parse_args(argv)

    cases = load_cases(args.quick, args.filter)
    if not cases:
        parser.error("no problem matches")
    results: dict[str, dict[Config, Measurement]] = {}
    started = datetime.datetime.now().astimezone()
    t_start = time.perf_counter()
    for i, case in enumerate(cases, 1):
        t0 = time.perf_counter()
        results[case.name] = measure_case(case, args.quick)
        print(f"[{i}/{len(cases)}] {case.name} ({case.problem.num_rows} rows): "
              f"{time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)

    lines = header_lines(args, started)
    lines += headline_table(cases, results)
    lines += summary(cases, results)
    lines += detail_table("stiction, all configurations", STICTION_CONFIGS, cases, results)
    lines += detail_table("Pinocchio, all configurations", PINOCCHIO_CONFIGS, cases, results)
    lines.append(f"Total benchmark time {time.perf_counter() - t_start:.0f} s.")
    report = "\n".join(lines) + "\n"
    sys.stdout.write(report)
    if args.out:
        Path(args.out).write_text(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
