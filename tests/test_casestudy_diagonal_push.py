"""Case study "diagonal-push": a cube pushed at an angle, the exact cone against facetized
pyramids; the module's predictions re-derived here independently (closed forms for the
4-facet pyramid, brute-force projections for the others)."""
import json
import math

import numpy as np
import pytest

from stiction import cli
from stiction.casestudies import diagonal_push as cs
from stated_checks import assert_checks_as_stated


@pytest.fixture(scope="module")
def result():
    return cs.run(quick=True)


def box_prediction(phi, r, inscribed=False):
    """4 facets, phi in [0, 45 deg], units mu m g, written out from the geometry: the box
    |f_x|, |f_y| <= rho. Sticks iff r cos phi <= rho (cos >= sin here). Sliding: along x with
    the friction on the facet f_x = -rho, f_y = -r sin phi (it holds the cross push) while
    r sin phi <= rho: error atan(r sin phi / rho); beyond, the friction sits at the corner
    (-rho, -rho) and v is along (r cos phi - rho, r sin phi - rho)."""
    rho = math.cos(math.pi / 4) if inscribed else 1.0
    if r * math.cos(phi) <= rho:
        return None, None
    if r * math.sin(phi) <= rho:
        return math.atan(r * math.sin(phi) / rho), 0.0
    psi = math.atan2(r * math.sin(phi) - rho, r * math.cos(phi) - rho)
    return math.pi / 4 - psi, math.degrees(psi)


# The module's checks as this file states them (docs/casestudies/diagonal-push.md): pattern,
# expected, tolerance, kind. Measured (quick run): exact directions 5e-15 rad, pyramids vs their
# geometry <= 4e-10 rad, sliding directions <= 1.2e-8 deg, sticking drift 1.8e-14 m, smallest
# slide 2.2e-3 m, yaw 2.5e-13 rad.
STATED = [
    (r"^[\w-]+: points misclassified", 0.0, 0.0, "=="),
    (r"^exact: largest friction direction error", 0.0, 1e-6, "<="),
    (r"^exact: largest per-contact friction direction error", 0.0, 1e-6, "<="),
    (r"^[\w-]+: max \|sliding direction - direction of F - P\(F\)\| \[deg\]", 0.0, 1e-4, "=="),
    (r"^pyramid-\d+(-inscribed)?: max \|direction error", 0.0, 1e-6, "=="),
    (r"^largest window displacement of a sticking run", 0.0, 1e-8, "<="),  # 1e-6 m / 100
    (r"^smallest window displacement of a sliding run", 1e-4, 0.0, ">="),  # 1e-6 m x 100
    (r"^largest yaw of the cube", 0.0, 1e-7, "<="),
]


def test_every_check_passes(result):
    failed = [(c.quantity, c.measured, c.expected) for c in result.checks if not c.passed]
    assert not failed
    assert_checks_as_stated(result, STATED)
    assert result.name == "diagonal-push"
    labels = {c.quantity.split(":")[0] for c in result.checks}
    assert {"exact", "pyramid-4", "pyramid-4-inscribed", "pyramid-8", "pyramid-16"} <= labels


def test_exact_sticks_iff_below_mu_m_g_and_opposes_velocity(result):
    exact = [p for p in result.points if p["formulation"] == "exact"]
    assert {p["sticks"] for p in exact} == {True, False}
    for p in exact:
        assert p["sticks"] == (p["force_ratio"] <= 1.0)
        if not p["sticks"]:
            assert p["direction_error_max_rad"] <= 1e-6
            assert p["contact_direction_error_max_rad"] <= 1e-6
            assert p["velocity_direction_deg"] == pytest.approx(p["phi_deg"], abs=1e-6)
            # a = (F - mu m g) / m along the push: the window distance of uniform acceleration
            a = (p["force_ratio"] - 1.0) * 0.5 * 9.81
            t0, t1 = cs.SETTLE, cs.SETTLE + cs.WINDOW
            h = 1e-3  # semi-implicit Euler from rest: x_k = a h^2 k (k + 1) / 2 = a t (t + h) / 2
            assert p["displacement"] == pytest.approx(0.5 * a * (t1 * (t1 + h) - t0 * (t0 + h)), rel=1e-6)
        else:
            assert p["displacement"] < 1e-12


