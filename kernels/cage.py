"""Making a cage: the mesh's signed distance on a voxel grid, whose level set at the offset is the cage's start (the
collapses that simplify it are checked in :mod:`.collapse`)."""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.func
def signed_distance_at(mesh: wp.uint64, p: wp.vec3, accuracy: float):
    """The distance from p to the mesh, negative inside it (generalised winding number > 1/2, so that open,
    self-intersecting and many-piece meshes have an inside too)."""
    query = wp.mesh_query_point_sign_winding_number(mesh, p, 1.0e30, accuracy, 0.5)
    return query.sign * wp.length(wp.mesh_eval_position(mesh, query.face, query.u, query.v) - p)


@wp.kernel
def signed_distance(mesh: wp.uint64, origin: wp.vec3, spacing: float, accuracy: float, stride: int,
                    field: wp.array3d(dtype=float)):
    """field = :func:`signed_distance_at` at the nodes (stride ti, stride tj, stride tk): every node with stride 1,
    the nodes of even coordinates with 2."""
    ti, tj, tk = wp.tid()
    i = stride * ti
    j = stride * tj
    k = stride * tk
    field[i, j, k] = signed_distance_at(mesh, origin + spacing * wp.vec3(float(i), float(j), float(k)), accuracy)


@wp.kernel
def signed_distance_between_even_nodes(mesh: wp.uint64, origin: wp.vec3, spacing: float, accuracy: float,
                                       cap: float, field: wp.array3d(dtype=float)):
    """The nodes with an odd coordinate, once the nodes of even coordinates have their signed distance
    (``signed_distance`` with stride 2): the distance without a winding number, and the sign of the even neighbours
    around the node (2, 4 or 8, at most sqrt(3) spacings away) where they agree and the mesh is farther than the
    farthest of them (a ball free of the mesh joins them: the same side); elsewhere :func:`signed_distance_at`.
    Distances beyond ``cap`` (at least 2 spacings) may be written as 1.01 ``cap``: the sign is all that is needed
    there (but see :func:`uncap_at_side_changes`). The winding numbers are most of the field's cost (on a CPU, nearly
    all of it on a fine grid)."""
    i, j, k = wp.tid()
    odd = wp.vec3i(i % 2, j % 2, k % 2)
    if odd[0] + odd[1] + odd[2] == 0:
        return
    p = origin + spacing * wp.vec3(float(i), float(j), float(k))
    side = float(0.0)
    agree = bool(True)
    for corner in range(8):
        o = wp.vec3i(corner & 1, (corner >> 1) & 1, (corner >> 2) & 1)
        if o[0] <= odd[0] and o[1] <= odd[1] and o[2] <= odd[2]:
            c = wp.vec3i(i - odd[0] + 2 * o[0], j - odd[1] + 2 * o[1], k - odd[2] + 2 * o[2])
            if c[0] >= field.shape[0] or c[1] >= field.shape[1] or c[2] >= field.shape[2]:
                agree = False
            else:
                s = wp.sign(field[c[0], c[1], c[2]])
                if field[c[0], c[1], c[2]] == 0.0 or (side != 0.0 and s != side):
                    agree = False
                side = s
    if agree:
        reach = 1.01 * cap  # a distance just below cap is found whatever the query's rounding at its bound
        query = wp.mesh_query_point_no_sign(mesh, p, reach)
        d = reach
        if query.result:
            d = wp.length(wp.mesh_eval_position(mesh, query.face, query.u, query.v) - p)
        if d > 1.01 * spacing * wp.sqrt(float(odd[0] + odd[1] + odd[2])):
            field[i, j, k] = side * d
            return
    field[i, j, k] = signed_distance_at(mesh, p, accuracy)


@wp.kernel
def uncap_at_side_changes(mesh: wp.uint64, origin: wp.vec3, spacing: float, cap: float,
                          field: wp.array3d(dtype=float)):
    """Nodes written as ``cap`` away (``signed_distance_between_even_nodes``) whose grid neighbour lies on the other
    side get their exact distance: an open mesh's inside ends where its winding number passes 1/2, which can be far
    from any face (across a hole), and marching cubes interpolates the distance there."""
    i, j, k = wp.tid()
    value = field[i, j, k]
    if wp.abs(value) < cap:
        return
    other = bool(False)
    for axis in range(3):
        for step in range(-1, 2, 2):
            n = wp.vec3i(i, j, k)
            n[axis] = n[axis] + step
            if n[axis] >= 0 and n[axis] < field.shape[axis]:
                if field[n[0], n[1], n[2]] * value <= 0.0:
                    other = True
    if other:
        p = origin + spacing * wp.vec3(float(i), float(j), float(k))
        query = wp.mesh_query_point_no_sign(mesh, p, 1.0e30)
        field[i, j, k] = wp.sign(value) * wp.length(wp.mesh_eval_position(mesh, query.face, query.u, query.v) - p)


@wp.kernel
def distance_to_points(points_bvh: wp.uint64, points: wp.array(dtype=wp.vec3), origin: wp.vec3, spacing: float,
                       reach: float, field: wp.array3d(dtype=float)):
    """field = min(field, the distance to the nearest of ``points`` within ``reach``) at nodes outside the mesh
    (field > 0): vertices on no face (a mesh's stray points) get a ball of the offset's radius, as faces get a
    shell; launch over the grid's nodes."""
    i, j, k = wp.tid()
    nearest = field[i, j, k]
    if nearest <= 0.0:
        return
    p = origin + spacing * wp.vec3(float(i), float(j), float(k))
    query = wp.bvh_query_aabb(points_bvh, p - wp.vec3(reach), p + wp.vec3(reach))
    index = int(0)
    while wp.bvh_query_next(query, index):
        nearest = wp.min(nearest, wp.length(points[index] - p))
    field[i, j, k] = nearest
