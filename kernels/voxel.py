"""Inside test by generalised winding number, and the ring and band around the interior."""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})

from .labels import BAND, INTERIOR, OUTSIDE, RING


@wp.func
def node_position(origin: wp.vec3, spacing: float, i: int, j: int, k: int):
    return origin + spacing * wp.vec3(float(i), float(j), float(k))


@wp.func
def classify_node(cage: wp.uint64, p: wp.vec3, accuracy: float, surface_tolerance: float):
    """INTERIOR where the winding number at p exceeds 1/2, OUTSIDE elsewhere and within `surface_tolerance` of the
    cage (where the winding number is 1/2 and its sign is noise: the domain is the open interior, so boxes and other
    grid-aligned cages voxelise deterministically)."""
    query = wp.mesh_query_point_sign_winding_number(cage, p, 1.0e30, accuracy, 0.5)
    label = OUTSIDE
    if query.result and query.sign < 0.0:
        if wp.length(wp.mesh_eval_position(cage, query.face, query.u, query.v) - p) > surface_tolerance:
            label = INTERIOR
    return wp.int8(label)


@wp.kernel
def classify_nodes(
    cage: wp.uint64,
    origin: wp.vec3,
    spacing: float,
    accuracy: float,
    surface_tolerance: float,
    first_i: int,
    stride: int,
    labels: wp.array3d(dtype=wp.int8),
):
    """:func:`classify_node` at the nodes (first_i + stride ti, stride tj, stride tk): every node with stride 1, the
    nodes of even coordinates with 2 (threads on a CPU take a slab each)."""
    ti, tj, tk = wp.tid()
    i = first_i + stride * ti
    j = stride * tj
    k = stride * tk
    labels[i, j, k] = classify_node(cage, node_position(origin, spacing, i, j, k), accuracy, surface_tolerance)


@wp.kernel
def classify_between_even_nodes(
    cage: wp.uint64,
    origin: wp.vec3,
    spacing: float,
    accuracy: float,
    surface_tolerance: float,
    first_i: int,
    labels: wp.array3d(dtype=wp.int8),
):
    """The nodes with an odd coordinate, once the nodes of even coordinates are classified (``classify_nodes`` with
    stride 2): a node whose even neighbours around it (2, 4 or 8, at most sqrt(3) spacings away) agree and that has
    no cage point within its distance to the farthest of them lies in their part of space: it takes their label.
    Otherwise :func:`classify_node`. The same labels as classifying every node (no winding number differs between
    points that a ball free of the cage joins), at about a quarter of the winding numbers where space is mostly far
    from the cage. Launch over the slab of nodes from i = first_i on."""
    ti, j, k = wp.tid()
    i = first_i + ti
    odd = wp.vec3i(i % 2, j % 2, k % 2)
    if odd[0] + odd[1] + odd[2] == 0:
        return
    p = node_position(origin, spacing, i, j, k)
    label = wp.int8(-1)
    agree = bool(True)
    for corner in range(8):
        o = wp.vec3i(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1)
        if o[0] <= odd[0] and o[1] <= odd[1] and o[2] <= odd[2]:
            c = wp.vec3i(i - odd[0] + 2 * o[0], j - odd[1] + 2 * o[1], k - odd[2] + 2 * o[2])
            if c[0] >= labels.shape[0] or c[1] >= labels.shape[1] or c[2] >= labels.shape[2]:
                agree = False
            else:
                corner_label = labels[c[0], c[1], c[2]]
                if label == wp.int8(-1):
                    label = corner_label
                elif corner_label != label:
                    agree = False
    if agree:
        # the ball reaching 1% beyond the farthest even neighbour holds no cage point
        reach = 1.01 * spacing * wp.sqrt(float(odd[0] + odd[1] + odd[2])) + surface_tolerance
        if not wp.mesh_query_point_no_sign(cage, p, reach).result:
            labels[i, j, k] = label
            return
    labels[i, j, k] = classify_node(cage, p, accuracy, surface_tolerance)


