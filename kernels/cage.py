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
