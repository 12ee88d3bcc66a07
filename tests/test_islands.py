"""Islands (islands.hpp): the simulator's exact-law problem split into the connected components of
A's block graph (bodies resting apart share no row of A), each solved alone, their answer judged as
one. The assembled impulses must solve the whole problem: checked here by an independent natural
map in numpy (De Saxce's, eq. 73-77) on the whole A and b, and by the bodies' momentum balance.
Impulses are not unique in a heap, so the whole-problem path is compared by its physics, not bit
for bit."""
import os

import numpy as np
import pytest

from stiction.simulator import Simulator

TOL = 1e-10


def _project_cone(x, mu):
    """Projection onto {||t|| <= mu n} of x = (t1, t2, n)."""
    t, n = x[:2], x[2]
    nt = np.linalg.norm(t)
    if nt <= mu * n:
        return x
    if mu * nt <= -n:
        return np.zeros(3)
    s = (mu * nt + n) / (1.0 + mu * mu)
    return np.array([*(mu * s * t / nt), s])


def _natural_map(A, b, lam, mu):
    """De Saxce's natural map of the whole problem, block by block (3 rows: t1, t2, n)."""
    u = A @ lam - b
    r = np.empty_like(lam)
    for o in range(0, len(lam), 3):
        ub = u[o:o + 3]
        shifted = ub + np.array([0.0, 0.0, mu * np.linalg.norm(ub[:2])])
        r[o:o + 3] = lam[o:o + 3] - _project_cone(lam[o:o + 3] - shifted, mu)
    return np.linalg.norm(r)


@pytest.fixture(scope="module")
def settled_pile():
    sim = Simulator("pile-24")
    sim.rollout(1.2)  # fallen: a heap of several bodies, pairs, and bodies resting alone
    return sim


def _components(sim):
    """Connected components of the bodies through their active body-body contacts (numpy)."""
    names = sim.contact_names
    parent = list(range(24))

    def root(i):
        while parent[i] != i:
            i = parent[i]
        return i

    for s in sim.data.active:
        if "|" in names[s]:
            a, b = names[s].split("#")[0].split("|")
            parent[root(int(a[4:]))] = root(int(b[4:]))
    return len({root(i) for i in range(24)})


def test_a_settled_pile_is_solved_island_by_island_and_the_answer_solves_the_whole_problem(settled_pile):
    sim = settled_pile
    mu = 0.5
    for _ in range(5):
        sim.step()
        r = sim.data.result
        assert r.converged and "islands)" in r.message, r.message
        islands = int(r.message.split("(")[1].split()[0])
        assert 2 <= islands <= _components(sim)  # heaps alone, the small ones (a box alone, a pair) together
        A, b, lam = np.asarray(sim.data.A), sim.dt * np.asarray(sim.data.b), np.asarray(r.lam)
        assert A.shape == (len(lam), len(lam)) and len(lam) % 3 == 0  # (contacts only)
        natural = _natural_map(A, b, lam, mu)
        assert natural <= 1.01 * TOL * np.linalg.norm(b)  # the default tolerance, on the whole problem
        assert r.relative_residual == pytest.approx(natural / np.linalg.norm(b), rel=1e-3, abs=1e-13)
        assert r.relative_residual <= TOL
        np.testing.assert_allclose(np.asarray(r.u), A @ lam - b, atol=1e-12 * np.linalg.norm(b))


def test_islands_and_the_whole_problem_give_the_same_motion_to_the_tolerance(settled_pile):
    """From one state, both paths: each answer meets the whole problem's tolerance, and the bodies'
    velocities after the step agree (the impulses of a heap need not)."""
    sim = settled_pile
    q, v, t = sim.data.q, sim.data.v, sim.data.t
    out = {}
    for flag in ("1", "0"):
        os.environ["STICTION_ISLANDS"] = flag
        try:
            sim.set_state(q, v, t)
            sim.step()
        finally:
            os.environ.pop("STICTION_ISLANDS")
        r = sim.data.result
        assert r.converged and r.relative_residual <= TOL
        assert ("islands)" in r.message) == (flag == "1")
        out[flag] = np.asarray(sim.data.v).copy()
    # velocities after the step: the same to within what the tolerance allows
    scale = np.abs(v).max() + 9.81 * sim.dt
    np.testing.assert_allclose(out["1"], out["0"], atol=1e-6 * scale)
