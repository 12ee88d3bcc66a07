"""Simulator.step_derivatives (issue 26): the analytic Jacobians of one time step (implicit function
theorem at the converged impulse, mode by mode) against central finite differences of the step itself
(the simulator run twice per direction at tolerance 1e-14) and against closed forms of a sliding and a
sticking block."""
import numpy as np
import pinocchio as pin
import pytest

from stiction.derivatives import StepDerivatives
from stiction.simulator import Simulator

TOLERANCE = 1e-6  # relative agreement with the finite differences (issue 26)


def _settled(name, steps, **overrides):
    sim = Simulator(name, tolerance=1e-14, **overrides)
    sim.controller = None  # the control in sim.data is the step's own
    for _ in range(steps):
        sim.step()
    return sim


def _step(sim, q, v, tau):
    sim.set_state(q=q, v=v)
    sim.data.tau_ff = tau
    sim.step()
    return sim.data.q.copy(), sim.data.v.copy()


def _central_differences(sim, wrt, eps):
    """(dq+, dv+) / d(wrt) by central differences of sim.step, q+ read as q+ (-) q+_0 (Pinocchio)."""
    model = sim.scene.model
    q0, v0, tau0 = sim.data.q.copy(), sim.data.v.copy(), np.array(sim.data.tau_ff)
    q_next, _ = _step(sim, q0, v0, tau0)
    Dq, Dv = np.zeros((model.nv, model.nv)), np.zeros((model.nv, model.nv))
    for k in range(model.nv):
        e = np.zeros(model.nv)
        e[k] = eps
        out = []
        for sign in (1.0, -1.0):
            q = pin.integrate(model, q0, sign * e) if wrt == "q" else q0
            v = v0 + sign * e if wrt == "v" else v0
            tau = tau0 + sign * e if wrt == "tau" else tau0
            out.append(_step(sim, q, v, tau))
        Dq[:, k] = (pin.difference(model, q_next, out[0][0]) - pin.difference(model, q_next, out[1][0])) / (2 * eps)
        Dv[:, k] = (out[0][1] - out[1][1]) / (2 * eps)
    sim.set_state(q=q0, v=v0)
    sim.data.tau_ff = tau0
    return Dq, Dv


def _relative_error(analytic, reference, floor=0.0):
    """max |analytic - reference| over the matrix's scale, and the distribution of the columns' errors."""
    scale = max(np.abs(reference).max(), floor)
    columns = np.abs(analytic - reference).max(axis=0) / scale
    return columns.max(), np.percentile(columns, [50, 90, 100])


# (scene, steps to settle, derivatives with respect to q, finite-difference steps for q / v / tau)
CASES = [
    ("cube-slide", 20, True, (1e-8, 1e-6, 1e-6)),          # four corners sliding
    ("cube-incline-stick", 20, True, (1e-8, 1e-6, 1e-6)),  # four corners sticking on a 30 degree slope
    ("solo12-stand", 20, True, (1e-8, 1e-6, 1e-6)),        # four feet sticking, implicit PD
    ("solo12-slope-slip", 20, True, (1e-8, 1e-6, 1e-6)),   # four feet sliding down the slope
    ("pinch", 20, False, (None, 1e-6, 1e-4)),              # pads on the box's faces (moving half-spaces)
    ("two-cube-stack", 20, True, (1e-8, 1e-6, 1e-6)),      # corners on the lower cube's top face
]


