"""Headless recordings: the HTML file renders in headless Chromium and replays the
expected animation (duration, tracks)."""
import json
import re
import shutil
import subprocess

import pytest

from stiction.recording import record_html
from stiction.simulator import Simulator

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader", "--enable-unsafe-swiftshader",
         "--disable-dev-shm-usage", "--no-first-run", "--disable-extensions"]


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

PROBE = """<script>
setTimeout(function () {
  var a = viewer.animator, info = {};
  try {
    info.actions = a.actions.length;
    info.duration = Math.max.apply(null, a.actions.map(function (x) { return x.getClip().duration; }));
    info.playing = a.playing;
    info.time = a.mixer.time;
    var meshes = 0;
    viewer.scene.traverse(function (o) { if (o.isMesh) meshes++; });
    info.meshes = meshes;
    // render one frame and count the colours in WebGL's framebuffer
    var r = viewer.renderer; r.render(viewer.scene, viewer.camera);
    var gl = r.getContext(), w = gl.drawingBufferWidth, h = gl.drawingBufferHeight;
    var px = new Uint8Array(w * h * 4); gl.readPixels(0, 0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
    var seen = {};
    for (var i = 0; i < px.length; i += 4 * 7) seen[(px[i] >> 3) + "," + (px[i + 1] >> 3) + "," + (px[i + 2] >> 3)] = 1;
    info.colours = Object.keys(seen).length; info.width = w; info.height = h;
  } catch (e) { info.error = String(e); }
  var el = document.createElement("pre"); el.id = "probe"; el.textContent = JSON.stringify(info);
  document.body.appendChild(el);
}, 1500);
</script></body>"""


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    sim = Simulator("solo12-stand")
    traj = sim.rollout(1.0)
    path = tmp_path_factory.mktemp("rec") / "solo12.html"
    info = record_html(sim, traj, path, fps=50)
    return sim, path, info


def test_recording_is_self_contained(recording):
    sim, path, info = recording
    html = path.read_text()
    assert "MeshCat.Viewer" in html and "http://" not in html.split("<script>", 2)[2][:1000]
    assert info["frames"] == 51 and info["duration"] == pytest.approx(1.0)
    # 17 visual geometries of solo12 + a point and two force arrows per foot
    assert info["tracks"] == 17 + 3 * 4
    assert 1e6 < info["bytes"] < 2e7


@pytest.fixture(scope="module")
def probed(recording, tmp_path_factory):
    """One headless Chromium run of the recording with a probe script appended: what the
    animator holds, and a frame rendered into WebGL's framebuffer."""
    if CHROMIUM is None:
        pytest.skip("chromium not installed (make test installs it as root)")
    _, path, info = recording
    tmp = tmp_path_factory.mktemp("probe")
    probe = tmp / "probe.html"
    probe.write_text(path.read_text().replace("</body>", PROBE))
    out = run_chromium(["--window-size=640,480", "--virtual-time-budget=4000", "--dump-dom", str(probe)],
                       tmp / "profile")
    m = re.search(r'<pre id="probe">(.*?)</pre>', out)
    assert m, "the page did not run its scripts"
    got = json.loads(m.group(1).replace("&quot;", '"'))
    assert "error" not in got, got
    return got, info


def test_recording_replays_in_headless_chromium(probed):
    got, info = probed
    assert got["actions"] == info["tracks"]
    assert got["duration"] == pytest.approx(1.0, abs=0.021)
    assert got["playing"] is True and got["time"] > 0.1
    assert got["meshes"] >= 17


def test_recording_renders_the_scene(probed):
    """A rendered frame holds a 3-D scene (robot, ground, sky gradient), not a blank page."""
    got, _ = probed
    assert got["width"] >= 320 and got["height"] >= 200
    assert got["colours"] > 50
