"""benchmarks/bench_derivatives.py (issue 26, "Fast"): the table's fields on a small run (never a timed
assertion). The accuracy columns are the analytic derivatives against central differences of the step."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_derivatives", ROOT / "benchmarks/bench_derivatives.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_bench_derivatives_table_fields(tmp_path, capsys):
    bench = _bench()
    out = tmp_path / "derivatives.json"
    result = bench.main(["--scenes", "ur5-push-wall", "ur5-joint-limit", "--repeats", "2", "--reference-repeats", "1",
                         "--out", str(out)])
    assert json.loads(out.read_text())["rows"][0]["scene"] == "ur5-push-wall"
    assert out.with_suffix(".md").read_text() == result["table"] == capsys.readouterr().out.rstrip("\n") + "\n"
    assert len(result["meta"]["load_before"]) == 3 and len(result["meta"]["load_after"]) == 3
    wall, limit = result["rows"]
    # the UR5 pressing on the wall: 6 dof, central differences over (q, v, tau) take 2 * 3 * 6 steps
    assert wall["nv"] == 6 and wall["fd_steps"] == 36 and wall["refused"] is None
    for key in ("step_us_cpp", "step_us_wall", "derivatives_us", "derivatives_no_q_us", "fd_us_wall",
                "fd_us_steps", "reference_fd_us"):
        assert wall[key] > 0, key
    assert wall["ratio_to_step"] == pytest.approx(wall["derivatives_us"] / wall["step_us_wall"])
    assert wall["speedup_over_fd"] == pytest.approx(wall["fd_us_wall"] / wall["derivatives_us"])
    assert wall["modes"] == ["stick"]
    # every block agrees with the differences of the step (eps 1e-6: truncation and rounding near 1e-7)
    assert set(wall["error_vs_fd"]) == set(bench.BLOCKS)
    assert max(wall["error_vs_fd"].values()) < 1e-5 and max(wall["error_vs_reference"].values()) < 1e-5
    # the cheap differences (tolerance 1e-10) and the reference's (1e-14) are the same derivative
    assert max(wall["error_fd_vs_reference"].values()) < 1e-6
    # a step with joint rows: step_derivatives refuses, and the row says so with its message
    assert limit["refused"].startswith("NotImplementedError") and limit["derivatives_us"] is None
    assert "refused: NotImplementedError" in result["table"]
