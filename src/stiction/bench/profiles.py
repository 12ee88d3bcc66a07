"""The contact solvers alone on problem sets: Dolan-Moré performance profiles, data profiles,
success and false-convergence rates (``stiction bench profiles``).

Sets: ``fclib``, the bundled FCLib problems (benchmarks/fclib), and ``robot``, problems the package
dumps from its own simulations (:func:`robot_problem_set`: standing, slipping, impacts, grasps,
stacks; one FCLib file per step, cached under ``--problems``). Solvers: ours (default, nsgs, admm, newton,
exact law eq. 65), Pinocchio's ADMM and PGS (:mod:`stiction.baselines`, its NCP with De Saxcé's
correction) and, when Debian's python3-siconos is importable by ``/usr/bin/python3``, Siconos'
NSGS, NSN-AC and PROX (:mod:`stiction.bench.siconos`: one helper process, timed there).

Every answer is judged by one yardstick, whatever the solver claims: ``residual`` = the natural
map of the exact law at λ relative to ‖b‖ (:func:`stiction.exact_law_measures`, eq. 65, on the
stored A), and ``solved`` = residual <= tol. Each solver is asked for the same ``tol`` (``asked_tol``;
the ``pinocchio-*-tight`` variants are asked tol / 100 and judged at tol, since Pinocchio's own
stopping test stops short of tol by this measure); a solve that fails, crashes or overruns the
time limit is not solved and counts at the time limit.
Times: the median wall time of the solve call over a few repeats (ours: ``stiction.solve``;
Pinocchio: its ``solver.solve``; Siconos: ``fc3d_driver`` timed in its process).
"""
from __future__ import annotations

import functools
import json
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np

from . import siconos
from .siconos import usable as siconos_usable

NAME = "profiles"
HELP = "solvers alone on FCLib and robot problem sets: performance/data profiles, false convergence"
FIELDS = ("set", "problem", "solver", "ours", "seconds", "residual", "converged_claimed", "solved",
          "tol", "iterations", "contacts", "time_limit", "failure", "asked_tol")
KEY_FIELDS = ("set", "problem", "solver", "tol", "time_limit")  # a resumed sweep never mixes limits
DEFAULT_WORKERS = 1  # timings must not share the machine

OURS = ("default", "nsgs", "admm", "newton")
PINOCCHIO = ("pinocchio-admm", "pinocchio-pgs", "pinocchio-admm-tight", "pinocchio-pgs-tight")
# Pinocchio's stopping test is on its own (absolute, max-norm) quantities: asked for tol it stops at a
# median 6-7 tol by the exact law's relative residual on the robot set. "-tight" asks it for
# tol / TIGHT and is still judged at tol: what it costs Pinocchio to actually meet tol.
TIGHT = 100.0
SICONOS = {f"siconos-{name}": solver_id for name, solver_id in siconos.SOLVERS.items()}
ALL_SOLVERS = OURS + PINOCCHIO + tuple(SICONOS)
QUICK_SOLVERS = ("default", "nsgs", "admm", "pinocchio-admm", "pinocchio-pgs")
TOLS = (1e-4, 1e-8)
SETS = ("fclib", "robot")
MAX_ITERATIONS = 10000
SGM_SHIFT = 1e-5  # s: the shifted geometric mean's shift, about the timer noise of one Python call
QUICK_FCLIB = ("Toy--FC3D_Example1.dat", "Toy--FrictionContact3D_RR_1c.dat", "Rover--Rover1039.dat",
               "Rover--Rover4613.dat", "CubesH8--LMGC_GlobalFrictionContactProblem00046.hdf5",
               "OneObject--OneObject-i1028-138.hdf5.dat")
# 2: talos-stand and go2-stand stand still (feed-forward of their static equilibrium; issue 23), so
# their problems differ from a cached v1 set
ROBOT_SET_VERSION = 2


# ---- the robot problem set ---------------------------------------------------------------------------

