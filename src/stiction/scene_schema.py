"""The scene file schema: every key a scene TOML may hold, its type, range, default and meaning.

A scene file is checked against this schema before anything is built
(:func:`validate_scene`): an unknown key or table is an error naming the key, its table and
the closest valid key; a wrong type, shape or range is an error naming the field and the value.
Unknown input is never ignored, so a typo cannot silently run a different experiment.

The same schema renders the reference of the scene keys in the documentation
(:func:`reference_markdown`), so the docs cannot drift from what the loader accepts.
"""
from __future__ import annotations

import difflib
import math
from dataclasses import dataclass, field
from typing import Any


class SceneError(ValueError):
    """A scene file (or dict) that does not follow the schema. The message is one line."""


@dataclass(frozen=True)
class Key:
    """One key of a table.

    kind: "str", "bool", "float", "int", "vector" (a list of numbers; `length` fixes its size),
    "strings" (a list of strings), "pairs" (a list of [string, string]), "named_numbers" (a
    table of name = number).
    """

    name: str
    kind: str
    doc: str
    default: Any = None
    required: bool = False
    low: float | None = None  # inclusive unless low_open
    high: float | None = None  # inclusive unless high_open
    low_open: bool = False
    high_open: bool = False
    length: int | None = None
    nonzero: bool = False  # vectors: not all zero (directions)
    positive_entries: bool = False  # vectors: every entry > 0 (sizes)
    choices: tuple[str, ...] | None = None
    nonempty: bool = False  # lists


@dataclass(frozen=True)
class Table:
    """A TOML table ([name]) or array of tables ([[name]], `array=True`)."""

    name: str
    doc: str
    keys: tuple[Key, ...] = ()
    tables: tuple["Table", ...] = ()
    array: bool = False

    def key(self, name: str) -> Key | None:
        return next((k for k in self.keys if k.name == name), None)

    def table(self, name: str) -> "Table | None":
        return next((t for t in self.tables if t.name == name), None)

    def names(self) -> list[str]:
        return [k.name for k in self.keys] + [t.name for t in self.tables]


_VEC3 = dict(kind="vector", length=3)

CONTACT_MODELS = ("spatial", "planar", "frictionless")
_MODEL_DOC = ("contact model: spatial (3 rows t1, t2, n), planar (2 rows t1, n: `joint = \"planar\"` scenes only) or "
              "frictionless (1 unilateral row n); mu = 0 uses the 1 row automatically")

GROUND = Table("ground", "The ground plane z = 0; a slope tilts gravity (downhill = +x).", (
    Key("slope_deg", "float", "slope angle in degrees (gravity tilted about y)", 0.0, low=-89.0, high=89.0),
    Key("mu", "float", "friction coefficient of every contact unless a wall or pair sets its own", 0.5, low=0.0),
))

CONTACTS = Table("contacts", "Which points of the robot touch the ground (analytic sphere/point contacts).", (
    Key("feet", "bool", "a sphere at each foot frame of a bundled robot (default: true when it has feet)"),
    Key("radius", "float", "sphere radius in m for `feet` and `frames` (default: the robot's foot radius, "
        "0 for frames)", low=0.0),
    Key("frames", "strings", "extra frames carrying a contact sphere of `radius`", ()),
    Key("soles", "bool", "the sole corner points of a bundled humanoid", True),
    Key("geoms", "strings", "`mjcf` scenes: the MJCF's sphere and capsule geoms (names or fnmatch patterns) that "
        "touch the ground as contact spheres: a sphere geom is one, a capsule the two at the ends of its axis (exact "
        "against a plane)", ()),
    Key("box_corners", "bool", "the 8 corners of the URDF's box visual as contact points (`joint = \"planar\"`: "
        "the 4 corners in the joint's plane)", False),
    Key("model", "str", _MODEL_DOC, "spatial", choices=CONTACT_MODELS),
))

