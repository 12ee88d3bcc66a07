"""Case study "slide-lift": the sliding cube under every formulation; the key numbers re-derived
here from the trajectories and the step results directly, not through the module."""
import json

import numpy as np
import pytest

import stiction
from stiction import cli
from stiction.casestudies import slide_lift as cs
from stiction.simulator import Simulator


@pytest.fixture(scope="module")
def result():
    return cs.run(quick=True)


def test_every_check_passes(result):
    failed = [(c.quantity, c.measured, c.expected) for c in result.checks if not c.passed]
    assert not failed
    assert result.name == "slide-lift"
    assert {"exact", "ccp", "nakaoka", "pyramid", "penalty"} <= {p["formulation"] for p in result.points}


def test_pinocchio_formulations_run_or_are_skipped_with_a_note(result):
    by = {p["formulation"]: p for p in result.points}
    if "pinocchio-admm-ccp" in by:  # Pinocchio's CCP setting lifts like ours
        assert by["pinocchio-admm-ccp"]["lift_ratio_median"] == pytest.approx(1.0, rel=0.01)
        assert by["pinocchio-admm-ccp"]["max_normal_velocity"] > 0.1
    if "pinocchio-admm" in by:  # its NCP setting does not
        assert abs(by["pinocchio-admm"]["lift_ratio_median"]) <= 0.01
        assert by["pinocchio-admm"]["airborne_fraction"] == 0.0
    for name in ("pinocchio-admm", "pinocchio-admm-ccp"):
        if name in by:
            continue
        assert any(n.startswith(f"{name}: skipped") for n in result.notes), result.notes
        with pytest.raises(Exception, match="not built yet|unknown formulation"):
            Simulator("cube-slide", formulation=name)


def test_exact_keeps_the_contacts_on_the_ground(result):
    ex = next(p for p in result.points if p["formulation"] == "exact")
    assert ex["max_normal_velocity"] <= 1e-9
    assert ex["airborne_fraction"] == 0.0
    assert abs(ex["lift_ratio_median"]) <= 1e-6
    assert ex["max_exact_law_residual"] <= 1e-10
    # d = v0^2 / (2 mu g) of the scene's description, to the step's O(h v0) error
    assert ex["distance"] == pytest.approx(1.0 / (2 * 0.5 * 9.81), abs=1e-3)


def test_ccp_first_step_lifts_at_mu_times_the_sliding_speed():
    """Independently of result.u: after the first step from a zero gap (Psi = 0, so u_n = J v_n),
    every loaded sliding corner moves up at mu times its tangential speed (eq. 79 on the
    cone's boundary), and the exact-law measures of that impulse report the same lift-off."""
    sim = Simulator("cube-slide", formulation="ccp")
    traj = sim.rollout(sim.dt)
    loaded = traj.lam[1, :, 2] > 0
    assert loaded.sum() == 4
    cv = traj.contact_velocity[1, loaded]
    vt = np.linalg.norm(cv[:, :2], axis=1)
    assert np.all(vt > 0.5)
    np.testing.assert_allclose(cv[:, 2], 0.5 * vt, rtol=1e-8)
    # the friction on the cone's boundary, opposite to the sliding
    lam = traj.lam[1, loaded]
    np.testing.assert_allclose(np.linalg.norm(lam[:, :2], axis=1), 0.5 * lam[:, 2], rtol=1e-8)
    # the same number from the step's SolverResult, by this test's own parsing
    res = sim.data.result
    u = np.asarray(res.u).reshape(-1, 3)
    sl = np.linalg.norm(u[:, :2], axis=1) > 1e-4
    np.testing.assert_allclose(u[sl, 2] / (0.5 * np.linalg.norm(u[sl, :2], axis=1)), 1.0, rtol=1e-8)


def test_ccp_and_nakaoka_numbers(result):
    by = {p["formulation"]: p for p in result.points}
    ccp, nak, pyr = by["ccp"], by["nakaoka"], by["pyramid"]
    assert ccp["lift_ratio_median"] == pytest.approx(1.0, rel=0.01)
    assert 0.99 <= ccp["lift_ratio_min"] <= ccp["lift_ratio_max"] <= 1.01
    assert ccp["airborne_fraction"] > 0.5 and ccp["max_normal_velocity"] > 0.1
    # CCP's normal impulse over the slide is still m g T (vertical momentum), so it stops at v0 / (mu g)
    assert ccp["stop_time"] == pytest.approx(1.0 / (0.5 * 9.81), abs=2e-3)
    assert nak["max_exact_law_residual"] >= 1e-3
    assert nak["max_normal_velocity"] > 1e-3
    # the 4-facet pyramid keeps the De Saxce term of its polygon: no lift
    assert pyr["max_normal_velocity"] <= 1e-9 and abs(pyr["lift_ratio_median"]) <= 1e-6


def test_cli_json(capsys):
    assert cli.main(["casestudy", "slide-lift", "--quick", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["name"] == "slide-lift" and out["passed"] is True
    keys = {"formulation", "max_normal_velocity", "airborne_fraction", "lift_ratio_median",
            "max_exact_law_residual", "own_converged_fraction", "us_per_step"}
    assert all(keys <= set(p) for p in out["points"])
    rows = {p["formulation"]: p for p in out["points"]}
    assert len(rows) == len(out["points"])
    assert rows["ccp"]["lift_ratio_median"] == pytest.approx(1.0, rel=0.01)
    assert all(0.0 <= p["own_converged_fraction"] <= 1.0 and p["us_per_step"] > 0 for p in rows.values())
    assert set(rows) <= set(stiction.formulation_names())


def test_plot(result, tmp_path):
    pytest.importorskip("matplotlib")
    path = tmp_path / "lift.png"
    cs.plot(result, path)
    assert path.stat().st_size > 10000
