"""The Delassus operator A = J M^-1 J^T (eq. 22) the simulator builds, checked independently."""
import numpy as np
import pinocchio as pin
import pytest

from stiction import _core
from stiction.scene import build_scene
from stiction.simulator import Simulator


def built(sim, q=None, v=None):
    q = sim.scene.q0 if q is None else q
    v = np.zeros(sim.scene.model.nv) if v is None else v
    _core.build_contact_problem(sim.model, sim.data, q, v, 1e-3, 0.5)
    return sim.data


@pytest.fixture(scope="module")
def solo():
    sim = Simulator("solo12-stand")
    q = sim.scene.q0.copy()
    q[7:] += np.random.default_rng(3).uniform(-0.2, 0.2, 12)  # a generic posture
    q[3:7] = pin.Quaternion(pin.utils.rpyToMatrix(0.05, -0.1, 0.3)).coeffs()
    sim.scene.q0 = q
    return sim, q


def test_symmetric_positive_semidefinite(solo):
    sim, q = solo
    d = built(sim, q)
    A = d.A
    assert A.shape == (3 * len(d.active), 3 * len(d.active))
    np.testing.assert_allclose(A, A.T, atol=1e-14)
    assert np.linalg.eigvalsh(A).min() > -1e-12


def test_equals_brute_force_J_Minv_Jt(solo):
    """J by central finite differences of the contact points on the configuration
    manifold, M from Pinocchio's crba: A = J M^-1 J^T to 1e-6."""
    sim, q = solo
    d = built(sim, q)
    model = sim.scene.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q)
    # material points: the sphere bottoms at q, fixed in their frames
    locals_ = []
    for i in d.active:
        c = sim.scene.contacts[i]
        p_world = data.oMf[c.frame].act(np.asarray(c.offset)) - c.radius * np.array([0, 0, 1.0])
        locals_.append((c.frame, data.oMf[c.frame].actInv(p_world)))

    def points(qq):
        pin.framesForwardKinematics(model, data, qq)
        return np.concatenate([data.oMf[f].act(p) for f, p in locals_])

    eps = 1e-6
    J = np.zeros((3 * len(locals_), model.nv))
    for k in range(model.nv):
        e = np.zeros(model.nv)
        e[k] = eps
        J[:, k] = (points(pin.integrate(model, q, e)) - points(pin.integrate(model, q, -e))) / (2 * eps)
    np.testing.assert_allclose(J, d.J, atol=1e-7)  # flat ground: rows (x, y, z) = (t1, t2, n)
    M = pin.crba(model, model.createData(), q)
    M = np.triu(M) + np.triu(M, 1).T
    A_bf = J @ np.linalg.solve(M, J.T)
    np.testing.assert_allclose(d.A, A_bf, rtol=1e-6, atol=1e-6 * np.abs(A_bf).max())


def test_equals_pinocchio_delassus_routes(solo):
    """Pinocchio's computeDelassusMatrix (3D contacts whose frames are world-aligned)
    agrees with stiction's A to round-off."""
    sim, q = solo
    d = built(sim, q)
    model = sim.scene.model
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    rcms = pin.StdVec_RigidConstraintModel()
    for i in d.active:
        c = sim.scene.contacts[i]
        frame = model.frames[c.frame]
        p_world = data.oMi[frame.parentJoint].act(frame.placement.act(np.asarray(c.offset))) - c.radius * np.array([0, 0, 1.0])
        oMi = data.oMi[frame.parentJoint]
        # a contact frame at the point with world-aligned axes, expressed in the joint frame
        placement = pin.SE3(oMi.rotation.T, oMi.actInv(p_world))
        rcms.append(pin.RigidConstraintModel(pin.ContactType.CONTACT_3D, model, frame.parentJoint, placement,
                                             0, pin.SE3(np.eye(3), p_world), pin.ReferenceFrame.LOCAL))
    rcds = pin.StdVec_RigidConstraintData()
    for m in rcms:
        rcds.append(m.createData())
    A_pin = pin.computeDelassusMatrix(model, data, q, rcms, rcds, 0.0)
    np.testing.assert_allclose(d.A, A_pin, rtol=1e-9, atol=1e-10 * np.abs(A_pin).max())


