"""The world split into parts (issue 8): each subtree of the universe (a robot, a free body) has a
Model and Data of its own, J is held by columns of parts, and A = sum over parts of
J_s M_s^-1 J_s^T (eq. 22) is assembled dense, or sparse for many parts. Checked against the
world model computed independently with Pinocchio's Python bindings, against a single cube, and
for memory at 1024 contacts."""
import json
import subprocess
import sys

import numpy as np
import pinocchio as pin
import pytest

from stiction import _core
from stiction.scene import load_scene
from stiction.simulator import Simulator


def world_reference(sim, q, v):
    """M, nle and A = J M^-1 J^T of the whole world from one pinocchio.Data (small worlds only)."""
    model = sim.scene.model
    data = model.createData()
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    nle = pin.nonLinearEffects(model, data, q, v)
    J = np.asarray(sim.data.J)
    return M, nle, J @ np.linalg.solve(M, J.T)


@pytest.mark.parametrize("scene", ["two-cube-stack", "box-tower-20", "cube-grid-64"])
def test_parts_reproduce_the_world_model(scene):
    sim = Simulator(load_scene(scene))
    assert sim.data.parts == sim.scene.model.njoints - 1  # one free body per part
    sim.rollout(0.05)
    rng = np.random.default_rng(3)
    q = np.asarray(sim.data.q).copy()
    v = 0.1 * rng.standard_normal(sim.scene.model.nv)
    _core.build_contact_problem(sim.model, sim.data, q, v, 1e-3, 0.5)
    M_ref, nle_ref, A_ref = world_reference(sim, q, v)
    assert np.abs(np.asarray(sim.data.M) - M_ref).max() <= 1e-12 * np.abs(M_ref).max()
    assert np.abs(np.asarray(sim.data.nle) - nle_ref).max() <= 1e-12 * max(1.0, np.abs(nle_ref).max())
    A = np.asarray(sim.data.A)
    assert A.shape[0] > 0
    assert np.abs(A - A_ref).max() <= 1e-12 * np.abs(A_ref).max()
    assert np.array_equal(A, A.T)


def test_contacts_between_parts_couple_them():
    """In a stack the contacts between two cubes belong to both parts: J has both cubes' columns,
    and A couples the contacts under and over a cube (the tower's A is block tridiagonal)."""
    sim = Simulator(load_scene("two-cube-stack"))
    sim.step()
    J = np.asarray(sim.data.J)
    active = list(sim.data.active)
    names = [sim.scene.contacts[i].name for i in active]
    between = [k for k, n in enumerate(names) if n.startswith("body1")]
    ground = [k for k, n in enumerate(names) if n.startswith("body0")]
    assert between and ground
    rows_between = np.concatenate([np.arange(3 * k, 3 * k + 3) for k in between])
    rows_ground = np.concatenate([np.arange(3 * k, 3 * k + 3) for k in ground])
    assert np.abs(J[np.ix_(rows_between, np.arange(0, 6))]).max() > 0.1  # the lower cube (the face)
    assert np.abs(J[np.ix_(rows_between, np.arange(6, 12))]).max() > 0.1  # the upper cube
    assert np.abs(J[np.ix_(rows_ground, np.arange(6, 12))]).max() == 0.0  # ground contacts: lower cube only
    A = np.asarray(sim.data.A)
    assert np.abs(A[np.ix_(rows_ground, rows_between)]).max() > 1e-3


def test_sparse_operator_is_one_block_per_cube():
    """cube-grid-1024: 256 parts, 3072 rows, a sparse A equal to 256 copies of one resting cube's
    12 x 12 block (identical cubes at rest on the ground, A is translation invariant)."""
    grid = Simulator(load_scene("cube-grid-1024"))
    single = Simulator(load_scene("cube-grid-64"))
    grid.step()
    single.step()
    assert grid.data.sparse and not single.data.sparse
    assert grid.data.parts == 256
    A = np.asarray(grid.data.A)
    block = np.asarray(single.data.A)[:12, :12]
    assert A.shape == (3072, 3072)
    assert np.abs(A - np.kron(np.eye(256), block)).max() <= 1e-12 * np.abs(block).max()


def test_large_grid_rests_exactly():
    """256 cubes at rest for 0.2 s: no penetration, no drift, every step converged (the sparse
    operator through the default solver)."""
    sim = Simulator(load_scene("cube-grid-1024"))
    s = sim.summary(sim.rollout(0.2))
    assert s["all_converged"]
    assert s["max_penetration"] <= 1e-8
    assert s["max_body_drift"] <= 1e-9
    assert s["max_residual"] <= 1e-10


MEMORY = r"""
import json, resource
from stiction.scene import load_scene
from stiction.simulator import Simulator
sim = Simulator(load_scene("cube-grid-1024"))
traj = sim.rollout(0.02)
s = sim.summary(traj)
print(json.dumps({"mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, "ok": s["all_converged"]}))
"""


def test_1024_contacts_fit_in_2_gb():
    """A world Data of 256 free bodies (nv = 1536) would hold 4 nv^3 doubles: 116 GB. By parts the
    whole process, Python and Pinocchio included, stays under 2 GB."""
    out = subprocess.run([sys.executable, "-c", MEMORY], capture_output=True, text=True, check=True)
    m = json.loads(out.stdout.strip().splitlines()[-1])
    assert m["ok"]
    assert m["mb"] < 2048


def test_contact_centers_match_pinocchio():
    sim = Simulator(load_scene("two-cube-stack"))
    traj = sim.rollout(0.02)
    centers = sim.contact_centers(traj)
    model = sim.scene.model
    data = model.createData()
    for k in (0, len(traj.t) - 1):
        pin.framesForwardKinematics(model, data, traj.q[k])
        for i, c in enumerate(sim.scene.contacts):
            assert np.allclose(centers[k, i], data.oMf[c.frame].act(np.asarray(c.offset)), atol=1e-14)
    with pytest.raises(ValueError, match="nq"):
        _core.contact_centers(sim.model, np.zeros((2, 3)))
