"""The batched CG's column dot products for a CPU: a thread per block of rows, looping over the handles in C++.

``cg.column_dots`` gives each (chunk, handle) thread one handle's entries of every chunk-th row: on a GPU the
threads of a warp read neighbouring handles at once, but a CPU runs the threads one after another (NVIDIA/warp#1309),
so each walks the whole array reading 16 bytes of every row it touches (on one thread the products were then a large
part of the solve). Here a thread sums a block of consecutive rows for 64 handles at a time, reading
each row's entries in order. Each handle's sum runs over the rows in order, then over the blocks in order: the same
numbers whatever the other handles (threads solving chunks of handles at once give the bits of one thread).
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

#: this module's kernels run on a CPU only
DEVICE_KINDS = ("cpu",)

#: handles per pass over a block of rows: their float64 sums stay in a buffer of this many
COLUMNS_PER_PASS = 64

_DOTS = f"""
const int H = a.shape[1];
double acc[{COLUMNS_PER_PASS}];
for (int h0 = 0; h0 < H; h0 += {COLUMNS_PER_PASS}) {{
    const int m = H - h0 < {COLUMNS_PER_PASS} ? H - h0 : {COLUMNS_PER_PASS};
    for (int h = 0; h < m; ++h) acc[h] = 0.0;
    for (int n = first; n < stop; ++n) {{
        const float* __restrict__ x = (const float*)((const char*)a.data + (size_t)n * a.strides[0]) + 4 * h0;
        const float* __restrict__ y = (const float*)((const char*)b.data + (size_t)n * b.strides[0]) + 4 * h0;
        for (int h = 0; h < m; ++h) {{
            const int k = 4 * h;
            float d = 0.0f;  // as Warp's dot of two vec4s
            d += x[k] * y[k];
            d += x[k + 1] * y[k + 1];
            d += x[k + 2] * y[k + 2];
            d += x[k + 3] * y[k + 3];
            acc[h] += (double)d;
        }}
    }}
    for (int h = 0; h < m; ++h) out.data[h0 + h] += acc[h];
}}
"""


@wp.func_native(_DOTS)
def _block_dots(a: wp.array2d(dtype=wp.vec4f), b: wp.array2d(dtype=wp.vec4f), first: int, stop: int,
                out: wp.array(dtype=wp.float64)): ...


@wp.kernel
def column_dots_rows(
    a: wp.array2d(dtype=wp.vec4f),
    b: wp.array2d(dtype=wp.vec4f),
    n_blocks: int,
    out: wp.array(dtype=wp.float64),
):
    """out[h] += sum_n a[n, h] . b[n, h] (``cg.column_dots`` for a CPU); launch (n_blocks,) on a zeroed, contiguous
    ``out``. The blocks' sums are added one after another: a CPU runs a launch's threads in turn."""
    c = wp.tid()
    size = (a.shape[0] + n_blocks - 1) // n_blocks
    _block_dots(a, b, wp.min(c * size, a.shape[0]), wp.min((c + 1) * size, a.shape[0]), out)
