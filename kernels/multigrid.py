"""Kernels of the geometric multigrid preconditioner for the compact coupled scheme.

Levels are sets of nodes on lattices of spacing 2^l h. A level's unknowns are rows of (node, handle) arrays of
vec4 (q, G) with G = (level spacing) grad q. The fine operator is applied matrix-free (stencil.py); coarse
operators are Galerkin products P^T A P stored as 4x4-block sparse matrices (warp.sparse BSR, compact rows).
"""

import warp as wp

# ---------------------------------------------------------------------------------------------------------------
# fine operator as blocks (input of the Galerkin product)


@wp.func
def face_block(axis: int, sign: float):
    """Coupling of a node's (q, G) equations to (q, G) of its face neighbour p + sign e_axis."""
    m = wp.mat44f()
    m[0, 0] = -10.0
    m[0, 1 + axis] = 3.0 * sign
    m[1 + axis, 1 + axis] = 1.0
    m[1 + axis, 0] = -3.0 * sign
    return m


@wp.func
def neighbour_triplet(
    index: wp.array3d(dtype=wp.int32),
    n_interior: int,
    row: int,
    nb: wp.vec3i,
    block: wp.mat44f,
    slot: int,
    rows: wp.array(dtype=int),
    cols: wp.array(dtype=int),
    blocks: wp.array(dtype=wp.mat44f),
):
    """Triplet `slot`: (row, neighbour's row, block), or -1 indices when the neighbour is known data."""
    col = int(index[nb[0], nb[1], nb[2]])
    if col >= n_interior:
        col = -1
    rows[slot] = wp.where(col >= 0, row, -1)
    cols[slot] = col
    blocks[slot] = block


@wp.kernel
def fine_operator_triplets(
    interior_ijk: wp.array(dtype=wp.vec3i),
    index: wp.array3d(dtype=wp.int32),
    n_interior: int,
    rows: wp.array(dtype=int),
    cols: wp.array(dtype=int),
    blocks: wp.array(dtype=wp.mat44f),
):
    """The 19 blocks of each interior row of A_II: 19 triplet slots per node, -1 where the neighbour is known."""
    n = wp.tid()
    c = interior_ijk[n]
    base = 19 * n
    centre = wp.mat44f()
    centre[0, 0] = 48.0
    centre[1, 1] = 4.0
    centre[2, 2] = 4.0
    centre[3, 3] = 4.0
    rows[base] = n
    cols[base] = n
    blocks[base] = centre
    slot = base + 1
    for axis in range(3):
        for side in range(2):
            e = wp.vec3i(0, 0, 0)
            e[axis] = 2 * side - 1
            neighbour_triplet(index, n_interior, n, c + e, face_block(axis, float(2 * side - 1)), slot, rows, cols,
                              blocks)
            slot += 1
    edge = wp.mat44f()
    edge[0, 0] = 1.0
    for a in range(3):
        for sa in range(2):
            for sb in range(2):
                e = wp.vec3i(0, 0, 0)
                e[a] = 2 * sa - 1
                e[(a + 1) % 3] = 2 * sb - 1
                neighbour_triplet(index, n_interior, n, c + e, edge, slot, rows, cols, blocks)
                slot += 1


# ---------------------------------------------------------------------------------------------------------------
# coarsening and cubic Hermite prolongation


@wp.kernel
def coarse_coverage(
    fine_index: wp.array3d(dtype=wp.int32),
    coarse_count: wp.array3d(dtype=wp.int32),
):
    """Number of fine unknown nodes among the 27 fine nodes f with |f - 2c| <= 1 around coarse node c."""
    i, j, k = wp.tid()
    count = int(0)
    for di in range(-1, 2):
        for dj in range(-1, 2):
            for dk in range(-1, 2):
                fi = 2 * i + di
                fj = 2 * j + dj
                fk = 2 * k + dk
                if fi >= 0 and fj >= 0 and fk >= 0:
                    if fi < fine_index.shape[0] and fj < fine_index.shape[1] and fk < fine_index.shape[2]:
                        if fine_index[fi, fj, fk] >= 0:
                            count += 1
    coarse_count[i, j, k] = count


