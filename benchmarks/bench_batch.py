#!/usr/bin/env python
"""Benchmark: batched rollouts on C++ threads — throughput with k threads against one, stiction's
``batch_rollout`` and MuJoCo's ``mujoco.rollout`` side by side.

Usage:  python benchmarks/bench_batch.py [--quick] [--scene SCENE] [--sims N] [--duration S] [--no-mujoco]

A batch of N independent simulations of one scene (default solo12-stand, N = 8, 2 s each) is run
by ``stiction.simulator.batch_rollout`` with 1 thread and with 2 threads (one per core of the
reference machine), fresh Simulators each time, timed by ``Batch.seconds`` (the C++ call: the
recordings laid out, the steps, the arrays handed to Python; not the Trajectories built after it).
When MuJoCo is installed (the ``bench`` extra), the scene's MuJoCo twin
(:func:`stiction.bench.mujoco_twins.mujoco_twin`, impratio 1) runs the same batch by
``mujoco.rollout.rollout`` with 1 and with 2 ``MjData`` (its thread pool: one thread per data),
recording its full physics state, timed by the wall clock around the call. Every repetition runs
the four configurations in an order rotated by one per repetition; the report gives the MEDIAN
wall time over repetitions (9, ``--quick`` 3), the throughput ratio median(1 thread) / median(2
threads) for each simulator, and the paired ratios (1 thread / 2 threads within a repetition).
The machine is shared: run it idle (``uptime``: load below 1) for the ratio to mean anything; the
load average is printed at the start and the end, and with each run the involuntary context
switches of this process (``preemptions``: another program took one of our cores meanwhile).
Beside the wall clock, for stiction, the CPU time of the call (``time.process_time``: every thread)
and of the calling thread alone (``time.thread_time``), both around ``batch_rollout`` (the
Trajectories built after the C++ call included): with 2 threads the calling thread runs what is
serial (layout, hand-over) and its share of the simulations, the other thread the rest, so
``cpu_bound_ratio`` = CPU(1 thread) / max(calling thread, other thread) with 2 is about the
throughput ratio the work allows when both cores are free, whatever the load (the wall ratio is
not); a little below it, as the Trajectories' Python, serial, is counted in it but not in the wall.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import time

import numpy as np

from stiction.simulator import Simulator, batch_rollout


CPU: dict[str, list[tuple[float, float]]] = {}  # stiction runs: (process CPU, calling thread CPU) seconds
PREEMPTIONS: dict[str, list[int]] = {}


def run_stiction(scene: str, sims: int, duration: float, threads: int) -> tuple[float, int]:
    """Wall seconds of the batch (Batch.seconds) and the preemptions meanwhile."""
    simulators = [Simulator(scene) for _ in range(sims)]
    before, cpu0, own0 = preemptions(), time.process_time(), time.thread_time()
    batch = batch_rollout(simulators, duration, threads=threads)
    CPU.setdefault(f"stiction {threads}", []).append((time.process_time() - cpu0, time.thread_time() - own0))
    if any(batch.errors):
        raise RuntimeError(f"a simulation failed: {batch.errors}")
    return batch.seconds, preemptions() - before


def preemptions() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_nivcsw


class MujocoBatch:
    """The scene's MuJoCo twin, its initial state and constant control tiled for `sims` rollouts."""

    def __init__(self, scene_name: str, sims: int, steps: int):
        import mujoco

        from stiction.bench import mujoco_twins
        from stiction.scene import load_scene

        scene = load_scene(scene_name)
        self.twin = mujoco_twins.mujoco_twin(scene, impratio=1.0)
        self.datas = [mujoco.MjData(self.twin.model) for _ in range(2)]
        state = self.twin.initial_state(scene.q0, scene.v0)
        self.initial = np.tile(state, (sims, 1))
        self.control = (np.tile(self.twin.ctrl, (sims, 1, 1)) if self.twin.model.nu else None)
        self.steps = steps

    def run(self, threads: int) -> tuple[float, int]:
        import mujoco.rollout

        data = self.datas[0] if threads == 1 else self.datas[:threads]
        before, t0 = preemptions(), time.perf_counter()
        mujoco.rollout.rollout(self.twin.model, data, self.initial, self.control, nstep=self.steps)
        return time.perf_counter() - t0, preemptions() - before


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--scene", default="solo12-stand")
    ap.add_argument("--sims", type=int, default=8)
    ap.add_argument("--duration", type=float, default=2.0)
    ap.add_argument("--threads", type=int, default=2, help="the parallel configuration (default 2)")
    ap.add_argument("--repeats", type=int, default=None, help="repetitions (default 9, --quick 3)")
    ap.add_argument("--no-mujoco", action="store_true", help="time stiction alone")
    args = ap.parse_args()
    reps = args.repeats or (3 if args.quick else 9)
    load_start = os.getloadavg()
    steps = round(args.duration / Simulator(args.scene).dt)
    timers = {f"stiction {c}": (lambda c=c: run_stiction(args.scene, args.sims, args.duration, c))
              for c in (1, args.threads)}
    if not args.no_mujoco:
        try:
            mj = MujocoBatch(args.scene, args.sims, steps)
        except ImportError:
            mj = None
        if mj is not None:
            timers.update({f"mujoco {c}": (lambda c=c: mj.run(c)) for c in (1, args.threads)})
    names = list(timers)
    for name in names:  # warm-up
        timers[name]()
    CPU.clear()
    times = {name: [] for name in names}
    for r in range(reps):
        order = names[r % len(names):] + names[: r % len(names)]
        for name in order:
            seconds, preempted = timers[name]()
            times[name].append(seconds)
            PREEMPTIONS.setdefault(name, []).append(preempted)
    med = {name: statistics.median(v) for name, v in times.items()}
    out = {
        "scene": args.scene, "simulations": args.sims, "duration": args.duration, "steps": steps,
        "repetitions": reps,
        "median_seconds": med,
        "steps_per_second": {name: args.sims * steps / med[name] for name in names},
        "throughput_ratio": {}, "paired_ratios": {},
        "load_average_start": load_start, "load_average_end": os.getloadavg(), "cpus": os.cpu_count(),
    }
    out["preemptions"] = PREEMPTIONS
    one, many = CPU["stiction 1"], CPU[f"stiction {args.threads}"]
    out["stiction_cpu_seconds"] = {name: statistics.median(c for c, _ in v) for name, v in CPU.items()}
    out["stiction_calling_thread_cpu_seconds"] = {name: statistics.median(o for _, o in v) for name, v in CPU.items()}
    out["cpu_bound_ratio"] = statistics.median(c for c, _ in one) / statistics.median(
        max(own, c - own) for c, own in many)
    for sim in ("stiction", "mujoco"):
        one, many = f"{sim} 1", f"{sim} {args.threads}"
        if one in med:
            out["throughput_ratio"][sim] = med[one] / med[many]
            out["paired_ratios"][sim] = [a / b for a, b in zip(times[one], times[many])]
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
