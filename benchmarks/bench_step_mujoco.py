#!/usr/bin/env python
"""Benchmark: one simulation step of stiction against MuJoCo 4.0 on Solo-12 standing.

Usage:  python benchmarks/bench_step_mujoco.py [--quick] [--out FILE]

MuJoCo is the optional ``bench`` extra (``mujoco==4.0.*``): without it the script says so and
exits 0.

Scene, identical in both simulators: Solo-12 (example-robot-data ``solo12.urdf``, free base)
holds the SRDF ``standing`` posture (HAA ±0.1, HFE ±0.8, KFE ∓1.6) with a joint PD,
kp = 20 N·m/rad, kd = 0.2 N·m·s/rad, towards that posture; a sphere of r = 0.016 m at each
``*_FOOT`` frame touches the ground plane z = 0, μ = 1; gravity (0, 0, −9.81); dt = 1 ms;
2 s simulated. Start: zero velocity, base lowered so the lowest foot sphere touches z = 0
(stiction's ``solo12-stand`` q0, h0 = 0.2319 m, which MuJoCo reuses).

stiction: ``Simulator("solo12-stand")`` (robots/scenes/solo12-stand.toml), exact Coulomb NCP
solved to 1e-10 at every step, the whole rollout in C++.

MuJoCo 4.0 (the peers' setup, /work/shared/reference/peers-mujoco-drake.md):

- model: ``solo12.urdf`` with every ``<visual>`` and ``<collision>`` removed, loaded through
  ``mujoco.MjSpec`` with ``<compiler fusestatic="false"/>`` so the ``*_FOOT`` links stay
  bodies; a free joint on ``base_link``; the URDF's ±10 rad joint limits disabled (stiction
  has none; they are never reached); URDF inertias, zero joint damping, armature, frictionloss;
- contacts: a sphere geom (r = 0.016 m) on each ``*_FOOT`` body and a ground plane,
  ``condim=3``, ``friction="1 0 0"`` on both (MuJoCo combines with max: μ = 1); no other geoms;
  default ``solref = (0.02, 1)``, ``solimp = (0.9, 0.95, 0.001, 0.5, 2)``, margin 0;
- control: one ``position`` actuator per joint, kp = 20, kv = 0.2, ctrl = the standing
  posture (force = kp (ctrl − q) − kv q̇, unlimited);
- options: ``cone = elliptic``, ``solver = Newton``, ``iterations = 100``,
  ``tolerance = 1e-10``, ``timestep = 0.001``, ``integrator = implicitfast``, other options at
  their defaults (``ls_iterations = 50``, ``noslip_iterations = 0``);
- two configurations: ``impratio = 1`` (the default) and ``impratio = 10`` (MuJoCo's advice
  for elliptic cones, and the peers' fair-comparison setting).

Timing (wall clock, ``time.perf_counter``): every repetition runs each of the timed runs once,
in an order rotated by one per repetition; the report gives the MEDIAN over repetitions
(7, ``--quick`` 3) after one untimed warm-up of each. Each repetition starts from a fresh
``Simulator`` / reset ``MjData``, so no warm start carries over.

- stiction C++ step: median over the steps of the per-step total timer measured in C++
  (``traj.timings[:, 4]``), and its phases (kinematics+collision, Delassus, solve, integrate);
- stiction end to end: wall time of ``sim.rollout(2.0)`` / 2000 (C++ loop, includes recording
  q, v, λ, gaps, … and building the numpy Trajectory);
- MuJoCo ``mujoco.rollout.rollout``: wall time / 2000 (C++ loop, records the full physics state
  at every step); this is the like-for-like partner of stiction's end-to-end time;
- MuJoCo ``mj_step`` in a Python loop: wall time / 2000 (includes the Python call overhead).

Accuracy, same 2 s, same measures for both simulators:

- foot displacement: the largest horizontal displacement of a foot-sphere centre from its
  position at the settle time 0.5 s (the peers' "slip", which includes rolling), and from its
  start position; stiction also reports its contact-point slip (integral of the tangential
  contact velocity, ``summary``);
- ft/fn: the largest |f_t| / f_n over the loaded feet at t = 0.25 s and t = 2 s;
- base height h of the ``base_link`` origin and its sag h(0.5 s) − h(2 s);
- max penetration: the largest depth of a foot sphere below the ground over the run.

The MuJoCo accuracy run is one separate, untimed ``mj_step`` loop that records after each step;
it ends in the same state as the timed ``mujoco.rollout`` (checked and reported).

Output: Markdown on stdout (and in ``--out FILE``); progress on stderr.
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pinocchio as pin

import stiction
from stiction.bench import sweep
from stiction.bench import mujoco_twins
from stiction.robots import ROBOTS
from stiction.simulator import PHASES, Simulator

try:
    import mujoco
    import mujoco.rollout
except ImportError:
    mujoco = None

SCENE = "solo12-stand"
ROBOT = ROBOTS["solo12"]
DURATION = 2.0  # s
FT_FN_TIMES = (0.25, 2.0)  # s
MUJOCO_IMPRATIOS = (1.0, 10.0)
REPEATS, QUICK_REPEATS = 7, 3


# ---------------------------------------------------------------- MuJoCo scene
def mujoco_model(scene, impratio: float) -> "mujoco.MjModel":
    """The MuJoCo twin of the stiction scene (see the module docstring for every setting): the
    robot, feet, ground and actuators from stiction.bench.mujoco_twins.solo12_spec, its options
    from mujoco_twins.accurate_options."""
    spec = mujoco_twins.solo12_spec(scene)
    mujoco_twins.accurate_options(spec, scene.dt, scene.model.gravity.linear, impratio)
    return spec.compile()


def mujoco_initial_state(model, scene) -> np.ndarray:
    """stiction's q0 as a MuJoCo mjSTATE_INTEGRATION vector, ctrl = the posture."""
    return mujoco_twins.solo12_state(model, scene.q0, scene.q_target)


