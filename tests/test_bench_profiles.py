"""stiction bench profiles: the profile arithmetic on a hand-made table, the robot problem set, and the
quick bench end to end (our solvers never claim a convergence the exact law denies)."""
import argparse
import csv
import json
import math

import h5py
import numpy as np
import pytest

import stiction
from stiction import cli, fclib
from stiction.bench import profiles, sweep


def _row(problem, solver, seconds, solved, claimed=True, limit=1.0, tol=1e-8, residual=None):
    return {"set": "s", "problem": problem, "solver": solver, "ours": solver == "a", "tol": tol,
            "seconds": seconds, "residual": residual if residual is not None else (1e-9 if solved else 1e-3),
            "converged_claimed": claimed, "solved": solved, "iterations": 1, "contacts": 1,
            "time_limit": limit, "failure": None if solved else "residual"}


def _table():
    # p1: a 1 ms, b 2 ms, c 4 ms.  p2: a fails (false claim), b 3 ms, c 1 ms.  p3: a 1 ms, b fails,
    # c solves but over the limit (2 s > 1 s).  p4: nobody solves it.
    return [
        _row("p1", "a", 1e-3, True), _row("p1", "b", 2e-3, True), _row("p1", "c", 4e-3, True),
        _row("p2", "a", 5e-4, False, claimed=True), _row("p2", "b", 3e-3, True), _row("p2", "c", 1e-3, True),
        _row("p3", "a", 1e-3, True), _row("p3", "b", None, False, claimed=False), _row("p3", "c", 2.0, True),
        _row("p4", "a", 0.1, False, claimed=False), _row("p4", "b", 0.1, False, claimed=True),
        _row("p4", "c", 0.2, False, claimed=False, residual=5e-8),
    ]


def test_performance_ratios_and_profiles_by_hand():
    ratios = profiles.performance_ratios(_table())
    inf = math.inf
    assert ratios["a"] == [1.0, inf, 1.0, inf]
    assert ratios["b"] == [2.0, 3.0, inf, inf]
    assert ratios["c"] == [4.0, 1.0, inf, inf]  # p3: solved but over the time limit -> a failure
    taus = [1.0, 1.5, 2.0, 3.0, 4.0, 1e9]
    for s, success in (("a", 0.5), ("b", 0.5), ("c", 0.5)):
        curve = [profiles.rho(ratios[s], t) for t in taus]
        assert all(x <= y for x, y in zip(curve, curve[1:]))  # non-decreasing
        assert curve[-1] == success  # ends at the success rate (p4 is in every denominator)
    assert [profiles.rho(ratios["b"], t) for t in taus] == [0.0, 0.0, 0.25, 0.5, 0.5, 0.5]
    summary = profiles.summarize(_table())["profiles"]["s"]["1e-08"]
    a, b, c = (summary["solvers"][k] for k in "abc")
    assert (a["solved"], b["solved"], c["solved"]) == (2, 2, 2)
    assert (a["false_claims"], b["false_claims"], c["false_claims"]) == (1, 1, 0)  # p2 by a, p4 by b
    assert a["false_convergence_rate"] == 0.25 and c["within_10x_tol"] == 1.0
    assert a["by_category"] == {"p1": "1/1", "p2": "0/1", "p3": "1/1", "p4": "0/1"}
    assert c["by_category"]["p3"] == "0/1"  # over the time limit
    # shifted geometric mean: failures at the 1 s limit
    sgm = math.exp(np.mean(np.log(np.array([1e-3, 1.0, 1e-3, 1.0]) + profiles.SGM_SHIFT))) - profiles.SGM_SHIFT
    assert a["sgm_seconds"] == pytest.approx(sgm, rel=1e-12)
    # data profile: fraction solved within each budget, ends at the success rate
    budgets = summary["budget_seconds"]
    assert budgets[-1] == pytest.approx(1.0)
    for d in (a, b, c):
        assert all(x <= y for x, y in zip(d["data_profile"], d["data_profile"][1:]))
        assert d["data_profile"][-1] == d["success_rate"]
    text = profiles.report(profiles.summarize(_table())).splitlines()
    assert text[0].startswith("s, tol 1e-08") and [line.split()[0] for line in text[1:]] == ["a", "c", "b"]  # by solved, then time
    k = next(i for i, t in enumerate(budgets) if t >= 1.5e-3)
    assert a["data_profile"][k] == 0.5 and b["data_profile"][k] == 0.0


