"""The compact scheme's operator for a CPU: one thread per interior node, looping over the handles.

Warp runs a CPU kernel's threads one after another on one core (NVIDIA/warp#1309). The GPU's patch walk
(``stencil.operator_kernel``: a thread per handle and patch of columns) then repeats each node's index look-ups and
plane reductions for every handle. Here a thread takes its node's 18 neighbour rows from a table formed once per grid
(:func:`neighbour_rows`) and applies the stencil to every handle's column in turn; a row's handles are consecutive in
memory, so the 19 rows a node reads are 19 streams. The loop over the handles is C++ (:func:`node_operator_source`),
which the compiler vectorises: Warp's code for the same loop takes one handle at a time. On one thread, with a
hundred-odd handles, the node loop takes a fraction of the walk's time per application, and the C++ loop less again.

The sums are the walk's, term for term and in its order, in the same precision (float32 for Krylov and smoothing
steps, float64 for residuals), without fused multiply-adds: both kernels give the same bits (tests/test_solve.py).
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

from .stencil import APPLY, RESIDUAL, STEP

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


#: handles per pass of a node's loop: a neighbour outside the unknowns reads this many zero columns
COLUMNS_PER_PASS = 64


def node_operator_source(scalar, mode) -> str:
    """The C++ of a node's loop over the handles (see :func:`node_operator_kernel`): the sums of the walk, term for
    term and in its order, with no contraction into fused multiply-adds (Warp's CPU code has none), so each handle's
    numbers are the walk's bits whatever width the compiler's vectors have. ``field``'s rows are addressed through
    its row pitch; a row's handles are consecutive vec4s (every array here is a row slice of a (rows, handles) array,
    which :func:`warp_stokes.solver.operator.apply_operator` checks)."""
    T = "double" if scalar is wp.float64 else "float"
    rhs = mode != APPLY
    step = mode == STEP
    names = ("xp", "xm", "yp", "ym", "zp", "zm", "e0", "e1", "e2", "e3", "a0", "a1", "a2", "a3", "b0", "b1", "b2",
             "b3")
    lines = [
        "#pragma clang fp contract(off)",
        f"typedef {T} real;",
        f"static const float zeros[4 * {COLUMNS_PER_PASS}] = {{}};",
        "const int H = out.shape[1];",
        "const char* base = (const char*)field.data;",
        "const size_t pitch = field.strides[0];",
        "const int* neighbour = (const int*)((const char*)rows.data + (size_t)n * rows.strides[0]);",
        "const float* row_of[18];",
        "for (int e = 0; e < 18; ++e) {",
        "    const int r = neighbour[e];",
        "    row_of[e] = (r >= 0 && r < n_rows) ? (const float*)(base + (size_t)r * pitch) : nullptr;",
        "}",
        "const float* centre = (const float*)(base + (size_t)n * pitch);",
        "float* out_row = (float*)((char*)out.data + (size_t)n * out.strides[0]);",
    ]
    if rhs:
        lines.append("const float* rhs_row = (const float*)((const char*)rhs.data + (size_t)n * rhs.strides[0]);")
    if step:
        lines.append("float* d_row = (float*)((char*)d.data + (size_t)n * d.strides[0]);")
    lines += [
        f"for (int h0 = 0; h0 < H; h0 += {COLUMNS_PER_PASS}) {{",
        f"    const int m = H - h0 < {COLUMNS_PER_PASS} ? H - h0 : {COLUMNS_PER_PASS};",
        "    const float* __restrict__ c = centre + 4 * h0;",
    ]
    # `out` may be `rhs` (a residual in place: each entry is read before it is written): those two are not
    # restricted, and the compiler's check of their overlap picks its vectorised loop when they are apart
    lines.append("    float* o = out_row + 4 * h0;" if rhs and not step else "    float* __restrict__ o = out_row + 4 * h0;")
    lines += [f"    const float* __restrict__ {name} = row_of[{e}] ? row_of[{e}] + 4 * h0 : zeros;"
              for e, name in enumerate(names)]
    if rhs:
        lines.append("    const float* g = rhs_row + 4 * h0;")
    if step:
        lines.append("    float* __restrict__ dd = d_row + 4 * h0;")
    lines += [
        "    for (int h = 0; h < m; ++h) {",
        "        const int k = 4 * h;",
        "        const real three = real(3.0), four = real(4.0);",
        "        const real c0 = c[k], c1 = c[k + 1], c2 = c[k + 2], c3 = c[k + 3];",
        "        const real xp0 = xp[k], xp1 = xp[k + 1], xm0 = xm[k], xm1 = xm[k + 1];",
        "        const real yp0 = yp[k], yp2 = yp[k + 2], ym0 = ym[k], ym2 = ym[k + 2];",
        "        const real corners = (real(e0[k]) + real(e1[k])) + (real(e2[k]) + real(e3[k]));",
        "        const real faces = (xp0 + xm0) + (yp0 + ym0);",
        "        const real in_plane = real(48.0) * c0 - real(10.0) * faces + corners + three * ((xp1 - xm1) + (yp2 - ym2));",
        "        float gx = (float)(xm1 + four * c1 + xp1 - three * (xp0 - xm0));",
        "        float gy = (float)(ym2 + four * c2 + yp2 - three * (yp0 - ym0));",
        "        const real faces_up = (real(a0[k]) + real(a1[k])) + (real(a2[k]) + real(a3[k]));",
        "        const real faces_down = (real(b0[k]) + real(b1[k])) + (real(b2[k]) + real(b3[k]));",
        "        const real q_up = zp[k], q_down = zm[k], gz_up = zp[k + 3], gz_down = zm[k + 3];",
        "        real value = in_plane - real(10.0) * (q_up + q_down) + (faces_up + faces_down);",
        "        value += three * (gz_up - gz_down);",
        "        real gz = gz_down + four * c3 + gz_up - three * (q_up - q_down);",
    ]
    if rhs:
        lines += [
            "        value = real(g[k]) - value;",
            "        gz = real(g[k + 3]) - gz;",
            "        gx = g[k + 1] - gx;",
            "        gy = g[k + 2] - gy;",
        ]
    lines.append("        float r0 = (float)value, r1 = gx, r2 = gy, r3 = (float)gz;")
    if step:
        # INVERSE_DIAGONAL: (1/48, 1/4, 1/4, 1/4) in float32
        lines += [
            "        const float s0 = ca * dd[k] + cb * (r0 * (float)(1.0 / 48.0));",
            "        const float s1 = ca * dd[k + 1] + cb * (r1 * 0.25f);",
            "        const float s2 = ca * dd[k + 2] + cb * (r2 * 0.25f);",
            "        const float s3 = ca * dd[k + 3] + cb * (r3 * 0.25f);",
            "        dd[k] = s0; dd[k + 1] = s1; dd[k + 2] = s2; dd[k + 3] = s3;",
            "        r0 = c[k] + s0; r1 = c[k + 1] + s1; r2 = c[k + 2] + s2; r3 = c[k + 3] + s3;",
        ]
    lines += [
        "        o[k] = r0; o[k + 1] = r1; o[k + 2] = r2; o[k + 3] = r3;",
        "    }",
        "}",
    ]
    return "\n".join(lines)


def node_operator_kernel(scalar, mode):
    """The batched operator for a CPU with sums in `scalar` (wp.float32 or wp.float64) writing, by `mode`, A x
    (``APPLY``), b - A x (``RESIDUAL``) or a Chebyshev step from b - A x (``STEP``): d = ca d + cb D^-1 (b - A x),
    out = x + d. Launch: one thread per interior node.

    A thread applies the stencil to its node's handles in C++ (:func:`node_operator_source`): Warp's CPU code for
    the same loop ran one handle at a time (nearly twice as slow, the same bits), while a compiler vectorises this
    loop over the handles."""

    @wp.func_native(node_operator_source(scalar, mode))
    def node_loop(field: wp.array2d(dtype=wp.vec4f), rows: wp.array2d(dtype=wp.int32), n_rows: int,
                  rhs: wp.array2d(dtype=wp.vec4f), ca: wp.float32, cb: wp.float32, d: wp.array2d(dtype=wp.vec4f),
                  out: wp.array2d(dtype=wp.vec4f), n: int): ...

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
        node_loop(field, rows, n_rows, rhs, ca, cb, d, out, wp.tid())

    return node_operator


#: residuals (float64 sums)
apply_operator = node_operator_kernel(wp.float64, APPLY)
#: Krylov and smoothing applications (float32 sums)
apply_operator_fast = node_operator_kernel(wp.float32, APPLY)
#: b - A x in one pass (float32 sums)
residual_operator_fast = node_operator_kernel(wp.float32, RESIDUAL)
#: a Chebyshev smoothing step from b - A x in one pass (float32 sums)
chebyshev_step_fast = node_operator_kernel(wp.float32, STEP)
