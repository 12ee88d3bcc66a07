"""The fused kinematics pass of a robot part (src/cpp/sim/tree.cpp): placements, the world-frame
joint Jacobian, velocities and bias accelerations of every joint kind it handles (free flyer,
revolute and prismatic about x, y, z or a tilted axis, tilted joint placements) in one pass, and
from them M (armature included) and nle in one backward pass. Checked against Pinocchio's own
crba, nonLinearEffects, joint Jacobians and forward kinematics on a random tree; a tree with a
joint the pass does not handle (spherical) takes Pinocchio's pass and must agree as well."""
import numpy as np
import pinocchio as pin
import pytest

from stiction import _core
from stiction.scene import load_scene
from stiction.simulator import Simulator
from test_world_parts import point_acceleration, point_jacobian


def random_tree(rng, with_spherical, armature):
    """A free-flying base with two branches of three joints of mixed kinds, tilted placements,
    random inertias; a sphere of radius 0.05 at the end of each branch (frames 'tip0', 'tip1')."""
    model = pin.Model()

    def placement():
        return pin.SE3(pin.rpy.rpyToMatrix(*rng.uniform(-1.0, 1.0, 3)), 0.3 * rng.standard_normal(3))

    def axis():
        a = rng.standard_normal(3)
        return a / np.linalg.norm(a)

    base = model.addJoint(0, pin.JointModelFreeFlyer(), placement(), "base")
    model.appendBodyToJoint(base, pin.Inertia.Random(), pin.SE3.Identity())
    branches = [
        [pin.JointModelRX(), pin.JointModelRevoluteUnaligned(axis()), pin.JointModelPZ()],
        [pin.JointModelRZ(), pin.JointModelPrismaticUnaligned(axis()),
         pin.JointModelSpherical() if with_spherical else pin.JointModelRY()],
    ]
    for b, kinds in enumerate(branches):
        parent = base
        for k, joint in enumerate(kinds):
            parent = model.addJoint(parent, joint, placement(), f"j{b}{k}")
            model.appendBodyToJoint(parent, pin.Inertia.Random(), pin.SE3.Identity())
        model.addFrame(pin.Frame(f"tip{b}", parent, placement(), pin.FrameType.OP_FRAME))
    model.armature[:] = armature
    return model


@pytest.mark.parametrize("with_spherical", [False, True], ids=["fused", "pinocchio-pass"])
@pytest.mark.parametrize("armature", [0.0, 0.25])
def test_random_tree_against_pinocchio(with_spherical, armature):
    rng = np.random.default_rng(7 + int(with_spherical))
    model = random_tree(rng, with_spherical, armature)
    ground = _core.HalfSpace()
    ground.name, ground.normal, ground.offset = "ground", np.array([0.1, -0.2, 1.0]), -100.0
    contacts = []
    for b in range(2):
        c = _core.SphereContact()
        c.name, c.frame, c.offset, c.radius = f"tip{b}", model.getFrameId(f"tip{b}"), np.zeros(3), 0.05
        c.halfspace, c.mu = 0, 0.7
        contacts.append(c)
    settings = Simulator(load_scene("solo12-stand")).model.settings
    settings.activation_distance = 1e3  # both spheres in the problem wherever they are
    sim = _core.SimulatorModel(model, [ground], contacts, [], settings)
    data = _core.SimulatorData(sim)
    for trial in range(3):
        q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        v = rng.standard_normal(model.nv)
        _core.build_contact_problem(sim, data, q, v, 1e-3, 0.5)

        ref = model.createData()
        M_ref = pin.crba(model, ref, q)
        M_ref = np.triu(M_ref) + np.triu(M_ref, 1).T
        nle_ref = pin.nonLinearEffects(model, ref, q, v)
        assert np.abs(np.asarray(data.M) - M_ref).max() <= 1e-12 * np.abs(M_ref).max()
        assert np.abs(np.asarray(data.nle) - nle_ref).max() <= 1e-12 * np.abs(nle_ref).max()

        pin.forwardKinematics(model, ref, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, ref, q)
        pin.updateFramePlacements(model, ref)
        n = np.asarray(sim.halfspaces[0].normal)
        T = np.vstack([sim.halfspaces[0].tangent1, sim.halfspaces[0].tangent2, n])
        J, drift = np.asarray(data.J), np.asarray(data.drift)
        assert J.shape == (6, model.nv)
        for b, c in enumerate(contacts):
            centre = ref.oMf[c.frame].translation
            point = centre - c.radius * n  # the material point of contact
            rows = slice(3 * b, 3 * b + 3)
            expected_J = T @ point_jacobian(model, ref, c.frame, point)
            np.testing.assert_allclose(J[rows], expected_J, rtol=0, atol=1e-12 * np.abs(expected_J).max())
            # drift J' v: tangential rows the contact point's, the normal row the centre's
            acc_point = point_acceleration(model, ref, c.frame, point)
            acc_centre = point_acceleration(model, ref, c.frame, centre)
            expected = np.array([T[0] @ acc_point, T[1] @ acc_point, n @ acc_centre])
            np.testing.assert_allclose(drift[rows], expected, rtol=0, atol=1e-11 * max(1.0, np.abs(expected).max()))
            # the gap: the sphere's lowest point above the plane (n made unit by the model)
            assert data.gaps[b] == pytest.approx(n @ centre - c.radius - ground.offset, abs=1e-12 * 100)


