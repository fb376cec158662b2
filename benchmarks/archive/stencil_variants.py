"""Earlier forms of the stencil for bench_stencil.py and stencil_experiments.py (same layout as the package).

lines  the package's kernel in sessions 2-3: one thread walks a z line of consecutive interior nodes (rows
       start .. start + length - 1) for one handle, keeping three whole planes (9 loads each) in registers
lean   the line walk with only the components each neighbour contributes kept per plane
       (16 floats instead of 24): fewer registers, the same loads
pairs  one thread walks two neighbouring columns (i, j0) and (i, j0 + 1) for one handle: a plane is 12
       loads for 2 nodes instead of 9 for 1
"""

import numpy as np
import warp as wp

from warp_stokes.kernels.stencil import node_value as value_at


@wp.struct
class Plane:
    """What the stencil reads in one z plane around a column (i, j): (q, G) at the column and its four face
    neighbours, and q at the four diagonal neighbours (+x+y, +x-y, -x+y, -x-y)."""

    centre: wp.vec4f
    xp: wp.vec4f
    xm: wp.vec4f
    yp: wp.vec4f
    ym: wp.vec4f
    corners: wp.vec4f


@wp.func
def load_plane(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
               k: int, handle: int):
    p = Plane()
    p.centre = value_at(field, index, n_rows, i, j, k, handle)
    p.xp = value_at(field, index, n_rows, i + 1, j, k, handle)
    p.xm = value_at(field, index, n_rows, i - 1, j, k, handle)
    p.yp = value_at(field, index, n_rows, i, j + 1, k, handle)
    p.ym = value_at(field, index, n_rows, i, j - 1, k, handle)
    p.corners = wp.vec4f(
        value_at(field, index, n_rows, i + 1, j + 1, k, handle)[0],
        value_at(field, index, n_rows, i + 1, j - 1, k, handle)[0],
        value_at(field, index, n_rows, i - 1, j + 1, k, handle)[0],
        value_at(field, index, n_rows, i - 1, j - 1, k, handle)[0],
    )
    return p


def line_kernel(scalar):
    """The package's operator in sessions 2-3, with sums in `scalar` (wp.float32 or wp.float64).

    One thread walks a run of consecutive interior nodes along z (a "line", rows start .. start + length - 1)
    for one handle, keeping the planes below, at and above the current node in registers: each step loads
    one new plane (9 neighbours) instead of the 18 neighbours of the node: neighbours are shared through
    registers rather than re-read from cache, which is what limited the one-thread-per-node form (31-35% of
    the copy bandwidth on an H100 against 44-57% for this one with float32 sums, benchmarks/HISTORY.md)."""
    vec4 = wp.types.vector(length=4, dtype=scalar)

    @wp.func
    def combine(below: Plane, mid: Plane, above: Plane):
        c = vec4(mid.centre)
        xp = vec4(mid.xp)
        xm = vec4(mid.xm)
        yp = vec4(mid.yp)
        ym = vec4(mid.ym)
        zp = vec4(above.centre)
        zm = vec4(below.centre)
        corners = vec4(mid.corners)
        edges = (corners[0] + corners[1]) + (corners[2] + corners[3])
        edges += (scalar(above.xp[0]) + scalar(above.xm[0])) + (scalar(above.yp[0]) + scalar(above.ym[0]))
        edges += (scalar(below.xp[0]) + scalar(below.xm[0])) + (scalar(below.yp[0]) + scalar(below.ym[0]))
        faces = xp[0] + xm[0] + yp[0] + ym[0] + zp[0] + zm[0]
        divergence = (xp[1] - xm[1]) + (yp[2] - ym[2]) + (zp[3] - zm[3])
        three = scalar(3.0)
        four = scalar(4.0)
        value = scalar(48.0) * c[0] - scalar(10.0) * faces + edges + three * divergence
        gx = xm[1] + four * c[1] + xp[1] - three * (xp[0] - xm[0])
        gy = ym[2] + four * c[2] + yp[2] - three * (yp[0] - ym[0])
        gz = zm[3] + four * c[3] + zp[3] - three * (zp[0] - zm[0])
        return wp.vec4f(wp.float32(value), wp.float32(gx), wp.float32(gy), wp.float32(gz))

    @wp.func
    def walk_line(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32),
                  interior_ijk: wp.array(dtype=wp.vec3i), line: wp.vec2i, n_rows: int, h: int,
                  out: wp.array2d(dtype=wp.vec4f)):
        start = line[0]
        c = interior_ijk[start]
        i = c[0]
        j = c[1]
        k = c[2]
        below = load_plane(field, index, n_rows, i, j, k - 1, h)
        mid = load_plane(field, index, n_rows, i, j, k, h)
        for t in range(line[1]):
            above = load_plane(field, index, n_rows, i, j, k + t + 1, h)
            out[start + t, h] = combine(below, mid, above)
            below = mid
            mid = above

    @wp.kernel(module="unique")
    def apply_operator(
        field: wp.array2d(dtype=wp.vec4f),
        index: wp.array3d(dtype=wp.int32),
        interior_ijk: wp.array(dtype=wp.vec3i),
        lines: wp.array(dtype=wp.vec2i),
        n_rows: int,
        out: wp.array2d(dtype=wp.vec4f),
    ):
        # launch (handle groups, lines, 32): the warps of a block walk neighbouring lines for the same handles
        g, s, lane = wp.tid()
        h = g * 32 + lane
        if h < out.shape[1]:
            walk_line(field, index, interior_ijk, lines[s], n_rows, h, out)

    return apply_operator


