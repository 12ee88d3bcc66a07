"""Every example runs from another directory, uses only the public API, and prints the physics
it claims (checked here against the closed forms it quotes)."""
import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


def run(path: Path, cwd: Path) -> str:
    out = subprocess.run([sys.executable, str(path)], capture_output=True, text=True, cwd=cwd, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr
    return out.stdout


def numbers(line: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+\.\d+(?:e-?\d+)?", line)]


@pytest.mark.parametrize("path", EXAMPLES, ids=[p.name for p in EXAMPLES])
def test_example_uses_only_the_public_api(path):
    source = path.read_text()
    assert "_core" not in source and "stiction._" not in source


def test_custom_model(tmp_path):
    out = run(Path(EXAMPLES[0].parent / "custom_model.py"), tmp_path)
    feet = next(line for line in out.splitlines() if "feet carry" in line)
    carried, weight = numbers(feet)
    assert carried == pytest.approx(weight, rel=1e-6)
    slope = next(line for line in out.splitlines() if "slope" in line)
    a, theory = numbers(slope)[-2:]
    assert a == pytest.approx(theory, rel=1e-5)


def test_solve_contact_problem(tmp_path):
    out = run(Path(EXAMPLES[0].parent / "solve_contact_problem.py"), tmp_path)
    for key in ("normal impulse", "friction impulse", "velocity after the step"):
        line = next(line for line in out.splitlines() if line.startswith(key))
        got, expected = numbers(line)[:2]
        assert got == pytest.approx(expected, abs=1e-9), line
    assert "converged True" in out


def test_every_example_has_a_test():
    tested = {"custom_model.py", "solve_contact_problem.py"}
    assert {p.name for p in EXAMPLES} == tested
