"""Fuzz the solver API (Hypothesis, derandomised): any arguments give a clear ValueError/TypeError
(one line, naming the argument, never Boost.Python's signature text) or an honest result (finite
numbers; `converged` only when the residual meets the tolerance)."""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import stiction
from stiction import Constraint, ContactProblem

ACCEPTED = (ValueError, TypeError)


def _clear(exc: BaseException) -> None:
    msg = str(exc)
    assert msg and "\n" not in msg.strip(), repr(msg)
    assert "C++ signature" not in msg and "did not match" not in msg, msg


scalars = st.one_of(st.none(), st.booleans(), st.integers(-3, 3), st.floats(allow_nan=True, allow_infinity=True),
                    st.text(max_size=4), st.complex_numbers(max_magnitude=2, allow_nan=False))


@st.composite
def arrays(draw, shape_hint: int):
    kind = draw(st.sampled_from(["good", "shape", "nan", "complex", "list", "scalar", "none", "str", "int"]))
    n = shape_hint
    if kind == "good":
        return draw(st.lists(st.floats(-5, 5), min_size=n, max_size=n)).copy()
    if kind == "shape":
        m = draw(st.integers(0, n + 2))
        return np.zeros((m, draw(st.integers(1, 3)))) if draw(st.booleans()) else np.zeros(m)
    if kind == "nan":
        a = np.zeros(n)
        if n:
            a[draw(st.integers(0, n - 1))] = draw(st.sampled_from([math.nan, math.inf, -math.inf]))
        return a
    if kind == "complex":
        return np.zeros(n, dtype=complex)
    if kind == "list":
        return [0.0] * n
    if kind == "scalar":
        return draw(st.floats(-1, 1))
    if kind == "none":
        return None
    if kind == "str":
        return "0 1 2"
    return np.arange(n, dtype=np.int64)


def _spd(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    return (Q * np.geomspace(1.0, 1e-3, n)) @ Q.T


@settings(max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(1, 3), st.integers(0, 10**6), st.data())
def test_problem_construction_and_solve(nc, seed, data):
    n = 3 * nc
    A = _spd(n, seed)
    b = np.random.default_rng(seed + 1).standard_normal(n)
    mu = data.draw(st.one_of(st.floats(0, 2), scalars))
    bad_A = data.draw(st.booleans())
    args_A = data.draw(arrays(n)) if bad_A else A
    if isinstance(args_A, list) and len(args_A) == n and not isinstance(args_A[0], list):
        args_A = A.tolist()  # a list of lists is a fine matrix
    args_b = data.draw(arrays(n)) if data.draw(st.booleans()) else b
    try:
        constraints = [Constraint.spatial_friction(mu)] * nc
        problem = ContactProblem(args_A, args_b, constraints)
    except ACCEPTED as exc:
        _clear(exc)
        return
    tol = data.draw(st.one_of(st.just(1e-10), scalars))
    max_iter = data.draw(st.one_of(st.just(200), scalars))
    time_limit = data.draw(st.one_of(st.just(1.0), scalars))
    warm = data.draw(st.one_of(st.none(), st.just("proxqp"), st.text(max_size=3), arrays(n)))
    solver = data.draw(st.sampled_from(["default", "nsgs", "admm", "newton", "pgs", ""]))
    try:
        result = stiction.solve(problem, solver=solver, tol=tol, max_iter=max_iter, warm_start=warm,
                                time_limit=time_limit)
    except ACCEPTED as exc:
        _clear(exc)
        return
    assert np.isfinite(result.lam).all() and math.isfinite(result.residual)
    if result.converged:
        assert result.relative_residual <= float(tol)
        assert stiction.residual(problem, result.lam) == pytest.approx(result.residual, rel=1e-6, abs=1e-12)


@pytest.mark.parametrize("call", [
    lambda: Constraint.spatial_friction("x"), lambda: Constraint.spatial_friction(None),
    lambda: Constraint.bilateral(-1), lambda: Constraint.bilateral(2.5),
    lambda: ContactProblem(np.eye(2), np.zeros(2), [Constraint.planar_friction(-1.0)]),
    lambda: ContactProblem(np.eye(3), np.zeros(3), "not a list"),
    lambda: ContactProblem(np.eye(3), np.zeros(3), [None]),
    lambda: ContactProblem(np.eye(3), np.zeros(3), [Constraint.spatial_friction(0.5)], "tol"),
    lambda: stiction.residual(ContactProblem(np.eye(3), np.zeros(3), [Constraint.spatial_friction(0.5)]), None),
    lambda: stiction.residual("problem", np.zeros(3)),
    lambda: stiction.solve("problem"),
    lambda: stiction.solve(None),
])
def test_bad_calls_are_clear(call):
    with pytest.raises(ACCEPTED) as info:
        call()
    _clear(info.value)
