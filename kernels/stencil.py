"""The compact second-order 19-point coupled scheme for the biharmonic equation (Altas et al.).

Per node the unknowns are the value q and the scaled gradient G = h grad q, packed as vec4 (q, Gx, Gy, Gz).
Fields are 2D arrays (node row, handle) with the handles innermost, so that the threads of one node read
consecutive handles (coalesced). `index[i, j, k]` maps a grid node to its row (-1 when inactive); interior
nodes come first, so row n < n_interior is interior node n.

    value eq:    48 q_p - 10 sum_face q + sum_edge q + 3 sum_a (G_a(p+e_a) - G_a(p-e_a)) = (h^4/2) f_p
    gradient eq: G_a(p-e_a) + 4 G_a(p) + G_a(p+e_a) - 3 (q(p+e_a) - q(p-e_a))   = 0
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.func
def node_value(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, i: int, j: int,
               k: int, handle: int):
    """The packed (q, G) of a node, zero where the node has no row below `n_rows`."""
    row = index[i, j, k]
    if row >= 0 and row < n_rows:
        return field[row, handle]
    return wp.vec4f()


#: handles per thread group (one warp's worth): the launch is (ceil(handles / GROUP), patches, GROUP)
GROUP = 32
#: columns (i, j) one thread walks along z: a plane costs (PATCH_I + 2)(PATCH_J + 2) row loads for
#: PATCH_I * PATCH_J nodes (16 for 4 with 2 x 2, against 9 for 1 walking single columns)
PATCH_I = 2
PATCH_J = 2
#: threads per block: four warps, i.e. four patches of the same 32 handles
BLOCK_DIM = 128
#: columns (i, j) of the patches the one-pass Chebyshev step walks: it keeps more per node than the plain walk (the
#: right-hand side, d and the step), and smaller patches ran faster (1 x 2 took a sixth less time than 2 x 2; every
#: larger patch was slower; the block size made no difference)
STEP_PATCH = (1, 2)
#: what a walk writes (see ``operator_kernel``): A x, b - A x, or a Chebyshev step from b - A x
APPLY = wp.constant(0)
RESIDUAL = wp.constant(1)
STEP = wp.constant(2)
#: the inverse of the scheme's diagonal block, diag(1/48, 1/4, 1/4, 1/4) (its centre coefficients, above); in float32
#: as the multigrid's fine-level ``inv_diag``
INVERSE_DIAGONAL = wp.constant(wp.vec4f(1.0 / 48.0, 0.25, 0.25, 0.25))


# about 110 lines: one kernel factory whose body is one walk over a patch of columns (load a plane, reduce it to
# the terms its nodes and the nodes above and below need, keep them in registers); split, the walk's state would
# have to pass through memory, which is what it exists to avoid
def operator_kernel(scalar, patch=(PATCH_I, PATCH_J), residual: bool = False, chebyshev: bool = False):
    """The batched operator with sums in `scalar` (wp.float32 or wp.float64), walking patches of `patch` columns;
    with `residual`, the kernel that writes rhs - A x instead (one pass instead of two); with `chebyshev`, the
    kernel that takes a Chebyshev smoothing step from that residual (:data:`chebyshev_step_fast`).

    Residuals of a nearly converged float32 field cancel to ~1e-7 of their terms: a float32 sum would stall
    the solver there, so residuals use float64 sums. Krylov and smoothing applications only need float32.

    One thread walks a patch of PI x PJ columns along z for one handle (an item (i0, j0, k0, length) of
    `Grid.interior_patches(patch)`). Each z plane is loaded once, from the (PI + 2) x (PJ + 2) rows
    around the patch, and reduced at once to what each column's nodes need from it: the in-plane part of its
    own equations, and for the nodes above and below, q, G_z and the sum of q over the four face neighbours
    (their edge terms): six values per column and plane, three planes in registers. Against one thread per
    column keeping three whole planes (the form before, bound by L2 bandwidth) this more than halves the rows
    loaded per interior node, and the loads that miss L1 are what limited it (measured: benchmarks/HISTORY.md)."""
    PI, PJ = patch
    W = PJ + 2
    RING = (PI + 2) * W
    COLUMNS = PI * PJ
    ring = wp.types.matrix(shape=(RING, 4), dtype=wp.float32)
    per_column = wp.types.vector(length=COLUMNS, dtype=scalar)
    per_column32 = wp.types.vector(length=COLUMNS, dtype=wp.float32)
    vec4 = wp.types.vector(length=4, dtype=scalar)

    @wp.struct
    class PlaneTerms:
        # per column of the patch; only the value equation's sums need `scalar`: the x and y gradient
        # equations are complete within the plane (rounded to float32 here as they would be on output), and
        # q, G_z are float32 data
        value: per_column  # the in-plane part of the value equation
        faces: per_column  # q summed over the four face neighbours in this plane (edges of the nodes above, below)
        gx: per_column32
        gy: per_column32
        q: per_column32
        gz: per_column32

    @wp.func
    def plane_terms(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, i0: int,
                    j0: int, k: int, h: int):
        m = ring()
        for a in range(PI + 2):
            for b in range(PJ + 2):
                m[a * W + b] = node_value(field, index, n_rows, i0 - 1 + a, j0 - 1 + b, k, h)
        t = PlaneTerms()
        three = scalar(3.0)
        four = scalar(4.0)
        for a in range(PI):
            for b in range(PJ):
                centre = (a + 1) * W + b + 1
                c = vec4(m[centre])
                xp = vec4(m[centre + W])
                xm = vec4(m[centre - W])
                yp = vec4(m[centre + 1])
                ym = vec4(m[centre - 1])
                corners = (scalar(m[centre + W + 1][0]) + scalar(m[centre + W - 1][0])) + (
                    scalar(m[centre - W + 1][0]) + scalar(m[centre - W - 1][0]))
                faces = (xp[0] + xm[0]) + (yp[0] + ym[0])
                n = a * PJ + b
                t.value[n] = scalar(48.0) * c[0] - scalar(10.0) * faces + corners + three * (
                    (xp[1] - xm[1]) + (yp[2] - ym[2]))
                t.faces[n] = faces
                t.gx[n] = wp.float32(xm[1] + four * c[1] + xp[1] - three * (xp[0] - xm[0]))
                t.gy[n] = wp.float32(ym[2] + four * c[2] + yp[2] - three * (yp[0] - ym[0]))
                t.q[n] = m[centre][0]
                t.gz[n] = m[centre][3]
        return t

    @wp.func
    def walk(field: wp.array2d(dtype=wp.vec4f), index: wp.array3d(dtype=wp.int32), n_rows: int, patch: wp.vec4i,
             h: int, rhs: wp.array2d(dtype=wp.vec4f), mode: int, d: wp.array2d(dtype=wp.vec4f), ca: wp.float32,
             cb: wp.float32, out: wp.array2d(dtype=wp.vec4f)):
        # at the interior nodes of one patch, for handle h: out = A field (mode APPLY), rhs - A field (RESIDUAL,
        # the sums' precision kept through the difference), or the Chebyshev step from that residual r (STEP):
        # d = ca d + cb D^-1 r and out = field + d
        i0 = patch[0]
        j0 = patch[1]
        k0 = patch[2]
        three = scalar(3.0)
        four = scalar(4.0)
        below = plane_terms(field, index, n_rows, i0, j0, k0 - 1, h)
        mid = plane_terms(field, index, n_rows, i0, j0, k0, h)
        for t in range(patch[3]):
            k = k0 + t
            above = plane_terms(field, index, n_rows, i0, j0, k + 1, h)
            for a in range(PI):
                for b in range(PJ):
                    # a patch also covers ring, band and outside nodes next to the interior: no equation there
                    row = index[i0 + a, j0 + b, k]
                    if row >= 0 and row < out.shape[0]:
                        n = a * PJ + b
                        q_up = scalar(above.q[n])
                        q_down = scalar(below.q[n])
                        gz_up = scalar(above.gz[n])
                        gz_down = scalar(below.gz[n])
                        value = mid.value[n] - scalar(10.0) * (q_up + q_down) + (above.faces[n] + below.faces[n])
                        value += three * (gz_up - gz_down)
                        gz = gz_down + four * scalar(mid.gz[n]) + gz_up - three * (q_up - q_down)
                        gx = mid.gx[n]
                        gy = mid.gy[n]
                        if mode != APPLY:
                            given = rhs[row, h]
                            value = scalar(given[0]) - value
                            gz = scalar(given[3]) - gz
                            gx = given[1] - gx
                            gy = given[2] - gy
                        result = wp.vec4f(wp.float32(value), gx, gy, wp.float32(gz))
                        if mode == STEP:
                            # D^-1 of the scheme: its centre coefficients 48 (value) and 4 (gradients)
                            step = ca * d[row, h] + cb * wp.cw_mul(result, INVERSE_DIAGONAL)
                            d[row, h] = step
                            result = field[row, h] + step
                        out[row, h] = result
            below = mid
            mid = above

    @wp.kernel(module="unique", enable_backward=False)
    def apply_operator(
        field: wp.array2d(dtype=wp.vec4f),
        index: wp.array3d(dtype=wp.int32),
        patches: wp.array(dtype=wp.vec4i),
        n_rows: int,
        out: wp.array2d(dtype=wp.vec4f),
    ):
        # out = A field at the interior nodes; launch (handle groups, patches, GROUP). Rows of `field` at or
        # beyond `n_rows` read as zero: with n_rows = n_interior this is the interior block A_II (Krylov
        # vectors); with all active rows it includes the known ring data (residuals).
        # Handles are innermost so a warp reads 32 consecutive handles of one row (512 coalesced bytes), and
        # the group is outermost so the warps of a block walk neighbouring patches for the same handles: the
        # rows one warp loads around its patch are rows its neighbour warps load, still in L1.
        g, s, lane = wp.tid()
        h = g * GROUP + lane
        if h >= out.shape[1]:
            return
        walk(field, index, n_rows, patches[s], h, out, APPLY, out, wp.float32(0.0), wp.float32(0.0), out)

    @wp.kernel(module="unique", enable_backward=False)
    def residual_operator(
        field: wp.array2d(dtype=wp.vec4f),
        index: wp.array3d(dtype=wp.int32),
        patches: wp.array(dtype=wp.vec4i),
        n_rows: int,
        rhs: wp.array2d(dtype=wp.vec4f),
        out: wp.array2d(dtype=wp.vec4f),
    ):
        # out = rhs - A field at the interior nodes, as apply_operator launches (out may alias rhs: each entry is
        # read once, by the thread that writes it)
        g, s, lane = wp.tid()
        h = g * GROUP + lane
        if h >= out.shape[1]:
            return
        walk(field, index, n_rows, patches[s], h, rhs, RESIDUAL, out, wp.float32(0.0), wp.float32(0.0), out)

    @wp.kernel(module="unique", enable_backward=False)
    def chebyshev_operator(
        field: wp.array2d(dtype=wp.vec4f),
        index: wp.array3d(dtype=wp.int32),
        patches: wp.array(dtype=wp.vec4i),
        n_rows: int,
        rhs: wp.array2d(dtype=wp.vec4f),
        ca: wp.float32,
        cb: wp.float32,
        d: wp.array2d(dtype=wp.vec4f),
        out: wp.array2d(dtype=wp.vec4f),
    ):
        # d = ca d + cb D^-1 (rhs - A field), out = field + d at the interior nodes, as apply_operator launches;
        # out must not be field (the walk reads field's neighbours after a node's step is written)
        g, s, lane = wp.tid()
        h = g * GROUP + lane
        if h >= out.shape[1]:
            return
        walk(field, index, n_rows, patches[s], h, rhs, STEP, d, ca, cb, out)

    if chebyshev:
        return chebyshev_operator
    return residual_operator if residual else apply_operator


#: residuals (float64 sums)
apply_operator = operator_kernel(wp.float64)
#: Krylov and smoothing applications (float32 sums)
apply_operator_fast = operator_kernel(wp.float32)
#: b - A x in one pass, for the smoother's residuals (float32 sums, as its applications)
residual_operator_fast = operator_kernel(wp.float32, residual=True)
#: a Chebyshev smoothing step from b - A x in one pass (float32 sums), the same numbers as the residual kernel and
#: ``multigrid.chebyshev_step`` in turn, without writing and reading back the residual
chebyshev_step_fast = operator_kernel(wp.float32, patch=STEP_PATCH, chebyshev=True)
#: the walks a bind launches on a GPU only (a CPU runs ``stencil_cpu``'s node loops): a first run on a CPU does not
#: compile them
CUDA_ONLY = (apply_operator, apply_operator_fast, residual_operator_fast, chebyshev_step_fast)


@wp.kernel
def pack_nodal_field(
    values: wp.array2d(dtype=wp.float64),
    active_ijk: wp.array(dtype=wp.vec3i),
    index: wp.array3d(dtype=wp.int32),
    n_with_gradient: int,
    field: wp.array2d(dtype=wp.vec4f),
):
    """field[n] = (q, G) from nodal values q: G_a = (q(p+e_a) - q(p-e_a)) / 2, the central difference of step h,
    exact for linear functions. Every neighbour of an interior or ring row (n < `n_with_gradient`) is an active
    node; a band row uses the one-sided difference where a neighbour is not (exact for linear functions too)."""
    n, h = wp.tid()
    q = values[n, h]
    g = wp.vec3d()
    c = active_ijk[n]
    for a in range(3):
        e = wp.vec3i(0, 0, 0)
        e[a] = 1
        up = c + e
        down = c - e
        row_up = index[up[0], up[1], up[2]]
        row_down = index[down[0], down[1], down[2]]
        if n < n_with_gradient or (row_up >= 0 and row_down >= 0):
            g[a] = wp.float64(0.5) * (values[row_up, h] - values[row_down, h])
        elif row_up >= 0:
            g[a] = values[row_up, h] - q
        elif row_down >= 0:
            g[a] = q - values[row_down, h]
    field[n, h] = wp.vec4f(wp.float32(q), wp.float32(g[0]), wp.float32(g[1]), wp.float32(g[2]))
