#!/usr/bin/env python
"""Benchmark: batched rollouts on C++ threads — throughput with k threads against one.

Usage:  python benchmarks/bench_batch.py [--quick] [--scene SCENE] [--sims N] [--duration S]

A batch of N independent simulations of one scene (default solo12-stand, N = 8, 0.5 s each) is
run by ``stiction.simulator.batch_rollout`` with 1 thread and with 2 threads (one per core of
the reference machine), fresh Simulators each time. Every repetition runs both configurations,
in an order rotated by one per repetition; the report gives the MEDIAN wall time over
repetitions (7, ``--quick`` 3) and the throughput ratio median(1 thread) / median(2 threads).
The machine is shared: run it idle (``uptime``: load below 1) for the ratio to mean anything;
the load average is printed with the result.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics

from stiction.simulator import Simulator, batch_rollout


def run(scene: str, sims: int, duration: float, threads: int) -> float:
    batch = batch_rollout([Simulator(scene) for _ in range(sims)], duration, threads=threads)
    if any(batch.errors):
        raise RuntimeError(f"a simulation failed: {batch.errors}")
    return batch.seconds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--scene", default="solo12-stand")
    ap.add_argument("--sims", type=int, default=8)
    ap.add_argument("--duration", type=float, default=0.5)
    ap.add_argument("--threads", type=int, default=2, help="the parallel configuration (default 2)")
    args = ap.parse_args()
    reps = 3 if args.quick else 7
    configs = [1, args.threads]
    for c in configs:  # warm-up
        run(args.scene, args.sims, args.duration / 5, c)
    times = {c: [] for c in configs}
    for r in range(reps):
        order = configs[r % 2:] + configs[: r % 2]
        for c in order:
            times[c].append(run(args.scene, args.sims, args.duration, c))
    med = {c: statistics.median(v) for c, v in times.items()}
    steps = args.sims * round(args.duration / Simulator(args.scene).dt)
    out = {
        "scene": args.scene, "simulations": args.sims, "duration": args.duration, "repetitions": reps,
        "median_seconds": {str(c): med[c] for c in configs},
        "steps_per_second": {str(c): steps / med[c] for c in configs},
        "throughput_ratio": med[1] / med[args.threads],
        "load_average": os.getloadavg(), "cpus": os.cpu_count(),
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
