"""`stiction bench scaling`: the JSON the charts issue builds on (never a timed assertion)."""
import json

import pytest

from stiction.bench import scaling
from stiction.cli import main


def test_scaling_json_has_one_row_per_size_and_an_exponent(capsys):
    assert main(["bench", "scaling", "--sizes", "4", "8", "--steps", "5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["command"] == "stiction bench scaling --sizes 4 8 --steps 5 --json"
    assert out["stamp"]["cores"] >= 1 and out["stamp"]["versions"]["pinocchio"].startswith("4.1")
    assert [r["contacts"] for r in out["rows"]] == [4, 8]
    for r in out["rows"]:
        assert set(r) >= {"scene", "contacts", "us_per_step", "us_per_contact", "peak_memory_mb", "mujoco_us_per_step"}
        assert r["us_per_step"] > 0 and r["us_per_contact"] == pytest.approx(r["us_per_step"] / r["contacts"])
        assert r["peak_memory_mb"] > 10 and r["all_converged"]
        assert r["max_penetration"] <= 1e-9 and r["max_body_drift"] <= 1e-9  # the grid rests exactly
        assert r["mujoco_us_per_step"] is None or r["mujoco_us_per_step"] > 0
    assert isinstance(out["exponent"], float)


def test_exponent_fit_is_the_log_log_slope():
    assert scaling.fit_exponent([4, 16, 64], [1.0, 4.0, 16.0]) == pytest.approx(1.0)
    assert scaling.fit_exponent([4, 16, 64], [1.0, 16.0, 256.0]) == pytest.approx(2.0)
    assert scaling.fit_exponent([4], [1.0]) is None


def test_contact_counts_must_be_whole_cubes(capsys):
    assert main(["bench", "scaling", "--sizes", "6", "--json"]) == 2
    assert "multiples of 4" in capsys.readouterr().err


def test_tower_layout_stacks_the_cubes(capsys):
    """The tower: every cube on the one below (contacts between parts), resting exactly."""
    assert main(["bench", "scaling", "--layout", "tower", "--sizes", "4", "12", "--steps", "5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["layout"] == "tower" and [r["scene"] for r in out["rows"]] == ["cube-tower-4", "cube-tower-12"]
    for r in out["rows"]:
        assert r["all_converged"] and r["max_penetration"] <= 1e-9 and r["max_body_drift"] <= 1e-9
    with pytest.raises(SystemExit) as exc:
        main(["bench", "scaling", "--layout", "heap", "--json"])
    assert exc.value.code == 2 and "invalid choice: 'heap'" in capsys.readouterr().err


def test_steps_must_be_positive_and_an_explicit_value_is_honoured(capsys):
    """--steps 0 is an error naming the flag (with --quick it used to run 50); --quick --steps 7 runs 7."""
    from stiction.cli import build_parser

    for bad in ("0", "-3", "2.5"):
        with pytest.raises(SystemExit) as exc:
            main(["bench", "scaling", "--quick", "--steps", bad, "--json"])
        assert exc.value.code == 2 and "--steps" in capsys.readouterr().err
    parse = build_parser().parse_args
    assert {c["steps"] for c in scaling.cases(parse(["bench", "scaling", "--quick", "--steps", "7"]))} == {7}
    assert {c["steps"] for c in scaling.cases(parse(["bench", "scaling", "--quick"]))} == {50}
    assert {c["steps"] for c in scaling.cases(parse(["bench", "scaling", "--steps", "9"]))} == {9}
    assert {c["steps"] for c in scaling.cases(parse(["bench", "scaling"]))} == {200}
