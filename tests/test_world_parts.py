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


@pytest.mark.parametrize("scene", ["two-cube-stack", "box-tower-20", "cube-grid-64", "solo12-stand", "talos-stand",
                                   "ur5-push-box", "solo12-on-board"])
def test_parts_reproduce_the_world_model(scene):
    """A robot's M is built from the step's own kinematics (world-frame composite inertias on the
    joint Jacobian's columns), not by crba's second forward pass: checked against crba, with the
    robot's joints moved off the scene's pose."""
    sim = Simulator(load_scene(scene))
    model = sim.scene.model
    robots = any(model.joints[j].shortname() != "JointModelFreeFlyer" for j in range(1, model.njoints))
    if not robots:
        assert sim.data.parts == model.njoints - 1  # one free body per part
    sim.rollout(0.05)
    rng = np.random.default_rng(3)
    q = np.asarray(sim.data.q).copy()
    for j in range(1, model.njoints):  # revolute joints moved 0.05 rad on average (the feet still touch)
        if model.joints[j].shortname() != "JointModelFreeFlyer":
            q[model.joints[j].idx_q:model.joints[j].idx_q + model.joints[j].nq] += 0.05 * rng.standard_normal(
                model.joints[j].nq)
    v = 0.1 * rng.standard_normal(sim.scene.model.nv)
    _core.build_contact_problem(sim.model, sim.data, q, v, 1e-3, 0.5)
    M_ref, nle_ref, A_ref = world_reference(sim, q, v)
    assert np.abs(np.asarray(sim.data.M) - M_ref).max() <= 1e-12 * np.abs(M_ref).max()
    assert np.abs(np.asarray(sim.data.nle) - nle_ref).max() <= 1e-12 * max(1.0, np.abs(nle_ref).max())
    A = np.asarray(sim.data.A)
    assert A.shape[0] > 0
    assert np.abs(A - A_ref).max() <= 1e-12 * np.abs(A_ref).max()
    assert np.array_equal(A, A.T)


def point_jacobian(model, data, frame, point):
    """The world velocity of the material point `point` (world) of frame `frame`'s body, from
    Pinocchio's joint Jacobian: v_o + omega x (p - o), 3 x nv (zeros for the universe)."""
    if frame == 0:
        return np.zeros((3, model.nv))
    joint = model.frames[frame].parentJoint
    Jj = pin.getJointJacobian(model, data, joint, pin.LOCAL_WORLD_ALIGNED)
    r = point - data.oMi[joint].translation
    skew = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    return Jj[:3] - skew @ Jj[3:]


def point_acceleration(model, data, frame, point):
    """The classical acceleration (world axes) of the material point `point` of frame `frame`'s body
    from Pinocchio's forward kinematics (at zero joint acceleration): R (a + alpha x r + omega x v_p)."""
    if frame == 0:
        return np.zeros(3)
    joint = model.frames[frame].parentJoint
    M = data.oMi[joint]
    r = M.actInv(point)
    vj, aj = data.v[joint], data.a[joint]
    v_point = vj.linear + np.cross(vj.angular, r)
    return M.rotation @ (aj.linear + np.cross(aj.angular, r) + np.cross(vj.angular, v_point))


def test_free_body_contact_rows_match_pinocchio():
    """The contact rows of free bodies (computed in closed form: R v - [R r]x R omega per point) equal
    the frame (t1, t2, n) times the relative point Jacobian from Pinocchio's own joint Jacobians of
    the whole world, for a tower's corners on the box below (both bodies move) at a moving state; and
    their drifts J' v (R omega x (v + omega x r)) the relative classical accelerations."""
    sim = Simulator(load_scene("box-tower-20"))
    sim.rollout(0.02)
    rng = np.random.default_rng(5)
    q = np.asarray(sim.data.q).copy()
    v = 0.3 * rng.standard_normal(sim.scene.model.nv)
    _core.build_contact_problem(sim.model, sim.data, q, v, 1e-3, 0.5)
    model = sim.scene.model
    data = model.createData()
    pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    J, drift = np.asarray(sim.data.J), np.asarray(sim.data.drift)
    halfspaces = sim.model.halfspaces
    row, checked = 0, 0
    for i in sim.data.active:
        c = sim.scene.contacts[i]
        h = halfspaces[c.halfspace]
        point = data.oMf[c.frame].act(np.asarray(c.offset))  # radius 0: the corner itself
        if h.frame:
            R = data.oMf[h.frame].rotation
            T = np.vstack([R @ h.tangent1, R @ h.tangent2, R @ h.normal])
        else:
            T = np.vstack([h.tangent1, h.tangent2, h.normal])
        rel = point_jacobian(model, data, c.frame, point) - point_jacobian(model, data, h.frame, point)
        np.testing.assert_allclose(J[row:row + 3], T @ rel, rtol=0, atol=1e-13)
        # the drift J' v: the corner's classical acceleration relative to the face's material point
        acc = point_acceleration(model, data, c.frame, point) - point_acceleration(model, data, h.frame, point)
        np.testing.assert_allclose(drift[row:row + 3], T @ acc, rtol=0, atol=1e-12)
        checked += h.frame != 0
        row += 3
    assert row == J.shape[0] and checked >= 60  # 19 interfaces of 4 corners between two moving boxes


