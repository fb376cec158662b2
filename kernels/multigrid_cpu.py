"""The multigrid's applying kernels for a CPU: a thread per row looping over the handles, the loop in C++.

Warp runs a CPU kernel's threads one after another on one core (NVIDIA/warp#1309), and its code for a loop over a
row's handles takes them one at a time. Here a thread finds its row's neighbours (a coarse operator's 27 blocks, a
coarse node's fine rows, a fine node's parents) once, then applies each block to all handles' columns in a loop a
compiler vectorises (:func:`block_sum_source`): every row's handles are consecutive vec4s. The sums are those of
``multigrid``'s kernels for a GPU (a thread per row and handle) term for term, in their order and without fused
multiply-adds (Warp's CPU code has none), so they give the same bits (tests/test_multigrid.py). On a cage of about a
hundred handles a coarse Chebyshev step, a restriction and a prolongation each take a quarter to a third of the time
of Warp's loop.
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

from .multigrid import diagonal_block, neighbour_offset, node_row, parent_entry, parent_slot

#: this module's kernels run on a CPU only (a GPU runs ``multigrid``'s thread per row and handle)
DEVICE_KINDS = ("cpu",)

#: handles per pass of a row's loop: the pass's sums stay in a buffer of this many vec4s
COLUMNS_PER_PASS = 64

#: the first line of every snippet: no products contracted into fused multiply-adds (Warp's CPU code has none)
NO_CONTRACTION = "#pragma clang fp contract(off)"

#: a coarse node's fine rows (at most 27) and a fine node's parents (at most 8)
_row_list27 = wp.types.vector(length=27, dtype=wp.int32)
_row_list8 = wp.types.vector(length=8, dtype=wp.int32)


def _row(array: str, row: str) -> str:
    """C++: a pointer to the first float of row ``row`` of the (rows, handles) vec4 array ``array``."""
    return f"(const float*)((const char*){array}.data + (size_t)({row}) * {array}.strides[0])"


def block_sum_source(transposed: bool, epilogue: list[str]) -> str:
    """C++ that sums ``count`` blocks times columns for every handle of a row, COLUMNS_PER_PASS handles at a time:
    ``acc[4 h + i] = sum_k (B_k x_k[h])_i`` over k in order, each product as Warp's mat44 * vec4 forms it
    (((B_i0 x0 + B_i1 x1) + B_i2 x2) + B_i3 x3; with ``transposed``, B_k's transpose), then ``epilogue`` (lines with
    the pass's handle ``h``, ``k = 4 h`` and its first handle ``h0``). Expects ``H``, ``count``, ``block[k]`` (16
    floats, row-major) and ``column[k]`` (a row's first float)."""
    lines = [
        f"float acc[4 * {COLUMNS_PER_PASS}];",
        f"for (int h0 = 0; h0 < H; h0 += {COLUMNS_PER_PASS}) {{",
        f"    const int m = H - h0 < {COLUMNS_PER_PASS} ? H - h0 : {COLUMNS_PER_PASS};",
        "    for (int j = 0; j < 4 * m; ++j) acc[j] = 0.0f;",
        "    for (int s = 0; s < count; ++s) {",
        "        const float* B = block[s];",
    ]
    for i in range(4):
        entries = ", ".join(f"b{i}{j} = B[{4 * j + i if transposed else 4 * i + j}]" for j in range(4))
        lines.append(f"        const float {entries};")
    lines += [
        "        const float* __restrict__ x = column[s] + 4 * h0;",
        "        for (int h = 0; h < m; ++h) {",
        "            const int k = 4 * h;",
        "            const float x0 = x[k], x1 = x[k + 1], x2 = x[k + 2], x3 = x[k + 3];",
    ]
    lines += [f"            acc[k + {i}] = acc[k + {i}] + (((b{i}0 * x0 + b{i}1 * x1) + b{i}2 * x2) + b{i}3 * x3);"
              for i in range(4)]
    lines += [
        "        }",
        "    }",
        "    for (int h = 0; h < m; ++h) {",
        "        const int k = 4 * h;",
        *("        " + line for line in epilogue),
        "    }",
        "}",
    ]
    return "\n".join(lines)


def _stencil_source(epilogue: list[str]) -> str:
    """C++ of a row of a 27-point block stencil: its existing neighbours' blocks and columns, then their sums."""
    return "\n".join([
        "const int H = x.shape[1];",
        "const int* neighbour = (const int*)((const char*)rows.data + (size_t)n * rows.strides[0]);",
        "const char* blocks_of_row = (const char*)blocks.data + (size_t)n * blocks.strides[0];",
        "const float* block[27];",
        "const float* column[27];",
        "int count = 0;",
        "for (int o = 0; o < 27; ++o) {",
        "    const int col = neighbour[o];",
        "    if (col >= 0) {",
        "        block[count] = (const float*)(blocks_of_row + (size_t)o * blocks.strides[1]);",
        f"        column[count] = {_row('x', 'col')};",
        "        ++count;",
        "    }",
        "}",
        block_sum_source(False, epilogue),
    ])


_STEP = [
    # v = ca d + cb (D^-1 (b - A x)); d = v; x_next = x + v
    "const float r0 = b_row[h0 * 4 + k] - acc[k], r1 = b_row[h0 * 4 + k + 1] - acc[k + 1];",
    "const float r2 = b_row[h0 * 4 + k + 2] - acc[k + 2], r3 = b_row[h0 * 4 + k + 3] - acc[k + 3];",
    *(f"const float v{i} = ca * d_row[h0 * 4 + k + {i}] + cb * (((D[{4 * i}] * r0 + D[{4 * i + 1}] * r1) "
      f"+ D[{4 * i + 2}] * r2) + D[{4 * i + 3}] * r3);" for i in range(4)),
    *(f"d_row[h0 * 4 + k + {i}] = v{i};" for i in range(4)),
    *(f"next_row[h0 * 4 + k + {i}] = x_row[h0 * 4 + k + {i}] + v{i};" for i in range(4)),
]


@wp.func_native("\n".join([
    NO_CONTRACTION,
    "const float* b_row = " + _row("b", "n") + ";",
    "const float* x_row = " + _row("x", "n") + ";",
    "float* d_row = (float*)((char*)d.data + (size_t)n * d.strides[0]);",
    "float* next_row = (float*)((char*)x_next.data + (size_t)n * x_next.strides[0]);",
    "const float* D = &d_inv.data[0][0];",
    _stencil_source(_STEP),
]))
def _chebyshev_step_row(blocks: wp.array2d(dtype=wp.mat44f), rows: wp.array2d(dtype=wp.int32),
                        b: wp.array2d(dtype=wp.vec4f), x: wp.array2d(dtype=wp.vec4f), d_inv: wp.mat44f, ca: float,
                        cb: float, d: wp.array2d(dtype=wp.vec4f), x_next: wp.array2d(dtype=wp.vec4f), n: int): ...


@wp.func_native("\n".join([
    NO_CONTRACTION,
    "const float* b_row = " + _row("b", "n") + ";",
    "float* out_row = (float*)((char*)out.data + (size_t)n * out.strides[0]);",
    _stencil_source([f"out_row[h0 * 4 + k + {i}] = b_row[h0 * 4 + k + {i}] - acc[k + {i}];" for i in range(4)]),
]))
def _residual_row(blocks: wp.array2d(dtype=wp.mat44f), rows: wp.array2d(dtype=wp.int32),
                  b: wp.array2d(dtype=wp.vec4f), x: wp.array2d(dtype=wp.vec4f), out: wp.array2d(dtype=wp.vec4f),
                  n: int): ...


@wp.kernel
def stencil_chebyshev_step_rows(
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
    """``multigrid.stencil_chebyshev_step`` for a CPU: d = ca d + cb D^-1 (b - A x), x_next = x + d (x_next is not
    x), the same bits. Launch (rows,)."""
    n = wp.tid()
    _chebyshev_step_row(blocks, rows, b, x, diagonal_block(inv_diag, n), ca, cb, d, x_next, n)


@wp.kernel
def stencil_residual_rows(
    blocks: wp.array2d(dtype=wp.mat44f),
    rows: wp.array2d(dtype=wp.int32),
    b: wp.array2d(dtype=wp.vec4f),
    x: wp.array2d(dtype=wp.vec4f),
    out: wp.array2d(dtype=wp.vec4f),
):
    """``multigrid.stencil_residual`` for a CPU: out = b - A x (out may be b, not x), the same bits. Launch
    (rows,)."""
    n = wp.tid()
    _residual_row(blocks, rows, b, x, out, n)


def _table_source(rows_name: str, array: str, epilogue: list[str], transposed: bool) -> str:
    """C++ of a transfer's row: the table's blocks ``entries`` and the rows ``rows_name`` of ``array``."""
    return "\n".join([
        f"const int H = {array}.shape[1];",
        "const float* block[27];",
        "const float* column[27];",
        "for (int s = 0; s < count; ++s) {",
        "    block[s] = &table.data[entries.c[s]].data[0][0];",
        f"    column[s] = {_row(array, rows_name + '.c[s]')};",
        "}",
        block_sum_source(transposed, epilogue),
    ])


@wp.func_native("\n".join([
    NO_CONTRACTION,
    "float* out_row = (float*)((char*)b.data + (size_t)m * b.strides[0]);",
    _table_source("rows", "r", [f"out_row[h0 * 4 + k + {i}] = acc[k + {i}];" for i in range(4)], transposed=True),
]))
def _restrict_row(table: wp.array(dtype=wp.mat44f), rows: _row_list27, entries: _row_list27, count: int,
                  r: wp.array2d(dtype=wp.vec4f), b: wp.array2d(dtype=wp.vec4f), m: int): ...


@wp.func_native("\n".join([
    NO_CONTRACTION,
    "float* x_row = (float*)((char*)x.data + (size_t)n * x.strides[0]);",
    _table_source("cols", "xc", [f"x_row[h0 * 4 + k + {i}] = x_row[h0 * 4 + k + {i}] + acc[k + {i}];"
                                 for i in range(4)], transposed=False),
]))
def _prolong_row(table: wp.array(dtype=wp.mat44f), cols: _row_list8, entries: _row_list8, count: int,
                 xc: wp.array2d(dtype=wp.vec4f), x: wp.array2d(dtype=wp.vec4f), n: int): ...


@wp.kernel
def restrict_rows(
    table: wp.array(dtype=wp.mat44f),
    coarse_ijk: wp.array(dtype=wp.vec3i),
    fine_index: wp.array3d(dtype=wp.int32),
    n_fine: int,
    shift: wp.vec3i,
    r: wp.array2d(dtype=wp.vec4f),
    b: wp.array2d(dtype=wp.vec4f),
):
    """``multigrid.restrict`` for a CPU: b = P^T r, a thread per coarse node finding its fine rows and their blocks
    once, the same bits. Launch (coarse rows,)."""
    m = wp.tid()
    c = coarse_ijk[m]
    rows = _row_list27()
    entries = _row_list27()
    count = int(0)
    for s in range(27):
        d = neighbour_offset(s)
        row = node_row(fine_index, n_fine, 2 * c + d + shift)
        if row >= 0:
            rows[count] = row
            entries[count] = parent_entry(d)
            count += 1
    _restrict_row(table, rows, entries, count, r, b, m)


@wp.kernel
def prolong_add_rows(
    table: wp.array(dtype=wp.mat44f),
    fine_ijk: wp.array(dtype=wp.vec3i),
    coarse_index: wp.array3d(dtype=wp.int32),
    shift: wp.vec3i,
    xc: wp.array2d(dtype=wp.vec4f),
    x: wp.array2d(dtype=wp.vec4f),
):
    """``multigrid.prolong_add`` for a CPU: x += P xc, a thread per fine node finding its kept parents once, the
    same bits. Launch (fine rows,)."""
    n = wp.tid()
    f = fine_ijk[n] - shift
    cols = _row_list8()
    entries = _row_list8()
    count = int(0)
    for slot in range(8):
        parent = parent_slot(f, slot)
        if parent[3] != 0:
            d = wp.vec3i(parent[0], parent[1], parent[2])
            col = node_row(coarse_index, xc.shape[0], (f - d) / 2)
            if col >= 0:
                cols[count] = col
                entries[count] = parent_entry(d)
                count += 1
    _prolong_row(table, cols, entries, count, xc, x, n)
