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
from .collapse_candidates import (csr, csr_rows, edge_placements, in_sorted, link_condition, round_candidates,
                                  unique_edges, vertex_quadrics)

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
#: still need. Near its end a surface makes a collapse every 10-100 rounds, or none, for thousands of rounds. The
#: limits are wide enough that no try that reached the count, over the test meshes and counts, would have given up
#: (at half STALL_ROUNDS some would have), so the cages made are the same; a try that cannot reach the count stops
#: early, which roughly halves the time of the coarsest cages
STALL_WINDOW = 128
STALL_ROUNDS = 1000
#: after a round that made no collapse, the next rounds are worked out ahead as if each refused all it tried (as
#: nearly all do there), and their candidates checked in one launch: at least AHEAD_CANDIDATES, twice as many after
#: each launch where none passed, up to AHEAD_MOST. The rounds are then taken in order up to the first where one
#: passed: the same collapses, refusals and rounds as one round at a time, without each round's edges, placements
#: and BVH (at a small offset, thousands of rounds that make almost nothing were most of a make's time)
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


def _apart(v, f, vf_start, vf, a, b, x, device) -> np.ndarray:
    """Of collapses checked one by one against the surface as it was (fans sharing no vertex, in priority order),
    those to make together: where the new faces of two cross, the later one waits for a later round. Only
    collapses whose new faces' boxes overlap another's are tested."""
    k = len(a)
    which, face = csr_rows(vf_start, vf, np.concatenate([a, b]))
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


def _refuse(refused_keys, refused_at, new_keys, rounds):
    """The sorted refused edge keys and the round of each refusal, with ``new_keys`` refused at ``rounds`` (an
    edge refused again keeps only its latest round)."""
    new_keys = np.unique(new_keys)  # sorted, for the lookup below
    keep = ~in_sorted(new_keys, refused_keys)
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


