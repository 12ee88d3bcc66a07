"""Command line: ``stiction demo``, ``stiction simulate SCENE``, ``stiction scenes``, ``stiction fclib FILE...``,
``stiction solvers``, ``stiction formulations``, ``stiction casestudy NAME``.

Exit codes: 0 success; 1 the computation ran but did not succeed (a solve that missed its
tolerance, a simulation that diverged), always with a one-line reason on stderr; 2 bad input
(unknown scene or key, a malformed file, a bad option value), one line naming the fault.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path


from . import fclib, formulation_infos, formulation_names, solver_names, solve
from ._optional import MissingExtraError, require
from ._validation import positive_int as _positive_int

from .resources import DEMO_FCLIB_PROBLEMS as DEMO_PROBLEMS  # one per family that shows something
from .resources import fclib_dir


def bundled_fclib_dir() -> Path:
    """The bundled FCLib problems (the demo set in a wheel; the whole set in a source checkout)."""
    return fclib_dir()


def _warm_start_arg(value: str | None, problem: fclib.FclibProblem):
    if value in (None, "none"):
        return None
    if value == "proxqp":
        return "proxqp"
    if value == "file":
        return problem.guess  # None if the file has no guess
    raise ValueError(f"unknown warm start {value!r}")


def solve_file(path: str, solver: str, tol: float, max_iter: int, time_limit: float,
               warm_start: str | None) -> dict:
    P = fclib.load(path)
    problem = P.problem()
    res = solve(problem, solver=solver, tol=tol, max_iter=max_iter, time_limit=time_limit,
                warm_start=_warm_start_arg(warm_start, P))
    states = [s.name for s in res.states]
    return {
        "file": os.path.basename(path),
        "contacts": P.contacts,
        "rows": problem.num_rows,
        "solver": res.solver,
        "residual": res.residual,
        "relative_residual": res.relative_residual,
        "iterations": res.iterations,
        "converged": bool(res.converged),
        "seconds": res.seconds,
        "warm_start_seconds": res.warm_start_seconds,
        "message": res.message,
        "states": {k: states.count(k) for k in ("open", "stick", "slip")},
    }


def _table(rows: list[dict]) -> str:
    head = f"{'file':52s} {'nc':>4s} {'residual':>9s} {'relative':>9s} {'iter':>5s} {'ms':>9s}  {'open/stick/slip':15s} status"
    lines = [head, "-" * len(head)]
    for r in rows:
        st = r["states"]
        lines.append(
            f"{r['file'][:52]:52s} {r['contacts']:4d} {r['residual']:9.1e} {r['relative_residual']:9.1e} "
            f"{r['iterations']:5d} {r['seconds'] * 1e3:9.2f}  {st['open']:3d}/{st['stick']:3d}/{st['slip']:3d}      "
            f"{'ok' if r['converged'] else 'NOT CONVERGED: ' + r['message']}"
        )
    return "\n".join(lines)


def cmd_fclib(args) -> int:
    rows = []
    for path in args.files:
        if not os.path.isfile(path):
            print(f"stiction fclib: no such file: {path}", file=sys.stderr)
            return 2
        rows.append(solve_file(path, args.solver, args.tol, args.max_iter, args.time_limit, args.warm_start))
    if args.json:
        json.dump(rows, sys.stdout, indent=1, default=lambda x: None if isinstance(x, float) and math.isnan(x) else x)
        sys.stdout.write("\n")
    else:
        print(_table(rows))
    failed = [r for r in rows if not r["converged"]]
    for r in failed:
        print(f"stiction fclib: {r['file']}: not converged: {r['message']} (relative residual "
              f"{r['relative_residual']:.3g})", file=sys.stderr)
    return 0 if not failed else 1


def cmd_demo(args) -> int:
    """The default demo: Solo-12 standing, then slipping down a slope (recordings, plots,
    summaries), then the exact solver on a few real contact problems."""
    from .simulator import Simulator

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    outputs = {}
    for module, extra, what in (("meshcat", "record", "recording"), ("matplotlib", "plot", "plot")):
        try:
            require(module, extra, f"the demo's {what}s")
            outputs[what] = True
        except MissingExtraError as exc:
            print(f"note: {exc}; skipping them", file=sys.stderr)
            outputs[what] = False
    print("stiction demo: exact Coulomb contact, A λ - b ∈ -lim N_C^{U_ε}(λ) (eq. 65), solved every step\n")
    failures = []
    for scene, duration in (("solo12-stand", 2.0), ("solo12-slope-slip", 1.0)):
        sim = Simulator(scene)
        traj = sim.rollout(duration)
        summary = sim.summary(traj)
        html, png = out / f"{scene}.html", out / f"{scene}.png"
        if outputs["recording"]:
            from .recording import record_html

            record_html(sim, traj, html)
        if outputs["plot"]:
            from .plots import plot_trajectory

            plot_trajectory(sim, traj, png)
        if not summary["all_converged"]:
            failures.append(f"{scene}: {summary['unconverged_steps']} steps did not converge")
        print(f"== {scene}: {sim.scene.description}")
        keys = ("steps", "us_per_step", "median_us_per_step", "max_penetration", "max_residual", "base_drift", "max_foot_slip",
                "max_normal_velocity_while_sliding", "mean_acceleration_along_slope",
                "expected_sliding_acceleration", "final_base_speed", "final_base_sway", "settled")
        for k in keys:
            print(f"   {k:36s} {summary[k]:.4g}" if isinstance(summary[k], float) else f"   {k:36s} {summary[k]}")
        print("   µs per phase: " + ", ".join(f"{k} {v:.2f}" for k, v in summary["us_per_phase"].items()))
        written = [str(p) for p, ok in ((html, outputs["recording"]), (png, outputs["plot"])) if ok]
        print(f"   wrote {'   '.join(written)}\n" if written else "")

    root = bundled_fclib_dir()
    print(f"== The solver alone on real contact problems from Siconos and LMGC90 ({root.name}/):")
    rows = [solve_file(str(root / name), "default", 1e-10, 5000, 30.0, None) for name in DEMO_PROBLEMS]
    print(_table(rows))
    failures += [f"{r['file']}: {r['message']}" for r in rows if not r["converged"]]
    print("\nresidual = ‖λ - P_C(λ - (u + E s(u)))‖ / (1 + ‖b‖); relative = the same / ‖b‖ (Siconos' measure).")
    print("More: stiction scenes | stiction simulate SCENE --json | stiction fclib FILE...")
    if failures:
        print("stiction demo: not everything converged: " + "; ".join(failures), file=sys.stderr)
        return 1
    return 0


def cmd_scenes(args) -> int:
    from .scene import list_scenes, scene_description

    for name in list_scenes():
        print(f"{name:22s} {scene_description(name)}")
    return 0


def _output_path(option: str, value: str, suffixes: tuple[str, ...]) -> Path:
    """Check an output file option before any work: not a directory, its folder exists and is
    writable, a known suffix."""
    p = Path(value)
    if p.is_dir() or value.endswith(os.sep):
        raise ValueError(f"{option} {value}: is a directory; give a file name ending in {' or '.join(suffixes)}")
    if p.suffix.lower() not in suffixes:
        raise ValueError(f"{option} {value}: the file name must end in {' or '.join(suffixes)}")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise ValueError(f"{option} {value}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise ValueError(f"{option} {value}: the folder {parent} is not writable")
    return p


def cmd_simulate(args) -> int:
    from .simulator import Simulator

    # outputs and optional packages are checked before simulating
    if args.record:
        _output_path("--record", args.record, (".html",))
        require("meshcat", "record", "--record (HTML recordings)")
    if args.plot:
        _output_path("--plot", args.plot, (".png", ".pdf", ".svg"))
        require("matplotlib", "plot", "--plot")
    if args.save:
        _output_path("--save", args.save, (".npz",))
    overrides = {k: getattr(args, k) for k in ("dt", "mode", "delta", "zeta", "mu", "duration", "solver",
                                               "formulation", "pyramid_facets", "penalty_stiffness",
                                               "penalty_damping")
                 if getattr(args, k) is not None}
    if args.pyramid_inscribed:
        overrides["pyramid_inscribed"] = True
    if args.tol is not None:
        overrides["tolerance"] = args.tol
    sim = Simulator(args.scene, **overrides)
    started = time.perf_counter()
    traj = sim.rollout()  # (with the scene's [controller], if any, before every step)
    wall = time.perf_counter() - started
    summary = sim.summary(traj)
    # the rollout call's wall time / steps: the C++ loop, its recording and the Trajectory built from it
    # (and a controller's Python), beside the step timer's mean (us_per_step) and median step
    summary["wall_us_per_step"] = wall / max(summary["steps"], 1) * 1e6
    if sim.controller is not None:  # the controller's Python runs in the loop: the whole loop's speed
        summary["wall_seconds"] = wall
        summary["real_time_factor"] = float(traj.t[-1] - traj.t[0]) / wall
    if args.save:
        traj.save(args.save)
        summary["trajectory"] = args.save
    if args.record:
        from .recording import record_html

        info = record_html(sim, traj, args.record)
        summary["recording"] = args.record
        summary["recording_info"] = info
    if args.plot:
        from .plots import plot_trajectory

        plot_trajectory(sim, traj, args.plot)
        summary["plot"] = args.plot
    if args.json:
        json.dump(summary, sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        for key, val in summary.items():
            print(f"{key:38s} {val}")
    for warning in summary["warnings"]:
        if summary["all_converged"] or "did not solve" not in warning:
            print(f"stiction simulate: warning: {warning}", file=sys.stderr)
    if not summary["all_converged"]:
        print(f"stiction simulate: {summary['unconverged_steps']} of {summary['steps']} steps did not solve the "
              f"contact problem to the tolerance (first at t = {summary['first_unconverged_t']:.6g} s; largest "
              f"residual {summary['max_residual']:.3g}); try a smaller --dt or another --solver", file=sys.stderr)
        return 1
    return 0


def cmd_casestudy(args) -> int:
    from . import casestudies

    mod = casestudies.module(args.name)  # unknown name: exit 2 before any work
    if args.plot:
        _output_path("--plot", args.plot, (".png", ".pdf", ".svg"))
        require("matplotlib", "plot", "--plot")
    result = mod.run(quick=args.quick)
    if args.plot:
        mod.plot(result, args.plot)
    if args.json:
        json.dump(result.to_json(), sys.stdout, indent=1)
        sys.stdout.write("\n")
    else:
        print(f"{result.name}: {result.title} (eq. {result.equations})")
        for c in result.checks:
            print(f"  {'ok  ' if c.passed else 'FAIL'} {c.quantity}: measured {c.measured:.6g}, expected "
                  f"{'' if c.kind == '==' else c.kind + ' '}{c.expected:.6g} (error {c.error:.3g}, tolerance {c.tolerance:.3g})")
        for note in result.notes:
            print(f"  note: {note}")
        if args.plot:
            print(f"  wrote {args.plot}")
    failed = [c.quantity for c in result.checks if not c.passed]
    if failed:
        print(f"stiction casestudy: {args.name}: {len(failed)} check(s) failed: {'; '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def cmd_formulations(args) -> int:
    infos = formulation_infos()
    if args.json:
        json.dump(infos, sys.stdout, indent=1)
        sys.stdout.write("\n")
        return 0
    for f in infos:
        print(f"{f['name']:20s} eq. {f['equations']:16s} {f['summary']}")
        for prm in f["parameters"]:
            print(f"{'':24s}- {prm}")
    print("\nEvery result is judged by the exact law (eq. 65); `--formulation NAME` in `stiction simulate`.")
    return 0


def cmd_bench(args) -> int:
    from .bench import load_bench, sweep

    module = load_bench(args.bench)
    if getattr(args, "plot", None):
        _output_path("--plot", args.plot, (".png", ".pdf", ".svg"))
    if args.out or getattr(args, "plot", None):
        require("matplotlib", "plot", "the charts (--out, --plot)")
    result = sweep.run(module, args, _command_line(args))
    if getattr(args, "plot", None):  # scaling's own --plot FILE, kept beside --out
        module.plot_result(result, args.plot, result["stamp"])
    if args.json:
        json.dump(result, sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
    else:
        _print_bench(module, result)
    return 0


def cmd_bench_all(args) -> int:
    """Every chart of docs/benchmarks.md, one bench after another, into one folder."""
    from .bench import ALL_RUNS

    common = ["--out", args.out] + (["--quick"] if args.quick else [])
    common += ["--cluster", args.cluster] if args.cluster is not None else []  # "" is refused by each bench
    common += ["--workers", str(args.workers)] if args.workers else []
    results = []
    for run in ALL_RUNS:
        argv = ["bench", *run, *common, "--json"] if args.json else ["bench", *run, *common]
        if not args.json:
            print(f"== stiction {' '.join(argv)}", flush=True)
        parsed = build_parser().parse_args(argv)
        parsed.argv = argv
        if args.json:
            from .bench import load_bench, sweep

            results.append(sweep.run(load_bench(parsed.bench), parsed, _command_line(parsed)))
        else:
            cmd_bench(parsed)
    if args.json:
        json.dump({"command": _command_line(args), "benches": results}, sys.stdout, indent=1, allow_nan=False)
        sys.stdout.write("\n")
    return 0


def _command_line(args) -> str:
    argv = getattr(args, "argv", None)
    return "stiction " + " ".join(argv) if argv else "stiction bench " + getattr(args, "bench", "all")


def _print_bench(module, result: dict) -> None:
    """A short human summary: the bench's own report when it has one, else the rows as a table
    (first columns), then the summary keys."""
    if hasattr(module, "report"):  # it names the files it wrote
        print(module.report(result))
        return
    rows = result["rows"]
    fields = list(module.FIELDS)[:8]
    print("  ".join(f"{f:>14.14}" for f in fields))
    shown = 40
    for r in rows[:shown]:
        print("  ".join(f"{_short(r[f]):>14.14}" for f in fields))
    if len(rows) > shown:
        print(f"... {len(rows) - shown} more rows (all of them with --json, or in the CSV with --out)")
    for k, v in result.items():
        if k not in ("command", "stamp", "rows", "files"):
            print(f"{k}: {_short(v) if not isinstance(v, (dict, list)) else json.dumps(v)[:200]}")
    for f in result.get("files", []):
        print(f"wrote {f}")


def _short(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return "" if v is None else str(v)


def cmd_solvers(args) -> int:
    for name in solver_names():
        print(name)
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (no usage block) and exit 2."""

    def error(self, message):
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def _finite(kind: str):
    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(x) or x < 0 or (kind == "positive" and x == 0):
            raise argparse.ArgumentTypeError(f"{text!r}: must be a finite number {'> 0' if kind == 'positive' else '>= 0'}")
        return x

    return parse


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    from . import __version__

    try:
        return version("stiction")
    except PackageNotFoundError:
        return __version__


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="stiction", description=__doc__.split("\n\n")[0],
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"stiction {_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    positive, nonneg = _finite("positive"), _finite("nonnegative")

    p = sub.add_parser("fclib", help="solve FCLib / Siconos .dat problems")
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--solver", default="default", choices=solver_names())
    p.add_argument("--tol", type=positive, default=1e-10, help="tolerance on the residual (default 1e-10)")
    p.add_argument("--max-iter", type=_positive_int, default=5000)
    p.add_argument("--time-limit", type=positive, default=60.0, help="seconds per problem (default 60)")
    p.add_argument("--warm-start", choices=["none", "proxqp", "file"], default="none",
                   help="file: the /guesses/1 of the file when it has one")
    p.add_argument("--json", action="store_true", help="print a JSON list instead of a table")
    p.set_defaults(func=cmd_fclib)

    p = sub.add_parser("demo", help="the default demo: Solo-12 standing and slipping, recordings and plots")
    p.add_argument("--out", default="out", help="folder for the HTML recordings and PNG plots (default out/)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("simulate", help="simulate a scene (see `stiction scenes`)")
    p.add_argument("scene", help="a scene name or a TOML file")
    p.add_argument("--duration", type=positive, help="seconds (default: the scene's)")
    p.add_argument("--dt", type=positive, help="time step (default: the scene's)")
    p.add_argument("--mode", choices=["timestep", "ode", "rk4", "adaptive"],
                   help="time stepping (eq. 70) or the relaxed DAI as an ODE (eq. 39 + 64): rk4 (= ode) or adaptive")
    p.add_argument("--delta", type=nonneg, help="ODE modes: Baumgarte delta (default dt)")
    p.add_argument("--zeta", type=positive, help="ODE modes: Baumgarte zeta (default 0.5)")
    p.add_argument("--mu", type=nonneg, help="friction coefficient of every contact (default: the scene's)")
    p.add_argument("--solver", choices=solver_names(), help="contact solver (default: default)")
    p.add_argument("--tol", type=positive, help="contact solver tolerance (default 1e-10)")
    p.add_argument("--formulation", choices=formulation_names(),
                   help="how each step is resolved (default exact; see `stiction formulations`)")
    p.add_argument("--pyramid-facets", type=_positive_int, help="pyramid: facets per cone (default 4)")
    p.add_argument("--pyramid-inscribed", action="store_true",
                   help="pyramid: corners on the cone (default: facets tangent to it)")
    p.add_argument("--penalty-stiffness", type=positive, help="penalty: K in N/m (default 1e5)")
    p.add_argument("--penalty-damping", type=nonneg, help="penalty: beta in s (default 1e-3)")
    p.add_argument("--record", metavar="FILE.html", help="write a self-contained meshcat recording")
    p.add_argument("--plot", metavar="FILE.png", help="plot base position, foot slip, contact forces")
    p.add_argument("--save", metavar="FILE.npz", help="save the trajectory")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("scenes", help="list the bundled scenes")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("casestudy", help="run one of the paper's case studies and check its numbers")
    p.add_argument("name", help="planar-friction, restitution, painleve, pendulum, kinematic-levels, "
                   "diagonal-push, slide-lift, identify-friction")
    p.add_argument("--plot", metavar="FILE.png", help="draw the case study's figure")
    p.add_argument("--json", action="store_true", help="print name, equations, checks and points as JSON")
    p.add_argument("--quick", action="store_true", help="a smaller sweep (same checks)")
    p.set_defaults(func=cmd_casestudy)

    p = sub.add_parser("formulations", help="list the formulations: name, the paper's equations, parameters")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_formulations)

    p = sub.add_parser("bench", help="benchmarks: scaling, work-precision, profiles, stability, creep, all")
    bench_sub = p.add_subparsers(dest="bench", required=True, parser_class=_Parser, metavar="BENCH")
    from .bench import available_benches, load_bench, sweep

    for name in available_benches():
        module = load_bench(name)
        q = bench_sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(q)
        sweep.add_common_arguments(q)
        q.set_defaults(func=cmd_bench)
    q = bench_sub.add_parser("all", help="every bench, into one folder (the figures of docs/benchmarks.md)")
    q.add_argument("--out", required=True, metavar="DIR", help="the folder for every CSV, JSON and PNG")
    q.add_argument("--quick", action="store_true", help="the small version of each bench")
    q.add_argument("--cluster", metavar="ADDRESS", help="a Dask scheduler address, or 'local'")
    q.add_argument("--workers", type=_positive_int, metavar="N", help="local worker processes")
    q.add_argument("--json", action="store_true", help="print every bench's result as one JSON document")
    q.set_defaults(func=cmd_bench_all)

    p = sub.add_parser("solvers", help="list the solver names")
    p.set_defaults(func=cmd_solvers)

    dump = _optional_module("dump")
    if dump is not None:
        p = sub.add_parser("dump", help="write each step's contact problem of a scene as FCLib HDF5")
        dump.add_arguments(p)
        p.set_defaults(func=dump.main)
    return parser


def _optional_module(name: str):
    """A module of the package that may be absent from a partial checkout (the parser lists it when present)."""
    import importlib

    try:
        return importlib.import_module(f"{__package__}.{name}")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__package__}.{name}":
            raise
        return None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    args.argv = argv
    try:
        return args.func(args)
    except (ValueError, TypeError, FileNotFoundError, IsADirectoryError, PermissionError, MissingExtraError) as exc:
        # bad input: the message names it
        print(f"stiction {args.command}: {_one_line(exc)}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # e.g. a simulation that diverged
        print(f"stiction {args.command}: {_one_line(exc)}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # the reader stopped early (`stiction scenes | head -1`): not an error
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        except (OSError, ValueError, AttributeError):
            pass
        return 0
    except KeyboardInterrupt:
        print(f"stiction {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug of ours: one line, the traceback on request
        if os.environ.get("STICTION_TRACEBACK"):
            raise
        print(f"stiction {args.command}: internal error: {type(exc).__name__}: {_one_line(exc)} "
              "(set STICTION_TRACEBACK=1 for the traceback and please report it)", file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


if __name__ == "__main__":
    sys.exit(main())
