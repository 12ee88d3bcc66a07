"""Headless recordings: the HTML file renders in headless Chromium, replays the expected
animation (duration, tracks), and shows what the trajectory says: the page is probed in
Chromium at a few animation times, and every contact's force arrow is read back from the live
three.js scene graph (visibility through its parents, world length, direction, material
colour) and compared with the trajectory's forces and contact states."""
import dataclasses
import json
from pathlib import Path
import math
import re
import shutil
import subprocess

import numpy as np
import pytest

from stiction.recording import record_html
from stiction.scene import load_scene
from stiction.simulator import Simulator

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-dev-shm-usage", "--no-first-run", "--disable-extensions"]
FPS = 50
EPS = 1e-6  # probe just after a frame's key (three.js keeps key times as float32)


def run_chromium(args, profile, timeout=60, attempts=3):
    """Run headless Chromium in its own process group with its own profile; on a hang kill
    the whole group (its helper processes too) and try again: on a shared 2-core machine a
    run occasionally stalls, which says nothing about the page."""
    import os
    import signal

    for attempt in range(attempts):
        proc = subprocess.Popen([CHROMIUM, *FLAGS, f"--user-data-dir={profile}-{attempt}", *args],
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                start_new_session=True)
        try:
            out, _ = proc.communicate(timeout=timeout)
            return out
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    raise AssertionError(f"headless Chromium hung {attempts} times")


# The page probes itself once the animation has played: what the animator holds, a frame
# rendered into WebGL's framebuffer, the legend, and then, for each time in TIMES (seeking
# the animator like its time slider: every action's time, mixer.update(0)), every contact
# node's visible meshes in meshcat's world frame, the robot's box in normalised device
# coordinates and the arrow-coloured pixels of a rendered frame (axes and grid hidden).
PROBE = """<script>
var TIMES = %s;
var started = {playing: viewer.animator.playing, finished: false};  // right after the scene's commands
viewer.animator.mixer.addEventListener("finished", function () { started.finished = true; });
setTimeout(function () {
  var a = viewer.animator, info = {}, T = MeshCat.THREE;
  try {
    info.actions = a.actions.length;
    info.duration = Math.max.apply(null, a.actions.map(function (x) { return x.getClip().duration; }));
    info.playing = started.playing;
    info.finished = started.finished;  // played to its end
    info.time = a.mixer.time;
    var meshes = 0;
    viewer.scene.traverse(function (o) { if (o.isMesh) meshes++; });
    info.meshes = meshes;
    var r = viewer.renderer, gl = r.getContext();
    function pixels() {
      r.render(viewer.scene, viewer.camera);
      var w = gl.drawingBufferWidth, h = gl.drawingBufferHeight, px = new Uint8Array(w * h * 4);
      gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
      return {w: w, h: h, px: px};
    }
    // render one frame and count the colours in WebGL's framebuffer
    var f = pixels(), seen = {};
    for (var i = 0; i < f.px.length; i += 4 * 7)
      seen[(f.px[i] >> 3) + "," + (f.px[i + 1] >> 3) + "," + (f.px[i + 2] >> 3)] = 1;
    info.colours = Object.keys(seen).length; info.width = f.w; info.height = f.h;
    var legend = document.getElementById("stiction-legend");
    info.legend = legend ? legend.textContent : null;

    a.pause();
    var tree = viewer.scene_tree.children, top = tree.meshcat.children.stiction;
    ["Axes", "Grid"].forEach(function (n) { if (tree[n]) tree[n].object.visible = false; });
    var contacts = top.children.contacts ? top.children.contacts.children : {};
    function shown(o) { for (var p = o; p; p = p.parent) if (!p.visible) return false; return true; }
    function world(o, v) { return viewer.scene.worldToLocal(o.localToWorld(v)).toArray(); }
    info.frames = [];
    TIMES.forEach(function (t) {
      a.seek(t);
      viewer.scene.updateMatrixWorld(true);
      var fr = {t: t, contacts: {}};
      Object.keys(contacts).forEach(function (c) {
        var out = [];
        contacts[c].object.traverse(function (o) {
          if (!o.isMesh || !shown(o)) return;
          var names = [];
          for (var p = o; p && p !== contacts[c].object; p = p.parent) if (p.name) names.unshift(p.name);
          o.geometry.computeBoundingBox();
          var bb = o.geometry.boundingBox;
          out.push({path: names.join("/"), color: o.material.color.getHex(),
                    base: world(o, new T.Vector3(0, bb.min.y, 0)), tip: world(o, new T.Vector3(0, bb.max.y, 0))});
        });
        fr.contacts[c] = out;
      });
      // the robot's box as the camera sees it
      var box = new T.Box3().setFromObject(top.children.robot.object), lo = [1e9, 1e9], hi = [-1e9, -1e9];
      viewer.camera.updateMatrixWorld();
      [0, 1].forEach(function (ix) { [0, 1].forEach(function (iy) { [0, 1].forEach(function (iz) {
        var p = new T.Vector3(ix ? box.max.x : box.min.x, iy ? box.max.y : box.min.y,
                              iz ? box.max.z : box.min.z).project(viewer.camera);
        lo = [Math.min(lo[0], p.x), Math.min(lo[1], p.y)]; hi = [Math.max(hi[0], p.x), Math.max(hi[1], p.y)];
      }); }); });
      fr.robot_ndc = [lo, hi];
      fr.robot_centre = viewer.scene.worldToLocal(box.getCenter(new T.Vector3())).toArray();  // meshcat's world
      // the frame without the contact nodes, averaged over a GW x GH grid (row 0: the bottom,
      // as readPixels and NDC y = -1): what the page shows of the bodies, and where
      var cs = top.children.contacts;
      if (cs) cs.object.visible = false;
      var s = pixels(), GW = 32, GH = 24, grid = [];
      for (var gy = 0; gy < GH; gy++) for (var gx = 0; gx < GW; gx++) {
        var xa = Math.floor(gx * s.w / GW), xb = Math.floor((gx + 1) * s.w / GW);
        var ya = Math.floor(gy * s.h / GH), yb = Math.floor((gy + 1) * s.h / GH), sum = [0, 0, 0], n = 0;
        for (var y = ya; y < yb; y++) for (var x = xa; x < xb; x++) {
          var k = 4 * (y * s.w + x);
          sum[0] += s.px[k]; sum[1] += s.px[k + 1]; sum[2] += s.px[k + 2]; n++;
        }
        grid.push([sum[0] / n, sum[1] / n, sum[2] / n]);
      }
      if (cs) cs.object.visible = true;
      fr.grid = grid; fr.grid_size = [GW, GH];
      var g = pixels(), red = 0, green = 0;
      for (var i = 0; i < g.px.length; i += 4) {
        var R = g.px[i], G = g.px[i + 1], B = g.px[i + 2];
        if (R > 90 && R > 2.2 * G && R > 2.2 * B) red++;
        if (G > 70 && G > 1.6 * R && G > 1.4 * B) green++;
      }
      fr.red_px = red; fr.green_px = green;
      info.frames.push(fr);
    });
  } catch (e) { info.error = String(e) + " " + e.stack; }
  var el = document.createElement("pre"); el.id = "probe"; el.textContent = JSON.stringify(info);
  document.body.appendChild(el);
}, 1500);
</script></body>"""


