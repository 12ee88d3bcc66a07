"""Robots from MJCF (MuJoCo's XML), loaded with Pinocchio's own parser and checked against MuJoCo.

``pinocchio.buildModelFromMJCF`` and ``buildGeomFromMJCF`` build the model, its visuals and its
collision shapes. Pinocchio 4.1's parser reads only the first ``<asset>`` section and not the
assets of ``<include>`` files, and it ignores ``<compiler settotalmass>``; :func:`load_mjcf`
therefore parses a flattened temporary copy (includes inlined, assets merged, mesh and texture
folders made absolute) and scales the masses and inertias as MuJoCo does for ``settotalmass``.

Where MuJoCo is importable, every model is compared with ``mujoco.MjModel`` of the same file
(:func:`compare_with_mujoco`): nq, nv, the total mass, the limited joints' ranges and the joint
space inertia matrix M(qpos0) with armature, to 1e-9 (relative). A difference is an error naming
it (:class:`MjcfMismatch`) unless the caller accepts it by name (``accept``; scene key
``mjcf_accept``): the model then differs from MuJoCo's in that respect and the scene says so.
Without MuJoCo the model loads unchecked (``MjcfRobot.checked`` is False).

Contacts from the MJCF's own geoms (:func:`geom_spheres`): a sphere geom is a contact sphere,
a capsule the two spheres at its ends; against a plane that is exact (a capsule's point nearest
a plane is always on one of its end spheres).
"""
from __future__ import annotations

import fnmatch
import math
import os
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

# The differences from MuJoCo the check reports, by the name `accept` / `mjcf_accept` takes.
DIFFERENCES = ("nq", "nv", "total_mass", "joint_range", "mass_matrix")
TOLERANCE = 1e-9


class MjcfMismatch(ValueError):
    """Pinocchio's model of an MJCF file differs from MuJoCo's (one line naming the difference)."""


@dataclass
class MjcfRobot:
    name: str
    model: pin.Model
    visual_model: pin.GeometryModel  # both: the geoms of moving bodies (the world's, e.g. a floor, left out)
    collision_model: pin.GeometryModel
    q0: np.ndarray  # the MJCF's qpos0 in Pinocchio's coordinates
    path: Path
    checked: bool  # compared with MuJoCo (False: MuJoCo is not installed)
    differences: dict[str, str] = field(default_factory=dict)  # accepted differences: name -> description
    total_mass_scale: float = 1.0  # settotalmass applied (1: none)


def flatten_mjcf(path: str | os.PathLike) -> str:
    """The MJCF text of `path` with every ``<include>`` inlined (recursively, relative to the
    including file), its ``<asset>`` sections merged into one and the compiler's mesh, texture
    and asset folders made absolute, so that the text parses the same from any folder."""
    path = Path(path).resolve()
    root = ET.parse(path).getroot()

    def expand(elem, base: Path, seen: tuple):
        i = 0
        while i < len(elem):
            child = elem[i]
            if child.tag == "include":
                target = (base / child.get("file", "")).resolve()
                if not target.is_file():
                    raise FileNotFoundError(f"{path}: <include file={child.get('file')!r}> not found (looked for "
                                            f"{target})")
                if target in seen:
                    raise ValueError(f"{path}: <include> loop through {target}")
                included = ET.parse(target).getroot()
                expand(included, target.parent, seen + (target,))
                elem.remove(child)
                for k, sub in enumerate(list(included)):
                    elem.insert(i + k, sub)
                i += len(included)
            else:
                expand(child, base, seen)
                i += 1

    expand(root, path.parent, (path,))
    assets = [a for a in root if a.tag == "asset"]
    for extra in assets[1:]:
        assets[0].extend(list(extra))
        root.remove(extra)
    compilers = [c for c in root if c.tag == "compiler"]
    compiler = compilers[0] if compilers else ET.SubElement(root, "compiler")
    for extra in compilers[1:]:  # (several <compiler> elements: their attributes merged, later wins)
        compiler.attrib.update(extra.attrib)
        root.remove(extra)
    asset_dir = path.parent / compiler.get("assetdir", "")
    for key in ("meshdir", "texturedir"):
        compiler.set(key, str((path.parent / compiler.get(key)) if compiler.get(key) else asset_dir))
    compiler.attrib.pop("assetdir", None)
    return ET.tostring(root, encoding="unicode")


def _settotalmass(path: Path) -> float | None:
    for c in ET.fromstring(flatten_mjcf(path)).iter("compiler"):
        if c.get("settotalmass") is not None:
            return float(c.get("settotalmass"))
    return None


def total_mass(model: pin.Model) -> float:
    return float(sum(model.inertias[j].mass for j in range(model.njoints)))


