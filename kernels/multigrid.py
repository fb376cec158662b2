"""Kernels of the geometric multigrid preconditioner for the compact coupled scheme.

Levels are sets of nodes on lattices of spacing 2^l h. A level's unknowns are rows of (node, handle) arrays of
vec4 (q, G) with G = (level spacing) grad q. Every operator is a block stencil on its lattice, applied and
formed without general sparse matrices (whose 32-bit offsets overflow on large grids):

- the fine operator is the 19-point stencil (stencil.py), here only needed as blocks inside the Galerkin product;
- coarse operators are Galerkin products P^T A P; on a lattice they couple a node to its 27 neighbours within one
  lattice step, stored as (nodes, 27) mat44 blocks, neighbour o = (di, dj, dk) at slot 9 (di + 1) + 3 (dj + 1)
  + dk + 1;
- the prolongation P is the cubic Hermite interpolation from the coarse lattice; its block for a fine node and one
  of its parents depends only on the node's parities and on which parent it is: a table of 8 x 8 blocks.

A row lookup `node_row(index, n_rows, p)` gives -1 for lattice points off the lattice, without a row, or with a
row >= n_rows: with the grid's index and n_rows = n_interior the fine level's unknowns are the interior nodes.

About 600 lines, one module on purpose: the forming kernels (Galerkin blocks, Hermite table) and the applying ones
(stencil, restriction, prolongation, Chebyshev steps) share the lattice helpers and the slot numbering above, and
read as one description of the V-cycle.
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

NEIGHBOURS = wp.constant(27)
CENTRE = wp.constant(13)


@wp.func
def neighbour_offset(slot: int):
    """(di, dj, dk) in {-1, 0, 1}^3 of neighbour slot 0..26."""
    return wp.vec3i(slot // 9 - 1, (slot // 3) % 3 - 1, slot % 3 - 1)


@wp.func
def neighbour_slot(d: wp.vec3i):
    return 9 * (d[0] + 1) + 3 * (d[1] + 1) + d[2] + 1


@wp.func
def node_row(index: wp.array3d(dtype=wp.int32), n_rows: int, p: wp.vec3i):
    """Row of lattice point p, or -1 when it is off the lattice or has no row below n_rows."""
    if p[0] < 0 or p[1] < 0 or p[2] < 0:
        return -1
    if p[0] >= index.shape[0] or p[1] >= index.shape[1] or p[2] >= index.shape[2]:
        return -1
    row = int(index[p[0], p[1], p[2]])
    if row >= n_rows:
        return -1
    return row


# ---------------------------------------------------------------------------------------------------------------
# the fine operator's blocks


#: the fine operator of a level: a (rows, 27) block array, the 19-point biharmonic stencil, or the 7-point Laplace
#: one of harmonic coordinates (kernels/laplace.py: q rows 6 q - sum_face q, identity G rows)
BLOCKS = wp.constant(0)
BIHARMONIC = wp.constant(1)
LAPLACE = wp.constant(2)


@wp.func
def laplace_block(d: wp.vec3i):
    """Block of the 7-point Laplace operator (identity gradient rows) coupling a node to its neighbour p + d."""
    m = wp.mat44d()
    steps = wp.abs(d[0]) + wp.abs(d[1]) + wp.abs(d[2])
    if steps == 0:
        m[0, 0] = wp.float64(6.0)
        m[1, 1] = wp.float64(1.0)
        m[2, 2] = wp.float64(1.0)
        m[3, 3] = wp.float64(1.0)
    elif steps == 1:
        m[0, 0] = wp.float64(-1.0)
    return m


@wp.func
def fine_block(d: wp.vec3i, equation: int):
    """Block of the fine operator (BIHARMONIC: the 19-point stencil; LAPLACE: the 7-point one) coupling a node's
    (q, G) equations to (q, G) of its neighbour p + d."""
    if equation == LAPLACE:
        return laplace_block(d)
    m = wp.mat44d()
    steps = wp.abs(d[0]) + wp.abs(d[1]) + wp.abs(d[2])
    if steps == 0:
        m[0, 0] = wp.float64(48.0)
        m[1, 1] = wp.float64(4.0)
        m[2, 2] = wp.float64(4.0)
        m[3, 3] = wp.float64(4.0)
    elif steps == 1:
        # value eq: -10 q + 3 sign G_a; gradient eq along a: G_a - 3 sign q
        axis = int(0)
        sign = wp.float64(0.0)
        for a in range(3):
            if d[a] != 0:
                axis = a
                sign = wp.float64(d[a])
        m[0, 0] = wp.float64(-10.0)
        m[0, 1 + axis] = wp.float64(3.0) * sign
        m[1 + axis, 1 + axis] = wp.float64(1.0)
        m[1 + axis, 0] = wp.float64(-3.0) * sign
    elif steps == 2:
        m[0, 0] = wp.float64(1.0)
    return m


@wp.kernel
def stencil_blocks(
    ijk: wp.array(dtype=wp.vec3i),
    index: wp.array3d(dtype=wp.int32),
    n_rows: int,
    equation: int,
    blocks: wp.array2d(dtype=wp.mat44f),
):
    """The fine operator (BIHARMONIC or LAPLACE) of the unknowns as (rows, 27) blocks, zero where the neighbour is
    not an unknown: only for small levels (a coarsest level that is the fine one, inspection); launch (rows, 27)."""
    m, o = wp.tid()
    d = neighbour_offset(o)
    b = wp.mat44f()
    if node_row(index, n_rows, ijk[m] + d) >= 0:
        b = wp.mat44f(fine_block(d, equation))
    blocks[m, o] = b


# ---------------------------------------------------------------------------------------------------------------
# coarsening and cubic Hermite prolongation


@wp.kernel
def parity_counts(fine_ijk: wp.array(dtype=wp.vec3i), counts: wp.array(dtype=wp.int32)):
    """counts[px + 2 py + 4 pz] += 1 for each fine unknown of parities (px, py, pz): how many coarse nodes each
    lattice shift would keep under :func:`coarse_nodes`; launch (fine rows,) on zeroed counts."""
    f = fine_ijk[wp.tid()]
    wp.atomic_add(counts, (f[0] % 2) + 2 * (f[1] % 2) + 4 * (f[2] % 2), 1)


@wp.kernel
def coarse_nodes(
    fine_index: wp.array3d(dtype=wp.int32),
    n_fine: int,
    shift: wp.vec3i,
    classes: wp.array3d(dtype=wp.int8),
):
    """Coarse node c is kept (class 0, else -1) when the fine node 2c + shift under it is a fine unknown.

    Why: a fine node at 2c + shift has one parent, and the prolongation's block there is diagonal (the identity, G
    halved to the finer spacing), so P has such a row block for every kept coarse node: |P v| >= |v| / 2, and every
    Galerkin operator P^T A P is positive definite, its smallest eigenvalue at least a quarter of the finer
    operator's. A rule that kept a coarse node for the fine unknowns around it (at least 27 / 8 of them) kept nodes
    that only a thin layer of fine nodes between them supported; two such nodes could prolong to the same few fine
    values, and the coarsest operator was singular (a human cage at n = 29 and 33, a flat ellipsoid at 21-30, a thin
    neck at 30-46). The shift (0 or 1 along each axis, chosen per level from :func:`parity_counts`) keeps coarsening
    going where the finer unknowns are a layer of odd coordinates (a thin sheet): with shift 0 none would be kept."""
    i, j, k = wp.tid()
    kept = wp.int8(-1)
    if node_row(fine_index, n_fine, wp.vec3i(2 * i, 2 * j, 2 * k) + shift) >= 0:
        kept = wp.int8(0)
    classes[i, j, k] = kept


@wp.func
def hermite_1d(axis: int, parity: int, side: int):
    """Block applied along `axis` to a coarse parent's (q, G) (G in coarse units).

    parity 0: the fine node sits on the parent (identity). parity 1: it is the edge midpoint between the parents
    side 0 (left) and side 1 (right): cubic Hermite value (q0+q1)/2 + (G0-G1)/8 and slope 1.5(q1-q0) -
    (G0+G1)/4 along the axis, linear averages of the transverse gradients."""
    m = wp.mat44d()
    if parity == 0:
        m = wp.identity(n=4, dtype=wp.float64)
    else:
        sign = wp.float64(2 * side - 1)  # -1 left, +1 right
        a = 1 + axis
        m[0, 0] = wp.float64(0.5)
        m[0, a] = wp.float64(-0.125) * sign
        m[a, 0] = wp.float64(1.5) * sign
        m[a, a] = wp.float64(-0.25)
        for b in range(3):
            if b != axis:
                m[1 + b, 1 + b] = wp.float64(0.5)
    return m


@wp.kernel
def hermite_table(table: wp.array(dtype=wp.mat44d)):
    """table[8 parity + side]: P's block for a fine node of parities (px, py, pz) = bits of `parity` and its
    parent on sides (sx, sy, sz) = bits of `side` (side 1 only along odd axes; other entries are zero).
    The tensor product applies x, then y, then z, and rescales G to fine units at the end."""
    t = wp.tid()
    parity = t // 8
    side = t % 8
    m = wp.mat44d()
    if (side & ~parity) == 0:
        to_fine = wp.mat44d()
        to_fine[0, 0] = wp.float64(1.0)
        to_fine[1, 1] = wp.float64(0.5)
        to_fine[2, 2] = wp.float64(0.5)
        to_fine[3, 3] = wp.float64(0.5)
        hx = hermite_1d(0, parity & 1, side & 1)
        hy = hermite_1d(1, (parity >> 1) & 1, (side >> 1) & 1)
        hz = hermite_1d(2, (parity >> 2) & 1, (side >> 2) & 1)
        m = to_fine * (hz * (hy * hx))
    table[t] = m


@wp.kernel
def trilinear_table(table: wp.array(dtype=wp.mat44d)):
    """The prolongation of the Laplace hierarchy in the layout of :func:`hermite_table`: trilinear interpolation of
    each of (q, G) on its own (the gradient rows are decoupled identity rows there)."""
    t = wp.tid()
    parity = t // 8
    side = t % 8
    m = wp.mat44d()
    if (side & ~parity) == 0:
        weight = wp.float64(1.0)
        for a in range(3):
            if (parity >> a) & 1 == 1:
                weight = weight * wp.float64(0.5)
        m = weight * wp.identity(n=4, dtype=wp.float64)
    table[t] = m


@wp.func
def parent_entry(d: wp.vec3i):
    """Table entry of P's block for the fine node 2c + d (d in {-1, 0, 1}^3) and its parent c."""
    parity = int(0)
    side = int(0)
    for a in range(3):
        if d[a] != 0:
            parity = parity | (1 << a)
        if d[a] < 0:  # the fine node lies before its parent: the parent is on its right
            side = side | (1 << a)
    return 8 * parity + side


