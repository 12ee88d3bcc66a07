"""FCLib problems: read FCLib HDF5 (local and global) and Siconos ``.dat`` files, write FCLib local files.

FCLib's local problem is  u = W r + q,  K* ∋ u + E s(u) ⟂ r ∈ K  with each contact ordered
(normal, t1, t2). stiction's problem (eq. 65/73) is  u = A λ - b  with (t1, t2, normal).
So A = P W Pᵀ, b = -P q, λ = P r, with P the per-contact permutation (n, t1, t2) -> (t1, t2, n).
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._core import Constraint, ContactProblem

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"

# Sane bounds, checked before anything is allocated from a size a file declares.
MAX_INDEX = 2**31 - 1  # FCLib stores sizes and indices as 32-bit ints
MAX_DATASET_ENTRIES = 2**28  # any one HDF5 dataset read
MAX_DENSE_ENTRIES = 2**27  # a dense W, or the ndof x 3nc block M⁻¹H of a global problem (1 GiB)
SYMMETRY_ROUNDOFF = 1e-10  # a condensed W this close to symmetric (max-norm, relative) is symmetrised


class FclibFormatError(ValueError):
    """A malformed or unsupported FCLib / Siconos file. The message names the file and the
    field (e.g. ``fclib_local/W/i``); ``path`` and ``field`` hold them."""

    def __init__(self, path: str, field: str, message: str):
        self.path, self.field, self.message = path, field, message
        super().__init__(f"{path}: {field}: {message}" if field else f"{path}: {message}")

    def __reduce__(self):
        return type(self), (self.path, self.field, self.message)


@dataclass
class FclibProblem:
    """One FCLib problem in stiction's convention (normal last, u = A λ - b)."""

    name: str
    kind: str  # "fclib_local" | "fclib_global" | "siconos_dat"
    A: np.ndarray  # (3nc, 3nc): W as stored; global files: Hᵀ M⁻¹ H (info says how M was read)
    b: np.ndarray  # (3nc,)
    mu: np.ndarray  # (nc,)
    guess: np.ndarray | None = None  # λ of /guesses/1, permuted, if the file has one
    info: dict = field(default_factory=dict)

    @property
    def contacts(self) -> int:
        return len(self.mu)

    def problem(self, asymmetry_tolerance: float | None = None) -> ContactProblem:
        """The ContactProblem on the stored W. By default the symmetry check is
        relaxed just enough for the file (some Siconos dumps are asymmetric)."""
        if asymmetry_tolerance is None:
            scale = np.abs(self.A).max() if self.A.size else 0.0
            asym = np.abs(self.A - self.A.T).max() / scale if scale > 0 else 0.0
            asymmetry_tolerance = max(1e-9, 1.01 * asym)
        try:
            return ContactProblem(
                np.asfortranarray(self.A),
                np.ascontiguousarray(self.b),
                [Constraint.spatial_friction(float(m)) for m in self.mu],
                asymmetry_tolerance,
            )
        except ValueError as exc:  # e.g. an indefinite W: the file's data is not a contact problem
            field = "W (condensed from M, H)" if self.kind == "fclib_global" else "W"
            raise FclibFormatError(self.info.get("path", self.name), field,
                                   str(exc).removeprefix("ContactProblem: ")) from None


def _to_stiction_order(nc: int) -> np.ndarray:
    """Index array p with ours[i] = fclib[p[i]]: (n, t1, t2) -> (t1, t2, n)."""
    base = 3 * np.arange(nc)
    return np.stack([base + 1, base + 2, base + 0], axis=1).ravel()


# ---------------------------------------------------------------------------------------------
# Validation helpers shared by both formats
# ---------------------------------------------------------------------------------------------

def _first_bad(mask: np.ndarray) -> int:
    return int(np.flatnonzero(mask)[0])


