"""The compact second-order 19-point coupled scheme for the biharmonic equation (Altas et al.).

Per node the unknowns are the value q and the scaled gradient G = h grad q, packed as vec4 (q, Gx, Gy, Gz).
Fields are 2D arrays (node row, handle) with the handles innermost, so that the threads of one node read
consecutive handles (coalesced). `index[i, j, k]` maps a grid node to its row (-1 when inactive); interior
nodes come first, so row n < n_interior is interior node n.

    value eq:    48 q_p - 10 sum_face q + sum_edge q + 3 sum_a (G_a(p+e_a) - G_a(p-e_a)) = (h^4/2) f_p
    gradient eq: G_a(p-e_a) + 4 G_a(p) + G_a(p+e_a) - 3 (q(p+e_a) - q(p-e_a))   = 0
"""

import warp as wp


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
def node_value(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
               k: int, handle: int):
    """The packed (q, G) of a node, zero where the node has no row below `n_rows`."""
    row = index[i, j, k]
    if row >= 0 and row < n_rows:
        return field[row, handle]
    return wp.vec4f()


@wp.func
def load_plane(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
               k: int, handle: int):
    p = Plane()
    p.centre = node_value(field, index, n_rows, i, j, k, handle)
    p.xp = node_value(field, index, n_rows, i + 1, j, k, handle)
    p.xm = node_value(field, index, n_rows, i - 1, j, k, handle)
    p.yp = node_value(field, index, n_rows, i, j + 1, k, handle)
    p.ym = node_value(field, index, n_rows, i, j - 1, k, handle)
    p.corners = wp.vec4f(
        node_value(field, index, n_rows, i + 1, j + 1, k, handle)[0],
        node_value(field, index, n_rows, i + 1, j - 1, k, handle)[0],
        node_value(field, index, n_rows, i - 1, j + 1, k, handle)[0],
        node_value(field, index, n_rows, i - 1, j - 1, k, handle)[0],
    )
    return p


#: handles per thread group (one warp's worth): the launch is (ceil(handles / GROUP), lines, GROUP)
GROUP = 32


def operator_kernel(scalar):
    """The batched operator with sums in `scalar` (wp.float32 or wp.float64).

    Residuals of a nearly converged float32 field cancel to ~1e-7 of their terms: a float32 sum would stall
    the solver there, so residuals use float64 sums. Krylov and smoothing applications only need float32.

    One thread walks a run of consecutive interior nodes along z (a "line", rows start .. start + length - 1)
    for one handle, keeping the planes below, at and above the current node in registers: each step loads
    one new plane (9 neighbours) instead of the 18 neighbours of the node: neighbours are shared through
    registers rather than re-read from cache, which is what limited the one-thread-per-node form (31-35% of
    the copy bandwidth on an H100 against 44-57% for this one with float32 sums, benchmarks/RESULTS.md)."""
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
        # out = A field at the interior nodes; launch (handle groups, lines, GROUP). Rows of `field` at or
        # beyond `n_rows` read as zero: with n_rows = n_interior this is the interior block A_II (Krylov
        # vectors); with all active rows it includes the known ring data (residuals).
        # Handles are innermost so a warp reads 32 consecutive handles of one row (512 coalesced bytes), and
        # the group is outermost so the warps of a block walk neighbouring lines for the same handles: the
        # y neighbours one warp loads are the rows its neighbour warps load, still in L1.
        g, s, lane = wp.tid()
        h = g * GROUP + lane
        if h < out.shape[1]:
            walk_line(field, index, interior_ijk, lines[s], n_rows, h, out)

    return apply_operator


#: residuals (float64 sums)
apply_operator = operator_kernel(wp.float64)
#: Krylov and smoothing applications (float32 sums)
apply_operator_fast = operator_kernel(wp.float32)


@wp.kernel
def pack_nodal_field(
    values: wp.array2d(dtype=wp.float64),
    active_ijk: wp.array(dtype=wp.vec3i),
    index: wp.array3d(dtype=wp.int32),
    n_with_gradient: int,
    field: wp.array2d(dtype=wp.vec4f),
):
    """field[n] = (q, G) from nodal values q: G_a = (q(p+e_a) - q(p-e_a)) / 2, the central difference of
    step h, exact for linear functions. Rows at or beyond `n_with_gradient` (the band) get G = 0: they are
    only ever sampled for q."""
    n, h = wp.tid()
    q = values[n, h]
    g = wp.vec3d()
    if n < n_with_gradient:
        c = active_ijk[n]
        for a in range(3):
            e = wp.vec3i(0, 0, 0)
            e[a] = 1
            up = c + e
            down = c - e
            g[a] = wp.float64(0.5) * (
                values[index[up[0], up[1], up[2]], h] - values[index[down[0], down[1], down[2]], h]
            )
    field[n, h] = wp.vec4f(wp.float32(q), wp.float32(g[0]), wp.float32(g[1]), wp.float32(g[2]))