@wp.func
def parent_slot(f: wp.vec3i, slot: int):
    """Parent `slot` of fine node f (bit a of `slot`: the right parent along axis a): (d, 1) with f = 2 c + d for
    that parent c, or (0, 0) when the slot does not exist (a right parent along an even axis, where the node sits
    on its only parent)."""
    d = wp.vec3i()
    for a in range(3):
        side = (slot >> a) & 1
        if f[a] % 2 == 0:
            if side != 0:
                return wp.vec4i(0, 0, 0, 0)
        else:
            d[a] = 1 - 2 * side  # side 0: the parent at (f - 1) / 2, so f = 2 c + 1
    return wp.vec4i(d[0], d[1], d[2], 1)


@wp.kernel
def prolongation_triplets(
    fine_ijk: wp.array(dtype=wp.vec3i),
    coarse_index: wp.array3d(dtype=wp.int32),
    n_coarse: int,
    shift: wp.vec3i,
    table: wp.array(dtype=wp.mat44d),
    rows: wp.array(dtype=int),
    cols: wp.array(dtype=int),
    blocks: wp.array(dtype=wp.mat44f),
):
    """P's blocks for each fine unknown as 8 triplet slots (parents), -1 where a parent does not exist or is not
    kept: P as a matrix, for inspection and tests (the V-cycle applies P and P^T with the kernels below). Coarse node
    c sits on the fine node 2c + shift."""
    n = wp.tid()
    f = fine_ijk[n] - shift
    for slot in range(8):
        parent = parent_slot(f, slot)
        d = wp.vec3i(parent[0], parent[1], parent[2])
        col = int(-1)
        if parent[3] != 0:
            col = node_row(coarse_index, n_coarse, (f - d) / 2)
        m = wp.mat44f()
        if col >= 0:
            m = wp.mat44f(table[parent_entry(d)])
        rows[8 * n + slot] = wp.where(col >= 0, n, -1)
        cols[8 * n + slot] = col
        blocks[8 * n + slot] = m


