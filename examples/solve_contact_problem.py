"""Solve one contact problem A λ − b ∈ −lim N_C^{U_ε}(λ) (eq. 65) and check the answer.

A 1 kg cube sliding at 1 m/s on the ground, one step of h = 1 ms: the four corners must carry
m g h of normal impulse in all, and friction μ m g h against the motion (Coulomb, sliding).

Run from anywhere: python examples/solve_contact_problem.py
"""
import numpy as np

import stiction
from stiction.problems import cube_on_ground

rigid = cube_on_ground(mass=1.0, mu=0.5, velocity=(1.0, 0.0, 0.0), h=1e-3)
result = stiction.solve(rigid.problem)
lam = result.lam.reshape(-1, 3)  # per corner (t1, t2, n)
print(f"solver {result.solver}: converged {result.converged} in {result.iterations} iterations, "
      f"{result.seconds * 1e6:.0f} µs, relative residual {result.relative_residual:.1e}")
print("states:", [s.name for s in result.states])
print(f"normal impulse {lam[:, 2].sum():.9f} N s   (m g h = {9.81e-3:.9f})")
print(f"friction impulse {lam[:, 0].sum():.9f} N s (−μ m g h = {-0.5 * 9.81e-3:.9f})")
v = rigid.velocity_after(result.lam)
print(f"velocity after the step {v[0]:.6f} m/s (1 − μ g h = {1 - 0.5 * 9.81e-3:.6f}); vertical {v[2]:.1e} m/s")

# The same problem built by hand: any symmetric PSD A, any b, blocks of mixed kinds.
A = np.array([[2.0, 0.0, 0.5], [0.0, 2.0, 0.0], [0.5, 0.0, 1.0]])
b = np.array([0.3, 0.0, 1.0])
problem = stiction.ContactProblem(A, b, [stiction.Constraint.spatial_friction(0.2)])
r = stiction.solve(problem, solver="newton")
print(f"hand-built: λ = {np.round(r.lam, 6)}, state {r.states[0].name}, residual {stiction.residual(problem, r.lam):.1e}")