# (category, scene, steps simulated, problems kept, first step eligible); quick keeps 2 of each row
ROBOT_SCENES = (
    ("standing", "solo12-stand", 300, 12, 20),
    ("standing", "go2-stand", 300, 12, 20),
    ("standing", "anymal-stand", 300, 12, 20),
    ("standing", "talos-stand", 300, 12, 20),
    ("slipping", "solo12-slope-slip", 300, 12, 20),
    ("slipping", "cube-incline-slip", 300, 12, 20),
    ("grasps", "ur5-push-box", 600, 12, 20),
    ("grasps", "ur5-push-wall", 600, 12, 20),
    ("stacks", "two-cube-stack", 300, 6, 20),
    ("stacks", "box-tower-20", 300, 6, 20),
)
QUICK_ROBOT_SCENES = ("solo12-stand", "cube-incline-slip", "ur5-push-wall", "two-cube-stack")
CUBE_DROPS, QUICK_CUBE_DROPS = 8, 1  # impacts: cubes dropped at random attitudes, 3 impact steps each
IMPACT_STEPS = 3


def default_problem_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "stiction" / "problems"


def _impact_steps(sim_factory, steps: int, count: int) -> list[int]:
    """The first `count` steps whose solve found a non-zero normal force (the landing)."""
    sim = sim_factory()
    traj = sim.rollout(steps * sim.dt)
    normal = traj.lam[1:, :, 2].max(axis=1) if traj.lam.shape[1] else np.zeros(len(traj.t) - 1)
    return [int(k) + 1 for k in np.flatnonzero(normal > 0)[:count]]


def _cube_drop(seed: int):
    """A 10 cm, 1 kg cube released 1-8 cm above flat ground (mu 0.5) at a seeded random attitude,
    moving sideways: its corners land one after another (impacts, eq. 65 with large -b_n)."""
    import pinocchio as pin

    from ..scene import build_scene
    from ..simulator import Simulator

    rng = np.random.default_rng(seed)
    scene = build_scene({"name": f"cube-drop-{seed}", "urdf": "cube.urdf", "free_flyer": True, "dt": 1e-3,
                         "ground": {"mu": 0.5}, "contacts": {"box_corners": True}})
    quat = rng.standard_normal(4)
    quat /= np.linalg.norm(quat)
    R = pin.Quaternion(quat[3], quat[0], quat[1], quat[2]).toRotationMatrix()
    corners = np.array([[sx, sy, sz] for sx in (-.05, .05) for sy in (-.05, .05) for sz in (-.05, .05)])
    lowest = (corners @ R.T)[:, 2].min()
    q = np.concatenate([[0.0, 0.0, -lowest + rng.uniform(0.01, 0.08)], quat])
    v = np.concatenate([rng.uniform(-1.0, 1.0, 2), [0.0], rng.uniform(-3.0, 3.0, 3)])

    def make():
        sim = Simulator(scene)
        sim.set_state(q=q, v=v)
        return sim
    return scene.name, make


def robot_problem_set(directory: str | os.PathLike | None = None, quick: bool = False, seed: int = 0) -> list[dict]:
    """Problems dumped from the package's own simulations (``stiction dump``): robots standing, sliding
    down a slope, objects landing (impacts), an arm pushing (grasps), stacked boxes (A couples the
    contacts through the bodies between them). Built once and cached in
    ``directory/robot-v<version>-seed<seed>[-quick]`` (a manifest.json lists them and the recipe; a
    folder built from another recipe is rebuilt). Steps are drawn by a seeded generator after each
    scene's first steps (standing, slipping, grasps, stacks); impacts are the first steps with contact
    force of a ball landing on a table and of seeded cube drops. Returns one record per problem:
    name, category, path, scene, step, contacts."""
    from ..dump import NO_JOINT_ROWS, dump

    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"robot_problem_set: seed must be an integer >= 0, got {seed!r}")
    root = Path(directory) if directory is not None else default_problem_dir()
    if root.exists() and not root.is_dir():
        raise ValueError(f"--problems {root} is a file, not a folder")
    folder = root / f"robot-v{ROBOT_SET_VERSION}-seed{seed}{'-quick' if quick else ''}"
    manifest = folder / "manifest.json"
    # what the set is made of: a cache built from another recipe is rebuilt
    recipe = {"scenes": [list(x) for x in ROBOT_SCENES if not quick or x[1] in QUICK_ROBOT_SCENES],
              "cube_drops": QUICK_CUBE_DROPS if quick else CUBE_DROPS, "impact_steps": IMPACT_STEPS}
    if manifest.is_file():
        try:
            old = json.loads(manifest.read_text())
        except ValueError:
            old = {}
        recs = old.get("problems", [])
        if old.get("recipe") == recipe and recs and all((folder / r["file"]).is_file() for r in recs):
            return [{**r, "path": str(folder / r["file"])} for r in recs]
        for f in folder.glob("*.hdf5"):  # stale: rebuild from scratch
            f.unlink()
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    recs = []

    def add(category, written):
        for w in written:
            p = Path(w["path"])
            recs.append({"name": p.stem, "category": category, "file": p.name,
                         "scene": w["scene"], "step": w["step"], "contacts": len(w["contacts"])})

    for category, scene, steps, keep, first in ROBOT_SCENES:
        if quick and scene not in QUICK_ROBOT_SCENES:
            continue
        n = 2 if quick else keep
        chosen = sorted(int(k) for k in rng.choice(np.arange(first, steps + 1), size=n, replace=False))
        # the contacts alone (FCLib holds no joint rows: TALOS's arm friction and limits are left out)
        add(category, dump(scene, max(chosen), folder, only=chosen, prefix=f"{category}--{scene}", **NO_JOINT_ROWS))
    from ..simulator import Simulator

    ball = lambda: Simulator("ball-on-table")  # noqa: E731
    hits = _impact_steps(ball, 400, 1 if quick else IMPACT_STEPS)
    add("impacts", dump(ball(), max(hits), folder, only=hits, prefix="impacts--ball-on-table"))
    for d in range(QUICK_CUBE_DROPS if quick else CUBE_DROPS):
        name, make = _cube_drop(int(rng.integers(2**31)))
        hits = _impact_steps(make, 300, 2 if quick else IMPACT_STEPS)
        if hits:
            add("impacts", dump(make(), max(hits), folder, only=hits, prefix=f"impacts--{name}"))
    manifest.write_text(json.dumps({"version": ROBOT_SET_VERSION, "seed": seed, "quick": quick,
                                    "recipe": recipe, "problems": recs}, indent=1))
    return [{**r, "path": str(folder / r["file"])} for r in recs]