GAINS = Table("gains", "Per-joint gains: each entry sets kp and/or kd of the robot's joints whose names match one "
              "of its patterns, over the uniform `kp`, `kd` (entries apply in order: a later one wins).", (
    Key("joints", "strings", "joint names or shell-style patterns (fnmatch: `leg_*`, `arm_*_1_joint`); each must "
        "match a joint of the robot", required=True, nonempty=True),
    Key("kp", "float", "joint stiffness in N m/rad of the matched joints (default: unchanged)", low=0.0),
    Key("kd", "float", "joint damping in N m s/rad of the matched joints (default: unchanged)", low=0.0),
), array=True)

CONTROL = Table("control", "Joint PD towards the initial posture (or `q_target`), implicit in time stepping.", (
    Key("kp", "float", "joint stiffness in N m/rad", 0.0, low=0.0),
    Key("kd", "float", "joint damping in N m s/rad", 0.0, low=0.0),
    Key("q_target", "vector", "joint positions the PD holds (nq minus the free flyer's 7)"),
    Key("gravity_feedforward", "bool", "add tau_ff = the joint torques that hold q_target still: g(q_target) for a "
        "fixed base; for a free-flyer robot, its static equilibrium on its contacts that touch at q_target (the "
        "sphere/point contacts whose gaps are within 1 µm of the lowest): tau_ff = g(q) - J^T lambda, lambda the "
        "least-norm split of the weight over them (an error when that split needs a pulling or slipping contact)",
        False),
    Key("lock_joints", "bool", "hold every joint at its initial value (a rigid robot)", False),
), tables=(GAINS,))

JOINT_OVERRIDE = Table("override", "Per-joint values over the URDF's (entries apply in order: a later one wins); "
                       "each value replaces the model's for every joint whose name matches one of the patterns.", (
    Key("joints", "strings", "joint names or shell-style patterns (fnmatch); each must match a joint of the robot",
        required=True, nonempty=True),
    Key("lower", "float", "lower position limit in rad or m (1-dof joints; default: the URDF's)"),
    Key("upper", "float", "upper position limit in rad or m (1-dof joints; default: the URDF's)"),
    Key("friction", "float", "dry friction torque tau_c in N m or N (0: none; default: the URDF's)", low=0.0),
    Key("damping", "float", "viscous damping in N m s/rad or N s/m (default: the URDF's)", low=0.0),
    Key("effort", "float", "actuator effort limit in N m or N (0: none; default: the URDF's)", low=0.0),
), array=True)

JOINTS = Table("joints", "The joints' own rows of the step problem, from the URDF (`<limit lower upper effort>`, "
               "`<dynamics friction damping>`; docs/joint-rows.md): position limits as unilateral rows, dry friction "
               "as box rows |lambda| <= h tau_c (exact stiction), effort limits on feed-forward + PD, damping implicit.",
               (
    Key("limits", "bool", "1-dof joints' position limits as unilateral rows (within `limit_margin`)", True),
    Key("friction", "bool", "dry joint friction as box rows (exact stiction)", True),
    Key("damping", "bool", "viscous joint damping, implicit in time stepping", True),
    Key("effort_limits", "bool", "actuator effort limits: |tau_ff + PD| <= effort (box rows with the implicit PD)",
        True),
    Key("limit_margin", "float", "rad or m: a limit's row enters the problem within this distance (or when the joint "
        "would reach it in a step)", 0.02, low=0.0),
), tables=(JOINT_OVERRIDE,))

