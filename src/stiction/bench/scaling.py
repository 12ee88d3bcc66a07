"""Cost per step against contact count: a grid of free cubes on the ground, or a tower of them
(layout "tower": each cube on the one below), 4 corner contacts each, 1 kg, 10 cm, mu = 0.5,
dt = 1 ms, time stepping, exact law to 1e-10, N = 4 ... contacts.

Each size runs in its own subprocess (so ``peak_memory_mb``, the process's peak resident memory,
is that size's) and simulates ``steps`` steps after ``warmup`` untimed ones. Both simulators are
timed with one statistic: the steps split into 10 consecutive blocks, the mean time per step of
each block, and the median of those 10 (stiction: its per-step C++ timings, which leave out the
recording; MuJoCo 4.0, the optional ``bench`` extra: wall clock around its ``mj_step`` calls). A
step that takes long (a hard solve) counts in its block's mean, as MuJoCo's do, while one noisy
block does not move the median. MuJoCo runs the same scene when it is importable: free boxes on
a plane, elliptic cones, Newton, tolerance 1e-10, the same masses, mu and dt
(:func:`stiction.bench.mujoco_twins.cube_array_spec`).

The fitted exponent is the least-squares slope of log(us_per_step) against log(contacts).

``--layout pile``: sizes are body counts of a pile of mixed shapes dropped into a bin, timed
interleaved with its MuJoCo twin in one process (:mod:`stiction.bench.pile_scaling`); the exponent
is then against bodies, and us_per_step is the mean step (median_us_per_step beside it).
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
import time

MEASURE = r"""
import json, resource, sys, time
import numpy as np
from stiction.scene import build_scene
from stiction.simulator import Simulator
cubes, steps, warmup, layout = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
sim = Simulator(build_scene({"name": f"cube-{layout}-{4 * cubes}", "array": {"layout": layout, "count": cubes},
                             "ground": {"mu": 0.5}}))
