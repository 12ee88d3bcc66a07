"""The Delassus operators' AVX2 kernels against the portable loops (STICTION_VECTOR_KERNELS=0/1).

A symmetric sparse A (the simulator's) is multiplied column by column: by a gather of x, or, when
every column holds its entries in runs of three consecutive rows (spatial contacts), by plain
loads of three rows. Each product must equal the exact one (fractions) within the rounding bound
the verdict's first stage assumes, gamma_k |A||x| with k = the operator's productRoundingTerms()
+ 2: a kernel that dropped a lane, a tail or a run would miss it by far more. A dense A's column
kernel (its product with |A| alongside) is held to the same bound, also for an x with most entries
zero (whose columns the dense products skip). The block Cholesky's
triangular solves (the sticking step's) have their own kernel: a resting tower steps the same
with and without it.
"""
import numpy as np
import pytest
from conftest import run_with_kernels

PRODUCTS = r"""
from fractions import Fraction
import numpy as np
import scipy.sparse as sp
from stiction import _core

EPS = 2.0 ** -53
rng = np.random.default_rng(11)
worst, cases = 0.0, 0

def check(S, x, dense=False):
    global worst, cases
    operator = np.asfortranarray(S) if dense else sp.csc_matrix(S)
    y, y_abs, both, both_abs, chain = _core._operator_products(operator, x, True)
    gamma = (chain + 2) * EPS / (1 - (chain + 2) * EPS)
    bound = np.abs(S) @ np.abs(x)
    for i in range(S.shape[0]):
        exact = sum((Fraction(S[i, j]) * Fraction(x[j]) for j in np.nonzero(S[i])[0]), Fraction(0))
        exact_abs = sum((abs(Fraction(S[i, j]) * Fraction(x[j])) for j in np.nonzero(S[i])[0]), Fraction(0))
        allowed = gamma * bound[i] + 1e-300
        for value, reference in ((y[i], exact), (both[i], exact), (y_abs[i], exact_abs), (both_abs[i], exact_abs)):
            worst = max(worst, float(abs(Fraction(value) - reference)) / allowed)
    cases += 1

for blocks in (1, 2, 3, 5, 12, 40):
    # runs of three: a symmetric pattern of 3 x 3 blocks (each block's column a run of 3 rows)
    pattern = rng.random((blocks, blocks)) < 0.4
    pattern = pattern | pattern.T | np.eye(blocks, dtype=bool)
    S = np.kron(pattern, np.ones((3, 3))) * rng.standard_normal((3 * blocks, 3 * blocks))
    S = np.triu(S) + np.triu(S, 1).T
    S[np.kron(pattern, np.ones((3, 3))) == 0] = 0.0
    for scale in (1.0, 1e8):
        x = rng.standard_normal(3 * blocks) * scale
        check(S, x)
        check(S, x, dense=True)  # the dense operator's column kernel (rows not a multiple of 4)
        # most entries of x zero (few contacts closed): the dense products skip those columns
        z = np.where(rng.random(x.size) < 0.3, x, 0.0)
        check(S, z)
        check(S, z, dense=True)
    # the same with entries removed (symmetrically): runs broken, the gather kernel
    holes = rng.random(S.shape) < 0.3
    T = np.where(holes | holes.T, 0.0, S)
    check(T, rng.standard_normal(3 * blocks))
print(worst, cases)
"""

TOWER = r"""
import sys
import numpy as np
from stiction.scene import build_scene
from stiction.simulator import Simulator

sim = Simulator(build_scene({"name": "tower-48", "array": {"layout": "tower", "count": 48}, "ground": {"mu": 0.5}}))
sim.rollout(0.02)
held = 0
for _ in range(30):
    sim.step()
    r = sim.data.result
    assert r.converged, r.message
    held += any(s.outcome == "converged (held factor)" for s in r.stages)
np.save(sys.argv[1], np.concatenate([np.asarray(sim.data.q), [held]]))
"""


@pytest.mark.parametrize("kernels", ["0", "1"])
def test_sparse_products_are_within_the_verdicts_bound(kernels):
    worst, cases = run_with_kernels(PRODUCTS, kernels).split()
    assert int(cases) == 54
    assert float(worst) <= 1.0, f"a product is off by {worst} x the verdict's rounding bound"


def test_a_resting_tower_steps_the_same_with_and_without_the_kernels(tmp_path):
    finals = []
    for kernels in ("0", "1"):
        path = tmp_path / f"q{kernels}.npy"
        run_with_kernels(TOWER, kernels, path)
        finals.append(np.load(path))
    q0, q1 = finals[0][:-1], finals[1][:-1]
    held0, held1 = finals[0][-1], finals[1][-1]
    assert held0 >= 7 and held1 >= 7, (held0, held1)  # the held factor's solves ran, on both paths
    np.testing.assert_allclose(q1, q0, rtol=0, atol=1e-12)