def fclib_problem_set(quick: bool = False) -> list[dict]:
    from ..resources import fclib_dir

    files = sorted(p for p in fclib_dir().iterdir() if p.suffix in (".hdf5", ".dat"))
    if quick:
        files = [p for p in files if p.name in QUICK_FCLIB]
    return [{"name": p.name, "category": p.name.split("--")[0], "path": str(p)} for p in files]


# ---- the bench contract ----------------------------------------------------------------------------

def _floats(text: str) -> list[float]:
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"--tols: positive finite numbers separated by commas, got {text!r}") from None
    if not vals or any(not (v > 0 and math.isfinite(v)) for v in vals):
        raise ValueError(f"--tols: positive finite numbers separated by commas, got {text!r}")
    return vals


def add_arguments(parser) -> None:
    parser.add_argument("--sets", default=",".join(SETS), help="problem sets, comma-separated: fclib, robot")
    parser.add_argument("--solvers", default=None,
                        help=f"comma-separated, of {', '.join(ALL_SOLVERS)} (default: all usable; --quick: "
                             f"{', '.join(QUICK_SOLVERS)})")
    parser.add_argument("--tols", default=",".join(f"{t:g}" for t in TOLS), help="tolerances (default 1e-4,1e-8)")
    parser.add_argument("--time-limit", type=float, default=None,
                        help="seconds per solve (default 10; --quick 2); a solve over it counts as failed")
    parser.add_argument("--problems", default=None,
                        help=f"cache folder of the robot problem set (default {default_problem_dir()})")
    parser.add_argument("--seed", type=int, default=0, help="seed of the robot problem set (default 0)")


