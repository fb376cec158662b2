"""Crossing cage faces: a segment-triangle test over the pairs that a BVH query finds."""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.func
def segment_crosses_triangle(p: wp.vec3d, q: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, eps: wp.float64):
    """Whether the open segment p-q (its end points excluded, within ``eps`` relative) meets triangle abc, its
    edges included: a segment through the diagonal that two coplanar triangles share crosses both (Moller-Trumbore)."""
    d = q - p
    e1 = b - a
    e2 = c - a
    s = wp.cross(d, e2)
    det = wp.dot(e1, s)
    scale = wp.length(d) * wp.length(e1) * wp.length(e2)
    if wp.abs(det) <= eps * scale:
        return False  # parallel (coplanar overlaps are not detected)
    inv = wp.float64(1.0) / det
    o = p - a
    u = wp.dot(o, s) * inv
    qv = wp.cross(o, e1)
    v = wp.dot(d, qv) * inv
    t = wp.dot(e2, qv) * inv
    return u >= -eps and v >= -eps and u + v <= wp.float64(1.0) + eps and t > eps and t < wp.float64(1.0) - eps


@wp.func
def edge_crosses_triangle(p: wp.vec3d, q: wp.vec3d, ip: int, iq: int, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d,
                          g: wp.vec3i, eps: wp.float64):
    """Whether edge ip-iq crosses triangle g = abc. An edge with an end at one of the triangle's corners can meet it
    there only (anywhere else it would lie in the triangle's plane, which is not detected): it is not tested, as
    rounding would place that end at t = 1 - 2e-9 when the two faces are nearly coplanar (a fine UV sphere's
    slivers near a pole)."""
    if ip == g[0] or ip == g[1] or ip == g[2] or iq == g[0] or iq == g[1] or iq == g[2]:
        return False
    return segment_crosses_triangle(p, q, a, b, c, eps)


@wp.func
def triangles_cross(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, f: wp.vec3i, x: wp.vec3d, y: wp.vec3d, z: wp.vec3d,
                    g: wp.vec3i, eps: wp.float64):
    """Whether triangles f = abc and g = xyz cross: an edge of one passes through the other (the non-coplanar
    cases)."""
    return (edge_crosses_triangle(a, b, f[0], f[1], x, y, z, g, eps)
            or edge_crosses_triangle(b, c, f[1], f[2], x, y, z, g, eps)
            or edge_crosses_triangle(c, a, f[2], f[0], x, y, z, g, eps)
            or edge_crosses_triangle(x, y, g[0], g[1], a, b, c, f, eps)
            or edge_crosses_triangle(y, z, g[1], g[2], a, b, c, f, eps)
            or edge_crosses_triangle(z, x, g[2], g[0], a, b, c, f, eps))


@wp.kernel
def crossing_faces(
    mesh: wp.uint64,
    vertices: wp.array(dtype=wp.vec3d),
    faces: wp.array(dtype=wp.vec3i),
    margin: float,
    eps: wp.float64,
    first_crossing: wp.array(dtype=wp.int32),
):
    """first_crossing[i] = the smallest face j > i that crosses face i and shares at most one vertex with it
    (faces sharing an edge meet along it), or -1; launch over faces. ``mesh`` is a BVH over the same faces in
    float32 (the candidates), ``vertices`` their float64 positions (the test)."""
    i = wp.tid()
    f = faces[i]
    a = vertices[f[0]]
    b = vertices[f[1]]
    c = vertices[f[2]]
    lower = wp.vec3(float(wp.min(wp.min(a[0], b[0]), c[0])), float(wp.min(wp.min(a[1], b[1]), c[1])),
                    float(wp.min(wp.min(a[2], b[2]), c[2]))) - wp.vec3(margin, margin, margin)
    upper = wp.vec3(float(wp.max(wp.max(a[0], b[0]), c[0])), float(wp.max(wp.max(a[1], b[1]), c[1])),
                    float(wp.max(wp.max(a[2], b[2]), c[2]))) + wp.vec3(margin, margin, margin)
    found = int(-1)
    query = wp.mesh_query_aabb(mesh, lower, upper)
    j = int(0)
    while wp.mesh_query_aabb_next(query, j):
        if j > i and (found < 0 or j < found):
            g = faces[j]
            shared = int(0)
            for k in range(3):
                for m in range(3):
                    if f[k] == g[m]:
                        shared += 1
            if shared < 2:
                if triangles_cross(a, b, c, f, vertices[g[0]], vertices[g[1]], vertices[g[2]], g, eps):
                    found = j
    first_crossing[i] = found