INITIAL = Table("initial", "The initial state.", (
    Key("q", "vector", "the full configuration (nq entries; quaternions x, y, z, w, non-zero)"),
    Key("base_velocity", "vector", "free-flyer velocity [vx, vy, vz, wx, wy, wz] (local frame)", length=6),
    Key("planar_velocity", "vector", "`joint = \"planar\"`: velocity [vx, vy, w] of the planar joint (body frame; "
        "vx along world x, vy up)", length=3),
    Key("base_xy", "vector", "free-flyer x, y position", length=2),
    Key("drop", "float", "height in m above touching the ground", 0.0, low=0.0),
    Key("top_velocity", "vector", "`bodies` scenes: velocity of the top body (6 entries)", length=6),
    Key("joints", "named_numbers", "positions of named 1-dof joints over the robot's reference posture, e.g. "
        "{ leg_left_6_joint = 0.0 } (rad or m; the PD holds them too unless `q_target` is given); a robot "
        "scene without initial.q"),
))

WALLS = Table("walls", "Extra fixed half-spaces {x : normal . x >= offset} and the spheres that touch them.", (
    Key("name", "str", "a name for messages and recordings"),
    Key("normal", "vector", "outward normal of the free space (world frame)", required=True, length=3,
        nonzero=True),
    Key("offset", "float", "free space: normal . x >= offset (normal normalised)", required=True),
    Key("frames", "strings", "frames carrying a sphere against this wall", ()),
    Key("radius", "float", "sphere radius in m", 0.0, low=0.0),
    Key("offset_in_frame", "vector", "sphere centre in the frame", (0.0, 0.0, 0.0), length=3),
    Key("mu", "float", "friction coefficient (default: [ground] mu)", low=0.0),
    Key("model", "str", "contact model of the wall's spheres (default: [contacts] model)", choices=CONTACT_MODELS),
    Key("body", "str", "the name of an `[[objects]]` box carrying the half-space (normal and offset then in its "
        "frame: a face of the box; default: fixed in the world)"),
), array=True)

OBJECTS = Table("objects", "Free boxes added to a `robot` or `urdf` scene, each a part of the world with its own "
                "model: its four bottom corners rest on the ground; a robot touches it through a `[[walls]]` "
                "entry with `body` = its name (a face of the box).", (
    Key("name", "str", "the box's name (its frames are suffixed with it; `walls.body` refers to it)",
        required=True),
    Key("urdf", "str", "a box URDF (relative: to the scene file's folder, then the bundled robots)", "cube.urdf"),
    Key("xy", "vector", "centre x, y in the world (the box rests on the ground; boxes may touch, not overlap)",
        required=True, length=2),
    Key("z", "float", "height in m of the box's bottom above the ground (0: it rests on it; above: held by the "
        "robot, e.g. between two pads, or falling)", 0.0, low=0.0),
    Key("mu", "float", "friction coefficient of its corners on the ground (default: [ground] mu)", low=0.0),
), array=True)

ANCHORS = Table("anchors", "Point anchors: 3 bilateral rows each (paper §3), to the world or to another body.", (
    Key("name", "str", "a name for messages"),
    Key("frame", "str", "the frame of the held point", required=True),
    Key("offset", "vector", "the point in `frame`", (0.0, 0.0, 0.0), length=3),
    Key("target", "vector", "world point it is held to (default: where it is at q0)", length=3),
    Key("frame2", "str", "hold it to a point of this frame instead (a closed loop)"),
    Key("offset2", "vector", "the point in `frame2`", (0.0, 0.0, 0.0), length=3),
), array=True)

BOXES = Table("boxes", "Fixed world boxes for the coal pairs.", (
    Key("name", "str", "geometry name used in `pairs`", required=True),
    Key("size", "vector", "edge lengths in m", required=True, length=3, positive_entries=True),
    Key("position", "vector", "centre in the world", (0.0, 0.0, 0.0), length=3),
), array=True)