def cases(args) -> list[dict]:
    quick = bool(getattr(args, "quick", False))
    # an option given empty is an error naming it, never the default
    sets_arg = getattr(args, "sets", None)
    sets = [s.strip() for s in (sets_arg if sets_arg is not None else ",".join(SETS)).split(",") if s.strip()]
    if not sets:
        raise ValueError(f"--sets: empty list (name at least one of {', '.join(SETS)})")
    for s in sets:
        if s not in SETS:
            raise ValueError(f"--sets: unknown set {s!r} (known: {', '.join(SETS)})")
    given = getattr(args, "solvers", None)
    if given is not None:
        solvers = [s.strip() for s in given.split(",") if s.strip()]
        if not solvers:
            raise ValueError(f"--solvers: empty list (name at least one of {', '.join(ALL_SOLVERS)})")
        for s in solvers:
            if s not in ALL_SOLVERS:
                raise ValueError(f"--solvers: unknown solver {s!r} (known: {', '.join(ALL_SOLVERS)})")
        if any(s in SICONOS for s in solvers) and not siconos_usable():
            raise ValueError("--solvers names Siconos, which /usr/bin/python3 cannot import "
                             "(apt install python3-siconos python3-scipy)")
    else:
        solvers = list(QUICK_SOLVERS if quick else OURS + PINOCCHIO)
        if not quick and siconos_usable():
            solvers += list(SICONOS)
    tols_arg = getattr(args, "tols", None)
    tols = _floats(tols_arg if tols_arg is not None else ",".join(map(str, TOLS)))
    limit = getattr(args, "time_limit", None)
    limit = (2.0 if quick else 10.0) if limit is None else float(limit)
    if not (limit > 0 and math.isfinite(limit)):
        raise ValueError(f"--time-limit must be a positive number of seconds, got {limit}")
    problems = []
    for s in sets:
        recs = fclib_problem_set(quick) if s == "fclib" else \
            robot_problem_set(getattr(args, "problems", None), quick, int(getattr(args, "seed", 0) or 0))
        problems += [(s, r) for r in recs]
    return [{"set": s, "problem": r["name"], "path": r["path"], "solver": solver, "ours": solver in OURS,
             "tol": tol, "time_limit": limit, "repeat_budget": 0.01 if quick else 0.2}
            for s, r in problems for tol in tols for solver in solvers]


@functools.lru_cache(maxsize=4)
def _load(path: str):
    from .. import fclib

    P = fclib.load(path)
    return P, P.problem()


def _relative_residual(problem, lam) -> float:
    from .. import _core

    lam = np.asarray(lam, dtype=np.float64)
    if lam.shape != (problem.num_rows,) or not np.all(np.isfinite(lam)):
        return math.inf
    return float(_core.exact_law_measures(problem, lam).relative_residual)


def _repeat(solve, budget: float):
    """The median time of `solve` (returns (seconds, result)) over up to 5 runs, stopping once
    `budget` seconds are spent; the last result."""
    times, spent, res = [], 0.0, None
    while True:
        t, res = solve()
        times.append(t)
        spent += t
        if spent >= budget or len(times) >= 5:
            return statistics.median(times), res


def _solve_ours(problem, solver, tol, limit, budget):
    import stiction

    def once():
        t0 = time.perf_counter()
        r = stiction.solve(problem, solver=solver, tol=tol, max_iter=MAX_ITERATIONS, time_limit=limit)
        return time.perf_counter() - t0, r
    seconds, r = _repeat(once, budget)
    return seconds, np.asarray(r.lam), bool(r.converged), int(r.iterations)


PINOCCHIO_PROBE = 20


def _solve_pinocchio(problem, method, tol, limit, budget):
    """Pinocchio cannot be stopped mid-solve: its iteration budget is set from a 20-iteration probe
    so that the solve fits the time limit (at most MAX_ITERATIONS)."""
    from ..baselines import pinocchio_solve

    probe = pinocchio_solve(problem, method, tol=tol, max_iter=PINOCCHIO_PROBE)
    max_iter = PINOCCHIO_PROBE
    if not probe.converged and probe.iterations >= PINOCCHIO_PROBE:
        per_iteration = max(probe.seconds, 1e-9) / probe.iterations
        max_iter = max(PINOCCHIO_PROBE, min(MAX_ITERATIONS, int(limit / per_iteration)))

    def once():
        r = pinocchio_solve(problem, method, tol=tol, max_iter=max_iter)
        return r.seconds, r
    seconds, r = _repeat(once, budget)
    return seconds, r.lam, bool(r.converged), int(r.iterations)


_siconos: siconos.Server | None = None


class _Failure(Exception):
    """A solve that returned nothing (crash, time limit); its message is the row's failure."""


def _solve_siconos(path, P, solver, tol, limit, budget):
    """Repeats stop once `budget` is spent (at most 5), so one over-long solve shows as a request
    past limit + budget (plus loading the problem): the helper is stopped then."""
    global _siconos
    if _siconos is None:
        _siconos = siconos.Server()
    out = _siconos.solve(path, P, solver.removeprefix("siconos-"), tol, siconos.Repeats(min_seconds=budget),
                         timeout=1.2 * limit + budget + 1.0)
    if "error" in out:
        raise _Failure(out["error"])
    return out["seconds"], out["lam"], out["info"] == 0, out["iterations"]


