"""Headless recordings: the HTML file renders in headless Chromium and replays the
expected animation (duration, tracks)."""
import json
import re
import shutil
import subprocess

import numpy as np
import pytest

from stiction.recording import record_html
from stiction.simulator import Simulator

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--use-gl=swiftshader", "--enable-unsafe-swiftshader"]

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


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (make test installs it as root)")
def test_recording_replays_in_headless_chromium(recording, tmp_path):
    _, path, info = recording
    probe = tmp_path / "probe.html"
    probe.write_text(path.read_text().replace("</body>", PROBE))
    out = subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                          "--virtual-time-budget=4000", "--dump-dom", str(probe)],
                         capture_output=True, text=True, timeout=120).stdout
    m = re.search(r'<pre id="probe">(.*?)</pre>', out)
    assert m, "the page did not run its scripts"
    got = json.loads(m.group(1).replace("&quot;", '"'))
    assert "error" not in got, got
    assert got["actions"] == info["tracks"]
    assert got["duration"] == pytest.approx(1.0, abs=0.021)
    assert got["playing"] is True and got["time"] > 0.1
    assert got["meshes"] >= 17


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (make test installs it as root)")
def test_recording_renders_the_scene(recording, tmp_path):
    """A screenshot: the robot, the ground and the sky are there (not a blank page)."""
    _, path, _ = recording
    shot = tmp_path / "shot.png"
    # a profile of its own: a second Chromium on the default profile can wait on the first's lock
    subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}", "--window-size=640,480",
                    "--virtual-time-budget=3000",
                    f"--screenshot={shot}", str(path)], capture_output=True, timeout=120)
    import matplotlib.image as mpimg

    img = mpimg.imread(shot)[..., :3]
    assert img.shape[:2] == (480, 640)
    colours = np.unique((img.reshape(-1, 3) * 15).astype(int), axis=0)
    assert len(colours) > 50  # a rendered 3-D scene, not a uniform page
