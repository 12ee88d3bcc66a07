#!/usr/bin/env python
"""Benchmark: every bundled robot scene, one step of stiction against MuJoCo 4.0, in one process.

Usage:  python benchmarks/bench_robots_mujoco.py [--quick] [--repeats N] [--scenes A B ...]
            [--duration S] [--impratio R ...] [--no-joint-rows] [--out FILE] [--json]

MuJoCo is the optional ``bench`` extra (``mujoco==4.0.*``): without it the script says so and
exits 0.

Scenes (default): solo12-stand, go2-stand, anymal-stand, talos-stand, ur5-push-wall,
ur5-push-box, solo12-slope-stick (joints locked, gravity tilted 15°, as stiction models the slope) and
solo12-on-board (Solo-12 on a free board on the ground: contacts between two bodies). The MuJoCo
twin of each is built by ``stiction.bench.mujoco_twins.mujoco_twin``
from the scene's own Pinocchio model (same masses, inertias, joint frames, contact spheres and
points on the same links, joint PD, initial state, dt, μ, gravity); MuJoCo: elliptic cones,
Newton, 100 iterations, tolerance 1e-10, implicitfast, impratio 1 (and any ``--impratio``), its
default solref/solimp. stiction: the scene as bundled (exact Coulomb NCP, eq. 65, to 1e-10 at
every step, warm-started).

Two sets of runs, timed interleaved:

- **joint rows off** (the main tables; comparable with the runs made before the joints' rows existed,
  issue 24): both simulators without joint limits, joint friction, damping or effort limits
  (stiction's overrides ``joint_limits``, ``joint_friction``, ``joint_damping``, ``effort_limits`` =
  False; the twin built with the same switches off);
- **joint rows on** (the table of that name; skipped by ``--no-joint-rows``): each scene with every joint
  row on in both simulators: stiction's 1-dof joints' position limits (unilateral rows), dry joint
  friction (box rows: exact stiction), damping and actuator effort limits (docs/joint-rows.md); the
  MuJoCo twin of the same scene with ``range``, ``frictionloss``, ``damping`` and actuator
  ``forcerange`` (``mujoco_twin``). The robots' URDFs give limits and effort limits (TALOS also
  friction and damping on its upper body), but no other friction, so each scene gets a
  ``[[joints.override]]`` with a dry friction tau_c on every actuated joint whose URDF has none
  (``JOINT_FRICTION``: Solo-12 0.03 N m, its small geared motors; Go2 0.1 N m; ANYmal 0.5 N m, its
  series-elastic drives; UR5 0.5 N m, its harmonic drives; TALOS's legs 1.0 N m, as its URDF's arms).
  The bundled scenes of ``JOINT_ROWS_AS_IS`` (solo12-stand-joint-rows: 0.03 N m and Solo-12's real
  2.7 N m effort limit) run as they are, in this set only. Reported: µs per step of both, their paired
  ratio beside the same scene's with the rows off, and whether every stiction step (timed or warm-up,
  rollouts and single steps) converged.

Timing (wall clock, one process, single thread; the machine may be shared, so the two
simulators of one scene run back to back, their order swapped every repetition, and the
scenes' order rotated): per repetition and scene,

- the C++ loops end to end (the goal's measure): ``Simulator(scene).rollout(D)`` (records q, v,
  λ, gaps, residuals, timings, builds the numpy Trajectory) and ``mujoco.rollout.rollout``
  (records the full physics state), wall / steps;
- one step at a time from Python, each step timed alone and the median over steps taken (robust
  to the machine's other work): stiction ``_core.step`` and MuJoCo ``mj_step`` — both include
  one Python → C++ call;
- stiction's own C++ step timer (median over steps) and its phases.

Reported: the median over repetitions (and min–max), and the ratio stiction / MuJoCo paired per
repetition (median, min–max). Each repetition starts from a fresh Simulator / reset MjData.

Accuracy (from the last repetition's rollouts; the same code measures both, from the
configurations alone: ``mujoco_twins.contact_accuracy``): drift — the largest displacement of
a closed contact along its half-space from the settle time to the end (sphere centres: rolling
counts); penetration — the deepest gap below zero over the run. stiction's convergence and
largest NCP residual are shown beside.

Output: Markdown on stdout (and ``--out FILE``), or JSON with ``--json``; progress on stderr.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pinocchio as pin

import stiction
from stiction import _core
from stiction.bench import sweep
from stiction.bench import mujoco_twins
from stiction.resources import scenes_dir
from stiction.scene import Scene, build_scene, load_scene
from stiction.simulator import PHASES, Simulator

SCENES = ("solo12-stand", "go2-stand", "anymal-stand", "talos-stand", "ur5-push-wall", "ur5-push-box",
          "solo12-slope-stick", "solo12-on-board")
DURATION = 2.0  # s
REPEATS, QUICK_REPEATS = 9, 3
# Dry friction tau_c (N m) of every actuated joint whose URDF has none, with the joint rows on (module
# doc): realistic for each robot's drives.
JOINT_FRICTION = {"solo12": 0.03, "go2": 0.1, "anymal": 0.5, "ur5": 0.5, "talos": 1.0}
# Scenes that already hold their joint rows: run as bundled, in the joint-rows set only.
JOINT_ROWS_AS_IS = ("solo12-stand-joint-rows",)
SWITCHES = ("joint_limits", "joint_friction", "joint_damping", "effort_limits")


def joint_rows_scene(name: str) -> tuple[Scene, float]:
    """The scene with its joint rows in play, and the dry friction tau_c it added (0: none): a scene of
    JOINT_ROWS_AS_IS as bundled; another with a [[joints.override]] giving each actuated joint whose
    URDF has no friction the robot's JOINT_FRICTION."""
    scene = load_scene(name)
    if name in JOINT_ROWS_AS_IS:
        return scene, 0.0
    path = scenes_dir() / f"{name}.toml"
    with open(path, "rb") as fh:
        cfg = tomllib.load(fh)
    model = scene.model
    bare = [model.names[j] for j in range(1, model.njoints)
            if model.joints[j].nv == 1 and model.friction[model.joints[j].idx_v] == 0.0
            and (scene.kp[model.joints[j].idx_v] or scene.kd[model.joints[j].idx_v] or scene.tau_ff[model.joints[j].idx_v])]
    if not bare:  # (joints locked, or every actuated joint has its URDF friction)
        return scene, 0.0
    robot = cfg.get("robot")
    if robot not in JOINT_FRICTION:
        raise ValueError(f"scene {name!r}: no dry joint friction chosen for robot {robot!r} (JOINT_FRICTION has "
                         f"{', '.join(JOINT_FRICTION)})")
    joints = cfg.setdefault("joints", {})
    joints["override"] = list(joints.get("override", [])) + [{"joints": bare, "friction": JOINT_FRICTION[robot]}]
    return build_scene(cfg, default_name=name, source=str(path), base_dir=path.parent), JOINT_FRICTION[robot]