@pytest.mark.parametrize("name,steps,wrt_q,eps", CASES, ids=[c[0] for c in CASES])
def test_against_central_differences(name, steps, wrt_q, eps):
    sim = _settled(name, steps)
    h = sim.dt
    d = sim.step_derivatives(wrt_q=wrt_q)
    assert isinstance(d, StepDerivatives)
    # (cube-incline-stick: the solver's answer for the four corners is one of many, one corner's friction on
    # the cone's edge, flagged; the sticking derivative holds, the body sticks either way)
    assert sum(d.boundary) <= (1 if name == "cube-incline-stick" else 0), f"{name}: {d.modes} {d.boundary}"
    # the natural scales: the identity for dv/dv and dq/dq, h M^-1 for dv/dtau (M with the implicit PD)
    tau_scale = h * np.abs(np.linalg.inv(sim.data.M)).max()
    for wrt, step in zip(("q", "v", "tau"), eps):
        if wrt == "q" and not wrt_q:
            continue
        Dq, Dv = _central_differences(sim, wrt, step)
        floor = tau_scale if wrt == "tau" else 1.0
        for label, analytic, reference, f in (("dq_d" + wrt, getattr(d, "dq_d" + wrt), Dq, h * floor),
                                              ("dv_d" + wrt, getattr(d, "dv_d" + wrt), Dv, floor)):
            error, spread = _relative_error(analytic, reference, f)
            assert error <= TOLERANCE, (f"{name} {label}: relative error {error:.2e} > {TOLERANCE} "
                                        f"(columns: median {spread[0]:.1e}, 90% {spread[1]:.1e}, max {spread[2]:.1e})")
    if not wrt_q:
        assert np.isnan(d.dq_dq).all() and np.isnan(d.dv_dq).all()


@pytest.mark.parametrize("name", ["cube-slide", "solo12-slope-slip"])
def test_friction_coefficient_against_central_differences(name):
    """A scene-wide mu (Simulator(..., mu=...)) moves every contact's: its derivative is the sum of the columns."""
    sim = _settled(name, 20)
    mu = sim.scene.contacts[0].mu
    q0, v0, tau0 = sim.data.q.copy(), sim.data.v.copy(), np.array(sim.data.tau_ff)
    d = sim.step_derivatives()
    eps = 1e-6
    out = []
    for sign in (1.0, -1.0):
        other = Simulator(name, tolerance=1e-14, mu=mu + sign * eps)
        other.controller = None
        out.append(_step(other, q0, v0, tau0))
    model = sim.scene.model
    q_ref, _ = _step(sim, q0, v0, tau0)
    dv = (out[0][1] - out[1][1]) / (2 * eps)
    dq = (pin.difference(model, q_ref, out[0][0]) - pin.difference(model, q_ref, out[1][0])) / (2 * eps)
    for label, analytic, reference in (("dv_dmu", d.dv_dmu.sum(axis=1), dv), ("dq_dmu", d.dq_dmu.sum(axis=1), dq)):
        error = np.abs(analytic - reference).max() / np.abs(reference).max()
        assert error <= TOLERANCE, f"{name} {label}: relative error {error:.2e} (analytic {analytic}, fd {reference})"


def test_sliding_block_closed_forms():
    """A block sliding at speed s along x on flat ground: v+ = v (1 - mu g h / s) (Coulomb friction mu m g h
    opposite to the slip), so dv+_x/dmu = -g h, dv+_x/dv_x = 1, dv+_y/dv_y = 1 - mu g h / s, and
    q+ = q + h v+ (its configuration follows v+)."""
    sim = _settled("cube-slide", 20)
    g, h = 9.81, sim.dt
    mu = sim.scene.contacts[0].mu
    s = np.linalg.norm(sim.data.v[:2])
    assert s > 0.5 and abs(sim.data.v[1]) < 1e-12
    d = sim.step_derivatives()
    assert set(m for m in d.modes if m != "none") == {"slide"}
    g_model = -sim.scene.model.gravity.linear[2]
    assert g_model == pytest.approx(g, rel=1e-3)
    assert d.dv_dmu.sum(axis=1)[0] == pytest.approx(-g_model * h, rel=1e-6)
    assert d.dv_dv[0, 0] == pytest.approx(1.0, abs=1e-9)
    assert d.dv_dv[1, 1] == pytest.approx(1.0 - mu * g_model * h / s, rel=1e-6)
    np.testing.assert_allclose(d.dq_dv[:3, :3], h * d.dv_dv[:3, :3], atol=1e-12)


