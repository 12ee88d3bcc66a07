"""The FCLib / Siconos readers validate everything they read: malformed files raise
FclibFormatError (a ValueError) naming the file and the field, never crash, hang or allocate
from a size a header merely claims; global problems store M's upper triangle only (LMGC90)."""
import json
import shutil
import subprocess
import sys
import textwrap
from concurrent.futures import ThreadPoolExecutor

import h5py
import numpy as np
import pytest

import stiction
from stiction import fclib
from stiction.fclib import FclibFormatError
from stiction.problems import two_cube_stack

from conftest import FCLIB_DIR

CLI = [sys.executable, "-c", "import sys; from stiction.cli import main; sys.exit(main())"]
LOCAL = "BoxesStack--local_problem_test.hdf5"  # CSR W, a guesses group, 82 kB
GLOBAL_FULL = "CubesH8--LMGC_GFC3D-i00001-1-00000.hdf5"  # M stored whole (triplets), 32 kB
GLOBAL_DIAG = "BoxStacks--Box_Stacks-i0122-82-5.hdf5"  # diagonal M, a guesses group
UPPER = ["CubesH8--CubeH8.hdf5", "CubesH8--LMGC_GlobalFrictionContactProblem00046.hdf5"]
DAT_DENSE = "Rover--Rover4396.dat"
DAT_SBM = "Confeti--Confeti-ex13-4contact-Fc3D-SBM.dat"


def cli(*args, timeout=120):
    return subprocess.run([*CLI, "fclib", *map(str, args)], capture_output=True, text=True, timeout=timeout)


def copy(tmp_path, name, new=None):
    dst = tmp_path / (new or name)
    shutil.copyfile(FCLIB_DIR / name, dst)
    return dst


def replace(f, key, data):
    del f[key]
    f.create_dataset(key, data=data)


def edit(key, fn):
    """A mutation setting dataset `key` to fn(its current value)."""
    def apply(f):
        replace(f, key, fn(f[key][()]))
    return apply


def setitem(key, index, value):
    def fn(a):
        a = a.copy()
        a[index] = value
        return a
    return edit(key, fn)


def delete(key):
    def apply(f):
        del f[key]
    return apply


def then(*mutations):
    def apply(f):
        for m in mutations:
            m(f)
    return apply


def to_triplets(f):
    """Rewrite the local W (CSR) as FCLib triplets (CSparse: i = row, p = column)."""
    g = f["fclib_local/W"]
    p, i = g["p"][:], g["i"][:]
    rows = np.repeat(np.arange(len(p) - 1), np.diff(p)).astype(np.int32)
    replace(g, "p", i.astype(np.int32))
    replace(g, "i", rows)
    replace(g, "nz", np.array([len(rows)], dtype=np.int32))


# --- the segfault of the issue ------------------------------------------------------------------

def test_out_of_range_sparse_index_is_refused_not_a_segfault(tmp_path):
    """W/i out of range made scipy write out of bounds: `stiction fclib` died with signal 11."""
    bad = copy(tmp_path, "Capsules--Capsules-i97-269.hdf5", "bad_index.hdf5")
    with h5py.File(bad, "r+") as f:
        f["fclib_local/W/i"][5] = 10**8
    with pytest.raises(FclibFormatError, match=r"bad_index\.hdf5: fclib_local/W/i: column index 100000000"):
        fclib.load(bad)
    out = cli(bad)
    assert out.returncode == 2, out
    assert out.stderr.startswith("stiction fclib: ") and "fclib_local/W/i" in out.stderr
    assert "Traceback" not in out.stderr


# --- HDF5 local ---------------------------------------------------------------------------------

W_ = "fclib_local/W/"
V_ = "fclib_local/vectors/"

