"""What the simulator refuses about joints and configurations, and why: a joint about any axis
with a non-unit axis (Pinocchio uses the axis as given, so its own M, nle and J then describe no
rigid body), a mass matrix that is not positive definite (a massless link), and a quaternion that
is not a unit one (set_state, a scene's initial.q, SimulatorData.q). A unit axis about any
direction still matches Pinocchio's crba, nonLinearEffects and Jacobians, with either
rigid_body_passes."""
import numpy as np
import pinocchio as pin
import pytest

from stiction import _core
from stiction.scene import build_scene
from stiction.simulator import Simulator
from test_world_parts import point_jacobian

TILTED = np.array([0.0, 1.0, 1.0])  # |axis| = sqrt 2


def arm(second_joint, name="arm", tip_inertia=None):
    """A fixed-base arm: a revolute 'shoulder' about z carrying `second_joint` ('elbow'), a tip
    frame 0.4 m out on the elbow's body."""
    model = pin.Model()
    model.name = name
    shoulder = model.addJoint(0, pin.JointModelRZ(), pin.SE3.Identity(), "shoulder")
    model.appendBodyToJoint(shoulder, pin.Inertia(2.0, np.array([0.3, 0.0, 0.0]), np.diag([0.01, 0.02, 0.03])),
                            pin.SE3.Identity())
    placement = pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.2, 0.5), np.array([0.6, 0.1, -0.05]))
    elbow = model.addJoint(shoulder, second_joint, placement, "elbow")
    rotational = np.array([[0.03, 0.002, -0.001], [0.002, 0.02, 0.003], [-0.001, 0.003, 0.04]])
    inertia = tip_inertia if tip_inertia is not None else pin.Inertia(1.5, np.array([0.2, -0.05, 0.1]), rotational)
    model.appendBodyToJoint(elbow, inertia, pin.SE3.Identity())
    model.addFrame(pin.Frame("tip", elbow, pin.SE3(np.eye(3), np.array([0.4, 0.0, 0.0])), pin.FrameType.OP_FRAME))
    return model


@pytest.mark.parametrize("kind", ["RevoluteUnaligned", "PrismaticUnaligned", "HelicalUnaligned"])
def test_a_non_unit_joint_axis_is_refused_naming_the_joint_robot_part_and_axis(kind):
    # Pinocchio itself takes the axis as given: with (0, 1, 1) its revolute "rotation" is not one
    if kind == "RevoluteUnaligned":
        model = arm(pin.JointModelRevoluteUnaligned(TILTED))
        data = model.createData()
        pin.forwardKinematics(model, data, np.array([0.0, 0.7]))
        assert np.linalg.det(data.oMi[2].rotation) == pytest.approx(1.75, abs=0.01)
    extra = (0.1,) if kind == "HelicalUnaligned" else ()  # (its pitch)
    model = arm(getattr(pin, f"JointModel{kind}")(TILTED, *extra))
    with pytest.raises(ValueError) as info:
        _core.SimulatorModel(model, [], [], [], _core.SimulatorSettings())
    message = str(info.value)
    assert f"joint 'elbow' (JointModel{kind}) of robot 'arm' (part 'shoulder'): axis (0, 1, 1) has norm " \
           "1.4142135623730951, not 1" in message
    assert "axis / |axis|" in message


@pytest.mark.parametrize("passes", ["fused", "pinocchio"])
@pytest.mark.parametrize("kind", ["RevoluteUnaligned", "PrismaticUnaligned"])
def test_a_unit_tilted_axis_matches_pinocchio(kind, passes):
    """M, nle (crba, rnea), the contact rows J (Pinocchio's joint Jacobians) and A = J M^-1 J^T at
    random states, to 1e-12 relative."""
    model = arm(getattr(pin, f"JointModel{kind}")(TILTED / np.linalg.norm(TILTED)))
    ground = _core.HalfSpace()
    ground.name, ground.normal, ground.offset = "ground", np.array([0.2, 0.1, 1.0]), -10.0
    tip = _core.SphereContact()
    tip.name, tip.frame, tip.offset, tip.radius, tip.halfspace, tip.mu = "tip", model.getFrameId("tip"), np.zeros(3), \
        0.0, 0, 0.5
    settings = _core.SimulatorSettings()
    settings.activation_distance = 100.0  # the tip in the problem wherever it is
    settings.rigid_body_passes = passes
    sim = _core.SimulatorModel(model, [ground], [tip], [], settings)
    assert sim.settings.rigid_body_passes == passes  # (the setting reached the C++ model)
    data = _core.SimulatorData(sim)
    rng = np.random.default_rng(11)
    for _ in range(4):
        q, v = rng.uniform(-2.0, 2.0, model.nq), rng.standard_normal(model.nv)
        _core.build_contact_problem(sim, data, q, v, 1e-3, 0.5)
        ref = model.createData()
        M = pin.crba(model, ref, q)
        M = np.triu(M) + np.triu(M, 1).T
        nle = pin.nonLinearEffects(model, ref, q, v)
        np.testing.assert_allclose(data.M, M, rtol=0, atol=1e-12 * np.abs(M).max())
        np.testing.assert_allclose(data.nle, nle, rtol=0, atol=1e-12 * np.abs(nle).max())
        pin.computeJointJacobians(model, ref, q)
        pin.updateFramePlacements(model, ref)
        h = sim.halfspaces[0]
        T = np.vstack([h.tangent1, h.tangent2, h.normal])
        J = T @ point_jacobian(model, ref, tip.frame, ref.oMf[tip.frame].translation)
        np.testing.assert_allclose(data.J, J, rtol=0, atol=1e-12 * np.abs(J).max())
        A = J @ np.linalg.solve(M, J.T)
        np.testing.assert_allclose(data.A, A, rtol=0, atol=1e-12 * np.abs(A).max())