COLLISION = Table("collision", "General shapes through coal: pairs among the URDF's collision geometries, "
                  "\"ground\" (the plane z = 0) and fixed world boxes.", (
    Key("pairs", "pairs", "[[geometry a, geometry b], ...]", required=True, nonempty=True),
    Key("mu", "float", "friction coefficient of the pairs (default: [ground] mu)", low=0.0),
    Key("max_contacts", "int", "contact points per pair", 4, low=1, high=64),
    Key("model", "str", "contact model of the pairs: spatial (3 rows) or frictionless (1 row); mu = 0: 1 row",
        "spatial", choices=("spatial", "frictionless")),
    Key("patch", "bool", "coal's contact patches: a face on a face touches at up to max_contacts vertices of their "
        "overlap (a box rests flat); false: coal's deepest point(s) only. Convex shapes and half-spaces only, not "
        "meshes", False),
), tables=(BOXES,))

ARRAY = Table("array", "An array of free bodies (instead of `robot`, `urdf` or `bodies`): a grid of boxes side by "
              "side on the ground or a tower of boxes (each box's four bottom corners touch the ground or the box "
              "below), or a random pile of boxes and balls dropped from a seed (their corners and spheres touch the "
              "ground; body against body through coal's contact patches, only for pairs whose bounding spheres come "
              "within the activation distance)", (
    Key("urdf", "str", "grid, tower: a box URDF (relative: to the scene file's folder, then the bundled robots)",
        "cube.urdf"),
    Key("layout", "str", "grid: side by side on the ground (rows of ceil(sqrt(count))); tower: stacked; pile: "
        "dropped at random from a seed", required=True, choices=("grid", "tower", "pile")),
    Key("count", "int", "number of bodies", required=True, low=1, high=4096),
    Key("spacing", "float", "grid: centre-to-centre distance in m (default: twice the box's width); pile: of the "
        "drop lattice (default: 1.2 times the largest bounding diameter)", low=0.0, low_open=True),
    Key("urdfs", "strings", "pile: the box and ball URDFs each body is drawn from (a box or sphere visual)",
        ("cube.urdf", "ball.urdf"), nonempty=True),
    Key("seed", "int", "pile: the random seed of the bodies' kinds, positions and orientations", 0, low=0),
    Key("mix", "strings", "pile: the shapes each body is drawn from, uniformly (repeat one to weigh it): box, "
        "sphere, capsule, cylinder, mesh (a convex hull of random points); dropped into a bin, every contact "
        "(body, floor, walls: mu of [ground]) through coal, the pairs found each step by the broad phase "
        "(stiction.pile). Instead of `urdfs`", nonempty=True),
    Key("bin", "float", "pile with `mix`: the bin's half width in m (default: rows of ceil(sqrt(count / 3)) "
        "bodies on the drop lattice)", low=0.0, low_open=True),
    Key("pairs_per_body", "int", "pile with `mix`: pool entries (pairs of shapes in contact range at once, 4 "
        "contact slots each) per body", 6, low=1, high=64),
))

CONTROLLER = Table("controller", "A controller run before every step by `Simulator.rollout` and `stiction simulate` "
                   "(stiction.controllers: it reads q, v, t and writes the joint PD's tau_ff, q_target, v_target, kp, "
                   "kd; docs/controllers.md).", (
    Key("name", "str", "a bundled controller (stiction.controllers.CONTROLLERS: trot) or \"module:Class\" of your "
        "own, imported from the Python path", required=True),
    Key("parameters", "named_numbers", "the controller's parameters by name (each checked against its PARAMETERS; "
        "default: the controller's defaults)"),
))