@wp.kernel
def mark_ring_and_band(
    labels_in: wp.array3d(dtype=wp.int8),
    band_width: int,
    first_i: int,
    labels_out: wp.array3d(dtype=wp.int8),
):
    """Exterior nodes in the 19-point stencil of an interior node are RING; others within
    `band_width` nodes (max-norm) of an interior node are BAND. The launch covers the slab of nodes from i = first_i
    on (threads on a CPU take a slab each)."""
    ti, j, k = wp.tid()
    i = first_i + ti
    if int(labels_in[i, j, k]) == INTERIOR:
        labels_out[i, j, k] = wp.int8(INTERIOR)
        return
    nx = labels_in.shape[0]
    ny = labels_in.shape[1]
    nz = labels_in.shape[2]
    ring = bool(False)
    near = bool(False)
    for di in range(-band_width, band_width + 1):
        for dj in range(-band_width, band_width + 1):
            for dk in range(-band_width, band_width + 1):
                ii = i + di
                jj = j + dj
                kk = k + dk
                if ii >= 0 and ii < nx and jj >= 0 and jj < ny and kk >= 0 and kk < nz:
                    if int(labels_in[ii, jj, kk]) == INTERIOR:
                        near = True
                        steps = wp.abs(di) + wp.abs(dj) + wp.abs(dk)
                        if steps <= 2 and wp.max(wp.max(wp.abs(di), wp.abs(dj)), wp.abs(dk)) == 1:
                            ring = True
    label = OUTSIDE
    if ring:
        label = RING
    elif near:
        label = BAND
    labels_out[i, j, k] = wp.int8(label)


@wp.kernel
def classify_points(
    cage: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    accuracy: float,
    inside: wp.array(dtype=wp.int32),
    distance: wp.array(dtype=float),
):
    """Inside flag (winding number > 1/2) and unsigned distance to the cage surface, per point."""
    n = wp.tid()
    p = points[n]
    query = wp.mesh_query_point_sign_winding_number(cage, p, 1.0e30, accuracy, 0.5)
    flag = 0
    d = float(0.0)
    if query.result:
        if query.sign < 0.0:
            flag = 1
        d = wp.length(wp.mesh_eval_position(cage, query.face, query.u, query.v) - p)
    inside[n] = flag
    distance[n] = d


@wp.kernel
def nearest_faces(cage: wp.uint64, points: wp.array(dtype=wp.vec3), face: wp.array(dtype=wp.int32)):
    """The cage face nearest to each point."""
    n = wp.tid()
    query = wp.mesh_query_point_no_sign(cage, points[n], 1.0e30)
    face[n] = query.face


@wp.func
def first_hit(cage: wp.uint64, start: wp.vec3, end: wp.vec3, tolerance: float):
    """The cage face that the segment from `start` to `end` meets first, more than `tolerance` before `end`; -1
    where it meets none."""
    d = end - start
    length = wp.length(d)
    face = int(-1)
    if length > tolerance:
        hit = wp.mesh_query_ray(cage, start, d / length, length - tolerance)
        if hit.result:
            face = hit.face
    return face


@wp.func
def near_along_the_cage(faces: wp.array2d(dtype=wp.int32), adjacent: wp.array2d(dtype=wp.int8), f: int, g: int):
    """Whether a corner of cage face f is a corner of g or an edge away from one: the two walls of one thin wedge
    of outside space where the cage folds back, rather than two parts of the body that happen to be close."""
    near = bool(False)
    for a in range(3):
        for b in range(3):
            if int(adjacent[faces[f, a], faces[g, b]]) != 0:
                near = True
    return near


@wp.func
def data_slope_at(faces: wp.array2d(dtype=wp.int32), handle_slope: wp.array(dtype=float), face: int, u: float,
                  v: float):
    """The steepest boundary data around a cage point (face, barycentric u, v): the largest slope of the handles whose
    hat function is not zero there. The same for either face when the point is on their shared edge."""
    slope = float(0.0)
    weights = wp.vec3(u, v, 1.0 - u - v)
    for c in range(3):
        if weights[c] > 1.0e-3:
            slope = wp.max(slope, handle_slope[faces[face, c]])
    return slope


#: the 3 x 3 x 3 offsets around a node, walked as one loop (longer than Warp's unrolling limit, ``wp.config.max_unroll``)
NEIGHBOURHOOD = wp.constant(27)