def load_mjcf(path: str | os.PathLike, accept=(), check: bool = True) -> MjcfRobot:
    """An MJCF robot with Pinocchio's parser; compared with MuJoCo when it is installed and `check`.

    accept: names of DIFFERENCES to tolerate; any other difference raises MjcfMismatch (one line).
    A name in `accept` that the model does not show is an error too (the scene would claim a
    difference that is not there)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"MJCF not found: {path}")
    accept = tuple(accept)
    for name in accept:
        if name not in DIFFERENCES:
            from .scene_schema import did_you_mean

            raise MjcfMismatch(f"mjcf_accept: unknown difference {name!r} ({did_you_mean(name, DIFFERENCES)}"
                               f"known: {', '.join(DIFFERENCES)})")
    with tempfile.TemporaryDirectory(prefix="stiction-mjcf-") as tmp:
        flat = Path(tmp) / path.name
        flat.write_text(flatten_mjcf(path))
        try:
            model = pin.buildModelFromMJCF(str(flat))
            visual = pin.buildGeomFromMJCF(model, str(flat), pin.GeometryType.VISUAL)
            collision = pin.buildGeomFromMJCF(model, str(flat), pin.GeometryType.COLLISION)
        except (ValueError, RuntimeError) as exc:
            last = [line for line in str(exc).splitlines() if line.strip()][-1]
            raise MjcfMismatch(f"{path.name}: Pinocchio's MJCF parser fails: {last}") from None
    model.name = path.stem
    scale = 1.0
    wanted = _settotalmass(path)
    if wanted is not None and wanted > 0:  # MuJoCo scales every body's mass and inertia alike
        scale = wanted / total_mass(model)
        for j in range(model.njoints):
            inertia = model.inertias[j]
            model.inertias[j] = pin.Inertia(inertia.mass * scale, inertia.lever, inertia.inertia * scale)
    visual, kept = _moving(visual), _moving(collision)
    q0 = model.referenceConfigurations["qpos0"].copy() if "qpos0" in [k.key() for k in model.referenceConfigurations] \
        else pin.neutral(model)
    robot = MjcfRobot(path.stem, model, visual, kept, q0, path, checked=False, total_mass_scale=scale)
    if not check:
        return robot
    try:
        import mujoco  # noqa: F401
    except ImportError:
        if accept:
            raise MjcfMismatch(f"mjcf_accept = {list(accept)}: the differences from MuJoCo are checked with "
                               "MuJoCo, which is not installed (pip install mujoco)") from None
        return robot
    found = compare_with_mujoco(model, path)
    refused = [name for name in found if name not in accept]
    if refused:
        raise MjcfMismatch(f"{path.name}: Pinocchio's model differs from MuJoCo's: "
                           + "; ".join(found[n] for n in refused)
                           + f" (accept with mjcf_accept = {refused!r}: the scene then runs the differing model)")
    for name in accept:
        if name not in found:
            raise MjcfMismatch(f"mjcf_accept: {path.name} shows no {name!r} difference from MuJoCo; remove it")
    robot.checked, robot.differences = True, found
    return robot


def _moving(geometry: pin.GeometryModel) -> pin.GeometryModel:
    """The geoms of moving bodies: the world's (a floor, walls: unbounded planes) are left to the
    scene, which has its own ground."""
    kept = pin.GeometryModel()
    for go in geometry.geometryObjects:
        if go.parentJoint != 0:
            kept.addGeometryObject(go)
    return kept


def _mujoco_to_pinocchio_q(mj, qpos: np.ndarray) -> np.ndarray:
    """MuJoCo's qpos in Pinocchio's order: quaternions (w, x, y, z) -> (x, y, z, w)."""
    q = np.array(qpos, dtype=float)
    for j in range(mj.njnt):
        a, kind = int(mj.jnt_qposadr[j]), int(mj.jnt_type[j])
        start = a + 3 if kind == 0 else a if kind == 1 else None  # free, ball
        if start is not None:
            q[start:start + 4] = np.roll(q[start:start + 4], -1)
    return q


def mujoco_model(path: str | os.PathLike):
    """``mujoco.MjModel.from_xml_path(path)`` with MuJoCo's compiler warnings caught instead of
    appended to MUJOCO_LOG.TXT in the working folder: the deprecation of ``settotalmass`` (which
    the loader applies itself) is dropped, any other warning is a Python warning."""
    import warnings

    import mujoco

    caught: list[str] = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(caught.append)
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    finally:
        mujoco.set_mju_user_warning(previous)
    for message in caught:
        if "settotalmass" not in message:
            warnings.warn(f"MuJoCo on {Path(path).name}: {message}", stacklevel=2)
    return model


def compare_with_mujoco(model: pin.Model, path: str | os.PathLike, tolerance: float = TOLERANCE) -> dict[str, str]:
    """The differences between `model` and ``mujoco.MjModel.from_xml_path(path)``: a dict
    {name in DIFFERENCES: one-line description}, empty when they agree to `tolerance`
    (relative for masses and M). Once nq or nv differ, the later checks are not made."""
    mj = mujoco_model(path)
    out: dict[str, str] = {}
    if model.nq != mj.nq:
        out["nq"] = f"nq {model.nq} against MuJoCo's {mj.nq}"
    if model.nv != mj.nv:
        out["nv"] = f"nv {model.nv} against MuJoCo's {mj.nv}"
    mass, mj_mass = total_mass(model), float(np.sum(mj.body_mass))
    if abs(mass - mj_mass) > tolerance * max(1.0, mj_mass):
        out["total_mass"] = f"total mass {mass:.6g} kg against MuJoCo's {mj_mass:.6g} kg"
    if out.keys() & {"nq", "nv"}:
        return out
    bad = []
    for j in range(mj.njnt):
        if int(mj.jnt_type[j]) not in (2, 3):  # slide, hinge
            continue
        a = int(mj.jnt_qposadr[j])
        lo, hi = (mj.jnt_range[j] if mj.jnt_limited[j] else (-math.inf, math.inf))
        plo, phi = float(model.lowerPositionLimit[a]), float(model.upperPositionLimit[a])
        same = all((math.isinf(x) and math.isinf(y) and x * y > 0) or abs(x - y) <= tolerance * max(1.0, abs(y))
                   for x, y in ((plo, lo), (phi, hi)))
        if not same:
            bad.append(f"{mj.joint(j).name} [{plo:.6g}, {phi:.6g}] against [{lo:.6g}, {hi:.6g}]")
    if bad:
        out["joint_range"] = f"joint ranges of {len(bad)} joint(s): " + "; ".join(bad[:3]) + \
            (" ..." if len(bad) > 3 else "")
    M_pin, M_mj = mass_matrices(model, mj)
    err = float(np.max(np.abs(M_pin - M_mj))) if M_pin.size else 0.0
    if err > tolerance * max(1.0, float(np.max(np.abs(M_mj))) if M_mj.size else 1.0):
        i, k = np.unravel_index(int(np.argmax(np.abs(M_pin - M_mj))), M_pin.shape)
        out["mass_matrix"] = (f"M(qpos0) differs by up to {err:.3g} (entry [{i}, {k}]: {M_pin[i, k]:.6g} against "
                              f"MuJoCo's {M_mj[i, k]:.6g})")
    return out


def mass_matrices(model: pin.Model, mj) -> tuple[np.ndarray, np.ndarray]:
    """M(qpos0) with armature from Pinocchio (crba) and from MuJoCo (mj_fullM), both in Pinocchio's
    velocity coordinates: a MuJoCo free joint's linear velocity is in the world frame, Pinocchio's
    in the body's, v_mj = R v_pin, so M_pin = T^T M_mj T with T = diag(R, I) on its rows."""
    import mujoco

    data = mujoco.MjData(mj)
    mujoco.mj_forward(mj, data)
    M_mj = np.zeros((mj.nv, mj.nv))
    mujoco.mj_fullM(mj, data, M_mj)  # (MuJoCo 4: from d.M)
    q = _mujoco_to_pinocchio_q(mj, mj.qpos0)
    pdata = model.createData()
    M_pin = pin.crba(model, pdata, q)
    M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
    T = np.eye(mj.nv)
    for j in range(mj.njnt):
        if int(mj.jnt_type[j]) == 0:
            a, d = int(mj.jnt_qposadr[j]), int(mj.jnt_dofadr[j])
            x, y, z, w = q[a + 3:a + 7]
            T[d:d + 3, d:d + 3] = pin.Quaternion(w, x, y, z).toRotationMatrix()
    return M_pin, T.T @ M_mj @ T


