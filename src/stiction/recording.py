"""Headless recordings: a rollout to one self-contained HTML file (meshcat).

No server and no display: meshcat's scene commands are collected in memory by a window
object of our own and written, with the viewer's JavaScript, into one HTML page that replays
the animation when opened (its commands decoded and run in order as the page loads).
Pinocchio 4.1's MeshcatVisualizer has no recording helper, so the animation is built here
from the recorded configurations: every visual geometry node gets a transform track, every
candidate contact a marker and one force arrow per contact state (see `record_html` for
what is drawn and how the arrows are keyed).
"""
from __future__ import annotations

import html as _html
import json
import math
import os
from pathlib import Path

import numpy as np
import pinocchio as pin

from . import _core

# Arrow colours per contact state (traj.states: 0 open, 1 stick, 2 slip, 3 closed/bilateral).
COLORS = {"stick": 0x22AA44, "slip": 0xDD2222, "closed": 0x2255DD}
STATE_CODES = {"stick": 1, "slip": 2, "closed": 3}
LEGEND_ID = "stiction-legend"
CAMERA_FOV_DEG = 75.0  # meshcat's default perspective camera


class _OfflineWindow:
    """The part of meshcat.visualizer.ViewerWindow that Visualizer uses (send, get_scene),
    keeping the scene tree in memory instead of talking to a server. `overlay` (HTML put over
    the 3-D pane) and `post_script` (JavaScript run after the scene commands) are ours."""

    web_url = "offline://"
    server_proc = None

    def __init__(self):
        from meshcat.servers.tree import SceneTree

        self.tree = SceneTree()
        self.overlay = ""
        self.post_script = ""

    def send(self, command):
        import umsgpack
        from meshcat.servers.tree import SceneTree, find_node

        d = command.lower()
        path = [p for p in d["path"].split("/") if p]
        packed = umsgpack.packb(d)
        kind = d["type"]
        if kind == "set_transform":
            find_node(self.tree, path).transform = packed
        elif kind == "set_object":
            node = find_node(self.tree, path)
            node.object, node.properties = packed, []
        elif kind == "set_property":
            find_node(self.tree, path).properties.append(packed)
        elif kind == "set_animation":
            find_node(self.tree, path).animation = packed
        elif kind == "delete":
            if path:
                parent = find_node(self.tree, path[:-1])
                if path[-1] in parent:
                    del parent[path[-1]]
            else:
                self.tree = SceneTree()

    def get_scene(self) -> str:
        import base64

        from meshcat.servers.tree import walk
        from meshcat.servers.zmqserver import VIEWER_ROOT

        commands, animations = [], []
        for node in walk(self.tree):
            commands += ([node.object] if node.object is not None else []) + list(node.properties) + \
                ([node.transform] if node.transform is not None else [])
            if node.animation is not None:
                animations.append(node.animation)
        # Animations last: a clip binds its tracks ("shaft.scale") to the nodes that exist
        # when it is loaded, and walk() visits the root (which holds the animation) first.
        # meshcat's own static page fetch()es every command from a data: URL, which runs them
        # asynchronously, in no promised order; decoded here, they run in order, at load.
        calls = "".join(f'_stictionCommand("{base64.b64encode(c).decode()}");\n' for c in commands + animations)
        js = Path(VIEWER_ROOT, "main.min.js").read_text()
        return (
            "<!DOCTYPE html>\n<html><head><meta charset=utf-8><title>stiction recording</title></head>\n"
            "<body><div id=\"meshcat-pane\"></div>\n" + self.overlay + "\n<script>" + js + "</script>\n"
            "<script>var viewer = new MeshCat.Viewer(document.getElementById(\"meshcat-pane\"));\n"
            "function _stictionCommand(b64) {\n"
            "  var s = atob(b64), a = new Uint8Array(s.length);\n"
            "  for (var i = 0; i < s.length; i++) a[i] = s.charCodeAt(i);\n"
            "  viewer.handle_command_bytearray(a);\n}\n"
            + calls + self.post_script +
            "</script>\n<style>body {margin: 0; } #meshcat-pane { width: 100vw; height: 100vh; overflow: hidden; }"
            "</style>\n</body></html>\n")

    def get_image(self):
        raise RuntimeError("offline recording: no browser attached")


