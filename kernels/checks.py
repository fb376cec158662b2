"""A posteriori checks of a weight field: partition of unity and linear precision at the nodes."""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.kernel
def identity_deviation(
    field: wp.array2d(dtype=wp.vec4f),
    ijk: wp.array(dtype=wp.vec3i),
    origin: wp.vec3d,
    spacing: wp.float64,
    columns: wp.array(dtype=wp.vec4d),
    scale: wp.float64,
    linear: int,
    out: wp.array(dtype=float),
):
    """out[0] = max over rows n of max(|sum_h a_h q_h - 1|, |sum_h c_h q_h - x_n| / scale), with x_n = origin +
    spacing ijk[n] the node's position, where column h contributes (a_h, c_h) = columns[h]: (1, its handle's
    position) for a cage coordinate, other values for columns that stand for sums of handles (the complement of
    a chunk). With ``linear`` = 0 only the first term (partition of unity) is taken.

    The exact discrete solution reproduces constants and linear functions, so this is a lower bound on the
    error of the weights that costs one pass over the field; launch over rows."""
    n = wp.tid()
    total = wp.float64(0.0)
    moment = wp.vec3d()
    for h in range(columns.shape[0]):
        q = wp.float64(field[n, h][0])
        c = columns[h]
        total += q * c[0]
        moment += q * wp.vec3d(c[1], c[2], c[3])
    node = ijk[n]
    x = origin + spacing * wp.vec3d(wp.float64(node[0]), wp.float64(node[1]), wp.float64(node[2]))
    d = wp.abs(total - wp.float64(1.0))
    if linear != 0:
        d = wp.max(d, wp.length(moment - x) / scale)
    wp.atomic_max(out, 0, float(d))
