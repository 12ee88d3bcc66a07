"""stiction dump: each step's contact problem written as FCLib HDF5 and read back unchanged."""
import argparse
import json
import math

import numpy as np
import pytest

import stiction
from stiction import cli, dump, fclib, resources
from stiction.simulator import Simulator


def _solver_problem(sim):
    """The problem the last step solved, from the solver's own answer: b = A lam - u (eq. 65)."""
    r = sim.data.result
    A = np.asarray(sim.data.A)
    return A, A @ np.asarray(r.lam) - np.asarray(r.u), np.asarray(r.lam)


@pytest.mark.parametrize("scene", ["cube-incline-slip", "two-cube-stack", "talos-stand"])
def test_dump_round_trip_is_the_problem_the_solver_saw(tmp_path, scene):
    recs = dump.dump(scene, 30, tmp_path, every=10, **dump.NO_JOINT_ROWS)
    assert [r["step"] for r in recs] == [10, 20, 30]
    ref = Simulator(scene, **dump.NO_JOINT_ROWS)
    for k in range(1, 31):
        ref.step()
        if k % 10:
            continue
        A, b, lam = _solver_problem(ref)
        rec = next(r for r in recs if r["step"] == k)
        P = fclib.load(rec["path"])
        assert P.kind == "fclib_local" and P.contacts == len(ref.data.active) == len(rec["contacts"])
        scale = np.abs(A).max()
        assert np.abs(P.A - A).max() <= 1e-12 * scale
        assert np.abs(P.b - b).max() <= 1e-12 * np.abs(b).max()
        mus = [ref.model.contacts[i].mu for i in ref.data.active]
        assert np.array_equal(P.mu, mus)
        # the simulator's forces solve the file's problem as well as they solved its own
        res = stiction.exact_law_measures(P.problem(), lam).relative_residual
        assert res <= 1e-9 and rec["converged"]
        meta = json.loads(_description(rec["path"]))
        assert meta["scene"] == scene and meta["step"] == k and meta["dt"] == pytest.approx(1e-3)


def _description(path):
    import h5py

    with h5py.File(path, "r") as f:
        return f["fclib_local/info/description"][()].decode()


def test_dumped_problem_carries_the_weight_in_impulses(tmp_path):
    """b is the right-hand side scaled by the step (impulses, eq. 65 for the time stepping of eq. 70): on
    the cube sliding down the 30 degree slope the normal impulses sum to m g cos(30) dt."""
    recs = dump.dump("cube-incline-slip", 200, tmp_path, every=100)
    for rec in recs:
        P = fclib.load(rec["path"])
        r = stiction.solve(P.problem(), tol=1e-12)
        assert r.converged
        normal = np.asarray(r.lam)[2::3].sum()
        assert normal == pytest.approx(1.0 * 9.81 * math.cos(math.radians(30)) * 1e-3, rel=2e-3)