def _check_finite(path: str, name: str, x: np.ndarray) -> None:
    bad = ~np.isfinite(x)
    if bad.any():
        k = _first_bad(bad)
        raise FclibFormatError(path, name, f"non-finite value {x[k]} at position {k}")


def _check_mu(path: str, name: str, mu: np.ndarray) -> None:
    if len(mu) == 0:
        raise FclibFormatError(path, name, "no contacts (empty friction coefficient vector)")
    _check_finite(path, name, mu)
    if (mu < 0).any():
        k = _first_bad(mu < 0)
        raise FclibFormatError(path, name, f"negative friction coefficient {mu[k]} at contact {k}")


def _check_dense_size(path: str, name: str, rows: int, cols: int, what: str) -> None:
    if rows * cols > MAX_DENSE_ENTRIES:
        raise FclibFormatError(path, name, f"{what} would be a dense {rows}x{cols} matrix, more than the "
                                           f"{MAX_DENSE_ENTRIES} entries stiction accepts")


def _check_indices(path: str, name: str, idx: np.ndarray, hi: int, what: str) -> None:
    bad = (idx < 0) | (idx >= hi)
    if bad.any():
        k = _first_bad(bad)
        raise FclibFormatError(path, name, f"{what} index {idx[k]} at position {k} is outside [0, {hi})")


# ---------------------------------------------------------------------------------------------
# FCLib HDF5
# ---------------------------------------------------------------------------------------------

