"""Python front of the C++ simulator: scenes in, trajectories and summaries out."""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pinocchio as pin

from . import _core
from .scene import Scene, load_scene

_VECTOR_KEYS = ("t", "residual", "iterations", "converged", "dt")


def _rollout(model, data, n_steps: int, every: int = 1) -> dict:
    """_core.rollout with every per-record matrix as a 2-D array (a 1-row Eigen
    matrix may come back 1-D)."""
    rec = _core.rollout(model, data, n_steps, every)
    n = len(rec["t"])
    return {k: (np.asarray(v).reshape(n) if k in _VECTOR_KEYS else np.asarray(v).reshape(n, -1))
            for k, v in rec.items()}
PHASES = ("kinematics", "delassus", "solve", "integrate", "total")


@dataclass
class Trajectory:
    """A recorded rollout. Shapes: N records, nc candidate contacts.

    t (N,), q (N, nq), v (N, nv); lam (N, nc, 3) contact forces (t1, t2, n) in N;
    contact_velocity (N, nc, 3) J v after each step; gaps (N, nc) signed distances;
    states (N, nc) 0 open / 1 stick / 2 slip / 3 closed; residual (N,) the largest solver
    residual of the step; iterations (N,); converged (N,); dt (N,) the step taken;
    timings (N, 5) µs per phase: kinematics+collision, Delassus, solve, integrate, total.
    """

    scene: str
    contact_names: list[str]
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    lam: np.ndarray
    contact_velocity: np.ndarray
    gaps: np.ndarray
    states: np.ndarray
    residual: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    dt: np.ndarray
    timings: np.ndarray

    def save(self, path: str | Path) -> None:
        arrays = {k: v for k, v in asdict(self).items() if isinstance(v, np.ndarray)}
        np.savez_compressed(path, scene=self.scene, contact_names=np.array(self.contact_names), **arrays)

    @classmethod
    def load(cls, path: str | Path) -> "Trajectory":
        with np.load(path, allow_pickle=False) as f:
            kw = {k: f[k] for k in f.files}
        kw["scene"] = str(kw["scene"])
        kw["contact_names"] = [str(x) for x in kw["contact_names"]]
        return cls(**kw)


