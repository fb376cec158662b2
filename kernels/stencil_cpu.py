"""The compact scheme's operator for a CPU: one thread per interior node, looping over the handles.

Warp runs a CPU kernel's threads one after another on one core (NVIDIA/warp#1309). The GPU's patch walk
(``stencil.operator_kernel``: a thread per handle and patch of columns) then repeats each node's index look-ups and
plane reductions for every handle. Here a thread takes its node's 18 neighbour rows from a table formed once per grid
(:func:`neighbour_rows`) and applies the stencil to every handle's column in turn; a row's handles are consecutive in
memory, so the 19 rows a node reads are 19 streams. The ogre at n = 64 (118 handles, 2-core Xeon, one thread): 16 ms
against the walk's 53 ms per application.

The sums are the walk's, term for term and in its order, in the same precision (float32 for Krylov and smoothing
steps, float64 for residuals): both kernels give the same bits (tests/test_solve.py).
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

from .stencil import APPLY, INVERSE_DIAGONAL, RESIDUAL, STEP

#: this module's kernels run on a CPU only (a GPU runs the patch walks of ``stencil``): what a first run compiles
DEVICE_KINDS = ("cpu",)

#: the neighbour table's columns: the six face neighbours (+x, -x, +y, -y, +z, -z), the four edge neighbours in the
#: node's plane ((+x, +y), (+x, -y), (-x, +y), (-x, -y)), the four face neighbours of the node above ((+x, -x, +y, -y)
#: at z + 1) and of the node below (at z - 1): the walk's order of summation
NEIGHBOURS = 18
OFFSETS = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1),
           (1, 1, 0), (1, -1, 0), (-1, 1, 0), (-1, -1, 0),
           (1, 0, 1), (-1, 0, 1), (0, 1, 1), (0, -1, 1),
           (1, 0, -1), (-1, 0, -1), (0, 1, -1), (0, -1, -1))
_OFFSETS = wp.constant(wp.types.matrix(shape=(NEIGHBOURS, 3), dtype=wp.int32)(*[c for o in OFFSETS for c in o]))


@wp.kernel
def neighbour_rows(index: wp.array3d(dtype=wp.int32), active_ijk: wp.array(dtype=wp.vec3i),
                   rows: wp.array2d(dtype=wp.int32)):
    """rows[n, e] = the row of interior node n's neighbour e (``OFFSETS``), -1 where that node is not active; launch
    (interior nodes, NEIGHBOURS). Every neighbour of an interior node lies on the grid (the band surrounds it)."""
    n, e = wp.tid()
    p = active_ijk[n]
    rows[n, e] = index[p[0] + _OFFSETS[e, 0], p[1] + _OFFSETS[e, 1], p[2] + _OFFSETS[e, 2]]


@wp.func
def visible(row: int, n_rows: int):
    """``row``, or -1 where it holds no data for this application (inactive, or at or beyond ``n_rows``)."""
    if row >= n_rows:
        return -1
    return row


@wp.func
def column_at(field: wp.array2d(dtype=wp.vec4f), row: int, h: int):
    if row < 0:
        return wp.vec4f()
    return field[row, h]


def node_operator_kernel(scalar, mode):
    """The batched operator for a CPU with sums in `scalar` (wp.float32 or wp.float64) writing, by `mode`, A x
    (``APPLY``), b - A x (``RESIDUAL``) or a Chebyshev step from b - A x (``STEP``): d = ca d + cb D^-1 (b - A x),
    out = x + d. Launch: one thread per interior node."""
    vec4 = wp.types.vector(length=4, dtype=scalar)

    @wp.kernel(module="unique", enable_backward=False)
    def node_operator(
        field: wp.array2d(dtype=wp.vec4f),
        rows: wp.array2d(dtype=wp.int32),
        n_rows: int,
        rhs: wp.array2d(dtype=wp.vec4f),
        ca: wp.float32,
        cb: wp.float32,
        d: wp.array2d(dtype=wp.vec4f),
        out: wp.array2d(dtype=wp.vec4f),
    ):
        # rows of `field` at or beyond `n_rows` read as zero (n_interior: the interior block; all active rows: with
        # the ring data). `out` may be `rhs` (RESIDUAL: each entry is read once, before it is written), never `field`
        n = wp.tid()
        xp_row = visible(rows[n, 0], n_rows)
        xm_row = visible(rows[n, 1], n_rows)
        yp_row = visible(rows[n, 2], n_rows)
        ym_row = visible(rows[n, 3], n_rows)
        zp_row = visible(rows[n, 4], n_rows)
        zm_row = visible(rows[n, 5], n_rows)
        e0 = visible(rows[n, 6], n_rows)
        e1 = visible(rows[n, 7], n_rows)
        e2 = visible(rows[n, 8], n_rows)
        e3 = visible(rows[n, 9], n_rows)
        a0 = visible(rows[n, 10], n_rows)
        a1 = visible(rows[n, 11], n_rows)
        a2 = visible(rows[n, 12], n_rows)
        a3 = visible(rows[n, 13], n_rows)
        b0 = visible(rows[n, 14], n_rows)
        b1 = visible(rows[n, 15], n_rows)
        b2 = visible(rows[n, 16], n_rows)
        b3 = visible(rows[n, 17], n_rows)
        three = scalar(3.0)
        four = scalar(4.0)
        for h in range(out.shape[1]):
            c = vec4(field[n, h])
            xp = vec4(column_at(field, xp_row, h))
            xm = vec4(column_at(field, xm_row, h))
            yp = vec4(column_at(field, yp_row, h))
            ym = vec4(column_at(field, ym_row, h))
            # the node's plane, as the walk reduces it
            corners = (scalar(column_at(field, e0, h)[0]) + scalar(column_at(field, e1, h)[0])) + (
                scalar(column_at(field, e2, h)[0]) + scalar(column_at(field, e3, h)[0]))
            faces = (xp[0] + xm[0]) + (yp[0] + ym[0])
            in_plane = scalar(48.0) * c[0] - scalar(10.0) * faces + corners + three * (
                (xp[1] - xm[1]) + (yp[2] - ym[2]))
            gx = wp.float32(xm[1] + four * c[1] + xp[1] - three * (xp[0] - xm[0]))
            gy = wp.float32(ym[2] + four * c[2] + yp[2] - three * (yp[0] - ym[0]))
            # the planes above and below: their q and G_z, and their face neighbours' q (the node's edges)
            up = column_at(field, zp_row, h)
            down = column_at(field, zm_row, h)
            faces_up = (scalar(column_at(field, a0, h)[0]) + scalar(column_at(field, a1, h)[0])) + (
                scalar(column_at(field, a2, h)[0]) + scalar(column_at(field, a3, h)[0]))
            faces_down = (scalar(column_at(field, b0, h)[0]) + scalar(column_at(field, b1, h)[0])) + (
                scalar(column_at(field, b2, h)[0]) + scalar(column_at(field, b3, h)[0]))
            q_up = scalar(up[0])
            q_down = scalar(down[0])
            gz_up = scalar(up[3])
            gz_down = scalar(down[3])
            value = in_plane - scalar(10.0) * (q_up + q_down) + (faces_up + faces_down)
            value += three * (gz_up - gz_down)
            gz = gz_down + four * scalar(c[3]) + gz_up - three * (q_up - q_down)
            if wp.static(mode != APPLY):
                given = rhs[n, h]
                value = scalar(given[0]) - value
                gz = scalar(given[3]) - gz
                gx = given[1] - gx
                gy = given[2] - gy
            result = wp.vec4f(wp.float32(value), gx, gy, wp.float32(gz))
            if wp.static(mode == STEP):
                step = ca * d[n, h] + cb * wp.cw_mul(result, INVERSE_DIAGONAL)
                d[n, h] = step
                result = field[n, h] + step
            out[n, h] = result

    return node_operator


#: residuals (float64 sums)
apply_operator = node_operator_kernel(wp.float64, APPLY)
#: Krylov and smoothing applications (float32 sums)
apply_operator_fast = node_operator_kernel(wp.float32, APPLY)
#: b - A x in one pass (float32 sums)
residual_operator_fast = node_operator_kernel(wp.float32, RESIDUAL)
#: a Chebyshev smoothing step from b - A x in one pass (float32 sums)
chebyshev_step_fast = node_operator_kernel(wp.float32, STEP)
