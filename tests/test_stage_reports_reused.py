"""The solve's stage reports and message are made in strings kept from the previous solve (no
allocation per simulator step, solver.cpp's clearStages / addStage): what a result says must not
depend on what the solves before it said. Checked against a single contact with A = I, whose
answer is closed-form (lambda = b inside the cone: sticking; outside, lambda_t = mu b_n b_t / |b_t|)."""
import numpy as np

import stiction

MU = 0.5  # (spatial_problem's mu)


def sticking_problem():
    return stiction.spatial_problem(np.eye(3), np.array([0.1, 0.05, 1.0]), [MU])


def sliding_problem():
    return stiction.spatial_problem(np.eye(3), np.array([2.0, 1.0, 1.0]), [MU])


def reports(result):
    return [(s.name, s.iterations, s.outcome) for s in result.stages], result.message, result.solver, result.own_law


def test_stage_reports_and_messages_read_the_same_whatever_came_before():
    b_stick = np.array([0.1, 0.05, 1.0])
    b_slide = np.array([2.0, 1.0, 1.0])
    slide_lam = np.array([MU * 2.0 / np.hypot(2.0, 1.0), MU * 1.0 / np.hypot(2.0, 1.0), 1.0])
    stiction.reset_solvers()
    first_stick = stiction.solve(sticking_problem(), tol=1e-10)
    stiction.reset_solvers()
    first_slide = stiction.solve(sliding_problem(), tol=1e-10)
    np.testing.assert_allclose(first_stick.lam, b_stick, rtol=0, atol=1e-12)
    np.testing.assert_allclose(first_slide.lam, slide_lam, rtol=0, atol=1e-12)
    assert first_stick.message == "converged (sticking step)", first_stick.message
    assert [s.name for s in first_stick.stages] == ["sticking step"]
    assert first_slide.message == "converged (newton)" and [s.name for s in first_slide.stages] == ["newton"]
    expected = {"stick": reports(first_stick), "slide": reports(first_slide)}
    for k in range(20):  # alternating: each solve's reports in the strings of the other's
        kind = "stick" if k % 3 else "slide"
        stiction.reset_solvers()  # (the held factor would change the outcome; the strings are kept)
        r = stiction.solve(sticking_problem() if kind == "stick" else sliding_problem(), tol=1e-10)
        assert reports(r) == expected[kind], (k, reports(r), expected[kind])
        np.testing.assert_allclose(r.lam, b_stick if kind == "stick" else slide_lam, rtol=0, atol=1e-12)
    # results read earlier keep what they said (copies, not views of reused strings)
    assert reports(first_stick) == expected["stick"] and reports(first_slide) == expected["slide"]