def test_sticking_block_does_not_feel_small_forces():
    """A cube sticking on a 30 degree slope (mu 0.6 > tan 30): v+ = 0 whatever a small force, dv+/dtau = 0."""
    sim = _settled("cube-incline-stick", 20)
    d = sim.step_derivatives()
    assert set(m for m in d.modes if m != "none") == {"stick"}
    free = sim.dt * np.abs(np.linalg.inv(sim.data.M)).max()  # what the free cube would gain
    assert np.abs(d.dv_dtau).max() <= 1e-9 * free
    assert np.abs(d.dv_dv).max() <= 1e-9


def test_does_not_change_the_simulator():
    sim = _settled("solo12-stand", 5)
    before = (sim.data.q.copy(), sim.data.v.copy(), sim.data.t, sim.data.b.copy(), sim.data.candidate_lambda.copy())
    d = sim.step_derivatives()
    after = (sim.data.q, sim.data.v, sim.data.t, sim.data.b, sim.data.candidate_lambda)
    for x, y in zip(before, after):
        assert np.array_equal(x, y)
    assert d.dv_dv.shape == (18, 18) and d.dv_dmu.shape == (18, 4) and len(d.modes) == 4
    assert d.contact_names == tuple(sim.contact_names)
    with pytest.raises(ValueError):
        d.dv_dv[0, 0] = 1.0  # read-only


def test_cube_sliding_on_a_cube():
    """The top cube of the stack sliding at 0.3 m/s over the lower one, which sticks: contacts on a moving
    half-space (its top face), sliding, with respect to q and v."""
    sim = _settled("two-cube-stack", 20)
    v = np.zeros(12)
    v[6] = 0.3
    sim.set_state(v=v)
    sim.step()
    d = sim.step_derivatives()
    assert d.modes == ("stick",) * 4 + ("slide",) * 4
    for wrt, eps in (("q", 1e-8), ("v", 1e-6)):
        Dq, Dv = _central_differences(sim, wrt, eps)
        for label, analytic, reference, floor in (("dq_d" + wrt, getattr(d, "dq_d" + wrt), Dq, sim.dt),
                                                  ("dv_d" + wrt, getattr(d, "dv_d" + wrt), Dv, 1.0)):
            error, spread = _relative_error(analytic, reference, floor)
            assert error <= TOLERANCE, f"{label}: {error:.2e} (columns: median {spread[0]:.1e}, max {spread[2]:.1e})"


def test_pinch_turned_is_flagged():
    """The pinch's four sticking pads on the box's faces: turning the box about the fingers' axis asks the
    pads to slip (no sticking answer exists), so the step changes mode under that perturbation, either way
    (the perturbed steps' own states, read from the simulator, show slip): every pad is flagged."""
    sim = _settled("pinch", 20)
    model = sim.scene.model
    q0, v0 = sim.data.q.copy(), sim.data.v.copy()
    d = sim.step_derivatives()
    assert d.modes[4:] == ("stick",) * 4 and all(d.boundary[4:])
    for sign in (1.0, -1.0):
        e = np.zeros(model.nv)
        e[6] = sign * 1e-8  # the box turned about y
        sim.set_state(q=pin.integrate(model, q0, e), v=v0)
        sim.step()
        assert "slip" in [str(x).split(".")[-1] for x in sim.data.states[4:]]
    sim.set_state(q=q0, v=v0)


def test_refusals():
    with pytest.raises(ValueError, match="time stepping"):
        Simulator("cube-slide", mode="rk4").step_derivatives()
    with pytest.raises(ValueError, match="exact formulation"):
        Simulator("cube-slide", formulation="ccp").step_derivatives()
    ball = _settled("ball-on-table", 250)  # resting on the table: a coal pair's contact
    with pytest.raises(NotImplementedError, match="coal pair"):
        ball.step_derivatives()
    assert ball.step_derivatives(wrt_q=False).modes == ("none", "stick")
    sim = _settled("solo12-stand-joint-rows", 2)
    with pytest.raises(NotImplementedError, match="joint rows"):
        sim.step_derivatives(wrt_q=False)
