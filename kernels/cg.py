"""Batched preconditioned conjugate gradients: every handle is an independent column with its own scalars.

Column reductions and updates run over (chunk, handle) threads: each thread strides over rows
n = chunk, chunk + n_chunks, ... and adds its partial sum to the handle's float64 accumulator once, so the
threads of one row still touch consecutive handles. The preconditioner is the inverse diagonal of the
operator, (1/48, 1/4, 1/4, 1/4) per node. A handle whose `running` flag is 0 is left untouched.
"""

import warp as wp

INV_DIAGONAL = wp.constant(wp.vec4f(1.0 / 48.0, 0.25, 0.25, 0.25))


@wp.func
def precondition(r: wp.vec4f):
    return wp.cw_mul(INV_DIAGONAL, r)


@wp.func
def dot64(a: wp.vec4f, b: wp.vec4f):
    return wp.float64(wp.dot(a, b))


@wp.kernel
def residual(
    rhs: wp.array2d(dtype=wp.vec4f),
    applied: wp.array2d(dtype=wp.vec4f),
    out: wp.array2d(dtype=wp.vec4f),
):
    """out = rhs - applied."""
    n, h = wp.tid()
    out[n, h] = rhs[n, h] - applied[n, h]


@wp.kernel
def column_norms(
    r: wp.array2d(dtype=wp.vec4f),
    n_chunks: int,
    out: wp.array(dtype=wp.float64),
):
    """out[h] += r^T M^-1 r over the rows of column h (the squared preconditioned residual norm)."""
    c, h = wp.tid()
    acc = wp.float64(0.0)
    for n in range(c, r.shape[0], n_chunks):
        v = r[n, h]
        acc += dot64(v, precondition(v))
    wp.atomic_add(out, h, acc)


@wp.kernel
def start_directions(r: wp.array2d(dtype=wp.vec4f), p: wp.array2d(dtype=wp.vec4f)):
    """p = M^-1 r."""
    n, h = wp.tid()
    p[n, h] = precondition(r[n, h])


@wp.kernel
def column_curvature(
    p: wp.array2d(dtype=wp.vec4f),
    ap: wp.array2d(dtype=wp.vec4f),
    n_chunks: int,
    out: wp.array(dtype=wp.float64),
):
    """out[h] += p^T A p."""
    c, h = wp.tid()
    acc = wp.float64(0.0)
    for n in range(c, p.shape[0], n_chunks):
        acc += dot64(p[n, h], ap[n, h])
    wp.atomic_add(out, h, acc)


@wp.kernel
def step(
    x: wp.array2d(dtype=wp.vec4f),
    r: wp.array2d(dtype=wp.vec4f),
    p: wp.array2d(dtype=wp.vec4f),
    ap: wp.array2d(dtype=wp.vec4f),
    rz: wp.array(dtype=wp.float64),
    pap: wp.array(dtype=wp.float64),
    running: wp.array(dtype=wp.int32),
    n_chunks: int,
    rz_next: wp.array(dtype=wp.float64),
):
    """x += alpha p, r -= alpha A p with alpha = r^T M^-1 r / p^T A p; accumulates the new r^T M^-1 r."""
    c, h = wp.tid()
    if running[h] == 0:
        return
    alpha = wp.float32(0.0)
    if pap[h] > wp.float64(0.0):
        alpha = wp.float32(rz[h] / pap[h])
    acc = wp.float64(0.0)
    for n in range(c, x.shape[0], n_chunks):
        x[n, h] = x[n, h] + alpha * p[n, h]
        v = r[n, h] - alpha * ap[n, h]
        r[n, h] = v
        acc += dot64(v, precondition(v))
    wp.atomic_add(rz_next, h, acc)


@wp.kernel
def new_directions(
    r: wp.array2d(dtype=wp.vec4f),
    p: wp.array2d(dtype=wp.vec4f),
    rz: wp.array(dtype=wp.float64),
    rz_next: wp.array(dtype=wp.float64),
    running: wp.array(dtype=wp.int32),
):
    """p = M^-1 r + beta p with beta = rz_next / rz."""
    n, h = wp.tid()
    if running[h] == 0:
        return
    beta = wp.float32(0.0)
    if rz[h] > wp.float64(0.0):
        beta = wp.float32(rz_next[h] / rz[h])
    p[n, h] = precondition(r[n, h]) + beta * p[n, h]


@wp.kernel
def add_columns(a: wp.array2d(dtype=wp.vec4f), b: wp.array2d(dtype=wp.vec4f), out: wp.array2d(dtype=wp.vec4f)):
    """out = a + b."""
    n, h = wp.tid()
    out[n, h] = a[n, h] + b[n, h]
