"""Robots from the example-robot-data wheel, loaded with plain Pinocchio.

example-robot-data 6.0.0 on PyPI ships the robot files (URDF, SRDF, meshes) under
``cmeel.prefix/share/example-robot-data/robots`` and no Python module, so stiction reads them
directly. Nothing is fetched at run time.

Where a robot's collision meshes are heavy (solo12 and go2 feet are meshes), the scenes put a
sphere at each foot frame instead: ``RobotSpec.feet`` and ``foot_radius``.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

# The placement of a planar root joint: joint (x, y, z) -> world (x, z, -y), i.e. the joint's
# plane is the world's vertical x-z plane and its rotation is about world -y.
PLANAR_ROTATION = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass(frozen=True)
class RobotSpec:
    urdf: str  # relative to the robots directory
    srdf: str | None
    reference: str | None  # SRDF reference posture
    free_flyer: bool
    feet: tuple[str, ...] = ()  # frames carrying a contact sphere
    foot_radius: float = 0.0
    # extra contact points (frame, offset in frame) with radius 0, e.g. sole corners
    points: tuple[tuple[str, tuple[float, float, float]], ...] = field(default=())


def _sole_corners(frame: str, hx: float, hy: float) -> tuple:
    return tuple((frame, (sx * hx, sy * hy, 0.0)) for sx in (-1, 1) for sy in (-1, 1))


ROBOTS: dict[str, RobotSpec] = {
    "solo12": RobotSpec("solo_description/robots/solo12.urdf", "solo_description/srdf/solo.srdf", "standing", True,
                        ("FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"), 0.016),
    "go2": RobotSpec("go2_description/urdf/go2.urdf", "go2_description/srdf/go2.srdf", "standing", True,
                     ("FL_foot", "FR_foot", "RL_foot", "RR_foot"), 0.022),
    "anymal": RobotSpec("anymal_b_simple_description/robots/anymal.urdf", "anymal_b_simple_description/srdf/anymal.srdf",
                        "standing", True, ("LF_FOOT", "LH_FOOT", "RF_FOOT", "RH_FOOT"), 0.031),
    "talos": RobotSpec("talos_data/robots/talos_reduced.urdf", "talos_data/srdf/talos.srdf", "half_sitting", True,
                       points=_sole_corners("left_sole_link", 0.1, 0.065) + _sole_corners("right_sole_link", 0.1, 0.065)),
    "ur5": RobotSpec("ur_description/urdf/ur5_robot.urdf", "ur_description/srdf/ur5.srdf", None, False),
    "panda": RobotSpec("panda_description/urdf/panda.urdf", "panda_description/srdf/panda.srdf", "default", False),
}


def robots_dir() -> Path:
    """The example-robot-data robots directory of the installed wheel."""
    candidates = []
    for entry in sys.path:
        candidates.append(Path(entry) / ".." / ".." / ".." / "share" / "example-robot-data" / "robots")
        candidates.append(Path(entry) / "cmeel.prefix" / "share" / "example-robot-data" / "robots")
    for c in candidates:
        if c.is_dir():
            return c.resolve()
    raise FileNotFoundError("example-robot-data robot files not found: pip install example-robot-data==6.0.0")


@dataclass
class LoadedRobot:
    name: str
    model: pin.Model
    visual_model: pin.GeometryModel
    q0: np.ndarray
    spec: RobotSpec | None
    urdf_path: Path


def robot_package_dirs() -> list[str]:
    """Mesh search paths for example-robot-data's URDFs (package://example-robot-data/robots/...)."""
    root = robots_dir()
    return [str(root.parent.parent), str(root)]


def load_urdf(path: str | os.PathLike, free_flyer: bool, package_dirs: list[str] | None = None,
              srdf: str | os.PathLike | None = None, reference: str | None = None, name: str | None = None,
              spec: RobotSpec | None = None, planar: bool = False) -> LoadedRobot:
    """planar: a planar root joint (instead of the free flyer) placed in the world's vertical x-z plane:
    Pinocchio's JointModelPlanar moves in its x-y plane and turns about its z; its placement (a
    rotation of +90 degrees about x) maps joint x to world x, joint y to world z (up) and joint z to
    world -y, so the ground z = 0, gravity and slopes of a scene stay as they are."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"URDF not found: {path}")
    dirs = [str(p) for p in (package_dirs or [])]
    root = pin.JointModelPlanar() if planar else pin.JointModelFreeFlyer() if free_flyer else None
    if root is None:
        model = pin.buildModelFromUrdf(str(path))
    else:
        model = pin.buildModelFromUrdf(str(path), root)
    if planar:
        model.jointPlacements[1] = pin.SE3(PLANAR_ROTATION, np.zeros(3))
    visual = pin.buildGeomFromUrdf(model, str(path), pin.GeometryType.VISUAL, package_dirs=dirs)
    q0 = pin.neutral(model)
    if srdf is not None and reference is not None:
        pin.loadReferenceConfigurations(model, str(srdf), False)
        if reference not in model.referenceConfigurations:
            raise ValueError(f"{srdf} has no reference posture {reference!r}")
        q0 = model.referenceConfigurations[reference].copy()
    return LoadedRobot(name or path.stem, model, visual, q0, spec, path)


def load_robot(name: str) -> LoadedRobot:
    """A robot of ROBOTS by name (solo12, go2, anymal, talos, ur5, panda)."""
    if name not in ROBOTS:
        raise ValueError(f"unknown robot {name!r}; known: {', '.join(sorted(ROBOTS))} (or give a URDF path)")
    spec = ROBOTS[name]
    root = robots_dir()
    srdf = root / spec.srdf if spec.srdf else None
    return load_urdf(root / spec.urdf, spec.free_flyer, robot_package_dirs(), srdf, spec.reference, name, spec)