@wp.func
def stencil_times(d: wp.vec3i, p: wp.mat44d):
    """fine_block(d) * p without the zeros: the centre scales rows, a face couples q and G along its axis, an
    edge keeps the value row, a corner is zero."""
    m = wp.mat44d()
    steps = wp.abs(d[0]) + wp.abs(d[1]) + wp.abs(d[2])
    if steps == 0:
        for j in range(4):
            m[0, j] = wp.float64(48.0) * p[0, j]
            m[1, j] = wp.float64(4.0) * p[1, j]
            m[2, j] = wp.float64(4.0) * p[2, j]
            m[3, j] = wp.float64(4.0) * p[3, j]
    elif steps == 1:
        axis = int(0)
        sign = wp.float64(0.0)
        for a in range(3):
            if d[a] != 0:
                axis = a
                sign = wp.float64(d[a])
        for j in range(4):
            m[0, j] = wp.float64(-10.0) * p[0, j] + wp.float64(3.0) * sign * p[1 + axis, j]
            m[1 + axis, j] = p[1 + axis, j] - wp.float64(3.0) * sign * p[0, j]
    elif steps == 2:
        for j in range(4):
            m[0, j] = p[0, j]
    return m


@wp.kernel
def galerkin_blocks(
    coarse_ijk: wp.array(dtype=wp.vec3i),
    coarse_index: wp.array3d(dtype=wp.int32),
    n_coarse: int,
    fine_index: wp.array3d(dtype=wp.int32),
    n_fine: int,
    fine_blocks: wp.array2d(dtype=wp.mat44f),
    fine_operator: int,
    shift: wp.vec3i,
    table: wp.array(dtype=wp.mat44d),
    first_row: int,
    blocks: wp.array2d(dtype=wp.mat44f),
):
    """blocks[m, o] = (P^T A P)[c, c + o] for coarse node c = coarse_ijk[m] and neighbour slot o >= 13 (the centre
    and the 13 neighbours after it), and its transpose, the block of the pair's other row (A is symmetric);
    launch (coarse nodes from first_row on, 14) on zeroed `blocks` (each block is written by one thread: launches
    over other rows may run at once). A is the 27-point block stencil `fine_blocks` (fine_operator =
    BLOCKS), the 19-point stencil (BIHARMONIC) or the 7-point one (LAPLACE); sums in float64.

    (P^T A P)[c, c'] = sum over the fine unknowns f around c (|f - 2c| <= 1) of P[f, c]^T (A P)[f, c'], with
    (A P)[f, c'] = sum over A's neighbours g of f that lie around c' (|g - 2c'| <= 1) of A[f, g] P[g, c'] (fine
    coordinates less ``shift``: coarse node c sits on the fine node 2c + shift)."""
    tm, u = wp.tid()
    m = first_row + tm
    o = CENTRE + u
    c = coarse_ijk[m]
    other = c + neighbour_offset(o)
    row_other = node_row(coarse_index, n_coarse, other)
    if row_other < 0:
        return
    acc = wp.mat44d()
    for s in range(27):
        ds = neighbour_offset(s)
        f = 2 * c + ds
        row_f = node_row(fine_index, n_fine, f + shift)
        if row_f >= 0:
            ap = wp.mat44d()
            for t in range(27):
                dt = neighbour_offset(t)
                e = f + dt - 2 * other
                if wp.abs(e[0]) <= 1 and wp.abs(e[1]) <= 1 and wp.abs(e[2]) <= 1:
                    if node_row(fine_index, n_fine, f + dt + shift) >= 0:
                        if fine_operator == BIHARMONIC:
                            ap += stencil_times(dt, table[parent_entry(e)])
                        elif fine_operator == LAPLACE:
                            ap += laplace_block(dt) * table[parent_entry(e)]
                        else:
                            ap += wp.mat44d(fine_blocks[row_f, t]) * table[parent_entry(e)]
            acc += wp.transpose(table[parent_entry(ds)]) * ap
    blocks[m, o] = wp.mat44f(acc)
    if o != CENTRE:
        blocks[row_other, NEIGHBOURS - 1 - o] = wp.mat44f(wp.transpose(acc))