def test_shifted_geometric_mean():
    assert profiles.shifted_geometric_mean([2.0, 8.0], shift=0.0) == pytest.approx(4.0)
    assert profiles.shifted_geometric_mean([1e-9, 1.0], shift=1.0) == pytest.approx(math.sqrt(2.0) - 1.0, rel=1e-6)


@pytest.fixture(scope="module")
def problem_dir(tmp_path_factory):
    """One cache of robot problem sets for the module (the quick set is built once)."""
    return tmp_path_factory.mktemp("problems")


def test_robot_problem_set_is_seeded_cached_and_large(tmp_path, problem_dir):
    full = profiles.robot_problem_set(tmp_path)
    assert len(full) >= 100
    cats = {r["category"] for r in full}
    assert cats >= {"standing", "slipping", "impacts", "grasps"}
    assert len({r["name"] for r in full}) == len(full)
    # every file is the problem its simulator solved: the forces it stored solve it (tolerance 1e-10)
    for r in full:
        P = fclib.load(r["path"])
        with h5py.File(r["path"], "r") as f:
            lam = f["solution/r"][()][fclib._to_stiction_order(P.contacts)]
        assert stiction.exact_law_measures(P.problem(), lam).relative_residual <= 1e-9, r["name"]
    again = profiles.robot_problem_set(tmp_path)  # from the cache
    assert [r["name"] for r in again] == [r["name"] for r in full]
    other = profiles.robot_problem_set(tmp_path / "b", quick=True, seed=1)
    quick = profiles.robot_problem_set(problem_dir, quick=True, seed=0)
    assert [r["name"] for r in other] != [r["name"] for r in quick]  # a different seed draws other steps
    assert {r["category"] for r in quick} == cats
    with pytest.raises(ValueError, match="seed"):
        profiles.robot_problem_set(tmp_path, seed=-1)
    (tmp_path / "f").write_text("")
    with pytest.raises(ValueError, match="not a folder"):
        profiles.robot_problem_set(tmp_path / "f")


def _args(problem_dir, *extra):
    parser = argparse.ArgumentParser()
    sweep.add_common_arguments(parser)
    profiles.add_arguments(parser)
    return parser.parse_args(["--quick", "--problems", str(problem_dir), *extra])


def test_quick_bench_end_to_end(tmp_path, problem_dir, capsys):
    args = _args(problem_dir, "--out", str(tmp_path / "out"))
    result = sweep.run(profiles, args, "stiction bench profiles --quick")
    rows = result["rows"]
    assert {r["set"] for r in rows} == {"fclib", "robot"}
    assert {r["tol"] for r in rows} == {1e-4, 1e-8}
    assert len({r["solver"] for r in rows}) >= 2
    for r in rows:
        assert r["failure"] is not None or (math.isfinite(r["seconds"]) and math.isfinite(r["residual"]))
        assert r["solved"] == (r["residual"] is not None and r["residual"] <= r["tol"])
    ours = [r for r in rows if r["ours"]]
    # on the robot set our solvers make no false claim of convergence, and solve everything
    robot = [r for r in ours if r["set"] == "robot"]
    assert robot and not any(r["converged_claimed"] and not r["solved"] for r in robot)
    assert all(r["solved"] for r in robot)
    assert not any(r["converged_claimed"] and not r["solved"] for r in ours)
    table = {(t["set"], t["tol"], t["solver"]): t for t in result["table"]}
    assert table[("robot", "1e-08", "default")]["success_rate"] == 1.0
    assert table[("robot", "1e-08", "default")]["false_convergence_rate"] == 0.0
    out = tmp_path / "out"
    with open(out / "profiles.csv", newline="") as fh:
        header = next(csv.reader(fh))
    assert tuple(header) == profiles.FIELDS
    assert (out / "profiles-fclib.png").stat().st_size > 10_000 and (out / "profiles-robot.png").is_file()
    assert (out / "profiles-robot-families.png").is_file()
    # the same through the CLI: resumed from the CSV (nothing re-run), the JSON on stdout
    code = cli.main(["bench", "profiles", "--quick", "--json", "--problems", str(problem_dir),
                     "--out", str(out)])
    assert code == 0
    again = json.loads(capsys.readouterr().out)
    assert again["resumed"] == len(rows) and len(again["rows"]) == len(rows)
    assert again["table"] == json.loads(json.dumps(result["table"]))
    # another time limit is another case: nothing resumed from the 2 s rows
    other = sweep.run(profiles, _args(problem_dir, "--out", str(out), "--sets", "robot", "--solvers", "default",
                                      "--tols", "1e-8", "--time-limit", "3"), "x")
    assert other["resumed"] == 0 and {r["time_limit"] for r in other["rows"]} == {3.0}