apply_lines_f64 = line_kernel(wp.float64)
apply_lines = line_kernel(wp.float32)


def interior_lines(grid, max_length=128):
    """Runs of consecutive interior nodes along z as (first row, length), cut at max_length (interior rows are
    numbered with k fastest, so a run's rows are consecutive)."""
    ijk = grid.active_ijk[: grid.n_interior].astype(np.int64)
    new_run = np.ones(len(ijk), dtype=bool)
    new_run[1:] = (ijk[1:, 0] != ijk[:-1, 0]) | (ijk[1:, 1] != ijk[:-1, 1]) | (ijk[1:, 2] != ijk[:-1, 2] + 1)
    starts = np.flatnonzero(new_run)
    ends = np.append(starts[1:], len(ijk))
    pieces = -(-(ends - starts) // max_length)
    first = np.repeat(starts, pieces)
    first += max_length * (np.arange(pieces.sum()) - np.repeat(np.cumsum(pieces) - pieces, pieces))
    lengths = np.minimum(first + max_length, np.repeat(ends, pieces)) - first
    return np.stack([first, lengths], axis=1).astype(np.int32)


@wp.struct
class LeanPlane:
    centre: wp.vec4f
    x: wp.vec4f  # (q, Gx) at i+1, then (q, Gx) at i-1
    y: wp.vec4f  # (q, Gy) at j+1, then (q, Gy) at j-1
    corners: wp.vec4f


@wp.func
def load_lean(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
              k: int, h: int):
    p = LeanPlane()
    p.centre = value_at(field, index, n_rows, i, j, k, h)
    xp = value_at(field, index, n_rows, i + 1, j, k, h)
    xm = value_at(field, index, n_rows, i - 1, j, k, h)
    yp = value_at(field, index, n_rows, i, j + 1, k, h)
    ym = value_at(field, index, n_rows, i, j - 1, k, h)
    p.x = wp.vec4f(xp[0], xp[1], xm[0], xm[1])
    p.y = wp.vec4f(yp[0], yp[2], ym[0], ym[2])
    p.corners = wp.vec4f(value_at(field, index, n_rows, i + 1, j + 1, k, h)[0],
                         value_at(field, index, n_rows, i + 1, j - 1, k, h)[0],
                         value_at(field, index, n_rows, i - 1, j + 1, k, h)[0],
                         value_at(field, index, n_rows, i - 1, j - 1, k, h)[0])
    return p


@wp.func
def node_equations(c: wp.vec4f, xq: wp.vec4f, yq: wp.vec4f, zp: wp.vec2f, zm: wp.vec2f, edges: float):
    """(value, gx, gy, gz) at a node from its centre (q, G), (q, Gx) at x+- (xq), (q, Gy) at y+- (yq),
    (q, Gz) at z+- and the sum of its 12 edge neighbours' q."""
    faces = xq[0] + xq[2] + yq[0] + yq[2] + zp[0] + zm[0]
    divergence = (xq[1] - xq[3]) + (yq[1] - yq[3]) + (zp[1] - zm[1])
    value = 48.0 * c[0] - 10.0 * faces + edges + 3.0 * divergence
    gx = xq[3] + 4.0 * c[1] + xq[1] - 3.0 * (xq[0] - xq[2])
    gy = yq[3] + 4.0 * c[2] + yq[1] - 3.0 * (yq[0] - yq[2])
    gz = zm[1] + 4.0 * c[3] + zp[1] - 3.0 * (zp[0] - zm[0])
    return wp.vec4f(value, gx, gy, gz)


@wp.kernel
def apply_lean(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32),
               interior_ijk: wp.array(dtype=wp.vec3i), lines: wp.array(dtype=wp.vec2i), n_rows: int,
               out: wp.array2d(dtype=wp.vec4f)):
    g, s, lane = wp.tid()
    h = g * 32 + lane
    if h >= out.shape[1]:
        return
    line = lines[s]
    start = line[0]
    c = interior_ijk[start]
    i = c[0]
    j = c[1]
    k = c[2]
    below = load_lean(field, index, n_rows, i, j, k - 1, h)
    mid = load_lean(field, index, n_rows, i, j, k, h)
    for t in range(line[1]):
        above = load_lean(field, index, n_rows, i, j, k + t + 1, h)
        edges = (mid.corners[0] + mid.corners[1]) + (mid.corners[2] + mid.corners[3])
        edges += (above.x[0] + above.x[2]) + (above.y[0] + above.y[2])
        edges += (below.x[0] + below.x[2]) + (below.y[0] + below.y[2])
        out[start + t, h] = node_equations(mid.centre, mid.x, mid.y, wp.vec2f(above.centre[0], above.centre[3]),
                                           wp.vec2f(below.centre[0], below.centre[3]), edges)
        below = mid
        mid = above