class _Group:
    """An HDF5 group of an FCLib file whose every read is checked; errors name file and field."""

    def __init__(self, path: str, obj, name: str):
        self.path, self.obj, self.name = path, obj, name

    def field(self, key: str) -> str:
        return f"{self.name}/{key}" if self.name else key

    def error(self, key: str, message: str) -> FclibFormatError:
        return FclibFormatError(self.path, self.field(key), message)

    def has(self, key: str) -> bool:
        try:
            return key in self.obj
        except Exception as exc:  # h5py raises many types on damaged files
            raise self.error(key, f"unreadable ({exc})") from None

    def _get(self, key: str, kind: str):
        import h5py

        if not self.has(key):
            raise self.error(key, f"missing {kind}")
        try:
            obj = self.obj[key]
        except Exception as exc:
            raise self.error(key, f"unreadable {kind} ({exc})") from None
        want = h5py.Group if kind == "group" else h5py.Dataset
        if not isinstance(obj, want):
            raise self.error(key, f"is not a {kind}")
        return obj

    def group(self, key: str) -> "_Group":
        return _Group(self.path, self._get(key, "group"), self.field(key))

    def vector(self, key: str, integer: bool = False, max_len: int = MAX_DATASET_ENTRIES) -> np.ndarray:
        """A 1-D numeric dataset, its size checked before it is read."""
        ds = self._get(key, "dataset")
        try:
            shape, dtype = ds.shape, ds.dtype
        except Exception as exc:
            raise self.error(key, f"unreadable dataset header ({exc})") from None
        if shape is None:
            raise self.error(key, "has no data (null dataspace)")
        if sum(s != 1 for s in shape) > 1:
            raise self.error(key, f"is not a vector (shape {shape})")
        size = int(np.prod(shape, dtype=np.float64)) if shape else 1
        if size > max_len:
            raise self.error(key, f"has {size} entries, more than the {max_len} allowed here")
        if dtype.kind not in "biuf":
            raise self.error(key, f"is not numeric (type {dtype})")
        try:
            data = np.asarray(ds[()]).reshape(-1)
        except Exception as exc:
            raise self.error(key, f"unreadable data ({exc})") from None
        if data.size != size:
            raise self.error(key, f"holds {data.size} values, its header says {size}")
        if not integer:
            data = data.astype(np.float64)
            _check_finite(self.path, self.field(key), data)
            return data
        if dtype.kind == "f":
            if not np.all(np.isfinite(data)) or np.any(data != np.round(data)):
                raise self.error(key, "holds non-integer values")
            if data.size and np.abs(data).max() > 2.0 ** 62:
                raise self.error(key, "holds integers out of range")
        elif dtype.kind == "u" and data.size and data.max() > 2 ** 62:
            raise self.error(key, "holds integers out of range")
        return data.astype(np.int64)

    def integer(self, key: str, lo: int, hi: int) -> int:
        v = self.vector(key, integer=True, max_len=1)
        if v.size != 1:
            raise self.error(key, "expected one integer, found none")
        val = int(v[0])
        if not lo <= val <= hi:
            raise self.error(key, f"{val} is outside [{lo}, {hi}]")
        return val

    def sparse(self, shape: tuple[int, int], shape_source: str) -> sp.csr_matrix:
        """An FCLib sparse matrix (triplet, CSC or CSR) whose declared shape must equal `shape`,
        the size implied by the vectors actually present (named by `shape_source`)."""
        m, n = self.integer("m", 0, MAX_INDEX), self.integer("n", 0, MAX_INDEX)
        nz = self.integer("nz", -2, MAX_INDEX)
        nzmax = self.integer("nzmax", 0, MAX_INDEX) if self.has("nzmax") else None
        if (m, n) != shape:
            bad = "m" if m != shape[0] else "n"
            raise self.error(bad, f"the matrix is declared {m}x{n} but {shape_source} make it {shape[0]}x{shape[1]}")
        p, i, x = self.vector("p", integer=True), self.vector("i", integer=True), self.vector("x")
        if nz >= 0:  # triplet (CSparse convention: i = row, p = column)
            if nzmax is not None and nz > nzmax:
                raise self.error("nz", f"{nz} entries declared, more than nzmax = {nzmax}")
            for key, arr in (("p", p), ("i", i), ("x", x)):
                if len(arr) < nz:
                    raise self.error(key, f"has {len(arr)} entries, nz = {nz} declared")
            rows, cols, vals = i[:nz], p[:nz], x[:nz]
            _check_indices(self.path, self.field("i"), rows, m, "row")
            _check_indices(self.path, self.field("p"), cols, n, "column")
            return sp.coo_matrix((vals, (rows, cols)), shape=(m, n)).tocsr()
        if nz not in (-1, -2):
            raise self.error("nz", f"{nz} is no FCLib storage (>= 0 triplet, -1 CSC, -2 CSR)")
        outer, inner = (n, m) if nz == -1 else (m, n)
        label = "CSC: n + 1" if nz == -1 else "CSR: m + 1"
        if len(p) != outer + 1:
            raise self.error("p", f"has {len(p)} entries, expected {outer + 1} ({label})")
        if p[0] != 0:
            raise self.error("p", f"p[0] = {p[0]}, must be 0")
        dp = np.diff(p)
        if (dp < 0).any():
            k = _first_bad(dp < 0)
            raise self.error("p", f"decreases at position {k + 1} ({p[k]} -> {p[k + 1]})")
        nnz = int(p[-1])
        if nnz > len(i):
            raise self.error("p", f"p[-1] = {nnz} but i has {len(i)} entries")
        if nnz > len(x):
            raise self.error("x", f"has {len(x)} entries, p[-1] = {nnz} needs them")
        if nzmax is not None and nnz > nzmax:
            raise self.error("p", f"p[-1] = {nnz} entries, more than nzmax = {nzmax}")
        idx = i[:nnz]
        _check_indices(self.path, self.field("i"), idx, inner, "row" if nz == -1 else "column")
        cls = sp.csc_matrix if nz == -1 else sp.csr_matrix
        return sp.csr_matrix(cls((x[:nnz].copy(), idx.copy(), p.copy()), shape=(m, n)))

    def spacedim(self) -> None:
        if self.has("spacedim"):
            d = self.integer("spacedim", 0, MAX_INDEX)
            if d != 3:
                raise self.error("spacedim", f"{d}: only 3-D friction problems are supported")

    def info(self) -> dict:
        out = {}
        if not self.has("info"):
            return out
        g = self.group("info")
        for key in ("title", "description", "math_info"):
            if g.has(key):
                ds = g._get(key, "dataset")
                try:  # a string, or the first entry of anything else (never a whole big dataset)
                    v = ds[()] if not ds.shape else ds[:1]
                    v = v[0] if isinstance(v, np.ndarray) and v.size else v
                except Exception as exc:
                    raise g.error(key, f"unreadable ({exc})") from None
                v = v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)
                out[key] = v[:10000]
        return out


