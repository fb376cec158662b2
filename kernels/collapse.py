"""Checks of candidate edge collapses that simplify a cage while it stays valid and keeps a mesh inside.

Launch with a block of 64 threads on CUDA: the kernel's two BVH queries keep their stacks in shared memory, which a
block of 256 would overflow (Warp's default). In a module of its own, so that no other kernel's launch compiles it
with the default block.
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

from .intersect import triangles_cross
from .local_boundary import closest_on_triangle


@wp.func
def orient(a: wp.vec3d, b: wp.vec3d, c: wp.vec3d, d: wp.vec3d):
    """Six times the signed volume of tetrahedron abcd."""
    return wp.dot(b - a, wp.cross(c - a, d - a))


@wp.func
def in_tetrahedron(p: wp.vec3d, x: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
    """+1 or -1 (its orientation) when p lies in tetrahedron (x, a, b, c), else 0: p's four barycentric volumes
    all have the whole's sign."""
    volume = orient(x, a, b, c)
    if volume == wp.float64(0.0):
        return 0
    s = wp.float64(1.0)
    if volume < wp.float64(0.0):
        s = wp.float64(-1.0)
    if s * orient(p, a, b, c) < wp.float64(0.0):
        return 0
    if s * orient(x, p, b, c) < wp.float64(0.0):
        return 0
    if s * orient(x, a, p, c) < wp.float64(0.0):
        return 0
    if s * orient(x, a, b, p) < wp.float64(0.0):
        return 0
    return int(s)


