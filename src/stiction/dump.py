"""``stiction dump``: the contact problem of each simulated step as an FCLib local HDF5 file.

A time step solves eq. 65 for A = J M⁻¹ Jᵀ and the right-hand side h b (eq. 27 scaled by the step,
the impulse form of eq. 70); the simulator keeps both after the step (``data.A``, ``data.b``,
``data.last_dt``), and ``data.result`` is the solve it made. Writing them, with the forces found,
lets any FCLib tool (Siconos, ``stiction bench profiles``) solve exactly the problem the simulator
saw. ODE modes (eq. 64) solve the problem at each RK stage with scale 1: the last stage's is kept.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterable

import numpy as np

from . import _core
from .fclib import write_local


def step_problem(sim) -> _core.ContactProblem | None:
    """The problem the last step's solve saw (None when no contact was active). ValueError when it
    holds blocks FCLib's local format cannot (planar or frictionless contacts, anchors, box rows)."""
    d = sim.data
    if d.joint_rows:
        raise ValueError(f"scene '{sim.scene.name}' at t = {d.t:g}: the step's problem has {len(d.joint_rows)} joint "
                         "row(s) (position limits, dry friction or effort limits: docs/joint-rows.md), which FCLib "
                         "local problems (spatial friction contacts only, no box rows) cannot hold; dump the contacts "
                         "alone with the joint rows off: stiction dump --no-joint-rows")
    active = list(d.active)
    if not active and sim.model.num_anchors == 0:
        return None
    rows = np.asarray(d.rows)
    names = sim.contact_names
    for i in active:
        if rows[i] != 3:
            kind = {1: "frictionless (1 row)", 2: "planar (2 rows)"}.get(int(rows[i]), f"{rows[i]} rows")
            raise ValueError(f"contact '{names[i]}' is {kind}: FCLib local problems hold spatial friction "
                             "contacts (3 rows) only")
    if sim.model.num_anchors:
        raise ValueError(f"scene '{sim.scene.name}' has {sim.model.num_anchors} anchor(s) (bilateral rows): "
                         "FCLib local problems hold spatial friction contacts only")
    timestep = sim.model.settings.mode == _core.IntegrationMode.timestep
    scale = float(d.last_dt) if timestep else 1.0  # step.cpp: solveContacts(sim, sd, h); rk4: 1.0
    A = np.asfortranarray(np.asarray(d.A, dtype=np.float64))
    extra = A.shape[0] - 3 * len(active)
    if extra > 0:  # rows that are no contact's: the joints' box rows
        raise ValueError(f"the step's problem has {extra} row(s) besides its contacts' (box rows: joint friction, "
                         "effort limits): FCLib has no box blocks")
    b = np.asarray(d.b, dtype=np.float64) * scale
    mus = [_candidate_mu(sim, i) for i in active]
    cons = [_core.Constraint.spatial_friction(m) for m in mus]
    return _core.ContactProblem(A, b, cons, 1e-6)


def _candidate_mu(sim, i: int) -> float:
    """The friction coefficient of candidate i: a sphere contact's own, or its coal pair's."""
    contacts = sim.model.contacts
    if i < len(contacts):
        return float(contacts[i].mu)
    slot = i - len(contacts)
    for p in sim.scene.pairs:
        if slot < p.max_contacts:
            return float(p.mu)
        slot -= p.max_contacts
    raise ValueError(f"candidate {i} is out of range ({sim.model.num_candidates} candidates)")


def dump(scene, steps: int, out_dir: str | os.PathLike, every: int = 1, solver: str | None = None,
         only: Iterable[int] | None = None, prefix: str | None = None, **overrides) -> list[dict]:
    """Simulate `steps` steps of `scene` (a name, TOML path, Scene or Simulator) and write the
    problem of every `every`-th step that has contacts (or of the steps in `only`, 1-based) to
    ``out_dir/<prefix>-step<k>.hdf5``. Returns one record per file: path, step, t, contacts, the
    simulator's verdict on its own solve (converged, relative_residual)."""
    from .simulator import Simulator

    for name, val in (("steps", steps), ("every", every)):
        if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 1:
            raise ValueError(f"dump: {name} must be an integer >= 1, got {val!r}")
    if only is None and every > steps:
        raise ValueError(f"dump: every = {every} is more than steps = {steps}: no step would be written (--every, --steps)")
    if solver is not None:
        if solver not in _core.solver_names():
            raise ValueError(f"dump: solver must be one of {', '.join(_core.solver_names())}, got {solver!r}")
        overrides["solver"] = solver
    sim = scene if isinstance(scene, Simulator) else Simulator(scene, **overrides)
    if isinstance(scene, Simulator) and overrides:
        raise ValueError("dump: overrides apply to a scene, not to a Simulator already built")
    wanted = None if only is None else {int(k) for k in only}
    if wanted is not None and any(k < 1 or k > steps for k in wanted):
        raise ValueError(f"dump: steps in `only` must lie in [1, {steps}], got {sorted(wanted)}")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"dump: --out {out} is a file, not a folder")
    out.mkdir(parents=True, exist_ok=True)
    prefix = prefix or sim.scene.name
    s = sim.model.settings
    records = []
    for k in range(1, steps + 1):
        sim.step()
        if (wanted is not None and k not in wanted) or (wanted is None and k % every):
            continue
        problem = step_problem(sim)
        if problem is None:
            continue
        r = sim.data.result
        names = [sim.contact_names[i] for i in sim.data.active]
        meta = {"scene": sim.scene.name, "step": k, "t": float(sim.data.t), "dt": float(sim.data.last_dt),
                "solver": s.solver, "formulation": s.formulation, "tolerance": float(s.tolerance),
                "contacts": names, "converged": bool(r.converged),
                "relative_residual": float(r.relative_residual)}
        path = out / f"{prefix}-step{k:06d}.hdf5"
        write_local(path, problem, title=f"{sim.scene.name} step {k}", description=json.dumps(meta),
                    solution=np.asarray(r.lam, dtype=np.float64))
        records.append({"path": str(path), **meta})
    return records


def add_arguments(parser) -> None:
    parser.add_argument("scene", help="a bundled scene name or a TOML path")
    parser.add_argument("--steps", type=int, required=True, help="steps to simulate")
    parser.add_argument("--out", required=True, help="directory for the .hdf5 files (created)")
    parser.add_argument("--every", type=int, default=1, help="write every K-th step (default 1)")
    parser.add_argument("--solver", choices=_core.solver_names(), help="the simulator's contact solver")
    parser.add_argument("--json", action="store_true", help="print one JSON record per file written")
    parser.add_argument("--no-joint-rows", action="store_true",
                        help="simulate with the joints' limits, dry friction, damping and effort limits off "
                             "(FCLib cannot hold their rows: docs/joint-rows.md)")


# The Simulator overrides that turn every joint row (and the damping) off: the contacts alone.
NO_JOINT_ROWS = {"joint_limits": False, "joint_friction": False, "joint_damping": False, "effort_limits": False}


def main(args) -> int:
    overrides = NO_JOINT_ROWS if args.no_joint_rows else {}
    records = dump(args.scene, args.steps, args.out, every=args.every, solver=args.solver, **overrides)
    if getattr(args, "json", False):
        print(json.dumps({"files": records}, indent=1))
    else:
        print(f"{len(records)} problem(s) written to {args.out}")
    return 0