def _symmetric_completion(M: sp.csr_matrix) -> tuple[sp.csr_matrix, str]:
    """FCLib requires M symmetric positive definite but has no flag for symmetric storage. A file
    whose nonzeros lie in one triangle only stores that triangle (LMGC90 dumps do): complete it.
    A matrix with entries on both sides is used as stored (never symmetrised)."""
    C = M.tocoo()
    nonzero = C.data != 0
    upper = bool(np.any((C.row < C.col) & nonzero))
    lower = bool(np.any((C.row > C.col) & nonzero))
    if upper and not lower:
        return sp.csr_matrix(M + sp.triu(M, k=1).T), "upper triangle completed"
    if lower and not upper:
        return sp.csr_matrix(M + sp.tril(M, k=-1).T), "lower triangle completed"
    return M, ("full" if upper else "diagonal")


def _relative_asymmetry(A) -> float:
    if sp.issparse(A):
        scale = abs(A).max() if A.nnz else 0.0
        diff = abs(A - A.T).max() if A.nnz else 0.0
    else:
        scale = np.abs(A).max() if A.size else 0.0
        diff = np.abs(A - A.T).max() if A.size else 0.0
    return float(diff / scale) if scale > 0 else 0.0


def _condense_global(path: str, M: sp.spmatrix, H: sp.spmatrix, f: np.ndarray, w: np.ndarray):
    """M v = H r + f, u = Hᵀ v + w  ->  W = Hᵀ M⁻¹ H, q = Hᵀ M⁻¹ f + w.
    Returns W, q and what was found (M's storage, W's asymmetry before round-off removal)."""
    info: dict = {}
    M, info["M_storage"] = _symmetric_completion(sp.csr_matrix(M))
    info["M_asymmetry"] = _relative_asymmetry(M)
    n = M.shape[0]
    d = M.diagonal()
    Hd = H.toarray()
    if (M - sp.diags(d)).count_nonzero() == 0:
        if (d == 0).any():
            raise FclibFormatError(path, "fclib_global/M", f"singular: zero diagonal entry at row {_first_bad(d == 0)}")
        info["M_min_eigenvalue"] = float(d.min())
        MinvH, Minvf = Hd / d[:, None], f / d
    else:  # FEM iteration matrices: sparse LU
        if n <= 2000:
            S = M.toarray()
            info["M_min_eigenvalue"] = float(np.linalg.eigvalsh(0.5 * (S + S.T))[0])
        try:
            lu = spla.splu(sp.csc_matrix(M))
            MinvH, Minvf = lu.solve(Hd), lu.solve(f)
        except RuntimeError as exc:
            raise FclibFormatError(path, "fclib_global/M", f"cannot be factorised ({exc})") from None
    W = H.T @ MinvH
    W = np.asarray(W)
    q = np.asarray(H.T @ Minvf).ravel() + w
    if not (np.all(np.isfinite(W)) and np.all(np.isfinite(q))):
        raise FclibFormatError(path, "fclib_global/M", "condensing H^T M^-1 H gives non-finite values "
                                                       "(M singular or too ill-conditioned)")
    # W is symmetric by construction when M is: remove round-off, but only round-off, and keep
    # the measured asymmetry (a larger one means M itself is asymmetric: W is kept as computed).
    info["W_asymmetry"] = _relative_asymmetry(W)
    info["W_symmetrised"] = info["W_asymmetry"] <= SYMMETRY_ROUNDOFF
    if info["W_symmetrised"]:
        W = 0.5 * (W + W.T)
    return W, q, info


