"""The verdict's compensated residual u = A x - b (src/cpp/include/stiction/compensated.hpp).

Rows built to cancel: b is the double nearest the exact A x, so A x - b is a few units of b's last
place while |A||x| is 1e3-1e16 times larger. The plain product's error is up to gamma_n |A||x|: it
loses every digit. The compensated one must stay within eps |u| + gamma_n^2 (|A||x| + |b|) of the
exact value (computed with fractions), on every operator path: dense, sparse gathered by columns
(a symmetric A: the simulator's), sparse scattered, each with and without the AVX2/FMA kernels.
"""
import pytest
from conftest import run_with_kernels

CHECK = r"""
import sys
from fractions import Fraction
import numpy as np
import scipy.sparse as sp
from stiction import _core

EPS = 2.0 ** -53
rng = np.random.default_rng(7)
worst = 0.0   # largest error / allowed bound over all rows
plain_bad = 0  # rows where the plain product A x - b misses that bound

def exact_residual(A, x, b):
    A = np.asarray(A)
    out = []
    for i in range(A.shape[0]):
        s = -Fraction(b[i])
        for j in np.nonzero(A[i])[0]:
            s += Fraction(A[i, j]) * Fraction(x[j])
        out.append(s)
    return out

def check(A_operator, A_dense, x, b, symmetric=False):
    global worst, plain_bad
    y = _core._compensated_residual(A_operator, x, b, symmetric)
    exact = exact_residual(A_dense, x, b)
    plain = A_dense @ x - b
    terms = np.count_nonzero(A_dense, axis=1) + 3
    gamma = terms * EPS / (1 - terms * EPS)
    absolute = np.abs(A_dense) @ np.abs(x) + np.abs(b)
    for i, e in enumerate(exact):
        allowed = EPS * abs(float(e)) + 2 * gamma[i] ** 2 * absolute[i] + 1e-300
        worst = max(worst, float(abs(Fraction(y[i]) - e)) / allowed)
        plain_bad += float(abs(Fraction(plain[i]) - e)) > allowed

def cancelling(A, x):
    # b: each row's exact A x rounded to double, so that A x - b is below b's last place
    return np.array([float(r) for r in exact_residual(A, x, np.zeros(A.shape[0]))])

for m in (1, 2, 3, 5, 8, 13, 31, 48):
    A = rng.standard_normal((m, m)) * 10.0 ** rng.integers(-8, 8, (m, m))
    x = rng.standard_normal(m) * 10.0 ** rng.integers(-8, 8, m)
    b = cancelling(A, x)
    check(np.asfortranarray(A), A, x, b)
    b_off = b * (1 + 3 * EPS)  # a residual of a few ulps of b
    check(np.asfortranarray(A), A, x, b_off)

for m in (4, 9, 30, 77):
    # rows of 0 to m entries (tails of 0-3 after the kernels' blocks of four)
    mask = rng.random((m, m)) < rng.random(m)[:, None]
    S = np.where(mask | mask.T, rng.standard_normal((m, m)), 0.0)
    S = S + S.T  # symmetric: the gathered path reads columns as rows
    D = 10.0 ** rng.integers(-4, 4, m)
    S = D[:, None] * S * D[None, :]  # rows of mixed scales,
    S = np.triu(S) + np.triu(S, 1).T  # exactly symmetric (the products rounded differently)
    x = rng.standard_normal(m) * 1e6
    b = cancelling(S, x)
    check(sp.csc_matrix(S), S, x, b, symmetric=True)
    N = np.where(mask, rng.standard_normal((m, m)) * 1e3, 0.0)  # not symmetric: scattered
    b = cancelling(N, x)
    check(sp.csc_matrix(N), N, x, b, symmetric=False)

print(worst, plain_bad)
"""


@pytest.mark.parametrize("kernels", ["0", "1"])
def test_compensated_residual_is_within_its_bound_where_the_plain_product_is_not(kernels):
    worst, plain_bad = run_with_kernels(CHECK, kernels).split()
    assert float(worst) <= 1.0, f"compensated residual off by {worst} x its bound"
    assert int(plain_bad) >= 100, f"the cancelling rows do not cancel: plain product in bound on all but {plain_bad}"


def test_compensated_residual_checks_its_input():
    import numpy as np
    from stiction import _core

    with pytest.raises(ValueError, match="x"):
        _core._compensated_residual(np.eye(3), np.zeros(2), np.zeros(3))