# ---------------------------------------------------------------------------------------------------------------
# batched (node, handle) operations


@wp.kernel
def neighbour_rows(ijk: wp.array(dtype=wp.vec3i), index: wp.array3d(dtype=wp.int32), n_rows: int,
                   rows: wp.array2d(dtype=wp.int32)):
    """The row of each node's 27 neighbours on a coarse level (-1: none): looked up once at setup, so that the block
    stencils read one int per block instead of forming the neighbour's lattice point and its index each time."""
    n, o = wp.tid()
    rows[n, o] = node_row(index, n_rows, ijk[n] + neighbour_offset(o))


@wp.func
def block_row(blocks: wp.array2d(dtype=wp.mat44f), rows: wp.array2d(dtype=wp.int32), x: wp.array2d(dtype=wp.vec4f),
              n: int, h: int):
    """(A x)[n] for a 27-point block stencil A with neighbour rows ``rows``, column h."""
    acc = wp.vec4f(0.0)
    for o in range(27):
        col = rows[n, o]
        if col >= 0:
            acc += blocks[n, o] * x[col, h]
    return acc


@wp.func
def block_chebyshev_step(blocks: wp.array2d(dtype=wp.mat44f), rows: wp.array2d(dtype=wp.int32),
                         b: wp.array2d(dtype=wp.vec4f), x: wp.array2d(dtype=wp.vec4f), d_inv: wp.mat44f, ca: float,
                         cb: float, d: wp.array2d(dtype=wp.vec4f), x_next: wp.array2d(dtype=wp.vec4f), n: int, h: int):
    """At row n, column h of a 27-point block stencil: d = ca d + cb D^-1 (b - A x), x_next = x + d."""
    v = ca * d[n, h] + cb * (d_inv * (b[n, h] - block_row(blocks, rows, x, n, h)))
    d[n, h] = v
    x_next[n, h] = x[n, h] + v