@dataclass
class MujocoRun:
    """A MuJoCo configuration ready to step: model, data and start state (ctrl included)."""

    model: "mujoco.MjModel"
    data: "mujoco.MjData"
    state0: np.ndarray  # mjSTATE_INTEGRATION
    n_steps: int
    q_end: np.ndarray | None = None  # final qpos of the last c_rollout

    def reset(self) -> None:
        mujoco.mj_resetData(self.model, self.data)
        mujoco.mj_setState(self.model, self.data, self.state0, mujoco.mjtState.mjSTATE_INTEGRATION)

    def python_loop(self) -> float:
        """Wall µs per step of mj_step called from Python."""
        self.reset()
        step, m, d = mujoco.mj_step, self.model, self.data
        t0 = time.perf_counter()
        for _ in range(self.n_steps):
            step(m, d)
        return (time.perf_counter() - t0) / self.n_steps * 1e6

    def c_rollout(self) -> float:
        """Wall µs per step of mujoco.rollout (C++ loop); keeps the final qpos in self.q_end."""
        self.reset()
        physics = mujoco.mjtState.mjSTATE_FULLPHYSICS
        initial = np.empty(mujoco.mj_stateSize(self.model, physics))
        mujoco.mj_getState(self.model, self.data, initial, physics)
        control = self.data.ctrl.copy().reshape(1, 1, -1)
        wall, _, states = mujoco_twins.rollout(self.model, self.data, initial, control, self.n_steps)
        us = wall / self.n_steps * 1e6
        self.q_end = states[0, -1, 1:1 + self.model.nq]  # FULLPHYSICS starts with time, then qpos
        return us

    def record(self, feet: list[int]) -> dict:
        """An untimed run recording, after every step: time, qpos, foot-sphere centres,
        per-foot contact force (f_n, |f_t|) and the deepest contact."""
        m, d = self.model, self.data
        self.reset()
        mujoco.mj_kinematics(m, d)
        n = self.n_steps
        t, q = np.zeros(n + 1), np.zeros((n + 1, m.nq))
        centres = np.zeros((n + 1, len(feet), 3))
        fn, ft = np.zeros((n + 1, len(feet))), np.zeros((n + 1, len(feet)))
        depth = np.zeros(n + 1)
        q[0], centres[0] = d.qpos, d.geom_xpos[feet]
        wrench = np.zeros(6)
        for k in range(1, n + 1):
            mujoco.mj_step(m, d)
            # forces and contacts are those of the step just taken; positions are refreshed to
            # the new state (mj_kinematics changes nothing the next mj_step reads)
            for i, contact in enumerate(d.contact[:d.ncon]):
                foot = feet.index(contact.geom2 if contact.geom2 in feet else contact.geom1)
                mujoco.mj_contactForce(m, d, i, wrench)  # contact frame, normal first
                fn[k, foot], ft[k, foot] = wrench[0], np.hypot(wrench[1], wrench[2])
                depth[k] = max(depth[k], -contact.dist)
            mujoco.mj_kinematics(m, d)
            t[k], q[k], centres[k] = d.time, d.qpos, d.geom_xpos[feet]
        return {"t": t, "h": q[:, 2], "q_end": q[-1].copy(), "centres": centres, "fn": fn, "ft": ft,
                "max_penetration": float(depth.max())}


# ---------------------------------------------------------------- measures
def max_displacement(t: np.ndarray, centres: np.ndarray, settle: float) -> float:
    """Largest horizontal displacement of a foot-sphere centre from its position at `settle`, m."""
    i0 = index_at(t, settle)
    return float(np.linalg.norm(centres[i0:, :, :2] - centres[i0, :, :2], axis=-1).max())


