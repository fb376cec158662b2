"""The normal equations of encoding, W^T W and W^T P, summed on the device in float64.

Weights are vertex-major (V, L) so that consecutive threads (consecutive handles) read consecutive addresses of each
vertex's row. Each thread sums one block of vertices and adds its float64 partial sum
atomically: V / block partial sums per entry instead of V sequential ones.
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.kernel
def gram(weights: wp.array2d(dtype=wp.float32), block: int, out: wp.array2d(dtype=wp.float64)):
    """out[i, j] += sum over the vertices of block b of w[v, i] w[v, j], for j >= i (the lower triangle is the
    transpose); launch (blocks, L, L) on a zeroed `out`."""
    b, i, j = wp.tid()
    if j < i:
        return
    start = b * block
    stop = wp.min(start + block, weights.shape[0])
    total = wp.float64(0.0)
    for v in range(start, stop):
        total += wp.float64(weights[v, i]) * wp.float64(weights[v, j])
    wp.atomic_add(out, i, j, total)


@wp.kernel
def project(weights: wp.array2d(dtype=wp.float32), positions: wp.array2d(dtype=wp.vec3d), centre: wp.vec3d,
            block: int, out: wp.array2d(dtype=wp.float64)):
    """out[i, 3 f + d] += sum over the vertices of block b of w[v, i] (p_f[v] - centre)[d]; launch (blocks, frames,
    L) on a zeroed `out`. The threads of a warp are consecutive handles: they read one vertex's row of weights
    (coalesced) and the same position (one load)."""
    b, f, i = wp.tid()
    start = b * block
    stop = wp.min(start + block, weights.shape[0])
    total = wp.vec3d()
    for v in range(start, stop):
        total += wp.float64(weights[v, i]) * (positions[f, v] - centre)
    for d in range(3):
        wp.atomic_add(out, i, 3 * f + d, total[d])