def test_ode_mode_problem_is_the_last_stage_unscaled(tmp_path):
    """In the ODE modes (eq. 64) each RK stage solves A lambda - b at scale 1: the file holds the last
    stage's problem, and the forces the simulator found solve it."""
    recs = dump.dump("cube-incline-slip", 10, tmp_path, every=5, mode="rk4")
    ref = Simulator("cube-incline-slip", mode="rk4")
    for k in range(1, 11):
        ref.step()
        if k % 5 == 0:
            A, b, lam = _solver_problem(ref)
            P = fclib.load(recs[k // 5 - 1]["path"])
            assert np.abs(P.A - A).max() <= 1e-12 * np.abs(A).max()
            assert np.abs(P.b - b).max() <= 1e-12 * np.abs(b).max()
            # force level, not impulses: the normal forces carry m g cos(30) itself
            assert lam[2::3].sum() == pytest.approx(9.81 * math.cos(math.radians(30)), rel=2e-3)


def test_no_file_while_nothing_touches(tmp_path):
    """The ball of ball-on-table falls 10 cm (0.14 s): no contact problem in its first 100 steps,
    and files from its landing on."""
    assert dump.dump("ball-on-table", 100, tmp_path) == []
    assert list(tmp_path.iterdir()) == []
    landed = dump.dump("ball-on-table", 200, tmp_path, every=50)
    assert [r["step"] for r in landed] == [150, 200]


def test_cli_contract(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    dump.add_arguments(parser)
    args = parser.parse_args(["solo12-stand", "--steps", "6", "--every", "3", "--out", str(tmp_path / "d"),
                              "--solver", "nsgs", "--json"])
    assert dump.main(args) == 0
    out = json.loads(capsys.readouterr().out)
    assert [r["step"] for r in out["files"]] == [3, 6]
    assert all(r["solver"] == "nsgs" for r in out["files"])
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == ["solo12-stand-step000003.hdf5",
                                                                   "solo12-stand-step000006.hdf5"]


def test_stiction_dump_command(tmp_path, capsys):
    code = cli.main(["dump", "cube-incline-slip", "--steps", "4", "--every", "2", "--out", str(tmp_path)])
    assert code == 0 and "2 problem(s)" in capsys.readouterr().out
    assert fclib.load(tmp_path / "cube-incline-slip-step000004.hdf5").contacts == 4
    assert cli.main(["dump", "cube-slide", "--steps", "0", "--out", str(tmp_path)]) == 2
    assert "steps" in capsys.readouterr().err
    # a scene file of one's own
    toml = tmp_path / "my-slope.toml"
    toml.write_text((resources.scenes_dir() / "cube-incline-slip.toml").read_text().replace(
        'name = "cube-incline-slip"', 'name = "my-slope"'))
    assert cli.main(["dump", str(toml), "--steps", "3", "--every", "3", "--out", str(tmp_path / "own")]) == 0
    assert fclib.load(tmp_path / "own" / "my-slope-step000003.hdf5").contacts == 4
    assert cli.main(["dump", "cube-slide", "--steps", "2", "--out", str(toml)]) == 2
    assert "is a file" in capsys.readouterr().err


def test_bad_input_is_loud(tmp_path):
    with pytest.raises(ValueError, match="steps"):
        dump.dump("cube-slide", 0, tmp_path)
    with pytest.raises(ValueError, match="every"):
        dump.dump("cube-slide", 5, tmp_path, every=0)
    with pytest.raises(ValueError, match="solver"):
        dump.dump("cube-slide", 5, tmp_path, solver="pgs")
    with pytest.raises(ValueError, match="only"):
        dump.dump("cube-slide", 5, tmp_path, only=[9])
    with pytest.raises(ValueError, match="planar"):  # 2-row contacts: no FCLib local counterpart
        dump.dump("planar-box-slide", 5, tmp_path)


def test_every_beyond_the_steps_is_refused(tmp_path, capsys):
    """--every 10 over 5 steps would write nothing and exit 0: refused (exit 2), before simulating."""
    with pytest.raises(ValueError, match="every = 10 is more than steps = 5"):
        dump.dump("cube-slide", 5, tmp_path, every=10)
    assert cli.main(["dump", "cube-slide", "--steps", "5", "--every", "10", "--out", str(tmp_path)]) == 2
    assert "every = 10 is more than steps = 5" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_dump_refuses_joint_rows(tmp_path):
    """FCLib has no box rows: a step with joint rows (talos-stand: its arms' dry friction) is refused with
    one line saying how to dump the contacts alone; --no-joint-rows does."""
    with pytest.raises(ValueError, match="joint row.*--no-joint-rows"):
        dump.dump("talos-stand", 1, tmp_path)
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "stiction.cli", "dump", "talos-stand", "--steps", "2", "--out",
                          str(tmp_path / "d"), "--no-joint-rows"], capture_output=True, text=True)
    assert out.returncode == 0 and "2 problem(s)" in out.stdout, out.stderr