def test_solo_drift_matches_pinocchio_at_a_moving_state():
    """Solo-12's contact rows' drifts J' v (from the fused pass's world-frame velocities and bias
    accelerations) against Pinocchio's classical accelerations, joints moved and moving."""
    sim = Simulator(load_scene("solo12-stand"))
    sim.rollout(0.02)
    model = sim.scene.model
    rng = np.random.default_rng(9)
    q = np.asarray(sim.data.q).copy()
    q[7:] += 0.02 * rng.standard_normal(model.nq - 7)
    v = 0.5 * rng.standard_normal(model.nv)
    _core.build_contact_problem(sim.model, sim.data, q, v, 1e-3, 0.5)
    ref = model.createData()
    pin.forwardKinematics(model, ref, q, v, np.zeros(model.nv))
    pin.updateFramePlacements(model, ref)
    drift = np.asarray(sim.data.drift)
    row = 0
    for i in sim.data.active:
        c = sim.scene.contacts[i]
        h = sim.model.halfspaces[c.halfspace]
        n = np.asarray(h.normal)
        centre = ref.oMf[c.frame].act(np.asarray(c.offset))
        point = centre - c.radius * n
        acc_point = point_acceleration(model, ref, c.frame, point)
        expected = np.array([h.tangent1 @ acc_point, h.tangent2 @ acc_point,
                             n @ point_acceleration(model, ref, c.frame, centre)])
        np.testing.assert_allclose(drift[row:row + 3], expected, rtol=0, atol=1e-12 * np.abs(expected).max())
        row += 3
    assert row == 12


ROBOT_OPERATOR = r"""
import sys
import numpy as np, pinocchio as pin
from stiction import _core
from stiction.scene import load_scene
from stiction.simulator import Simulator
sys.path.insert(0, sys.argv[2])
from test_tree_kinematics import random_tree
out = {}
# Solo-12 and TALOS (its arms out of every chain), moving
for name in ("solo12-stand", "talos-stand"):
    sim = Simulator(load_scene(name))
    sim.rollout(0.01)
    rng = np.random.default_rng(4)
    v = 0.3 * rng.standard_normal(sim.model.nv)
    _core.build_contact_problem(sim.model, sim.data, np.asarray(sim.data.q), v, 1e-3, 0.5)
    out[name] = (np.asarray(sim.data.J), np.asarray(sim.data.A), np.asarray(sim.data.M))
# a random tree: tip0 on the ground (its chain: base and branch 0), tip1 against a half-space carried
# by tip0's body (rows between two limbs: not one root path, so the general operator)
rng = np.random.default_rng(12)
model = random_tree(rng, False, 0.0)
ground = _core.HalfSpace()
ground.name, ground.normal, ground.offset = "ground", np.array([0.0, 0.0, 1.0]), -100.0
wall = _core.HalfSpace()
wall.name, wall.normal, wall.offset, wall.frame = "wall", np.array([0.3, 1.0, 0.2]), -100.0, model.getFrameId("tip0")
contacts = []
for b, h in ((0, 0), (1, 1)):
    c = _core.SphereContact()
    c.name, c.frame, c.offset, c.radius, c.halfspace, c.mu = f"tip{b}", model.getFrameId(f"tip{b}"), np.zeros(3), 0.05, h, 0.5
    contacts.append(c)
settings = Simulator(load_scene("solo12-stand")).model.settings
settings.activation_distance = 1e3
# blocks of 1 and 2 rows: frictionless and planar contacts on the two branches
rows12 = []
for b, (mu, planar) in enumerate(((0.0, False), (0.4, True))):
    c = _core.SphereContact()
    c.name, c.frame, c.offset, c.radius, c.halfspace, c.mu = f"tip{b}", model.getFrameId(f"tip{b}"), np.zeros(3), 0.05, 0, mu
    c.planar = planar
    rows12.append(c)
for tag, halfspaces, cs in (("tree", [ground], [contacts[0]]), ("two-limbs", [ground, wall], contacts),
                            ("rows-1-2", [ground], rows12)):
    sim = _core.SimulatorModel(model, halfspaces, cs, [], settings)
    data = _core.SimulatorData(sim)
    q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
    _core.build_contact_problem(sim, data, q, rng.standard_normal(model.nv), 1e-3, 0.5)
    out[tag] = (np.asarray(data.J), np.asarray(data.A), np.asarray(data.M))
np.savez(sys.argv[1], **{f"{k}_{i}": a for k, v in out.items() for i, a in enumerate(v)})
"""