@wp.struct
class PairPlane:
    a: wp.vec4f  # (q, G) at (i, j0)
    b: wp.vec4f  # (q, G) at (i, j0 + 1)
    xa: wp.vec4f  # (q, Gx) at (i+1, j0), (i-1, j0)
    xb: wp.vec4f  # (q, Gx) at (i+1, j0+1), (i-1, j0+1)
    ends: wp.vec4f  # (q, Gy) at (i, j0-1), (i, j0+2)
    corners: wp.vec4f  # q at (i+1, j0-1), (i-1, j0-1), (i+1, j0+2), (i-1, j0+2)


@wp.func
def load_pair(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
              k: int, h: int):
    p = PairPlane()
    p.a = value_at(field, index, n_rows, i, j, k, h)
    p.b = value_at(field, index, n_rows, i, j + 1, k, h)
    xpa = value_at(field, index, n_rows, i + 1, j, k, h)
    xma = value_at(field, index, n_rows, i - 1, j, k, h)
    xpb = value_at(field, index, n_rows, i + 1, j + 1, k, h)
    xmb = value_at(field, index, n_rows, i - 1, j + 1, k, h)
    p.xa = wp.vec4f(xpa[0], xpa[1], xma[0], xma[1])
    p.xb = wp.vec4f(xpb[0], xpb[1], xmb[0], xmb[1])
    ym = value_at(field, index, n_rows, i, j - 1, k, h)
    yp = value_at(field, index, n_rows, i, j + 2, k, h)
    p.ends = wp.vec4f(ym[0], ym[2], yp[0], yp[2])
    p.corners = wp.vec4f(value_at(field, index, n_rows, i + 1, j - 1, k, h)[0],
                         value_at(field, index, n_rows, i - 1, j - 1, k, h)[0],
                         value_at(field, index, n_rows, i + 1, j + 2, k, h)[0],
                         value_at(field, index, n_rows, i - 1, j + 2, k, h)[0])
    return p