@dataclass(frozen=True)
class GeomSphere:
    name: str
    frame: int
    offset: np.ndarray  # the centre in the frame
    radius: float


def geom_spheres(model: pin.Model, collision: pin.GeometryModel, patterns) -> list[GeomSphere]:
    """Contact spheres of the collision geoms whose names match one of the fnmatch `patterns`:
    a sphere geom is one sphere, a capsule the spheres at the two ends of its axis (exact against
    a plane). Each pattern must match a sphere or capsule geom; a matched geom of another shape
    is an error naming it."""
    import coal

    names = [go.name for go in collision.geometryObjects]
    out: list[GeomSphere] = []
    for pattern in patterns:
        matched = [go for go in collision.geometryObjects if fnmatch.fnmatchcase(go.name, pattern)]
        if not matched:
            from .scene_schema import did_you_mean

            raise ValueError(f"contacts.geoms: {pattern!r} matches no geom of a moving body "
                             f"({did_you_mean(pattern, names)}geoms: {', '.join(names) or 'none'})")
        for go in matched:
            if any(s.name.startswith(go.name + "@") or s.name == go.name for s in out):
                continue  # matched by an earlier pattern too
            frame = go.parentFrame
            to_frame = model.frames[frame].placement.inverse() * go.placement  # geom -> frame (both on one joint)
            shape = go.geometry
            if isinstance(shape, coal.Sphere):
                out.append(GeomSphere(go.name, frame, to_frame.translation.copy(), float(shape.radius)))
            elif isinstance(shape, coal.Capsule):
                for end, sign in (("a", -1.0), ("b", 1.0)):
                    centre = to_frame.act(np.array([0.0, 0.0, sign * float(shape.halfLength)]))
                    out.append(GeomSphere(f"{go.name}@{end}", frame, centre, float(shape.radius)))
            else:
                raise ValueError(f"contacts.geoms: geom {go.name!r} is a {type(shape).__name__}; contact spheres "
                                 "come from sphere and capsule geoms (use [collision] pairs for other shapes)")
    return out