@pytest.mark.parametrize("kernels", ["0", "1"])
def test_robot_operator_by_chains(tmp_path, kernels):
    """A robot that is the whole problem gets A = J M^-1 J^T from its tree's chains (each contact's
    root path; two contacts share their common ancestor's): equal to J M^-1 J^T of the step's own J
    and M, exactly symmetric, with the AVX2 kernel and with the portable loops; a contact between
    two of the robot's limbs (not one root path) takes the general operator."""
    import os
    import pathlib
    import subprocess
    import sys

    out = tmp_path / "ops.npz"
    env = dict(os.environ, STICTION_VECTOR_KERNELS=kernels)
    run = subprocess.run([sys.executable, "-c", ROBOT_OPERATOR, str(out), str(pathlib.Path(__file__).parent)],
                         capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr
    saved = np.load(out)
    for tag in ("solo12-stand", "talos-stand", "tree", "two-limbs", "rows-1-2"):
        J, A, M = saved[f"{tag}_0"], saved[f"{tag}_1"], saved[f"{tag}_2"]
        reference = J @ np.linalg.solve(M, J.T)
        assert A.shape == reference.shape and A.shape[0] == (3 if tag == "rows-1-2" else A.shape[0]) >= 3
        np.testing.assert_array_equal(A, A.T)
        np.testing.assert_allclose(A, reference, rtol=0, atol=1e-12 * np.abs(reference).max())


@pytest.mark.parametrize("base_kp", [0.0, 3.0])
def test_joint_pd_torque_against_pinocchio_difference(base_kp):
    """tau = kp (q_target (-) q) + kd (v_target - v) + tau_ff: revolute joints by q_target - q and a free
    base without stiffness skipped (its log6 unused), or, with a stiffness on the base, Pinocchio's
    difference on the manifold: both equal the formula with pinocchio.difference."""
    sim = Simulator(load_scene("solo12-stand"))
    model = sim.scene.model
    rng = np.random.default_rng(8)
    kp = np.array(sim.data.kp)
    kp[:6] = base_kp
    sim.data.kp = kp
    q_target = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
    sim.data.q_target = q_target
    q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
    v = rng.standard_normal(model.nv)
    _core.build_contact_problem(sim.model, sim.data, q, v, 1e-3, 0.5)
    expected = kp * pin.difference(model, q, q_target) + np.asarray(sim.data.kd) * (
        np.asarray(sim.data.v_target) - v) + np.asarray(sim.data.tau_ff)
    np.testing.assert_allclose(np.asarray(sim.data.tau), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


JOINT_ANGLES = r"""
import sys
import numpy as np, pinocchio as pin
from stiction import _core
from stiction.scene import load_scene
from stiction.simulator import Simulator
sys.path.insert(0, sys.argv[2])
from test_world_parts import point_jacobian
# a fixed-base arm of five revolute joints (x, z, y, z, tilted: one lane of the last group of four
# used), each 0.4 m from the last, a sphere at the tip
model = pin.Model()
parent = 0
for k, joint in enumerate([pin.JointModelRX(), pin.JointModelRZ(), pin.JointModelRY(), pin.JointModelRZ(),
                           pin.JointModelRevoluteUnaligned(np.array([0.6, 0.0, 0.8]))]):
    parent = model.addJoint(parent, joint, pin.SE3(np.eye(3), np.array([0.4, 0.1 * k, 0.0])), f"j{k}")
    model.appendBodyToJoint(parent, pin.Inertia.Random(), pin.SE3.Identity())
model.addFrame(pin.Frame("tip", parent, pin.SE3(np.eye(3), np.array([0.4, 0.0, 0.0])), pin.FrameType.OP_FRAME))
ground = _core.HalfSpace()
ground.name, ground.normal, ground.offset = "ground", np.array([0.0, 0.0, 1.0]), -100.0
c = _core.SphereContact()
c.name, c.frame, c.offset, c.radius, c.halfspace, c.mu = "tip", model.getFrameId("tip"), np.zeros(3), 0.05, 0, 0.5
settings = Simulator(load_scene("solo12-stand")).model.settings
settings.activation_distance = 1e3
sim = _core.SimulatorModel(model, [ground], [c], [], settings)
data = _core.SimulatorData(sim)
worst = 0.0
# angles small and large, both signs, on and off the multiples of pi / 2 (where the argument
# reduction of sin and cos is hardest)
rng = np.random.default_rng(3)
angles = [np.zeros(5), np.full(5, np.pi / 2), np.array([1e-9, -np.pi, 3 * np.pi / 2, 1e3, -1e5]),
          np.array([1e8, -7.0, 0.5, 2e4 * np.pi, 1.0])] + [rng.uniform(-20, 20, 5) for _ in range(20)]
for q in angles:
    _core.build_contact_problem(sim, data, q, np.zeros(5), 1e-3, 0.5)
    ref = model.createData()
    pin.forwardKinematics(model, ref, q)
    pin.computeJointJacobians(model, ref, q)
    pin.updateFramePlacements(model, ref)
    point = ref.oMf[c.frame].translation - c.radius * np.array([0.0, 0.0, 1.0])
    expected = np.vstack([sim.halfspaces[0].tangent1, sim.halfspaces[0].tangent2, [0.0, 0.0, 1.0]]) @ \
        point_jacobian(model, ref, c.frame, point)
    worst = max(worst, np.abs(np.asarray(data.J) - expected).max() / np.abs(expected).max())
    worst = max(worst, abs(data.gaps[0] - (point[2] + 100.0)) / 100.0)  # (the gap's scale: the offset)
print(worst)
"""


@pytest.mark.parametrize("kernels", ["0", "1"])
def test_joint_sines_and_cosines_at_any_angle(kernels):
    """The fused pass takes every revolute joint's sine and cosine before the pass, four lanes at a
    time where the processor has AVX2 (glibc's libmvec, within 4 ulp) and one at a time otherwise:
    the contact rows and gap of an arm of five revolute joints (the last group of four one lane
    full) equal Pinocchio's (scalar sincos) to 5e-15, at angles up to 1e8 rad and at multiples of
    pi / 2."""
    import os
    import pathlib
    import subprocess
    import sys

    env = dict(os.environ, STICTION_VECTOR_KERNELS=kernels)
    run = subprocess.run([sys.executable, "-c", JOINT_ANGLES, "", str(pathlib.Path(__file__).parent)],
                         capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr
    assert float(run.stdout.split()[-1]) <= 5e-15, run.stdout  # (measured: 7e-16 scalar, 9e-16 libmvec)


@pytest.mark.parametrize("kernels", ["0", "1"])
def test_velocity_update_by_the_chains(kernels):
    """A robot whose A came from its chains takes M^-1 J^T P from the same Y = D^-1/2 U^-1 J^T
    (one back substitution, dynamics.cpp): v+ = v + h M^-1 (tau - nle) + M^-1 J^T P against numpy's
    solves with the step's own M, J, nle, tau and impulses, for Solo-12 moving (both kernel paths:
    Y from the AVX2 kernel and from the portable loops). The base's linear velocity is re-expressed
    in its turned frame after the update, so it is checked through the contact velocities J v+."""
    import os
    import subprocess
    import sys

    script = r"""
import numpy as np
from stiction import _core
from stiction.simulator import Simulator
sim = Simulator("solo12-stand")
sim.rollout(0.1)
rng = np.random.default_rng(5)
sim.data.v = np.asarray(sim.data.v) + 0.05 * rng.standard_normal(sim.model.nv)
v0 = np.asarray(sim.data.v).copy()
rec = _core.rollout(sim.model, sim.data, 1, 1)
h = sim.model.settings.dt
J, M, nle, tau = (np.asarray(x) for x in (sim.data.J, sim.data.M, sim.data.nle, sim.data.tau))
P = np.asarray(sim.data.result.lam)
assert J.shape == (12, 18) and np.abs(P).max() > 0
turn = np.zeros_like(v0)
turn[:3] = h * np.cross(v0[3:6], v0[:3])  # the base's frame turn (integrate.cpp, addFrameTurn)
impulse = np.linalg.solve(M, J.T @ P)
vplus = v0 + h * np.linalg.solve(M, tau - nle) + turn + impulse
joints = np.abs(np.asarray(rec["v"])[1][3:] - vplus[3:]).max() / np.abs(impulse).max()
rows = np.abs(np.asarray(rec["contact_velocity"]).reshape(2, -1)[1][:12] - J @ vplus).max() / np.abs(J @ impulse).max()
print(joints, rows)
"""
    env = dict(os.environ, STICTION_VECTOR_KERNELS=kernels)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env)
    assert run.returncode == 0, run.stderr
    joints, rows = (float(x) for x in run.stdout.split())
    assert joints <= 1e-13 and rows <= 1e-13, (joints, rows)