sim.rollout(warmup * sim.dt)
traj = sim.rollout(steps * sim.dt)
s = sim.summary(traj)
per_step = traj.timings[1:, 4]
blocks = np.array_split(per_step, min(10, len(per_step)))  # the statistic MuJoCo's timing below uses
print(json.dumps({"us_per_step": float(np.median([b.mean() for b in blocks])), "all_converged": s["all_converged"],
                  "max_penetration": s["max_penetration"], "max_body_drift": s["max_body_drift"],
                  "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}))
"""


LAYOUTS = ("grid", "tower", "pile")


def mujoco_us_per_step(cubes: int, steps: int, warmup: int, layout: str = "grid") -> float | None:
    from . import mujoco_twins

    if not mujoco_twins.available():
        return None
    import mujoco

    model = mujoco_twins.cube_array_spec(cubes, layout).compile()
    data = mujoco.MjData(model)
    for _ in range(warmup):
        mujoco.mj_step(model, data)
    blocks = []
    per_block = max(1, steps // 10)
    for _ in range(10):
        t0 = time.perf_counter()
        for _ in range(per_block):
            mujoco.mj_step(model, data)
        blocks.append((time.perf_counter() - t0) / per_block * 1e6)
    blocks.sort()
    return blocks[len(blocks) // 2]


def fit_exponent(contacts: list[int], us: list[float]) -> float | None:
    pts = [(math.log(c), math.log(u)) for c, u in zip(contacts, us) if u and u > 0]
    if len(pts) < 2:
        return None
    mx = sum(p[0] for p in pts) / len(pts)
    my = sum(p[1] for p in pts) / len(pts)
    sxx = sum((p[0] - mx) ** 2 for p in pts)
    return sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx if sxx > 0 else None


NAME = "scaling"
HELP = "cost per step against contact count: a grid or a tower of cubes, beside MuJoCo"
FIELDS = ("scene", "layout", "contacts", "steps", "us_per_step", "us_per_contact", "peak_memory_mb",
          "mujoco_us_per_step", "all_converged", "max_penetration", "max_body_drift",
          # the pile's (None for the cube arrays): stiction.bench.pile_scaling
          "bodies", "median_us_per_step", "energy_drift", "mujoco_median_us_per_step", "mujoco_contacts",
          "mujoco_max_penetration", "mujoco_energy_drift")
PILE_ONLY = FIELDS[11:]
KEY_FIELDS = ("scene", "steps")
DEFAULT_WORKERS = 1  # a timing and a peak-memory figure per size: one size at a time on the machine
WARMUP_STEPS = 20
DEFAULT_STEPS, QUICK_STEPS = 200, 50


def add_arguments(parser) -> None:
    parser.add_argument("--sizes", type=int, nargs="+", metavar="N",
                        help="contact counts (multiples of 4); --layout pile: body counts")
    from ..cli import _positive_int  # the CLI's own integer check (called when the CLI builds its parser)

    parser.add_argument("--steps", type=_positive_int, default=None,
                        help=f"timed steps per size, >= 1 (default {DEFAULT_STEPS}; --quick {QUICK_STEPS})")
    parser.add_argument("--layout", choices=list(LAYOUTS), default="grid",
                        help="cubes side by side on the ground (default) or stacked; pile: mixed shapes dropped "
                        "into a bin, beside MuJoCo interleaved (sizes: bodies)")
    parser.add_argument("--warmup", type=_positive_int, default=None,
                        help="--layout pile: untimed steps of both simulators before the timed ones (default 300: "
                        "the bodies landing)")
    parser.add_argument("--plot", metavar="FILE.png", help="the log-log chart (also written to --out)")


def cases(args) -> list[dict]:
    if args.layout == "pile":
        from . import pile_scaling

        bodies = args.sizes or ([8, 24] if args.quick else [24, 64, 256])
        given = getattr(args, "steps", None)
        steps = given if given is not None else (pile_scaling.QUICK_STEPS if getattr(args, "quick", False)
                                                 else pile_scaling.DEFAULT_STEPS)
        for n in bodies:
            if n < 1:
                raise ValueError(f"--layout pile: body counts must be >= 1, got {n}")
        warmup = getattr(args, "warmup", None)
        warmup = pile_scaling.WARMUP_STEPS if warmup is None else warmup
        return [{"scene": f"pile-mix-{n}", "layout": "pile", "bodies": n, "steps": steps, "warmup": warmup}
                for n in bodies]
    sizes = args.sizes or ([4, 16, 64] if args.quick else [4, 16, 64, 128, 256])
    given = getattr(args, "steps", None)  # an explicit --steps is honoured, --quick or not
    steps = given if given is not None else (QUICK_STEPS if getattr(args, "quick", False) else DEFAULT_STEPS)
    if args.layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {args.layout!r}")
    if steps < 1:
        raise ValueError(f"--steps must be >= 1, got {steps}")
    if getattr(args, "warmup", None) is not None:
        raise ValueError("--warmup applies to --layout pile only")
    for contacts in sizes:
        if contacts < 4 or contacts % 4:
            raise ValueError(f"contact counts must be positive multiples of 4 (4 corners per cube), got {contacts}")
    return [{"scene": f"cube-{args.layout}-{c}", "layout": args.layout, "contacts": c, "steps": steps} for c in sizes]


def evaluate(case: dict) -> dict:
    """One size in its own subprocess (its peak memory is that size's), MuJoCo beside it."""
    if case["layout"] == "pile":
        from . import pile_scaling

        row = pile_scaling.evaluate(case)
        return {**row, "us_per_contact": row["us_per_step"] / row["contacts"] if row["contacts"] else None,
                "max_body_drift": None}
    layout, contacts, steps = case["layout"], case["contacts"], case["steps"]
    cubes = contacts // 4
    out = subprocess.run([sys.executable, "-c", MEASURE, str(cubes), str(steps), str(WARMUP_STEPS), layout],
                         capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"cube {layout} of {contacts} contacts failed: {out.stderr.strip().splitlines()[-1:]}")
    m = json.loads(out.stdout.strip().splitlines()[-1])
    return {"scene": f"cube-{layout}-{contacts}", "layout": layout, "contacts": contacts, "steps": steps,
            "us_per_step": m["us_per_step"], "us_per_contact": m["us_per_step"] / contacts,
            "peak_memory_mb": m["peak_memory_mb"],
            "mujoco_us_per_step": mujoco_us_per_step(cubes, steps, WARMUP_STEPS, layout),
            "all_converged": m["all_converged"], "max_penetration": m["max_penetration"],
            "max_body_drift": m["max_body_drift"], "bodies": cubes, **{k: None for k in PILE_ONLY if k != "bodies"}}


def result_stem(args) -> str:
    """scaling.json for the grid, scaling-tower.json for the tower (one CSV holds both)."""
    return "scaling" if args.layout == "grid" else f"scaling-{args.layout}"


def summarize(rows: list[dict]) -> dict:
    layouts = sorted({r["layout"] for r in rows})
    size = "bodies" if layouts == ["pile"] else "contacts"  # the pile's cost against bodies
    out = {"layout": layouts[0] if len(layouts) == 1 else layouts,
           "exponent": fit_exponent([r[size] for r in rows], [r["us_per_step"] for r in rows])}
    mj = [r["mujoco_us_per_step"] for r in rows]
    out["mujoco_exponent"] = fit_exponent([r[size] for r in rows], mj) if rows and all(mj) else None
    if layouts == ["pile"]:
        out["exponent_in"] = "bodies"
        out["ratio_to_mujoco"] = [r["us_per_step"] / r["mujoco_us_per_step"] if r["mujoco_us_per_step"] else None
                                  for r in rows]
    return out


def plot(rows: list[dict], out_dir, stamp: dict) -> list:
    from pathlib import Path

    layouts = {r["layout"] for r in rows}
    name = "scaling" if layouts == {"grid"} else "scaling-" + "-".join(sorted(layouts))
    path = Path(out_dir) / f"{name}.png"
    plot_result({"rows": rows, **summarize(rows)}, path, stamp)
    return [path]


def plot_result(result: dict, path, stamp: dict | None = None) -> None:
    from .._optional import require

    require("matplotlib", "plot", "the scaling chart")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    pile = result.get("layout") == "pile"
    n = [r["bodies"] if pile else r["contacts"] for r in rows]
    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    ax.loglog(n, [r["us_per_step"] for r in rows], "o-", label=f"stiction (exponent {result['exponent']:.2f})")
    if result.get("mujoco_exponent") is not None:
        ax.loglog(n, [r["mujoco_us_per_step"] for r in rows], "s--",
                  label=f"MuJoCo 4.0 (exponent {result['mujoco_exponent']:.2f})")
    if pile:
        ax.set_xlabel("bodies (boxes, spheres, capsules, cylinders, convex hulls dropped into a bin)")
        ax.set_ylabel("µs per step (mean; timed interleaved with MuJoCo)")
    else:
        ax.set_xlabel(f"contacts (cube {result.get('layout', 'grid')}, 4 per cube)")
        ax.set_ylabel("µs per step (median of 10 block means)")
    ax.set_title("Cost per step against body count: a pile" if pile else "Cost per step against contact count")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    if stamp is not None:
        from .sweep import stamp_figure

        stamp_figure(fig, stamp)
    fig.savefig(path, dpi=120)
    plt.close(fig)