def _load_hdf5(path: str):
    import h5py

    try:
        fh = h5py.File(path, "r")
    except Exception as exc:
        raise FclibFormatError(path, "", f"not a readable HDF5 file ({exc})") from None
    with fh:
        root = _Group(path, fh, "")
        guess = None
        if root.has("fclib_local"):
            g = root.group("fclib_local")
            for key in ("V", "R"):
                if g.has(key):
                    raise g.error(key, "FCLib local problems with equality constraints (V, R) are not supported")
            g.spacedim()
            vec = g.group("vectors")
            q, mu = vec.vector("q"), vec.vector("mu")
            _check_mu(path, vec.field("mu"), mu)
            nc = len(mu)
            if len(q) != 3 * nc:
                raise vec.error("q", f"has {len(q)} entries, 3 x {nc} contacts (mu) = {3 * nc} expected")
            _check_dense_size(path, vec.field("mu"), 3 * nc, 3 * nc, f"W ({nc} contacts)")
            W = g.group("W").sparse((3 * nc, 3 * nc), f"q and mu ({nc} contacts)").toarray()
            kind, info = "fclib_local", g.info()
            if root.has("guesses"):
                gg = root.group("guesses")
                count = gg.integer("number_of_guesses", 0, MAX_INDEX)
                if count > 0:
                    guess = gg.group("1").vector("r")
                    if len(guess) != 3 * nc:
                        raise FclibFormatError(path, "guesses/1/r", f"has {len(guess)} entries, {3 * nc} expected")
        elif root.has("fclib_global"):
            g = root.group("fclib_global")
            if g.has("G"):
                raise g.error("G", "FCLib global problems with equality constraints (G) are not supported")
            g.spacedim()
            vec = g.group("vectors")
            fv, mu = vec.vector("f"), vec.vector("mu")
            _check_mu(path, vec.field("mu"), mu)
            nc, ndof = len(mu), len(fv)
            w = vec.vector("w") if vec.has("w") else np.zeros(3 * nc)
            if len(w) != 3 * nc:
                raise vec.error("w", f"has {len(w)} entries, 3 x {nc} contacts (mu) = {3 * nc} expected")
            _check_dense_size(path, g.field("H"), ndof, 3 * nc, "M⁻¹H")
            _check_dense_size(path, vec.field("mu"), 3 * nc, 3 * nc, f"W (Hᵀ M⁻¹ H, {nc} contacts)")
            M = g.group("M").sparse((ndof, ndof), f"f ({ndof} entries)")
            H = g.group("H").sparse((ndof, 3 * nc), f"f ({ndof} entries) and mu ({nc} contacts)")
            W, q, found = _condense_global(path, M, H, fv, w)
            kind, info = "fclib_global", {**g.info(), **found}
        else:
            raise FclibFormatError(path, "", "no /fclib_local or /fclib_global group "
                                             "(rolling friction problems are not supported)")
    return kind, W, q, mu, guess, info


# ---------------------------------------------------------------------------------------------
# Siconos numerics .dat (text)
# ---------------------------------------------------------------------------------------------

_INT_TOKEN = re.compile(r"[+-]?[0-9]{1,18}\Z")