def test_box_pyramid_matches_its_closed_form(result):
    seen_regimes = set()
    for label, inscribed in (("pyramid-4", False), ("pyramid-4-inscribed", True)):
        for p in (q for q in result.points if q["formulation"] == label):
            phi = math.radians(p["phi_deg"])
            rho = math.cos(math.pi / 4) if inscribed else 1.0
            assert p["stick_bound_ratio"] == pytest.approx(rho / max(abs(math.cos(phi)), abs(math.sin(phi))),
                                                           rel=1e-12)
            err, vdir = box_prediction(phi, p["force_ratio"], inscribed)
            assert p["sticks"] == (err is None), p
            if err is None:
                continue
            assert p["predicted_direction_error_rad"] == pytest.approx(err, abs=1e-12)
            assert p["direction_error_rad"] == pytest.approx(err, abs=1e-6), p
            assert p["velocity_direction_deg"] == pytest.approx(vdir, abs=1e-4), p
            seen_regimes.add("corner" if vdir > 0 else "facet")
    # the quick sweep exercises both regimes, and the 45-deg point sticks beyond mu m g
    assert seen_regimes == {"corner", "facet"}
    p45 = [p for p in result.points if p["formulation"] == "pyramid-4" and p["phi_deg"] == 45.0]
    assert p45 and all(p["sticks"] and p["force_ratio"] > 1.0 for p in p45)


def test_projection_against_brute_force():
    """cs.project onto the N-gon vs the nearest of 200,000 points of its boundary."""
    rng = np.random.default_rng(7)
    for facets, inscribed in ((4, False), (4, True), (8, False), (16, False), (5, False)):
        half = math.pi / facets
        radius = (math.cos(half) if inscribed else 1.0) / math.cos(half)
        a = 2 * math.pi * np.arange(facets) / facets + half
        corners = radius * np.column_stack([np.cos(a), np.sin(a)])
        s = np.linspace(0.0, 1.0, 200000 // facets, endpoint=False)[:, None]
        boundary = np.concatenate([c0 + s * (c1 - c0) for c0, c1 in zip(corners, np.roll(corners, -1, axis=0))])
        for _ in range(20):
            F = rng.uniform(-2.0, 2.0, 2)
            P = cs.project(F, facets, inscribed)
            inside = all(math.cos(2 * math.pi * k / facets) * F[0] + math.sin(2 * math.pi * k / facets) * F[1]
                         <= radius * math.cos(half) for k in range(facets))
            if inside:
                assert np.allclose(P, F)
                continue
            ref = boundary[np.argmin(np.linalg.norm(boundary - F, axis=1))]
            assert np.linalg.norm(P - ref) < 1e-4


def test_cli_json(capsys):
    assert cli.main(["casestudy", "diagonal-push", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["name"] == "diagonal-push" and out["passed"] is True
    assert out["checks"] and all(c["passed"] for c in out["checks"])
    keys = {"formulation", "phi_deg", "force_ratio", "sticks", "direction_error_rad", "predicted_sticks",
            "predicted_direction_error_rad", "stick_bound_ratio", "displacement"}
    assert all(keys <= set(p) for p in out["points"])
    sliding = [p for p in out["points"] if not p["sticks"]]
    assert sliding and all(isinstance(p["direction_error_rad"], float) for p in sliding)
    assert all(p["direction_error_rad"] is None for p in out["points"] if p["sticks"])


def test_plot(result, tmp_path):
    pytest.importorskip("matplotlib")
    path = tmp_path / "push.png"
    cs.plot(result, path)
    assert path.stat().st_size > 10000
