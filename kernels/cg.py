"""Batched preconditioned conjugate gradients: every handle is an independent column with its own scalars.

Column reductions and updates run over (chunk, handle) threads: each thread strides over rows
n = chunk, chunk + n_chunks, ... and adds its partial sum to the handle's float64 accumulator once, so the
threads of one row still touch consecutive handles. A handle whose `running` flag is 0 is left untouched.
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

INV_DIAGONAL = wp.constant(wp.vec4f(1.0 / 48.0, 0.25, 0.25, 0.25))


@wp.kernel
def jacobi(r: wp.array2d(dtype=wp.vec4f), z: wp.array2d(dtype=wp.vec4f)):
    """z = D^-1 r with D = diag(48, 4, 4, 4), the diagonal of the fine operator."""
    n, h = wp.tid()
    z[n, h] = wp.cw_mul(INV_DIAGONAL, r[n, h])


@wp.kernel
def residual(
    rhs: wp.array2d(dtype=wp.vec4f),
    applied: wp.array2d(dtype=wp.vec4f),
    out: wp.array2d(dtype=wp.vec4f),
):
    """out = rhs - applied (out may alias either input)."""
    n, h = wp.tid()
    out[n, h] = rhs[n, h] - applied[n, h]


@wp.kernel
def negate(a: wp.array2d(dtype=wp.vec4f), out: wp.array2d(dtype=wp.vec4f)):
    """out = -a (out may alias a)."""
    n, h = wp.tid()
    out[n, h] = -a[n, h]


@wp.kernel
def add_columns(a: wp.array2d(dtype=wp.vec4f), b: wp.array2d(dtype=wp.vec4f), out: wp.array2d(dtype=wp.vec4f)):
    """out = a + b."""
    n, h = wp.tid()
    out[n, h] = a[n, h] + b[n, h]


@wp.kernel
def clear_columns(x: wp.array2d(dtype=wp.vec4f), cleared: wp.array(dtype=wp.int32)):
    """x[:, h] = 0 for every handle h with cleared[h] != 0."""
    n, h = wp.tid()
    if cleared[h] != 0:
        x[n, h] = wp.vec4f(0.0)


@wp.kernel
def column_dots(
    a: wp.array2d(dtype=wp.vec4f),
    b: wp.array2d(dtype=wp.vec4f),
    n_chunks: int,
    out: wp.array(dtype=wp.float64),
):
    """out[h] += sum_n a[n, h] . b[n, h]; launch (chunks, handles) on a zeroed `out`."""
    c, h = wp.tid()
    acc = wp.float64(0.0)
    for n in range(c, a.shape[0], n_chunks):
        acc += wp.float64(wp.dot(a[n, h], b[n, h]))
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
):
    """x += alpha p, r -= alpha A p with alpha = r.z / p.Ap per handle."""
    n, h = wp.tid()
    if running[h] == 0 or pap[h] <= wp.float64(0.0):
        return
    alpha = wp.float32(rz[h] / pap[h])
    x[n, h] = x[n, h] + alpha * p[n, h]
    r[n, h] = r[n, h] - alpha * ap[n, h]


@wp.kernel
def new_directions(
    z: wp.array2d(dtype=wp.vec4f),
    p: wp.array2d(dtype=wp.vec4f),
    rz: wp.array(dtype=wp.float64),
    rz_next: wp.array(dtype=wp.float64),
    running: wp.array(dtype=wp.int32),
):
    """p = z + beta p with beta = rz_next / rz."""
    n, h = wp.tid()
    if running[h] == 0:
        return
    beta = wp.float32(0.0)
    if rz[h] > wp.float64(0.0):
        beta = wp.float32(rz_next[h] / rz[h])
    p[n, h] = z[n, h] + beta * p[n, h]