class Simulator:
    """A scene (name, TOML path or Scene) with its C++ model and data.

    Settings overrides: dt, mode ("timestep", "rk4"/"ode", "adaptive"), delta, zeta,
    tolerance, max_iterations, solver, ode_tolerance.
    """

    def __init__(self, scene: Scene | str, **overrides):
        self.scene = load_scene(scene) if isinstance(scene, str) else scene
        self.settings = self.scene.settings(**overrides)
        sc = self.scene
        self.model = _core.SimulatorModel(sc.model, sc.halfspaces, sc.contacts, sc.anchors, self.settings,
                                          sc.geometry, sc.pairs)
        self.data = _core.SimulatorData(self.model)
        self.reset()

    @property
    def contact_names(self) -> list[str]:
        """Candidates: the sphere/point contacts, then max_contacts slots per coal pair."""
        names = [c.name for c in self.scene.contacts]
        for p in self.scene.pairs:
            names += [f"{p.name}#{k}" for k in range(p.max_contacts)]
        return names

    def reset(self) -> None:
        sc, d = self.scene, self.data
        d.q, d.v, d.t = sc.q0, sc.v0, 0.0
        d.kp, d.kd, d.q_target, d.tau_ff = sc.kp, sc.kd, sc.q_target, sc.tau_ff

    def step(self) -> None:
        _core.step(self.model, self.data)

    def rollout(self, duration: float | None = None, record_every: int = 1,
                callback: Callable[["Simulator"], None] | None = None) -> Trajectory:
        """Simulate `duration` seconds (default: the scene's). The loop runs in C++ unless a
        `callback(simulator)` is given, which then runs before every step (e.g. to set
        data.tau_ff or data.q_target)."""
        duration = self.scene.duration if duration is None else float(duration)
        if duration < 0:
            raise ValueError("duration must be >= 0")
        if self.settings.mode == _core.IntegrationMode.adaptive:
            return self._rollout_adaptive(duration, callback)
        n = int(round(duration / self.settings.dt))
        if callback is None:
            rec = _rollout(self.model, self.data, n, record_every)
        else:
            chunks = [_rollout(self.model, self.data, 0, 1)]
            for k in range(1, n + 1):
                callback(self)
                r = _rollout(self.model, self.data, 1, 1)
                if k % record_every == 0:
                    chunks.append({key: val[1:] for key, val in r.items()})
            rec = {key: np.concatenate([c[key] for c in chunks]) for key in chunks[0]}
        return self._trajectory(rec)

    def _rollout_adaptive(self, duration, callback) -> Trajectory:
        chunks = [_rollout(self.model, self.data, 0, 1)]
        end = self.data.t + duration
        while self.data.t < end - 1e-12:
            if callback is not None:
                callback(self)
            r = _rollout(self.model, self.data, 1, 1)
            chunks.append({key: val[1:] for key, val in r.items()})
        rec = {key: np.concatenate([c[key] for c in chunks]) for key in chunks[0]}
        return self._trajectory(rec)

    def _trajectory(self, rec: dict) -> Trajectory:
        nc = self.model.num_candidates
        n = len(rec["t"])
        return Trajectory(
            scene=self.scene.name, contact_names=self.contact_names, t=rec["t"], q=rec["q"], v=rec["v"],
            lam=rec["lam"].reshape(n, nc, 3), contact_velocity=rec["contact_velocity"].reshape(n, nc, 3),
            gaps=rec["gaps"].reshape(n, nc), states=rec["states"].astype(np.int8).reshape(n, nc),
            residual=rec["residual"], iterations=rec["iterations"].astype(np.int32),
            converged=rec["converged"].astype(bool), dt=rec["dt"], timings=rec["timings"])

    # ---- post-processing
    def contact_centers(self, traj: Trajectory) -> np.ndarray:
        """World position of every candidate sphere centre (points: the point), (N, nc, 3)."""
        model, data = self.scene.model, self.scene.model.createData()
        out = np.empty((len(traj.t), len(self.scene.contacts), 3))
        for k, q in enumerate(traj.q):
            pin.framesForwardKinematics(model, data, q)
            for i, c in enumerate(self.scene.contacts):
                out[k, i] = data.oMf[c.frame].act(np.asarray(c.offset))
        return out

    def summary(self, traj: Trajectory) -> dict:
        """The numbers `stiction simulate --json` prints."""
        sc = self.scene
        after = traj.t >= sc.settle_time - 1e-12
        if not after.any():
            after[-1] = True
        free = sc.model.njoints > 1 and sc.model.joints[1].shortname() == "JointModelFreeFlyer"
        base = traj.q[:, :3] if free else np.zeros((len(traj.t), 3))
        i0 = int(np.argmax(after))
        base_drift = float(np.linalg.norm(base[-1] - base[i0])) if free else 0.0
        slipping = traj.states == 2
        vn = np.abs(traj.contact_velocity[..., 2])
        max_vn_slip = float(vn[slipping].max()) if slipping.any() else 0.0
        # acceleration along the slope (+x downhill): least-squares slope of the base's
        # world-frame x velocity (a free flyer's v is in its body frame: rotate it)
        accel = 0.0
        if free and after.sum() >= 3:
            vx = [pin.Quaternion(q[3:7]).matrix()[0] @ v[:3] for q, v in zip(traj.q[after], traj.v[after])]
            accel = float(np.polyfit(traj.t[after], vx, 1)[0])
        ns = len(sc.contacts)  # sphere/point contacts (centres known); coal slots follow
        # foot slip after settling, for the contacts that stay closed: the distance the
        # contact point slid (integral of the tangential contact velocity: rolling is
        # not slip), and the horizontal displacement of the sphere centre (the peers'
        # measure, which includes rolling).
        closed = (traj.gaps[after] <= 1e-4).all(axis=0)
        slip = displacement = 0.0
        if closed.any():
            speed = np.linalg.norm(traj.contact_velocity[after][:, closed, :2], axis=-1)
            slip = float((speed[1:] * traj.dt[after][1:, None]).sum(axis=0).max())
            sphere_closed = closed[:ns]
            if sphere_closed.any():
                centers = self.contact_centers(traj)
                disp = centers[after][:, sphere_closed, :2] - centers[i0][sphere_closed, :2]
                displacement = float(np.linalg.norm(disp, axis=-1).max())
        tim = np.median(traj.timings[1:], axis=0) if len(traj.t) > 1 else np.zeros(5)
        return {
            "scene": sc.name,
            "mode": {0: "timestep", 1: "rk4", 2: "adaptive"}[int(self.settings.mode)],
            "dt": self.settings.dt,
            "duration": float(traj.t[-1] - traj.t[0]),
            "steps": int(len(traj.t) - 1),
            "contacts": len(sc.contacts),
            "us_per_step": float(tim[4]),
            "us_per_phase": {p: float(x) for p, x in zip(PHASES[:4], tim[:4])},
            "max_penetration": float(max(0.0, -np.nanmin(np.where(np.isfinite(traj.gaps), traj.gaps, np.nan))))
            if np.isfinite(traj.gaps).any() else 0.0,
            "max_residual": float(traj.residual.max()),
            "all_converged": bool(traj.converged[1:].all()) if len(traj.t) > 1 else True,
            "settle_time": sc.settle_time,
            "base_drift": base_drift,
            "max_normal_velocity_while_sliding": max_vn_slip,
            "mean_acceleration_along_slope": accel,
            "expected_sliding_acceleration": sliding_acceleration(sc),
            "max_foot_slip": slip,
            "max_foot_displacement": displacement,
        }


def sliding_acceleration(scene: Scene) -> float:
    """g (sin θ - μ cos θ) when that is positive (a rigid body slides), else 0."""
    th = math.radians(scene.slope_deg)
    a = 9.81 * (math.sin(th) - scene.mu * math.cos(th))
    return a if a > 0 else 0.0
