"""A pile of mixed shapes in a bin (``[array] layout = "pile"`` with ``mix``): boxes, spheres,
capsules, cylinders and convex meshes (the convex hull of random points), drawn from a seed,
dropped from a jittered lattice into a bin (a floor and four walls, coal boxes fixed to the world).

Every contact goes through coal: body on body, body on floor, body on wall, each pair with its
contact patch (up to four points). No pair is listed: the pairs are a pool of ``pairs_per_body *
count`` dynamic entries (``GeometryPairContact.dynamic``) that the broad phase
(src/cpp/sim/broad_phase.cpp: sweep-and-prune over the shapes' world boxes) fills each step with
the pairs of shapes whose boxes, grown by the activation distance, overlap. A pair keeps its entry
while it overlaps, so the entry's slots (and their warm start) follow one pair of shapes; the
candidates are the entries' slots, ``pool<k>#<slot>`` in ``Simulator.contact_names``, and which two
shapes an entry holds changes from step to step.

Bodies are uniform solids of ``DENSITY`` (their masses and inertias from coal's volume and moments,
tests/test_pile_mix.py checks them against closed forms and scipy); ``SIZE`` is the scale of each
kind. The layout without ``mix`` (pile-24: boxes and balls from URDFs, analytic ground contacts and
every two bodies a listed pair) is :func:`stiction.scene._pile_bodies`.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from . import _core
from .scene_schema import SceneError, did_you_mean

DENSITY = 1000.0  # kg/m^3: water (a 10 cm cube weighs 1 kg)
SHAPES = ("box", "sphere", "capsule", "cylinder", "mesh")
DEFAULT_MIX = SHAPES
PAIRS_PER_BODY = 6  # pool entries per body (a body in a settled pile overlaps ~4-8 boxes of others, walls, floor)
WALL_THICKNESS = 0.2  # m
MESH_POINTS = 16  # random points whose convex hull is a "mesh" body


def _convex(points: np.ndarray):
    import coal

    vec = coal.StdVec_Vec3s()
    for p in points:
        vec.append(np.asarray(p, dtype=float))
    return coal.Convex.convexHull(vec, True, "")


def make_shape(kind: str, rng: np.random.Generator):
    """One body of `kind`: (coal shape centred on its centre of mass, mass, 3 x 3 inertia about the
    centre of mass, bounding radius). A mesh is the convex hull of MESH_POINTS random points in a
    shell of 4-4.5 cm radius, moved so that its centre of mass is the origin."""
    import coal

    if kind == "box":
        shape = coal.Box(0.10, 0.08, 0.06)
    elif kind == "sphere":
        shape = coal.Sphere(0.04)
    elif kind == "capsule":
        shape = coal.Capsule(0.025, 0.06)  # radius, length of the cylinder between the two half balls
    elif kind == "cylinder":
        shape = coal.Cylinder(0.035, 0.07)  # radius, length
    elif kind == "mesh":
        directions = rng.normal(size=(MESH_POINTS, 3))
        points = directions / np.linalg.norm(directions, axis=1)[:, None] * rng.uniform(0.04, 0.045, (MESH_POINTS, 1))
        hull = _convex(points)
        com = np.asarray(hull.computeCOM(), dtype=float)
        shape = _convex(np.array(hull.points()) - com)
    else:
        raise SceneError(f"array.mix: unknown shape {kind!r} ({did_you_mean(kind, SHAPES)}shapes: {', '.join(SHAPES)})")
    volume = float(shape.computeVolume())
    inertia = DENSITY * np.asarray(shape.computeMomentofInertiaRelatedToCOM(), dtype=float)
    shape.computeLocalAABB()
    return shape, DENSITY * volume, inertia, float(shape.aabb_radius)


def shape_parameters(shape) -> dict:
    """What a twin simulator needs to rebuild a coal shape: its kind and sizes (a mesh: its vertices)."""
    name = type(shape).__name__
    if name == "Box":
        return {"kind": "box", "half": np.asarray(shape.halfSide, dtype=float)}
    if name == "Sphere":
        return {"kind": "sphere", "radius": float(shape.radius)}
    if name == "Capsule":
        return {"kind": "capsule", "radius": float(shape.radius), "half_length": float(shape.halfLength)}
    if name == "Cylinder":
        return {"kind": "cylinder", "radius": float(shape.radius), "half_length": float(shape.halfLength)}
    if name == "Convex":
        return {"kind": "mesh", "vertices": np.array(shape.points())}
    raise ValueError(f"no parameters for a coal {name}")


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def mixed_pile(count: int, seed: int, mix, spacing: float | None, bin_half: float | None, mu: float,
               pairs_per_body: int, cmodel: str = "spatial"):
    """`count` bodies of the kinds in `mix` (drawn uniformly from the list: repeat a kind to weigh it)
    on a jittered lattice inside a square bin of half width `bin_half` (default: the lattice's rows
    of ceil(sqrt(count / 3)) bodies, so ~3 layers), at random orientations, none overlapping.
    Returns model, visual, q0, geometry, pairs."""
    import coal

    if not mix:
        raise SceneError("array.mix: list at least one shape")
    for kind in mix:
        if kind not in SHAPES:
            raise SceneError(f"array.mix: unknown shape {kind!r} ({did_you_mean(kind, SHAPES)}shapes: "
                             f"{', '.join(SHAPES)})")
    rng = np.random.default_rng(seed)
    kinds = [mix[int(i)] for i in rng.integers(len(mix), size=count)]
    bodies = [make_shape(kind, rng) for kind in kinds]
    largest = max(b[3] for b in bodies)
    step = spacing if spacing is not None else 2.4 * largest
    if step <= 2.0 * largest:
        raise SceneError(f"array.spacing = {step:g}: bodies on the lattice could overlap (the largest body's "
                         f"bounding diameter is {2 * largest:g} m)")
    if bin_half is None:
        per_row = math.ceil(math.sqrt(count / 3.0))
        bin_half = 0.5 * per_row * step + 0.25 * step
    else:
        per_row = math.floor((2.0 * bin_half - 0.5 * step) / step)
        if per_row < 1:
            raise SceneError(f"array.bin = {bin_half:g}: narrower than one body of the drop lattice "
                             f"(spacing {step:g} m); give a wider bin or a smaller spacing")
    jitter = 0.45 * (step - 2.0 * largest)
    layers = math.ceil(count / per_row ** 2)
    model, visual, geometry = pin.Model(), pin.GeometryModel(), pin.GeometryModel()
    q_parts = []
    for k, (shape, mass, inertia, _) in enumerate(bodies):
        joint = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), f"body{k}")
        model.appendBodyToJoint(joint, pin.Inertia(mass, np.zeros(3), inertia), pin.SE3.Identity())
        frame = model.addFrame(pin.Frame(f"body{k}", joint, 0, pin.SE3.Identity(), pin.FrameType.BODY), False)
        layer, rest = divmod(k, per_row * per_row)
        i, j = divmod(rest, per_row)
        centre = np.array([(j - (per_row - 1) / 2) * step, (i - (per_row - 1) / 2) * step,
                           largest + 0.5 * step + layer * step]) + rng.uniform(-jitter, jitter, size=3)
        q_parts.append(np.concatenate([centre, _random_rotation(rng)]))
        geometry.addGeometryObject(pin.GeometryObject(f"body{k}", joint, frame, pin.SE3.Identity(), shape))
        go = pin.GeometryObject(f"body{k}", joint, frame, pin.SE3.Identity(), shape)
        go.meshColor = np.array([0.55, 0.6, 0.7, 1.0])
        visual.addGeometryObject(go)
    # the bin: a floor (top face at z = 0) and four walls (inner faces at +-bin_half), tall enough
    # for the drop lattice; boxes fixed to the world (joint 0), each a shape of the broad phase
    top = largest + 0.5 * step + layers * step + step
    outer = bin_half + WALL_THICKNESS
    walls = [("floor", (2 * outer, 2 * outer, WALL_THICKNESS), (0.0, 0.0, -WALL_THICKNESS / 2)),
             ("wall+x", (WALL_THICKNESS, 2 * outer, top), (bin_half + WALL_THICKNESS / 2, 0.0, top / 2)),
             ("wall-x", (WALL_THICKNESS, 2 * outer, top), (-bin_half - WALL_THICKNESS / 2, 0.0, top / 2)),
             ("wall+y", (2 * outer, WALL_THICKNESS, top), (0.0, bin_half + WALL_THICKNESS / 2, top / 2)),
             ("wall-y", (2 * outer, WALL_THICKNESS, top), (0.0, -bin_half - WALL_THICKNESS / 2, top / 2))]
    for name, size, position in walls:
        placement = pin.SE3(np.eye(3), np.array(position))
        geometry.addGeometryObject(pin.GeometryObject(name, 0, 0, placement, coal.Box(*size)))
    pairs = []
    for k in range(pairs_per_body * count):
        gp = _core.GeometryPairContact()
        gp.name, gp.dynamic, gp.mu, gp.max_contacts, gp.patch = f"pool{k}", True, mu, 4, True
        gp.model = getattr(_core.ContactModel, cmodel)
        pairs.append(gp)
    return model, visual, np.concatenate(q_parts), geometry, pairs