LOCAL_CASES = {
    "i negative": (setitem(W_ + "i", 0, -1), W_ + "i", "outside"),
    "i too large": (setitem(W_ + "i", -1, 144), W_ + "i", "outside"),
    "p[0] not 0": (setitem(W_ + "p", 0, 1), W_ + "p", "must be 0"),
    "p decreasing": (setitem(W_ + "p", 3, 0), W_ + "p", "decreases"),
    "p[-1] beyond i": (setitem(W_ + "p", -1, 10**6), W_ + "p", "but i has 4896 entries"),
    "p too short": (edit(W_ + "p", lambda a: a[:-2]), W_ + "p", "expected 145"),
    "nz unknown": (setitem(W_ + "nz", 0, -3), W_ + "nz", "outside"),
    "nzmax too small": (setitem(W_ + "nzmax", 0, 10), W_ + "p", "nzmax"),
    "m mismatch": (setitem(W_ + "m", 0, 147), W_ + "m", "declared 147x144"),
    "m 1e12": (edit(W_ + "m", lambda a: np.array([10**12])), W_ + "m", "outside"),
    "m int32 max": (setitem(W_ + "m", 0, 2**31 - 1), W_ + "m", "declared"),
    "n negative": (setitem(W_ + "n", 0, -5), W_ + "n", "outside"),
    "x NaN": (setitem(W_ + "x", 7, np.nan), W_ + "x", "non-finite"),
    "x inf": (setitem(W_ + "x", 0, np.inf), W_ + "x", "non-finite"),
    "x too short": (edit(W_ + "x", lambda a: a[:100]), W_ + "x", "needs"),
    "i as strings": (edit(W_ + "i", lambda a: np.array([b"abc"] * len(a))), W_ + "i", "not numeric"),
    "i as floats": (edit(W_ + "i", lambda a: a + 0.5), W_ + "i", "non-integer"),
    "x as a matrix": (edit(W_ + "x", lambda a: np.ones((2, 3))), W_ + "x", "not a vector"),
    "no W/i": (delete(W_ + "i"), W_ + "i", "missing dataset"),
    "no W/nz": (delete(W_ + "nz"), W_ + "nz", "missing"),
    "no W": (delete("fclib_local/W"), "fclib_local/W", "missing group"),
    "W/x a group": (lambda f: (delete(W_ + "x")(f), f.create_group(W_ + "x")), W_ + "x", "not a dataset"),
    "no vectors": (delete("fclib_local/vectors"), "fclib_local/vectors", "missing"),
    "no q": (delete(V_ + "q"), V_ + "q", "missing"),
    "q short": (edit(V_ + "q", lambda a: a[:-1]), V_ + "q", "143 entries"),
    "q NaN": (setitem(V_ + "q", 3, np.nan), V_ + "q", "non-finite"),
    "mu longer": (edit(V_ + "mu", lambda a: np.r_[a, 0.5]), V_ + "q", "3 x 49"),
    "mu empty": (edit(V_ + "mu", lambda a: a[:0]), V_ + "mu", "no contacts"),
    "mu negative": (setitem(V_ + "mu", 2, -0.1), V_ + "mu", "negative friction coefficient -0.1 at contact 2"),
    "mu NaN": (setitem(V_ + "mu", 0, np.nan), V_ + "mu", "non-finite"),
    "spacedim 2": (setitem("fclib_local/spacedim", 0, 2), "fclib_local/spacedim", "only 3-D"),
    "V present": (lambda f: f.create_group("fclib_local/V"), "fclib_local/V", "not supported"),
    "guess missing": (delete("guesses/1"), "guesses/1", "missing group"),
    "guess short": (edit("guesses/1/r", lambda a: a[:5]), "guesses/1/r", "5 entries"),
    "guess NaN": (setitem("guesses/1/r", 0, np.nan), "guesses/1/r", "non-finite"),
    "guess count": (setitem("guesses/number_of_guesses", 0, -1), "guesses/number_of_guesses", "outside"),
    "negative diagonal": (lambda f: f[W_ + "x"].__setitem__(0, -1.0), "fclib_local/W", "negative"),
    "triplet row out of range": (then(to_triplets, setitem(W_ + "i", 4, 144)), W_ + "i", "row index 144"),
    "triplet column negative": (then(to_triplets, setitem(W_ + "p", 4, -2)), W_ + "p", "column index -2"),
    "triplet nz beyond nzmax": (then(to_triplets, setitem(W_ + "nz", 0, 10**6)), W_ + "nz", "nzmax"),
    "triplet nz beyond data": (then(to_triplets, setitem(W_ + "nz", 0, 5000), setitem(W_ + "nzmax", 0, 5000)),
                               W_ + "p", "nz = 5000"),
}


