"""The candidates of :func:`~warp_stokes.geometry.simplify.simplify_enclosing`'s rounds: which edges may collapse
and keep the surface a manifold (:func:`link_condition`), where to (:func:`edge_placements`, by quadric error), and
which a round tries together (:func:`round_candidates`: cheapest first, fans sharing no vertex); with the sparse
arrays (CSR lists, sorted keys) that the rounds share.
"""

from __future__ import annotations

import numpy as np

from .topology import face_edges

__all__ = ["vertex_quadrics", "edge_placements", "unique_edges", "csr", "csr_rows", "in_sorted", "link_condition",
           "round_candidates"]


def vertex_quadrics(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """(V, 4, 4) sums of the area-weighted plane quadrics of each vertex's faces."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area2 = np.linalg.norm(n, axis=1)
    unit = n / np.maximum(area2, 1e-300)[:, None]
    plane = np.column_stack([unit, -np.einsum("ij,ij->i", unit, v[f[:, 0]])])
    q = 0.5 * area2[:, None, None] * plane[:, :, None] * plane[:, None, :]
    out = np.zeros((len(v), 4, 4))
    for k in range(3):
        np.add.at(out, f[:, k], q)
    return out


def edge_placements(qa: np.ndarray, qb: np.ndarray, pa: np.ndarray, pb: np.ndarray):
    """Candidate positions for collapsing edges (a, b), in order of their quadric error: the quadric's minimiser
    (where it is well conditioned and near the edge), the midpoint, a and b. Returns positions (E, 4, 3) and
    errors (E, 4)."""
    q = qa + qb
    mid = 0.5 * (pa + pb)
    a3, b3 = q[:, :3, :3], -q[:, :3, 3]
    det = np.linalg.det(a3)
    scale = np.maximum(np.einsum("eii->e", a3), 1e-300) ** 3
    good = np.abs(det) > 1e-6 * scale
    opt = mid.copy()
    if good.any():
        opt[good] = np.linalg.solve(a3[good], b3[good][:, :, None])[:, :, 0]
    # a minimiser far from the edge (a nearly flat or cylindrical patch) is no placement to trust
    far = np.linalg.norm(opt - mid, axis=1) > np.linalg.norm(pb - pa, axis=1)
    opt[far] = mid[far]
    cand = np.stack([opt, mid, pa, pb], axis=1)
    h = np.concatenate([cand, np.ones(cand.shape[:2] + (1,))], axis=2)
    cost = np.einsum("eci,eij,ecj->ec", h, q, h)
    cost = np.maximum(cost, 0.0)
    order = np.argsort(cost, axis=1, kind="stable")
    return np.take_along_axis(cand, order[:, :, None], axis=1), np.take_along_axis(cost, order, axis=1)


def unique_edges(f: np.ndarray, n: int) -> np.ndarray:
    """(E, 2) the undirected edges of faces f (vertex ids below n), each once, (a < b), sorted."""
    e = face_edges(f)
    keys = np.unique(np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1]))
    return np.column_stack([keys // n, keys % n])


def csr(source: np.ndarray, target: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(start (n + 1,), items) listing target[k] under source[k]."""
    order = np.argsort(source, kind="stable")
    start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(source, minlength=n), out=start[1:])
    return start, target[order]


