"""Contact problems with known physics, built from rigid bodies in numpy.

Each body has 6 velocity coordinates (v, ω): the linear velocity of its centre of mass
and its angular velocity, both in the world frame. A contact point at r from the centre
moves with v + ω × r, i.e. J = [I, -[r]×]. One time step of the paper's time-stepping
scheme (eq. 70) with ζ = 1/2, δ = h and zero gaps is

    u = A λ - b,   A = J M⁻¹ Jᵀ (eq. 22),   b = -J v_free,   v_free = v + h M⁻¹ f_ext,

with λ the contact impulse and u = J v⁺ the post-step contact velocity.
Rows per contact: (t1, t2, n) = (x, y, z) for horizontal surfaces (normal last).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._core import Constraint, ContactProblem

GRAVITY = 9.81


def skew(r: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]])


def box_inertia(mass: float, half_extents) -> np.ndarray:
    a, b, c = half_extents
    return mass / 3.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


@dataclass
class RigidProblem:
    """A ContactProblem together with the mechanics it came from."""

    problem: ContactProblem
    J: np.ndarray  # (rows, 6 * bodies)
    M: np.ndarray  # (6 * bodies, 6 * bodies)
    v_free: np.ndarray  # (6 * bodies,)
    h: float
    masses: list[float]
    description: str

    def velocity_after(self, lam: np.ndarray) -> np.ndarray:
        """v⁺ = v_free + M⁻¹ Jᵀ λ."""
        return self.v_free + np.linalg.solve(self.M, self.J.T @ lam)


def _box_corners(half: float, z_sign: float) -> list[np.ndarray]:
    return [np.array([sx * half, sy * half, z_sign * half]) for sx in (-1, 1) for sy in (-1, 1)]


def _assemble(jacobians, masses, halves, velocities, mu, h, description) -> RigidProblem:
    nb = len(masses)
    M = np.zeros((6 * nb, 6 * nb))
    f = np.zeros(6 * nb)
    for i, (m, hx) in enumerate(zip(masses, halves)):
        M[6 * i : 6 * i + 3, 6 * i : 6 * i + 3] = m * np.eye(3)
        M[6 * i + 3 : 6 * i + 6, 6 * i + 3 : 6 * i + 6] = box_inertia(m, (hx, hx, hx))
        f[6 * i + 2] = -m * GRAVITY
    J = np.vstack(jacobians)
    v = np.concatenate(velocities)
    v_free = v + h * np.linalg.solve(M, f)
    A = J @ np.linalg.solve(M, J.T)
    A = 0.5 * (A + A.T)
    b = -J @ v_free
    nc = J.shape[0] // 3
    mus = np.broadcast_to(np.asarray(mu, dtype=float), (nc,))
    problem = ContactProblem(np.asfortranarray(A), b, [Constraint.spatial_friction(float(m)) for m in mus])
    return RigidProblem(problem, J, M, v_free, h, list(masses), description)


def cube_on_ground(mass: float = 1.0, half: float = 0.05, mu: float = 0.5, velocity=(0.0, 0.0, 0.0),
                   h: float = 1e-3) -> RigidProblem:
    """A cube resting on z = 0 by its 4 bottom corners: A is 12x12 of rank 6."""
    Js = []
    for r in _box_corners(half, -1.0):
        Js.append(np.hstack([np.eye(3), -skew(r)]))
    v = np.concatenate([np.asarray(velocity, dtype=float), np.zeros(3)])
    return _assemble(Js, [mass], [half], [v], mu, h,
                     f"cube m={mass} on ground, 4 corners, mu={mu}, v={tuple(velocity)}")


def two_cube_stack(mass_ratio: float = 1e4, mu: float = 0.5, top_velocity=(0.0, 0.0, 0.0),
                   bottom_mass: float = 1.0, half: float = 0.05, h: float = 1e-3) -> RigidProblem:
    """Two equal-size cubes stacked on the ground, top mass = mass_ratio * bottom mass.

    8 contacts (24 rows) on 12 degrees of freedom. Contacts 0-3: bottom cube on the
    ground; 4-7: top cube on the bottom cube (force on the top, reaction on the bottom).
    With top_velocity = (v, 0, 0) the top cube slides on the bottom one.
    """
    top_mass = mass_ratio * bottom_mass
    Js = []
    for r in _box_corners(half, -1.0):  # bottom cube corners on the ground
        Js.append(np.hstack([np.eye(3), -skew(r), np.zeros((3, 6))]))
    for r in _box_corners(half, -1.0):  # top cube's bottom corners on the bottom cube's top face
        r_bottom = r + np.array([0.0, 0.0, 2.0 * half])
        Js.append(np.hstack([-np.eye(3), skew(r_bottom), np.eye(3), -skew(r)]))
    v_bottom = np.zeros(6)
    v_top = np.concatenate([np.asarray(top_velocity, dtype=float), np.zeros(3)])
    return _assemble(Js, [bottom_mass, top_mass], [half, half], [v_bottom, v_top], mu, h,
                     f"two-cube stack, mass ratio {mass_ratio:g}, mu={mu}, top v={tuple(top_velocity)}")


def random_problem(rng: np.random.Generator, kinds: list[str], dofs: int, mu_range=(0.1, 1.0),
                   approaching: float = 0.7) -> ContactProblem:
    """A random problem A = J M⁻¹ Jᵀ with the given block kinds
    ("spatial", "planar", "unilateral", "bilateral1".."bilateral6", "box": a 1-row interval
    [-U(0.05, 0.5), U(0.05, 0.5)], as a joint's dry friction).

    If the rows outnumber `dofs`, A is rank-deficient, as with redundant contacts.
    b is drawn so that about `approaching` of the contacts are pushed together.
    """
    constraints, sizes = [], []
    for k in kinds:
        if k == "spatial":
            constraints.append(Constraint.spatial_friction(float(rng.uniform(*mu_range))))
        elif k == "planar":
            constraints.append(Constraint.planar_friction(float(rng.uniform(*mu_range))))
        elif k == "unilateral":
            constraints.append(Constraint.unilateral())
        elif k == "box":
            constraints.append(Constraint.box(-float(rng.uniform(0.05, 0.5)), float(rng.uniform(0.05, 0.5))))
        elif k.startswith("bilateral"):
            constraints.append(Constraint.bilateral(int(k[len("bilateral"):] or 3)))
        else:
            raise ValueError(f"unknown kind {k!r}")
        sizes.append(constraints[-1].size)
    m = sum(sizes)
    L = rng.standard_normal((dofs, dofs))
    M = L @ L.T + dofs * np.eye(dofs)
    J = rng.standard_normal((m, dofs))
    A = J @ np.linalg.solve(M, J.T)
    A = 0.5 * (A + A.T)
    b = rng.standard_normal(m) * 0.3
    row = 0
    for c in constraints:
        if c.kind.name not in ("bilateral", "box"):  # normal row last: positive b pushes the contact closed
            n = row + c.size - 1
            b[n] = abs(b[n]) if rng.uniform() < approaching else -abs(b[n])
        row += c.size
    return ContactProblem(np.asfortranarray(A), b, constraints)
