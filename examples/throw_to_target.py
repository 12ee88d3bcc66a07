"""Throw a cube so that it slides to rest on a target point: a trajectory optimisation through contact.

A 1 kg cube (side 0.1 m) is launched on flat ground with μ = 0.5 at an initial velocity (vx, vy); it slides
and sticks where friction stops it. We look for the launch velocity that brings it to rest at TARGET
after DURATION. Gradient method: Newton on r(v0) = p_N(v0) - TARGET, the 2 x 2 Jacobian dp_N/dv0 chained
through the steps (S_{k+1} = F_k S_k with F_k the step's state Jacobian: ``Simulator.step_derivatives()``
when this build has it, else the step's Jacobian-vector products by central differences,
``stiction.derivatives.finite_difference_step_jvp``, 3 steps per column). Baseline: scipy's Nelder-Mead
on the distance with the same budget of simulated steps (every step the gradient method ran, its
finite-difference steps included, counts; a step_derivatives() call counts as 5 steps, the issue's bound
on its cost).

Run from anywhere: python examples/throw_to_target.py [--quick]
"""
import argparse

import numpy as np
import pinocchio as pin
from scipy.optimize import minimize

from stiction.derivatives import finite_difference_step_jvp
from stiction.simulator import Simulator

TARGET = np.array([0.25, 0.10])
DURATION = 0.5  # s: the cube is at rest well before (it slides v0 / (mu g) ~ 0.33 s)
START = np.array([0.5, 0.0])  # the first guess of (vx, vy), m/s
CONVERGED = 1e-6  # m from the target
DERIVATIVE_COST = 5  # steps a step_derivatives() call counts for in the budget (issue 26's bound: <= 5 steps' time)

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--quick", action="store_true", help="(the same run: it takes a few seconds)")
parser.add_argument("--derivatives", choices=("analytic", "fd"), default=None)
args = parser.parse_args()
derivatives = args.derivatives or ("analytic" if hasattr(Simulator, "step_derivatives") else "fd")
sim = Simulator("cube-slide")
steps_per_rollout = int(round(DURATION / sim.dt))
model = sim.scene.model
nv = model.nv
counter = {"steps": 0}


def throw(v0, gradient=False):
    """The rest position (x, y) after DURATION from launch velocity v0, and with gradient=True its
    Jacobian d(x, y)/d(vx, vy)."""
    sim.reset()
    sim.set_state(v=np.array([v0[0], v0[1], 0.0, 0.0, 0.0, 0.0]))
    S = np.zeros((2 * nv, 2))
    S[nv, 0] = S[nv + 1, 1] = 1.0  # v0 moves the body-frame linear velocity (the cube starts unrotated)
    for _ in range(steps_per_rollout):
        if gradient and derivatives == "analytic":
            S = sim.step_derivatives().state_jacobian() @ S
            counter["steps"] += DERIVATIVE_COST
        elif gradient:
            columns = [finite_difference_step_jvp(sim, S[:nv, j], S[nv:, j]) for j in range(2)]
            counter["steps"] += 6
            S = np.array([np.concatenate(c) for c in columns]).T
        sim.step()
        counter["steps"] += 1
    q = sim.data.q
    position = q[:2].copy()
    if not gradient:
        return position
    rotation = pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix()
    return position, (rotation @ S[:3])[:2]  # tangent (local) displacement -> world


# the gradient method: Newton on the rest position
v0 = START.copy()
history = []
for iteration in range(20):
    position, jacobian = throw(v0, gradient=True)
    distance = float(np.linalg.norm(position - TARGET))
    history.append((iteration, v0.copy(), distance, counter["steps"]))
    if distance < 1e-10:
        break
    v0 = v0 - np.linalg.solve(jacobian, position - TARGET)
budget = counter["steps"]
final_gradient = float(np.linalg.norm(throw(v0) - TARGET))
for iteration, v, distance, steps in history:
    print(f"gradient iteration {iteration}: v0 = ({v[0]:.9f}, {v[1]:.9f}) m/s, distance {distance:.3e} m, "
          f"{steps} steps so far")
print(f"gradient ({derivatives} derivatives): distance {final_gradient:.3e} m after {budget} steps")

# the baseline: Nelder-Mead with the same budget of steps
counter["steps"] = 0
evaluations = budget // steps_per_rollout
# (a generous first simplex, 0.5 m/s wide: scipy's default, 5 % of START, crawls from there)
simplex = np.array([START, START + [0.5, 0.0], START + [0.0, 0.5]])
nm = minimize(lambda v: float(np.linalg.norm(throw(v) - TARGET)), START, method="Nelder-Mead",
              options={"maxfev": evaluations, "xatol": 1e-12, "fatol": 1e-14, "initial_simplex": simplex})
final_nm = float(np.linalg.norm(throw(nm.x) - TARGET))
print(f"nelder-mead: distance {final_nm:.3e} m after {evaluations} rollouts ({evaluations * steps_per_rollout} steps)")
print(f"converged (< {CONVERGED:g} m): gradient {final_gradient < CONVERGED}, nelder-mead {final_nm < CONVERGED}")