class Case:
    """One scene in both simulators, ready to time: joint rows off in both (the main tables) or on in
    both (module doc)."""

    def __init__(self, scene_name: str, duration: float, impratios: tuple[float, ...], joint_rows: bool = False):
        import mujoco

        self.name, self.joint_rows = scene_name, joint_rows
        self.key = f"{scene_name} (joint rows)" if joint_rows else scene_name
        if joint_rows:
            self.scene, self.friction_added = joint_rows_scene(scene_name)
        else:
            self.scene, self.friction_added = load_scene(scene_name), 0.0
        self.switches = {s: joint_rows for s in SWITCHES}  # the same in both simulators
        self.n = int(round(duration / self.scene.dt))
        self.duration = self.n * self.scene.dt
        self.twins = {r: mujoco_twins.mujoco_twin(self.scene, impratio=r, **self.switches) for r in impratios}
        self.datas = {r: mujoco.MjData(t.model) for r, t in self.twins.items()}
        self.state0 = {r: t.initial_state(self.scene.q0, self.scene.v0) for r, t in self.twins.items()}
        self.last: dict = {}
        self.steps_run = self.steps_unconverged = 0  # every stiction step, timed or not

    def simulator(self) -> Simulator:
        return Simulator(self.scene, **self.switches)

    def rows_in_play(self) -> dict:
        """What the joint rows act on in this scene (stiction's model): limited 1-dof joints, and the
        velocity coordinates with dry friction, damping and an effort limit on an actuated joint."""
        model = self.scene.model
        if not self.joint_rows:
            return {"limits": 0, "friction": 0, "damping": 0, "effort": 0}
        limits = sum(1 for j in range(1, model.njoints) if model.joints[j].nq == 1 and model.joints[j].nv == 1 and (
            np.isfinite(model.lowerPositionLimit[model.joints[j].idx_q])
            or np.isfinite(model.upperPositionLimit[model.joints[j].idx_q])))
        effort = np.asarray(model.effortLimit)
        actuated = (self.scene.kp != 0) | (self.scene.kd != 0) | (self.scene.tau_ff != 0)
        return {"limits": limits, "friction": int((np.asarray(model.friction) > 0).sum()),
                "damping": int((np.asarray(model.damping) > 0).sum()),
                "effort": int((actuated & (effort > 0) & (effort < np.finfo(float).max)).sum())}

    # ---- stiction
    def stiction_rollout(self) -> tuple[float, float]:
        sim = self.simulator()
        t0, c0 = time.perf_counter(), time.process_time()
        traj = sim.rollout(self.duration)
        us, cpu = (time.perf_counter() - t0) / self.n * 1e6, (time.process_time() - c0) / self.n * 1e6
        self.last["stiction"] = (sim, traj)
        self.steps_run += len(traj.t) - 1
        self.steps_unconverged += int((~traj.converged[1:].astype(bool)).sum())
        return us, cpu

    def stiction_steps(self) -> float:
        sim = self.simulator()
        step, model, data, clock = _core.step, sim.model, sim.data, time.perf_counter_ns
        times = np.empty(self.n)
        unconverged = 0
        for k in range(self.n):
            t0 = clock()
            step(model, data)
            times[k] = clock() - t0
            unconverged += not data.all_converged_step  # (read after the clock)
        self.steps_run += self.n
        self.steps_unconverged += unconverged
        self.last["stiction_q_end"] = np.asarray(data.q)
        return float(np.median(times)) / 1e3

    # ---- MuJoCo
    def mujoco_rollout(self, impratio: float) -> tuple[float, float]:
        import mujoco

        twin, data = self.twins[impratio], self.datas[impratio]
        mujoco.mj_resetData(twin.model, data)
        control = twin.ctrl.reshape(1, 1, -1) if twin.model.nu else None
        wall, cpu, states = mujoco_twins.rollout(twin.model, data, self.state0[impratio], control, self.n)
        us, cpu = wall / self.n * 1e6, cpu / self.n * 1e6
        self.last[("mujoco", impratio)] = states[0, :, 1:1 + twin.model.nq]  # FULLPHYSICS: time, qpos, ...
        return us, cpu

    def mujoco_steps(self, impratio: float) -> float:
        import mujoco

        twin, data = self.twins[impratio], self.datas[impratio]
        mujoco.mj_resetData(twin.model, data)
        mujoco.mj_setState(twin.model, data, self.state0[impratio], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        data.ctrl[:] = twin.ctrl
        step, model, clock = mujoco.mj_step, twin.model, time.perf_counter_ns
        times = np.empty(self.n)
        for k in range(self.n):
            t0 = clock()
            step(model, data)
            times[k] = clock() - t0
        self.last[("mujoco_qpos_end", impratio)] = data.qpos.copy()
        return float(np.median(times)) / 1e3

    # ---- accuracy (last rollouts)
    def accuracy(self) -> dict:
        sim, traj = self.last["stiction"]
        summary = sim.summary(traj)
        out = {"stiction": {**mujoco_twins.contact_accuracy(self.scene, traj.t, traj.q),
                            "converged": summary["all_converged"], "max_residual": summary["max_residual"],
                            "slip": summary["max_foot_slip"],
                            "phases_us": dict(zip(PHASES, (float(x) for x in np.median(traj.timings[1:], axis=0))))}}
        t = np.arange(self.n + 1) * self.scene.dt
        for r, twin in self.twins.items():
            qpos = self.last[("mujoco", r)]
            Q = np.vstack([self.scene.q0, twin.q_from_qpos(qpos, self.scene.model.nq)])
            acc = mujoco_twins.contact_accuracy(self.scene, t, Q)
            # the step-by-step run and mujoco.rollout end in the same state (same model, control)
            acc["rollout_vs_steps"] = float(np.abs(qpos[-1] - self.last[("mujoco_qpos_end", r)]).max())
            out[f"mujoco impratio {r:g}"] = acc
        return out


git_revision, machine = sweep.git_description, sweep.machine_description


def spread(values: list[float]) -> dict:
    return {"median": statistics.median(values), "min": min(values), "max": max(values), "all": list(values)}


def run(scenes: list[str], repeats: int, duration: float, impratios: tuple[float, ...],
        joint_rows: list[str] | None = None) -> dict:
    """Time `scenes` with the joint rows off and `joint_rows` (default: the same scenes) with them on,
    every case interleaved with the others (module doc)."""
    import mujoco

    load_start = os.getloadavg()
    joint_rows = list(scenes) if joint_rows is None else list(joint_rows)
    cases = [Case(s, duration, impratios) for s in scenes] + [Case(s, duration, impratios, True) for s in joint_rows]
    timers = {}
    for c in cases:
        timers[c.key] = {"stiction rollout": c.stiction_rollout, "stiction steps": c.stiction_steps}
        for r in impratios:
            timers[c.key][f"mujoco {r:g} rollout"] = lambda c=c, r=r: c.mujoco_rollout(r)
            timers[c.key][f"mujoco {r:g} steps"] = lambda c=c, r=r: c.mujoco_steps(r)
    for fns in timers.values():  # one untimed warm-up of each
        for fn in fns.values():
            fn()
    times = {s: {k: [] for k in fns} for s, fns in timers.items()}
    for s, fns in timers.items():
        times[s].update({f"{k} cpu": [] for k in fns if k.endswith("rollout")})
    for rep in range(repeats):
        k = rep % len(cases)
        for c in cases[k:] + cases[:k]:
            # each kind (rollout, steps) back to back in both simulators, order swapped every repetition
            for kind in ("rollout", "steps"):
                names = [n for n in timers[c.key] if n.endswith(kind)]  # stiction first, then MuJoCo
                if rep % 2:
                    names.reverse()
                for n in names:
                    value = timers[c.key][n]()
                    if isinstance(value, tuple):  # a rollout: wall and CPU time
                        value, cpu = value
                        times[c.key][f"{n} cpu"].append(cpu)
                    times[c.key][n].append(value)
        first = f"mujoco {impratios[0]:g} rollout"
        print(f"repetition {rep + 1}/{repeats}, stiction / MuJoCo: " + ", ".join(
            f"{c.key} {times[c.key]['stiction rollout'][-1] / times[c.key][first][-1]:.2f}" for c in cases),
            file=sys.stderr, flush=True)
    rows = []
    for c in cases:
        t = times[c.key]
        row = {"scene": c.name, "nv": int(c.scene.model.nv), "contacts": len(c.scene.contacts), "steps": c.n,
               "us": {n: spread(v) for n, v in t.items()}, "ratio": {}, "accuracy": c.accuracy()}
        for r in impratios:
            for kind in ("rollout", "rollout cpu", "steps"):
                paired = [a / b for a, b in zip(t[f"stiction {kind}"], t[f"mujoco {r:g} {kind}"])]
                row["ratio"][f"{kind} vs impratio {r:g}"] = spread(paired)
                # the fastest run of each: the least disturbed by the machine's other work
                row["ratio"][f"{kind} vs impratio {r:g}, fastest"] = (min(t[f"stiction {kind}"])
                                                                      / min(t[f"mujoco {r:g} {kind}"]))
        if c.joint_rows:
            row["rows_in_play"] = c.rows_in_play()
            row["friction_added"] = c.friction_added
            row["stiction_steps_run"], row["stiction_steps_unconverged"] = c.steps_run, c.steps_unconverged
        rows.append(row)
    return {
        "command": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]),
        "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": machine(), "load_average_start": load_start[0], "load_average_end": os.getloadavg()[0],
        "versions": {"python": platform.python_version(), "stiction": stiction.__version__, "git": git_revision(),
                     "pinocchio": pin.__version__, "mujoco": mujoco.mj_versionString(), "numpy": np.__version__},
        "repeats": repeats, "duration": duration, "impratios": list(impratios),
        "rows": rows[:len(scenes)], "joint_rows": rows[len(scenes):],
    }