class _Tokens:
    def __init__(self, path: str, tokens: list[str]):
        self.path, self.tokens, self.pos = path, tokens, 0

    def error(self, name: str, message: str) -> FclibFormatError:
        return FclibFormatError(self.path, name, message)

    @property
    def left(self) -> int:
        return len(self.tokens) - self.pos

    def _take(self, k: int, name: str) -> list[str]:
        if k > self.left:
            raise self.error(name, f"truncated file: {k} values expected, {self.left} left")
        out = self.tokens[self.pos: self.pos + k]
        self.pos += k
        return out

    def ints(self, k: int, name: str, lo: int = 0, hi: int = MAX_INDEX) -> np.ndarray:
        start = self.pos
        toks = self._take(k, name)
        for j, t in enumerate(toks):
            if not _INT_TOKEN.match(t):
                raise self.error(name, f"non-integer token {t[:40]!r} (token {start + j})")
        out = np.array([int(t) for t in toks], dtype=np.int64)
        bad = (out < lo) | (out > hi)
        if bad.any():
            j = _first_bad(bad)
            raise self.error(name, f"{out[j]} is outside [{lo}, {hi}]" + (f" (entry {j})" if k > 1 else ""))
        return out

    def int(self, name: str, lo: int = 0, hi: int = MAX_INDEX) -> int:
        return int(self.ints(1, name, lo, hi)[0])

    def floats(self, k: int, name: str) -> np.ndarray:
        start = self.pos
        toks = self._take(k, name)
        try:
            out = np.array(toks, dtype=np.float64)
        except ValueError:
            for j, t in enumerate(toks):
                try:
                    float(t)
                except ValueError:
                    raise self.error(name, f"non-numeric token {t[:40]!r} (token {start + j})") from None
            raise
        _check_finite(self.path, name, out)
        return out


def _block_ends(tk: _Tokens, k: int, size: int, name: str) -> np.ndarray:
    ends = tk.ints(k, name, 1, size)
    if k and (np.any(np.diff(ends) <= 0) or ends[-1] != size):
        raise tk.error(name, f"cumulated block sizes must increase strictly up to {size}")
    return ends


def _load_dat(path: str):
    with open(path, "rb") as fh:
        raw = fh.read()
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        raise FclibFormatError(path, "", f"not a Siconos .dat text file (byte {raw[exc.start]:#04x} "
                                         f"at offset {exc.start})") from None
    tk = _Tokens(path, text.split())
    if not tk.tokens:
        raise FclibFormatError(path, "", "empty file")
    dim = tk.int("dim", 0)
    if dim != 3:
        raise tk.error("dim", f"only 3-D friction problems are supported (dim = {dim})")
    nc = tk.int("nc", 1)
    if 4 * nc > tk.left:  # each contact needs 3 entries of q and its mu: bound nc by the data
        raise tk.error("nc", f"truncated file: {nc} contacts need at least {4 * nc} more values, {tk.left} left")
    m = 3 * nc
    storage = tk.int("W/storage", 0, 2)
    size0, size1 = tk.int("W/size0", 0), tk.int("W/size1", 0)
    if (size0, size1) != (m, m):
        raise tk.error("W/size0" if size0 != m else "W/size1",
                       f"W is declared {size0}x{size1}, {nc} contacts need {m}x{m}")
    _check_dense_size(path, "W", m, m, "W")
    if storage == 0:  # dense, column-major, sizes repeated
        again = tk.ints(2, "W/dense sizes", 0)
        if tuple(again) != (m, m):
            raise tk.error("W/dense sizes", f"{again[0]}x{again[1]} does not repeat {m}x{m}")
        W = tk.floats(m * m, "W/values").reshape((m, m), order="F")
    elif storage == 1:  # sparse block matrix (Siconos SparseBlockStructuredMatrix)
        nbblocks = tk.int("W/nbblocks", 0, tk.left)
        bn0, bn1 = tk.int("W/blocknumber0", 0, m), tk.int("W/blocknumber1", 0, m)
        ends0 = _block_ends(tk, bn0, m, "W/blocksize0")
        ends1 = _block_ends(tk, bn1, m, "W/blocksize1")
        filled1 = tk.int("W/filled1", 0, bn0 + 1)
        filled2 = tk.int("W/filled2", 0, tk.left)
        if filled2 != nbblocks:
            raise tk.error("W/filled2", f"{filled2} blocks, but nbblocks = {nbblocks}")
        row_ptr = tk.ints(filled1, "W/index1_data", 0, filled2)
        if filled1 and (row_ptr[0] != 0 or np.any(np.diff(row_ptr) < 0) or row_ptr[-1] != filled2):
            raise tk.error("W/index1_data", f"must increase from 0 to filled2 = {filled2}")
        if filled1 == 0 and filled2 != 0:
            raise tk.error("W/filled1", f"0 block rows but {filled2} blocks declared")
        col_idx = tk.ints(filled2, "W/index2_data", 0, max(bn1 - 1, 0))
        if filled2 and bn1 == 0:
            raise tk.error("W/index2_data", "blocks declared in a matrix of 0 block columns")
        W = np.zeros((m, m))
        seen = set()
        for br in range(filled1 - 1):
            r0 = 0 if br == 0 else int(ends0[br - 1])
            nr = int(ends0[br]) - r0
            for blk in range(int(row_ptr[br]), int(row_ptr[br + 1])):
                bc = int(col_idx[blk])
                if (br, bc) in seen:
                    raise tk.error("W/index2_data", f"block ({br}, {bc}) stored twice")
                seen.add((br, bc))
                c0 = 0 if bc == 0 else int(ends1[bc - 1])
                ncol = int(ends1[bc]) - c0
                number = tk.int(f"W/block {blk} number", 0)
                if number != blk:
                    raise tk.error(f"W/block {blk} number", f"block numbering mismatch ({number} != {blk})")
                W[r0: r0 + nr, c0: c0 + ncol] = tk.floats(nr * ncol, f"W/block {blk}").reshape((nr, ncol), order="F")
    else:
        raise tk.error("W/storage", f"Siconos matrix storage {storage} is not supported (0 dense, 1 sparse block)")
    q = tk.floats(m, "q")
    mu = tk.floats(nc, "mu")
    _check_mu(path, "mu", mu)
    return "siconos_dat", W, q, mu, None, {}