SCENE = Table("scene", "A scene: exactly one of `robot`, `urdf`, `mjcf`, `bodies` or `[array]`, the ground, contacts, "
              "control, the initial state.", (
    Key("name", "str", "scene name (default: the file name)"),
    Key("description", "str", "one line shown by `stiction scenes`", ""),
    Key("robot", "str", "a bundled robot (stiction.robots.ROBOTS)"),
    Key("urdf", "str", "a URDF path (relative: to the scene file's folder, then the bundled robots)"),
    Key("mjcf", "str", "an MJCF (MuJoCo XML) path, loaded with Pinocchio's MJCF parser (relative: to the scene "
        "file's folder, then the bundled robots, e.g. \"mjcf/dm_control/hopper.xml\"); the file defines the root "
        "joint. Checked against MuJoCo's model of the same file when MuJoCo is installed (docs/mjcf.md)"),
    Key("mjcf_accept", "strings", "`mjcf`: differences from MuJoCo's model to accept by name (nq, nv, total_mass, "
        "joint_range, mass_matrix); any other difference is an error, and so is a name the model does not show", ()),
    Key("free_flyer", "bool", "`urdf`: a free-flyer root joint", True),
    Key("joint", "str", "`urdf`: the root joint (default: free_flyer, or fixed when free_flyer = false). planar: "
        "Pinocchio's planar joint (x, y, rotation about z) placed in the world's vertical x-z plane (joint x = "
        "world x, joint y = world z, up); q = [x, z, cos, sin]", choices=("free_flyer", "planar", "fixed")),
    Key("bodies", "strings", "free-flying URDF boxes stacked in the listed order", nonempty=True),
    Key("duration", "float", "seconds simulated by default", 2.0, low=0.0, low_open=True),
    Key("dt", "float", "time step in s", 1e-3, low=0.0, low_open=True),
    Key("settle_time", "float", "seconds excluded from the drift and slip measures (shorter than `duration`)", 0.0,
        low=0.0),
    Key("mode", "str", "integration: time stepping (eq. 70) or the relaxed DAI as an ODE (eq. 64)", "timestep",
        choices=("timestep", "rk4", "ode", "adaptive")),
    Key("delta", "float", "ODE modes: Baumgarte delta in s (0: dt)", 0.0, low=0.0),
    Key("zeta", "float", "ODE modes: Baumgarte zeta", 0.5, low=0.0, low_open=True),
), tables=(GROUND, CONTACTS, CONTROL, JOINTS, INITIAL, WALLS, ANCHORS, COLLISION, ARRAY, OBJECTS, CONTROLLER))


def _where(path: str) -> str:
    return f"[{path}]" if path else "the top level"


def did_you_mean(name: str, options, cutoff: float = 0.5) -> str:
    """"did you mean 'x'? " for the option closest to a misspelt name, or "" (every "unknown ..."
    message of the package uses it)."""
    match = difflib.get_close_matches(str(name), list(options), n=1, cutoff=cutoff)
    return f"did you mean {match[0]!r}? " if match else ""