@pytest.mark.parametrize("case", LOCAL_CASES)
def test_malformed_local_hdf5(tmp_path, case):
    mutate, field, match = LOCAL_CASES[case]
    path = copy(tmp_path, LOCAL, "local.hdf5")
    with h5py.File(path, "r+") as f:
        mutate(f)
    with pytest.raises(FclibFormatError) as err:
        fclib.load(path)
    assert str(err.value).startswith(f"{path}: {field}: "), str(err.value)
    assert err.value.path == str(path) and err.value.field == field
    assert any(m in str(err.value) for m in match.split("|")), str(err.value)


def test_triplet_and_csc_storage_read_the_same_w(tmp_path):
    ref = fclib.load(FCLIB_DIR / LOCAL)
    trip = copy(tmp_path, LOCAL, "triplets.hdf5")
    with h5py.File(trip, "r+") as f:
        to_triplets(f)
    np.testing.assert_array_equal(fclib.load(trip).A, ref.A)
    csc = copy(tmp_path, LOCAL, "csc.hdf5")  # the CSR arrays of W read as CSC: Wᵀ
    with h5py.File(csc, "r+") as f:
        f[W_ + "nz"][0] = -1
    np.testing.assert_array_equal(fclib.load(csc).A, ref.A.T)


def test_declared_huge_dataset_is_refused_before_reading(tmp_path, monkeypatch):
    """A dataset declaring 2^30 entries (chunked, never written: the file stays small) is refused
    from its header; reading it would allocate 8 GiB."""
    path = copy(tmp_path, LOCAL, "huge.hdf5")
    with h5py.File(path, "r+") as f:
        del f[W_ + "x"]
        f.create_dataset(W_ + "x", shape=(2**30,), dtype=np.float64, chunks=(4096,))
    assert path.stat().st_size < 10**6
    # what "before reading" means, counted rather than timed: no dataset of that size is read
    # (every h5py read goes through Dataset.__getitem__ or read_direct; a large one is refused
    # here rather than allocated, should the loader ever try)
    read = []
    real_getitem, real_read_direct = h5py.Dataset.__getitem__, h5py.Dataset.read_direct

    def seen(ds):
        read.append((ds.name, ds.size))
        if ds.size >= 10**6:
            raise MemoryError(f"test: {ds.name} ({ds.size} entries) read")

    def getitem(ds, key):
        seen(ds)
        return real_getitem(ds, key)

    def read_direct(ds, *args, **kwargs):
        seen(ds)
        return real_read_direct(ds, *args, **kwargs)

    monkeypatch.setattr(h5py.Dataset, "__getitem__", getitem)
    monkeypatch.setattr(h5py.Dataset, "read_direct", read_direct)
    with pytest.raises(FclibFormatError, match="fclib_local/W/x: has 1073741824 entries, more than"):
        fclib.load(path)
    assert read and all(size < 10**6 for _, size in read), read  # the small ones were read, not W/x
    assert "/" + W_ + "x" not in {name for name, _ in read}


def test_dense_size_bound(tmp_path):
    """Consistent sizes, but a W too big to hold densely: refused before allocating it."""
    path = copy(tmp_path, LOCAL, "big.hdf5")
    with h5py.File(path, "r+") as f:
        replace(f, V_ + "mu", np.full(5000, 0.5))
        replace(f, V_ + "q", np.zeros(15000))
    with pytest.raises(FclibFormatError,
                       match=r"fclib_local/vectors/mu: W \(5000 contacts\) would be a dense 15000x15000"):
        fclib.load(path)


def test_error_carries_path_and_field_and_pickles():
    import pickle

    e = pickle.loads(pickle.dumps(FclibFormatError("a.hdf5", "fclib_local/W/i", "bad")))
    assert isinstance(e, ValueError)
    assert (e.path, e.field, str(e)) == ("a.hdf5", "fclib_local/W/i", "a.hdf5: fclib_local/W/i: bad")


# --- HDF5 global --------------------------------------------------------------------------------

G_ = "fclib_global/"

