"""Crossing cage faces: a segment-triangle test over the pairs that a BVH query finds."""

import warp as wp


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
def triangles_cross(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, x: wp.vec3d, y: wp.vec3d, z: wp.vec3d,
                    eps: wp.float64):
    """Whether two triangles cross: an edge of one passes through the other (the non-coplanar cases)."""
    return (segment_crosses_triangle(a, b, x, y, z, eps) or segment_crosses_triangle(b, c, x, y, z, eps)
            or segment_crosses_triangle(c, a, x, y, z, eps) or segment_crosses_triangle(x, y, a, b, c, eps)
            or segment_crosses_triangle(y, z, a, b, c, eps) or segment_crosses_triangle(z, x, a, b, c, eps))


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
                if triangles_cross(a, b, c, vertices[g[0]], vertices[g[1]], vertices[g[2]], eps):
                    found = j
    first_crossing[i] = found