def test_bad_options_are_loud(problem_dir):
    for bad, match in ((["--sets", "fclib,nope"], "nope"), (["--solvers", "default,pgs"], "pgs"),
                       (["--tols", "1e-4,-1"], "tols"), (["--time-limit", "0"], "time-limit")):
        with pytest.raises(ValueError, match=match):
            profiles.cases(_args(problem_dir, *bad))


def test_an_option_given_empty_is_an_error_naming_it(problem_dir):
    """`--sets ""` (or only commas) used to run the default sets; the same for --solvers and --tols."""
    for bad, match in ((["--sets", ""], "--sets"), (["--sets", " , "], "--sets"),
                       (["--sets", "fclib", "--solvers", ""], "--solvers"),
                       (["--sets", "fclib", "--tols", ""], "--tols"), (["--sets", "fclib", "--tols", "abc"], "--tols")):
        with pytest.raises(ValueError, match=match):
            profiles.cases(_args(problem_dir, *bad))
    assert cli.main(["bench", "profiles", "--quick", "--sets", "", "--json"]) == 2


def test_a_cache_from_another_recipe_is_rebuilt(tmp_path, monkeypatch):
    first = profiles.robot_problem_set(tmp_path, quick=True)
    monkeypatch.setattr(profiles, "QUICK_ROBOT_SCENES", ("cube-incline-slip",))
    second = profiles.robot_problem_set(tmp_path, quick=True)
    assert {r["scene"] for r in second if r["category"] != "impacts"} == {"cube-incline-slip"}
    assert len(second) < len(first)
    folder = next(tmp_path.iterdir())
    assert sorted(p.name for p in folder.glob("*.hdf5")) == sorted(r["file"] for r in second)


def test_siconos_only_when_usable(problem_dir, monkeypatch):
    monkeypatch.setattr(profiles, "siconos_usable", lambda python="/usr/bin/python3": False)
    solvers = {c["solver"] for c in profiles.cases(_full_args(problem_dir, "--sets", "fclib"))}
    assert solvers == set(profiles.OURS + profiles.PINOCCHIO)
    with pytest.raises(ValueError, match="Siconos"):
        profiles.cases(_full_args(problem_dir, "--sets", "fclib", "--solvers", "default,siconos-nsgs"))
    monkeypatch.setattr(profiles, "siconos_usable", lambda python="/usr/bin/python3": True)
    solvers = {c["solver"] for c in profiles.cases(_full_args(problem_dir, "--sets", "fclib"))}
    assert solvers == set(profiles.ALL_SOLVERS)


def _full_args(problem_dir, *extra):
    parser = argparse.ArgumentParser()
    sweep.add_common_arguments(parser)
    profiles.add_arguments(parser)
    return parser.parse_args(["--problems", str(problem_dir), *extra])