def _closest(name: str, options: list[str]) -> str:
    hint = did_you_mean(name, options)
    return f" ({hint.strip()})" if hint else f" (valid: {', '.join(options)})"


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _check_value(key: Key, value, where: str) -> Any:
    label = f"{where}.{key.name}" if where else key.name

    def fail(expected: str):
        raise SceneError(f"{label} = {value!r}: {expected}")

    def in_range(x: float) -> bool:
        if key.low is not None and (x < key.low or (key.low_open and x == key.low)):
            return False
        if key.high is not None and (x > key.high or (key.high_open and x == key.high)):
            return False
        return True

    def range_text() -> str:
        lo = "" if key.low is None else f"{'>' if key.low_open else '>='} {key.low:g}"
        hi = "" if key.high is None else f"{'<' if key.high_open else '<='} {key.high:g}"
        return " and ".join(p for p in (lo, hi) if p)

    if key.kind == "str":
        if not isinstance(value, str):
            fail("must be a string")
        if key.choices is not None and value not in key.choices:
            fail(f"must be one of {', '.join(key.choices)}")
        return value
    if key.kind == "bool":
        if not isinstance(value, bool):
            fail("must be true or false")
        return value
    if key.kind in ("float", "int"):
        if not _is_number(value) or (key.kind == "int" and not isinstance(value, int)):
            fail("must be " + ("an integer" if key.kind == "int" else "a number"))
        if not math.isfinite(value):
            fail("must be finite")
        if not in_range(value):
            fail(f"must be {range_text()}")
        return int(value) if key.kind == "int" else float(value)
    if key.kind == "vector":
        if not isinstance(value, list) or not all(_is_number(x) for x in value):
            fail("must be a list of numbers" + (f" ({key.length} entries)" if key.length else ""))
        if key.length is not None and len(value) != key.length:
            fail(f"must have {key.length} entries, got {len(value)}")
        if not all(math.isfinite(x) for x in value):
            fail("entries must be finite")
        if key.nonzero and not any(x != 0 for x in value):
            fail("must not be the zero vector")
        if key.positive_entries and not all(x > 0 for x in value):
            fail("entries must be > 0")
        return [float(x) for x in value]
    if key.kind == "strings":
        if not isinstance(value, list) or not all(isinstance(x, str) for x in value):
            fail("must be a list of strings")
        if key.nonempty and not value:
            fail("must not be empty")
        return list(value)
    if key.kind == "pairs":
        if (not isinstance(value, list) or not all(isinstance(p, list) and len(p) == 2 and
                                                   all(isinstance(x, str) for x in p) for p in value)):
            fail("must be a list of [name, name] pairs")
        if key.nonempty and not value:
            fail("must not be empty")
        return [list(p) for p in value]
    if key.kind == "named_numbers":
        if not isinstance(value, dict) or not all(isinstance(k, str) and _is_number(x) for k, x in value.items()):
            fail("must be a table of name = number")
        if not all(math.isfinite(x) for x in value.values()):
            fail("entries must be finite")
        return {k: float(x) for k, x in value.items()}
    raise AssertionError(f"schema: unknown kind {key.kind}")


def _validate_table(table: Table, cfg, path: str, present: bool = True) -> dict:
    """The table with defaults filled in; `present=False` for an absent table (defaults only,
    no required keys)."""
    if not isinstance(cfg, dict):
        raise SceneError(f"{_where(path) if path else 'the scene'} must be a table, got {cfg!r}")
    out: dict = {}
    for name, value in cfg.items():
        key, sub = table.key(name), table.table(name)
        if key is None and sub is None:
            raise SceneError(f"unknown key {name!r} in {_where(path)}{_closest(name, table.names())}")
        child = f"{path}.{name}" if path else name
        if key is not None:
            out[name] = _check_value(key, value, path)
        elif sub.array:
            if isinstance(value, dict):
                raise SceneError(f"{child} must be an array of tables: write [[{child}]], not [{child}]")
            if not isinstance(value, list):
                raise SceneError(f"{child} must be an array of tables ([[{child}]]), got {value!r}")
            out[name] = [_validate_table(sub, item, f"{child}[{i}]") for i, item in enumerate(value)]
        else:
            if isinstance(value, list):
                raise SceneError(f"{child} must be a table: write [{child}], not [[{child}]]")
            out[name] = _validate_table(sub, value, child)
    for key in table.keys:
        if key.name not in out:
            if key.required and present:
                raise SceneError(f"{_where(path)}: missing required key {key.name!r} ({key.doc})")
            out[key.name] = list(key.default) if isinstance(key.default, tuple) else key.default
    for sub in table.tables:
        if sub.name not in out:
            out[sub.name] = [] if sub.array else _validate_table(sub, {}, f"{path}.{sub.name}" if path else sub.name,
                                                                 present=False)
    return out