def index_at(t: np.ndarray, time_s: float) -> int:
    return int(np.argmin(np.abs(t - time_s)))


def ft_over_fn(fn: np.ndarray, ft: np.ndarray) -> float:
    """max |f_t| / f_n over the loaded feet of one step."""
    loaded = fn > 1e-9
    return float((ft[loaded] / fn[loaded]).max()) if loaded.any() else float("nan")


def accuracy(t, h, centres, fn, ft, max_penetration, settle) -> dict:
    i_settle = index_at(t, settle)
    return {
        "displacement": max_displacement(t, centres, settle),
        "displacement_from_start": max_displacement(t, centres, 0.0),
        **{f"ftfn@{s:g}": ft_over_fn(fn[index_at(t, s)], ft[index_at(t, s)]) for s in FT_FN_TIMES},
        "h0": float(h[0]), "h_settle": float(h[i_settle]), "h_end": float(h[-1]),
        "sag": float(h[i_settle] - h[-1]),
        "max_penetration": max_penetration,
    }


# ---------------------------------------------------------------- stiction runs
def stiction_run() -> dict:
    """One timed rollout from a fresh Simulator: end-to-end wall µs/step, C++ per-step
    medians (total and phases), and the trajectory."""
    sim = Simulator(SCENE)
    n = int(round(DURATION / sim.settings.dt))
    t0 = time.perf_counter()
    traj = sim.rollout(DURATION)
    wall = (time.perf_counter() - t0) / n * 1e6
    return {"wall": wall, "phases": np.median(traj.timings[1:], axis=0), "sim": sim, "traj": traj}


def stiction_accuracy(sim: Simulator, traj) -> dict:
    summary = sim.summary(traj)
    lam = traj.lam
    acc = accuracy(traj.t, traj.q[:, 2], sim.contact_centers(traj), lam[..., 2],
                   np.linalg.norm(lam[..., :2], axis=-1), summary["max_penetration"], sim.scene.settle_time)
    acc["slip"] = summary["max_foot_slip"]
    acc["converged"] = summary["all_converged"]
    acc["max_residual"] = summary["max_residual"]
    return acc


# ---------------------------------------------------------------- report
git_revision, machine = sweep.git_description, sweep.machine_description


def fmt(x: float, spec: str) -> str:
    return "n/a" if x != x else format(x, spec)


