"""Independent float64 reference for the compact 19-point coupled biharmonic scheme.

Written directly from docs/method.md section 3 with numpy + scipy.sparse; it deliberately imports nothing from
``warp_stokes`` so that it can be used to check the package's solvers.

On a uniform grid of spacing ``h`` with ``G = h * grad(q)``, the unknowns per INTERIOR node ``p`` are
``q, Gx, Gy, Gz`` and the equations at ``p`` are

    value eq:     48 q_p - 10 sum_face q + sum_edge q + 3 sum_a ( G_a(p+e_a) - G_a(p-e_a) ) = (h^4 / 2) f_p
    gradient eq:  G_a(p-e_a) + 4 G_a(p) + G_a(p+e_a) - 3 ( q(p+e_a) - q(p-e_a) ) = 0            (a = x, y, z)

Values/gradients at non-interior nodes are known data and are moved to the right-hand side. Rows are kept exactly
as written (no sign flips): the matrix is then symmetric positive definite.

Unknown ordering: interior nodes in C order (``np.flatnonzero(interior.ravel())``), 4 unknowns per node
``[q, Gx, Gy, Gz]`` contiguous, i.e. unknown ``4 * i + c`` is component ``c`` of the ``i``-th interior node.

Array layouts: ``known`` is ``(nx, ny, nz, H, 4)`` float64 with the last axis ``(q, Gx, Gy, Gz)``; ``f`` is
``(nx, ny, nz, H)``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["FACE_OFFSETS", "EDGE_OFFSETS", "stencil_terms", "assemble", "reference_solve", "residual"]

# 6 face neighbours, ordered (axis, sign)
FACE_OFFSETS = [tuple(s if b == a else 0 for b in range(3)) for a in range(3) for s in (-1, 1)]
# 12 edge neighbours: two nonzero components of +-1
EDGE_OFFSETS = [
    tuple(o)
    for o in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")).reshape(3, -1).T
    if np.count_nonzero(o) == 2
]
assert len(EDGE_OFFSETS) == 12


def stencil_terms():
    """All off-diagonal terms of the scheme as (row_component, offset, column_component, coefficient).

    Component 0 is q, component 1 + a is G_a. The diagonal terms are 48 (value eq) and 4 (gradient eqs).
    """
    terms = []
    # value equation (row component 0)
    for d in FACE_OFFSETS:
        terms.append((0, d, 0, -10.0))
    for d in EDGE_OFFSETS:
        terms.append((0, d, 0, 1.0))
    for a in range(3):
        for s in (-1, 1):
            d = tuple(s if b == a else 0 for b in range(3))
            terms.append((0, d, 1 + a, 3.0 * s))  # +3 G_a(p+e_a), -3 G_a(p-e_a)
    # gradient equations (row component 1 + a)
    for a in range(3):
        for s in (-1, 1):
            d = tuple(s if b == a else 0 for b in range(3))
            terms.append((1 + a, d, 1 + a, 1.0))  # G_a(p -+ e_a)
            terms.append((1 + a, d, 0, -3.0 * s))  # -3 q(p+e_a) + 3 q(p-e_a)
    return terms


DIAGONAL = np.array([48.0, 4.0, 4.0, 4.0])


def _check_interior(interior) -> np.ndarray:
    interior = np.asarray(interior)
    if interior.ndim != 3:
        raise ValueError(f"interior must be a 3-D boolean array, got shape {interior.shape}")
    interior = interior.astype(bool, copy=False)
    if (
        interior[0].any()
        or interior[-1].any()
        or interior[:, 0].any()
        or interior[:, -1].any()
        or interior[:, :, 0].any()
        or interior[:, :, -1].any()
    ):
        raise ValueError("interior must be False on the outermost layer of grid nodes")
    return interior


def assemble(interior: np.ndarray) -> tuple[sp.csr_matrix, Callable]:
    """Assemble the scheme on the interior nodes of a boolean mask.

    interior: bool (nx, ny, nz), False on the outermost layer (ValueError otherwise).
    Unknown ordering: interior nodes in C order (``np.flatnonzero(interior.ravel())``), 4 unknowns each
    ``[q, Gx, Gy, Gz]`` contiguous.

    Returns ``(A, rhs)``: ``A`` is the (4N x 4N) float64 CSR matrix and ``rhs(known, f=None, h=1.0)`` returns the
    (4N, H) right-hand side, i.e. ``(h**4/2) f`` in the value rows minus the contributions of the known data at the
    non-interior neighbours. ``known`` is (nx, ny, nz, H, 4) (a (nx, ny, nz, 4) array is taken as H = 1); its
    entries at interior nodes are ignored. ``f`` is (nx, ny, nz, H) (or (nx, ny, nz) for H = 1), None means 0.
    """
    interior = _check_interior(interior)
    shape = interior.shape
    coords = np.nonzero(interior)  # C order == np.flatnonzero(interior.ravel())
    n = coords[0].size
    index = np.full(shape, -1, dtype=np.int64)
    index[coords] = np.arange(n, dtype=np.int64)

    rows, cols, vals = [], [], []
    # diagonal
    node = np.arange(n, dtype=np.int64)
    for c in range(4):
        rows.append(4 * node + c)
        cols.append(4 * node + c)
        vals.append(np.full(n, DIAGONAL[c]))

    # known-data terms: (row_component, column_component, coefficient, row node ids, flat neighbour ids)
    known_terms = []
    for rc, d, cc, coef in stencil_terms():
        nb = tuple(coords[k] + d[k] for k in range(3))
        j = index[nb]
        inside = j >= 0
        rows.append(4 * node[inside] + rc)
        cols.append(4 * j[inside] + cc)
        vals.append(np.full(int(inside.sum()), coef))
        out = ~inside
        if out.any():
            flat = np.ravel_multi_index(tuple(x[out] for x in nb), shape)
            known_terms.append((rc, cc, coef, node[out], flat))

    A = sp.coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(4 * n, 4 * n)
    ).tocsr()
    A.sum_duplicates()
    flat_interior = np.flatnonzero(interior.ravel())
    nnodes = int(np.prod(shape))

    def rhs(known, f=None, h=1.0) -> np.ndarray:
        known = np.asarray(known, dtype=np.float64)
        if known.shape == shape + (4,):
            known = known[:, :, :, None, :]
        if known.ndim != 5 or known.shape[:3] != shape or known.shape[4] != 4:
            raise ValueError(f"known must have shape {shape + ('H', 4)}, got {known.shape}")
        H = known.shape[3]
        kf = known.reshape(nnodes, H, 4)
        b = np.zeros((n, 4, H))
        for rc, cc, coef, rnode, flat in known_terms:
            # each term has one offset, so a row node appears at most once in rnode: plain fancy indexing is safe
            b[rnode, rc, :] -= coef * kf[flat, :, cc]
        if f is not None:
            f = np.asarray(f, dtype=np.float64)
            if f.shape == shape:
                f = f[..., None]
            if f.shape != shape + (H,):
                raise ValueError(f"f must have shape {shape + (H,)}, got {f.shape}")
            b[:, 0, :] += (h**4 / 2.0) * f.reshape(nnodes, H)[flat_interior]
        return b.reshape(4 * n, H)

    return A, rhs


def _nested_dissection(coords: np.ndarray, leaf: int = 32) -> np.ndarray:
    """Node permutation (new position -> node id) by recursive bisection with single-plane separators.

    coords: (N, 3) integer grid coordinates of the interior nodes. Sub-domains are ordered before their separator.
    """
    parts = []

    def rec(ids):
        c = coords[ids]
        ext = c.max(axis=0) - c.min(axis=0)
        a = int(np.argmax(ext))
        if len(ids) <= leaf or ext[a] < 2:
            parts.append(ids)
            return
        ca = c[:, a]
        mid = (int(ca.min()) + int(ca.max())) // 2
        rec(ids[ca < mid])
        rec(ids[ca > mid])
        parts.append(ids[ca == mid])

    if len(coords):
        rec(np.arange(len(coords)))
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


def reference_solve(interior, known, f=None, h=1.0) -> np.ndarray:
    """Solve the scheme with one sparse direct factorisation for all H columns.

    interior: bool (nx, ny, nz), must be False on the outermost layer of grid nodes (ValueError otherwise).
    known: float64 (nx, ny, nz, H, 4) holding (q, Gx, Gy, Gz) at every node (G = h * grad q); entries at interior
        nodes are ignored.
    f: optional float64 (nx, ny, nz, H) source term (rhs of the value eq is h**4/2 * f).
    Returns a float64 copy of ``known`` (same shape) with the interior nodes replaced by the solution.
    """
    interior = _check_interior(interior)
    known = np.asarray(known, dtype=np.float64)
    if known.ndim != 5 or known.shape[:3] != interior.shape or known.shape[4] != 4:
        raise ValueError(f"known must have shape {interior.shape + ('H', 4)}, got {known.shape}")
    out = known.copy()
    A, rhs = assemble(interior)
    n = A.shape[0] // 4
    if n == 0:
        return out
    b = rhs(known, f, h)
    # Geometric nested dissection (the 19-point stencil couples only nodes at most one step apart per axis, so one
    # grid plane separates the two sides), applied symmetrically; the matrix is SPD, so diagonal pivots are stable
    # and SuperLU is told to keep them. This fills far less than SuperLU's own orderings on 3-D grids.
    perm = (4 * _nested_dissection(np.argwhere(interior))[:, None] + np.arange(4)).ravel()
    lu = spla.splu(
        A[perm][:, perm].tocsc(),
        permc_spec="NATURAL",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )
    x = np.empty_like(b)
    x[perm] = lu.solve(b[perm])
    H = known.shape[3]
    out[interior] = x.reshape(n, 4, H).transpose(0, 2, 1)
    return out


def residual(interior, full, f=None, h=1.0) -> np.ndarray:
    """Residual ``(h^4/2) f - stencil(full)`` of the scheme at interior nodes, as (N, H, 4) (row order q, Gx, Gy, Gz).

    ``full`` is (nx, ny, nz, H, 4) with values at every node (interior included).
    """
    A, rhs = assemble(interior)
    interior = np.asarray(interior, dtype=bool)
    full = np.asarray(full, dtype=np.float64)
    n = A.shape[0] // 4
    H = full.shape[3]
    u = full[interior].transpose(0, 2, 1).reshape(4 * n, H)
    r = rhs(full, f, h) - A @ u
    return r.reshape(n, 4, H).transpose(0, 2, 1)
