"""Inside test by generalised winding number, and the ring and band around the interior."""

import warp as wp

from .labels import BAND, INTERIOR, OUTSIDE, RING


@wp.func
def node_position(origin: wp.vec3, spacing: float, i: int, j: int, k: int):
    return origin + spacing * wp.vec3(float(i), float(j), float(k))


@wp.kernel
def classify_nodes(
    cage: wp.uint64,
    origin: wp.vec3,
    spacing: float,
    accuracy: float,
    surface_tolerance: float,
    labels: wp.array3d(dtype=wp.int8),
):
    """INTERIOR where the winding number exceeds 1/2, OUTSIDE elsewhere. Nodes on the cage surface
    (closer than `surface_tolerance`), where the winding number is 1/2 and its sign is noise, are outside:
    the domain is the open interior, so boxes and other grid-aligned cages voxelise deterministically."""
    i, j, k = wp.tid()
    p = node_position(origin, spacing, i, j, k)
    query = wp.mesh_query_point_sign_winding_number(cage, p, 1.0e30, accuracy, 0.5)
    label = OUTSIDE
    if query.result and query.sign < 0.0:
        if wp.length(wp.mesh_eval_position(cage, query.face, query.u, query.v) - p) > surface_tolerance:
            label = INTERIOR
    labels[i, j, k] = wp.int8(label)


@wp.kernel
def mark_ring_and_band(
    labels_in: wp.array3d(dtype=wp.int8),
    band_width: int,
    labels_out: wp.array3d(dtype=wp.int8),
):
    """Exterior nodes in the 19-point stencil of an interior node are RING; others within
    `band_width` nodes (max-norm) of an interior node are BAND."""
    i, j, k = wp.tid()
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