def label(row: dict) -> str:
    """A row's scene, marked when it ran with the joint rows on."""
    return f"{row['scene']} (joint rows on)" if "rows_in_play" in row else row["scene"]


def joint_rows_table(res: dict) -> list[str]:
    """The "joint rows on" table: µs per step of both, their paired ratio beside the same scene's with
    the rows off, and stiction's convergence over every step it ran."""
    if not res["joint_rows"]:
        return []
    r0 = res["impratios"][0]
    off = {row["scene"]: row for row in res["rows"]}

    def cell(s: dict, spec: str) -> str:
        return f"{s['median']:{spec}} ({s['min']:{spec}}–{s['max']:{spec}})"

    lines = [
        "",
        f"## Joint rows on: stiction / MuJoCo per step (MuJoCo impratio {r0:g}), median over repetitions (min–max)",
        "",
        "| scene | limits / dry friction / damping / effort limits | tau_c added [N m] | stiction rollout CPU µs "
        "| MuJoCo rollout CPU µs | **stiction / MuJoCo, rollout CPU** | same, joint rows off | one step from "
        "Python, ratio | stiction: every step converged |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for row in res["joint_rows"]:
        us, ratio, n = row["us"], row["ratio"], row["rows_in_play"]
        base = off.get(row["scene"])
        beside = cell(base["ratio"][f"rollout cpu vs impratio {r0:g}"], ".2f") if base else "—"
        bad, total = row["stiction_steps_unconverged"], row["stiction_steps_run"]
        converged = f"yes ({total} steps)" if bad == 0 else f"**no: {bad} of {total} steps**"
        lines.append(f"| {row['scene']} | {n['limits']} / {n['friction']} / {n['damping']} / {n['effort']} | "
                     f"{row['friction_added']:g} | {cell(us['stiction rollout cpu'], '.1f')} | "
                     f"{cell(us[f'mujoco {r0:g} rollout cpu'], '.1f')} | "
                     f"**{cell(ratio[f'rollout cpu vs impratio {r0:g}'], '.2f')}** | {beside} | "
                     f"{cell(ratio[f'steps vs impratio {r0:g}'], '.2f')} | {converged} |")
    lines += [
        "",
        "Both simulators with every joint row on: stiction's position limits of 1-dof joints (unilateral rows "
        "within 0.02 rad of a limit), dry joint friction (box rows: exact stiction), damping (implicit) and "
        "actuator effort limits (box rows, the implicit PD their compliance), docs/joint-rows.md; the MuJoCo "
        "twin with the same values as `range`, `frictionloss`, `damping` and actuator `forcerange` (its soft "
        "limits and friction loss, default solref/solimp). Counts: limited joints / coordinates with dry "
        "friction / with damping / actuators with an effort limit. tau_c added: the dry friction this benchmark "
        "gives every actuated joint whose URDF has none (JOINT_FRICTION; 0: none added — the URDF's or the "
        "scene's own). Every step converged: over all of stiction's steps in this run (warm-up and timed, "
        "rollouts and single steps), the solver met its tolerance at each.",
    ]
    return lines


def markdown(res: dict) -> str:
    r0 = res["impratios"][0]
    v = res["versions"]
    lines = [
        "# Every bundled robot: one step of stiction against MuJoCo 4.0",
        "",
        f"Measured {res['date']} on {res['machine']}, load average {res['load_average_start']:.2f} at start and "
        f"{res['load_average_end']:.2f} at the end; Python {v['python']}, stiction {v['stiction']} ({v['git']}, "
        f"Pinocchio {v['pinocchio']}), MuJoCo {v['mujoco']}, numpy {v['numpy']}. `{res['command']}`: "
        f"{res['duration']:g} s per scene, {res['repeats']} alternating repetitions, single thread, medians "
        "(min–max over repetitions).",
        "",
        f"## stiction / MuJoCo per step, joint rows off (MuJoCo impratio {r0:g}): "
        "median over repetitions of the paired ratio (min–max)",
        "",
        "Both simulators without joint limits, joint friction, damping or effort limits, as before the joints' "
        "rows existed; with them: the table \"joint rows on\" below.",
        "",
        "| scene | nv | contacts | **rollout, CPU time** | rollout, wall time | one step from Python | "
        "fastest rollouts (wall) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]

    def cell(s: dict, spec: str = ".1f") -> str:
        return f"{s['median']:{spec}} ({s['min']:{spec}}–{s['max']:{spec}})"

    for row in res["rows"]:
        ratio = row["ratio"]
        lines.append(f"| {row['scene']} | {row['nv']} | {row['contacts']} | "
                     f"**{cell(ratio[f'rollout cpu vs impratio {r0:g}'], '.2f')}** | "
                     f"{cell(ratio[f'rollout vs impratio {r0:g}'], '.2f')} | "
                     f"{cell(ratio[f'steps vs impratio {r0:g}'], '.2f')} | "
                     f"{ratio[f'rollout vs impratio {r0:g}, fastest']:.2f} |")
    lines += [
        "",
        "## Time per step (µs), joint rows off: median over repetitions (min–max)",
        "",
        "| scene | stiction rollout CPU | MuJoCo rollout CPU | stiction rollout wall | MuJoCo rollout wall "
        "| stiction step | MuJoCo step | stiction C++ step timer |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in res["rows"]:
        us = row["us"]
        cpp = row["accuracy"]["stiction"]["phases_us"]["total"]
        lines.append(f"| {row['scene']} | {cell(us['stiction rollout cpu'])} | "
                     f"{cell(us[f'mujoco {r0:g} rollout cpu'])} | "
                     f"{cell(us['stiction rollout'])} | {cell(us[f'mujoco {r0:g} rollout'])} | "
                     f"{cell(us['stiction steps'])} | {cell(us[f'mujoco {r0:g} steps'])} | {cpp:.1f} |")
    for r in res["impratios"][1:]:
        lines += ["", f"MuJoCo impratio {r:g}: ratio rollout CPU / step: " + "; ".join(
            f"{row['scene']} {row['ratio'][f'rollout cpu vs impratio {r:g}']['median']:.2f} / "
            f"{row['ratio'][f'steps vs impratio {r:g}']['median']:.2f}" for row in res["rows"])]
    lines += [
        "",
        "rollout: the C++ loop end to end / steps (stiction records q, v, λ, gaps, residuals and timings; MuJoCo "
        "its full physics state), as the process's CPU time (time.process_time: not counting the time other "
        "processes held the core; both loops run in this one thread) and as wall time. one step: each step "
        "called from Python and timed alone (wall), median over the steps. Ratios are paired: stiction / MuJoCo "
        "within a repetition (the two ran back to back). fastest rollouts: stiction's fastest repetition over "
        "MuJoCo's. stiction C++ step timer: the median of its own per-step timer over the last rollout.",
    ]
    lines += joint_rows_table(res)
    every = res["rows"] + res["joint_rows"]
    lines += [
        "",
        "## stiction's phases (median µs per step over the last rollout)",
        "",
        "| scene | " + " | ".join(PHASES) + " |",
        "|---|" + "---:|" * len(PHASES),
    ]
    for row in every:
        ph = row["accuracy"]["stiction"]["phases_us"]
        lines.append(f"| {label(row)} | " + " | ".join(f"{ph[p]:.1f}" for p in PHASES) + " |")
    labels = [k for k in res["rows"][0]["accuracy"]]
    lines += [
        "",
        "## Accuracy over the same run (same measure for both, from the configurations)",
        "",
        "| scene | " + " | ".join(f"{lab}: drift [m] | {lab}: penetration [m]" for lab in labels)
        + " | stiction: contact-point slip [m] | stiction converged, max residual |",
        "|---|" + "---:|---:|" * len(labels) + "---:|---|",
    ]
    for row in every:
        acc = row["accuracy"]
        s = acc["stiction"]
        lines.append(f"| {label(row)} | " + " | ".join(f"{acc[lab]['drift']:.2e} | {acc[lab]['penetration']:.2e}"
                                                         for lab in labels)
                     + f" | {s['slip']:.1e} | {s['converged']}, {s['max_residual']:.1e} |")
    lines += [
        "",
        "drift: the largest displacement, along its half-space, of a contact closed at the settle time and at the "
        "end, from the settle time on (sphere centres, so rolling counts; ur5-push-box: in the crate's frame for "
        "the tool on the crate face, and the crate's corners are pushed 15 cm on purpose). Contact-point slip: "
        "stiction's own measure (the integral of the tangential contact velocity after settling: rolling is not "
        "slip; `summary()['max_foot_slip']`). MuJoCo's "
        "`mujoco.rollout` and its step-by-step run end in the same state: max |Δqpos| = "
        + ", ".join(f"{label(row)} {max(a.get('rollout_vs_steps', 0.0) for a in row['accuracy'].values()):.1e}"
                    for row in every) + ".",
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=f"{QUICK_REPEATS} repetitions, 1.5 s per scene")
    ap.add_argument("--repeats", type=int, help=f"repetitions (default {REPEATS}; at least 1)")
    ap.add_argument("--scenes", nargs="+", default=list(SCENES), help="scene names (default: every robot scene)")
    ap.add_argument("--duration", type=float, help=f"simulated seconds per run (default {DURATION:g})")
    ap.add_argument("--impratio", type=float, nargs="+", default=[1.0], help="MuJoCo impratio(s) (default 1)")
    ap.add_argument("--no-joint-rows", action="store_true",
                    help="skip the second set of runs, with the joint rows on in both simulators")
    ap.add_argument("--out", type=Path, help="also write the Markdown report to this file")
    ap.add_argument("--json", action="store_true", help="print JSON instead of Markdown")
    args = ap.parse_args(argv)
    if not mujoco_twins.available():
        print("bench_robots_mujoco: MuJoCo is not installed (the optional `bench` extra: "
              "pip install 'mujoco==4.0.*'); nothing to compare, skipping.")
        return 0
    repeats = args.repeats if args.repeats is not None else QUICK_REPEATS if args.quick else REPEATS
    if repeats < 1:
        raise ValueError(f"--repeats must be >= 1, got {repeats}")
    duration = args.duration if args.duration is not None else 1.5 if args.quick else DURATION
    if not duration > 0:
        raise ValueError(f"--duration must be > 0, got {duration}")
    if args.no_joint_rows:
        joint_rows = []
    else:  # the same scenes, and the bundled joint-rows scenes when every robot scene runs
        extra = JOINT_ROWS_AS_IS if args.scenes == list(SCENES) else ()
        joint_rows = list(args.scenes) + [s for s in extra if s not in args.scenes]
    res = run(args.scenes, repeats, duration, tuple(args.impratio), joint_rows)
    text = markdown(res)
    if args.out:
        args.out.write_text(text)
    print(json.dumps(res, indent=1) if args.json else text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