def _cube_slide_drop():
    """cube-slide 3 cm above the ground: open (falling), slip (lands sliding at 1 m/s), stick."""
    scene = load_scene("cube-slide")
    q0 = scene.q0.copy()
    q0[2] += 0.03
    return Simulator(dataclasses.replace(scene, q0=q0))


# scene -> (simulator, duration, probe times: frame times (+EPS) and a few between frames)
CASES = {
    "solo12-stand": (lambda: Simulator("solo12-stand"), 1.0, [0.0, 0.01, 0.02, 0.2, 0.5, 0.51, 1.0]),
    "cube-slide-drop": (_cube_slide_drop, 0.4, [0.04, 0.06, 0.07, 0.08, 0.1, 0.15, 0.2, 0.21, 0.22, 0.3, 0.4]),
    "cube-incline-slip": (lambda: Simulator("cube-incline-slip"), 0.6, [0.0, 0.1, 0.3, 0.33, 0.6]),
}


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    out, folder = {}, tmp_path_factory.mktemp("rec")
    for name, (make, duration, _) in CASES.items():
        sim = make()
        traj = sim.rollout(duration)
        path = folder / f"{name}.html"
        out[name] = (sim, traj, path, record_html(sim, traj, path, fps=FPS))
    return out


@pytest.fixture(scope="module")
def recording(recordings):
    sim, _, path, info = recordings["solo12-stand"]
    return sim, path, info


