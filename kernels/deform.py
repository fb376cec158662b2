"""Deformation p'_j = sum_l w_j(l) c'_l for a batch of cage poses."""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.kernel
def deform_vertices(
    weights_t: wp.array2d(dtype=wp.float32),
    offsets: wp.array2d(dtype=wp.vec3f),
    centres: wp.array(dtype=wp.vec3f),
    out: wp.array2d(dtype=wp.vec3f),
):
    """out[f, v] = centre_f + sum_l weights_t[l, v] offsets[f, l]; launch (frames, vertices).

    `offsets` are the pose's handles relative to its centre (exact by partition of unity), which keeps the
    float32 sums small. Weights are stored handle-major so that neighbouring vertices read neighbouring
    addresses."""
    f, v = wp.tid()
    acc = wp.vec3f(0.0)
    for l in range(weights_t.shape[0]):
        acc += weights_t[l, v] * offsets[f, l]
    out[f, v] = centres[f] + acc