@wp.kernel
def stencil_apply(
    blocks: wp.array2d(dtype=wp.mat44f),
    rows: wp.array2d(dtype=wp.int32),
    x: wp.array2d(dtype=wp.vec4f),
    out: wp.array2d(dtype=wp.vec4f),
):
    """out = A x for a 27-point block stencil A, every handle a column; launch (rows, handles)."""
    n, h = wp.tid()
    out[n, h] = block_row(blocks, rows, x, n, h)


@wp.kernel
def stencil_residual(
    blocks: wp.array2d(dtype=wp.mat44f),
    rows: wp.array2d(dtype=wp.int32),
    b: wp.array2d(dtype=wp.vec4f),
    x: wp.array2d(dtype=wp.vec4f),
    out: wp.array2d(dtype=wp.vec4f),
):
    """out = b - A x in one pass (out may alias b, not x); launch (rows, handles)."""
    n, h = wp.tid()
    out[n, h] = b[n, h] - block_row(blocks, rows, x, n, h)


@wp.kernel
def stencil_chebyshev_step(
    blocks: wp.array2d(dtype=wp.mat44f),
    rows: wp.array2d(dtype=wp.int32),
    b: wp.array2d(dtype=wp.vec4f),
    x: wp.array2d(dtype=wp.vec4f),
    inv_diag: wp.array(dtype=wp.mat44f),
    ca: float,
    cb: float,
    d: wp.array2d(dtype=wp.vec4f),
    x_next: wp.array2d(dtype=wp.vec4f),
):
    """A Chebyshev step from the residual of a 27-point block stencil, in one pass: d = ca d + cb D^-1 (b - A x),
    x_next = x + d (the residual and ``chebyshev_step`` in turn, without writing the residual); x_next is not x."""
    n, h = wp.tid()
    block_chebyshev_step(blocks, rows, b, x, diagonal_block(inv_diag, n), ca, cb, d, x_next, n, h)