def test_recording_is_self_contained(recording):
    sim, path, info = recording
    html = path.read_text()
    assert "MeshCat.Viewer" in html and "http://" not in html.split("<script>", 2)[2][:1000]
    assert info["frames"] == 51 and info["duration"] == pytest.approx(1.0)
    # 17 visual geometries of solo12 + per foot a marker, a stick and a slip arrow (one
    # animated node each: an arrow's shaft and cone are keyed by its node's clip)
    assert info["tracks"] == 17 + 3 * 4
    assert 1e6 < info["bytes"] < 2e7
    assert info["force_scale"] > 0


_probe_cache = {}


def _run_probe(path, times, tmp_path_factory):
    """The page at `path` opened in headless Chromium with the probe appended: per time, the
    visible contact meshes (per node c<i>) and pixel counts."""
    if CHROMIUM is None:
        pytest.skip("chromium not installed (make test installs it as root)")
    times = [t if t == 0 else t + EPS for t in times]
    tmp = tmp_path_factory.mktemp("probe")
    probe = tmp / "probe.html"
    probe.write_text(Path(path).read_text().replace("</body>", PROBE % json.dumps(times)))
    out = run_chromium(["--window-size=640,480", "--virtual-time-budget=4000", "--dump-dom", str(probe)],
                       tmp / "profile")
    m = re.search(r'<pre id="probe">(.*?)</pre>', out)
    assert m, "the page did not run its scripts"
    got = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert "error" not in got, got
    return got


def _probe(recordings, name, tmp_path_factory):
    if name not in _probe_cache:
        _, _, path, info = recordings[name]
        _probe_cache[name] = _run_probe(path, CASES[name][2], tmp_path_factory)
    return _probe_cache[name]


@pytest.fixture(scope="module")
def probed(recordings, tmp_path_factory):
    """One headless Chromium run of the solo recording with the probe script appended."""
    return _probe(recordings, "solo12-stand", tmp_path_factory), recordings["solo12-stand"][3]


def test_recording_replays_in_headless_chromium(probed):
    got, info = probed
    assert got["actions"] == info["tracks"]
    assert got["duration"] == pytest.approx(1.0, abs=0.021)
    # it plays on load; by the probe (1.5 s of virtual time, but requestAnimationFrame is
    # throttled on a loaded machine) it has advanced or played to its end
    assert got["playing"] is True and (got["time"] > 0.1 or got["finished"])
    assert got["meshes"] >= 17


def test_recording_renders_the_scene(recordings, tmp_path_factory):
    """What the page shows follows the trajectory (cube-incline-slip: the cube slides ~12 cm in
    0.6 s). (1) The cube's box read back from the live scene graph at each on-frame probe time is
    centred where Pinocchio puts the cube (its joint placement, the scene root tilted by the
    slope). (2) In the rendered frames (contact arrows hidden, 32 x 24 cell averages) the cells
    that change between t = 0 and t = 0.6 s lie where the cube was or is, and there are some."""
    import pinocchio as pin

    got = _probe(recordings, "cube-incline-slip", tmp_path_factory)
    sim, traj, _, _ = recordings["cube-incline-slip"]
    assert got["width"] >= 320 and got["height"] >= 200
    th = math.radians(sim.scene.slope_deg)
    R = np.array([[math.cos(th), 0.0, math.sin(th)], [0.0, 1.0, 0.0], [-math.sin(th), 0.0, math.cos(th)]])
    model = sim.scene.model
    data = model.createData()
    on_frame, centre_error = 0, 0.0
    for fr in got["frames"]:
        k = int(math.floor(fr["t"] * FPS + 1e-3))
        if fr["t"] * FPS - k > 1e-3:
            continue  # between frames: interpolated
        j = min(int(np.searchsorted(traj.t - traj.t[0], k / FPS - 1e-9)), len(traj.t) - 1)
        pin.forwardKinematics(model, data, traj.q[j])
        centre = np.asarray(fr["robot_centre"])  # of its bounding box: the cube's centre
        # measured: within 1.7e-7 m (three.js keeps float32 positions)
        np.testing.assert_allclose(centre, R @ data.oMi[1].translation, atol=1e-5, err_msg=f"t={fr['t']}")
        centre_error = max(centre_error, float(np.abs(centre - R @ data.oMi[1].translation).max()))
        on_frame += 1
    assert on_frame >= 4
    first, last = got["frames"][0], got["frames"][-1]
    assert first["t"] == 0.0 and last["t"] == pytest.approx(0.6, abs=1e-5)
    gw, gh = first["grid_size"]
    change = np.abs(np.subtract(first["grid"], last["grid"])).max(axis=1).reshape(gh, gw)
    changed = change > 8.0  # of 255: a cell the cube entered or left (measured: unchanged cells differ by 0)
    cx = -1 + 2 * (np.arange(gw) + 0.5) / gw
    cy = -1 + 2 * (np.arange(gh) + 0.5) / gh
    near = np.zeros_like(changed)
    for fr in (first, last):  # the cube's projected box, one cell wider on each side
        (x0, y0), (x1, y1) = fr["robot_ndc"]
        near |= ((cy[:, None] >= y0 - 2 / gh) & (cy[:, None] <= y1 + 2 / gh)
                 & (cx[None, :] >= x0 - 2 / gw) & (cx[None, :] <= x1 + 2 / gw))
    print(f"\ncube-incline-slip: {changed.sum()} of {gw * gh} cells changed (largest change {change.max():.0f}, "
          f"largest outside the cube's boxes {change[~near].max():.1f}), centres within {centre_error:.1e} m")
    assert changed.sum() >= 4, change.max()
    assert not (changed & ~near).any(), np.argwhere(changed & ~near)