GLOBAL_CASES = {
    "M/i out of range": (setitem(G_ + "M/i", 3, 48), G_ + "M/i", "row index 48"),
    "M/p negative": (setitem(G_ + "M/p", 3, -1), G_ + "M/p", "column index -1"),
    "H/p out of range": (setitem(G_ + "H/p", 0, 3), G_ + "H/p", "column index 3"),
    "H/i out of range": (setitem(G_ + "H/i", 0, 2**31 - 1), G_ + "H/i", "row index 2147483647"),
    "H/n mismatch": (setitem(G_ + "H/n", 0, 6), G_ + "H/n", "declared 48x6"),
    "M/m 1e9": (setitem(G_ + "M/m", 0, 10**9), G_ + "M/m", "declared 1000000000x48"),
    "f short": (edit(G_ + "vectors/f", lambda a: a[:-3]), G_ + "M/m", "f (45 entries)"),
    "w long": (edit(G_ + "vectors/w", lambda a: np.r_[a, 0.0]), G_ + "vectors/w", "4 entries"),
    "f NaN": (setitem(G_ + "vectors/f", 0, np.nan), G_ + "vectors/f", "non-finite"),
    "mu inf": (setitem(G_ + "vectors/mu", 0, np.inf), G_ + "vectors/mu", "non-finite"),
    "no H": (delete(G_ + "H"), G_ + "H", "missing group"),
    "no f": (delete(G_ + "vectors/f"), G_ + "vectors/f", "missing"),
    "M x NaN": (setitem(G_ + "M/x", 0, np.nan), G_ + "M/x", "non-finite"),
    "M singular": (edit(G_ + "M/x", np.zeros_like), G_ + "M", "singular"),
    "G present": (lambda f: f.create_group(G_ + "G"), G_ + "G", "not supported"),
    "spacedim 2": (setitem(G_ + "spacedim", 0, 2), G_ + "spacedim", "only 3-D"),
}


@pytest.mark.parametrize("case", GLOBAL_CASES)
def test_malformed_global_hdf5(tmp_path, case):
    mutate, field, match = GLOBAL_CASES[case]
    path = copy(tmp_path, GLOBAL_FULL, "global.hdf5")
    with h5py.File(path, "r+") as f:
        mutate(f)
    with pytest.raises(FclibFormatError) as err:
        fclib.load(path)
    assert str(err.value).startswith(f"{path}: {field}: "), str(err.value)
    assert match in str(err.value), str(err.value)


# --- not FCLib at all ---------------------------------------------------------------------------

def test_files_that_are_not_problems(tmp_path):
    empty = tmp_path / "empty.hdf5"
    empty.write_bytes(b"")
    text = tmp_path / "text.hdf5"
    text.write_text("3 1 0 3 3 3 3 1 0 0 0 1 0 0 0 1 -1 0 0 0.5\n")
    half = tmp_path / "half.hdf5"
    half.write_bytes((FCLIB_DIR / LOCAL).read_bytes()[:20000])
    junk = tmp_path / "junk.dat"
    junk.write_bytes(bytes(range(256)) * 4)
    nogroup = tmp_path / "nogroup.hdf5"
    with h5py.File(nogroup, "w") as f:
        f.create_group("something_else")
    cases = [(empty, "no HDF5 signature"), (text, "no HDF5 signature"), (half, "not a readable HDF5 file"),
             (junk, "not a Siconos .dat text file"), (nogroup, "no /fclib_local or /fclib_global group"),
             (tmp_path, "is a directory")]
    for path, match in cases:
        with pytest.raises(FclibFormatError, match=match) as err:
            fclib.load(path)
        assert str(err.value).startswith(f"{path}: ")
    with pytest.raises(FileNotFoundError):
        fclib.load(tmp_path / "missing.dat")


# --- Siconos .dat -------------------------------------------------------------------------------

def dat_tokens(name):
    return (FCLIB_DIR / name).read_text().split()


def with_token(name, index, value):
    t = dat_tokens(name)
    t[index] = value
    return " ".join(t)


