"""Every example runs from another directory, uses only the public API, and prints the physics
it claims (checked here against the closed forms it quotes)."""
import re
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = sorted((Path(__file__).resolve().parents[1] / "examples").glob("*.py"))


def run(path: Path, cwd: Path, *args: str) -> str:
    out = subprocess.run([sys.executable, str(path), *args], capture_output=True, text=True, cwd=cwd, timeout=300)
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


def test_joint_rows(tmp_path):
    """The example's pendulum (1 kg point mass 0.5 m below a hinge about y, 1e-6 kg m^2 of its own) against
    closed forms: gravity's torque -m g L sin(theta), I = m L^2 + 1e-6."""
    import math

    out = run(Path(EXAMPLES[0].parent / "joint_rows.py"), tmp_path)
    lines = {line.split(":")[0]: numbers(line) for line in out.splitlines()}
    m, g, length, tau_c = 1.0, 9.81, 0.5, 0.5
    moved, friction, gravity = next(v for k, v in lines.items() if k.startswith("hold"))[1:]
    assert moved == 0.0 and friction == pytest.approx(0.9 * tau_c, abs=1e-6) and gravity == -friction
    theta = math.asin(1.1 * tau_c / (m * g * length))
    expected = (-m * g * length * math.sin(theta) + tau_c) / (m * length ** 2 + 1e-6)
    got = next(v for k, v in lines.items() if k.startswith("slip"))[1]
    assert got == pytest.approx(expected, rel=1e-8)
    smallest, overshoot, limit, gravity = next(v for k, v in lines.items() if k.startswith("limit"))[1:]
    assert abs(smallest - 0.2) <= 1e-12 and overshoot <= 1e-12
    assert limit == pytest.approx(m * g * length * math.sin(0.2), rel=1e-6) and gravity == pytest.approx(-limit, rel=1e-6)
    assert next(v for k, v in lines.items() if k.startswith("effort"))[-1] == 2.0


def test_trot(tmp_path):
    """The trot on both grounds, stiction and (when installed) MuJoCo side by side: stiction walks the
    commanded distance (0.3 m/s from 0.5 s, ramped over 0.5 s) to 30 % on mu = 0.8 with no stance slip
    beyond 1e-9 m (only touchdown steps slide); on ice its feet slide by millimetres per stance."""
    out = run(Path(EXAMPLES[0].parent / "trot.py"), tmp_path, "--quick")

    def row(ground: str, simulator: str) -> list[float]:  # distance, slip, sliding, real-time factor
        return numbers(next(line for line in out.splitlines() if line.startswith(ground) and simulator in line))[1:]

    distance, slip, sliding, _ = row("mu 0.8", "stiction")
    commanded = 0.3 * (1.5 - 0.5 - 0.25)
    assert abs(distance - commanded) <= 0.3 * commanded and slip <= 1e-9 and sliding < 0.01
    ice_distance, ice_slip, ice_sliding, _ = row("mu 0.1", "stiction")
    assert ice_slip > 1e-3 and ice_sliding > 0.05 and ice_distance < distance
    try:
        import mujoco  # noqa: F401
    except ImportError:
        return
    assert row("mu 0.8", "mujoco")[0] > 0.0  # the same controller moves the twin forward too


def test_identify_friction(tmp_path):
    """The cube's mu and mass recovered from the noisy recording to 1e-3 (relative) in <= 50 iterations."""
    out = run(Path(EXAMPLES[0].parent / "identify_friction.py"), tmp_path, "--quick")
    mu = next(line for line in out.splitlines() if line.startswith("cube: mu"))
    mass = next(line for line in out.splitlines() if line.startswith("cube: mass"))
    assert abs(numbers(mu)[0] - 0.5) / 0.5 <= 1e-3 and abs(numbers(mass)[0] - 1.0) <= 1e-3
    assert int(next(line for line in out.splitlines() if "iterations" in line).split()[1]) <= 50


def test_throw_to_target(tmp_path):
    """Newton through the chained step Jacobians lands the sliding cube on the target (< 1e-6 m) and
    Nelder-Mead, given the same number of simulated steps, does not; the launch velocity found agrees
    with the closed form of a slide from rest speed v0: distance v0^2 / (2 mu g) along v0, to the
    discretisation's O(h) (the exact law's time-stepped stop is within a step of the continuous one)."""
    out = run(Path(EXAMPLES[0].parent / "throw_to_target.py"), tmp_path, "--quick")
    gradient = numbers(next(line for line in out.splitlines() if line.startswith("gradient (")))
    nelder_mead = numbers(next(line for line in out.splitlines() if line.startswith("nelder-mead")))
    assert gradient[0] < 1e-6 and nelder_mead[0] > 1e-6
    assert "gradient True, nelder-mead False" in out
    last = next(line for line in reversed(out.splitlines()) if line.startswith("gradient iteration"))
    vx, vy = numbers(last)[:2]
    v0 = (vx * vx + vy * vy) ** 0.5
    distance = v0 * v0 / (2 * 0.5 * 9.81)  # (the cube starts at x = y = 0)
    assert distance == pytest.approx((0.25 ** 2 + 0.10 ** 2) ** 0.5, rel=0.02)
    assert vy / vx == pytest.approx(0.10 / 0.25, rel=1e-6)  # a straight slide: no rotation, friction along -v


def test_every_example_has_a_test():
    tested = {"custom_model.py", "solve_contact_problem.py", "joint_rows.py", "trot.py", "identify_friction.py",
              "throw_to_target.py"}
    assert {p.name for p in EXAMPLES} == tested