def _has_hdf5_signature(fh) -> bool:
    """HDF5's signature is at byte 0, or at 512, 1024, 2048, ... after a user block."""
    size = os.fstat(fh.fileno()).st_size
    offset = 0
    while offset + 8 <= size:
        fh.seek(offset)
        if fh.read(8) == HDF5_SIGNATURE:
            return True
        offset = 512 if offset == 0 else 2 * offset
    return False


def load(path: str | os.PathLike) -> FclibProblem:
    """Read an FCLib HDF5 (local or global) or Siconos .dat problem.

    Everything read is validated: a malformed file raises :class:`FclibFormatError` (a
    ``ValueError``) whose message names the file and the field; a missing file raises
    ``FileNotFoundError``."""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise FclibFormatError(path, "", "is a directory, not an FCLib or Siconos .dat file")
    try:
        with open(path, "rb") as fh:
            is_hdf5 = _has_hdf5_signature(fh)
        if not is_hdf5 and path.lower().endswith((".hdf5", ".h5")):
            raise FclibFormatError(path, "", "has an HDF5 name but no HDF5 signature "
                                             "(empty, truncated or not an HDF5 file)")
        kind, W, q, mu, guess, info = (_load_hdf5 if is_hdf5 else _load_dat)(path)
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise FclibFormatError(path, "", f"cannot be read ({exc.strerror or exc})") from None
    nc = len(mu)
    # the readers check all of this; kept as the contract FclibProblem relies on
    if W.shape != (3 * nc, 3 * nc) or q.shape != (3 * nc,) or nc == 0:
        raise FclibFormatError(path, "", f"inconsistent sizes (W {W.shape}, q {q.shape}, {nc} contacts)")
    for name, arr in (("W", W), ("q", q), ("mu", mu)):
        _check_finite(path, name, np.ravel(arr))
    d = np.diagonal(W)
    if (d < 0).any():  # FCLib's W (and M) are positive (semi-)definite
        k = _first_bad(d < 0)
        where = {"fclib_local": "fclib_local/W", "fclib_global": "fclib_global/M"}.get(kind, "W")
        raise FclibFormatError(path, where, f"W[{k},{k}] = {d[k]:.3g} is negative: W is not positive "
                                            "semi-definite as FCLib requires")
    p = _to_stiction_order(nc)
    A = np.asfortranarray(W[np.ix_(p, p)])
    b = -q[p]
    if guess is not None:
        guess = guess[p]
    info.setdefault("path", str(path))
    return FclibProblem(os.path.basename(path), kind, A, b, mu, guess, info)


