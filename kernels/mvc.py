"""Mean value coordinates of a closed triangle cage (Ju, Schaefer and Warren 2005), in float64.

They reproduce constants and linear functions exactly at every point off the cage (inside and outside) and
equal the piecewise linear hat functions on it: the boundary data of Stokes cage coordinates.
"""

import warp as wp

PI = wp.constant(wp.float64(3.141592653589793))


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
    """Unnormalised MVC weights of one triangle's corners; the 4th entry says how to use them:
    0 = regular, 1 = skip (point in the triangle's plane, outside it), 2 = point lies on the triangle
    (the three weights are then its barycentric coordinates, up to scale)."""
    one = wp.float64(1.0)
    two = wp.float64(2.0)
    zero = wp.float64(0.0)
    t0 = half_angle(u1, u2)
    t1 = half_angle(u2, u0)
    t2 = half_angle(u0, u1)
    h = (t0 + t1 + t2) * wp.float64(0.5)
    if PI - h < eps:
        return wp.vec4d(wp.sin(t0) * d1 * d2, wp.sin(t1) * d2 * d0, wp.sin(t2) * d0 * d1, two)
    sh = wp.sin(h)
    s_t0 = wp.sin(t0)
    s_t1 = wp.sin(t1)
    s_t2 = wp.sin(t2)
    c0 = two * sh * wp.sin(h - t0) / (s_t1 * s_t2) - one
    c1 = two * sh * wp.sin(h - t1) / (s_t2 * s_t0) - one
    c2 = two * sh * wp.sin(h - t2) / (s_t0 * s_t1) - one
    det = wp.dot(u0, wp.cross(u1, u2))
    if wp.abs(det) <= eps:
        # x lies in the triangle's plane, outside it (e.g. on the line through an edge, where one angle is 0
        # and the paper's test on s below is defeated by round-off): the triangle contributes nothing
        return wp.vec4d(zero, zero, zero, one)
    sign = wp.sign(det)
    s0 = sign * wp.sqrt(wp.max(one - c0 * c0, zero))
    s1 = sign * wp.sqrt(wp.max(one - c1 * c1, zero))
    s2 = sign * wp.sqrt(wp.max(one - c2 * c2, zero))
    if wp.abs(s0) <= eps or wp.abs(s1) <= eps or wp.abs(s2) <= eps:
        return wp.vec4d(zero, zero, zero, one)
    w0 = (t0 - c1 * t2 - c2 * t1) / (d0 * s_t1 * s2)
    w1 = (t1 - c2 * t0 - c0 * t2) / (d1 * s_t2 * s0)
    w2 = (t2 - c0 * t1 - c1 * t0) / (d2 * s_t0 * s1)
    return wp.vec4d(w0, w1, w2, zero)


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
    eps_angle: wp.float64,
    first_handle: int,
    weights: wp.array2d(dtype=wp.float64),
):
    """weights[n, c] = MVC of handle first_handle + c at points[n], for the handles of one chunk (the columns of
    `weights`); one thread per point. Normalised by the total over all handles, so rows of a full chunk sum to 1."""
    n = wp.tid()
    x = points[n]
    zero = wp.float64(0.0)
    for c in range(weights.shape[1]):
        weights[n, c] = zero
    for l in range(cage.shape[0]):
        if wp.length(cage[l] - x) < eps_distance:
            add_weight(weights, n, l, first_handle, wp.float64(1.0))
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
        w = triangle_weights(e0 / d0, e1 / d1, e2 / d2, d0, d1, d2, eps_angle)
        if w[3] == wp.float64(2.0):
            # x lies on this triangle: the coordinates are its barycentric coordinates there
            for c in range(weights.shape[1]):
                weights[n, c] = zero
            s = w[0] + w[1] + w[2]
            add_weight(weights, n, tri[0], first_handle, w[0] / s)
            add_weight(weights, n, tri[1], first_handle, w[1] / s)
            add_weight(weights, n, tri[2], first_handle, w[2] / s)
            return
        if w[3] == zero:
            add_weight(weights, n, tri[0], first_handle, w[0])
            add_weight(weights, n, tri[1], first_handle, w[1])
            add_weight(weights, n, tri[2], first_handle, w[2])
            total = total + w[0] + w[1] + w[2]
    for c in range(weights.shape[1]):
        weights[n, c] = weights[n, c] / total


@wp.kernel
def complement_columns(
    points: wp.array(dtype=wp.vec3d),
    chunk_handles: wp.array(dtype=wp.vec3d),
    weights: wp.array2d(dtype=wp.float64),
):
    """After the k = chunk_handles.shape[0] columns of a chunk's coordinates, write the four columns that stand
    for the rest of the cage: weights[n, k] = 1 - sum_c w_c and weights[n, k+1 .. k+3] = x_n - sum_c c_c w_c,
    the sums over the other handles of w_l and c_l w_l (exact: the coordinates reproduce 1 and x)."""
    n = wp.tid()
    k = chunk_handles.shape[0]
    total = wp.float64(0.0)
    moment = wp.vec3d()
    for c in range(k):
        w = weights[n, c]
        total += w
        moment += w * chunk_handles[c]
    rest = points[n] - moment
    weights[n, k] = wp.float64(1.0) - total
    weights[n, k + 1] = rest[0]
    weights[n, k + 2] = rest[1]
    weights[n, k + 3] = rest[2]
