"""Trilinear sampling of the nodal weight field at mesh vertices."""

import warp as wp


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