def evaluate(case: dict) -> dict:
    """One solve of one problem by one solver, judged by the exact law's relative residual."""
    row = {k: case[k] for k in ("set", "problem", "solver", "ours", "tol", "time_limit")}
    row.update(seconds=None, residual=None, converged_claimed=False, solved=False, iterations=None,
               contacts=None, failure=None, asked_tol=case["tol"])
    try:
        P, problem = _load(case["path"])
        row["contacts"] = int(P.contacts)
        solver, tol, limit, budget = case["solver"], float(case["tol"]), float(case["time_limit"]), \
            float(case.get("repeat_budget", 0.2))
        if solver in OURS:
            seconds, lam, claimed, its = _solve_ours(problem, solver, tol, limit, budget)
        elif solver in PINOCCHIO:
            method = solver.split("-")[1]
            asked = tol / TIGHT if solver.endswith("-tight") else tol
            row["asked_tol"] = asked
            seconds, lam, claimed, its = _solve_pinocchio(problem, method, asked, limit, budget)
        elif solver in SICONOS:
            seconds, lam, claimed, its = _solve_siconos(case["path"], P, solver, tol, limit, budget)
        else:
            raise ValueError(f"unknown solver {solver!r}")
        res = _relative_residual(problem, lam)
        row.update(seconds=float(seconds), residual=res if math.isfinite(res) else None,
                   converged_claimed=bool(claimed), iterations=int(its), solved=bool(res <= tol))
        if not math.isfinite(res):
            row["failure"] = "non-finite"
        elif seconds > limit:
            row["failure"] = "time limit"
        elif not row["solved"]:
            row["failure"] = "residual"
    except _Failure as exc:
        row["failure"] = str(exc)[:160]
    except Exception as exc:  # a failing solver is data
        row["failure"] = f"{type(exc).__name__}: {exc}"[:160]
    return row


# ---- profiles ---------------------------------------------------------------------------------------

def effective_times(rows: list[dict]) -> dict:
    """{(problem, solver): seconds} with a failure (not solved, or over the time limit) at +inf."""
    out = {}
    for r in rows:
        ok = r["solved"] and r["seconds"] is not None and r["seconds"] <= r["time_limit"]
        out[(r["problem"], r["solver"])] = float(r["seconds"]) if ok else math.inf
    return out


def performance_ratios(rows: list[dict]) -> dict:
    """Dolan-Moré ratios r_ps = t_ps / min_s t_ps per solver (one per problem; inf when s failed
    or no solver solved p). `rows`: one tolerance of one set."""
    t = effective_times(rows)
    problems = sorted({p for p, _ in t})
    solvers = sorted({s for _, s in t})
    best = {p: min(t.get((p, s), math.inf) for s in solvers) for p in problems}
    return {s: [t.get((p, s), math.inf) / best[p] if math.isfinite(best[p]) else math.inf for p in problems]
            for s in solvers}


def rho(ratios: list[float], tau: float) -> float:
    """rho_s(tau): the fraction of problems with r_ps <= tau (non-decreasing in tau; its limit is
    the success rate)."""
    return sum(r <= tau for r in ratios) / len(ratios) if ratios else 0.0


def shifted_geometric_mean(times: list[float], shift: float = SGM_SHIFT) -> float:
    """exp(mean log(t + shift)) - shift: a mean of times that no few tiny ones dominate."""
    if not times:
        return math.nan
    return math.exp(sum(math.log(t + shift) for t in times) / len(times)) - shift


def _tau_grid(ratios: dict) -> list[float]:
    finite = [r for rs in ratios.values() for r in rs if math.isfinite(r)]
    top = max(finite + [2.0])
    # past the largest ratio, so every curve shows its final level (its success rate)
    return [float(x) for x in np.unique(np.concatenate([np.geomspace(1.0, 2.0 * top, 60), finite]))]


def _budget_grid(rows: list[dict]) -> list[float]:
    limit = max(r["time_limit"] for r in rows)
    return [float(x) for x in np.geomspace(1e-6, limit, 61)]


def _categories(problems: list[str]) -> dict:
    out: dict = {}
    for p in problems:
        out.setdefault(p.split("--")[0], []).append(p)
    return out


