"""The De Saxce natural map of a spatial contact problem in 80-digit arithmetic (mpmath): the
independent check of a solver's verdict that tests/test_honest_solver.py and tests/test_scale.py
share."""
import mpmath


def natural_map_80_digits(A, b, mus, lam):
    """||lam - P_C(lam - (u + E s(u)))||, u = A lam - b, spatial blocks (t1, t2, n), evaluated
    in 80-digit arithmetic at the given double-precision lam, as an mpf (no exponent limit: scales
    of 1e+-300 are exact inputs; float() it where it is within double range)."""
    mp = mpmath.mp
    with mpmath.workdps(80):
        m = len(b)
        Am = [[mp.mpf(float(A[i, j])) for j in range(m)] for i in range(m)]
        lm = [mp.mpf(float(x)) for x in lam]
        u = [mpmath.fsum(Am[i][j] * lm[j] for j in range(m)) - mp.mpf(float(b[i])) for i in range(m)]
        sq = mp.mpf(0)
        for k, mu in enumerate(mus):
            mu, o = mp.mpf(float(mu)), 3 * k
            ut = mpmath.sqrt(u[o] ** 2 + u[o + 1] ** 2)
            z = [lm[o] - u[o], lm[o + 1] - u[o + 1], lm[o + 2] - u[o + 2] - mu * ut]
            zt, zn = mpmath.sqrt(z[0] ** 2 + z[1] ** 2), z[2]
            if zn >= 0 and zt <= mu * zn:
                p = z
            elif mu * zt <= -zn:
                p = [mp.mpf(0)] * 3
            else:
                a = (zn + mu * zt) / (1 + mu * mu)
                s = mu * a / zt if zt > 0 else mp.mpf(0)
                p = [z[0] * s, z[1] * s, a]
            sq += sum((lm[o + i] - p[i]) ** 2 for i in range(3))
        return mpmath.sqrt(sq)


def relative_natural_map_80_digits(A, b, mus, lam):
    """natural_map_80_digits / ||b||, both in 80 digits (an mpf: it may be beyond double's range)."""
    with mpmath.workdps(80):
        bn = mpmath.sqrt(mpmath.fsum(mpmath.mpf(float(x)) ** 2 for x in b))
        return natural_map_80_digits(A, b, mus, lam) / bn