# Confeti 4-contact SBM tokens: dim nc 3 4 | storage size0 size1 1 12 12 | nbblocks 16 | block rows/cols 4 4 |
# blocksize0 3 6 9 12 | blocksize1 3 6 9 12 | filled1 filled2 5 16 | index1_data 0 4 8 12 16 (18-22) |
# index2_data 0 1 2 3 (x4, 23-38) | block 0: its number "0" (39) + 9 values ...
SBM = DAT_SBM
DAT_CASES = {
    "truncated": (lambda: " ".join(dat_tokens(SBM)[:100]), "W/block", "truncated file"),
    "truncated in q": (lambda: " ".join(dat_tokens(DAT_DENSE)[:-6]), "q", "truncated file"),
    "empty": (lambda: "", "", "empty file"),
    "word": (lambda: with_token(DAT_DENSE, 30, "abc"), "W/values", "non-numeric token 'abc'"),
    "float size": (lambda: with_token(DAT_DENSE, 3, "6.0"), "W/size0", "non-integer token '6.0'"),
    "negative nc": (lambda: with_token(DAT_DENSE, 1, "-2"), "nc", "outside"),
    "nc 1e9": (lambda: with_token(DAT_DENSE, 1, "1000000000"), "nc", "truncated file"),
    "nc 1e12": (lambda: with_token(DAT_DENSE, 1, "1000000000000"), "nc", "outside"),
    "storage 2": (lambda: with_token(DAT_DENSE, 2, "2"), "W/storage", "not supported"),
    "dim 2": (lambda: with_token(DAT_DENSE, 0, "2"), "dim", "only 3-D"),
    "storage 7": (lambda: with_token(DAT_DENSE, 2, "7"), "W/storage", "outside"),
    "size0 mismatch": (lambda: with_token(DAT_DENSE, 3, "9"), "W/size0", "declared 9x6"),
    "dense sizes not repeated": (lambda: with_token(DAT_DENSE, 5, "5"), "W/dense sizes", "does not repeat"),
    "W NaN": (lambda: with_token(DAT_DENSE, 10, "nan"), "W/values", "non-finite"),
    "q inf": (lambda: with_token(DAT_DENSE, 7 + 36, "inf"), "q", "non-finite"),
    "mu negative": (lambda: with_token(DAT_DENSE, 7 + 36 + 6, "-0.7"), "mu", "negative friction"),
    "mu NaN": (lambda: with_token(DAT_DENSE, 7 + 36 + 7, "NaN"), "mu", "non-finite"),
    "block column out of range": (lambda: with_token(SBM, 23, "4"), "W/index2_data", "outside [0, 3]"),
    "block column negative": (lambda: with_token(SBM, 23, "-1"), "W/index2_data", "outside"),
    "row pointers decrease": (lambda: with_token(SBM, 19, "9"), "W/index1_data", "must increase"),
    "row pointers too long": (lambda: with_token(SBM, 16, "6"), "W/filled1", "outside [0, 5]"),
    "block count": (lambda: with_token(SBM, 17, "15"), "W/filled2", "nbblocks = 16"),
    "block sizes": (lambda: with_token(SBM, 10, "2"), "W/blocksize0", "increase strictly"),
    "block sizes beyond W": (lambda: with_token(SBM, 15, "13"), "W/blocksize1", "outside [1, 12]"),
    "block number": (lambda: with_token(SBM, 39, "5"), "W/block 0 number", "numbering mismatch"),
    "block duplicated": (lambda: with_token(SBM, 23, "1"), "W/index2_data", "stored twice"),
}


@pytest.mark.parametrize("case", DAT_CASES)
def test_malformed_dat(tmp_path, case):
    make, field, match = DAT_CASES[case]
    path = tmp_path / "p.dat"
    path.write_text(make())
    with pytest.raises(FclibFormatError) as err:
        fclib.load(path)
    assert str(err.value).startswith(f"{path}: {field}"), str(err.value)
    assert match in str(err.value), str(err.value)


def test_sbm_header_is_as_documented():
    t = dat_tokens(SBM)
    assert t[:23] == ["3", "4", "1", "12", "12", "16", "4", "4", "3", "6", "9", "12", "3", "6", "9", "12",
                      "5", "16", "0", "4", "8", "12", "16"]
    assert t[23:39] == ["0", "1", "2", "3"] * 4 and t[39] == "0"


def test_malformed_files_exit_2_with_the_message(tmp_path):
    bad = tmp_path / "nan_mu.dat"
    bad.write_text(with_token(DAT_DENSE, 7 + 36 + 7, "nan"))
    out = cli(bad)
    assert out.returncode == 2 and out.stderr.startswith(f"stiction fclib: {bad}: mu: non-finite")
    out = cli(tmp_path)  # a directory
    assert out.returncode == 2 and "Traceback" not in out.stderr


def test_write_local_rejects_what_load_would_refuse(tmp_path):
    problem = two_cube_stack(10.0, 0.4, (0.2, 0.0, 0.0)).problem
    with pytest.raises(ValueError, match="solution must be 24 finite values"):
        fclib.write_local(tmp_path / "x.hdf5", problem, solution=np.zeros(5))


# --- global problems: M stored as its upper triangle --------------------------------------------