class _Collapses:
    """The rounds of :func:`simplify_enclosing`: the surface as collapsed so far and what one round leaves the next,
    with a method per step (:meth:`launch` takes one launch's rounds through them).

    Attributes
    ----------
    handles, points, margin, give_up_above : as :func:`simplify_enclosing` takes them
    centre, pad, device, points_bvh, points_d : the surface's box centre (the device's positions are relative to
        it) and a tiny pad; the points to keep inside on the device (:meth:`enclose`)
    v, f, q : (n, 3) positions, (F, 3) faces and (n, 4, 4) quadrics of the surface so far; ``n`` shrinks when the
        survivors are renumbered
    alive : (n,) bool, the vertices still on the surface
    changed_at, moved_at : (n,) int, the round when a vertex's fan last changed, and when it last moved (collapsed to)
    refused_keys, refused_at : the edges refused (sorted keys) and when: tried again once their fan changes
    cached_keys, cached_place, cached_costs : last round's placements of its eligible edges, by key
    rounds, reasons, left, gave_up : the rounds made, the refusals by reason code, the vertices left after each
        round (with ``give_up_above``) and whether it gave up
    ahead : how many candidates the next launch works out ahead: none until a round makes no collapse
    edges, keys, nbr_start, nbr, place, costs, vf_start, vf : of the launch under way: the edges, their keys, each
        vertex's neighbours (CSR), the edges' placements and their costs, each vertex's faces (CSR)
    """

    def __init__(self, vertices, faces, handles, points, margin, give_up_above):
        self.v = np.array(vertices, dtype=np.float64)
        self.f = np.asarray(faces, dtype=np.int64)
        self.points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        self.handles, self.margin, self.give_up_above = handles, margin, give_up_above
        self.n = n = len(self.v)
        self.q = vertex_quadrics(self.v, self.f)
        self.alive = np.zeros(n, dtype=bool)
        self.alive[np.unique(self.f)] = True
        self.changed_at = np.full(n, -1, dtype=np.int64)
        self.moved_at = np.full(n, -1, dtype=np.int64)
        self.cached_keys = np.zeros(0, dtype=np.int64)
        self.cached_place, self.cached_costs = np.zeros((0, 4, 3)), np.zeros((0, 4))
        self.refused_keys = np.zeros(0, dtype=np.int64)
        self.refused_at = np.zeros(0, dtype=np.int64)
        self.centre = 0.5 * (self.v.min(axis=0) + self.v.max(axis=0))
        self.pad = 1e-6 * np.linalg.norm(self.v.max(axis=0) - self.v.min(axis=0))
        self.rounds = 0
        self.reasons = np.zeros(8, dtype=np.int64)
        self.left, self.gave_up = [], False
        self.ahead = 0

    def enclose(self, device) -> None:
        """The points to keep inside on ``device`` (the current Warp device): their positions, and a BVH of tiny
        boxes about them relative to the centre."""
        import warp as wp

        self.device = device
        rel = (self.points - self.centre).astype(np.float32)
        self.points_bvh = wp.Bvh(wp.array(rel - self.pad, dtype=wp.vec3), wp.array(rel + self.pad, dtype=wp.vec3))
        self.points_d = wp.array(self.points, dtype=wp.vec3d)

    def launch(self) -> bool:
        """One launch of the collapse checks and the rounds it decides; whether there may be more to make."""
        if self.alive.sum() < self.n // 2:  # the arrays of every round are as long as n
            self.renumber()
        eligible = self.eligible_edges()
        if not eligible.any():
            return False
        self.placements(eligible)
        plan = self.plan(eligible)
        if not plan:
            return False
        choices, reasons = self.check(np.concatenate(plan))
        walked, made = self.walk(plan, choices, reasons)
        if self.gave_up:
            return False
        # how many candidates the next launch works out ahead: its size only, never its outcome
        self.ahead = 0 if len(made) else min(max(2 * self.ahead, AHEAD_CANDIDATES), AHEAD_MOST)
        if walked:  # the placements kept for the next round: of its eligible edges, as one round at a time
            held = ~in_sorted(np.sort(self.keys[np.concatenate(plan[:walked])]), self.cached_keys)
            self.cached_keys, self.cached_place = self.cached_keys[held], self.cached_place[held]
            self.cached_costs = self.cached_costs[held]
        return True

    def renumber(self) -> None:
        """Number the surviving vertices 0 to n - 1, in order."""
        n = self.n
        keep = np.flatnonzero(self.alive)
        remap = np.full(n, -1, dtype=np.int64)
        remap[keep] = np.arange(len(keep))
        ra, rb = remap[self.refused_keys // n], remap[self.refused_keys % n]
        live = (ra >= 0) & (rb >= 0)
        self.n = n = len(keep)
        refused_keys, refused_at = np.minimum(ra, rb)[live] * n + np.maximum(ra, rb)[live], self.refused_at[live]
        order = np.argsort(refused_keys)
        self.refused_keys, self.refused_at = refused_keys[order], refused_at[order]
        self.v, self.q, self.f = self.v[keep], self.q[keep], remap[self.f]
        self.changed_at, self.moved_at = self.changed_at[keep], self.moved_at[keep]
        self.cached_keys = self.cached_keys[:0]  # keys are vertex numbers: renumbered
        self.alive = np.ones(n, dtype=bool)

    def eligible_edges(self) -> np.ndarray:
        """The surface's edges now (``edges``, ``keys``, neighbours), and which may collapse: those that keep it a
        manifold, not refused since their fan last changed."""
        n, changed_at = self.n, self.changed_at
        self.edges = edges = unique_edges(self.f, n)
        self.keys = edges[:, 0] * n + edges[:, 1]
        src = np.concatenate([edges[:, 0], edges[:, 1]])
        dst = np.concatenate([edges[:, 1], edges[:, 0]])
        self.nbr_start, self.nbr = csr(src, dst, n)
        eligible = link_condition(edges, self.nbr_start, self.nbr, n)
        seen = in_sorted(self.refused_keys, self.keys)
        if seen.any():
            when = self.refused_at[np.searchsorted(self.refused_keys, self.keys[seen])]
            eligible[seen] &= np.maximum(changed_at[edges[seen, 0]], changed_at[edges[seen, 1]]) > when
        return eligible

    def placements(self, eligible: np.ndarray) -> None:
        """``place`` and ``costs`` of the eligible edges (:func:`edge_placements`), kept for the next round."""
        edges, keys, index = self.edges, self.keys, np.flatnonzero(eligible)
        place = np.empty((len(edges), 4, 3))
        costs = np.empty((len(edges), 4))
        # an edge's placements change only when an end moved (its quadric with it): the others are last round's
        hit = in_sorted(self.cached_keys, keys[index]) & (self.moved_at[edges[index, 0]] < self.rounds) & (
            self.moved_at[edges[index, 1]] < self.rounds)
        at = np.searchsorted(self.cached_keys, keys[index[hit]])
        place[index[hit]], costs[index[hit]] = self.cached_place[at], self.cached_costs[at]
        fresh = index[~hit]
        ea, eb = edges[fresh, 0], edges[fresh, 1]
        place[fresh], costs[fresh] = edge_placements(self.q[ea], self.q[eb], self.v[ea], self.v[eb])
        self.cached_keys, self.cached_place, self.cached_costs = keys[index], place[index], costs[index]
        self.place, self.costs = place, costs

    def plan(self, eligible: np.ndarray) -> list:
        """This round's candidates, and while nothing is being made (``ahead``), the next rounds' as if all were
        refused: a list of the rounds' edges."""
        plan, count = [], 0
        while eligible.any():
            chosen = round_candidates(self.edges, self.keys, self.costs[:, 0], eligible, self.nbr_start, self.nbr,
                                       self.n, int(self.alive.sum()) - self.handles)
            if len(chosen) == 0:
                break
            plan.append(chosen)
            count += len(chosen)
            if count >= self.ahead:
                break
            eligible[chosen] = False  # a refused edge waits until its fan changes
        return plan

    def check(self, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The collapse checks of the candidate edges in one launch: (choice, reason) per candidate, the placement
        taken or -1 with the reason refused (:data:`REFUSALS`)."""
        import warp as wp

        from ..kernels import collapse

        edges, v, f = self.edges, self.v, self.f
        self.vf_start, self.vf = csr(f.ravel(), np.repeat(np.arange(len(f)), 3), self.n)
        cos_flip, cos_fold = np.cos(np.radians(FLIP_DEGREES)), np.cos(np.radians(MAX_FOLD_DEGREES))
        sin_angle = np.sin(np.radians(MIN_ANGLE_DEGREES))
        rel_v = (v - self.centre).astype(np.float32)
        surface = wp.Mesh(points=wp.array(rel_v, dtype=wp.vec3), indices=wp.array(f.astype(np.int32).ravel(),
                                                                                   dtype=wp.int32))
        choice_out = wp.empty(len(candidates), dtype=wp.int32)
        reason_out = wp.empty(len(candidates), dtype=wp.int32)
        wp.launch(collapse.collapse_choice, dim=len(candidates),
                  inputs=[wp.array(v, dtype=wp.vec3d), wp.array(f.astype(np.int32), dtype=wp.vec3i),
                          wp.array(self.vf_start.astype(np.int32), dtype=wp.int32),
                          wp.array(self.vf.astype(np.int32), dtype=wp.int32),
                          wp.array(edges[candidates, 0].astype(np.int32), dtype=wp.int32),
                          wp.array(edges[candidates, 1].astype(np.int32), dtype=wp.int32),
                          wp.array(np.ascontiguousarray(self.place[candidates]), dtype=wp.vec3d), surface.id,
                          wp.vec3d(*self.centre), self.points_bvh.id, self.points_d, float(self.margin),
                          float(cos_flip), float(cos_fold), float(sin_angle)],
                  outputs=[choice_out, reason_out], block_dim=COLLAPSE_BLOCK)
        return choice_out.numpy(), reason_out.numpy()

    def walk(self, plan: list, choices: np.ndarray, reasons: np.ndarray) -> tuple[int, np.ndarray]:
        """The planned rounds in order, up to the first where a collapse passed (or it gave up): (the index of the
        last round walked, the collapses it made, by position in its edges)."""
        start = 0
        for walked, chosen in enumerate(plan):
            choice, reason = choices[start:start + len(chosen)], reasons[start:start + len(chosen)]
            start += len(chosen)
            self.rounds += 1
            self.reasons += np.bincount(reason[choice < 0], minlength=8)
            made = self.settle(chosen, choice)
            if self.give_up_above is not None:
                self.left.append(int(self.alive.sum()))
                self.gave_up = _stalled(self.left, self.give_up_above)
            if self.gave_up or (choice >= 0).any():
                break
        return walked, made

    def settle(self, chosen: np.ndarray, choice: np.ndarray) -> np.ndarray:
        """One round's outcome: the refused edges noted, the passed collapses whose new faces cross none of the
        others' made (:func:`_apart`). Returns those made, by position in ``chosen``."""
        a, b = self.edges[chosen, 0], self.edges[chosen, 1]
        passed = np.flatnonzero(choice >= 0)
        made = passed[:0]
        if len(passed):
            made = passed[_apart(self.v, self.f, self.vf_start, self.vf, a[passed], b[passed],
                                 self.place[chosen[passed], choice[passed]], self.device)]
        no = choice < 0
        if no.any():
            self.refused_keys, self.refused_at = _refuse(self.refused_keys, self.refused_at, self.keys[chosen[no]],
                                                         self.rounds)
        if len(made):
            self.collapse(a[made], b[made], self.place[chosen[made], choice[made]])
        return made

    def collapse(self, a: np.ndarray, b: np.ndarray, x: np.ndarray) -> None:
        """Collapse edges (a, b) (fans sharing no vertex) to a, moved to x."""
        self.v[a] = x
        self.q[a] += self.q[b]
        relabel = np.arange(self.n)
        relabel[b] = a
        f = relabel[self.f]
        self.f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
        self.alive[b] = False
        _, touched = csr_rows(self.nbr_start, self.nbr, np.concatenate([a, b]))
        self.changed_at[touched] = self.rounds
        self.changed_at[a] = self.rounds
        self.moved_at[a] = self.rounds  # the next round recomputes the placements of the edges at a

    def simplified(self) -> Simplified:
        """The surface as it is now, its vertices renumbered."""
        keep = np.flatnonzero(self.alive)
        remap = np.full(self.n, -1, dtype=np.int64)
        remap[keep] = np.arange(len(keep))
        refusals = {why: int(self.reasons[code]) for code, why in REFUSALS.items() if self.reasons[code]}
        return Simplified(vertices=self.v[keep], faces=remap[self.f], rounds=self.rounds, refusals=refusals,
                          gave_up=self.gave_up)


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
    >>> import trimesh
    >>> sphere = trimesh.creation.icosphere(subdivisions=2)
    >>> s = simplify_enclosing(sphere.vertices, sphere.faces, 40, np.zeros((1, 3)), margin=0.5)
    >>> len(s.vertices), len(s.faces)
    (40, 76)
    """
    import warp as wp

    from ..device import Backend

    collapses = _Collapses(vertices, faces, handles, points, margin, give_up_above)
    device = Backend.of(device).device
    with wp.ScopedDevice(device):
        collapses.enclose(device)
        while collapses.alive.sum() > handles:
            if not collapses.launch():
                break
    return collapses.simplified()
