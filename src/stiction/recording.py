"""Headless recordings: a rollout to one self-contained HTML file (meshcat).

No server and no display: meshcat's scene commands are collected in memory by a window
object of our own and written, with the viewer's JavaScript, into one HTML page that replays
the animation when opened. Pinocchio 4.1's MeshcatVisualizer has no recording helper, so the
animation is built here from the recorded configurations: every visual geometry node gets a
transform track, every candidate contact a marker and two force arrows (green while it
sticks, red while it slips; an open contact's arrows shrink to nothing).
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pinocchio as pin

ARROW_SCALE = 0.004  # m per N (solo12 feet carry ~6 N)
COLORS = {"stick": 0x22AA44, "slip": 0xDD2222}


class _OfflineWindow:
    """The part of meshcat.visualizer.ViewerWindow that Visualizer uses (send, get_scene),
    keeping the scene tree in memory instead of talking to a server."""

    web_url = "offline://"
    server_proc = None

    def __init__(self):
        from meshcat.servers.tree import SceneTree

        self.tree = SceneTree()

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
        from meshcat.servers.tree import walk
        from meshcat.servers.zmqserver import VIEWER_ROOT, create_command

        commands = []
        for node in walk(self.tree):
            for packed in ([node.object] if node.object is not None else []) + list(node.properties) + \
                    ([node.transform] if node.transform is not None else []) + \
                    ([node.animation] if node.animation is not None else []):
                commands.append(create_command(packed))
        js = Path(VIEWER_ROOT, "main.min.js").read_text()
        return (
            "<!DOCTYPE html>\n<html><head><meta charset=utf-8><title>stiction recording</title></head>\n"
            "<body><div id=\"meshcat-pane\"></div>\n<script>" + js + "</script>\n"
            "<script>var viewer = new MeshCat.Viewer(document.getElementById(\"meshcat-pane\"));\n"
            + "".join(commands) +
            "</script>\n<style>body {margin: 0; } #meshcat-pane { width: 100vw; height: 100vh; overflow: hidden; }"
            "</style>\n</body></html>\n")

    def get_image(self):
        raise RuntimeError("offline recording: no browser attached")


def _arrow_transform(origin: np.ndarray, force: np.ndarray) -> np.ndarray:
    """A unit cylinder along y (meshcat's axis) placed from origin along force, scaled by |force|."""
    T = np.eye(4)
    length = float(np.linalg.norm(force)) * ARROW_SCALE
    if length < 1e-9:
        T[:3, :3] = np.diag([1e-6, 1e-6, 1e-6])
        T[:3, 3] = origin
        return T
    y = force / np.linalg.norm(force)
    ref = np.array([1.0, 0.0, 0.0]) if abs(y[0]) < 0.9 else np.array([0.0, 0.0, 1.0])
    x = np.cross(y, ref)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    T[:3, :3] = np.column_stack([x, y * length, z])
    T[:3, 3] = origin + 0.5 * length * y
    return T


def record_html(sim, traj, path: str | os.PathLike, fps: int = 50) -> dict:
    """Write `traj` of simulator `sim` to a self-contained HTML file; returns
    {frames, duration, tracks, bytes}."""
    import meshcat
    import meshcat.geometry as mg
    from meshcat.animation import Animation
    from pinocchio.visualize import MeshcatVisualizer

    scene = sim.scene
    model = scene.model
    vis = meshcat.Visualizer(window=_OfflineWindow())
    root = "stiction"
    viz = MeshcatVisualizer(model, None, scene.visual_model)
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
    nc = len(scene.contacts)
    for i in range(nc):
        vis[f"{root}/contacts/c{i}/point"].set_object(mg.Sphere(0.006), mg.MeshLambertMaterial(color=0x333333))
        for state, color in COLORS.items():
            vis[f"{root}/contacts/c{i}/{state}"].set_object(mg.Cylinder(1.0, 0.003), mg.MeshLambertMaterial(color=color))

    vmodel, vdata, data = viz.visual_model, viz.visual_data, viz.data
    names = [viz.getViewerNodeName(go, pin.GeometryType.VISUAL) for go in vmodel.geometryObjects]
    scales = [np.diag(go.meshScale) for go in vmodel.geometryObjects]
    anim = Animation(default_framerate=fps)
    # frame k shows the state at time k / fps
    times = np.arange(0.0, traj.t[-1] - traj.t[0] + 1e-9, 1.0 / fps)
    idx = np.searchsorted(traj.t - traj.t[0], times - 1e-9).clip(0, len(traj.t) - 1)
    centers = sim.contact_centers(traj)
    for frame_no, k in enumerate(idx):
        q = traj.q[k]
        pin.forwardKinematics(model, data, q)
        pin.updateGeometryPlacements(model, data, vmodel, vdata)
        with anim.at_frame(vis, frame_no) as frame:
            for g, name in enumerate(names):
                T = vdata.oMg[g].homogeneous.copy()
                T[:3, :3] = T[:3, :3] @ scales[g]
                frame[name].set_transform(T)
            for i, c in enumerate(scene.contacts):  # coal pair slots are not drawn
                h = sim.model.halfspaces[c.halfspace]
                n, t1, t2 = (np.asarray(h.normal), np.asarray(h.tangent1), np.asarray(h.tangent2))
                point = centers[k, i] - c.radius * n
                force = traj.lam[k, i, 0] * t1 + traj.lam[k, i, 1] * t2 + traj.lam[k, i, 2] * n
                P = np.eye(4)
                P[:3, 3] = point
                frame[f"{root}/contacts/c{i}/point"].set_transform(P)
                state = int(traj.states[k, i])
                for name_state, code in (("stick", 1), ("slip", 2)):
                    shown = force if state == code else np.zeros(3)
                    frame[f"{root}/contacts/c{i}/{name_state}"].set_transform(_arrow_transform(point, shown))
    viz.display(traj.q[0])
    vis.set_animation(anim, play=True, repetitions=1)  # repetitions=0 would play it zero times
    html = vis.static_html()
    Path(path).write_text(html)
    return {"frames": len(idx), "duration": float(times[-1]) if len(times) else 0.0,
            "tracks": len(names) + 3 * nc, "bytes": len(html)}
