"""The compact second-order 19-point coupled scheme for the biharmonic equation (Altas et al.).

Per node the unknowns are the value q and the scaled gradient G = h grad q, packed as vec4 (q, Gx, Gy, Gz).
Fields are 2D arrays (node row, handle) with the handles innermost, so that the threads of one node read
consecutive handles (coalesced). `index[i, j, k]` maps a grid node to its row (-1 when inactive); interior
nodes come first, so row n < n_interior is interior node n.

    value eq:    48 q_p - 10 sum_face q + sum_edge q + 3 sum_a (G_a(p+e_a) - G_a(p-e_a)) = (h^4/2) f_p
    gradient eq: G_a(p-e_a) + 4 G_a(p) + G_a(p+e_a) - 3 (q(p+e_a) - q(p-e_a))   = 0
"""

import warp as wp


def operator_kernel(scalar):
    """The batched operator with sums in `scalar` (wp.float32 or wp.float64).

    Residuals of a nearly converged float32 field cancel to ~1e-7 of their terms: a float32 sum would stall
    the solver there, so residuals use float64 sums. Krylov and smoothing applications only need float32;
    float64 sums cost about a quarter of the kernel's speed (benchmarks/RESULTS.md)."""
    vec4 = wp.types.vector(length=4, dtype=scalar)

    @wp.func
    def node_value(
        field: wp.array2d(dtype=wp.vec4f),
        index: wp.array3d(dtype=wp.int32),
        n_rows: int,
        i: int,
        j: int,
        k: int,
        handle: int,
    ):
        # the packed (q, G) of a node, zero where the node has no row below `n_rows`
        row = index[i, j, k]
        if row >= 0 and row < n_rows:
            return vec4(field[row, handle])
        return vec4()

    @wp.kernel(module="unique")
    def apply_operator(
        field: wp.array2d(dtype=wp.vec4f),
        index: wp.array3d(dtype=wp.int32),
        interior_ijk: wp.array(dtype=wp.vec3i),
        n_rows: int,
        out: wp.array2d(dtype=wp.vec4f),
    ):
        # out = A field at the interior nodes, one launch of (interior nodes, handles). Rows of `field` at or
        # beyond `n_rows` read as zero: with n_rows = n_interior this is the interior block A_II (Krylov
        # vectors); with all active rows it includes the known ring data (residuals).
        n, h = wp.tid()
        c = interior_ijk[n]
        i = c[0]
        j = c[1]
        k = c[2]
        centre = vec4(field[n, h])
        xp = node_value(field, index, n_rows, i + 1, j, k, h)
        xm = node_value(field, index, n_rows, i - 1, j, k, h)
        yp = node_value(field, index, n_rows, i, j + 1, k, h)
        ym = node_value(field, index, n_rows, i, j - 1, k, h)
        zp = node_value(field, index, n_rows, i, j, k + 1, h)
        zm = node_value(field, index, n_rows, i, j, k - 1, h)
        edges = scalar(0.0)
        for a in range(-1, 2, 2):
            for b in range(-1, 2, 2):
                edges += node_value(field, index, n_rows, i + a, j + b, k, h)[0]
                edges += node_value(field, index, n_rows, i + a, j, k + b, h)[0]
                edges += node_value(field, index, n_rows, i, j + a, k + b, h)[0]
        faces = xp[0] + xm[0] + yp[0] + ym[0] + zp[0] + zm[0]
        divergence = (xp[1] - xm[1]) + (yp[2] - ym[2]) + (zp[3] - zm[3])
        three = scalar(3.0)
        four = scalar(4.0)
        value = scalar(48.0) * centre[0] - scalar(10.0) * faces + edges + three * divergence
        gx = xm[1] + four * centre[1] + xp[1] - three * (xp[0] - xm[0])
        gy = ym[2] + four * centre[2] + yp[2] - three * (yp[0] - ym[0])
        gz = zm[3] + four * centre[3] + zp[3] - three * (zp[0] - zm[0])
        out[n, h] = wp.vec4f(wp.float32(value), wp.float32(gx), wp.float32(gy), wp.float32(gz))

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