# ---- what the trajectory says the viewer should see

def _expected(sim, traj):
    """Per frame (frame k: the first sample at or after t0 + k / FPS): contact states, forces
    and contact points in meshcat's world (the scene root is tilted by the slope)."""
    times = np.arange(0.0, traj.t[-1] - traj.t[0] + 1e-9, 1.0 / FPS)
    idx = np.searchsorted(traj.t - traj.t[0], times - 1e-9).clip(0, len(traj.t) - 1)
    th = math.radians(sim.scene.slope_deg)
    R = np.array([[math.cos(th), 0.0, math.sin(th)], [0.0, 1.0, 0.0], [-math.sin(th), 0.0, math.cos(th)]])
    import pinocchio as pin

    model = sim.scene.model
    data = model.createData()
    centers = sim.contact_centers(traj)[idx]
    nc = len(sim.scene.contacts)
    forces, points = np.zeros((len(idx), nc, 3)), np.zeros((len(idx), nc, 3))
    for k, j in enumerate(idx):
        pin.framesForwardKinematics(model, data, traj.q[j])
        for i, c in enumerate(sim.scene.contacts):
            h = sim.model.halfspaces[c.halfspace]
            B = np.column_stack([h.tangent1, h.tangent2, h.normal])  # a body's face turns with it
            B = B if h.frame == 0 else data.oMf[h.frame].rotation @ B
            forces[k, i] = R @ B @ traj.lam[j, i]
            points[k, i] = R @ (centers[k, i] - c.radius * B[:, 2])
    return traj.states[idx, :nc].astype(int), forces, points


def _hue(color):
    r, g, b = (color >> 16) & 255, (color >> 8) & 255, color & 255
    return "red" if r > max(g, b) else "green" if g > max(r, b) else "blue" if b > max(r, g) else "grey"


EXPECTED_HUE = {1: "green", 2: "red", 3: "blue"}


def _arrows(meshes):
    """A contact's visible arrows: {arrow node: (its meshes, shaft)} (the marker excluded; an
    arrow counts when one of its meshes has a size)."""
    out = {}
    for m in meshes:
        node = m["path"].split("/")[0] if m["path"] else ""
        if node == "point":
            continue
        out.setdefault(node, []).append(m)
    arrows = {}
    for node, ms in out.items():
        if max(np.linalg.norm(np.subtract(m["tip"], m["base"])) for m in ms) < 1e-5:
            continue
        shaft = [m for m in ms if "shaft" in m["path"]] or ms
        arrows[node] = (ms, shaft[0])
    return arrows