@wp.kernel
def cut_off_nodes(
    cage: wp.uint64,
    faces: wp.array2d(dtype=wp.int32),
    adjacent: wp.array2d(dtype=wp.int8),
    handle_slope: wp.array(dtype=float),
    inside: wp.array3d(dtype=wp.int8),
    origin: wp.vec3,
    spacing: float,
    facing: float,
    max_change: float,
    labels: wp.array3d(dtype=wp.int8),
):
    """RING (known data) for interior nodes that a thin wedge of outside space cuts off from a stencil neighbour:
    an interior neighbour on the wedge's other side (the link enters and leaves through two walls that face each
    other, normals' dot product below `facing`, and are near along the cage), or an exterior neighbour whose data
    comes from the far wall (its closest cage point is hidden behind the wall next to the node, and the data extends
    from there towards the node's wall). Only where the boundary data extended to the node over a diagonal link
    (1.5 cells) changes by at most `max_change`: elsewhere the faces are too small for the grid and the node stays
    an unknown."""
    i, j, k = wp.tid()
    if int(inside[i, j, k]) != INTERIOR:
        return
    p = node_position(origin, spacing, i, j, k)
    near = wp.mesh_query_point_no_sign(cage, p, 1.5 * spacing)
    if not near.result:
        return  # no link from here reaches the cage
    if 1.5 * spacing * data_slope_at(faces, handle_slope, near.face, near.u, near.v) > max_change:
        return
    cut = bool(False)
    # one loop over the 27 offsets, not three nested ones: Warp unrolls short constant loops, and 27 copies of
    # this body (three inlined BVH queries each) took 33 s to compile on the CPU
    for s in range(NEIGHBOURHOOD):
        di = s // 9 - 1
        dj = (s // 3) % 3 - 1
        dk = s % 3 - 1
        steps = wp.abs(di) + wp.abs(dj) + wp.abs(dk)
        if steps >= 1 and steps <= 2 and not cut:
            neighbour = node_position(origin, spacing, i + di, j + dj, k + dk)
            if int(inside[i + di, j + dj, k + dk]) == INTERIOR:
                entry = first_hit(cage, p, neighbour, 0.0)
                if entry >= 0:
                    exit = first_hit(cage, neighbour, p, 0.0)
                    if exit >= 0:
                        facing_walls = wp.dot(wp.mesh_eval_face_normal(cage, entry),
                                              wp.mesh_eval_face_normal(cage, exit)) < facing
                        cut = facing_walls and near_along_the_cage(faces, adjacent, entry, exit)
            else:
                closest = wp.mesh_query_point_no_sign(cage, neighbour, 2.0 * spacing)
                if closest.result:
                    y = wp.mesh_eval_position(cage, closest.face, closest.u, closest.v)
                    wall = first_hit(cage, p, y, 1.0e-3 * spacing)
                    if wall >= 0:
                        # the direction the neighbour's data extends in, from its closest point
                        extension = wp.normalize(neighbour - y)
                        facing_walls = wp.dot(wp.mesh_eval_face_normal(cage, wall), extension) < facing
                        cut = facing_walls and near_along_the_cage(faces, adjacent, wall, closest.face)
    if cut:
        labels[i, j, k] = wp.int8(RING)


# -- numbering: the active nodes in (class, lattice order), computed on the device one (i, j) column per thread --------

#: classes of numbered nodes, in row order: interior, cut-off (ring nodes inside the cage), other ring, band
LATTICE_CLASSES = wp.constant(4)


@wp.func
def node_class(label: wp.int8, inside: wp.int8):
    """The row block a node is numbered in: 0 interior, 1 cut off (RING but inside the cage), 2 ring, 3 band, -1 none."""
    lab = int(label)
    if lab == INTERIOR:
        return 0
    if lab == RING:
        if int(inside) != 0:
            return 1
        return 2
    if lab == BAND:
        return 3
    return -1


@wp.kernel
def node_classes(labels: wp.array3d(dtype=wp.int8), inside: wp.array3d(dtype=wp.int8),
                 classes: wp.array3d(dtype=wp.int8)):
    i, j, k = wp.tid()
    classes[i, j, k] = wp.int8(node_class(labels[i, j, k], inside[i, j, k]))


@wp.kernel
def count_classes(classes: wp.array3d(dtype=wp.int8), counts: wp.array(dtype=wp.int32)):
    """Nodes of each class in column (i, j), at counts[class * columns + i * ny + j]: an exclusive scan of counts then
    gives each column's first row in every class, in the numbering's order (class, then lattice order)."""
    i, j = wp.tid()
    ny = classes.shape[1]
    columns = classes.shape[0] * ny
    c0 = int(0)
    c1 = int(0)
    c2 = int(0)
    c3 = int(0)
    for k in range(classes.shape[2]):
        c = int(classes[i, j, k])
        if c == 0:
            c0 += 1
        elif c == 1:
            c1 += 1
        elif c == 2:
            c2 += 1
        elif c == 3:
            c3 += 1
    column = i * ny + j
    counts[column] = c0
    counts[columns + column] = c1
    counts[2 * columns + column] = c2
    counts[3 * columns + column] = c3


@wp.kernel
def number_classes(classes: wp.array3d(dtype=wp.int8), first_rows: wp.array(dtype=wp.int32),
                   index: wp.array3d(dtype=wp.int32), ijk: wp.array(dtype=wp.vec3i)):
    """Each node's row (-1 for class -1) from its column's first rows (``count_classes``, scanned), and each row's
    node."""
    i, j = wp.tid()
    ny = classes.shape[1]
    columns = classes.shape[0] * ny
    column = i * ny + j
    r0 = first_rows[column]
    r1 = first_rows[columns + column]
    r2 = first_rows[2 * columns + column]
    r3 = first_rows[3 * columns + column]
    for k in range(classes.shape[2]):
        c = int(classes[i, j, k])
        row = int(-1)
        if c == 0:
            row = r0
            r0 += 1
        elif c == 1:
            row = r1
            r1 += 1
        elif c == 2:
            row = r2
            r2 += 1
        elif c == 3:
            row = r3
            r3 += 1
        index[i, j, k] = row
        if row >= 0:
            ijk[row] = wp.vec3i(i, j, k)


# -- the stencil's work items: runs along z of patches of columns that hold interior nodes, one patch column per thread

@wp.func
def patch_holds_interior(labels: wp.array3d(dtype=wp.int8), i0: int, j0: int, pi: int, pj: int, k: int):
    """Whether one of the pi x pj columns from (i0, j0) has an interior node in plane k."""
    for di in range(pi):
        for dj in range(pj):
            i = i0 + di
            j = j0 + dj
            if i < labels.shape[0] and j < labels.shape[1]:
                if int(labels[i, j, k]) == INTERIOR:
                    return True
    return False


@wp.kernel
def count_patch_items(labels: wp.array3d(dtype=wp.int8), pi: int, pj: int, max_length: int,
                      counts: wp.array(dtype=wp.int32)):
    """Work items of patch column (a, b): each run of planes where the patch holds an interior node, in pieces of at
    most ``max_length``; at counts[a * patch columns along y + b] (scanned, each column's first item)."""
    a, b = wp.tid()
    columns_y = (labels.shape[1] + pj - 1) // pj
    items = int(0)
    run = int(0)
    for k in range(labels.shape[2]):
        if patch_holds_interior(labels, a * pi, b * pj, pi, pj, k):
            run += 1
        else:
            items += (run + max_length - 1) // max_length
            run = 0
    items += (run + max_length - 1) // max_length
    counts[a * columns_y + b] = items


@wp.kernel
def write_patch_items(labels: wp.array3d(dtype=wp.int8), pi: int, pj: int, max_length: int,
                      first: wp.array(dtype=wp.int32), items: wp.array(dtype=wp.vec4i)):
    """The items counted by ``count_patch_items`` from each patch column's first: (i0, j0, k0, planes), in k order."""
    a, b = wp.tid()
    columns_y = (labels.shape[1] + pj - 1) // pj
    out = first[a * columns_y + b]
    nz = labels.shape[2]
    start = int(-1)
    for k in range(nz + 1):
        holds = bool(False)
        if k < nz:
            holds = patch_holds_interior(labels, a * pi, b * pj, pi, pj, k)
        if holds:
            if start < 0:
                start = k
        elif start >= 0:
            s = start
            while s < k:
                items[out] = wp.vec4i(a * pi, b * pj, s, wp.min(max_length, k - s))
                out += 1
                s += max_length
            start = -1
