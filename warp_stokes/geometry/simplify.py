"""Simplifying a closed surface to a cage: quadric edge collapses that keep it a closed, oriented, manifold surface
that does not cross itself, does not fold, and keeps a set of points inside, at a margin from it.

Every collapse is checked before it is made (not repaired after), on the device (:mod:`warp_stokes.kernels.collapse`):
no face turned over or with an angle below the minimum, no fold sharper than :data:`MAX_FOLD_DEGREES`, no new face
crossing another face, and no point of the enclosed set swept out of the surface (a winding number about the region
between the old and the new faces) or brought within the margin of it. The link condition (the surface stays a
manifold) is checked on the host. So the surface is valid after every step; where no collapse is valid it stops
short of the count asked for.

Collapses are made in rounds: the cheapest edges (quadric error, in bins of a quarter octave, a fixed scrambled
order within a bin), whose fans share no vertex, checked all at once against the surface as it is; of those that
pass, one whose new faces would cross another's waits for the next round. An edge refused is tried again once its
fan has changed. Where rounds make nothing (near the end, most candidates are refused), the next rounds' candidates
are worked out ahead and checked in one launch (:data:`AHEAD_CANDIDATES`): the same rounds, in fewer launches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cage_faults import crossing_faces
from .topology import face_edges

__all__ = ["simplify_enclosing", "Simplified", "MAX_FOLD_DEGREES", "REFUSALS", "STALL_WINDOW", "STALL_ROUNDS"]

#: no collapse makes two neighbouring faces' normals more than this many degrees apart (a cage's own check notes
#: folds beyond 150 degrees)
MAX_FOLD_DEGREES = 120.0
#: no collapse makes a face with an angle below this many degrees, or turns a face by more than FLIP_DEGREES
MIN_ANGLE_DEGREES = 1.0
FLIP_DEGREES = 120.0
#: threads per CUDA block of the collapse checks: each of their two BVH queries keeps its stack in shared memory,
#: which 256 threads would overflow (66 KB of the 48 KB a block may have)
COLLAPSE_BLOCK = 64
#: with ``give_up_above``: the rounds over which the pace of the collapses is measured, and the most rounds it may
#: still need. Near its end a surface makes a collapse every 10-100 rounds, or none, for thousands of rounds: on 33
#: meshes and counts (the shared pairs, 14 public test meshes, six QMVC pairs; 8 to 126 handles) no try that reached
#: the count would have given up (with 500 two would have); 30 meshes and counts made again came out bit for bit the
#: same; asked for 8, the QMVC SpikyBox and WireSphere (61k, 49k vertices) took 5.6 and 6.5 s instead of 10.0 and
#: 14.2 on 2 cores
STALL_WINDOW = 128
STALL_ROUNDS = 1000
#: after a round that made no collapse, the next rounds are worked out ahead as if each refused all it tried (as
#: nearly all do there), and their candidates checked in one launch: at least AHEAD_CANDIDATES, twice as many after
#: each launch where none passed, up to AHEAD_MOST. The rounds are then taken in order up to the first where one
#: passed: the same collapses, refusals and rounds as one round at a time, without each round's edges, placements
#: and BVH (the shared ogre made at an offset of 0.5 %: 2,532 rounds and 12-15 s before, 383 rounds and 7 s on 2
#: cores, with the refusals' fix of the same commit)
AHEAD_CANDIDATES = 16
AHEAD_MOST = 256
#: why collapses were refused (the kernel's codes, in ``Simplified.refusals``)
REFUSALS = {1: "small angle", 2: "face turned", 3: "fold", 4: "faces cross", 5: "point within the margin",
            6: "point swept out"}


@dataclass
class Simplified:
    """The simplified surface: ``vertices`` (V, 3), ``faces`` (F, 3) outward as given; the ``rounds`` of collapses
    made, ``refusals``: how many times a collapse was refused, by reason (:data:`REFUSALS`), and whether it
    ``gave_up`` (see ``give_up_above``)."""

    vertices: np.ndarray
    faces: np.ndarray
    rounds: int
    refusals: dict
    gave_up: bool = False


def _quadrics(v: np.ndarray, f: np.ndarray) -> np.ndarray:
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


def _placements(qa: np.ndarray, qb: np.ndarray, pa: np.ndarray, pb: np.ndarray):
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


def _unique_edges(f: np.ndarray, n: int) -> np.ndarray:
    """(E, 2) the undirected edges of faces f (vertex ids below n), each once, (a < b), sorted."""
    e = face_edges(f)
    keys = np.unique(np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1]))
    return np.column_stack([keys // n, keys % n])


def _csr(source: np.ndarray, target: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(start (n + 1,), items) listing target[k] under source[k]."""
    order = np.argsort(source, kind="stable")
    start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(source, minlength=n), out=start[1:])
    return start, target[order]