def _compare(name, recordings, got):
    """Every probed time and contact against the trajectory; returns the measurements."""
    sim, traj, _, info = recordings[name]
    scale = info["force_scale"]
    states, forces, points = _expected(sim, traj)
    nf, nc = states.shape
    rows = []
    for fr in got["frames"]:
        t = fr["t"]
        k = min(int(math.floor(t * FPS + 1e-3)), nf - 1)
        a = t * FPS - k if k < nf - 1 else 0.0
        for i in range(nc):
            s = int(states[k, i])
            arrows = _arrows(fr["contacts"][f"c{i}"])
            where = f"{name} t={t:.4f} c{i} state {s}"
            if s <= 0:  # open, or record 0 (-1: before any step, no force)
                assert not arrows, f"{where}: open contact shows {list(arrows)}"
                continue
            assert len(arrows) == 1, f"{where}: {len(arrows)} visible arrows {list(arrows)}"
            (meshes, shaft), = arrows.values()
            hues = {_hue(m["color"]) for m in meshes}
            assert hues == {EXPECTED_HUE[s]}, f"{where}: colours {hues}"
            f_k = np.linalg.norm(forces[k, i])
            held = k + 1 >= nf or states[k + 1, i] != s  # the arrow leaves after this frame
            f_exp = f_k if held or a < 1e-3 else (1 - a) * f_k + a * np.linalg.norm(forces[k + 1, i])
            vec = np.subtract(shaft["tip"], shaft["base"])
            length, want = float(np.linalg.norm(vec)), f_exp / scale
            assert abs(length - want) <= max(0.02 * want, 5e-4), f"{where}: length {length} m, want {want} m"
            row = {"t": t, "c": i, "state": s, "hue": EXPECTED_HUE[s], "length": length, "want": want,
                   "force": float(length * scale), "vertical": float(vec[2] * scale)}
            if a < 1e-3:  # on a frame: the arrow starts at the contact point, along the force
                assert np.linalg.norm(np.subtract(shaft["base"], points[k, i])) < 1e-3, f"{where}: base"
                if want > 2e-3:
                    cos = np.dot(vec, forces[k, i]) / (length * f_k)
                    row["angle_deg"] = float(math.degrees(math.acos(min(1.0, cos))))
                    assert row["angle_deg"] < 1.0, f"{where}: direction off by {row['angle_deg']:.2f} deg"
            rows.append(row)
    return rows


@pytest.mark.parametrize("name", list(CASES))
def test_force_arrows_show_the_trajectory(recordings, tmp_path_factory, name):
    """At every probed time, per contact: open -> no arrow; closed -> exactly one arrow, green
    if it sticks, red if it slips, shaft length |force| / scale within 2 % (0.5 mm floor),
    from the contact point along the force; between frames the state of the earlier frame."""
    got = _probe(recordings, name, tmp_path_factory)
    rows = _compare(name, recordings, got)
    assert rows, "no closed contact probed"
    errs = [abs(r["length"] - r["want"]) / r["want"] for r in rows if r["want"] > 0.025]
    print(f"\n{name}: {len(rows)} arrows at {len(got['frames'])} times, max length error "
          f"{max(errs) if errs else 0:.2e} (relative), scale {recordings[name][3]['force_scale']} N/m")


def test_standing_solo_shows_four_green_arrows_carrying_its_weight(recordings, tmp_path_factory):
    """Solo-12 standing never slips: no red arrow (nor red pixel) anywhere; once it stands, four
    green arrows whose vertical components add up to m g."""
    import pinocchio as pin

    got = _probe(recordings, "solo12-stand", tmp_path_factory)
    rows = _compare("solo12-stand", recordings, got)
    sim = recordings["solo12-stand"][0]
    weight = pin.computeTotalMass(sim.scene.model) * 9.81
    assert all(r["hue"] == "green" for r in rows)
    for fr in got["frames"]:
        assert fr["red_px"] == 0, fr["t"]
        at = [r for r in rows if r["t"] == fr["t"]]
        if fr["t"] >= 0.2:
            assert len(at) == 4 and fr["green_px"] > 200
            vertical = [r["vertical"] for r in at]
            # measured: the arrows' vertical sum within 2.4e-3 of m g at 0.2 s (still settling),
            # 9e-5 from 0.5 s on
            assert sum(vertical) == pytest.approx(weight, rel=0.01 if fr["t"] < 0.5 else 1e-3)
            # the stance is symmetric: each foot a quarter (measured spread 3e-5, arrows included)
            assert all(v == pytest.approx(sum(vertical) / 4, rel=1e-3) for v in vertical)


def test_sliding_cube_shows_red_arrows(recordings, tmp_path_factory):
    """The cube on the 30 degree slope slides: four red arrows under it (the top corners are
    open: none), no green; the red shows in the rendered frame."""
    got = _probe(recordings, "cube-incline-slip", tmp_path_factory)
    rows = _compare("cube-incline-slip", recordings, got)
    for fr in got["frames"]:
        at = [r for r in rows if r["t"] == fr["t"]]
        if fr["t"] >= 0.1:
            assert len(at) == 4 and all(r["hue"] == "red" for r in at), fr["t"]
            assert fr["red_px"] > 100 and fr["green_px"] == 0


