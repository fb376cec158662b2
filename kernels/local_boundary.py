"""Local boundary data: each node takes its data from the closest point of the cage, Taylor-extended.

At a node x with closest cage point y on face f (barycentric coordinates b, unit normal n_f):

    q_l(x) = hat_l(y) + (x - y) . (grad_T hat_l + g_l n_f)

hat_l(y) is b_i for the face's corner i = l and 0 for every other handle; grad_T hat_l is the (constant) gradient
of that barycentric function in the face's plane; g_l are per-face normal derivatives with sum_l g_l = 0 and
sum_l g_l c_l = n_f. Then sum_l q_l(x) = 1 and sum_l c_l q_l(x) = x exactly, whatever y is on the face's plane.
"""

import warp as wp


@wp.kernel
def local_field(
    ijk: wp.array(dtype=wp.vec3i),
    first_row: int,
    origin: wp.vec3d,
    spacing: wp.float64,
    mesh: wp.uint64,
    cage: wp.array(dtype=wp.vec3d),
    triangles: wp.array(dtype=wp.vec3i),
    normals: wp.array(dtype=wp.vec3d),
    tangent_gradients: wp.array2d(dtype=wp.vec3d),
    normal_derivatives: wp.array2d(dtype=wp.float64),
    first_handle: int,
    n_handles: int,
    complement: int,
    field: wp.array2d(dtype=wp.vec4f),
):
    """field[n, c] = (q, h grad q) of handle first_handle + c at active row n = first_row + thread, the gradient
    that of the same Taylor extension (grad_T hat_l + g_l n_f: constant per face), for c < n_handles; with
    `complement`, the four columns after them stand for the rest of the cage (1 - sum q, x - sum c q, and their
    gradients 0 - sum, h e_a - sum). `mesh` is the cage in float32 (for the closest-point query only), `cage` its
    vertices in float64, relative to the same centre as `origin`; `tangent_gradients[f, i]` is grad_T of corner
    i's barycentric function on face f and `normal_derivatives[f, l]` is g_l on face f for every handle l."""
    n = first_row + wp.tid()
    node = ijk[n]
    x = origin + spacing * wp.vec3d(wp.float64(node[0]), wp.float64(node[1]), wp.float64(node[2]))
    query = wp.mesh_query_point_no_sign(mesh, wp.vec3f(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2])),
                                        1.0e30)
    f = query.face
    tri = triangles[f]
    # Warp's barycentric coordinates: the point is u p0 + v p1 + (1 - u - v) p2
    u = wp.float64(query.u)
    v = wp.float64(query.v)
    b = wp.vec3d(u, v, wp.float64(1.0) - u - v)
    y = b[0] * cage[tri[0]] + b[1] * cage[tri[1]] + b[2] * cage[tri[2]]
    offset = x - y
    normal = normals[f]
    height = wp.dot(offset, normal)
    total = wp.float64(0.0)
    moment = wp.vec3d()
    total_gradient = wp.vec3d()
    moment_gradient = wp.mat33d()
    for c in range(n_handles):
        l = first_handle + c
        g = normal_derivatives[f, l]
        q = height * g
        grad = g * normal
        for i in range(3):
            if tri[i] == l:
                q += b[i] + wp.dot(offset, tangent_gradients[f, i])
                grad += tangent_gradients[f, i]
        field[n, c] = wp.vec4f(wp.float32(q), wp.float32(spacing * grad[0]), wp.float32(spacing * grad[1]),
                               wp.float32(spacing * grad[2]))
        if complement != 0:
            total += q
            moment += q * cage[l]
            total_gradient += grad
            moment_gradient += wp.outer(cage[l], grad)
    if complement != 0:
        rest_gradient = -total_gradient
        field[n, n_handles] = wp.vec4f(wp.float32(wp.float64(1.0) - total), wp.float32(spacing * rest_gradient[0]),
                                       wp.float32(spacing * rest_gradient[1]), wp.float32(spacing * rest_gradient[2]))
        rest = x - moment
        for a in range(3):
            e = wp.vec3d()
            e[a] = wp.float64(1.0)
            row = e - wp.vec3d(moment_gradient[a, 0], moment_gradient[a, 1], moment_gradient[a, 2])
            field[n, n_handles + 1 + a] = wp.vec4f(wp.float32(rest[a]), wp.float32(spacing * row[0]),
                                                   wp.float32(spacing * row[1]), wp.float32(spacing * row[2]))
