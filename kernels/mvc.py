"""Mean value coordinates of a closed triangle cage (Ju, Schaefer and Warren 2005), in float64.

They reproduce constants and linear functions exactly at every point off the cage (inside and outside) and
equal the piecewise linear hat functions on it: the boundary data of Stokes cage coordinates.
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.func
def half_angle(u: wp.vec3d, v: wp.vec3d):
    """Angle between unit vectors u and v, as 2 asin(|u - v| / 2) (accurate for small angles)."""
    s = wp.min(wp.length(u - v) * wp.float64(0.5), wp.float64(1.0))
    return wp.float64(2.0) * wp.asin(s)


@wp.func
def triangle_weights(
    u0: wp.vec3d,
    u1: wp.vec3d,
    u2: wp.vec3d,
    d0: wp.float64,
    d1: wp.float64,
    d2: wp.float64,
    eps: wp.float64,
):
    """Unnormalised MVC weights of one triangle's corners, from the mean vector of its projection on the unit
    sphere around x (Ju, Schaefer and Warren 2005, eq. 7): m = sum_i theta_i / 2 n_i with theta_i the arc opposite
    corner i and n_i the unit normal of the plane through x and that arc; w_i = (n_i . m) / (n_i . u_i) / d_i.
    Unlike the half-angle form, it keeps full float64 accuracy next to the triangle's plane (1e-16 at 1e-8 of the
    cage's size from faces, their diagonals and edges). The 4th entry is 1 when x lies in the triangle's plane
    outside it (the projection is an arc: the triangle contributes nothing), else 0."""
    zero = wp.float64(0.0)
    det = wp.dot(u0, wp.cross(u1, u2))
    if wp.abs(det) <= eps:
        return wp.vec4d(zero, zero, zero, wp.float64(1.0))
    n0 = wp.normalize(wp.cross(u1, u2))
    n1 = wp.normalize(wp.cross(u2, u0))
    n2 = wp.normalize(wp.cross(u0, u1))
    half = wp.float64(0.5)
    m = half * (half_angle(u1, u2) * n0 + half_angle(u2, u0) * n1 + half_angle(u0, u1) * n2)
    w0 = wp.dot(n0, m) / (wp.dot(n0, u0) * d0)
    w1 = wp.dot(n1, m) / (wp.dot(n1, u1) * d1)
    w2 = wp.dot(n2, m) / (wp.dot(n2, u2) * d2)
    return wp.vec4d(w0, w1, w2, zero)


@wp.func
def on_triangle(x: wp.vec3d, p0: wp.vec3d, p1: wp.vec3d, p2: wp.vec3d, tolerance: wp.float64):
    """Barycentric coordinates of x's projection on the triangle when x lies on it (within `tolerance` of its plane
    and of the inside of all three edges), clamped to the triangle; a 4th entry 1 says x is on it, 0 not.

    A geometric test, because the angle test of the MVC formula fails on a triangle's edges (pi - h comes out
    ~1.5e-8 there in float64, not 0) and near them."""
    zero = wp.float64(0.0)
    area_normal = wp.cross(p1 - p0, p2 - p0)  # 2 A n
    double_area = wp.length(area_normal)
    if double_area <= zero:
        return wp.vec4d(zero, zero, zero, zero)
    n = area_normal / double_area
    if wp.abs(wp.dot(x - p0, n)) > tolerance:
        return wp.vec4d(zero, zero, zero, zero)
    # signed distances of the projection from the three edges' lines, positive inside
    e0 = p2 - p1
    e1 = p0 - p2
    e2 = p1 - p0
    d0 = wp.dot(wp.cross(e0, x - p1), n) / wp.length(e0)
    d1 = wp.dot(wp.cross(e1, x - p2), n) / wp.length(e1)
    d2 = wp.dot(wp.cross(e2, x - p0), n) / wp.length(e2)
    if d0 < -tolerance or d1 < -tolerance or d2 < -tolerance:
        return wp.vec4d(zero, zero, zero, zero)
    # barycentric coordinates: distance from the opposite edge over the triangle's height there
    b = wp.vec3d(wp.max(d0, zero) * wp.length(e0), wp.max(d1, zero) * wp.length(e1), wp.max(d2, zero) * wp.length(e2))
    b = b / (b[0] + b[1] + b[2])
    return wp.vec4d(b[0], b[1], b[2], wp.float64(1.0))


@wp.func
def add_weight(weights: wp.array2d(dtype=wp.float64), n: int, handle: int, first: int, w: wp.float64):
    column = handle - first
    if column >= 0 and column < weights.shape[1]:
        weights[n, column] = weights[n, column] + w


@wp.kernel
def mean_value_coordinates(
    points: wp.array(dtype=wp.vec3d),
    cage: wp.array(dtype=wp.vec3d),
    triangles: wp.array(dtype=wp.vec3i),
    eps_distance: wp.float64,
    eps_plane: wp.float64,
    first_handle: int,
    weights: wp.array2d(dtype=wp.float64),
):
    """weights[n, c] = MVC of handle first_handle + c at points[n], for the handles of one chunk (the columns of
    `weights`); one thread per point. Normalised by the total over all handles, so rows of a full chunk sum to 1.
    A point within `eps_distance` of a triangle (faces, edges and vertices included) gets the hat functions at its
    projection; `eps_plane` bounds the triple product of the unit vectors to a triangle's corners below which the
    point is in the triangle's plane (and, having passed the first test, outside it)."""
    n = wp.tid()
    x = points[n]
    zero = wp.float64(0.0)
    for c in range(weights.shape[1]):
        weights[n, c] = zero
    for t in range(triangles.shape[0]):
        tri = triangles[t]
        b = on_triangle(x, cage[tri[0]], cage[tri[1]], cage[tri[2]], eps_distance)
        if b[3] > zero:
            # x lies on the cage: the coordinates are the hat functions there
            add_weight(weights, n, tri[0], first_handle, b[0])
            add_weight(weights, n, tri[1], first_handle, b[1])
            add_weight(weights, n, tri[2], first_handle, b[2])
            return
    total = zero
    for t in range(triangles.shape[0]):
        tri = triangles[t]
        e0 = cage[tri[0]] - x
        e1 = cage[tri[1]] - x
        e2 = cage[tri[2]] - x
        d0 = wp.length(e0)
        d1 = wp.length(e1)
        d2 = wp.length(e2)
        w = triangle_weights(e0 / d0, e1 / d1, e2 / d2, d0, d1, d2, eps_plane)
        if w[3] == zero:
            add_weight(weights, n, tri[0], first_handle, w[0])
            add_weight(weights, n, tri[1], first_handle, w[1])
            add_weight(weights, n, tri[2], first_handle, w[2])
            total = total + w[0] + w[1] + w[2]
    for c in range(weights.shape[1]):
        weights[n, c] = weights[n, c] / total


