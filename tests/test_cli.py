"""The command line: bad input ends with exit 2 and one line naming the fault (never a traceback,
never Boost.Python signature text); a run that fails ends with exit 1 and says why."""
import json
import subprocess
import sys
import textwrap

import pytest

from stiction.cli import main


def run(capsys, *argv):
    try:
        rc = main(list(argv))
    except SystemExit as exc:  # argparse errors and --version
        rc = exc.code
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_line(err: str, *parts: str):
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "C++ signature" not in err
    for part in parts:
        assert part in lines[0], f"{part!r} not in {lines[0]!r}"


@pytest.fixture
def typo_scene(tmp_path):
    path = tmp_path / "typo.toml"
    path.write_text('urdf = "cube.urdf"\ndurration = 1.0\n')
    return str(path)


BAD = [
    (["simulate", "cube-slid"], ["unknown scene 'cube-slid'", "did you mean 'cube-slide'"]),
    (["simulate", "cube-slide", "--dt", "-1"], ["--dt", "> 0"]),
    (["simulate", "cube-slide", "--dt", "abc"], ["--dt", "not a number"]),
    (["simulate", "cube-slide", "--duration", "nan"], ["--duration", "finite"]),
    (["simulate", "cube-slide", "--duration", "inf"], ["--duration", "finite"]),
    (["simulate", "cube-slide", "--duration", "0.0004"], ["shorter than one step"]),
    (["simulate", "cube-slide", "--dt", "1"], ["duration 0.5 s is shorter than one step (dt = 1 s)"]),  # the scene's
    (["simulate", "cube-slide", "--mode", "rk5"], ["--mode", "rk5"]),
    (["simulate", "cube-slide", "--mu", "-1"], ["--mu"]),
    (["simulate", "cube-slide", "--zeta", "0"], ["--zeta"]),
    (["simulate", "cube-slide", "--solver", "pgs"], ["--solver", "pgs"]),
    (["simulate", "cube-incline-slip", "--duration", "0.05"], ["settle_time = 0.1 s", "ends at t = 0.05 s"]),
    (["simulate", "cube-slide", "--mode", "timestep", "--delta", "1e-3"], []),  # accepted, see below
    (["simulate", "cube-slide", "--plot", "out.txt"], ["--plot", ".png"]),
    (["simulate", "cube-slide", "--save", "t.csv"], ["--save", ".npz"]),
    (["simulate", "cube-slide", "--record", "no/such/folder/x.html"], ["--record", "does not exist"]),
    (["simulate", "/no/such/scene.toml"], ["not found", "/no/such/scene.toml"]),
    (["fclib", "/no/such/file.dat"], ["no such file", "/no/such/file.dat"]),
    (["fclib", "x.dat", "--tol", "0"], ["--tol"]),
    (["fclib", "x.dat", "--max-iter", "-3"], ["--max-iter"]),
    (["nonsense"], ["invalid choice", "nonsense"]),
    ([], ["required", "command"]),
]


@pytest.mark.parametrize("argv,parts", BAD, ids=[" ".join(a) or "none" for a, _ in BAD])
def test_bad_input_exits_2_with_one_line(capsys, tmp_path, monkeypatch, argv, parts):
    monkeypatch.chdir(tmp_path)
    if "--delta" in argv:  # delta with time stepping is meaningless: refused, not ignored
        rc, out, err = run(capsys, *argv)
        assert rc == 2
        assert_one_line(err, "delta")
        return
    rc, out, err = run(capsys, *argv)
    assert rc == 2, (rc, err)
    assert_one_line(err, *parts)


def test_scene_typo_exits_2_naming_the_key(capsys, typo_scene):
    rc, out, err = run(capsys, "simulate", typo_scene)
    assert rc == 2
    assert_one_line(err, "typo.toml", "'durration'", "did you mean 'duration'")