def validate_scene(cfg: dict, source: str = "scene") -> dict:
    """Check a scene (the dict of a TOML file) against the schema; return it with every default
    filled in. Raises SceneError (a ValueError) with one line naming the file, field and value."""
    try:
        out = _validate_table(SCENE, cfg, "")
        given = [k for k in ("robot", "urdf", "mjcf", "bodies", "array") if k in cfg]
        if len(given) != 1:
            raise SceneError("a scene needs exactly one of `robot`, `urdf`, `mjcf`, `bodies` or `[array]`" +
                             (f", got {', '.join(given)}" if given else ""))
        if "controller" not in cfg:
            out["controller"] = None
        else:
            _check_controller(out["controller"])
        if "array" not in cfg:
            out["array"] = None
        else:
            layout = out["array"]["layout"]
            if layout == "tower" and out["array"]["spacing"] is not None:
                raise SceneError("array.spacing applies to layout = \"grid\" or \"pile\" only")
            for key in ("urdfs", "seed", "mix", "bin", "pairs_per_body"):
                if layout != "pile" and key in cfg["array"]:
                    raise SceneError(f"array.{key} applies to layout = \"pile\" only")
            for key in ("bin", "pairs_per_body"):
                if key in cfg["array"] and "mix" not in cfg["array"]:
                    raise SceneError(f"array.{key} applies to a pile with `mix` only")
            if "mix" in cfg["array"] and "urdfs" in cfg["array"]:
                raise SceneError("array.mix and array.urdfs: a pile draws its bodies from one of them")
            if layout == "pile" and "urdf" in cfg["array"]:
                raise SceneError("array.urdf: a pile draws its bodies from `urdfs`")
        robot_scene = any(out[k] is not None for k in ("robot", "urdf", "mjcf"))
        if out["mjcf"] is None:
            if "mjcf_accept" in cfg:
                raise SceneError("mjcf_accept applies to `mjcf` scenes only")
            if out["contacts"]["geoms"]:
                raise SceneError("contacts.geoms applies to `mjcf` scenes only (the MJCF's geoms)")
        elif "free_flyer" in cfg:
            raise SceneError("free_flyer: an `mjcf` scene's root joint is the MJCF file's own (a <freejoint>, or "
                             "the slides and hinges of its top body)")
        if out["objects"] and not robot_scene:
            raise SceneError("objects: free boxes are added to `robot` or `urdf` scenes (and `mjcf` ones; `bodies` "
                             "and [array] scenes are boxes already)")
        names = [o["name"] for o in out["objects"]]
        if len(set(names)) != len(names):
            raise SceneError(f"objects: names must be unique, got {names}")
        if out["settle_time"] >= out["duration"]:
            raise SceneError(f"settle_time = {out['settle_time']:g} must be shorter than duration = "
                             f"{out['duration']:g} (drift and slip are measured after settling)")
        planar_root = out["joint"] == "planar" or out["mjcf"] is not None  # (mjcf: checked on the model)
        for label, model in [("contacts.model", out["contacts"]["model"])] + \
                [(f"walls[{i}].model", w["model"]) for i, w in enumerate(out["walls"])]:
            if model == "planar" and not planar_root:
                raise SceneError(f"{label} = \"planar\": planar contacts (rows t1, n: no friction across the "
                                 "plane) need a planar scene (joint = \"planar\"); this scene moves in 3-D: use "
                                 "spatial")
        if out["mode"] == "timestep" and "delta" in cfg:
            raise SceneError("delta applies to the ODE modes (mode = rk4, ode or adaptive) only")
        if "joint" in cfg and "free_flyer" in cfg and (out["joint"] == "free_flyer") != out["free_flyer"]:
            raise SceneError(f"joint = {out['joint']!r} contradicts free_flyer = {str(out['free_flyer']).lower()}; "
                             "give `joint` only")
        if out["joint"] is not None and out["urdf"] is None:
            raise SceneError("joint applies to `urdf` scenes only")
        for i, g in enumerate(out["control"]["gains"]):
            if g["kp"] is None and g["kd"] is None:
                raise SceneError(f"control.gains[{i}]: give kp, kd or both (joints {g['joints']} would keep their gains)")
        for i, o in enumerate(out["joints"]["override"]):
            if all(o[k] is None for k in ("lower", "upper", "friction", "damping", "effort")):
                raise SceneError(f"joints.override[{i}]: give at least one of lower, upper, friction, damping, effort")
            if o["lower"] is not None and o["upper"] is not None and o["lower"] > o["upper"]:
                raise SceneError(f"joints.override[{i}]: lower = {o['lower']:g} is above upper = {o['upper']:g}")
        if out["joints"]["override"] and not robot_scene:
            raise SceneError("joints.override applies to `robot`, `urdf` and `mjcf` scenes (the bodies of the others have no "
                             "joints)")
        for i, a in enumerate(out["anchors"]):
            if a["target"] is not None and a["frame2"] is not None:
                raise SceneError(f"anchors[{i}]: give `target` or `frame2`, not both")
    except SceneError as exc:
        raise SceneError(f"{source}: {exc}") from None
    return out