@wp.func
def hermite_1d(axis: int, parity: int, side: int):
    """Block applied along `axis` to a coarse parent's (q, G) (G in coarse units).

    parity 0: the fine node sits on the parent (identity). parity 1: it is the edge midpoint between the parents
    side 0 (left) and side 1 (right): cubic Hermite value (q0+q1)/2 + (G0-G1)/8 and slope 1.5(q1-q0) -
    (G0+G1)/4 along the axis, linear averages of the transverse gradients."""
    m = wp.mat44f()
    if parity == 0:
        m = wp.identity(n=4, dtype=wp.float32)
    else:
        sign = float(2 * side - 1)  # -1 left, +1 right
        a = 1 + axis
        m[0, 0] = 0.5
        m[0, a] = -0.125 * sign
        m[a, 0] = 1.5 * sign
        m[a, a] = -0.25
        for b in range(3):
            if b != axis:
                m[1 + b, 1 + b] = 0.5
    return m


@wp.kernel
def prolongation_triplets(
    fine_ijk: wp.array(dtype=wp.vec3i),
    coarse_index: wp.array3d(dtype=wp.int32),
    rows: wp.array(dtype=int),
    cols: wp.array(dtype=int),
    blocks: wp.array(dtype=wp.mat44f),
):
    """P's blocks for each fine unknown: 8 triplet slots (parents), -1 where a parent does not exist or is
    not kept. The tensor product applies x, then y, then z, and rescales G to fine units at the end."""
    n = wp.tid()
    f = fine_ijk[n]
    px = f[0] % 2
    py = f[1] % 2
    pz = f[2] % 2
    to_fine = wp.mat44f()
    to_fine[0, 0] = 1.0
    to_fine[1, 1] = 0.5
    to_fine[2, 2] = 0.5
    to_fine[3, 3] = 0.5
    for slot in range(8):
        sx = slot & 1
        sy = (slot >> 1) & 1
        sz = (slot >> 2) & 1
        col = int(-1)
        # a parity-0 axis has one parent: only side 0 is used
        if (px == 1 or sx == 0) and (py == 1 or sy == 0) and (pz == 1 or sz == 0):
            ci = (f[0] - px) // 2 + sx
            cj = (f[1] - py) // 2 + sy
            ck = (f[2] - pz) // 2 + sz
            if ci < coarse_index.shape[0] and cj < coarse_index.shape[1] and ck < coarse_index.shape[2]:
                col = int(coarse_index[ci, cj, ck])
        m = wp.mat44f()
        if col >= 0:
            m = to_fine * (hermite_1d(2, pz, sz) * (hermite_1d(1, py, sy) * hermite_1d(0, px, sx)))
        rows[8 * n + slot] = wp.where(col >= 0, n, -1)
        cols[8 * n + slot] = col
        blocks[8 * n + slot] = m


# ---------------------------------------------------------------------------------------------------------------
# batched (node, handle) operations


@wp.kernel
def bsr_apply(
    offsets: wp.array(dtype=int),
    columns: wp.array(dtype=int),
    blocks: wp.array(dtype=wp.mat44f),
    x: wp.array2d(dtype=wp.vec4f),
    alpha: float,
    beta: float,
    y: wp.array2d(dtype=wp.vec4f),
):
    """y = alpha A x + beta y for a compact 4x4-block sparse A, every handle a column; launch (rows, handles)."""
    row, h = wp.tid()
    acc = wp.vec4f(0.0)
    for k in range(offsets[row], offsets[row + 1]):
        acc += blocks[k] * x[columns[k], h]
    if beta == 0.0:
        y[row, h] = alpha * acc
    else:
        y[row, h] = alpha * acc + beta * y[row, h]


@wp.kernel
def invert_blocks(blocks: wp.array(dtype=wp.mat44f), inverse: wp.array(dtype=wp.mat44f)):
    i = wp.tid()
    inverse[i] = wp.inverse(blocks[i])


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
    v = scale * (inv_diag[n] * r[n, h])
    d[n, h] = v
    x[n, h] = x[n, h] + v


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
    v = a * d[n, h] + b * (inv_diag[n] * r[n, h])
    d[n, h] = v
    x[n, h] = x[n, h] + v


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
