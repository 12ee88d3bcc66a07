"""The case-study tests state each check's tolerance themselves (tests/test_casestudy_*.py):
a module that loosens its own tolerance, changes what a check expects, or drops a check fails
here, where `check.passed` (judged with the module's own numbers) would not notice."""
import math
import re


def _error(kind, measured, expected):
    if kind == "==":
        return abs(measured - expected)
    if kind == "<=":
        return max(0.0, measured - expected)
    return max(0.0, expected - measured)


def assert_checks_as_stated(result, stated):
    """`stated`: rows (pattern, expected, tolerance, kind). `pattern` is a regular expression
    searched in each check's quantity and must match exactly one row; `expected` is the number
    the check compares with (None: a reference the module computes, compared with an independent
    computation by another test of the file; a callable: computed from the check); `tolerance` a
    number or a callable of the check. Each check's tolerance may be tighter than stated, never
    looser (for a bound "<=" / ">=", whose expected is the bound, likewise); the test re-judges
    measured against the stated expected value with the stated tolerance. Every row
    must match at least one check."""
    used = {row[0]: 0 for row in stated}
    for c in result.checks:
        rows = [row for row in stated if re.search(row[0], c.quantity)]
        assert len(rows) == 1, f"check {c.quantity!r} matches {len(rows)} stated rows {[r[0] for r in rows]}"
        pattern, expected, tolerance, kind = rows[0]
        used[pattern] += 1
        assert c.kind == kind, f"{c.quantity!r}: kind {c.kind!r}, stated {kind!r}"
        want = c.expected
        if expected is not None:
            want = expected(c) if callable(expected) else expected
            close = math.isclose(c.expected, want, rel_tol=1e-12, abs_tol=1e-15)
            # a bound may be tighter than stated, never looser; an equality's value is the stated one
            ok = close or (kind == "<=" and c.expected < want) or (kind == ">=" and c.expected > want)
            assert ok, f"{c.quantity!r}: expects {c.expected!r}, stated {want!r} ({kind})"
        tol = tolerance(c) if callable(tolerance) else tolerance
        assert c.tolerance <= tol * (1 + 1e-12), f"{c.quantity!r}: tolerance {c.tolerance!r}, stated {tol!r}"
        error = _error(kind, c.measured, want)
        assert math.isfinite(c.measured) and error <= tol, \
            f"{c.quantity!r}: measured {c.measured!r}, expected {c.expected!r}, error {error!r} > stated {tol!r}"
    unused = [p for p, n in used.items() if n == 0]
    assert not unused, f"stated checks the module no longer makes: {unused}"
