"""Plots of a rollout: base position, foot slip, contact forces (headless, Agg)."""
from __future__ import annotations

import os

import numpy as np


def plot_trajectory(sim, traj, path: str | os.PathLike) -> None:
    """Write a PNG (or PDF/SVG, by the suffix) of the base position, foot slip and contact forces
    of a rollout. Needs the optional extra ``stiction[plot]`` (matplotlib)."""
    from ._optional import require

    matplotlib = require("matplotlib", "plot", "plots")

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scene = sim.scene
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    t = traj.t
    free = scene.model.njoints > 1 and scene.model.joints[1].shortname() == "JointModelFreeFlyer"
    ax = axes[0]
    if free:
        for k, label in enumerate("xyz"):
            ax.plot(t, traj.q[:, k] - traj.q[0, k], label=f"base {label} - {label}0")
        ax.set_ylabel("base displacement [m]")
        ax.legend(loc="best", fontsize=8)
    elif scene.model.njoints > 1 and scene.model.joints[1].shortname() == "JointModelComposite":
        # an MJCF root of slides and hinges (rootx, rootz, rooty): its coordinates
        for k in range(scene.model.joints[1].nq):
            ax.plot(t, traj.q[:, k] - traj.q[0, k], label=f"root q[{k}] - q0[{k}]")
        ax.set_ylabel("root coordinates [m, rad]")
        ax.legend(loc="best", fontsize=8)
    ax.set_title(f"{scene.name}: {scene.description[:90]}", fontsize=9)

    ax = axes[1]
    slid = np.cumsum(np.linalg.norm(traj.contact_velocity[..., :2], axis=-1) * traj.dt[:, None], axis=0)
    for i, name in enumerate(traj.contact_names):
        ax.plot(t, slid[:, i], label=name)
    ax.set_ylabel("distance slid [m]")
    ax.legend(loc="best", fontsize=7, ncol=2)

    ax = axes[2]
    for i, name in enumerate(traj.contact_names):
        if np.abs(traj.lam[1:, i]).max(initial=0.0) == 0:  # (record 0: no step, NaN)
            continue
        line, = ax.plot(t, traj.lam[:, i, 2], label=f"{name} normal")
        ax.plot(t, np.linalg.norm(traj.lam[:, i, :2], axis=-1), "--", color=line.get_color())
    ax.set_ylabel("contact force [N] (dashed: tangential)")
    ax.set_xlabel("t [s]")
    ax.legend(loc="best", fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