@wp.kernel
def restrict(
    table: wp.array(dtype=wp.mat44f),
    coarse_ijk: wp.array(dtype=wp.vec3i),
    fine_index: wp.array3d(dtype=wp.int32),
    n_fine: int,
    shift: wp.vec3i,
    r: wp.array2d(dtype=wp.vec4f),
    b: wp.array2d(dtype=wp.vec4f),
):
    """b = P^T r: each coarse node gathers from the fine unknowns around it (coarse node c sits on the fine node
    2c + shift); launch (coarse rows, handles). The table in float32 (its entries are halves, quarters and eighths:
    exact)."""
    m, h = wp.tid()
    c = coarse_ijk[m]
    acc = wp.vec4f(0.0)
    for s in range(27):
        d = neighbour_offset(s)
        row = node_row(fine_index, n_fine, 2 * c + d + shift)
        if row >= 0:
            acc += wp.transpose(table[parent_entry(d)]) * r[row, h]
    b[m, h] = acc


@wp.kernel
def prolong_add(
    table: wp.array(dtype=wp.mat44f),
    fine_ijk: wp.array(dtype=wp.vec3i),
    coarse_index: wp.array3d(dtype=wp.int32),
    shift: wp.vec3i,
    xc: wp.array2d(dtype=wp.vec4f),
    x: wp.array2d(dtype=wp.vec4f),
):
    """x += P xc: each fine unknown gathers from its kept parents (coarse node c sits on the fine node 2c + shift);
    launch (fine rows, handles)."""
    n, h = wp.tid()
    f = fine_ijk[n] - shift
    acc = wp.vec4f(0.0)
    for slot in range(8):
        parent = parent_slot(f, slot)
        if parent[3] != 0:
            d = wp.vec3i(parent[0], parent[1], parent[2])
            col = node_row(coarse_index, xc.shape[0], (f - d) / 2)
            if col >= 0:
                acc += table[parent_entry(d)] * xc[col, h]
    x[n, h] = x[n, h] + acc


@wp.kernel
def diagonal_inverse(blocks: wp.array2d(dtype=wp.mat44f), inverse: wp.array(dtype=wp.mat44f)):
    """Inverses of the centre blocks of a 27-point block stencil."""
    i = wp.tid()
    inverse[i] = wp.inverse(blocks[i, CENTRE])


@wp.func
def diagonal_block(inv_diag: wp.array(dtype=wp.mat44f), n: int):
    """D^-1 of row n; a single block stands for every row (the fine stencil's diagonal is constant)."""
    if inv_diag.shape[0] == 1:
        return inv_diag[0]
    return inv_diag[n]