def literal_condensation(path):
    """W = Hᵀ M⁻¹ H with M read exactly as stored (no completion), in FCLib order."""
    with h5py.File(path) as f:
        def mat(g):
            nz = int(g["nz"][0])
            A = np.zeros((int(g["m"][0]), int(g["n"][0])))
            np.add.at(A, (g["i"][:nz], g["p"][:nz]), g["x"][:nz])
            return A
        M, H = mat(f["fclib_global/M"]), mat(f["fclib_global/H"])
    return M, H.T @ np.linalg.solve(M, H)


@pytest.mark.parametrize("name", UPPER)
def test_upper_triangle_m_is_completed(name):
    M, W_literal = literal_condensation(FCLIB_DIR / name)
    assert np.all(np.tril(M, -1) == 0) and np.any(np.triu(M, 1) != 0)  # one triangle stored
    M_full = M + np.triu(M, 1).T
    assert np.linalg.eigvalsh(M_full).min() > 10.0  # 16.7: positive definite, as FCLib requires
    P = fclib.load(FCLIB_DIR / name)
    assert P.info["M_storage"] == "upper triangle completed"
    assert P.info["M_min_eigenvalue"] == pytest.approx(np.linalg.eigvalsh(M_full).min(), rel=1e-9)
    assert P.info["W_asymmetry"] < 1e-12 and P.info["W_symmetrised"]  # measured before symmetrising
    np.testing.assert_array_equal(P.A, P.A.T)
    assert np.linalg.eigvalsh(P.A).min() > 0
    r = stiction.solve(P.problem(), tol=1e-10)
    assert r.converged and r.relative_residual <= 1e-10
    # the literal reading is what the file does not mean: asymmetric W (16 % on the 9-contact one)
    asym = np.abs(W_literal - W_literal.T).max() / np.abs(W_literal).max()
    assert asym > (0.1 if P.contacts > 1 else 1e-13)


def test_lower_triangle_is_completed_too_and_gives_the_same_problem(tmp_path):
    path = copy(tmp_path, UPPER[1], "lower.hdf5")
    with h5py.File(path, "r+") as f:
        g = f["fclib_global/M"]
        i, p = g["i"][:], g["p"][:]
        g["i"][:], g["p"][:] = p, i  # the transpose: lower triangle only
    P, ref = fclib.load(path), fclib.load(FCLIB_DIR / UPPER[1])
    assert P.info["M_storage"] == "lower triangle completed"
    np.testing.assert_allclose(P.A, ref.A, rtol=1e-13, atol=0)


def test_full_m_is_used_as_stored_and_asymmetry_is_not_hidden(tmp_path):
    ref = fclib.load(FCLIB_DIR / GLOBAL_FULL)
    assert ref.info["M_storage"] == "full" and ref.info["W_symmetrised"]
    path = copy(tmp_path, GLOBAL_FULL, "asym.hdf5")
    with h5py.File(path, "r+") as f:  # perturb one off-diagonal entry of a fully stored M
        g = f["fclib_global/M"]
        i, p, x = g["i"][:], g["p"][:], g["x"][:]
        k = int(np.flatnonzero((i != p) & (np.abs(x) > 0.1 * np.abs(x[i != p]).max()))[0])
        x[k] *= 1.5
        g["x"][:] = x
    P = fclib.load(path)
    assert P.info["M_storage"] == "full" and P.info["M_asymmetry"] > 1e-3
    assert not P.info["W_symmetrised"] and P.info["W_asymmetry"] > 1e-6
    assert np.abs(P.A - P.A.T).max() > 0  # kept as computed, not symmetrised


def test_diagonal_m():
    P = fclib.load(FCLIB_DIR / GLOBAL_DIAG)
    assert P.info["M_storage"] == "diagonal" and P.info["M_min_eigenvalue"] > 0


# --- seeded fuzzing -----------------------------------------------------------------------------