def _group_summary(rows: list[dict]) -> dict:
    ratios = performance_ratios(rows)
    t = effective_times(rows)
    problems = sorted({r["problem"] for r in rows})
    taus, budgets = _tau_grid(ratios), _budget_grid(rows)
    per = {}
    for s in sorted(ratios):
        mine = [r for r in rows if r["solver"] == s]
        limit = max(r["time_limit"] for r in mine)
        times = [t[(p, s)] if math.isfinite(t.get((p, s), math.inf)) else limit for p in problems]
        solved_times = [x for x in (t.get((p, s), math.inf) for p in problems) if math.isfinite(x)]
        claims = sum(bool(r["converged_claimed"]) for r in mine)
        false_claims = sum(bool(r["converged_claimed"]) and not r["solved"] for r in mine)
        per[s] = {
            "ours": bool(mine[0]["ours"]),
            "problems": len(problems),
            "solved": len(solved_times),
            "success_rate": len(solved_times) / len(problems),
            "claims": claims,
            "false_claims": false_claims,
            "false_convergence_rate": false_claims / len(problems),
            # how near the misses are: a stopping test on other quantities may stop just short of tol
            "within_10x_tol": sum(r["residual"] is not None and r["residual"] <= 10 * r["tol"] for r in mine)
            / len(problems),
            "sgm_seconds": shifted_geometric_mean(times),
            # where it fails: solved / problems per family (the name's prefix before "--")
            "by_category": {c: f"{sum(math.isfinite(t.get((p, s), math.inf)) for p in ps)}/{len(ps)}"
                            for c, ps in _categories(problems).items()},
            "rho": [rho(ratios[s], x) for x in taus],
            "data_profile": [sum(x <= b for x in solved_times) / len(problems) for b in budgets],
        }
    return {"tau": taus, "budget_seconds": budgets, "solvers": per}


def summarize(rows: list[dict]) -> dict:
    """Per set and tolerance: each solver's success rate, false-convergence rate (claimed converged,
    residual above tol), shifted geometric mean time (failures at the time limit, shift SGM_SHIFT),
    performance profile rho(tau) and data profile (fraction solved within each time budget)."""
    out: dict = {}
    for s in sorted({r["set"] for r in rows}):
        for tol in sorted({r["tol"] for r in rows if r["set"] == s}, reverse=True):
            group = [r for r in rows if r["set"] == s and r["tol"] == tol]
            out.setdefault(s, {})[f"{tol:g}"] = _group_summary(group)
    table = [{"set": s, "tol": tol, "solver": name,
              **{k: v for k, v in d.items() if k not in ("rho", "data_profile", "by_category")}}
             for s, by_tol in out.items() for tol, g in by_tol.items() for name, d in g["solvers"].items()]
    return {"profiles": out, "table": table}


def report(result: dict) -> str:
    """The human summary (instead of thousands of rows): per set and tolerance, one line per solver."""
    lines = []
    for s, by_tol in result.get("profiles", {}).items():
        for tol, g in by_tol.items():
            lines.append(f"{s}, tol {tol}:  solver / solved / false claims / residual <= 10 tol / "
                         f"shifted geometric mean time (failures at the limit)")
            for name, d in sorted(g["solvers"].items(), key=lambda kv: (-kv[1]["solved"], kv[1]["sgm_seconds"])):
                lines.append(f"  {name:22s} {d['solved']:4d}/{d['problems']:<4d} {d['false_claims']:4d}   "
                             f"{d['within_10x_tol']:6.0%}   {d['sgm_seconds'] * 1e3:10.4g} ms")
    lines += [f"wrote {f}" for f in result.get("files", [])]
    return "\n".join(lines)


# ---- charts -------------------------------------------------------------------------------------------