@wp.func
def triangle_distance(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
    """The distance from p to triangle abc."""
    w = closest_on_triangle(p, a, b, c)
    return wp.length(p - (w[0] * a + w[1] * b + w[2] * c))


@wp.func
def corner(positions: wp.array(dtype=wp.vec3d), v: int, a: int, b: int, x: wp.vec3d):
    """A corner's position once edge (a, b) collapses to x."""
    if v == a or v == b:
        return x
    return positions[v]


@wp.func
def label(v: int, a: int, b: int):
    """A corner's vertex id once edge (a, b) collapses (-1: the new vertex, a corner of no other face)."""
    if v == a or v == b:
        return -1
    return v


@wp.func
def has(f: wp.vec3i, v: int):
    return f[0] == v or f[1] == v or f[2] == v


@wp.func
def collapsed_normal(positions: wp.array(dtype=wp.vec3d), f: wp.vec3i, a: int, b: int, x: wp.vec3d):
    """The (unnormalised) normal of face f once edge (a, b) collapses to x."""
    p0 = corner(positions, f[0], a, b, x)
    p1 = corner(positions, f[1], a, b, x)
    p2 = corner(positions, f[2], a, b, x)
    return wp.cross(p1 - p0, p2 - p0)


@wp.func
def fan_face(vf_start: wp.array(dtype=wp.int32), vf_faces: wp.array(dtype=wp.int32), a: int, b: int, k: int):
    """The k-th face of the fan of edge (a, b): the faces at a, then those at b; -1 past the end."""
    na = vf_start[a + 1] - vf_start[a]
    if k < na:
        return vf_faces[vf_start[a] + k]
    k2 = k - na
    if k2 < vf_start[b + 1] - vf_start[b]:
        return vf_faces[vf_start[b] + k2]
    return -1


@wp.func
def cone_count(p: wp.vec3d, x: wp.vec3d, positions: wp.array(dtype=wp.vec3d), faces: wp.array(dtype=wp.vec3i),
               vf_start: wp.array(dtype=wp.int32), vf_faces: wp.array(dtype=wp.int32), a: int, b: int):
    """The winding number at p of the region between the fan of edge (a, b) and its faces once collapsed to x:
    the tetrahedra (x, old face) that hold p, counted with their orientation."""
    na = vf_start[a + 1] - vf_start[a]
    n = na + vf_start[b + 1] - vf_start[b]
    count = int(0)
    for k in range(n):
        f = faces[fan_face(vf_start, vf_faces, a, b, k)]
        if has(f, a) and has(f, b) and k >= na:
            continue  # a vanishing face, once
        count += in_tetrahedron(p, x, positions[f[0]], positions[f[1]], positions[f[2]])
    return count


@wp.func
def across(faces: wp.array(dtype=wp.vec3i), vf_start: wp.array(dtype=wp.int32), vf_faces: wp.array(dtype=wp.int32),
           g: int, u: int, w: int, a: int, b: int):
    """The face other than g that has edge (u, w) once edge (a, b) collapses (u or w may be -1, the new vertex);
    -1 when none. Faces at both a and b vanish in the collapse and are never returned."""
    if u == -1 or w == -1:
        y = u
        if u == -1:
            y = w
        # around the new vertex: another face of the fan at y
        n = vf_start[a + 1] - vf_start[a] + vf_start[b + 1] - vf_start[b]
        for k in range(n):
            h = fan_face(vf_start, vf_faces, a, b, k)
            f = faces[h]
            if h != g and has(f, y) and not (has(f, a) and has(f, b)):
                return h
        return -1
    for k in range(vf_start[u], vf_start[u + 1]):
        h = vf_faces[k]
        f = faces[h]
        if h != g and has(f, w) and not (has(f, a) and has(f, b)):
            return h
    return -1


@wp.kernel
def collapse_choice(
    positions: wp.array(dtype=wp.vec3d),
    faces: wp.array(dtype=wp.vec3i),
    vf_start: wp.array(dtype=wp.int32),
    vf_faces: wp.array(dtype=wp.int32),
    edge_a: wp.array(dtype=wp.int32),
    edge_b: wp.array(dtype=wp.int32),
    placements: wp.array2d(dtype=wp.vec3d),
    surface: wp.uint64,
    centre: wp.vec3d,
    points_bvh: wp.uint64,
    points: wp.array(dtype=wp.vec3d),
    margin: wp.float64,
    cos_flip: wp.float64,
    cos_fold: wp.float64,
    sin_angle: wp.float64,
    choice: wp.array(dtype=wp.int32),
    reason: wp.array(dtype=wp.int32),
):
    """choice[e] = the first placement x (of placements[e], in order of cost) where collapsing edge (a, b) to x keeps
    the surface valid, or -1: no face turned by more than the flip angle or with an angle below the minimum, no
    fold sharper than the fold limit, no new face crossing another face (of the surface or new), and no point swept
    out of the surface or within ``margin`` of a new face. ``surface`` is a BVH over the faces (float32, relative to
    ``centre``), and ``points_bvh`` one over the points to keep inside; launch over the candidate edges."""
    e = wp.tid()
    a = edge_a[e]
    b = edge_b[e]
    n = vf_start[a + 1] - vf_start[a] + vf_start[b + 1] - vf_start[b]
    eps = wp.float64(1.0e-9)
    result = int(-1)
    why = int(0)
    for c in range(placements.shape[1]):
        if result >= 0:
            break
        x = placements[e, c]
        ok = bool(True)
        for k in range(n):
            if not ok:
                break
            g = fan_face(vf_start, vf_faces, a, b, k)
            f = faces[g]
            if has(f, a) and has(f, b):
                continue  # vanishes
            normal = collapsed_normal(positions, f, a, b, x)
            length = wp.length(normal)
            p0 = corner(positions, f[0], a, b, x)
            p1 = corner(positions, f[1], a, b, x)
            p2 = corner(positions, f[2], a, b, x)
            l0 = wp.length(p1 - p0)
            l1 = wp.length(p2 - p1)
            l2 = wp.length(p0 - p2)
            longest = wp.max(wp.max(l0 * l1, l1 * l2), l2 * l0)
            old = wp.cross(positions[f[1]] - positions[f[0]], positions[f[2]] - positions[f[0]])
            old_length = wp.length(old)
            q0 = wp.length(positions[f[1]] - positions[f[0]])
            q1 = wp.length(positions[f[2]] - positions[f[1]])
            q2 = wp.length(positions[f[0]] - positions[f[2]])
            old_longest = wp.max(wp.max(q0 * q1, q1 * q2), q2 * q0)
            # |n| / (the two longest sides' product) is the smallest angle's sine: below the minimum, a face may
            # not get worse (the surface's first faces may be slivers)
            if length <= sin_angle * longest and length * old_longest <= old_length * longest:
                ok = False
                why = 1
                continue
            if old_length > wp.float64(0.0) and wp.dot(old, normal) < cos_flip * old_length * length:
                ok = False
                why = 2
                continue
            unit = normal / length
            labels = wp.vec3i(label(f[0], a, b), label(f[1], a, b), label(f[2], a, b))
            for m in range(3):
                h = across(faces, vf_start, vf_faces, g, labels[m], labels[(m + 1) % 3], a, b)
                if h >= 0:
                    other = collapsed_normal(positions, faces[h], a, b, x)
                    other_length = wp.length(other)
                    if other_length > wp.float64(0.0) and wp.dot(unit, other) < cos_fold * other_length:
                        ok = False
                        why = 3
            if not ok:
                continue
            # no new face crosses a face outside the fan
            lower = wp.vec3(float(wp.min(wp.min(p0[0], p1[0]), p2[0]) - centre[0]),
                            float(wp.min(wp.min(p0[1], p1[1]), p2[1]) - centre[1]),
                            float(wp.min(wp.min(p0[2], p1[2]), p2[2]) - centre[2]))
            upper = wp.vec3(float(wp.max(wp.max(p0[0], p1[0]), p2[0]) - centre[0]),
                            float(wp.max(wp.max(p0[1], p1[1]), p2[1]) - centre[1]),
                            float(wp.max(wp.max(p0[2], p1[2]), p2[2]) - centre[2]))
            pad = 1.0e-5 * wp.length(upper - lower) + 1.0e-30
            query = wp.mesh_query_aabb(surface, lower - wp.vec3(pad, pad, pad), upper + wp.vec3(pad, pad, pad))
            h = int(0)
            while wp.mesh_query_aabb_next(query, h):
                fh = faces[h]
                if not (has(fh, a) or has(fh, b)):
                    if triangles_cross(p0, p1, p2, labels, positions[fh[0]], positions[fh[1]], positions[fh[2]],
                                       fh, eps):
                        ok = False
                        why = 4
            # nor another new face (they share the new vertex, labelled -1 in both)
            for k2 in range(k + 1, n):
                f2 = faces[fan_face(vf_start, vf_faces, a, b, k2)]
                if not (has(f2, a) and has(f2, b)):
                    if triangles_cross(p0, p1, p2, labels, corner(positions, f2[0], a, b, x),
                                       corner(positions, f2[1], a, b, x), corner(positions, f2[2], a, b, x),
                                       wp.vec3i(label(f2[0], a, b), label(f2[1], a, b), label(f2[2], a, b)), eps):
                        ok = False
                        why = 4
        if not ok:
            continue
        # no point within the margin of a new face, none swept out. The region between the old and the new faces
        # is the cone from x over the old fan (the new faces hold x: their cones are flat), so a point is swept out
        # when the tetrahedra (x, old face) that hold it, counted with their orientation, do not cancel. A query per
        # old face finds the points near its tetrahedron (and so near its new face); the count is made for a point in it
        na = vf_start[a + 1] - vf_start[a]
        for k in range(n):
            if not ok:
                break
            f = faces[fan_face(vf_start, vf_faces, a, b, k)]
            vanishing = has(f, a) and has(f, b)
            if vanishing and k >= na:
                continue  # a vanishing face, once (it is at a and at b)
            fa = positions[f[0]]
            fb = positions[f[1]]
            fc = positions[f[2]]
            lo = wp.min(wp.min(x, fa), wp.min(fb, fc)) - wp.vec3d(margin, margin, margin) - centre
            hi = wp.max(wp.max(x, fa), wp.max(fb, fc)) + wp.vec3d(margin, margin, margin) - centre
            near = wp.bvh_query_aabb(points_bvh, wp.vec3(float(lo[0]), float(lo[1]), float(lo[2])),
                                     wp.vec3(float(hi[0]), float(hi[1]), float(hi[2])))
            i = int(0)
            while ok and wp.bvh_query_next(near, i):
                p = points[i]
                if not vanishing:
                    if triangle_distance(p, corner(positions, f[0], a, b, x), corner(positions, f[1], a, b, x),
                                         corner(positions, f[2], a, b, x)) < margin:
                        ok = False
                        why = 5
                if ok and in_tetrahedron(p, x, fa, fb, fc) != 0:
                    if cone_count(p, x, positions, faces, vf_start, vf_faces, a, b) != 0:
                        ok = False
                        why = 6
        if ok:
            result = c
    choice[e] = result
    reason[e] = why