@pytest.mark.parametrize("passes", ["fused", "pinocchio"])
def test_a_massless_link_is_named_with_the_usual_causes(passes):
    """A massless last link: the elbow's subtree has no inertia, M is singular (its pivot 0)."""
    model = arm(pin.JointModelRY(), name="arm", tip_inertia=pin.Inertia.Zero())
    settings = _core.SimulatorSettings()
    settings.rigid_body_passes = passes
    sim = _core.SimulatorModel(model, [], [], [], settings)
    data = _core.SimulatorData(sim)
    with pytest.raises(RuntimeError) as info:
        _core.step(sim, data)
    message = str(info.value)
    assert message.startswith("the mass matrix of robot 'arm' (part 'shoulder') is not positive definite at this "
                              "configuration: pivot 0 at its velocity coordinate 1 (joint 'elbow')")
    for cause in ("massless link", "subtree has no inertia", "zero armature", "model.armature"):
        assert cause in message
    # the cause named is the cause: an armature on the elbow makes M positive definite
    model.armature[1] = 1e-3
    sim = _core.SimulatorModel(model, [], [], [], settings)
    data = _core.SimulatorData(sim)
    _core.step(sim, data)
    assert np.isfinite(data.q).all()


def test_set_state_refuses_a_quaternion_that_normalises_to_nothing():
    """(0, 0, 0, 1e300): its squared norm overflows, and dividing by it stored (0, 0, 0, 0), a
    zero rotation the fused pass then used without a word."""
    sim = Simulator("cube-slide")
    q = np.array(sim.data.q)
    q[3:7] = [0.0, 0.0, 0.0, 1e300]
    with pytest.raises(ValueError) as info:
        sim.set_state(q=q)
    message = str(info.value)
    assert "joint 'root_joint'" in message and "(0, 0, 0, 1.0000000000000001e+300)" in message
    assert "no finite norm" in message
    np.testing.assert_array_equal(sim.data.q[3:7], [0, 0, 0, 1])  # the state unchanged
    # a large but finite norm still normalises (the documented behaviour)
    q[3:7] = [0.0, 0.0, 0.0, 1e150]
    sim.set_state(q=q)
    np.testing.assert_array_equal(sim.data.q[3:7], [0, 0, 0, 1])


def test_a_scene_initial_quaternion_names_the_joint_and_the_value():
    cfg = {"name": "cube", "urdf": "cube.urdf", "free_flyer": True, "contacts": {"box_corners": True},
           "initial": {"q": [0.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1e300]}}
    with pytest.raises(ValueError) as info:
        build_scene(cfg)
    message = str(info.value)
    assert "initial.q" in message and "joint 'root_joint'" in message and "1.0000000000000001e+300" in message


@pytest.mark.parametrize("quaternion", [[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 2.0], [0.0, 0.0, 0.7071, 0.7071]])
def test_a_non_unit_quaternion_assigned_to_data_q_is_refused_at_the_step(quaternion):
    """SimulatorData.q takes any finite vector; the step (the fused pass and Pinocchio alike read
    a quaternion as a rotation without normalising it) refuses one off unit by more than 1e-9."""
    sim = Simulator("cube-slide")
    q = np.array(sim.data.q)
    q[3:7] = quaternion
    sim.data.q = q
    with pytest.raises(ValueError, match=r"q: the quaternion \(x, y, z, w\) of joint 'root_joint' \(q\[3\.\.6\]\) = "
                                         r"\(0, 0, .*has norm .*, not 1.*set_state"):
        sim.step()
    sim.set_state(q=q) if np.linalg.norm(quaternion) > 0 else sim.reset()
    sim.step()  # normalised: accepted
    assert np.isfinite(sim.data.q).all()