def test_rank_drops_with_redundant_contacts():
    """All 8 corners of a cube in the problem: A is 24 x 24 of rank 6 (the cube's DOFs)."""
    sc = build_scene({"urdf": "cube.urdf", "contacts": {"box_corners": True}})
    sim = Simulator(sc)
    s = sim.model.settings
    s.activation_distance = 1.0  # include the 4 top corners too
    model = _core.SimulatorModel(sc.model, sc.halfspaces, sc.contacts, [], s)
    data = _core.SimulatorData(model)
    _core.build_contact_problem(model, data, sc.q0, np.zeros(6), 1e-3, 0.5)
    A = data.A
    assert A.shape == (24, 24)
    assert np.linalg.matrix_rank(A, tol=1e-10 * np.abs(A).max()) == 6
    sim_bottom = Simulator(sc)
    assert np.linalg.matrix_rank(built(sim_bottom).A, tol=1e-10) == 6  # 4 corners, 12 rows


def test_eigenvalues_invariant_to_a_yaw_of_the_robot(solo):
    """Turning the robot about the vertical rotates every contact's tangent basis
    relative to the body: the spectrum of A must not change."""
    sim, q = solo
    ev = np.linalg.eigvalsh(built(sim, q).A)
    q2 = q.copy()
    R = pin.utils.rotate("z", 0.7) @ pin.Quaternion(q[3:7]).matrix()
    q2[3:7] = pin.Quaternion(R).coeffs()
    q2[:3] = pin.utils.rotate("z", 0.7) @ q[:3]
    ev2 = np.linalg.eigvalsh(built(sim, q2).A)
    np.testing.assert_allclose(ev, ev2, rtol=1e-10, atol=1e-12 * ev.max())


def test_unit_impulse_response_is_a_column_of_A(solo):
    """Apply the generalized force J^T e_i (no gravity, zero velocity) through Pinocchio's
    ABA: the contact velocity change J M^-1 J^T e_i is column i of A."""
    sim, q = solo
    d = built(sim, q)
    model = sim.scene.model.copy()
    model.gravity = pin.Motion.Zero()
    data = model.createData()
    J, A = d.J, d.A
    for i in range(A.shape[0]):
        e = np.zeros(A.shape[0])
        e[i] = 1.0
        ddq = pin.aba(model, data, q, np.zeros(model.nv), J.T @ e)
        np.testing.assert_allclose(J @ ddq, A[:, i], rtol=1e-9, atol=1e-10 * np.abs(A).max())


def test_equals_pinocchio_constraint_cholesky_route(solo):
    """Pinocchio's constraint Cholesky (ContactCholeskyDecomposition on point contacts, the
    route its own solvers use) gives the same Delassus operator, up to its 1e-12 damping."""
    sim, q = solo
    d = built(sim, q)
    model = sim.scene.model
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    pin.computeJointJacobians(model, data, q)
    pin.crba(model, data, q)
    cms = pin.StdVec_ConstraintModel()
    for i in d.active:
        c = sim.scene.contacts[i]
        frame = model.frames[c.frame]
        j = frame.parentJoint
        p_world = data.oMi[j].act(frame.placement.act(np.asarray(c.offset))) - c.radius * np.array([0, 0, 1.0])
        cms.append(pin.PointContactConstraintModel(model, 0, pin.SE3(np.eye(3), p_world), j,
                                                   pin.SE3(np.eye(3), data.oMi[j].actInv(p_world))))
    cds = pin.StdVec_ConstraintData()
    for cm in cms:
        cds.append(cm.createData())
    for cm, cd in zip(cms, cds):
        cm.calc(model, data, cd)  # required before the decomposition (Pinocchio 4.1)
    chol = pin.ContactCholeskyDecomposition(model, data, cms, cds)
    chol.compute(model, data, cms, cds, 1e-12)
    G = chol.getDelassusOperatorCholeskyExpression().matrix()
    np.testing.assert_allclose(d.A, G, atol=1e-10 * np.abs(G).max())
