"""Making a cage: the mesh's signed distance on a voxel grid, whose level set at the offset is the cage's start (the
collapses that simplify it are checked in :mod:`.collapse`)."""

import warp as wp

# no kernel of the package is differentiated: without adjoints a first run compiles in half the time
wp.set_module_options({"enable_backward": False})


@wp.kernel
def signed_distance(mesh: wp.uint64, origin: wp.vec3, spacing: float, accuracy: float,
                    field: wp.array3d(dtype=float)):
    """field = the distance to the mesh, negative inside it (generalised winding number > 1/2, so that open,
    self-intersecting and many-piece meshes have an inside too); launch over the grid's nodes."""
    i, j, k = wp.tid()
    p = origin + spacing * wp.vec3(float(i), float(j), float(k))
    query = wp.mesh_query_point_sign_winding_number(mesh, p, 1.0e30, accuracy, 0.5)
    d = wp.length(wp.mesh_eval_position(mesh, query.face, query.u, query.v) - p)
    field[i, j, k] = query.sign * d


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