class _SetAnimation:
    """meshcat's set_animation command from already-lowered clips: meshcat.animation keys only
    position and quaternion, the arrows also need scale and visibility tracks."""

    def __init__(self, animations, play=True, repetitions=1):
        self.animations, self.play, self.repetitions = animations, play, repetitions

    def lower(self):
        return {"type": "set_animation", "animations": self.animations,
                "options": {"play": self.play, "repetitions": self.repetitions}, "path": ""}


def _nice_ceil(x: float) -> float:
    """The smallest of 1, 2, 2.5, 5 x 10^k that is >= x (x > 0)."""
    e = math.floor(math.log10(x))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        v = m * 10.0 ** e
        if v >= x * (1 - 1e-12):
            return float(f"{v:.12g}")
    return 10.0 ** (e + 1)


def _quat_y_to(d: np.ndarray) -> list:
    """Quaternion [x, y, z, w] (three.js order) turning +y (the cylinders' axis) onto unit d."""
    y = np.array([0.0, 1.0, 0.0])
    c = float(np.dot(y, d))
    if c < -1.0 + 1e-12:
        return [1.0, 0.0, 0.0, 0.0]  # half turn about x
    axis = np.cross(y, d)
    w = 1.0 + c
    q = np.array([axis[0], axis[1], axis[2], w])
    q /= np.linalg.norm(q)
    return [float(v) for v in q]


def _track(name, jstype, values, frames=None):
    frames = range(len(values)) if frames is None else frames
    return {"name": name, "type": jstype, "keys": [{"time": int(f), "value": v} for f, v in zip(frames, values)]}


def _fill_hidden(values: list, shown: np.ndarray) -> list:
    """Hidden frames hold the last shown value (the first shown one before it appears), so a
    linearly keyed track never moves while its arrow is hidden nor in the frame interval
    where the arrow disappears: no half-length arrow of a state the contact has left."""
    out = list(values)
    if not shown.any():
        return out
    first = int(np.argmax(shown))
    last = out[first]
    for k in range(len(out)):
        if shown[k]:
            last = out[k]
        else:
            out[k] = last
    return out


def _fmt(x: float) -> str:
    return f"{x:.4g}"


def visual_poses(visual_model, oMi: np.ndarray) -> np.ndarray:
    """World placement of every visual geometry, (N, geometries, 4, 4), from the joints' world
    placements oMi (N, joints, 4, 4) (`Simulator.joint_placements`): oMi[parent] @ placement, what
    `pinocchio.updateGeometryPlacements` computes, without a world Data."""
    objects = visual_model.geometryObjects
    parents = [go.parentJoint for go in objects]
    local = np.array([np.asarray(go.placement.homogeneous) for go in objects]).reshape(len(objects), 4, 4)
    return np.einsum("kgab,gbc->kgac", oMi[:, parents], local)


