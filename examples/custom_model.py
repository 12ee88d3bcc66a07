"""Simulate a pinocchio.Model you built yourself: a ball dropped on a slope, rolling.

Run: .venv/bin/python examples/custom_model.py
"""
import numpy as np
import pinocchio as pin

from stiction import _core
from stiction.scene import build_scene
from stiction.simulator import Simulator

# A scene from a dict (the same keys as robots/scenes/*.toml): the ball URDF, a 20° slope.
scene = build_scene({"urdf": "ball.urdf", "ground": {"slope_deg": 20.0, "mu": 0.8}, "settle_time": 0.1,
                     "contacts": {"frames": ["ball"], "radius": 0.05}, "duration": 1.0})
sim = Simulator(scene)
traj = sim.rollout()
a = sim.summary(traj)["mean_acceleration_along_slope"]  # world-frame base velocity, after 0.1 s
# A solid ball rolls without slipping: a = (5/7) g sin(theta)
print(f"ball acceleration {a:.5f} m/s^2, rolling theory {5 / 7 * 9.81 * np.sin(np.radians(20)):.5f}")
print("contact state at the end:", _core.ContactState.values[int(traj.states[-1, 0])], "(rolling = sticking)")

# Or pass your own pinocchio.Model straight to the C++ simulator (here: the same ball, flat ground):
model = pin.buildModelFromUrdf("robots/ball.urdf", pin.JointModelFreeFlyer())
ground = _core.HalfSpace()
contact = _core.SphereContact()
contact.frame, contact.radius, contact.mu = model.getFrameId("ball"), 0.05, 0.8
settings = _core.SimulatorSettings()
sim_model = _core.SimulatorModel(model, [ground], [contact], [], settings)
data = _core.SimulatorData(sim_model)
q = pin.neutral(model)
q[2] = 0.05
data.q = q
for _ in range(100):
    _core.step(sim_model, data)
force = np.asarray(data.candidate_lambda).reshape(3, -1)[:, 0]  # 3 x contacts (t1, t2, n)
print("after 0.1 s: base", np.round(data.q[:3], 6), "contact force", np.round(force, 4), "N (m g = 4.905)")
