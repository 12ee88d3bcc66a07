"""The fused rigid-body passes (src/cpp/sim/tree.cpp, the free bodies' fixed-size code) are a speed
choice; Pinocchio's own passes (rigid_body_passes="pinocchio": forwardKinematics,
computeJointJacobians, crba, nonLinearEffects, cholesky::decompose/solve, integrate, difference)
stay the reference. Every bundled scene is rolled out both ways from the same state and the
trajectories compared.

Tolerance (measured, 300 steps each; q relative to max(1, the run's largest |q|), v likewise):
in every scene the two agree to <= 2e-13 in q and <= 2e-10 in v (go2-stand: 1.7e-13, 2.0e-10;
box-tower-20, cube-slide, solo12-slope-slip, talos-stand: 3-4.5e-11 in v; two-cube-stack 1.2e-11;
the rest below 3e-12) while the contact states are the same; 1e-9 leaves a margin of 5x (20x but
for go2) for rounding (the two passes sum in different orders: M and nle agree to ~1e-15 a step, the
contact solves amplify that through the Delassus operator's conditioning). It has teeth: one
foot's inertia scaled by 1 + 1e-6 in the reference moved Solo-12's v by 1.0e-8 and TALOS's by
9.2e-9 over the 300 steps. Two scenes switch contact modes within 300 steps, after which
the trajectories separate to the scene's own sensitivity: ur5-push-box (two contacts start
slipping at step 85: v then differs by up to 6.2e-8, and a 1e-15 nudge of v in the fused pass
alone differs from the unnudged run by as much, 5e-8) and pile-24 (boxes landing from step 147:
up to 1.1e-9 in v by step 240). They are compared strictly up to the switch, and the whole 300
steps within 1e-6."""
import numpy as np
import pytest

from stiction.scene import list_scenes, load_scene
from stiction.simulator import Simulator

STEPS = 300
STRICT = 1e-9  # relative, while the contact modes agree
LOOSE = 1e-6   # relative, the whole run (after a mode switch: the scene's own sensitivity to rounding)
# the last step compared strictly where a contact mode switch comes first (see the module's docstring)
# dmc-humanoid-stand: eight coplanar foot spheres carry the weight, a split that is not unique; from step
# 46 the passes' rounding picks different splits (a sphere carrying 1.3 N in one is open in the other)
# with the same motion (v within 2e-10 over the 300 steps)
STRICT_UNTIL = {"ur5-push-box": 84, "pile-24": 230, "dmc-humanoid-stand": 45}
# the mixed piles (hundreds of bodies tumbling: the passes' rounding picks other patch vertices from the
# first impacts on, ~step 155, and the runs part chaotically) are compared up to their first impacts
STEPS_OF = {"pile-256": 150, "pile-1000": 150}


def relative_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per step, max |a - b| over the coordinates, relative to max(1, max |a|) over the run."""
    return np.abs(a - b).max(axis=1) / max(1.0, float(np.abs(a).max()))


@pytest.mark.parametrize("name", list_scenes())
def test_fused_and_pinocchio_passes_give_the_same_trajectory(name):
    scene = load_scene(name)
    fused = Simulator(scene)
    assert fused.settings.rigid_body_passes == "fused"  # the default
    reference = Simulator(scene, rigid_body_passes="pinocchio")
    assert reference.settings.rigid_body_passes == "pinocchio"
    steps = STEPS_OF.get(name, STEPS)
    a, b = (sim.rollout(steps * scene.dt) for sim in (fused, reference))
    assert len(a.t) == len(b.t) == steps + 1
    dq, dv = relative_difference(a.q, b.q), relative_difference(a.v, b.v)
    strict = STRICT_UNTIL.get(name, steps) + 1
    np.testing.assert_array_equal(a.states[:strict], b.states[:strict])
    assert dq[:strict].max() <= STRICT and dv[:strict].max() <= STRICT, (dq[:strict].max(), dv[:strict].max())
    assert dq.max() <= LOOSE and dv.max() <= LOOSE, (dq.max(), dv.max())
    assert a.converged.all() and b.converged.all()


def test_the_passes_are_really_different_code():
    """The reference is not the fused pass again: on a robot the two runs differ by rounding
    (not bit for bit), and an unknown name is refused by Python and by C++."""
    scene = load_scene("solo12-stand")
    a, b = (Simulator(scene, rigid_body_passes=p).rollout(20 * scene.dt) for p in ("fused", "pinocchio"))
    assert not np.array_equal(a.v, b.v)
    with pytest.raises(ValueError, match="rigid_body_passes must be one of fused, pinocchio, got 'pinochio'"):
        Simulator(scene, rigid_body_passes="pinochio")
    from stiction import _core

    settings = _core.SimulatorSettings()
    settings.rigid_body_passes = "crba"
    with pytest.raises(ValueError, match="rigid_body_passes must be 'fused' or 'pinocchio', got 'crba'"):
        _core.SimulatorModel(scene.model, [], [], [], settings)