WORKER = textwrap.dedent("""
    import json, sys
    import numpy as np
    from stiction import fclib
    for line in open(sys.argv[1]):
        path = line.strip()
        print(json.dumps({"start": path}), flush=True)
        try:
            P = fclib.load(path)
            n = 3 * P.contacts
            ok = (P.contacts > 0 and P.A.shape == (n, n) and P.b.shape == (n,) and P.mu.shape == (n // 3,)
                  and np.all(np.isfinite(P.A)) and np.all(np.isfinite(P.b)) and np.all(np.isfinite(P.mu))
                  and np.all(P.mu >= 0)
                  and (P.guess is None or (P.guess.shape == (n,) and np.all(np.isfinite(P.guess)))))
            P.problem()  # what the CLI builds next must not fail either
            res = {"path": path, "loaded": True, "consistent": bool(ok)}
        except fclib.FclibFormatError as exc:
            res = {"path": path, "loaded": False, "message": str(exc)}
        except BaseException as exc:
            res = {"path": path, "loaded": False, "unexpected": f"{type(exc).__name__}: {exc}"}
        print(json.dumps(res), flush=True)
""")


def h5_objects(path):
    names = []
    with h5py.File(path) as f:
        f.visititems(lambda name, obj: names.append((name, isinstance(obj, h5py.Dataset))))
    return names


def mutate_hdf5(rng, src, dst, objects):
    """One random structural change made with h5py (field-level), or a byte-level one."""
    op = rng.choice(["delete", "scalar", "index", "value", "resize", "retype", "bytes", "truncate"])
    raw = src.read_bytes()
    if op in ("bytes", "truncate"):
        b = bytearray(raw[: rng.integers(len(raw))] if op == "truncate" else raw)
        if op == "bytes":  # mostly in the first 4 kB: superblock, object headers, B-trees
            for _ in range(rng.integers(1, 10)):
                j = rng.integers(min(4096, len(b))) if rng.random() < 0.7 else rng.integers(len(b))
                b[j] ^= int(rng.integers(1, 256))
        dst.write_bytes(bytes(b))
        return op
    shutil.copyfile(src, dst)
    datasets = [n for n, is_ds in objects if is_ds]
    with h5py.File(dst, "r+") as f:
        if op == "delete":
            del f[objects[rng.integers(len(objects))][0]]
            return op
        scalars = [n for n in datasets if f[n].size == 1]
        vectors = [n for n in datasets if f[n].size > 1 and f[n].dtype.kind in "iuf"]
        if op == "scalar":
            key = scalars[rng.integers(len(scalars))]
            v = f[key][()]
            cur = int(np.ravel(v)[0]) if v.dtype.kind in "iu" else 1
            new = rng.choice([-3, -2, -1, 0, 1, 2, cur - 1, cur + 1, cur * 3, 2**31 - 1, 10**12, -(10**12)])
            replace(f, key, np.array([new], dtype=np.int64))
        elif op == "index":
            ints = [n for n in vectors if f[n].dtype.kind in "iu"] or vectors
            key = ints[rng.integers(len(ints))]
            a = f[key][()].astype(np.int64)
            a[rng.integers(len(a))] = rng.choice([-1, -(2**31), a.max() + 1, a.max() + 3, 2**31 - 1, 10**9])
            replace(f, key, a)
        elif op == "value":
            floats = [n for n in vectors if f[n].dtype.kind == "f"]
            key = floats[rng.integers(len(floats))]
            a = f[key][()]
            a[rng.integers(len(a))] = rng.choice([np.nan, np.inf, -np.inf, -1.0, 1e300, 0.0, -1e-300])
            replace(f, key, a)
        elif op == "resize":
            key = vectors[rng.integers(len(vectors))]
            a = f[key][()]
            k = int(rng.integers(len(a) + 5))
            replace(f, key, a[:k] if k <= len(a) else np.r_[a, np.zeros(k - len(a), dtype=a.dtype)])
        else:  # retype
            key = datasets[rng.integers(len(datasets))]
            kind = rng.integers(3)
            del f[key]
            if kind == 0:
                f.create_dataset(key, data=np.bytes_("not a number"))
            elif kind == 1:
                f.create_group(key)
            else:
                f.create_dataset(key, data=np.ones((2, 2)))
    return op


JUNK_TOKENS = ["nan", "inf", "-inf", "-1", "0", "abc", "1e400", "3.5", "99999999999", "-99999999", "2", "", "0x10"]


def mutate_dat(rng, src, dst):
    raw = src.read_bytes()
    op = rng.choice(["token", "header", "delete", "insert", "bytes", "truncate"])
    if op in ("bytes", "truncate"):
        b = bytearray(raw[: rng.integers(len(raw))] if op == "truncate" else raw)
        if op == "bytes":
            for _ in range(rng.integers(1, 6)):
                b[rng.integers(len(b))] = int(rng.integers(256))
        dst.write_bytes(bytes(b))
        return op
    t = raw.decode().split()
    j = int(rng.integers(40 if op == "header" else len(t)))
    if op == "delete":
        del t[j]
    elif op == "insert":
        t.insert(j, str(rng.choice(JUNK_TOKENS + t[:40])))
    else:
        t[j] = str(rng.choice(JUNK_TOKENS))
    dst.write_text(" ".join(t))
    return op


