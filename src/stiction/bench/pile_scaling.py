"""`stiction bench scaling --layout pile`: cost per step against body count for a pile of mixed
shapes dropped into a bin (stiction.pile: boxes, spheres, capsules, cylinders, convex hulls; seed 1,
mu = 0.5, dt = 1 ms, the exact law to the default tolerance), beside its MuJoCo 4.0 twin
(:func:`stiction.bench.mujoco_twins.pile_spec`: the same shapes, masses, inertias, friction and
initial poses; elliptic cones, Newton, tolerance 1e-10, Euler).

Both are timed the same way, in one process, interleaved: after ``warmup`` untimed steps of each
(the bodies falling), the ``steps`` timed steps go in chunks of ``CHUNK``, one simulator's chunk then
the other's (the first alternating chunk by chunk), each step between two ``perf_counter`` reads
(the Python call included, ~1 us, for both). So a load that comes and goes hits both alike.
``us_per_step`` is the mean (total time / steps), ``median_us_per_step`` the median step.

Per size: ``contacts`` the mean number of contact points in our problem per timed step (MuJoCo's:
``mujoco_contacts``), ``all_converged`` every step of ours (warmup included) converged,
``max_penetration`` the deepest overlap of ours in any step (m), ``energy_drift`` the largest rise of
kinetic + potential energy over any interval of the run (warmup included), relative to the initial
energy (0: it never rose; the contacts only dissipate), and MuJoCo's penetration and energy drift
beside them.
"""
from __future__ import annotations

import json
import subprocess
import sys

CHUNK = 10
WARMUP_STEPS = 300  # the lowest layer lands at ~0.1 s, the top one at ~0.45 s
DEFAULT_STEPS, QUICK_STEPS = 300, 50
MIX = ("box", "sphere", "capsule", "cylinder", "mesh")
SEED = 1

MEASURE = r"""
import json, resource, sys, time
import numpy as np
import mujoco
from stiction import _core
from stiction.bench.mujoco_twins import pile_spec
from stiction.bench.pile_scaling import scene_config, largest_rise
from stiction.scene import build_scene
from stiction.simulator import Simulator
bodies, steps, warmup, chunk = (int(x) for x in sys.argv[1:5])
scene = build_scene(scene_config(bodies))
sim = Simulator(scene)
mj_model = pile_spec(scene).compile()
mj_data = mujoco.MjData(mj_model)
mass = np.array([scene.model.inertias[j].mass for j in range(1, scene.model.njoints)])
inertia = np.array([scene.model.inertias[j].inertia for j in range(1, scene.model.njoints)])
g = -float(scene.model.gravity.linear[2])

def energy(q, v):  # free bodies, centre of mass at the joint: linear speed (any frame), angular in the body's
    q, v = q.reshape(-1, 7), v.reshape(-1, 6)
    return float(0.5 * (mass * (v[:, :3] ** 2).sum(1)).sum() + 0.5 * np.einsum("ki,kij,kj->", v[:, 3:], inertia, v[:, 3:])
                 + g * (mass * q[:, 2]).sum())

ours = {"time": [], "contacts": [], "energy": [energy(sim.data.q, sim.data.v)], "pen": 0.0, "converged": True}
theirs = {"time": [], "contacts": [], "energy": [energy(mj_data.qpos, mj_data.qvel)], "pen": 0.0}
model, data, clock = sim.model, sim.data, time.perf_counter

def run_ours(n, timed):
    for _ in range(n):
        t0 = clock()
        _core.step(model, data)
        t1 = clock()
        active = data.active
        if timed:
            ours["time"].append(t1 - t0)
            ours["contacts"].append(len(active))
        ours["converged"] &= bool(data.all_converged_step)
        if active:
            ours["pen"] = max(ours["pen"], -float(np.asarray(data.gaps)[list(active)].min()))
        ours["energy"].append(energy(data.q, data.v))

def run_theirs(n, timed):
    for _ in range(n):
        t0 = clock()
        mujoco.mj_step(mj_model, mj_data)
        t1 = clock()
        if timed:
            theirs["time"].append(t1 - t0)
            theirs["contacts"].append(mj_data.ncon)
        if mj_data.ncon:
            theirs["pen"] = max(theirs["pen"], -float(mj_data.contact.dist[:mj_data.ncon].min()))
        theirs["energy"].append(energy(mj_data.qpos, mj_data.qvel))

for k, start in enumerate(range(0, warmup + steps, chunk)):
    n = min(chunk, warmup + steps - start)
    timed = start >= warmup
    pair = (run_ours, run_theirs) if k % 2 == 0 else (run_theirs, run_ours)
    for f in pair:
        f(n, timed)
t_ours, t_theirs = np.array(ours["time"]) * 1e6, np.array(theirs["time"]) * 1e6
print(json.dumps({
    "contacts": float(np.mean(ours["contacts"])), "us_per_step": float(t_ours.mean()),
    "median_us_per_step": float(np.median(t_ours)), "mujoco_us_per_step": float(t_theirs.mean()),
    "mujoco_median_us_per_step": float(np.median(t_theirs)), "mujoco_contacts": float(np.mean(theirs["contacts"])),
    "all_converged": ours["converged"], "max_penetration": ours["pen"], "mujoco_max_penetration": theirs["pen"],
    "energy_drift": largest_rise(ours["energy"]), "mujoco_energy_drift": largest_rise(theirs["energy"]),
    "peak_memory_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}))
"""


def scene_config(bodies: int) -> dict:
    """The bench's pile of `bodies` (the keys of robots/scenes/pile-256.toml and pile-1000.toml)."""
    return {"name": f"pile-mix-{bodies}", "duration": 2.0, "dt": 0.001,
            "array": {"layout": "pile", "count": bodies, "seed": SEED, "mix": list(MIX)}, "ground": {"mu": 0.5}}


def largest_rise(energy) -> float:
    """The largest rise of `energy` over any interval (a later value minus an earlier, lowest one),
    relative to the first value; 0 when it never rises."""
    lowest, rise = float("inf"), 0.0
    for e in energy:
        lowest = min(lowest, e)
        rise = max(rise, e - lowest)
    return rise / abs(energy[0]) if energy[0] else rise


def evaluate(case: dict) -> dict:
    """One size in its own subprocess (its peak memory is that size's), both simulators in it."""
    bodies, steps = case["bodies"], case["steps"]
    out = subprocess.run([sys.executable, "-c", MEASURE, str(bodies), str(steps), str(case.get("warmup", WARMUP_STEPS)),
                          str(CHUNK)], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"pile of {bodies} bodies failed: {out.stderr.strip().splitlines()[-1:]}")
    m = json.loads(out.stdout.strip().splitlines()[-1])
    return {"scene": case["scene"], "layout": "pile", "bodies": bodies, "steps": steps, **m}
