"""The 7-point Laplace equation in the (q, G) layout of the compact scheme: harmonic coordinates on the same grid.

Harmonic coordinates (Joshi et al. 2007; what Blender's Mesh Deform computes) solve Laplace's equation with the same
boundary data. To run through the same batched CG and multigrid as the biharmonic scheme, a node keeps its vec4
(q, Gx, Gy, Gz), and the system is block diagonal:

    value eq:    6 q_p - sum_face q = h^2 f_p
    gradient eq: G_a(p) = 0

The gradient rows are the identity, decoupled from the values (so the system stays symmetric positive definite and
one Jacobi step solves them); once q is solved, G is set to the central differences of q (``gradient_from_values``),
second-order accurate, which is what the Hermite sampling reads.
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

from .stencil import node_value
from .stencil_cpu import column_at, visible


def laplace_kernel(scalar):
    """The batched 7-point operator with the value equation's sums in `scalar` (wp.float64 for residuals,
    wp.float32 for Krylov and smoothing steps); launch (interior rows, handles)."""

    @wp.kernel(module="unique", enable_backward=False)
    def apply_laplacian(
        field: wp.array2d(dtype=wp.vec4f),
        index: wp.array3d(dtype=wp.int32),
        active_ijk: wp.array(dtype=wp.vec3i),
        n_rows: int,
        out: wp.array2d(dtype=wp.vec4f),
    ):
        # rows of `field` at or beyond `n_rows` read as zero, as in the biharmonic stencil: n_rows = n_interior
        # gives A_II, all active rows include the ring data's forcing
        n, h = wp.tid()
        p = active_ijk[n]
        centre = node_value(field, index, n_rows, p[0], p[1], p[2], h)
        faces = scalar(0.0)
        for a in range(3):
            e = wp.vec3i(0, 0, 0)
            e[a] = 1
            up = p + e
            down = p - e
            faces += scalar(node_value(field, index, n_rows, up[0], up[1], up[2], h)[0]) + scalar(
                node_value(field, index, n_rows, down[0], down[1], down[2], h)[0])
        value = scalar(6.0) * scalar(centre[0]) - faces
        out[n, h] = wp.vec4f(wp.float32(value), centre[1], centre[2], centre[3])

    return apply_laplacian


def laplace_rows_kernel(scalar):
    """:func:`laplace_kernel` for a CPU (where a kernel's threads run one after another): a thread per interior node
    takes its face neighbours' rows from the grid's neighbour table (``stencil_cpu.neighbour_rows``: its first six
    columns) and loops over the handles; the same sums in the same order, the same bits. Launch (interior rows,)."""

    @wp.kernel(module="unique", enable_backward=False)
    def apply_laplacian_rows(
        field: wp.array2d(dtype=wp.vec4f),
        rows: wp.array2d(dtype=wp.int32),
        n_rows: int,
        out: wp.array2d(dtype=wp.vec4f),
    ):
        n = wp.tid()
        xp = visible(rows[n, 0], n_rows)
        xm = visible(rows[n, 1], n_rows)
        yp = visible(rows[n, 2], n_rows)
        ym = visible(rows[n, 3], n_rows)
        zp = visible(rows[n, 4], n_rows)
        zm = visible(rows[n, 5], n_rows)
        for h in range(out.shape[1]):
            centre = field[n, h]
            faces = scalar(0.0)
            faces += scalar(column_at(field, xp, h)[0]) + scalar(column_at(field, xm, h)[0])
            faces += scalar(column_at(field, yp, h)[0]) + scalar(column_at(field, ym, h)[0])
            faces += scalar(column_at(field, zp, h)[0]) + scalar(column_at(field, zm, h)[0])
            value = scalar(6.0) * scalar(centre[0]) - faces
            out[n, h] = wp.vec4f(wp.float32(value), centre[1], centre[2], centre[3])

    return apply_laplacian_rows


#: residuals (float64 sums)
apply_laplacian = laplace_kernel(wp.float64)
#: Krylov and smoothing applications (float32 sums)
apply_laplacian_fast = laplace_kernel(wp.float32)
#: the same on a CPU, a thread per node looping over the handles
apply_laplacian_rows = laplace_rows_kernel(wp.float64)
apply_laplacian_rows_fast = laplace_rows_kernel(wp.float32)
#: the (node, handle) launches a bind makes on a GPU only, and the node loops it makes on a CPU only: a first run
#: compiles those of its device's kind
CUDA_ONLY = (apply_laplacian, apply_laplacian_fast)
CPU_ONLY = (apply_laplacian_rows, apply_laplacian_rows_fast)


@wp.kernel
def gradient_from_values(
    field: wp.array2d(dtype=wp.vec4f),
    index: wp.array3d(dtype=wp.int32),
    active_ijk: wp.array(dtype=wp.vec3i),
):
    """G of interior row n from the values, in place: G_a = (q(p+e_a) - q(p-e_a)) / 2 (every neighbour of an
    interior node is an interior or ring node); launch (interior rows, handles). A thread reads its neighbours' q
    and rewrites its own node with the same q: no thread's reads depend on another's writes."""
    n, h = wp.tid()
    p = active_ijk[n]
    g = wp.vec3f()
    for a in range(3):
        e = wp.vec3i(0, 0, 0)
        e[a] = 1
        up = p + e
        down = p - e
        g[a] = wp.float32(0.5) * (field[index[up[0], up[1], up[2]], h][0] - field[index[down[0], down[1], down[2]], h][0])
    field[n, h] = wp.vec4f(field[n, h][0], g[0], g[1], g[2])


@wp.kernel
def jacobi(r: wp.array2d(dtype=wp.vec4f), z: wp.array2d(dtype=wp.vec4f)):
    """z = D^-1 r with D = diag(6, 1, 1, 1), the diagonal of the 7-point operator."""
    n, h = wp.tid()
    v = r[n, h]
    z[n, h] = wp.vec4f(v[0] / wp.float32(6.0), v[1], v[2], v[3])
