"""Simulate a robot you loaded yourself: your pinocchio.Model goes straight into stiction.

Solo-12 is loaded here with plain Pinocchio from its URDF (example-robot-data's files; use your
own path), put in its SRDF standing posture, given sphere feet, and simulated standing on flat
ground under a joint PD. Then a ball (also your own model) rolls down a 20° slope without slipping.

Run from anywhere: python examples/custom_model.py
"""
import numpy as np
import pinocchio as pin

from stiction.robots import robots_dir  # where example-robot-data keeps its robot files
from stiction.scene import scene_from_model
from stiction.simulator import Simulator

# ---- your robot, loaded by you
erd = robots_dir()
urdf = erd / "solo_description/robots/solo12.urdf"
model = pin.buildModelFromUrdf(str(urdf), pin.JointModelFreeFlyer())
visual = pin.buildGeomFromUrdf(model, str(urdf), pin.GeometryType.VISUAL, package_dirs=[str(erd.parents[1])])
pin.loadReferenceConfigurations(model, str(erd / "solo_description/srdf/solo.srdf"), False)
q0 = model.referenceConfigurations["standing"].copy()

feet = ["FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"]
scene = scene_from_model(model, visual, q0, name="my-solo", spheres=[(f, 0.016) for f in feet], mu=1.0,
                         kp=20.0, kd=0.2, duration=1.0, settle_time=0.3)
sim = Simulator(scene)
summary = sim.summary(sim.rollout())
mass = sum(inertia.mass for inertia in model.inertias)
print(f"Solo-12 standing 1 s: {summary['steps']} steps, {summary['us_per_step']:.1f} µs/step, "
      f"foot slip {summary['max_foot_slip']:.1e} m, penetration {summary['max_penetration']:.1e} m")
normal_force = float(np.asarray(sim.data.candidate_lambda).reshape(3, -1)[2].sum())
print(f"   feet carry {normal_force:.3f} N, m g = {mass * 9.81:.3f} N")

# ---- a ball of your own on a slope: it rolls, a = (5/7) g sin(theta)
ball = pin.Model()
radius, m = 0.05, 0.5
joint = ball.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "ball")
ball.appendBodyToJoint(joint, pin.Inertia(m, np.zeros(3), np.eye(3) * 0.4 * m * radius**2), pin.SE3.Identity())
ball.addBodyFrame("ball", joint, pin.SE3.Identity(), 0)
scene = scene_from_model(ball, spheres=[("ball", radius)], mu=0.8, slope_deg=20.0, duration=1.0, settle_time=0.1)
sim = Simulator(scene)
a = sim.summary(sim.rollout())["mean_acceleration_along_slope"]
print(f"ball on a 20° slope: a = {a:.6f} m/s², rolling theory (5/7) g sin θ = "
      f"{5 / 7 * 9.81 * np.sin(np.radians(20)):.6f} m/s²")