def test_dropped_cube_open_slip_stick(recordings, tmp_path_factory):
    """cube-slide dropped from 3 cm: no arrow while it falls, red while it slides, green once
    it stops; between the last sliding frame and the first sticking one no green arrow
    appears and the red one keeps its length."""
    got = _probe(recordings, "cube-slide-drop", tmp_path_factory)
    rows = _compare("cube-slide-drop", recordings, got)
    hue_at = {}
    for r in rows:
        hue_at.setdefault(round(r["t"], 3), set()).add(r["hue"])
    assert not {0.04, 0.06, 0.07} & set(hue_at)  # falling: nothing
    assert hue_at[0.1] == {"red"} and hue_at[0.21] == {"red"} and hue_at[0.3] == {"green"}


@pytest.mark.parametrize("name", list(CASES))
def test_legend_and_camera(recordings, tmp_path_factory, name):
    """The page states the colours and the force scale it used, and the camera frames the
    robot: its box is in view and spans a good part of the image at every probed time."""
    got = _probe(recordings, name, tmp_path_factory)
    scale = recordings[name][3]["force_scale"]
    legend = got["legend"] or ""
    assert "stick" in legend and "slip" in legend
    assert f"{scale:g} N/m" in legend and f"1 cm = {0.01 * scale:g} N" in legend
    for fr in got["frames"]:
        (x0, y0), (x1, y1) = fr["robot_ndc"]
        assert -1.05 < x0 and x1 < 1.05 and -1.05 < y0 and y1 < 1.05, (fr["t"], fr["robot_ndc"])
        span = max(x1 - x0, y1 - y0) / 2  # fraction of the image's width or height
        assert span > 0.2, (fr["t"], span)


def test_bilateral_closed_contacts_get_their_own_arrow(recordings, tmp_path):
    """State 3 (a closed bilateral contact) has its own (blue) arrow and legend entry; no
    bundled scene has one, so the solo trajectory is relabelled."""
    sim, traj, _, _ = recordings["solo12-stand"]
    states = traj.states.copy()
    states[states == 1] = 3
    info = record_html(sim, dataclasses.replace(traj, states=states), tmp_path / "closed.html", fps=FPS)
    html = (tmp_path / "closed.html").read_text()
    assert info["tracks"] == 17 + 4 * 4 and "closed (bilateral)" in html and "#2255dd" in html


def test_coal_pair_forces_are_drawn_where_the_ball_rests_on_the_table(tmp_path_factory):
    """ball-on-table: the ball (0.5 kg) touches the table through a coal pair (ball_0|table), not a
    sphere contact. Once it rests, the page shows at that pair's slot one green arrow from the top
    of the table under the ball, straight up (the force on the pair's first geometry, the ball),
    m g / scale long; the pair with the ground (never closed) has no node."""
    sim = Simulator("ball-on-table")
    traj = sim.rollout(1.0)
    path = tmp_path_factory.mktemp("pair") / "ball.html"
    info = record_html(sim, traj, path, fps=FPS)
    # the ball's visual, then one drawn contact: its marker, stick and slip arrows
    assert info["tracks"] == len(sim.scene.visual_model.geometryObjects) + 3
    got = _run_probe(path, [0.9, 1.0], tmp_path_factory)
    assert all(set(fr["contacts"]) == {"c1"} for fr in got["frames"])  # slot 0, ball|ground: never closed
    ball = traj.q[-1, :3]
    for fr in got["frames"]:
        arrows = _arrows(fr["contacts"]["c1"])
        assert list(arrows) == ["stick"], (fr["t"], list(arrows))
        (meshes, shaft), = arrows.values()
        assert {_hue(m["color"]) for m in meshes} == {"green"}
        base, vec = np.asarray(shaft["base"]), np.subtract(shaft["tip"], shaft["base"])
        np.testing.assert_allclose(base, [ball[0], ball[1], 0.2], atol=1e-3)
        length = float(np.linalg.norm(vec))
        assert length == pytest.approx(0.5 * 9.81 / info["force_scale"], rel=0.02)
        assert vec[2] / length > math.cos(math.radians(1.0))  # up, on the ball