def _check_controller(cfg: dict) -> None:
    """[controller]: a bundled name (did you mean ...) and its parameter names; a user's
    "module:Class" is imported when the simulator is built, not here."""
    name = cfg["name"]
    if ":" in name:
        module, _, attr = name.partition(":")
        if not module or not attr:
            raise SceneError(f"controller.name = {name!r}: write \"module:Class\" for a controller of your own")
        return
    from .controllers import CONTROLLERS, check_parameters  # noqa: PLC0415 - (imports this module)

    if name not in CONTROLLERS:
        raise SceneError(f"controller.name = {name!r}: unknown controller ({did_you_mean(name, CONTROLLERS)}"
                         f"bundled: {', '.join(CONTROLLERS)}; or \"module:Class\")")
    check_parameters(CONTROLLERS[name], cfg["parameters"] or {})


# ---- documentation

def _default_text(key: Key) -> str:
    if key.required:
        return "required"
    if key.default is None:
        return "—"
    if isinstance(key.default, bool):
        return "true" if key.default else "false"
    if isinstance(key.default, str):
        return f'"{key.default}"'
    if isinstance(key.default, (tuple, list)):
        return "[" + ", ".join(f"{x:g}" if _is_number(x) else repr(x) for x in key.default) + "]"
    return f"{key.default:g}"


def _type_text(key: Key) -> str:
    base = {"str": "string", "bool": "bool", "float": "number", "int": "integer", "strings": "list of strings",
            "pairs": "list of [name, name]", "named_numbers": "table of name = number"}.get(key.kind, "list of numbers")
    if key.kind == "vector" and key.length:
        base = f"{key.length} numbers"
    if key.choices:
        base += " (" + ", ".join(key.choices) + ")"
    lo = "" if key.low is None else f"{'>' if key.low_open else '≥'} {key.low:g}"
    hi = "" if key.high is None else f"{'<' if key.high_open else '≤'} {key.high:g}"
    rng = ", ".join(p for p in (lo, hi) if p)
    return f"{base}, {rng}" if rng else base


def reference_markdown() -> str:
    """The scene keys as Markdown tables, one per table of the schema (for the docs)."""
    lines = ["# Scene file keys", "",
             "Generated from `stiction.scene_schema` (the schema the loader enforces; regenerate with",
             "`python -c \"from stiction.scene_schema import reference_markdown as r; print(r())\" > docs/scene-keys.md`).",
             "Unknown keys are errors; so are wrong types, shapes and ranges.", ""]

    def emit(table: Table, heading: str):
        lines.extend([f"## {heading}", "", table.doc, "", "| key | type | default | meaning |", "|---|---|---|---|"])
        for k in table.keys:
            lines.append(f"| `{k.name}` | {_type_text(k)} | {_default_text(k)} | {k.doc} |")
        lines.append("")
        for sub in table.tables:
            name = heading.strip("[]") + "." + sub.name if table is not SCENE else sub.name
            emit(sub, f"[[{name}]]" if sub.array else f"[{name}]")

    emit(SCENE, "Top level")
    return "\n".join(lines)