@wp.kernel
def apply_pairs(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32),
                items: wp.array(dtype=wp.vec4i), n_rows: int, out: wp.array2d(dtype=wp.vec4f)):
    g, s, lane = wp.tid()
    h = g * 32 + lane
    if h >= out.shape[1]:
        return
    item = items[s]
    i = item[0]
    j = item[1]
    k = item[2]
    n_interior = out.shape[0]
    below = load_pair(field, index, n_rows, i, j, k - 1, h)
    mid = load_pair(field, index, n_rows, i, j, k, h)
    for t in range(item[3]):
        above = load_pair(field, index, n_rows, i, j, k + t + 1, h)
        # node A = (i, j0): y+ is B's column, y- the left end; node B: y- is A's column, y+ the right end
        row_a = index[i, j, k + t]
        if row_a >= 0 and row_a < n_interior:
            edges = (mid.xb[0] + mid.xb[2]) + (mid.corners[0] + mid.corners[1])
            edges += (above.xa[0] + above.xa[2]) + (above.b[0] + above.ends[0])
            edges += (below.xa[0] + below.xa[2]) + (below.b[0] + below.ends[0])
            out[row_a, h] = node_equations(mid.a, mid.xa, wp.vec4f(mid.b[0], mid.b[2], mid.ends[0], mid.ends[1]),
                                           wp.vec2f(above.a[0], above.a[3]), wp.vec2f(below.a[0], below.a[3]),
                                           edges)
        row_b = index[i, j + 1, k + t]
        if row_b >= 0 and row_b < n_interior:
            edges = (mid.xa[0] + mid.xa[2]) + (mid.corners[2] + mid.corners[3])
            edges += (above.xb[0] + above.xb[2]) + (above.a[0] + above.ends[2])
            edges += (below.xb[0] + below.xb[2]) + (below.a[0] + below.ends[2])
            out[row_b, h] = node_equations(mid.b, mid.xb, wp.vec4f(mid.ends[2], mid.ends[3], mid.a[0], mid.a[2]),
                                           wp.vec2f(above.b[0], above.b[3]), wp.vec2f(below.b[0], below.b[3]),
                                           edges)
        below = mid
        mid = above


def pair_items(grid, max_length=128):
    """(i, j0, k0, length) runs along z where column j0 = 2m or j0 + 1 has interior nodes, cut at max_length."""
    interior = np.zeros(grid.shape, dtype=bool)
    ijk = grid.active_ijk[: grid.n_interior]
    interior[tuple(ijk.T)] = True
    nx, ny, nz = grid.shape
    if ny % 2:
        interior = np.concatenate([interior, np.zeros((nx, 1, nz), bool)], axis=1)
    either = interior[:, 0::2, :] | interior[:, 1::2, :]
    padded = np.zeros(either.shape[:2] + (nz + 2,), bool)
    padded[:, :, 1:-1] = either
    d = np.diff(padded.astype(np.int8), axis=2)
    si, sj, sk = np.nonzero(d == 1)
    ei, ej, ek = np.nonzero(d == -1)
    lengths = ek - sk
    pieces = -(-lengths // max_length)
    first = np.repeat(sk, pieces) + max_length * (np.arange(pieces.sum()) - np.repeat(np.cumsum(pieces) - pieces, pieces))
    last = np.repeat(ek, pieces)
    return np.stack([np.repeat(si, pieces), 2 * np.repeat(sj, pieces), first, np.minimum(first + max_length, last) - first],
                    axis=1).astype(np.int32)