def test_seeded_fuzz(tmp_path):
    """A few hundred mutated copies of valid FCLib local/global HDF5 and Siconos .dat files:
    fclib.load either raises FclibFormatError naming the file or returns a finite, consistent
    problem (checked in a worker process, so a crash in HDF5 or scipy fails this test instead of
    killing pytest); a sample goes through `stiction fclib FILE --json`: exit 0, 1 or 2 only.
    ~15 s of CPU; subprocess timeouts catch hangs."""
    rng = np.random.default_rng(20261122)
    base = tmp_path / "base"
    base.mkdir()
    local = base / "local.hdf5"
    shutil.copyfile(FCLIB_DIR / LOCAL, local)
    stack = base / "stack.hdf5"  # what write_local writes, with a solution group
    problem = two_cube_stack(10.0, 0.4, (0.2, 0.0, 0.0)).problem
    fclib.write_local(stack, problem, solution=stiction.solve(problem).lam)
    triplets = base / "triplets.hdf5"
    shutil.copyfile(FCLIB_DIR / LOCAL, triplets)
    with h5py.File(triplets, "r+") as f:
        to_triplets(f)
    hdf5 = [local, stack, triplets] + [shutil.copyfile(FCLIB_DIR / n, base / n)
                                       for n in (GLOBAL_FULL, GLOBAL_DIAG, UPPER[0])]
    dat = [shutil.copyfile(FCLIB_DIR / n, base / n) for n in (DAT_DENSE, DAT_SBM, "Toy--FC3D_Example1_SBM.dat")]
    objects = {p: h5_objects(p) for p in hdf5}

    cases = []
    for k in range(360):
        if k % 2 == 0:
            src = hdf5[(k // 2) % len(hdf5)]
            dst = tmp_path / f"case{k:03d}.hdf5"
            op = mutate_hdf5(rng, src, dst, objects[src])
        else:
            src = dat[(k // 2) % len(dat)]
            dst = tmp_path / f"case{k:03d}.dat"
            op = mutate_dat(rng, src, dst)
        cases.append((str(dst), f"{src.name} {op}"))
    listing = tmp_path / "cases.txt"
    listing.write_text("".join(p + "\n" for p, _ in cases))

    out = subprocess.run([sys.executable, "-c", WORKER, str(listing)], capture_output=True, text=True, timeout=300)
    lines = [json.loads(line) for line in out.stdout.splitlines()]
    results = [r for r in lines if "start" not in r]
    what = dict(cases)
    if out.returncode != 0:
        last = [r["start"] for r in lines if "start" in r][-1]
        pytest.fail(f"the loader died (rc {out.returncode}) on {last} ({what[last]}):\n{out.stderr[-3000:]}")
    assert len(results) == len(cases)
    loaded = 0
    for r in results:
        assert "unexpected" not in r, f"{what[r['path']]}: {r['unexpected']}"
        if r["loaded"]:
            loaded += 1
            assert r["consistent"], what[r["path"]]
        else:
            assert r["message"].startswith(r["path"] + ": "), r["message"]
    assert 0.1 * len(cases) < loaded < 0.9 * len(cases)  # the mutations hit both outcomes

    sample = [cases[i] for i in rng.choice(len(cases), size=20, replace=False)]
    with ThreadPoolExecutor(max_workers=2) as pool:  # the interpreter start-up dominates
        runs = pool.map(lambda c: cli(c[0], "--json", "--max-iter", "200", "--time-limit", "2", timeout=60), sample)
        for (path, how), run in zip(sample, runs):
            assert run.returncode in (0, 1, 2), (path, how, run.returncode, run.stderr[-2000:])
            assert "Traceback" not in run.stderr, (path, how, run.stderr[-2000:])
            if run.returncode == 2:
                assert run.stderr.startswith(f"stiction fclib: {path}: "), run.stderr
            else:
                assert json.loads(run.stdout)[0]["file"] == path.rsplit("/", 1)[-1]