def _pair_slots(sim, traj, idx) -> tuple[np.ndarray, np.ndarray]:
    """The point and the (t1, t2, n) frame (columns) of every coal pair slot at the trajectory rows
    `idx`, as the solve of each row's step saw them: detection run again (on a scratch
    SimulatorData) at the configuration the step started from, row j - 1 when the rows are
    consecutive steps (row 0 and coarser recordings: row j). Returns (len(idx), slots, 3) and
    (len(idx), slots, 3, 3)."""
    nc = len(sim.scene.contacts)
    slots = traj.lam.shape[1] - nc
    scratch = _core.SimulatorData(sim.model)
    dt = sim.model.settings.dt
    points, frames = np.zeros((len(idx), slots, 3)), np.zeros((len(idx), slots, 3, 3))
    for k, j in enumerate(idx):
        start = j - 1 if j > 0 and abs((traj.t[j] - traj.t[j - 1]) - dt) <= 1e-9 * max(1.0, dt) else j
        _core.build_contact_problem(sim.model, scratch, traj.q[start], traj.v[start], dt, 0.5)
        points[k] = np.asarray(scratch.pair_points).T[nc:]
        frames[k] = np.stack([np.asarray(scratch.pair_t1).T[nc:], np.asarray(scratch.pair_t2).T[nc:],
                              np.asarray(scratch.pair_normals).T[nc:]], axis=2)
    return points, frames