@wp.kernel
def chebyshev_start(
    r: wp.array2d(dtype=wp.vec4f),
    inv_diag: wp.array(dtype=wp.mat44f),
    scale: float,
    x: wp.array2d(dtype=wp.vec4f),
    d: wp.array2d(dtype=wp.vec4f),
):
    """d = scale D^-1 r; x += d."""
    n, h = wp.tid()
    v = scale * (diagonal_block(inv_diag, n) * r[n, h])
    d[n, h] = v
    x[n, h] = x[n, h] + v


@wp.kernel
def chebyshev_first(
    b: wp.array2d(dtype=wp.vec4f),
    inv_diag: wp.array(dtype=wp.mat44f),
    scale: float,
    x: wp.array2d(dtype=wp.vec4f),
    d: wp.array2d(dtype=wp.vec4f),
):
    """d = x = scale D^-1 b: the first step from x = 0, without reading (or zeroing) x."""
    n, h = wp.tid()
    v = scale * (diagonal_block(inv_diag, n) * b[n, h])
    d[n, h] = v
    x[n, h] = v


@wp.kernel
def chebyshev_step(
    r: wp.array2d(dtype=wp.vec4f),
    inv_diag: wp.array(dtype=wp.mat44f),
    a: float,
    b: float,
    x: wp.array2d(dtype=wp.vec4f),
    d: wp.array2d(dtype=wp.vec4f),
):
    """d = a d + b D^-1 r; x += d."""
    n, h = wp.tid()
    v = a * d[n, h] + b * (diagonal_block(inv_diag, n) * r[n, h])
    d[n, h] = v
    x[n, h] = x[n, h] + v


@wp.kernel
def row_sum_bound(
    blocks: wp.array2d(dtype=wp.mat44f),
    inv_diag: wp.array(dtype=wp.mat44f),
    slot: int,
    bound: wp.array(dtype=wp.float32),
):
    """bound[slot] = max over rows of sum_j |(D^-1 A)_ij| for a 27-point block stencil: a guaranteed upper bound of the
    largest eigenvalue of D^-1 A (its infinity norm); launch (rows,)."""
    n = wp.tid()
    sums = wp.vec4f(0.0)
    d_inv = inv_diag[n]
    for o in range(NEIGHBOURS):
        b = d_inv * blocks[n, o]
        for r in range(4):
            sums[r] += wp.abs(b[r, 0]) + wp.abs(b[r, 1]) + wp.abs(b[r, 2]) + wp.abs(b[r, 3])
    wp.atomic_max(bound, slot, wp.max(wp.max(sums[0], sums[1]), wp.max(sums[2], sums[3])))


@wp.kernel
def random_column(seed: int, v: wp.array2d(dtype=wp.vec4f)):
    """v[:, 0] = standard normal entries (the start of a power iteration)."""
    n = wp.tid()
    state = wp.rand_init(seed, n)
    v[n, 0] = wp.vec4f(wp.randn(state), wp.randn(state), wp.randn(state), wp.randn(state))


@wp.kernel
def divide_column(v: wp.array2d(dtype=wp.vec4f), squared_norm: wp.array(dtype=wp.float64)):
    """v[:, 0] /= sqrt(squared_norm[0]): normalised without a trip to the host."""
    n = wp.tid()
    v[n, 0] = v[n, 0] / wp.float32(wp.sqrt(squared_norm[0]))


@wp.kernel
def dense_apply(
    inverse: wp.array2d(dtype=wp.float32),
    b: wp.array2d(dtype=wp.vec4f),
    x: wp.array2d(dtype=wp.vec4f),
):
    """x = M b on the coarsest level, M a dense (4N x 4N) inverse; launch (rows N, handles)."""
    n, h = wp.tid()
    out = wp.vec4f(0.0)
    for m in range(b.shape[0]):
        v = b[m, h]
        for r in range(4):
            row = 4 * n + r
            out[r] += (
                inverse[row, 4 * m] * v[0]
                + inverse[row, 4 * m + 1] * v[1]
                + inverse[row, 4 * m + 2] * v[2]
                + inverse[row, 4 * m + 3] * v[3]
            )
    x[n, h] = out