def csr_rows(start: np.ndarray, items: np.ndarray, owners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each owner o, the items start[o]:start[o+1]: (which owner (by position in owners), item)."""
    counts = start[owners + 1] - start[owners]
    which = np.repeat(np.arange(len(owners)), counts)
    offset = np.arange(len(which)) - np.repeat(np.cumsum(counts) - counts, counts)
    return which, items[start[owners][which] + offset]


def in_sorted(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Which keys are in the sorted array."""
    if len(sorted_keys) == 0:
        return np.zeros(len(keys), dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    return sorted_keys[pos] == keys


def link_condition(edges, nbr_start, nbr, n) -> np.ndarray:
    """Edges whose ends share exactly two neighbours, neither of valence 3: collapsing them keeps the surface a
    manifold (and never flattens a tetrahedron)."""
    keys = edges[:, 0] * n + edges[:, 1]
    valence = np.diff(nbr_start)
    which, c = csr_rows(nbr_start, nbr, edges[:, 0])
    b = edges[which, 1]
    common = (c != b) & in_sorted(keys, np.minimum(b, c) * n + np.maximum(b, c))
    count = np.bincount(which, weights=common, minlength=len(edges))
    thin = np.bincount(which, weights=common & (valence[c] <= 3), minlength=len(edges))
    return (count == 2) & (thin == 0)


def _cost_bins(cost: np.ndarray) -> np.ndarray:
    """Costs in bins a quarter of an octave wide (the cheapest hundred-millionth of the largest in one): collapses
    are taken cheapest bin first, and within a bin in a scrambled order, so that where costs vary smoothly over the
    surface (or are all zero, on its flat parts) the independent sets are large, not one local minimum per round."""
    floor = 1e-8 * max(float(cost.max()), 1e-300)
    return np.floor(4.0 * np.log2(np.maximum(cost, floor) / floor)).astype(np.int64)


def _scramble(keys: np.ndarray) -> np.ndarray:
    """A fixed pseudo-random order of edge keys (Knuth's multiplicative hash): deterministic, spatially uncorrelated."""
    return (keys.astype(np.uint64) * np.uint64(2654435761)) % np.uint64(2**32)


def _first_at_both_ends(edges, priority, n) -> np.ndarray:
    """Edges that come first (smallest priority) among the edges at each of their two ends: no two share a vertex."""
    big = np.iinfo(np.int64).max
    m = np.full(n, big, dtype=np.int64)
    np.minimum.at(m, edges[:, 0], priority)
    np.minimum.at(m, edges[:, 1], priority)
    return (priority < big) & (priority == m[edges[:, 0]]) & (priority == m[edges[:, 1]])


def _disjoint_fans(which: np.ndarray, ring: np.ndarray, k: int, n: int, passes: int = 8) -> np.ndarray:
    """Of k collapses in priority order, whose fans hold vertices ``ring`` (``which`` collapse each), a set whose
    fans share no vertex, nearly maximal: in each pass a collapse is taken when it comes first at every vertex of
    its fan among those still open; collapses touching a taken fan close (Luby's rounds, with priorities)."""
    taken = np.zeros(k, dtype=bool)
    open_ = np.ones(k, dtype=bool)
    for _ in range(passes):
        live = open_[which]
        owner = np.full(n, k, dtype=np.int64)
        np.minimum.at(owner, ring[live], which[live])
        lost = np.bincount(which[live], weights=owner[ring[live]] != which[live], minlength=k) > 0
        won = open_ & ~lost
        taken |= won
        blocked = np.zeros(n, dtype=bool)
        blocked[ring[won[which]]] = True
        open_ &= ~won & ~(np.bincount(which, weights=blocked[ring], minlength=k) > 0)
        if not open_.any():
            break
    return taken


def round_candidates(edges, keys, cost, eligible, nbr_start, nbr, n, most) -> np.ndarray:
    """A round's collapses to check, in priority order: the eligible edges first at both ends (by cost bin, then a
    scrambled order), whose fans share no vertex, at most ``most``."""
    index = np.flatnonzero(eligible)
    priority = np.full(len(edges), np.iinfo(np.int64).max, dtype=np.int64)
    priority[index[np.lexsort((_scramble(keys[index]), _cost_bins(cost[index])))]] = np.arange(len(index))
    chosen = np.flatnonzero(_first_at_both_ends(edges, priority, n))
    chosen = chosen[np.argsort(priority[chosen])]
    if len(chosen) == 0:
        return chosen
    # fans that share no vertex: each vertex goes to the first collapse (in priority order) whose fan holds it
    which, ring = csr_rows(nbr_start, nbr, np.concatenate([edges[chosen, 0], edges[chosen, 1]]))
    which %= len(chosen)
    return chosen[_disjoint_fans(which, ring, len(chosen), n)][:most]