def record_html(sim, traj, path: str | os.PathLike, fps: int = 50, force_scale: float | None = None) -> dict:
    """Write `traj` of simulator `sim` to a self-contained HTML file (meshcat viewer).

    Frame k shows the trajectory at t0 + k / fps (the first sample at or after it). Drawn:
    the robot's visual geometries (transform tracks), per sphere/point contact a grey marker
    at the contact point and its force: an arrow from the contact point along the force the
    ground exerts (traj.lam in the half-space frame), green while the contact sticks, red
    while it slips, blue while a bilateral contact is closed (state 3; only if it occurs),
    nothing while it is open or before the first step (record 0: state -1, no force yet). Exactly one arrow (the state's own) is visible per closed
    contact. The arrow's shaft is `|force| / force_scale` long (metres); the cone at its
    tip has a fixed size and is not part of that length. Arrow position, direction and
    length are keyed per frame and interpolate linearly between frames; visibility is
    keyed as booleans (discrete: the state of frame k holds until frame k + 1), and a hidden
    arrow holds its last shown pose, so a state change never shows a shrinking arrow of the
    old state. Coal geometry-pair contacts (ball-on-table, the bodies of a pile) are drawn the
    same way, for the slots closed at some frame: the arrow shows the force on the pair's
    *first* geometry (the ball on the table), from the slot's point; their points and frames are
    not in the trajectory, so the recorder runs detection again at the configuration each
    drawn step solved at (`_pair_slots`).

    The slope is drawn by tilting the scene's root node (gravity is tilted in the physics).
    The camera (meshcat's, 75 degree field of view) is placed so that the bounding sphere
    of the robot's box over the whole trajectory, force arrows included up to the scale's
    reference force, fills the view, looking from -y, a little from +x and from above; an
    HTML legend (id "stiction-legend") gives the colours and the force scale.

    force_scale: N per metre of arrow shaft; default: a round number (1, 2, 2.5 or 5 x 10^k)
    such that the 98th percentile of the drawn forces is at most 30 % of the scene's size.

    Returns {frames, duration (s), tracks, bytes, force_scale (N/m)}: `tracks` counts the
    animated scene nodes (one three.js clip/action each): the visual geometries, and per
    contact its marker and one arrow per drawn state (stick, slip, and closed if it occurs).
    """
    from ._optional import require

    meshcat = require("meshcat", "record", "HTML recordings")
    import meshcat.geometry as mg
    from meshcat.animation import Animation
    from pinocchio.visualize import MeshcatVisualizer

    scene = sim.scene
    model = scene.model
    window = _OfflineWindow()
    vis = meshcat.Visualizer(window=window)
    root = "stiction"
    # An empty model's Data: the visualizer would build one for the world model (nv^3 tensors:
    # out of memory for a world of many bodies); placements come from the simulator, part by part.
    viz = MeshcatVisualizer(model, None, scene.visual_model, data=pin.Model().createData())
    viz.initViewer(viewer=vis)
    viz.loadViewerModel(rootNodeName=f"{root}/robot")
    # The slope is tilted gravity; tilt the picture instead so gravity points down.
    tilt = np.eye(4)
    tilt[:3, :3] = pin.utils.rotate("y", math.radians(scene.slope_deg))
    vis[root].set_transform(tilt)
    vis[f"{root}/ground"].set_object(mg.Box([3.0, 3.0, 0.01]), mg.MeshLambertMaterial(color=0x999999, opacity=0.8))
    vis[f"{root}/ground"].set_transform(pin.SE3(np.eye(3), np.array([0.0, 0.0, -0.005])).homogeneous)
    for k, h in enumerate(sim.model.halfspaces[1:], start=1):
        if h.frame != 0:
            continue  # a body's face is drawn with the body
        n = np.asarray(h.normal)
        T = np.eye(4)
        T[:3, :3] = np.column_stack([np.asarray(h.tangent1), np.asarray(h.tangent2), n])
        T[:3, 3] = n * h.offset - 0.005 * n
        vis[f"{root}/wall{k}"].set_object(mg.Box([1.0, 1.0, 0.01]), mg.MeshLambertMaterial(color=0xAAAACC, opacity=0.5))
        vis[f"{root}/wall{k}"].set_transform(T)

    # ---- sample the trajectory: frame k shows the state at time k / fps
    times = np.arange(0.0, traj.t[-1] - traj.t[0] + 1e-9, 1.0 / fps)
    idx = np.searchsorted(traj.t - traj.t[0], times - 1e-9).clip(0, len(traj.t) - 1)
    nf = len(idx)
    nc = len(scene.contacts)  # sphere/point contacts; coal pair slots follow them (_pair_slots)
    oMi = sim.joint_placements(traj.q[idx])  # (nf, joints, 4, 4), part by part: no world Data
    parents = [model.frames[c.frame].parentJoint for c in scene.contacts]
    local = np.array([model.frames[c.frame].placement.act(np.asarray(c.offset)) for c in scene.contacts])
    centers = np.einsum("kiab,ib->kia", oMi[:, parents][..., :3, :3], local.reshape(nc, 3)) + oMi[:, parents][..., :3, 3]
    # the contacts' half-space frames (t1, t2, n) in the world: a body's face turns with it
    frames = np.empty((nf, nc, 3, 3))
    for k in range(nf):
        for i, c in enumerate(scene.contacts):
            h = sim.model.halfspaces[c.halfspace]
            B = np.column_stack([np.asarray(h.tangent1), np.asarray(h.tangent2), np.asarray(h.normal)])
            if h.frame != 0:
                f = model.frames[h.frame]
                B = oMi[k, f.parentJoint, :3, :3] @ np.asarray(f.placement.rotation) @ B
            frames[k, i] = B
    normals = frames[..., 2]
    points = centers - np.array([c.radius for c in scene.contacts])[None, :, None] * normals
    # (the first record has no step behind it: lam NaN, states -1; drawn as no force)
    forces = np.einsum("kiab,kib->kia", frames, np.nan_to_num(traj.lam[idx, :nc]))
    states = traj.states[idx, :nc].astype(int)
    ids = list(range(nc))  # the candidate each drawn contact is (node c<id>)
    if traj.lam.shape[1] > nc:  # coal pair slots: the ones closed at some drawn frame
        pair_states = traj.states[idx, nc:].astype(int)
        used = np.flatnonzero((pair_states > 0).any(axis=0))
        if used.size:
            pair_points, pair_frames = _pair_slots(sim, traj, idx)
            pair_points, pair_frames = pair_points[:, used], pair_frames[:, used]
            # the force on the pair's first geometry: lambda acts on the second along the frame
            pair_forces = -np.einsum("kiab,kib->kia", pair_frames, np.nan_to_num(traj.lam[idx][:, nc + used]))
            points = np.concatenate([points, pair_points], axis=1)
            normals = np.concatenate([normals, -pair_frames[..., 2]], axis=1)
            forces = np.concatenate([forces, pair_forces], axis=1)
            states = np.concatenate([states, pair_states[:, used]], axis=1)
            ids += [nc + int(u) for u in used]
    drawn = ["stick", "slip"] + (["closed"] if (states == 3).any() else [])

    # ---- the robot over the trajectory: poses, and its bounding box (physics frame)
    vmodel = viz.visual_model
    names = [viz.getViewerNodeName(go, pin.GeometryType.VISUAL) for go in vmodel.geometryObjects]
    scales = [np.diag(go.meshScale) for go in vmodel.geometryObjects]
    corners = []
    for go in vmodel.geometryObjects:
        try:
            go.geometry.computeLocalAABB()
            lo, hi = np.asarray(go.geometry.aabb_local.min_), np.asarray(go.geometry.aabb_local.max_)
            lo, hi = lo * go.meshScale, hi * go.meshScale
            corners.append(np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
                                     for c in (lo[2], hi[2])]))
        except Exception:  # a geometry without a box: its origin only
            corners.append(np.zeros((1, 3)))
    world = visual_poses(vmodel, oMi)  # (nf, geometries, 4, 4)
    poses = world.copy()
    pts = [points.reshape(-1, 3)]
    for g in range(len(names)):
        poses[:, g, :3, :3] = world[:, g, :3, :3] @ scales[g]
        pts.append((corners[g] @ world[:, g, :3, :3].transpose(0, 2, 1) + world[:, g, None, :3, 3]).reshape(-1, 3))
    pts = np.concatenate(pts)
    size = max(float(np.linalg.norm(pts.max(0) - pts.min(0))), 0.1)

    # ---- force scale (N per m of shaft)
    mags = np.linalg.norm(forces, axis=2)
    closed = states > 0
    ref = float(np.percentile(mags[closed], 98)) if closed.any() else 0.0
    if force_scale is None:
        force_scale = _nice_ceil(ref / (0.3 * size)) if ref > 1e-9 else 1.0
    force_scale = float(force_scale)
    if not force_scale > 0:
        raise ValueError(f"force_scale must be positive (N per m), got {force_scale}")
    lengths = mags / force_scale
    # arrow tips (up to the reference force) belong to the framed box
    unit = np.divide(forces, mags[..., None], out=np.zeros_like(forces), where=mags[..., None] > 1e-12)
    tips = points + unit * np.minimum(mags, ref)[..., None] / force_scale
    pts = np.concatenate([pts, tips[closed]])

    # ---- arrows: a shaft (unit cylinder along y, scaled) and a cone at its tip, per state
    r_shaft = float(np.clip(0.006 * size, 0.001, 0.01))
    r_head, h_head = 2.5 * r_shaft, 7.5 * r_shaft
    for i, cid in enumerate(ids):
        vis[f"{root}/contacts/c{cid}/point"].set_object(mg.Sphere(max(1.5 * r_shaft, 0.003)),
                                                         mg.MeshLambertMaterial(color=0x333333))
        for s in drawn:
            node = vis[f"{root}/contacts/c{cid}/{s}"]
            mat = mg.MeshLambertMaterial(color=COLORS[s])
            node["shaft"].set_object(mg.Cylinder(1.0, r_shaft), mat)
            node["head"].set_object(mg.Cylinder(h_head, radiusTop=0.0, radiusBottom=r_head), mat)
            node.set_property("visible", False)

    anim = Animation(default_framerate=fps)
    for frame_no in range(nf):
        with anim.at_frame(vis, frame_no) as frame:
            for g, name in enumerate(names):
                frame[name].set_transform(poses[frame_no, g])
            for i, cid in enumerate(ids):
                P = np.eye(4)
                P[:3, 3] = points[frame_no, i]
                frame[f"{root}/contacts/c{cid}/point"].set_transform(P)
    clips = anim.lower()
    for i, cid in enumerate(ids):
        # a closed contact without force: a cone on the contact point, along the normal
        quats = [_quat_y_to(unit[k, i] if mags[k, i] > 1e-12 else normals[k, i]) for k in range(nf)]
        for s in drawn:
            shown = states[:, i] == STATE_CODES[s]
            L = np.maximum(lengths[:, i], 1e-6)
            pos = _fill_hidden([[float(x) for x in points[k, i]] for k in range(nf)], shown)
            quat = _fill_hidden(quats, shown)
            scl = _fill_hidden([[1.0, float(L[k]), 1.0] for k in range(nf)], shown)
            shaft = [[0.0, 0.5 * v[1], 0.0] for v in scl]
            head = [[0.0, v[1] + 0.5 * h_head, 0.0] for v in scl]
            # visibility keyed where it changes (boolean tracks are discrete in three.js)
            change = [0] + [k for k in range(1, nf) if shown[k] != shown[k - 1]]
            if nf - 1 not in change:
                change.append(nf - 1)
            tracks = [
                _track(".position", "vector3", pos),
                _track(".quaternion", "quaternion", quat),
                _track(".visible", "bool", [bool(shown[k]) for k in change], change),
                _track("shaft.scale", "vector3", scl),
                _track("shaft.position", "vector3", shaft),
                _track("head.position", "vector3", head),
            ]
            clips.append({"path": vis[f"{root}/contacts/c{cid}/{s}"].path.lower(),
                          "clip": {"fps": fps, "name": "default", "tracks": tracks}})
    for g, name in enumerate(names):  # the first pose (what viz.display(q0) would set)
        vis[name].set_transform(poses[0, g])
    # repetitions=0 would play it zero times
    window.send(_SetAnimation(clips, play=True, repetitions=1))

    # ---- camera: frame the robot's box over the trajectory, seen from -y (the slope's
    # profile: it turns about y), a little from +x and from above
    world = pts @ tilt[:3, :3].T
    lo, hi = world.min(0), world.max(0)
    center = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 0.08)
    view = np.array([0.35, -1.0, 0.45])
    view /= np.linalg.norm(view)
    eye = center + view * 1.1 * radius / math.sin(math.radians(CAMERA_FOV_DEG) / 2)

    def three(p):  # meshcat's world (z up) in three.js coordinates (y up): the scene is turned
        return [float(p[0]), float(p[2]), float(-p[1])]

    window.post_script = (
        "(function () { var c = viewer.camera, o = viewer.controls;\n"
        f"  c.position.fromArray({json.dumps(three(eye))}); o.target.fromArray({json.dumps(three(center))});\n"
        "  o.update(); viewer.set_dirty(); })();\n")

    # ---- legend
    per_cm = 0.01 * force_scale
    labels = {"stick": "stick", "slip": "slip", "closed": "closed (bilateral)"}
    rows = "".join(
        f"<div><span style=\"display:inline-block;width:2em;height:0.5em;margin-right:0.5em;"
        f"background:#{COLORS[s]:06x}\"></span>{labels[s]}</div>" for s in drawn)
    window.overlay = (
        f"<div id=\"{LEGEND_ID}\" style=\"position:absolute;left:8px;top:8px;padding:6px 10px;"
        "background:rgba(255,255,255,0.85);font:13px/1.4 sans-serif;color:#222;border-radius:4px;"
        f"pointer-events:none\" data-force-scale=\"{force_scale!r}\">"
        f"<b>{_html.escape(scene.name)}</b> &mdash; contact forces{rows}"
        "<div>open contact: no arrow</div>"
        f"<div>force scale: 1 cm = {_fmt(per_cm)} N ({_fmt(force_scale)} N/m of shaft; "
        "the tip cone is not to scale)</div></div>")

    text = vis.static_html()
    Path(path).write_text(text)
    return {"frames": nf, "duration": float(times[-1]) if len(times) else 0.0,
            "tracks": len(clips), "bytes": len(text), "force_scale": force_scale}
