"""Command line: ``stiction demo``, ``stiction fclib FILE...``, ``stiction solvers``."""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path


from . import fclib, solver_names, solve

# Problems the demo solves: small, varied, one per family that shows something.
DEMO_PROBLEMS = [
    "Toy--FrictionContact3D_RR_1c.dat",
    "Rover--Rover1039.dat",
    "OneObject--OneObject-i1028-138.hdf5.dat",
    "BoxesStack--BoxesStack1-i100000-32.hdf5.dat",
    "PerioBox--LMGC_100_PR_PerioBox-i00361-60-03000.hdf5",
    "Confeti--Confeti-ex13-Fc3D-SBM.dat",
]


def bundled_fclib_dir() -> Path:
    """benchmarks/fclib of the source tree (the package is installed editable from it)."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        candidate = parent / "benchmarks" / "fclib"
        if candidate.is_dir():
            return candidate
    raise FileNotFoundError("benchmarks/fclib not found next to the stiction sources")


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
    return 0 if all(r["converged"] for r in rows) else 1


def cmd_demo(args) -> int:
    """The default demo: Solo-12 standing, then slipping down a slope (recordings, plots,
    summaries), then the exact solver on a few real contact problems."""
    from .recording import record_html
    from .plots import plot_trajectory
    from .simulator import Simulator

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print("stiction demo: exact Coulomb contact, A λ - b ∈ -lim N_C^{U_ε}(λ) (eq. 65), solved every step\n")
    ok = True
    for scene, duration in (("solo12-stand", 2.0), ("solo12-slope-slip", 1.0)):
        sim = Simulator(scene)
        traj = sim.rollout(duration)
        summary = sim.summary(traj)
        html, png = out / f"{scene}.html", out / f"{scene}.png"
        record_html(sim, traj, html)
        plot_trajectory(sim, traj, png)
        ok &= summary["all_converged"]
        print(f"== {scene}: {sim.scene.description}")
        keys = ("steps", "us_per_step", "max_penetration", "max_residual", "base_drift", "max_foot_slip",
                "max_normal_velocity_while_sliding", "mean_acceleration_along_slope",
                "expected_sliding_acceleration")
        for k in keys:
            print(f"   {k:36s} {summary[k]:.4g}" if isinstance(summary[k], float) else f"   {k:36s} {summary[k]}")
        print("   µs per phase: " + ", ".join(f"{k} {v:.2f}" for k, v in summary["us_per_phase"].items()))
        print(f"   recording {html}   plot {png}\n")

    root = bundled_fclib_dir()
    print(f"== The solver alone on real contact problems from Siconos and LMGC90 ({root.name}/):")
    rows = [solve_file(str(root / name), "default", 1e-10, 5000, 30.0, None) for name in DEMO_PROBLEMS]
    print(_table(rows))
    ok &= all(r["converged"] for r in rows)
    print("\nresidual = ‖λ - P_C(λ - (u + E s(u)))‖ / (1 + ‖b‖); relative = the same / ‖b‖ (Siconos' measure).")
    print("More: stiction scenes | stiction simulate SCENE --json | stiction fclib benchmarks/fclib/*")
    return 0 if ok else 1


def cmd_scenes(args) -> int:
    from .scene import SCENES_DIR, list_scenes
    import tomllib

    for name in list_scenes():
        with open(SCENES_DIR / f"{name}.toml", "rb") as fh:
            desc = tomllib.load(fh).get("description", "")
        print(f"{name:22s} {desc}")
    return 0


def cmd_simulate(args) -> int:
    from .simulator import Simulator

    overrides = {}
    if args.dt is not None:
        overrides["dt"] = args.dt
    if args.mode is not None:
        overrides["mode"] = args.mode
    if args.delta is not None:
        overrides["delta"] = args.delta
    if args.zeta is not None:
        overrides["zeta"] = args.zeta
    sim = Simulator(args.scene, **overrides)
    traj = sim.rollout(args.duration)
    summary = sim.summary(traj)
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
    return 0 if summary["all_converged"] else 1


def cmd_solvers(args) -> int:
    for name in solver_names():
        print(name)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="stiction", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("fclib", help="solve FCLib / Siconos .dat problems")
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("--solver", default="default", choices=solver_names())
    p.add_argument("--tol", type=float, default=1e-10, help="tolerance on the residual (default 1e-10)")
    p.add_argument("--max-iter", type=int, default=5000)
    p.add_argument("--time-limit", type=float, default=60.0, help="seconds per problem (default 60)")
    p.add_argument("--warm-start", choices=["none", "proxqp", "file"], default="none",
                   help="file: the /guesses/1 of the file when it has one")
    p.add_argument("--json", action="store_true", help="print a JSON list instead of a table")
    p.set_defaults(func=cmd_fclib)

    p = sub.add_parser("demo", help="the default demo: Solo-12 standing and slipping, recordings and plots")
    p.add_argument("--out", default="out", help="folder for the HTML recordings and PNG plots (default out/)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("simulate", help="simulate a scene (see `stiction scenes`)")
    p.add_argument("scene", help="a scene name or a TOML file")
    p.add_argument("--duration", type=float, help="seconds (default: the scene's)")
    p.add_argument("--dt", type=float, help="time step (default: the scene's)")
    p.add_argument("--mode", choices=["timestep", "ode", "rk4", "adaptive"],
                   help="time stepping (eq. 70) or the relaxed DAI as an ODE (eq. 39 + 64): rk4 (= ode) or adaptive")
    p.add_argument("--delta", type=float, help="ODE modes: Baumgarte delta (default dt)")
    p.add_argument("--zeta", type=float, help="ODE modes: Baumgarte zeta (default 0.5)")
    p.add_argument("--record", metavar="FILE.html", help="write a self-contained meshcat recording")
    p.add_argument("--plot", metavar="FILE.png", help="plot base position, foot slip, contact forces")
    p.add_argument("--save", metavar="FILE.npz", help="save the trajectory")
    p.add_argument("--json", action="store_true", help="print the summary as JSON")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("scenes", help="list the bundled scenes")
    p.set_defaults(func=cmd_scenes)

    p = sub.add_parser("solvers", help="list the solver names")
    p.set_defaults(func=cmd_solvers)

    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as exc:  # bad input: the message names it
        print(f"stiction {args.command}: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # e.g. a simulation that diverged
        print(f"stiction {args.command}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