def write_local(path: str | os.PathLike, problem: ContactProblem, title: str = "", description: str = "",
                solution: np.ndarray | None = None) -> None:
    """Write a problem made of spatial friction contacts as an FCLib HDF5 local problem
    (W in CSR storage), so scenes can be dumped and solved by other tools. ValueError for any
    other block (FCLib has no box blocks: joint friction and effort limits cannot be written)."""
    import h5py

    from ._core import ConstraintKind

    cons = problem.constraints
    boxes = [i for i, c in enumerate(cons) if c.kind == ConstraintKind.box]
    if boxes:
        raise ValueError(f"FCLib has no box blocks: this problem has {len(boxes)} box row(s) (joint friction, "
                         f"effort limits; first: block {boxes[0]}), which an FCLib file cannot store")
    if any(c.kind != ConstraintKind.spatial_friction for c in cons):
        raise ValueError("FCLib local problems hold spatial friction contacts only; "
                         "this problem has other constraint kinds")
    nc = len(cons)
    p = _to_stiction_order(nc)
    inv = np.empty_like(p)
    inv[p] = np.arange(3 * nc)  # fclib[j] = ours[inv[j]]
    W = sp.csr_matrix(problem.A[np.ix_(inv, inv)])
    q = -problem.b[inv]
    mu = np.array([c.mu for c in cons])
    if nc == 0:
        raise ValueError("FCLib local problems need at least one contact")
    # write only what load() accepts back
    if not (np.all(np.isfinite(W.data)) and np.all(np.isfinite(q)) and np.all(np.isfinite(mu))):
        raise ValueError("the problem holds non-finite values; FCLib files must not")
    if W.nnz > MAX_INDEX:
        raise ValueError(f"W has {W.nnz} nonzeros, more than FCLib's 32-bit indices can hold")
    lam = None
    if solution is not None:
        lam = np.asarray(solution, dtype=np.float64)
        if lam.shape != (3 * nc,) or not np.all(np.isfinite(lam)):
            raise ValueError(f"solution must be {3 * nc} finite values (shape {lam.shape} given)")
    with h5py.File(os.fspath(path), "w") as f:
        g = f.create_group("fclib_local")
        g.create_dataset("spacedim", data=np.array([3], dtype=np.int32))
        wg = g.create_group("W")
        for key, val in (("m", W.shape[0]), ("n", W.shape[1]), ("nz", -2), ("nzmax", W.nnz)):
            wg.create_dataset(key, data=np.array([val], dtype=np.int32))
        wg.create_dataset("p", data=W.indptr.astype(np.int32))
        wg.create_dataset("i", data=W.indices.astype(np.int32))
        wg.create_dataset("x", data=W.data.astype(np.float64))
        vg = g.create_group("vectors")
        vg.create_dataset("q", data=q)
        vg.create_dataset("mu", data=mu)
        ig = g.create_group("info")
        ig.create_dataset("title", data=np.bytes_(title or "stiction"))
        ig.create_dataset("description", data=np.bytes_(description or "written by stiction.fclib.write_local"))
        ig.create_dataset("math_info", data=np.bytes_("u = W r + q, contact rows (n, t1, t2)"))
        if lam is not None:
            sg = f.create_group("solution")
            sg.create_dataset("r", data=lam[inv])
            u = problem.A @ lam - problem.b
            sg.create_dataset("u", data=u[inv])
