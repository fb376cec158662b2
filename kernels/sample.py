"""Sampling the nodal weight field at mesh vertices: tricubic Hermite of (q, G = h grad q), or trilinear of q."""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.kernel
def locate_cells(
    points: wp.array(dtype=wp.vec3d),
    origin: wp.vec3d,
    spacing: wp.float64,
    index: wp.array3d(dtype=wp.int32),
    corners: wp.array2d(dtype=wp.int32),
    fractions: wp.array(dtype=wp.vec3d),
):
    """Rows of the 8 corners of the cell holding each point (corner c = (c&1, c>>1&1, c>>2&1) offsets),
    -1 where a corner is not an active node or the point is off the grid, and the point's offset in the cell."""
    v = wp.tid()
    u = (points[v] - origin) / spacing
    i = int(wp.floor(u[0]))
    j = int(wp.floor(u[1]))
    k = int(wp.floor(u[2]))
    fractions[v] = wp.vec3d(u[0] - wp.float64(i), u[1] - wp.float64(j), u[2] - wp.float64(k))
    inside = i >= 0 and j >= 0 and k >= 0
    inside = inside and i + 1 < index.shape[0] and j + 1 < index.shape[1] and k + 1 < index.shape[2]
    for c in range(8):
        row = int(-1)
        if inside:
            row = index[i + (c & 1), j + ((c >> 1) & 1), k + ((c >> 2) & 1)]
        corners[v, c] = row


@wp.kernel
def sample_trilinear(
    corners: wp.array2d(dtype=wp.int32),
    fractions: wp.array(dtype=wp.vec3d),
    field: wp.array2d(dtype=wp.vec4f),
    weights: wp.array2d(dtype=wp.float32),
):
    """weights[v, h] = trilinear interpolation of q over the cell's corners; launch (vertices, handles)."""
    v, h = wp.tid()
    f = fractions[v]
    one = wp.float64(1.0)
    acc = wp.float64(0.0)
    for c in range(8):
        row = corners[v, c]
        wx = wp.where((c & 1) == 1, f[0], one - f[0])
        wy = wp.where(((c >> 1) & 1) == 1, f[1], one - f[1])
        wz = wp.where(((c >> 2) & 1) == 1, f[2], one - f[2])
        if row >= 0:
            acc += wx * wy * wz * wp.float64(field[row, h][0])
    weights[v, h] = wp.float32(acc)


@wp.func
def hermite_value(t: wp.float64, corner: int):
    """The 1D cubic Hermite basis for the value at corner 0 (2t^3 - 3t^2 + 1) or corner 1 (-2t^3 + 3t^2)."""
    t2 = t * t
    if corner == 0:
        return wp.float64(2.0) * t2 * t - wp.float64(3.0) * t2 + wp.float64(1.0)
    return wp.float64(-2.0) * t2 * t + wp.float64(3.0) * t2


@wp.func
def hermite_slope(t: wp.float64, corner: int):
    """The 1D cubic Hermite basis for the scaled derivative h q' at corner 0 (t^3 - 2t^2 + t) or 1 (t^3 - t^2)."""
    t2 = t * t
    if corner == 0:
        return t2 * t - wp.float64(2.0) * t2 + t
    return t2 * t - t2


@wp.kernel
def sample_hermite(
    corners: wp.array2d(dtype=wp.int32),
    fractions: wp.array(dtype=wp.vec3d),
    field: wp.array2d(dtype=wp.vec4f),
    weights: wp.array2d(dtype=wp.float32),
):
    """weights[v, h] = tricubic Hermite interpolation of (q, G) over the cell's corners, mixed derivatives zero;
    launch (vertices, handles).

    The tensor product of 1D cubic Hermite interpolants, with the second and third mixed derivatives taken as zero
    at every node: on a cell face the value and the normal derivative depend on that face's corners only, so the
    interpolant is C1 across faces; it reproduces every function whose mixed derivatives vanish, linear ones among
    them (partition of unity and linear precision stay exact)."""
    v, h = wp.tid()
    f = fractions[v]
    acc = wp.float64(0.0)
    for c in range(8):
        row = corners[v, c]
        if row >= 0:
            a = c & 1
            b = (c >> 1) & 1
            d = (c >> 2) & 1
            node = field[row, h]
            hx = hermite_value(f[0], a)
            hy = hermite_value(f[1], b)
            hz = hermite_value(f[2], d)
            acc += wp.float64(node[0]) * hx * hy * hz
            acc += wp.float64(node[1]) * hermite_slope(f[0], a) * hy * hz
            acc += wp.float64(node[2]) * hx * hermite_slope(f[1], b) * hz
            acc += wp.float64(node[3]) * hx * hy * hermite_slope(f[2], d)
    weights[v, h] = wp.float32(acc)