def report(repeats: int, stiction_times: list[dict], mujoco_times: dict[str, dict[str, list[float]]],
           acc: dict[str, dict], rollout_match: dict[str, float], load: tuple[float, ...]) -> str:
    med = statistics.median
    phases = np.median([r["phases"] for r in stiction_times], axis=0)
    s_cpp, s_wall = float(phases[4]), med(r["wall"] for r in stiction_times)
    lines = [
        "# stiction vs MuJoCo: one 1 ms step of Solo-12 standing",
        "",
        f"Measured {datetime.datetime.now():%Y-%m-%d %H:%M} on {machine()}, load average {load[0]:.2f} at start; "
        f"Python {platform.python_version()}, stiction {stiction.__version__} ({git_revision()}, Pinocchio {pin.__version__}), "
        f"MuJoCo {mujoco.mj_versionString()}, numpy {np.__version__}. Scene `{SCENE}`: 2 s at dt = 1 ms "
        f"(2000 steps), median of {repeats} alternating repetitions, single thread.",
        "",
        "## Time per step",
        "",
        "| simulator | what is timed | µs / step | stiction end-to-end ÷ this |",
        "|---|---|---:|---:|",
        f"| stiction | C++ step timer (median over steps) | {s_cpp:.1f} | {s_wall / s_cpp:.2f} |",
        f"| stiction | `sim.rollout(2.0)` wall / steps (C++ loop, records everything) | {s_wall:.1f} | 1.00 |",
    ]
    for label, times in mujoco_times.items():
        roll, loop = med(times["rollout"]), med(times["loop"])
        lines += [
            f"| MuJoCo {label} | `mujoco.rollout` wall / steps (C++ loop, records state) | {roll:.1f} | {s_wall / roll:.2f} |",
            f"| MuJoCo {label} | `mj_step` Python loop wall / steps | {loop:.1f} | {s_wall / loop:.2f} |",
        ]
    ratios = ", ".join(
        f"{s_wall / med(t['rollout']):.2f} (C++ step timer: {s_cpp / med(t['rollout']):.2f}) against MuJoCo {label}"
        for label, t in mujoco_times.items())
    lines += [
        "",
        f"**Ratio stiction / MuJoCo per step, both C++ loops end to end:** {ratios}.",
        "",
        "## stiction phases (median µs per step)",
        "",
        "| " + " | ".join(("kinematics+collision", "Delassus", "solve", "integrate", "total")) + " |",
        "|---:|---:|---:|---:|---:|",
        "| " + " | ".join(f"{x:.2f}" for x in phases) + " |",
        "",
        f"The phases ({', '.join(PHASES[:4])}) do not add up to the total exactly: each column is its own median.",
        "",
        "## Accuracy over the same 2 s (μ = 1; exact Coulomb must hold ft/fn with zero slip)",
        "",
        "| quantity | " + " | ".join(acc) + " |",
        "|---|" + "---:|" * len(acc),
    ]
    rows = [
        ("max foot displacement 0.5 → 2 s [m]", "displacement", ".2e"),
        ("max foot displacement 0 → 2 s [m]", "displacement_from_start", ".2e"),
        ("max contact-point slip 0.5 → 2 s [m]", "slip", ".2e"),
        ("ft/fn at 0.25 s", "ftfn@0.25", ".3f"),
        ("ft/fn at 2 s", "ftfn@2", ".3f"),
        ("base height h0 [m]", "h0", ".4f"),
        ("base height h(0.5 s) [m]", "h_settle", ".4f"),
        ("base height h(2 s) [m]", "h_end", ".4f"),
        ("base sag h(0.5 s) − h(2 s) [m]", "sag", ".2e"),
        ("max penetration [m]", "max_penetration", ".2e"),
    ]
    for title, key, spec in rows:
        lines.append(f"| {title} | " + " | ".join(fmt(a.get(key, float("nan")), spec) for a in acc.values()) + " |")
    s_acc = acc["stiction"]
    lines += [
        "",
        f"stiction: every step converged: {s_acc['converged']}, largest NCP residual {s_acc['max_residual']:.1e}. "
        "Foot displacement is that of the sphere centre, so it includes rolling (the legs tilt while the "
        "base settles); contact-point slip is stiction's own measure (n/a for MuJoCo). "
        "The MuJoCo accuracy run (Python loop) and `mujoco.rollout` end in the same state: max |Δqpos| = "
        + ", ".join(f"{v:.1e} ({label})" for label, v in rollout_match.items()) + ".",
    ]
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------- main
def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=f"{QUICK_REPEATS} repetitions instead of {REPEATS}")
    ap.add_argument("--out", type=Path, help="also write the Markdown report to this file")
    args = ap.parse_args()
    if mujoco is None:
        print("bench_step_mujoco: MuJoCo is not installed (the optional `bench` extra: "
              "pip install 'mujoco==4.0.*'); nothing to compare, skipping.")
        return 0
    repeats = QUICK_REPEATS if args.quick else REPEATS
    load = os.getloadavg()

    scene = Simulator(SCENE).scene
    n_steps = int(round(DURATION / scene.dt))
    runs = {}
    for impratio in MUJOCO_IMPRATIOS:
        label = f"elliptic, impratio {impratio:g}"
        model = mujoco_model(scene, impratio)
        runs[label] = MujocoRun(model, mujoco.MjData(model), mujoco_initial_state(model, scene), n_steps)

    # timed runs (name, callable): one warm-up each, then repetitions in a rotated order
    timed: list[tuple[str, Callable[[], object]]] = [("stiction", stiction_run)]
    for label, run in runs.items():
        timed += [(f"{label}/rollout", run.c_rollout), (f"{label}/loop", run.python_loop)]
    results: dict[str, list] = {name: [] for name, _ in timed}
    for _, fn in timed:
        fn()
    for rep in range(repeats):
        k = rep % len(timed)
        for name, fn in timed[k:] + timed[:k]:
            results[name].append(fn())
        print(f"repetition {rep + 1}/{repeats}, µs/step: stiction {results['stiction'][-1]['wall']:.1f}, "
              + ", ".join(f"{name} {results[name][-1]:.1f}" for name, _ in timed[1:]), file=sys.stderr, flush=True)

    last = results["stiction"][-1]
    acc = {"stiction": stiction_accuracy(last["sim"], last["traj"])}
    mujoco_times, rollout_match = {}, {}
    for label, run in runs.items():
        feet = [run.model.geom(f).id for f in ROBOT.feet]
        rec = run.record(feet)
        acc[f"MuJoCo {label}"] = accuracy(rec["t"], rec["h"], rec["centres"], rec["fn"], rec["ft"],
                                         rec["max_penetration"], scene.settle_time)
        rollout_match[label] = float(np.abs(run.q_end - rec["q_end"]).max())
        mujoco_times[label] = {"rollout": results[f"{label}/rollout"], "loop": results[f"{label}/loop"]}

    text = report(repeats, results["stiction"], mujoco_times, acc, rollout_match, load)
    if args.out:
        args.out.write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
