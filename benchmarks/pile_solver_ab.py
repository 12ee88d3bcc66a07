"""pile-24 A/B of the solve path against a MuJoCo twin of the same pile, in one process, interleaved.

Usage: python benchmarks/pile_solver_ab.py [--steps N] [--reps R] [--variants a,b] [--profile]
The MuJoCo twin: each free body's mass, lever and inertia from the Pinocchio model, its box or sphere
from the pile's coal geometry, the same initial poses, mu, dt; elliptic cones, Newton, 1e-10 (the
robot twins' accurate_options), MuJoCo's Euler integrator (as the scaling bench's cubes).
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


def pile_twin(scene):
    import coal
    import mujoco as mj
    import pinocchio as pin

    from stiction.bench.mujoco_twins import _ground, accurate_options

    spec = mj.MjSpec()
    _ground(spec, float(scene.mu), name="", size=(10, 10, 0.1))
    model = scene.model
    for j in range(1, model.njoints):
        q = scene.q0[model.idx_qs[j]: model.idx_qs[j] + 7]
        inertia = model.inertias[j]
        body = spec.worldbody.add_body(pos=list(q[:3]), quat=[q[6], q[3], q[4], q[5]])
        body.add_freejoint()
        body.mass = float(inertia.mass)
        body.ipos = list(inertia.lever)
        body.fullinertia = [*np.diag(inertia.inertia), inertia.inertia[0, 1], inertia.inertia[0, 2], inertia.inertia[1, 2]]
        body.explicitinertial = True
        go = next(g for g in scene.geometry.geometryObjects if g.parentJoint == j)
        pl = go.placement
        quat = pin.Quaternion(pl.rotation)
        kw = dict(pos=list(pl.translation), quat=[quat.w, quat.x, quat.y, quat.z], friction=[float(scene.mu), 0, 0],
                  condim=3, mass=0)
        if isinstance(go.geometry, coal.Box):
            body.add_geom(type=mj.mjtGeom.mjGEOM_BOX, size=list(go.geometry.halfSide), **kw)
        else:
            body.add_geom(type=mj.mjtGeom.mjGEOM_SPHERE, size=[go.geometry.radius, 0, 0], **kw)
    accurate_options(spec, float(scene.dt), (0.0, 0.0, -9.81), implicit=False)
    return spec.compile()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--scene", default="pile-24")
    ap.add_argument("--variants", default="", help="'|'-separated variants, each space-separated ENV=VALUE settings "
                    "(A/B in one build), e.g. 'STICTION_ISLANDS=0|STICTION_ISLANDS=1'")
    args = ap.parse_args()
    import mujoco

    from stiction.scene import load_scene
    from stiction.simulator import Simulator

    scene = load_scene(args.scene)
    mjm = pile_twin(scene) if scene.geometry is not None else None  # (no twin for a scene without coal pairs)
    variants = args.variants.split("|") if args.variants else [""]
    rows = {v: [] for v in variants}
    rows["mujoco"] = []
    print("load", os.getloadavg())
    for rep in range(args.reps):
        for v in variants:
            env = dict(kv.split("=", 1) for kv in v.split())
            os.environ.update(env)
            sim = Simulator(args.scene)
            t0 = time.perf_counter()
            traj = sim.rollout(args.steps * sim.dt)
            wall = (time.perf_counter() - t0) / args.steps * 1e6
            step, solve = traj.timings[1:, 4], traj.timings[1:, 2]
            rows[v].append((np.median(step), np.mean(step), wall, bool(traj.converged[1:].all()),
                            np.median(solve), np.mean(solve)))
            for k in env:
                del os.environ[k]
        if mjm is None:
            continue
        d = mujoco.MjData(mjm)
        per = []
        t0 = time.perf_counter()
        for _ in range(args.steps):
            t1 = time.perf_counter()
            mujoco.mj_step(mjm, d)
            per.append(time.perf_counter() - t1)
        wall = (time.perf_counter() - t0) / args.steps * 1e6
        rows["mujoco"].append((np.median(per) * 1e6, np.mean(per) * 1e6, wall, True, 0.0, 0.0))
    print("load", os.getloadavg())
    for k, r in rows.items():
        if not r:
            continue
        r = np.array(r, dtype=float)
        print(f"{k or 'default':>50}: median {np.median(r[:, 0]):7.1f} us  mean {np.median(r[:, 1]):7.1f} us  "
              f"wall {np.median(r[:, 2]):7.1f} us  solve median {np.median(r[:, 4]):6.1f} mean {np.median(r[:, 5]):6.1f}  "
              f"converged {bool(r[:, 3].all())}")


if __name__ == "__main__":
    main()