@pytest.mark.parametrize("scene", ["solo12-stand", "talos-stand", "anymal-stand"])
def test_robot_contact_rows_match_pinocchio(scene):
    """A robot's contact rows (from the world-frame joint Jacobian of the step's kinematics: a
    column (v_o, omega) moves a point p at v_o + omega x p, over the joint's ancestors) equal the
    frame (t1, t2, n) times the point Jacobian from Pinocchio's own joint Jacobian of the whole
    model, at the material point of contact (sphere centre - r n), joints moved and moving."""
    sim = Simulator(load_scene(scene))
    sim.rollout(0.02)
    model = sim.scene.model
    rng = np.random.default_rng(6)
    q = np.asarray(sim.data.q).copy()
    for j in range(1, model.njoints):  # revolute joints moved 0.02 rad on average (the feet still touch)
        if model.joints[j].shortname() != "JointModelFreeFlyer":
            q[model.joints[j].idx_q] += 0.02 * rng.standard_normal()
    v = 0.3 * rng.standard_normal(model.nv)
    _core.build_contact_problem(sim.model, sim.data, q, v, 1e-3, 0.5)
    data = model.createData()
    pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    J = np.asarray(sim.data.J)
    halfspaces = sim.model.halfspaces
    row = 0
    for i in sim.data.active:
        c = sim.scene.contacts[i]
        h = halfspaces[c.halfspace]
        assert h.frame == 0  # the ground
        T = np.vstack([h.tangent1, h.tangent2, h.normal])
        point = data.oMf[c.frame].act(np.asarray(c.offset)) - c.radius * np.asarray(h.normal)
        expected = T @ point_jacobian(model, data, c.frame, point)
        np.testing.assert_allclose(J[row:row + 3], expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        row += 3
    assert row >= 12
    # then the joints' rows (docs/joint-rows.md): +e_dof (lower limit, friction, effort), -e_dof (upper limit)
    for kind, dof in sim.data.joint_rows:
        expected = np.zeros(model.nv)
        expected[dof] = -1.0 if kind == "upper_limit" else 1.0
        assert np.array_equal(J[row], expected), (kind, dof)
        row += 1
    assert row == J.shape[0]


def test_a_robots_operator_on_the_coordinates_its_contacts_move():
    """TALOS on its two soles: the contacts move the base and the legs, 18 of 38 coordinates; A is
    assembled from U, D and J restricted to those (their ancestors included) and equals
    J M^-1 J^T of the whole model, computed independently."""
    sim = Simulator(load_scene("talos-stand"), joint_friction=False, joint_limits=False, effort_limits=False)
    sim.rollout(0.02)
    q = np.asarray(sim.data.q).copy()
    v = 0.1 * np.random.default_rng(4).standard_normal(sim.scene.model.nv)
    _core.build_contact_problem(sim.model, sim.data, q, v, 1e-3, 0.5)
    J = np.asarray(sim.data.J)
    moved = np.flatnonzero(np.abs(J).max(axis=0))
    assert J.shape == (24, 38) and len(moved) == 18  # the free flyer and two legs of 6
    M_ref, _, A_ref = world_reference(sim, q, v)
    A = np.asarray(sim.data.A)
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
    from stiction.scene import build_scene

    grid = Simulator(load_scene("cube-grid-1024"))
    single = Simulator(build_scene({"array": {"layout": "grid", "count": 1}, "ground": {"mu": 0.5}}))
    grid.step()
    single.step()
    assert grid.data.sparse and not single.data.sparse
    assert grid.data.parts == 256
    A = np.asarray(grid.data.A)
    block = np.asarray(single.data.A)[:12, :12]
    assert A.shape == (3072, 3072)
    assert np.abs(A - np.kron(np.eye(256), block)).max() <= 1e-12 * np.abs(block).max()


@pytest.mark.parametrize("layout, cubes", [("grid", 36), ("tower", 16)])
def test_sparse_operator_updated_in_place_is_the_current_one(layout, cubes):
    """Cubes spinning on the ground, or on each other: A changes every step (the corners' lever arms
    turn) while the same contacts stay active, so the simulator refreshes its sparse operator's
    values in place (the grid: copied in; the tower, whose A is assembled by its plan: swapped in,
    and data.A read from the operator). Each step's impulses must satisfy the exact law for that
    step's operator (A and b assembled afresh from the parts) and not for the previous step's."""
    from stiction._core import Constraint, ContactProblem, residual
    from stiction.scene import build_scene

    sim = Simulator(build_scene({"array": {"layout": layout, "count": cubes}, "ground": {"mu": 0.3}}))
    v = np.asarray(sim.data.v).copy()
    v[5::6] = np.linspace(-4.0, 4.0, cubes)  # spin about z (each free body's last velocity row)
    v[0::6] = 0.2
    sim.set_state(v=v)
    cones = [Constraint.spatial_friction(0.3)] * (4 * cubes)
    previous = None
    for _ in range(30):
        sim.step()
        A, b, lam = np.asarray(sim.data.A), sim.dt * np.asarray(sim.data.b), np.asarray(sim.data.result.lam)
        assert sim.data.sparse and sim.data.result.converged
        nb = np.linalg.norm(b)  # the solver's promise: natural map <= 1e-10 ||b|| (residual: / (1 + ||b||))
        assert residual(ContactProblem(A, b, cones), lam) <= 1.01e-10 * nb / (1.0 + nb)
        if previous is not None:
            assert np.abs(A - previous[0]).max() > 1e-4 * np.abs(A).max()  # the operator moved
            assert residual(ContactProblem(previous[0], b, cones), lam) > 1e-6 * np.abs(b).max()
        previous = (A, b)


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
traj = sim.rollout(0.02)  # (shorter than the scene's settle_time: no summary)
print(json.dumps({"mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
                  "ok": bool(traj.converged[1:].all())}))
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


def _crate_slide_is_where_the_arm_stops(sim, traj):
    """The crate's slide against Pinocchio's kinematics and statics of the arm: the PD target puts
    the tool sphere's far side 0.1499 m beyond the crate's face (forward kinematics at q_target);
    at rest the tool touches the face (gap 0 from the crate's placement) and the arm is in static
    equilibrium, g(q) = kp (q_target - q) - kd v + g(q_target) + J^T F (F the face's force), so it
    stops short of its target by its compliance: measured slide 0.1468 m, 3.1e-3 m short; the
    equilibrium holds to 2.4e-4 N m of torques up to 45 N m."""
    sc, model = sim.scene, sim.scene.model
    data = model.createData()
    face = next(i for i, c in enumerate(sc.contacts) if c.name.startswith("tool0"))
    c, h = sc.contacts[face], sim.model.halfspaces[sc.contacts[face].halfspace]
    half = h.offset  # the face lies half the crate's size from its centre

    def tool_centre(q):
        pin.framesForwardKinematics(model, data, q)
        return data.oMf[c.frame].act(np.asarray(c.offset, float))

    q, q_target = traj.q[-1], traj.q[-1].copy()
    q_target[:6] = sc.q_target[:6]
    crate0 = traj.q[0, 6]
    nominal = tool_centre(q_target)[0] + c.radius + half - crate0
    slide = q[6] - crate0
    tool = tool_centre(q)
    oMface = data.oMf[h.frame]
    gap = float(np.dot(h.normal, oMface.actInv(tool)) - h.offset - c.radius)
    assert abs(gap) <= 1e-9  # touching
    assert slide == pytest.approx(tool[0] + c.radius + half - crate0, abs=5e-4)  # measured 1.1e-4 (crate yaw)
    assert 0.0 < nominal - slide < 0.01, (nominal, slide)  # short of the target, by the compliance
    # the arm's statics at rest, the face force on the tool at its contact point
    F = oMface.rotation @ np.column_stack([h.tangent1, h.tangent2, h.normal]) @ traj.lam[-1, face]
    point = tool - c.radius * (oMface.rotation @ np.asarray(h.normal))
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    J = pin.getFrameJacobian(model, data, c.frame, pin.LOCAL_WORLD_ALIGNED)
    J_point = J[:3] - pin.skew(point - data.oMf[c.frame].translation) @ J[3:]
    g, g_target = pin.computeGeneralizedGravity(model, data, q), pin.computeGeneralizedGravity(model, data, q_target)
    kp, kd = np.asarray(sc.kp)[:6], np.asarray(sc.kd)[:6]
    pd = kp * (q_target[:6] - q[:6]) - kd * traj.v[-1, :6]
    residual = g[:6] - (pd + g_target[:6] + (J_point.T @ F)[:6])
    assert np.abs(residual).max() <= 1e-2, residual


def test_ur5_pushes_a_free_crate():
    """A robot and a free body in one world (two parts coupled by the tool-face contact): the crate
    slides 14.7 cm along +x (where the arm's statics stop it), stays on the floor (no corner lifts more than a rocking of 3 mm), the
    face contact pushes (positive normal force) and A couples the face and floor contacts."""
    from stiction.scene import load_scene as load

    sim = Simulator(load("ur5-push-box"))
    assert sim.data.parts == 2
    traj = sim.rollout(sim.scene.duration)
    s = sim.summary(traj)
    assert s["all_converged"] and s["max_residual"] <= 1e-10
    crate = traj.q[:, 6:9]  # the crate's position (after the UR5's 6 joints)
    _crate_slide_is_where_the_arm_stops(sim, traj)
    assert abs(crate[-1, 1] - crate[0, 1]) < 0.01
    assert np.abs(crate[:, 2] - 0.15).max() < 3e-3
    assert np.abs(traj.v[-1, 6:]).max() < 1e-4 and np.abs(traj.v[-1]).max() < 1e-3  # at rest against the arm
    face = [i for i, c in enumerate(sim.scene.contacts) if c.name.startswith("tool0")]
    assert len(face) == 1
    assert traj.lam[1:, face[0], 2].max() > 1.0  # newtons, pushing (record 0: no step, NaN)
    sim2 = Simulator(load("ur5-push-box"))
    sim2.set_state(q=traj.q[200], v=traj.v[200])
    sim2.step()
    names = [sim2.scene.contacts[i].name for i in sim2.data.active]
    assert any(n.startswith("tool0") for n in names) and any(n.startswith("crate") for n in names)
    A, rows = np.asarray(sim2.data.A), np.cumsum([0] + [3] * len(names))
    k = next(i for i, n in enumerate(names) if n.startswith("tool0"))
    others = np.concatenate([np.arange(rows[i], rows[i + 1]) for i in range(len(names)) if i != k])
    assert np.abs(A[rows[k]:rows[k + 1]][:, others]).max() > 1e-3  # the crate couples the arm and the floor


def test_objects_are_checked():
    from stiction.scene import build_scene
    from stiction.scene_schema import SceneError

    base = {"robot": "ur5", "contacts": {"feet": False}, "objects": [{"name": "crate", "urdf": "crate.urdf",
                                                                       "xy": [0.8, 0.0]}]}
    with pytest.raises(SceneError, match="walls\\[0\\].body = 'crat'.*crate"):
        build_scene({**base, "walls": [{"body": "crat", "normal": [-1, 0, 0], "offset": 0.15, "frames": ["tool0"]}]})
    with pytest.raises(SceneError, match="objects: free boxes are added to `robot` or `urdf` scenes"):
        build_scene({"array": {"layout": "grid", "count": 2}, "objects": [{"name": "a", "xy": [0, 0]}]})
    with pytest.raises(SceneError, match="unique"):
        build_scene({**base, "objects": base["objects"] * 2})
    sc = build_scene(base)
    assert sc.model.nq == 6 + 7 and np.all(sc.kp[6:] == 0) and np.all(sc.tau_ff[6:] == 0)


def test_solo12_stands_still_on_a_free_board():
    """A robot standing on a free body (two parts, the feet on the board's top face, the board on
    the ground): the board does not move, the feet do not slip on it."""
    sim = Simulator(load_scene("solo12-on-board"))
    assert sim.data.parts == 2
    traj = sim.rollout(2.0)
    s = sim.summary(traj)
    assert s["all_converged"] and s["max_residual"] <= 1e-10
    board = traj.q[:, 19:22]  # after Solo-12's 19 coordinates
    assert np.abs(board - board[0]).max() < 1e-12
    assert s["max_foot_slip"] < 1e-9
    assert s["base_drift"] < 1e-7
    feet = [k for k, c in enumerate(sim.scene.contacts) if c.name.endswith("board top")]
    assert len(feet) == 4
    weight = 9.81 * sum(i.mass for i in sim.scene.model.inertias[1:-1])  # the robot (the board is last)
    assert abs(traj.lam[-1, feet, 2].sum() - weight) < 1e-3 * weight  # at rest the feet carry the robot


def test_joint_placements_match_pinocchio():
    sim = Simulator(load_scene("ur5-push-box"))
    traj = sim.rollout(0.3)
    P = sim.joint_placements(traj.q[[0, -1]])
    model = sim.scene.model
    data = model.createData()
    for row, k in enumerate((0, len(traj.t) - 1)):
        pin.forwardKinematics(model, data, traj.q[k])
        for j in range(model.njoints):
            assert np.allclose(P[row, j], data.oMi[j].homogeneous, atol=1e-14)


def test_recorded_poses_match_pinocchio():
    """The recorder's geometry poses (joint placements part by part) are what
    pinocchio.updateGeometryPlacements gives with a world Data: the UR5's meshes and the crate."""
    from stiction.recording import visual_poses

    sim = Simulator(load_scene("ur5-push-box"))
    traj = sim.rollout(0.3)
    model, vmodel = sim.scene.model, sim.scene.visual_model
    Q = traj.q[[0, 150, -1]]
    poses = visual_poses(vmodel, sim.joint_placements(Q))
    data, vdata = model.createData(), vmodel.createData()
    assert poses.shape == (3, len(vmodel.geometryObjects), 4, 4) and len(vmodel.geometryObjects) > 5
    for k, q in enumerate(Q):
        pin.forwardKinematics(model, data, q)
        pin.updateGeometryPlacements(model, data, vmodel, vdata)
        for g in range(len(vmodel.geometryObjects)):
            assert np.allclose(poses[k, g], vdata.oMg[g].homogeneous, atol=1e-14)


def test_recording_a_world_of_many_bodies(tmp_path):
    """pinocchio's visualizer would build a world Data (116 GB for 256 cubes): the recording takes
    its placements from the simulator's parts instead. Every cube and every contact's marker,
    stick and slip arrows are animated."""
    pytest.importorskip("meshcat")
    from stiction.recording import record_html as record

    sim = Simulator(load_scene("cube-grid-1024"))
    traj = sim.rollout(0.05)
    out = tmp_path / "grid.html"
    info = record(sim, traj, str(out))
    assert out.stat().st_size == info["bytes"]
    assert info["frames"] == 3  # 0, 20 and 40 ms at 50 fps
    assert info["tracks"] == 256 + 3 * 1024
    assert info["force_scale"] > 0


def test_a_tower_s_face_gaps_agree_corner_by_corner():
    """A 64-box tower (6.4 m): a corner's gap on the face of the box below is computed relative to
    that box (detect.cpp). In world coordinates each corner's gap rounded to the positions' size
    (9e-16 m at 6 m), corner by corner, and no motion fits such gaps: through Psi / delta^2 they put
    2e-10 m/s of b outside A's range, above the tolerance 1e-10 ||b||, and 7 steps in 1000 could not
    converge. Relative, the four corners of each face agree to 1e-16 m, b lies in the range of J to
    rounding, and every step converges. (The boxes' rounding-level tilt comes and goes: every 15
    steps or so a face's corners differ by up to 7e-16 m for a step, so the typical spread is
    measured, every 5 ms; world coordinates would put 4e-16 to 9e-16 m on some upper face at
    every step.)"""
    from stiction.scene import build_scene

    sim = Simulator(build_scene({"name": "tower-64", "array": {"layout": "tower", "count": 64}, "ground": {"mu": 0.5}}))
    upper_spreads = []
    for _ in range(30):
        traj = sim.rollout(0.005)
        assert traj.converged.all(), (traj.t[0], np.flatnonzero(~traj.converged))
        d = sim.data
        active = np.asarray(d.active)
        assert len(active) == 256
        faces = np.asarray(d.gaps)[active].reshape(64, 4)  # the ground's 4 corners, then each box's on the one below
        assert np.abs(faces).max() <= 1e-14
        spread = faces.max(axis=1) - faces.min(axis=1)
        upper_spreads.append(spread[32:].max())  # the upper half: 3.2 to 6.4 m
    assert np.median(upper_spreads) <= 1e-16, upper_spreads
    J, b = np.asarray(d.J), np.asarray(d.b)
    coef, *_ = np.linalg.lstsq(J, b, rcond=None)
    assert np.linalg.norm(b - J @ coef) <= 1e-12 * np.linalg.norm(b)

    lifted = Simulator(build_scene({"name": "box", "array": {"layout": "tower", "count": 1}, "ground": {"mu": 0.5}}))
    q = np.array(lifted.data.q)
    q[2] += 1e-9
    lifted.data.q = q
    lifted.step()
    np.testing.assert_allclose(np.asarray(lifted.data.position_error)[2::3], 1e-9, rtol=1e-6)


TOWER_OPERATOR = r"""
import sys, numpy as np
from stiction.scene import build_scene
from stiction.simulator import Simulator
sim = Simulator(build_scene({"name": "tower-16", "array": {"layout": "tower", "count": 16}, "ground": {"mu": 0.5}}))
sim.data.v = np.random.default_rng(3).uniform(-0.01, 0.01, sim.model.nv)  # a moving tower: no zero blocks
sim.step()
q, v = np.array(sim.data.q), np.array(sim.data.v)  # (the first step's solve uses the kernels too)
sim.step()  # the second step's A comes from the plan of the first's pattern
with open(sys.argv[1], "wb") as f:
    np.savez(f, A=np.asarray(sim.data.A), q=q, v=v)
"""


@pytest.mark.parametrize("kernels", ["0", "1"])
def test_the_tower_operator_is_the_same_with_and_without_vector_kernels(tmp_path, kernels):
    """Free bodies' 3 x 3 blocks of a sparse A are assembled by an AVX2/FMA kernel where the processor
    has it (STICTION_VECTOR_KERNELS=0 turns it off): either way A equals the whole world's J M^-1 J^T
    from Pinocchio's Python bindings, and is exactly symmetric."""
    import os

    out = tmp_path / "A.npy"
    env = dict(os.environ, STICTION_VECTOR_KERNELS=kernels)
    subprocess.run([sys.executable, "-c", TOWER_OPERATOR, str(out)], check=True, env=env)
    saved = np.load(out)
    A, q, v = saved["A"], saved["q"], saved["v"]
    # the reference at the subprocess's own state
    from stiction.scene import build_scene

    sim = Simulator(build_scene({"name": "tower-16", "array": {"layout": "tower", "count": 16}, "ground": {"mu": 0.5}}))
    sim.data.q, sim.data.v = q, v
    sim.step()
    assert sim.data.sparse
    _, _, reference = world_reference(sim, q, v)
    assert A.shape == reference.shape == (192, 192)
    np.testing.assert_array_equal(A, A.T)
    np.testing.assert_allclose(A, reference, rtol=0, atol=1e-12 * np.abs(reference).max())


def test_a_wrong_vector_kernel_switch_is_an_error():
    import os

    env = dict(os.environ, STICTION_VECTOR_KERNELS="yes")
    out = subprocess.run([sys.executable, "-c", TOWER_OPERATOR, "/dev/null"], capture_output=True, text=True, env=env)
    assert out.returncode != 0 and "STICTION_VECTOR_KERNELS must be 0 or 1, got 'yes'" in out.stderr
