"""A posteriori checks of a weight field: partition of unity and linear precision at the nodes."""

import warp as wp


@wp.kernel
def identity_deviation(
    field: wp.array2d(dtype=wp.vec4f),
    positions: wp.array(dtype=wp.vec3d),
    handles: wp.array(dtype=wp.vec3d),
    scale: wp.float64,
    out: wp.array(dtype=float),
):
    """out[0] = max over rows n of max(|sum_h q_h - 1|, |sum_h q_h c_h - x_n| / scale).

    The exact discrete solution reproduces constants and linear functions, so this is a lower bound on the
    error of the weights that costs one pass over the field; launch over rows."""
    n = wp.tid()
    total = wp.float64(0.0)
    moment = wp.vec3d()
    for h in range(handles.shape[0]):
        q = wp.float64(field[n, h][0])
        total += q
        moment += q * handles[h]
    d = wp.max(wp.abs(total - wp.float64(1.0)), wp.length(moment - positions[n]) / scale)
    wp.atomic_max(out, 0, float(d))
