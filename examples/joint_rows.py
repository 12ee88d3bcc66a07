"""Joint limits, dry joint friction and effort limits on a model you built yourself.

A one-joint pendulum (a 1 kg point mass on a 0.5 m massless arm, hinge about y) built in code with
Pinocchio. Its dry friction, position limit and effort limit are the pinocchio.Model's own fields
(model.friction, model.upperPositionLimit, model.effortLimit: what a URDF's <dynamics friction> and
<limit> set), and stiction puts each into the step's exact problem as a row beside the contacts
(docs/joint-rows.md):

1. released at rest where gravity gives 0.9 of the friction torque: it does not move at all;
2. at 1.1 of it: it starts at (tau_g - tau_c) / I;
3. no friction, released at 0.6 rad above a lower limit at 0.2 rad: it falls onto the limit and rests
   there, the limit torque holding gravity's;
4. a feed-forward torque of 10 N m against an effort limit of 2 N m: 2 N m is applied.

Run from anywhere: python examples/joint_rows.py
"""
import math

import numpy as np
import pinocchio as pin

from stiction.scene import scene_from_model
from stiction.simulator import Simulator

MASS, LENGTH, G = 1.0, 0.5, 9.81


def pendulum(friction=0.0, lower=-math.pi, effort=0.0):
    model = pin.Model()
    hinge = model.addJoint(0, pin.JointModelRY(), pin.SE3(np.eye(3), np.array([0.0, 0.0, 1.0])), "hinge")
    # a point mass LENGTH below the hinge (a tiny inertia keeps the body's inertia positive definite)
    model.appendBodyToJoint(hinge, pin.Inertia(MASS, np.array([0.0, 0.0, -LENGTH]), 1e-6 * np.eye(3)), pin.SE3.Identity())
    model.friction[:] = friction
    model.lowerPositionLimit[:] = lower
    model.upperPositionLimit[:] = math.pi
    model.effortLimit[:] = effort  # 0: no limit
    return model


def gravity_torque(model, theta):
    """The generalized force of gravity on the hinge (Pinocchio: -g(q))."""
    return -pin.computeGeneralizedGravity(model, model.createData(), np.array([theta]))[0]


tau_c = 0.5
for ratio in (0.9, 1.1):
    theta = math.asin(ratio * tau_c / (MASS * G * LENGTH))
    model = pendulum(friction=tau_c)
    sim = Simulator(scene_from_model(model, q0=[theta], duration=1.0))
    traj = sim.rollout()
    if ratio < 1:
        print(f"hold at {ratio} tau_c: moved {np.abs(traj.q[:, 0] - theta).max():.3e} rad in 1 s, friction torque "
              f"{traj.joint_friction[-1, 0]:.6f} N m against gravity's {gravity_torque(model, theta):.6f} N m")
    else:
        inertia = pin.crba(model, model.createData(), np.array([theta]))[0, 0]
        tau_g = gravity_torque(model, theta)
        expected = (tau_g - math.copysign(tau_c, tau_g)) / inertia
        print(f"slip at {ratio} tau_c: first acceleration {traj.v[1, 0] / sim.dt:.9f} rad/s^2, "
              f"(tau_g - tau_c) / I = {expected:.9f} rad/s^2")

model = pendulum(lower=0.2)
sim = Simulator(scene_from_model(model, q0=[0.6], duration=1.0))
traj = sim.rollout()
print(f"limit at 0.2 rad: smallest angle {traj.q[:, 0].min():.12f} rad, overshoot "
      f"{max(0.0, 0.2 - traj.q[:, 0].min()):.3e} rad, limit torque at the end {traj.limit_torque[-1, 0]:.9f} N m "
      f"against gravity's {gravity_torque(model, traj.q[-1, 0]):.9f} N m")

model = pendulum(effort=2.0)
sim = Simulator(scene_from_model(model, q0=[0.0], duration=0.01))
sim.data.tau_ff = np.array([10.0])
traj = sim.rollout()
print(f"effort limit 2 N m, 10 N m asked: applied {traj.tau[1:, 0].max():.6f} N m at most")
