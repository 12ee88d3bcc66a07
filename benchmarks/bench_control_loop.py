#!/usr/bin/env python
"""Benchmark: a controller in the loop, from Python, at the cost of the step (issue 25).

Usage:  python benchmarks/bench_control_loop.py [--quick] [--repeats N] [--steps N] [--scene NAME]
            [--out FILE] [--json]

On one scene (default solo12-stand) and its MuJoCo twin (``stiction.bench.mujoco_twins.mujoco_twin``:
same masses, joints, foot spheres, PD, dt, mu), in one process, every way of running N steps with a
control written before each, timed interleaved (the order of the ways rotated every repetition; a
fresh Simulator, or MuJoCo's data reset, each time) and reported as the median over repetitions:

stiction
- ``rollout``: ``sim.rollout(N dt)``, the C++ loop (records every step, builds the Trajectory): the
  yardstick the others are compared with;
- ``rollout, no-op callback``: ``sim.rollout(N dt, callback=lambda s: None)``;
- ``rollout, callback writing tau_ff``: ``callback = lambda s: s.data.tau_ff.__setitem__(...)``, i.e.
  ``s.data.tau_ff[:] = u`` (the callback's own work included);
- ``Python loop, in place``: ``for k in range(N): sim.data.tau_ff[:] = u; sim.step()``;
- ``Python loop, whole array``: ``sim.data.tau_ff = u; sim.step()`` (checked: shape, dtype, finite);
- ``Python loop, step only``: ``sim.step()`` (no write: what the write costs in the loop);
- the C++ step's own timer (median over the rollout's steps): what the step costs inside C++.

MuJoCo 4.0 (optional, the ``bench`` extra; without it those rows are left out)
- ``mj_step loop``: ``d.ctrl[:] = u; mujoco.mj_step(m, d)`` in Python;
- ``mujoco.rollout``: its C++ loop (records the full physics state), the same constant control.

The control u is the scene's own (tau_ff = 0 for stiction, the PD targets for MuJoCo's position
actuators), so every way simulates the same standing robot: the stiction ways end in the same state
bit for bit (checked). Then the cost of one control write alone (``timeit`` of the statement): stiction's
``sim.data.tau_ff[:] = u``, ``sim.data.tau_ff = u``, and its parts (``sim.data``, the view
``sim.data.tau_ff``), MuJoCo's ``d.ctrl[:] = u``.

Times are wall clock per step, and the process's CPU time beside it (on a shared machine the wall
clock also counts the time other jobs held the core: then read the CPU column); ratios and overheads
are paired within a repetition, then the median taken. Output: Markdown on stdout (and ``--out``),
or JSON with ``--json``; progress on stderr.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import timeit
from pathlib import Path

import numpy as np

from stiction import _core
from stiction.bench import sweep
from stiction.scene import load_scene
from stiction.simulator import Simulator

STEPS, QUICK_STEPS = 2000, 500
REPEATS, QUICK_REPEATS = 9, 3
WRITES = 20000  # control writes timed per repetition


def _mujoco():
    try:
        import mujoco  # noqa: PLC0415
    except ImportError:
        return None
    return mujoco


class Bench:
    """The scene in both simulators and the ways of running it (module doc)."""

    def __init__(self, scene_name: str, steps: int):
        self.scene = load_scene(scene_name)
        self.sim = Simulator(self.scene)
        self.n = steps
        self.duration = steps * self.sim.dt
        self.u = np.array(self.scene.tau_ff, dtype=float)
        self.final_q: dict[str, np.ndarray] = {}
        self.step_timer_us: list[float] = []
        self.unconverged = 0
        self.mj = _mujoco()
        if self.mj is not None:
            from stiction.bench import mujoco_twins  # noqa: PLC0415

            self.twin = mujoco_twins.mujoco_twin(self.scene)
            self.mj_data = self.mj.MjData(self.twin.model)
            self.mj_state0 = self.twin.initial_state(self.scene.q0, self.scene.v0)
            self.mj_u = np.array(self.twin.ctrl, dtype=float)

    # ---- stiction
    def _fresh(self) -> Simulator:
        """A new Simulator (reset() would keep the last solve's impulses, which warm-start the next)."""
        self.sim = Simulator(self.scene)
        return self.sim

    def _timed(self, fn) -> tuple[float, float]:
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        return (time.perf_counter() - t0) / self.n * 1e6, (time.process_time() - c0) / self.n * 1e6

    def _finish(self, key: str, sim: Simulator) -> None:
        self.final_q[key] = np.asarray(sim.data.q)

    def rollout(self):
        sim = self._fresh()
        out = {}
        times = self._timed(lambda: out.setdefault("traj", sim.rollout(self.duration)))
        traj = out["traj"]
        self.step_timer_us.append(float(np.median(traj.timings[1:, 4])))
        self.unconverged += int((~traj.converged[1:]).sum())
        self._finish("rollout", sim)
        return times

    def rollout_noop(self):
        sim = self._fresh()
        times = self._timed(lambda: sim.rollout(self.duration, callback=lambda s: None))
        self._finish("rollout, no-op callback", sim)
        return times

    def rollout_writing(self):
        sim, u = self._fresh(), self.u

        def control(s):
            s.data.tau_ff[:] = u

        times = self._timed(lambda: sim.rollout(self.duration, callback=control))
        self._finish("rollout, callback writing tau_ff", sim)
        return times

    def loop_in_place(self):
        sim, u, n = self._fresh(), self.u, self.n

        def loop():
            for _ in range(n):
                sim.data.tau_ff[:] = u
                sim.step()

        times = self._timed(loop)
        self._finish("Python loop, in place", sim)
        return times

    def loop_whole(self):
        sim, u, n = self._fresh(), self.u, self.n

        def loop():
            for _ in range(n):
                sim.data.tau_ff = u
                sim.step()

        times = self._timed(loop)
        self._finish("Python loop, whole array", sim)
        return times

    def loop_step_only(self):
        sim, n = self._fresh(), self.n

        def loop():
            for _ in range(n):
                sim.step()

        times = self._timed(loop)
        self._finish("Python loop, step only", sim)
        return times

    # ---- MuJoCo
    def mj_loop(self):
        mj, m, d, u, n = self.mj, self.twin.model, self.mj_data, self.mj_u, self.n
        mj.mj_resetData(m, d)
        mj.mj_setState(m, d, self.mj_state0, mj.mjtState.mjSTATE_FULLPHYSICS)
        step = mj.mj_step

        def loop():
            for _ in range(n):
                d.ctrl[:] = u
                step(m, d)

        return self._timed(loop)

    def mj_rollout(self):
        from stiction.bench import mujoco_twins  # noqa: PLC0415

        mj, m, d = self.mj, self.twin.model, self.mj_data
        mj.mj_resetData(m, d)
        wall, cpu, _ = mujoco_twins.rollout(m, d, self.mj_state0, self.mj_u.reshape(1, 1, -1), self.n)
        return wall / self.n * 1e6, cpu / self.n * 1e6

    def ways(self) -> dict:
        out = {"rollout": self.rollout, "rollout, no-op callback": self.rollout_noop,
               "rollout, callback writing tau_ff": self.rollout_writing,
               "Python loop, in place": self.loop_in_place, "Python loop, whole array": self.loop_whole,
               "Python loop, step only": self.loop_step_only}
        if self.mj is not None:
            out["MuJoCo mj_step loop"] = self.mj_loop
            out["MuJoCo mujoco.rollout"] = self.mj_rollout
        return out

    # ---- one control write
    def writes(self) -> dict:
        """µs per statement as a controller writes it (timeit of the source text: Python's own bytecode
        for `x[:] = u`), each the best of 3 runs of WRITES."""
        sim = self._fresh()
        names = {"sim": sim, "u": self.u, "view": sim.data.tau_ff}
        statements = {
            "sim.data.tau_ff[:] = u": "sim.data.tau_ff[:] = u",
            "sim.data.tau_ff = u": "sim.data.tau_ff = u",
            "  part: sim.data": "sim.data",
            "  part: sim.data.tau_ff (the view)": "sim.data.tau_ff",
            "  part: view[:] = u (a view kept)": "view[:] = u",
            "  (pass: the timing's own cost)": "pass",
        }
        if self.mj is not None:
            names.update(d=self.mj_data, mu=self.mj_u)
            statements["MuJoCo d.ctrl[:] = u"] = "d.ctrl[:] = mu"
        return {k: min(timeit.repeat(code, number=WRITES, repeat=3, globals=names)) / WRITES * 1e6
                for k, code in statements.items()}


def run(scene: str, steps: int, repeats: int) -> dict:
    bench = Bench(scene, steps)
    ways = bench.ways()
    names = list(ways)
    wall = {k: [] for k in names}
    cpu = {k: [] for k in names}
    writes = []
    for rep in range(repeats):
        order = names[rep % len(names):] + names[:rep % len(names)]
        for name in order:
            w, c = ways[name]()
            wall[name].append(w)
            cpu[name].append(c)
        writes.append(bench.writes())
        print(f"repetition {rep + 1}/{repeats}: " + ", ".join(f"{k} {wall[k][-1]:.2f}" for k in names),
              file=sys.stderr)
    reference = bench.final_q["rollout"]
    same = {k: bool(np.array_equal(q, reference)) for k, q in bench.final_q.items()}
    rows = []
    mj_loop = wall.get("MuJoCo mj_step loop")
    for name in names:
        over = [a - b for a, b in zip(wall[name], wall["rollout"])]
        over_cpu = [a - b for a, b in zip(cpu[name], cpu["rollout"])]
        row = {"way": name, "us_per_step": statistics.median(wall[name]), "min": min(wall[name]),
               "max": max(wall[name]), "cpu_us_per_step": statistics.median(cpu[name]),
               "over_rollout_us": statistics.median(over), "over_rollout_cpu_us": statistics.median(over_cpu),
               "vs_rollout": statistics.median(a / b for a, b in zip(wall[name], wall["rollout"])),
               "vs_rollout_cpu": statistics.median(a / b for a, b in zip(cpu[name], cpu["rollout"]))}
        if mj_loop is not None:
            row["vs_mujoco_loop"] = statistics.median(a / b for a, b in zip(wall[name], mj_loop))
            row["vs_mujoco_loop_cpu"] = statistics.median(
                a / b for a, b in zip(cpu[name], cpu["MuJoCo mj_step loop"]))
        rows.append(row)
    import pinocchio as pin  # noqa: PLC0415

    return {
        "stamp": sweep.stamp(" ".join([Path(sys.argv[0]).name] + sys.argv[1:])), "scene": scene,
        "steps": steps, "repeats": repeats, "dt": bench.sim.dt, "rows": rows,
        "step_timer_us": statistics.median(bench.step_timer_us), "unconverged_steps": bench.unconverged,
        "same_final_state": same, "pinocchio": pin.__version__,
        "writes_us": {k: statistics.median(w[k] for w in writes) for k in writes[0]},
        "mujoco": bench.mj is not None,
    }


def markdown(res: dict) -> str:
    st = res["stamp"]
    lines = [
        f"Scene {res['scene']} (dt = {res['dt']:g} s), {res['steps']} steps per run, {res['repeats']} repetitions "
        f"interleaved; medians. {sweep.stamp_text(st)}.",
        "",
        "| way | µs / step (wall) | min – max | CPU µs / step | beyond the C++ rollout, µs / step (wall; CPU) "
        "| / C++ rollout (wall; CPU) | / MuJoCo's Python loop (wall; CPU) |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in res["rows"]:
        vs_mj = f"{r['vs_mujoco_loop']:.2f}; {r['vs_mujoco_loop_cpu']:.2f}" if "vs_mujoco_loop" in r else "—"
        lines.append(f"| {r['way']} | {r['us_per_step']:.2f} | {r['min']:.2f} – {r['max']:.2f} | "
                     f"{r['cpu_us_per_step']:.2f} | {r['over_rollout_us']:+.2f}; {r['over_rollout_cpu_us']:+.2f} | "
                     f"{r['vs_rollout']:.2f}; {r['vs_rollout_cpu']:.2f} | {vs_mj} |")
    lines += [
        "",
        f"The C++ step's own timer (inside the rollout, median over steps): {res['step_timer_us']:.2f} µs. "
        f"Unconverged stiction steps (rollouts): {res['unconverged_steps']}. Every stiction way ends in the "
        "C++ rollout's state bit for bit: "
        + ("yes" if all(res["same_final_state"].values()) else
           "NO (" + ", ".join(k for k, v in res["same_final_state"].items() if not v) + ")") + ".",
        "",
        "| one control write | µs |",
        "|---|---:|",
    ]
    lines += [f"| {k} | {v:.3f} |" for k, v in res["writes_us"].items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--scene", default="solo12-stand")
    p.add_argument("--steps", type=int, default=None, help=f"steps per run (default {STEPS}, --quick {QUICK_STEPS})")
    p.add_argument("--repeats", type=int, default=None, help=f"default {REPEATS}, --quick {QUICK_REPEATS}")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--json", action="store_true")
    a = p.parse_args(argv)
    steps = a.steps or (QUICK_STEPS if a.quick else STEPS)
    repeats = a.repeats or (QUICK_REPEATS if a.quick else REPEATS)
    if steps < 1 or repeats < 1:
        p.error("--steps and --repeats must be >= 1")
    res = run(a.scene, steps, repeats)
    text = json.dumps(res, indent=1) if a.json else markdown(res)
    if not res["mujoco"]:
        print("MuJoCo is not installed (pip install 'stiction[bench]'): its rows are left out", file=sys.stderr)
    print(text)
    if a.out is not None:
        a.out.write_text(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