def test_record_into_a_directory_is_refused_before_simulating(capsys, tmp_path, monkeypatch):
    import stiction.simulator as simulator

    def never(*args, **kwargs):
        raise AssertionError("simulated before checking --record")

    monkeypatch.setattr(simulator.Simulator, "rollout", never)
    rc, out, err = run(capsys, "simulate", "cube-slide", "--record", str(tmp_path))
    assert rc == 2
    assert_one_line(err, "--record", "is a directory")


def test_unconverged_run_exits_1_and_says_why(capsys):
    """A tolerance no solver can reach: every step is reported unconverged, and the CLI says so."""
    rc, out, err = run(capsys, "simulate", "cube-slide", "--duration", "0.005", "--tol", "1e-300",
                       "--solver", "nsgs", "--json")
    assert rc == 1
    summary = json.loads(out)
    assert summary["all_converged"] is False and summary["unconverged_steps"] == summary["steps"] == 5
    assert_one_line(err, "5 of 5 steps did not solve", "first at t = 0.001")


def test_simulate_json_reports_the_overrides(capsys):
    rc, out, err = run(capsys, "simulate", "cube-slide", "--duration", "0.1", "--dt", "5e-4", "--mu", "0.3", "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["dt"] == 5e-4 and s["steps"] == 200 and s["duration"] == pytest.approx(0.1)
    assert s["all_converged"] and s["unconverged_steps"] == 0 and s["first_unconverged_t"] is None


def test_version_and_python_dash_m(tmp_path):
    import stiction

    out = subprocess.run([sys.executable, "-m", "stiction", "--version"], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0 and out.stdout.strip() == f"stiction {stiction.__version__}"
    bad = subprocess.run([sys.executable, "-m", "stiction", "simulate", "cube-slid"], capture_output=True, text=True,
                         cwd=tmp_path)
    assert bad.returncode == 2
    assert_one_line(bad.stderr, "unknown scene")


def test_internal_errors_are_one_line_too(capsys, monkeypatch):
    import stiction.cli as cli

    def boom(args):
        raise KeyError("x")

    monkeypatch.setattr(cli, "cmd_scenes", boom)
    monkeypatch.delenv("STICTION_TRACEBACK", raising=False)
    rc, out, err = run(capsys, "scenes")
    assert rc == 1
    assert_one_line(err, "internal error: KeyError", "STICTION_TRACEBACK=1")


def test_scenes_lists_descriptions(capsys):
    rc, out, err = run(capsys, "scenes")
    assert rc == 0
    assert "cube-slide" in out and "solo12-stand" in out and "Solo-12" in out


def test_scene_file_cli_roundtrip(capsys, tmp_path):
    path = tmp_path / "mine.toml"
    path.write_text(textwrap.dedent("""\
        urdf = "cube.urdf"
        duration = 0.05
        [ground]
        slope_deg = 30.0
        mu = 0.6
        [contacts]
        box_corners = true
        """))
    rc, out, err = run(capsys, "simulate", str(path), "--json")
    assert rc == 0, err
    s = json.loads(out)
    assert s["scene"] == "mine" and s["steps"] == 50 and s["base_drift"] < 1e-9


def test_coarse_step_penetration_is_warned_about(capsys):
    """ball-on-table at dt = 50 ms: the ball lands 4.7 cm inside the table for one step (then rests
    exactly on it); the run succeeds but says so."""
    rc, out, err = run(capsys, "simulate", "ball-on-table", "--dt", "0.05", "--json")
    assert rc == 0
    s = json.loads(out)
    assert s["max_penetration"] == pytest.approx(0.04715, abs=1e-4)
    assert len(s["warnings"]) == 1 and "too coarse" in s["warnings"][0]
    assert_one_line(err, "warning: max penetration 0.0472 m exceeds 0.001 m")


def test_a_reader_that_stops_early_is_not_an_error(monkeypatch, capsys):
    """`stiction scenes | head -1` or `| grep -q`: the closed pipe ends the command quietly with 0
    (it was reported as an internal error, exit 1, which failed the CI smoke test's pipeline)."""
    import io

    class ClosedPipe(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(sys, "stdout", ClosedPipe())
    assert main(["scenes"]) == 0
    assert "internal error" not in capsys.readouterr().err