def plot(rows: list[dict], out_dir, stamp: dict) -> list[Path]:
    from .._optional import require

    require("matplotlib", "plot", "the profiles charts")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .sweep import stamp_figure

    summary = summarize(rows)["profiles"]
    paths = []
    for set_name, by_tol in summary.items():
        tols = list(by_tol)
        fig, axes = plt.subplots(len(tols), 3, figsize=(15, 4.2 * len(tols)), squeeze=False)
        for i, tol in enumerate(tols):
            g = by_tol[tol]
            names = list(g["solvers"])
            palette = [plt.cm.tab10(k) for k in range(10)] + [plt.cm.Dark2(k) for k in range(8)]
            colours = {n: palette[k % len(palette)] for k, n in enumerate(names)}
            ax_p, ax_d, ax_b = axes[i]
            for n in names:
                d = g["solvers"][n]
                style = "-" if d["ours"] else (":" if n.startswith("siconos") else "--")
                ax_p.step(g["tau"], d["rho"], where="post", ls=style, color=colours[n],
                          label=f"{n} ({d['solved']}/{d['problems']})")
                ax_d.step(g["budget_seconds"], d["data_profile"], where="post", ls=style, color=colours[n],
                          label=f"{n} (sgm {d['sgm_seconds'] * 1e3:.3g} ms)")
            ax_p.set(xscale="log", xlabel="τ (time / best time on the problem)", ylabel="ρ(τ): fraction within τ",
                     ylim=(-0.02, 1.02), title=f"{set_name}: performance profile, tol {tol}")
            ax_d.set(xscale="log", xlabel="time budget (s)", ylabel="fraction solved",
                     ylim=(-0.02, 1.02), title=f"{set_name}: data profile, tol {tol}")
            x = np.arange(len(names))
            succ = [g["solvers"][n]["success_rate"] for n in names]
            near = [g["solvers"][n]["within_10x_tol"] for n in names]
            false = [g["solvers"][n]["false_convergence_rate"] for n in names]
            ax_b.bar(x - 0.27, succ, 0.27, label="solved (residual ≤ tol, in time)", color="tab:green")
            ax_b.bar(x, near, 0.27, label="residual ≤ 10 tol", color="tab:olive", alpha=0.6)
            ax_b.bar(x + 0.27, false, 0.27, label="false convergence (claimed, not solved)", color="tab:red")
            for k, n in enumerate(names):
                ax_b.text(k + 0.27, false[k] + 0.01, str(g["solvers"][n]["false_claims"]), ha="center",
                          va="bottom", fontsize=7)
            ax_b.set_xticks(x, names, rotation=30, ha="right", fontsize=8)
            ax_b.set_yticks(np.linspace(0, 1, 6))
            ax_b.set(ylim=(0, 1.45), ylabel="fraction of problems",
                     title=f"{set_name}: success and false convergence, tol {tol}")
            for ax in (ax_p, ax_d, ax_b):
                ax.grid(alpha=0.3)
                ax.legend(fontsize=7 if ax is ax_b else 6.5, loc="best" if ax is not ax_b else "upper center",
                          ncol=1 if ax is not ax_b else 2)
        fig.suptitle(f"Solvers alone on the {set_name} problem set ({g['solvers'][names[0]]['problems']} "
                     "problems); solved = exact-law relative residual ≤ tol, whatever the solver claims; "
                     "failures count at the time limit", fontsize=10)
        fig.tight_layout(rect=(0, 0.02, 1, 0.97))
        stamp_figure(fig, stamp)
        path = Path(out_dir) / f"profiles-{set_name}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
        paths.append(_plot_categories(plt, set_name, by_tol, Path(out_dir), stamp))
    return paths


def _plot_categories(plt, set_name: str, by_tol: dict, out_dir: Path, stamp: dict) -> Path:
    """Where each solver fails: the fraction solved per problem family, one heat map per tolerance."""
    from .sweep import stamp_figure

    tols = list(by_tol)
    first = by_tol[tols[0]]["solvers"]
    names = list(first)
    cats = list(next(iter(first.values()))["by_category"])
    fig, axes = plt.subplots(len(tols), 1, figsize=(max(10.0, 0.8 * len(cats) + 2.5),  # the stamp fits
                                                    (0.3 * len(names) + 1.6) * len(tols)), squeeze=False)
    for ax, tol in zip(axes[:, 0], tols):
        g = by_tol[tol]["solvers"]
        cells = [[g[n]["by_category"][c] for c in cats] for n in names]
        frac = np.array([[int(x.split("/")[0]) / int(x.split("/")[1]) for x in row] for row in cells])
        ax.imshow(frac, cmap="RdYlGn", vmin=-0.4, vmax=1.4, aspect="auto")  # light ends: the text stays legible
        for i, row in enumerate(cells):
            for j, text in enumerate(row):
                ax.text(j, i, text, ha="center", va="center", fontsize=7)
        ax.set_xticks(range(len(cats)), cats, rotation=35, ha="right", fontsize=8)
        ax.set_yticks(range(len(names)), names, fontsize=8)
        ax.set_title(f"{set_name}: solved per family (residual ≤ {tol}, in time)", fontsize=9)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    stamp_figure(fig, stamp)
    path = out_dir / f"profiles-{set_name}-families.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