@wp.kernel
def complement_column(n_handles: int, weights: wp.array2d(dtype=wp.float64)):
    """After the k = n_handles columns of a chunk's coordinates, write the column that stands for the rest of the
    cage: weights[n, k] = 1 - sum_c w_c, the sum of the other handles' w_l (exact: the coordinates sum to 1)."""
    n = wp.tid()
    total = wp.float64(0.0)
    for c in range(n_handles):
        total += weights[n, c]
    weights[n, n_handles] = wp.float64(1.0) - total


@wp.kernel
def copy_columns(source: wp.array2d(dtype=wp.float64), first: int, out: wp.array2d(dtype=wp.float64)):
    """out[n, c] = source[n, first + c] for the rows of ``source`` (a chunk's columns of a table of all handles)."""
    n, c = wp.tid()
    out[n, c] = source[n, first + c]


@wp.kernel
def node_positions(
    ijk: wp.array(dtype=wp.vec3i),
    origin: wp.vec3d,
    spacing: wp.float64,
    positions: wp.array(dtype=wp.vec3d),
):
    """positions[n] = origin + spacing ijk[n]: the nodes' positions where the MVC kernel reads them."""
    n = wp.tid()
    c = ijk[n]
    positions[n] = origin + spacing * wp.vec3d(wp.float64(c[0]), wp.float64(c[1]), wp.float64(c[2]))


@wp.kernel
def lattice_interpolation(
    lattice_values: wp.array2d(dtype=wp.float64),
    lattice_index: wp.array3d(dtype=wp.int32),
    ijk: wp.array(dtype=wp.vec3i),
    values: wp.array2d(dtype=wp.float64),
):
    """values[n, c] = the trilinear interpolation at node ijk[n] of ``lattice_values`` at the nodes of even
    coordinates around it (lattice node m = ijk / 2 has row lattice_index[m]): the value there when ijk is even, the
    mean of 2, 4 or 8 of them otherwise (only those with a non-zero weight are read); launch (rows, columns)."""
    n, c = wp.tid()
    p = ijk[n]
    base = wp.vec3i(p[0] // 2, p[1] // 2, p[2] // 2)
    odd = wp.vec3i(p[0] - 2 * base[0], p[1] - 2 * base[1], p[2] - 2 * base[2])
    total = wp.float64(0.0)
    count = int(0)
    for corner in range(8):
        o = wp.vec3i(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1)
        if o[0] <= odd[0] and o[1] <= odd[1] and o[2] <= odd[2]:
            total += lattice_values[lattice_index[base[0] + o[0], base[1] + o[1], base[2] + o[2]], c]
            count += 1
    values[n, c] = total / wp.float64(count)