def _expand(start: np.ndarray, items: np.ndarray, owners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each owner o, the items start[o]:start[o+1]: (which owner (by position in owners), item)."""
    counts = start[owners + 1] - start[owners]
    which = np.repeat(np.arange(len(owners)), counts)
    offset = np.arange(len(which)) - np.repeat(np.cumsum(counts) - counts, counts)
    return which, items[start[owners][which] + offset]


def _contains(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Which keys are in the sorted array."""
    if len(sorted_keys) == 0:
        return np.zeros(len(keys), dtype=bool)
    pos = np.minimum(np.searchsorted(sorted_keys, keys), len(sorted_keys) - 1)
    return sorted_keys[pos] == keys


def _link_condition(edges, nbr_start, nbr, n) -> np.ndarray:
    """Edges whose ends share exactly two neighbours, neither of valence 3: collapsing them keeps the surface a
    manifold (and never flattens a tetrahedron)."""
    keys = edges[:, 0] * n + edges[:, 1]
    valence = np.diff(nbr_start)
    which, c = _expand(nbr_start, nbr, edges[:, 0])
    b = edges[which, 1]
    common = (c != b) & _contains(keys, np.minimum(b, c) * n + np.maximum(b, c))
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


def _apart(v, f, vf_start, vf, a, b, x, device) -> np.ndarray:
    """Of collapses checked one by one against the surface as it was (fans sharing no vertex, in priority order),
    those to make together: where the new faces of two cross, the later one waits for a later round. Only
    collapses whose new faces' boxes overlap another's are tested."""
    k = len(a)
    which, face = _expand(vf_start, vf, np.concatenate([a, b]))
    which %= k
    faces = f[face]
    keep = ~((faces == a[which][:, None]).any(axis=1) & (faces == b[which][:, None]).any(axis=1))
    which, faces = which[keep], faces[keep]
    moved = v.copy()
    moved[a] = x
    relabel = np.arange(len(v))
    relabel[b] = a
    faces = relabel[faces]
    corners = moved[faces]
    lower = np.full((k, 3), np.inf)
    upper = np.full((k, 3), -np.inf)
    np.minimum.at(lower, which, corners.min(axis=1))
    np.maximum.at(upper, which, corners.max(axis=1))
    overlap = ((lower[:, None] <= upper[None]) & (lower[None] <= upper[:, None])).all(axis=2)
    np.fill_diagonal(overlap, False)
    kept = np.ones(k, dtype=bool)
    near = overlap.any(axis=1)[which]
    if not near.any():
        return kept
    which, faces = which[near], faces[near]
    used, faces = np.unique(faces, return_inverse=True)
    pairs = crossing_faces(moved[used], faces.reshape(-1, 3), device=device)
    first, second = which[pairs[:, 0]], which[pairs[:, 1]]
    kept[np.maximum(first, second)[first != second]] = False
    return kept


def _round_candidates(edges, keys, cost, eligible, nbr_start, nbr, n, most) -> np.ndarray:
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
    which, ring = _expand(nbr_start, nbr, np.concatenate([edges[chosen, 0], edges[chosen, 1]]))
    which %= len(chosen)
    return chosen[_disjoint_fans(which, ring, len(chosen), n)][:most]


def _refuse(refused_keys, refused_at, new_keys, rounds):
    """The sorted refused edge keys and the round of each refusal, with ``new_keys`` refused at ``rounds`` (an
    edge refused again keeps only its latest round)."""
    new_keys = np.unique(new_keys)  # sorted, for the lookup below
    keep = ~_contains(new_keys, refused_keys)
    refused_keys = np.concatenate([refused_keys[keep], new_keys])
    refused_at = np.concatenate([refused_at[keep], np.full(len(new_keys), rounds)])
    order = np.argsort(refused_keys)
    return refused_keys[order], refused_at[order]


def _stalled(left, give_up_above) -> bool:
    """Whether, at the pace of the last :data:`STALL_WINDOW` rounds (``left``: the vertices after each round), coming
    down to ``give_up_above`` would take more than :data:`STALL_ROUNDS` rounds."""
    to_go = left[-1] - give_up_above
    return len(left) > STALL_WINDOW and to_go > 0 and (
        (left[-1 - STALL_WINDOW] - left[-1]) * STALL_ROUNDS < to_go * STALL_WINDOW)


def simplify_enclosing(vertices: np.ndarray, faces: np.ndarray, handles: int, points: np.ndarray, margin: float,
                       device=None, give_up_above: int | None = None) -> Simplified:
    """Collapse edges of a closed, oriented, manifold surface until it has ``handles`` vertices, keeping it valid
    and ``points`` inside it at least ``margin`` from it.

    Parameters
    ----------
    vertices : (V, 3) float array
    faces : (F, 3) int array, a closed, consistently oriented, manifold surface that does not cross itself and has
        every point inside it at least ``margin`` from it
    handles : int, the vertex count to reach
    points : (P, 3) float array, the points to keep inside (a mesh's vertices)
    margin : float, the smallest distance allowed between a point and the surface
    device : None | str, the Warp device of the collapse checks (default: CUDA when present, else the CPU)
    give_up_above : int, optional
        For a caller with a larger offset to try: stop early (``gave_up``) when, at the pace of the last
        :data:`STALL_WINDOW` rounds, coming down to this count would take more than :data:`STALL_ROUNDS` rounds.
        Default: go on while any collapse is valid.

    Returns
    -------
    Simplified
        With ``len(vertices) > handles`` when no valid collapse was left (or it gave up).

    Examples
    --------
    >>> from warp_stokes.geometry.shapes import latitude_longitude_sphere
    >>> v, f = latitude_longitude_sphere(12, 16, radius=1.0)
    >>> s = simplify_enclosing(v, f, 40, np.zeros((1, 3)), margin=0.5)
    >>> len(s.vertices), len(s.faces)
    (40, 76)
    """
    import warp as wp

    from ..device import Backend
    from ..kernels import collapse

    v = np.array(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(v)
    q = _quadrics(v, f)
    alive = np.zeros(n, dtype=bool)
    alive[np.unique(f)] = True
    changed_at = np.full(n, -1, dtype=np.int64)   # the round when a vertex's fan last changed
    moved_at = np.full(n, -1, dtype=np.int64)     # the round when a vertex last moved (collapsed to)
    cached_keys = np.zeros(0, dtype=np.int64)      # last round's placements of its eligible edges, by key
    cached_place, cached_costs = np.zeros((0, 4, 3)), np.zeros((0, 4))
    refused_keys = np.zeros(0, dtype=np.int64)     # edges refused, and when: tried again once their fan changes
    refused_at = np.zeros(0, dtype=np.int64)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    pad = 1e-6 * np.linalg.norm(v.max(axis=0) - v.min(axis=0))
    device = Backend.of(device).device
    rounds = 0
    reasons = np.zeros(8, dtype=np.int64)
    left, gave_up = [], False  # the surviving vertices after each round
    ahead = 0  # candidates to check ahead: none until a round makes no collapse
    cos_flip, cos_fold = np.cos(np.radians(FLIP_DEGREES)), np.cos(np.radians(MAX_FOLD_DEGREES))
    sin_angle = np.sin(np.radians(MIN_ANGLE_DEGREES))
    with wp.ScopedDevice(device):
        rel = (points - centre).astype(np.float32)
        points_bvh = wp.Bvh(wp.array(rel - pad, dtype=wp.vec3), wp.array(rel + pad, dtype=wp.vec3))
        points_d = wp.array(points, dtype=wp.vec3d)
        while alive.sum() > handles:
            if alive.sum() < n // 2:  # renumber the survivors: the arrays of every round are as long as n
                keep = np.flatnonzero(alive)
                remap = np.full(n, -1, dtype=np.int64)
                remap[keep] = np.arange(len(keep))
                ra, rb = remap[refused_keys // n], remap[refused_keys % n]
                live = (ra >= 0) & (rb >= 0)
                n = len(keep)
                refused_keys, refused_at = np.minimum(ra, rb)[live] * n + np.maximum(ra, rb)[live], refused_at[live]
                order = np.argsort(refused_keys)
                refused_keys, refused_at = refused_keys[order], refused_at[order]
                v, q, changed_at, moved_at, f = v[keep], q[keep], changed_at[keep], moved_at[keep], remap[f]
                cached_keys = cached_keys[:0]  # keys are vertex numbers: renumbered
                alive = np.ones(n, dtype=bool)
            edges = _unique_edges(f, n)
            keys = edges[:, 0] * n + edges[:, 1]
            src = np.concatenate([edges[:, 0], edges[:, 1]])
            dst = np.concatenate([edges[:, 1], edges[:, 0]])
            nbr_start, nbr = _csr(src, dst, n)
            eligible = _link_condition(edges, nbr_start, nbr, n)
            seen = _contains(refused_keys, keys)
            if seen.any():
                when = refused_at[np.searchsorted(refused_keys, keys[seen])]
                eligible[seen] &= np.maximum(changed_at[edges[seen, 0]], changed_at[edges[seen, 1]]) > when
            if not eligible.any():
                break
            index = np.flatnonzero(eligible)
            place = np.empty((len(edges), 4, 3))
            costs = np.empty((len(edges), 4))
            # an edge's placements change only when an end moved (its quadric with it): the others are last round's
            hit = _contains(cached_keys, keys[index]) & (moved_at[edges[index, 0]] < rounds) & (
                moved_at[edges[index, 1]] < rounds)
            at = np.searchsorted(cached_keys, keys[index[hit]])
            place[index[hit]], costs[index[hit]] = cached_place[at], cached_costs[at]
            fresh = index[~hit]
            ea, eb = edges[fresh, 0], edges[fresh, 1]
            place[fresh], costs[fresh] = _placements(q[ea], q[eb], v[ea], v[eb])
            cached_keys, cached_place, cached_costs = keys[index], place[index], costs[index]
            # this round's candidates, and while nothing is being made, the next rounds' as if all were refused
            plan, count = [], 0
            while eligible.any():
                chosen = _round_candidates(edges, keys, costs[:, 0], eligible, nbr_start, nbr, n,
                                           int(alive.sum()) - handles)
                if len(chosen) == 0:
                    break
                plan.append(chosen)
                count += len(chosen)
                if count >= ahead:
                    break
                eligible[chosen] = False  # a refused edge waits until its fan changes
            if not plan:
                break
            candidates = np.concatenate(plan)
            vf_start, vf = _csr(f.ravel(), np.repeat(np.arange(len(f)), 3), n)
            rel_v = (v - centre).astype(np.float32)
            surface = wp.Mesh(points=wp.array(rel_v, dtype=wp.vec3), indices=wp.array(f.astype(np.int32).ravel(),
                                                                                       dtype=wp.int32))
            choice_out = wp.empty(len(candidates), dtype=wp.int32)
            reason_out = wp.empty(len(candidates), dtype=wp.int32)
            wp.launch(collapse.collapse_choice, dim=len(candidates),
                      inputs=[wp.array(v, dtype=wp.vec3d), wp.array(f.astype(np.int32), dtype=wp.vec3i),
                              wp.array(vf_start.astype(np.int32), dtype=wp.int32),
                              wp.array(vf.astype(np.int32), dtype=wp.int32),
                              wp.array(edges[candidates, 0].astype(np.int32), dtype=wp.int32),
                              wp.array(edges[candidates, 1].astype(np.int32), dtype=wp.int32),
                              wp.array(np.ascontiguousarray(place[candidates]), dtype=wp.vec3d), surface.id,
                              wp.vec3d(*centre), points_bvh.id, points_d, float(margin), float(cos_flip),
                              float(cos_fold), float(sin_angle)],
                      outputs=[choice_out, reason_out], block_dim=COLLAPSE_BLOCK)
            all_choices, all_reasons = choice_out.numpy(), reason_out.numpy()
            start = 0
            for walked, chosen in enumerate(plan):  # in order, up to the first round where a collapse passed
                choice, reason = all_choices[start:start + len(chosen)], all_reasons[start:start + len(chosen)]
                start += len(chosen)
                rounds += 1
                reasons += np.bincount(reason[choice < 0], minlength=8)
                a, b = edges[chosen, 0], edges[chosen, 1]
                passed = np.flatnonzero(choice >= 0)
                made = passed[:0]
                if len(passed):
                    made = passed[_apart(v, f, vf_start, vf, a[passed], b[passed],
                                         place[chosen[passed], choice[passed]], device)]
                no = choice < 0
                if no.any():
                    refused_keys, refused_at = _refuse(refused_keys, refused_at, keys[chosen[no]], rounds)
                if len(made):
                    a, b, x = a[made], b[made], place[chosen[made], choice[made]]
                    v[a] = x
                    q[a] += q[b]
                    relabel = np.arange(n)
                    relabel[b] = a
                    f = relabel[f]
                    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
                    alive[b] = False
                    _, touched = _expand(nbr_start, nbr, np.concatenate([a, b]))
                    changed_at[touched] = rounds
                    changed_at[a] = rounds
                    moved_at[a] = rounds  # the next round recomputes the placements of the edges at a
                if give_up_above is not None:
                    left.append(int(alive.sum()))
                    gave_up = _stalled(left, give_up_above)
                if gave_up or len(passed):
                    break
            if gave_up:
                break
            # how many candidates the next launch works out ahead: its size only, never its outcome
            ahead = 0 if len(made) else min(max(2 * ahead, AHEAD_CANDIDATES), AHEAD_MOST)
            if walked:  # the placements kept for the next round: of its eligible edges, as one round at a time
                held = ~_contains(np.sort(keys[np.concatenate(plan[:walked])]), cached_keys)
                cached_keys, cached_place, cached_costs = cached_keys[held], cached_place[held], cached_costs[held]
    keep = np.flatnonzero(alive)
    remap = np.full(n, -1, dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    refusals = {why: int(reasons[code]) for code, why in REFUSALS.items() if reasons[code]}
    return Simplified(vertices=v[keep], faces=remap[f], rounds=rounds, refusals=refusals, gave_up=gave_up)
