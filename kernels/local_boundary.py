"""Local boundary data: each node takes its data from the closest points of the cage, Taylor-extended.

From a point y on face f (barycentric coordinates b, unit normal n_f), the data of handle l at x is

    q_l(x) = hat_l(y) + (x - y) . (grad_T hat_l + g_l n_f),     grad q_l = grad_T hat_l + g_l n_f,

hat_l(y) = b_i for the face's corner i = l and 0 for every other handle; grad_T hat_l is the (constant) gradient of
that barycentric function in the face's plane; g_l are per-face normal derivatives with sum_l g_l = 0 and
sum_l g_l c_l = n_f. Then sum_l q_l(x) = 1 and sum_l c_l q_l(x) = x exactly, whatever y is on the face's plane, and
any convex combination of such data over several faces is exact too. A node blends the faces whose distance is
within `band` of the nearest one's (weights (1 - t)^2, t the excess over the band): the data is continuous where
the nearest face changes (medial surfaces, convex edges), and the same on every device.
"""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.func
def closest_on_triangle(p: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
    """Barycentric coordinates (for a, b, c) of the point of triangle abc closest to p (Ericson, Real-Time Collision
    Detection, 5.1.5), in float64."""
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    ab = b - a
    ac = c - a
    ap = p - a
    d1 = wp.dot(ab, ap)
    d2 = wp.dot(ac, ap)
    if d1 <= zero and d2 <= zero:
        return wp.vec3d(one, zero, zero)
    bp = p - b
    d3 = wp.dot(ab, bp)
    d4 = wp.dot(ac, bp)
    if d3 >= zero and d4 <= d3:
        return wp.vec3d(zero, one, zero)
    vc = d1 * d4 - d3 * d2
    if vc <= zero and d1 >= zero and d3 <= zero:
        v = d1 / (d1 - d3)
        return wp.vec3d(one - v, v, zero)
    cp = p - c
    d5 = wp.dot(ab, cp)
    d6 = wp.dot(ac, cp)
    if d6 >= zero and d5 <= d6:
        return wp.vec3d(zero, zero, one)
    vb = d5 * d2 - d1 * d6
    if vb <= zero and d2 >= zero and d6 <= zero:
        w = d2 / (d2 - d6)
        return wp.vec3d(one - w, zero, w)
    va = d3 * d6 - d5 * d4
    if va <= zero and (d4 - d3) >= zero and (d5 - d6) >= zero:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return wp.vec3d(zero, one - w, w)
    denominator = one / (va + vb + vc)
    v = vb * denominator
    w = vc * denominator
    return wp.vec3d(one - v - w, v, w)


@wp.func
def face_distance(x: wp.vec3d, cage: wp.array(dtype=wp.vec3d), tri: wp.vec3i):
    b = closest_on_triangle(x, cage[tri[0]], cage[tri[1]], cage[tri[2]])
    return wp.length(x - (b[0] * cage[tri[0]] + b[1] * cage[tri[1]] + b[2] * cage[tri[2]]))


#: most faces a node blends (more within the band are dropped, the farthest first: it takes a node equidistant from
#: more than this many faces)
MAX_BLEND = 8
face_list = wp.types.vector(length=MAX_BLEND, dtype=wp.int32)
weight_list = wp.types.vector(length=MAX_BLEND, dtype=wp.float64)
point_list = wp.types.matrix(shape=(MAX_BLEND, 3), dtype=wp.float64)


@wp.struct
class Blend:
    """The faces a point takes its data from: those within the band of the nearest one (``count`` of them), their
    shares of the blend ((1 - t)^2 over the sum) and the barycentric coordinates of their closest points."""

    count: wp.int32
    faces: face_list
    fractions: weight_list
    points: point_list


@wp.func
def grid_point(ijk: wp.array(dtype=wp.vec3i), n: int, origin: wp.vec3d, spacing: wp.float64):
    node = ijk[n]
    return origin + spacing * wp.vec3d(wp.float64(node[0]), wp.float64(node[1]), wp.float64(node[2]))


#: most faces a BVH search of :func:`blend_near` collects; beyond, the search over every face (the same blend)
MAX_CANDIDATES = 64
candidate_list = wp.types.vector(length=MAX_CANDIDATES, dtype=wp.int32)


@wp.func
def blend_over(x: wp.vec3d, band: wp.float64, cage: wp.array(dtype=wp.vec3d), triangles: wp.array(dtype=wp.vec3i),
               found: candidate_list, count: int, every_face: bool):
    """The faces within ``band`` of the nearest one to x, as a :class:`Blend`, searched over every face (in index
    order) or over the first ``count`` faces of ``found`` (in that order)."""
    n_faces = count
    if every_face:
        n_faces = triangles.shape[0]
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    nearest = wp.float64(1.0e300)
    for k in range(n_faces):
        f = k
        if not every_face:
            f = found[k]
        nearest = wp.min(nearest, face_distance(x, cage, triangles[f]))
    faces = face_list()
    weights = weight_list()
    points = point_list()
    kept = int(0)
    total_weight = zero
    for k in range(n_faces):
        f = k
        if not every_face:
            f = found[k]
        tri = triangles[f]
        b = closest_on_triangle(x, cage[tri[0]], cage[tri[1]], cage[tri[2]])
        t = (wp.length(x - (b[0] * cage[tri[0]] + b[1] * cage[tri[1]] + b[2] * cage[tri[2]])) - nearest) / band
        if t < one and kept < MAX_BLEND:
            faces[kept] = f
            weights[kept] = (one - t) * (one - t)
            points[kept, 0] = b[0]
            points[kept, 1] = b[1]
            points[kept, 2] = b[2]
            total_weight += weights[kept]
            kept += 1
    for k in range(kept):
        weights[k] = weights[k] / total_weight
    blend = Blend()
    blend.count = wp.int32(kept)
    blend.faces = faces
    blend.fractions = weights
    blend.points = points
    return blend


@wp.func
def blend_at(x: wp.vec3d, band: wp.float64, cage: wp.array(dtype=wp.vec3d), triangles: wp.array(dtype=wp.vec3i)):
    """The faces within ``band`` of the nearest one to x, as a :class:`Blend`: the search over every face."""
    return blend_over(x, band, cage, triangles, candidate_list(), 0, True)


@wp.func
def handle_data(x: wp.vec3d, l: int, blend: Blend, cage: wp.array(dtype=wp.vec3d),
                triangles: wp.array(dtype=wp.vec3i), normals: wp.array(dtype=wp.vec3d),
                tangent_gradients: wp.array2d(dtype=wp.vec3d), normal_derivatives: wp.array2d(dtype=wp.float64)):
    """(q, grad q) of handle l at x, blended over ``blend``'s faces."""
    q = wp.float64(0.0)
    grad = wp.vec3d()
    for k in range(int(blend.count)):
        f = blend.faces[k]
        tri = triangles[f]
        b = wp.vec3d(blend.points[k, 0], blend.points[k, 1], blend.points[k, 2])
        offset = x - (b[0] * cage[tri[0]] + b[1] * cage[tri[1]] + b[2] * cage[tri[2]])
        g = normal_derivatives[f, l]
        qf = wp.dot(offset, normals[f]) * g
        gradf = g * normals[f]
        for i in range(3):
            if tri[i] == l:
                qf += b[i] + wp.dot(offset, tangent_gradients[f, i])
                gradf += tangent_gradients[f, i]
        q += blend.fractions[k] * qf
        grad += blend.fractions[k] * gradf
    return wp.vec4d(q, grad[0], grad[1], grad[2])


@wp.func
def write_handles(field: wp.array2d(dtype=wp.vec4f), n: int, x: wp.vec3d, spacing: wp.float64, blend: Blend,
                  cage: wp.array(dtype=wp.vec3d), triangles: wp.array(dtype=wp.vec3i),
                  normals: wp.array(dtype=wp.vec3d), tangent_gradients: wp.array2d(dtype=wp.vec3d),
                  normal_derivatives: wp.array2d(dtype=wp.float64), first_handle: int, n_handles: int,
                  complement: int):
    """field[n, c] = (q, h grad q) of handle first_handle + c for c < n_handles, and with ``complement`` the rest
    of the cage's column after them (1 - sum q, - sum grad q)."""
    one = wp.float64(1.0)
    total = wp.float64(0.0)
    total_gradient = wp.vec3d()
    for c in range(n_handles):
        data = handle_data(x, first_handle + c, blend, cage, triangles, normals, tangent_gradients, normal_derivatives)
        field[n, c] = wp.vec4f(wp.float32(data[0]), wp.float32(spacing * data[1]), wp.float32(spacing * data[2]),
                               wp.float32(spacing * data[3]))
        if complement != 0:
            total += data[0]
            total_gradient += wp.vec3d(data[1], data[2], data[3])
    if complement != 0:
        field[n, n_handles] = wp.vec4f(wp.float32(one - total), wp.float32(-spacing * total_gradient[0]),
                                       wp.float32(-spacing * total_gradient[1]), wp.float32(-spacing * total_gradient[2]))


# about 75 lines: one thread per (node, handle) assembles the local data of its closest face and the faces blended
# with it; the steps share the per-face values held in registers. The same arithmetic as blend_at and write_handles
# written out: through their struct a GPU took about twice as long
@wp.kernel
def local_field(
    ijk: wp.array(dtype=wp.vec3i),
    positions: wp.array(dtype=wp.vec3d),
    first_row: int,
    origin: wp.vec3d,
    spacing: wp.float64,
    band: wp.float64,
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
    """field[n, c] = (q, h grad q) of handle first_handle + c at active row n = first_row + thread, for
    c < n_handles, blended over the faces within `band` of the nearest; with `complement`, the column after
    them stands for the rest of the cage (1 - sum q and its gradient, - sum grad q). Row n is the grid node ijk[n],
    or, when `positions` is not empty, the point positions[n] (e.g. mesh vertices beyond the grid).
    `cage` holds the vertices relative to the same centre as `origin`; `tangent_gradients[f, i]` is grad_T of
    corner i's barycentric function on face f and `normal_derivatives[f, l]` is g_l on face f for every handle l."""
    n = first_row + wp.tid()
    x = wp.vec3d()
    if positions.shape[0] > 0:
        x = positions[n]
    else:
        x = grid_point(ijk, n, origin, spacing)
    zero = wp.float64(0.0)
    one = wp.float64(1.0)
    nearest = wp.float64(1.0e300)
    for f in range(triangles.shape[0]):
        nearest = wp.min(nearest, face_distance(x, cage, triangles[f]))
    # the faces within the band, their weights (1 - t)^2 and closest points' barycentric coordinates
    faces = face_list()
    weights = weight_list()
    points = point_list()
    count = int(0)
    total_weight = zero
    for f in range(triangles.shape[0]):
        tri = triangles[f]
        b = closest_on_triangle(x, cage[tri[0]], cage[tri[1]], cage[tri[2]])
        t = (wp.length(x - (b[0] * cage[tri[0]] + b[1] * cage[tri[1]] + b[2] * cage[tri[2]])) - nearest) / band
        if t < one and count < MAX_BLEND:
            faces[count] = f
            weights[count] = (one - t) * (one - t)
            points[count, 0] = b[0]
            points[count, 1] = b[1]
            points[count, 2] = b[2]
            total_weight += weights[count]
            count += 1
    total = zero
    total_gradient = wp.vec3d()
    for c in range(n_handles):
        l = first_handle + c
        q = zero
        grad = wp.vec3d()
        for k in range(count):
            f = faces[k]
            tri = triangles[f]
            b = wp.vec3d(points[k, 0], points[k, 1], points[k, 2])
            offset = x - (b[0] * cage[tri[0]] + b[1] * cage[tri[1]] + b[2] * cage[tri[2]])
            g = normal_derivatives[f, l]
            qf = wp.dot(offset, normals[f]) * g
            gradf = g * normals[f]
            for i in range(3):
                if tri[i] == l:
                    qf += b[i] + wp.dot(offset, tangent_gradients[f, i])
                    gradf += tangent_gradients[f, i]
            weight = weights[k] / total_weight
            q += weight * qf
            grad += weight * gradf
        field[n, c] = wp.vec4f(wp.float32(q), wp.float32(spacing * grad[0]), wp.float32(spacing * grad[1]),
                               wp.float32(spacing * grad[2]))
        if complement != 0:
            total += q
            total_gradient += grad
    if complement != 0:
        field[n, n_handles] = wp.vec4f(wp.float32(one - total), wp.float32(-spacing * total_gradient[0]),
                                       wp.float32(-spacing * total_gradient[1]), wp.float32(-spacing * total_gradient[2]))


@wp.func
def blend_near(x: wp.vec3d, band: wp.float64, cage: wp.array(dtype=wp.vec3d), triangles: wp.array(dtype=wp.vec3i),
               mesh: wp.uint64, slack: wp.float32):
    """:func:`blend_at`'s blend, its faces found through the cage's BVH (``mesh``: the cage in float32, in the same
    frame as x): the nearest face's distance in float32, plus the band and ``slack`` (more than float32's error in
    that distance), bounds a cube around x; the faces whose boxes meet it hold every face within the band of the
    nearest, and the float64 search of :func:`blend_at` over them, in the order of their indices, gives the same
    faces, shares and bits. Where more than MAX_CANDIDATES boxes meet the cube, the search over every face."""
    p = wp.vec3(wp.float32(x[0]), wp.float32(x[1]), wp.float32(x[2]))
    closest = wp.mesh_query_point_no_sign(mesh, p, wp.float32(1.0e30))
    if not closest.result:
        return blend_at(x, band, cage, triangles)
    reach = wp.length(wp.mesh_eval_position(mesh, closest.face, closest.u, closest.v) - p) + wp.float32(band) + slack
    found = candidate_list()
    count = int(0)
    query = wp.mesh_query_aabb(mesh, p - wp.vec3(reach), p + wp.vec3(reach))
    f = int(0)
    while wp.mesh_query_aabb_next(query, f):
        if count == MAX_CANDIDATES:
            return blend_at(x, band, cage, triangles)
        # insertion in index order
        k = count
        while k > 0 and found[k - 1] > f:
            found[k] = found[k - 1]
            k -= 1
        found[k] = f
        count += 1
    return blend_over(x, band, cage, triangles, found, count, False)


@wp.kernel
def blend_table(
    ijk: wp.array(dtype=wp.vec3i),
    first_row: int,
    origin: wp.vec3d,
    spacing: wp.float64,
    band: wp.float64,
    cage: wp.array(dtype=wp.vec3d),
    triangles: wp.array(dtype=wp.vec3i),
    mesh: wp.uint64,
    slack: wp.float32,
    table: wp.array(dtype=Blend),
):
    """The blend at active row first_row + thread, in the thread's entry of ``table``: what
    :func:`local_field_from_table` reads for every chunk of handles, instead of searching the faces again. The
    faces are found through the cage's BVH (:func:`blend_near`)."""
    i = wp.tid()
    table[i] = blend_near(grid_point(ijk, first_row + i, origin, spacing), band, cage, triangles, mesh, slack)


@wp.kernel
def local_field_from_table(
    ijk: wp.array(dtype=wp.vec3i),
    first_row: int,
    origin: wp.vec3d,
    spacing: wp.float64,
    cage: wp.array(dtype=wp.vec3d),
    triangles: wp.array(dtype=wp.vec3i),
    normals: wp.array(dtype=wp.vec3d),
    tangent_gradients: wp.array2d(dtype=wp.vec3d),
    normal_derivatives: wp.array2d(dtype=wp.float64),
    table: wp.array(dtype=Blend),
    first_handle: int,
    n_handles: int,
    complement: int,
    field: wp.array2d(dtype=wp.vec4f),
):
    """:func:`local_field` at grid rows, each row's blend read from :func:`blend_table`'s table (the same
    values)."""
    i = wp.tid()
    n = first_row + i
    write_handles(field, n, grid_point(ijk, n, origin, spacing), spacing, table[i], cage, triangles, normals,
                  tangent_gradients, normal_derivatives, first_handle, n_handles, complement)


@wp.func
def heap_sift_up(heap: wp.array2d(dtype=wp.int32), position: wp.array2d(dtype=wp.int32),
                 distance: wp.array2d(dtype=wp.float64), row: int, start: int):
    """Move heap[row, start] up until its parent is no farther (a binary min-heap on ``distance``)."""
    i = start
    node = heap[row, i]
    key = distance[row, node]
    while i > 0:
        parent = (i - 1) // 2
        above = heap[row, parent]
        if distance[row, above] <= key:
            break
        heap[row, i] = above
        position[row, above] = i
        i = parent
    heap[row, i] = node
    position[row, node] = i


@wp.func
def heap_sift_down(heap: wp.array2d(dtype=wp.int32), position: wp.array2d(dtype=wp.int32),
                   distance: wp.array2d(dtype=wp.float64), row: int, size: int):
    """Move heap[row, 0] down until both children are no nearer."""
    i = int(0)
    node = heap[row, 0]
    key = distance[row, node]
    while 2 * i + 1 < size:
        child = 2 * i + 1
        if child + 1 < size and distance[row, heap[row, child + 1]] < distance[row, heap[row, child]]:
            child = child + 1
        below = heap[row, child]
        if distance[row, below] >= key:
            break
        heap[row, i] = below
        position[row, below] = i
        i = child
    heap[row, i] = node
    position[row, node] = i


@wp.kernel
def graph_distances(
    offsets: wp.array(dtype=wp.int32),
    neighbours: wp.array(dtype=wp.int32),
    lengths: wp.array(dtype=wp.float64),
    first_source: int,
    heap: wp.array2d(dtype=wp.int32),
    position: wp.array2d(dtype=wp.int32),
    distance: wp.array2d(dtype=wp.float64),
):
    """distance[s, v] = shortest path from handle first_source + s to handle v along the cage's edges (Dijkstra with
    a binary heap: O(E log L) per source, where Floyd-Warshall's O(L^3) took minutes for thousands of handles); the
    graph in compressed rows (``offsets``, ``neighbours``, ``lengths``); launch over sources. ``heap`` and
    ``position`` are scratch rows (position -1: not reached, -2: settled)."""
    row = wp.tid()
    n = distance.shape[1]
    for v in range(n):
        distance[row, v] = wp.float64(wp.inf)
        position[row, v] = -1
    source = first_source + row
    distance[row, source] = wp.float64(0.0)
    heap[row, 0] = source
    position[row, source] = 0
    size = int(1)
    while size > 0:
        u = heap[row, 0]
        position[row, u] = -2
        size -= 1
        if size > 0:
            heap[row, 0] = heap[row, size]
            heap_sift_down(heap, position, distance, row, size)
        for e in range(offsets[u], offsets[u + 1]):
            v = neighbours[e]
            if position[row, v] != -2:
                through = distance[row, u] + lengths[e]
                if through < distance[row, v]:
                    distance[row, v] = through
                    if position[row, v] == -1:
                        heap[row, size] = v
                        size += 1
                        heap_sift_up(heap, position, distance, row, size - 1)
                    else:
                        heap_sift_up(heap, position, distance, row, position[row, v])
