"""FCLib problems: read FCLib HDF5 (local and global) and Siconos ``.dat`` files, write FCLib local files.

FCLib's local problem is  u = W r + q,  K* ∋ u + E s(u) ⟂ r ∈ K  with each contact ordered
(normal, t1, t2). stiction's problem (eq. 65/73) is  u = A λ - b  with (t1, t2, normal).
So A = P W Pᵀ, b = -P q, λ = P r, with P the per-contact permutation (n, t1, t2) -> (t1, t2, n).
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ._core import Constraint, ContactProblem

HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


@dataclass
class FclibProblem:
    """One FCLib problem in stiction's convention (normal last, u = A λ - b)."""

    name: str
    kind: str  # "fclib_local" | "fclib_global" | "siconos_dat"
    A: np.ndarray  # (3nc, 3nc), as stored (not symmetrised)
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
        return ContactProblem(
            np.asfortranarray(self.A),
            np.ascontiguousarray(self.b),
            [Constraint.spatial_friction(float(m)) for m in self.mu],
            asymmetry_tolerance,
        )


def _to_stiction_order(nc: int) -> np.ndarray:
    """Index array p with ours[i] = fclib[p[i]]: (n, t1, t2) -> (t1, t2, n)."""
    base = 3 * np.arange(nc)
    return np.stack([base + 1, base + 2, base + 0], axis=1).ravel()


def _sparse_from_group(g) -> sp.csr_matrix:
    m, n, nz = int(g["m"][0]), int(g["n"][0]), int(g["nz"][0])
    p = np.asarray(g["p"][:], dtype=np.int64)
    i = np.asarray(g["i"][:], dtype=np.int64)
    x = np.asarray(g["x"][:], dtype=np.float64)
    if nz >= 0:  # triplets: i = row, p = column (checked on the data)
        return sp.coo_matrix((x[:nz], (i[:nz], p[:nz])), shape=(m, n)).tocsr()
    if nz == -1:  # CSC
        return sp.csc_matrix((x[: p[-1]], i[: p[-1]], p), shape=(m, n)).tocsr()
    if nz == -2:  # CSR
        return sp.csr_matrix((x[: p[-1]], i[: p[-1]], p), shape=(m, n))
    raise ValueError(f"unknown FCLib sparse storage nz={nz}")


def _read_info(grp) -> dict:
    out = {}
    if "info" in grp:
        for key in ("title", "description", "math_info"):
            if key in grp["info"]:
                v = grp["info"][key][()]
                out[key] = v.decode("utf-8", "replace") if isinstance(v, bytes) else str(v)
    return out


def _condense_global(M: sp.spmatrix, H: sp.spmatrix, f: np.ndarray, w: np.ndarray):
    """M v = H r + f, u = Hᵀ v + w  ->  W = Hᵀ M⁻¹ H, q = Hᵀ M⁻¹ f + w."""
    M = sp.csc_matrix(M)
    d = M.diagonal()
    if (M - sp.diags(d)).count_nonzero() == 0:
        MinvH = sp.diags(1.0 / d) @ H
        Minvf = f / d
        MinvH = MinvH.toarray()
    else:  # FEM iteration matrices: sparse LU
        lu = spla.splu(M)
        MinvH = lu.solve(H.toarray())
        Minvf = lu.solve(f)
    W = np.asarray(H.T @ MinvH)
    W = 0.5 * (W + W.T)  # symmetric by construction; remove round-off
    q = np.asarray(H.T @ Minvf).ravel() + w
    return W, q


def _load_hdf5(path: str):
    import h5py

    with h5py.File(path, "r") as f:
        guess = None
        if "fclib_local" in f:
            g = f["fclib_local"]
            if "V" in g or "R" in g:
                raise ValueError(f"{path}: FCLib local problems with equality constraints (V, R) are not supported")
            W = _sparse_from_group(g["W"]).toarray()
            q = np.asarray(g["vectors"]["q"][:], dtype=np.float64)
            mu = np.asarray(g["vectors"]["mu"][:], dtype=np.float64)
            kind, info = "fclib_local", _read_info(g)
        elif "fclib_global" in f:
            g = f["fclib_global"]
            if "G" in g:
                raise ValueError(f"{path}: FCLib global problems with equality constraints (G) are not supported")
            M, H = _sparse_from_group(g["M"]), _sparse_from_group(g["H"])
            vec = g["vectors"]
            fv = np.asarray(vec["f"][:], dtype=np.float64)
            w = np.asarray(vec["w"][:], dtype=np.float64) if "w" in vec else np.zeros(H.shape[1])
            W, q = _condense_global(M, H, fv, w)
            mu = np.asarray(vec["mu"][:], dtype=np.float64)
            kind, info = "fclib_global", _read_info(g)
        else:
            raise ValueError(f"{path}: no /fclib_local or /fclib_global group (rolling friction is not supported)")
        if kind == "fclib_local" and "guesses" in f and int(f["guesses"]["number_of_guesses"][0]) > 0:
            guess = np.asarray(f["guesses"]["1"]["r"][:], dtype=np.float64)
    return kind, W, q, mu, guess, info


def _load_dat(path: str):
    tokens = open(path).read().split()
    pos = 0

    def take(k: int, conv=float):
        nonlocal pos
        if pos + k > len(tokens):
            raise ValueError(f"{path}: truncated Siconos .dat file")
        out = [conv(t) for t in tokens[pos : pos + k]]
        pos += k
        return out

    dim, nc = take(2, int)
    if dim != 3:
        raise ValueError(f"{path}: only 3-D friction problems are supported (dim = {dim})")
    storage, size0, size1 = take(3, int)
    if storage == 0:  # dense, column-major
        size0, size1 = take(2, int)
        W = np.array(take(size0 * size1)).reshape((size0, size1), order="F")
    elif storage == 1:  # sparse block matrix
        (nbblocks,) = take(1, int)
        bn0, bn1 = take(2, int)
        ends0, ends1 = take(bn0, int), take(bn1, int)
        filled1, filled2 = take(2, int)
        row_ptr, col_idx = take(filled1, int), take(filled2, int)
        W = np.zeros((size0, size1))
        for br in range(filled1 - 1):
            r0 = 0 if br == 0 else ends0[br - 1]
            nr = ends0[br] - r0
            for blk in range(row_ptr[br], row_ptr[br + 1]):
                bc = col_idx[blk]
                c0 = 0 if bc == 0 else ends1[bc - 1]
                ncol = ends1[bc] - c0
                (number,) = take(1, int)
                if number != blk:
                    raise ValueError(f"{path}: sparse block numbering mismatch ({number} != {blk})")
                W[r0 : r0 + nr, c0 : c0 + ncol] = np.array(take(nr * ncol)).reshape((nr, ncol), order="F")
        if nbblocks != filled2:
            raise ValueError(f"{path}: block count mismatch")
    else:
        raise ValueError(f"{path}: Siconos matrix storage {storage} is not supported")
    q = np.array(take(size0))
    mu = np.array(take(nc))
    return "siconos_dat", W, q, mu, None, {}


def load(path: str | os.PathLike) -> FclibProblem:
    """Read an FCLib HDF5 (local or global) or Siconos .dat problem."""
    path = os.fspath(path)
    with open(path, "rb") as fh:
        is_hdf5 = fh.read(8) == HDF5_SIGNATURE
    kind, W, q, mu, guess, info = (_load_hdf5 if is_hdf5 else _load_dat)(path)
    nc = len(mu)
    if W.shape != (3 * nc, 3 * nc) or q.shape != (3 * nc,):
        raise ValueError(f"{path}: inconsistent sizes (W {W.shape}, q {q.shape}, {nc} contacts)")
    p = _to_stiction_order(nc)
    A = np.asfortranarray(W[np.ix_(p, p)])
    b = -q[p]
    if guess is not None:
        guess = guess[p] if guess.shape == (3 * nc,) else None
    return FclibProblem(os.path.basename(path), kind, A, b, mu, guess, info)


def write_local(path: str | os.PathLike, problem: ContactProblem, title: str = "", description: str = "",
                solution: np.ndarray | None = None) -> None:
    """Write a problem made of spatial friction contacts as an FCLib HDF5 local problem
    (W in CSR storage), so scenes can be dumped and solved by other tools."""
    import h5py

    from ._core import ConstraintKind

    cons = problem.constraints
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
        if solution is not None:
            sg = f.create_group("solution")
            lam = np.asarray(solution, dtype=np.float64)
            sg.create_dataset("r", data=lam[inv])
            u = problem.A @ lam - problem.b
            sg.create_dataset("u", data=u[inv])
