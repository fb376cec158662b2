import numpy as np
import pytest

import warp_stokes as ws
from conftest import PAIRS, float32_rounding, pair
from warp_stokes.kernels import labels as L


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_mvc_partition_of_unity_and_linear_precision(name, device):
    _, cage_path = pair(name)
    cage = ws.check_cage(cage_path)
    rng = np.random.default_rng(0)
    lo, hi = cage.vertices.min(0), cage.vertices.max(0)
    pad = 0.2 * (hi - lo)
    points = rng.uniform(lo - pad, hi + pad, size=(400, 3))  # inside and outside the cage
    w = ws.mean_value_coordinates(cage, points, device=device)
    assert np.abs(w.sum(1) - 1).max() < 1e-10
    assert np.linalg.norm(w @ cage.vertices - points, axis=1).max() < 1e-9 * cage.diagonal


def test_mvc_interpolates_on_the_cage(arm_cage, device):
    # at a cage vertex: the Kronecker delta; on a face: the face's barycentric coordinates
    w = ws.mean_value_coordinates(arm_cage, arm_cage.vertices[[3, 10]], device=device)
    np.testing.assert_allclose(w, np.eye(len(arm_cage.vertices))[[3, 10]], atol=1e-12)
    tri = arm_cage.faces[7]
    bary = np.array([0.2, 0.3, 0.5])
    w = ws.mean_value_coordinates(arm_cage, (bary @ arm_cage.vertices[tri])[None], device=device)[0]
    expected = np.zeros(len(arm_cage.vertices))
    expected[tri] = bary
    np.testing.assert_allclose(w, expected, atol=1e-7)


def test_mvc_in_the_plane_of_cage_triangles(device):
    # points on the lines through a box's edges lie in the planes of the triangles at those edges
    from conftest import box_cage

    cage = ws.check_cage(box_cage(lo=(-1, -2, -3), hi=(1, 2, 3)))
    points = np.array([[1, 2, 3.5], [1, 2, -4], [1.25, 2, 3], [-1, -2.5, -3], [1.5, 3, 3], [2, 2, 3]], float)
    w = ws.mean_value_coordinates(cage, points, device=device)
    assert np.abs(w.sum(1) - 1).max() < 1e-10
    assert np.linalg.norm(w @ cage.vertices - points, axis=1).max() < 1e-9 * cage.diagonal


def test_mvc_on_the_line_through_a_cage_edge_with_round_off(device):
    # Grid nodes of this ellipsoid at resolution 24 include a point on the line through vertices 8 and 9,
    # where one corner angle comes out as 1e-16 instead of 0 and the paper's coplanarity test on s misses it:
    # linear precision was off by 0.99 there before the test on the unit vectors' volume.
    import trimesh

    sphere = trimesh.creation.uv_sphere(radius=1.0, count=[18, 14])
    sphere.vertices *= [2.0, 1.0, 0.8]
    cage = ws.check_cage(sphere)
    grid = ws.voxelize(cage, 24, device=device)
    points = grid.node_positions() + grid.centre
    w = ws.mean_value_coordinates(cage, points, device=device)
    assert np.abs(w.sum(1) - 1).max() < 1e-10
    assert np.linalg.norm(w @ cage.vertices - points, axis=1).max() < 1e-7


def test_mvc_are_positive_inside_a_convex_cage(device):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=1)
    cage = ws.check_cage(m)
    points = np.random.default_rng(1).normal(size=(200, 3))
    points *= 0.8 * np.random.default_rng(2).uniform(size=(200, 1)) / np.linalg.norm(points, axis=1, keepdims=True)
    w = ws.mean_value_coordinates(cage, points, device=device)
    assert (w > 0).all()


def test_boundary_field_reproduces_linear_functions(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=16, device=device, boundary="mvc")
    field = ws.boundary_field(grid, arm_cage, device=device).numpy().astype(np.float64)  # (N, L, 4)
    q, g = field[..., 0], field[..., 1:]
    n_grad = grid.n_interior + grid.n_ring
    pos = grid.node_positions() + grid.centre
    c = arm_cage.vertices - grid.centre
    # sum_l phi_l = 1 and sum_l c_l phi_l = x at every active node; G of those is 0 and h * identity. The data is
    # float64 stored as float32: each entry rounded once (half an eps), so the sums are off by at most half an eps
    # of the sums of magnitudes; 8 eps of those
    np.testing.assert_allclose(q.sum(1), 1.0, rtol=0, atol=float32_rounding(np.abs(q).sum(1).max()))
    np.testing.assert_allclose(q @ c, pos - grid.centre, rtol=0, atol=float32_rounding((np.abs(q) @ np.abs(c)).max()))
    np.testing.assert_allclose(g[:n_grad].sum(1), 0.0, rtol=0, atol=float32_rounding(np.abs(g[:n_grad]).sum(1).max()))
    for a in range(3):
        expected = np.zeros(3)
        expected[a] = grid.spacing
        np.testing.assert_allclose(np.einsum("l,nld->nd", c[:, a], g[:n_grad]),
                                   np.broadcast_to(expected, (n_grad, 3)), rtol=0,
                                   atol=float32_rounding(np.einsum("l,nld->nd", np.abs(c[:, a]), np.abs(g[:n_grad]))
                                                         .max()))
    assert (grid.labels[tuple(grid.active_ijk[grid.n_interior:].T)] != L.INTERIOR).all()


def test_the_starting_guess_is_mvc_interpolated_from_the_even_nodes(arm_cage):
    # With the local data on a CPU the interior rows carry the solve's starting guess: mean value coordinates at the
    # nodes of even coordinates (computed here by ws.mean_value_coordinates), interpolated trilinearly; they keep
    # partition of unity and linear precision, and a table of all handles for threads (start_values) gives a chunk's
    # bits. (A GPU computes them at every node: test_boundary_field_reproduces_linear_functions checks those.)
    from warp_stokes.geometry.boundary import start_values

    device = "cpu"
    grid = ws.voxelize(arm_cage, resolution=20, device=device)
    field = ws.boundary_field(grid, arm_cage, device=device).numpy().astype(np.float64)
    interior = grid.active_ijk[: grid.n_interior]
    expected = np.zeros((grid.n_interior, arm_cage.n_handles))
    odd = interior % 2
    corners = [np.array(c) for c in np.ndindex(2, 2, 2)]
    count = np.zeros(grid.n_interior)
    for corner in corners:
        reads = (corner <= odd).all(axis=1)
        even = 2 * (interior[reads] // 2 + corner)
        positions = grid.centre + grid.origin + grid.spacing * even
        expected[reads] += ws.mean_value_coordinates(arm_cage, positions, device=device)
        count[reads] += 1
    expected /= count[:, None]
    assert (odd.sum(axis=1) == 3).any() and (odd.sum(axis=1) == 0).any()
    q = field[: grid.n_interior, :, 0]
    np.testing.assert_allclose(q, expected, rtol=0, atol=float32_rounding(np.abs(expected).max()))
    np.testing.assert_allclose(q.sum(1), 1.0, rtol=0, atol=float32_rounding(np.abs(q).sum(1).max()))
    c = arm_cage.vertices - grid.centre
    np.testing.assert_allclose(q @ c, grid.origin + grid.spacing * interior, rtol=0,
                               atol=float32_rounding((np.abs(q) @ np.abs(c)).max()))
    chunk = slice(7, 40)
    table = start_values(grid, arm_cage, device=device, threads=2)
    np.testing.assert_array_equal(ws.boundary_field(grid, arm_cage, device=device, handles=chunk, start=table).numpy(),
                                  ws.boundary_field(grid, arm_cage, device=device, handles=chunk).numpy())


def test_complement_column_is_the_rest_of_the_cage(arm_cage, device):
    # The column after a chunk stands for the other handles: sum_l w_l over the handles outside the chunk,
    # value and gradient, computed here from those handles' own fields.
    grid = ws.voxelize(arm_cage, resolution=16, device=device, boundary="mvc")
    chunk = slice(20, 35)
    field = ws.boundary_field(grid, arm_cage, device=device, handles=chunk, complement=True).numpy()
    assert field.shape == (grid.n_active, 15 + ws.COMPLEMENT_COLUMNS, 4) and ws.COMPLEMENT_COLUMNS == 1
    whole = ws.boundary_field(grid, arm_cage, device=device).numpy().astype(np.float64)  # (N, L, 4)
    np.testing.assert_array_equal(field[:, :15], whole[:, chunk])
    rest = np.ones(arm_cage.n_handles, bool)
    rest[chunk] = False
    # float64 sums stored as float32 against sums of float32-stored terms: 8 eps of the sums of magnitudes
    np.testing.assert_allclose(field[:, 15], whole[:, rest].sum(1), rtol=0,
                               atol=float32_rounding(np.abs(whole[:, rest]).sum(1).max()))
    # the chunk and its complement sum to 1 like the whole cage, with zero gradient
    np.testing.assert_allclose(field[:, :16].astype(np.float64).sum(1),
                               np.broadcast_to([1.0, 0, 0, 0], (grid.n_active, 4)), rtol=0,
                               atol=float32_rounding(np.abs(field[:, :16].astype(np.float64)).sum(1).max()))


def _box_points(cage):
    """On a box cage: points on a face, on a face's diagonal (the edge its two triangles share), on a cage edge and
    at a vertex."""
    return {"face": np.array([0.3, -0.4, 1.0]), "diagonal": np.array([0.25, 0.25, 1.0]),
            "edge": np.array([0.3, 1.0, 1.0]), "vertex": np.array([1.0, 1.0, 1.0])}


def test_mvc_on_faces_their_diagonals_edges_and_vertices_are_the_hat_functions(device):
    from conftest import box_cage

    cage = ws.check_cage(box_cage())
    for where, p in _box_points(cage).items():
        w = ws.mean_value_coordinates(cage, p[None], device=device)[0]
        # the hat functions at p: the barycentric coordinates in a triangle that holds p
        expected = None
        for tri in cage.faces:
            a = np.vstack([cage.vertices[tri].T, np.ones(3)])  # (4, 3): corners and the affine row
            b = np.linalg.lstsq(a, np.append(p, 1.0), rcond=None)[0]
            if np.allclose(a @ b, np.append(p, 1.0), atol=1e-12) and (b >= -1e-12).all():
                expected = np.zeros(cage.n_handles)
                expected[tri] = b
                break
        assert expected is not None
        np.testing.assert_allclose(w, expected, atol=1e-14, err_msg=where)


@pytest.mark.parametrize("distance", [1e-8, 1e-6, 1e-4, 1e-2])
def test_mvc_keeps_partition_of_unity_and_linear_precision_next_to_the_cage(distance, device):
    # inside and outside, next to a face, a face's diagonal, an edge and a vertex (the half-angle formula lost up
    # to 0.3 of the diagonal in linear precision at 1e-9 from an edge, and snapped points within 1e-5 to the face)
    from conftest import box_cage

    cage = ws.check_cage(box_cage())
    direction = np.array([0.3, 0.5, 1.0]) / np.linalg.norm([0.3, 0.5, 1.0])
    points = np.array([p + side * distance * cage.diagonal * direction
                       for p in _box_points(cage).values() for side in (1, -1)])
    w = ws.mean_value_coordinates(cage, points, device=device)
    assert np.abs(w.sum(1) - 1).max() < 1e-13
    assert np.linalg.norm(w @ cage.vertices - points, axis=1).max() < 1e-12 * cage.diagonal


@pytest.mark.parametrize("subdivided", [False, True])
@pytest.mark.parametrize("boundary", ["mvc", "local"])
def test_box_cages_bind_like_any_cage(subdivided, boundary, device):
    # grid nodes fall on the box's faces and their diagonals: before MVC was exact there, the bind never converged
    # (78 iterations, linear precision off by 2-4% of the diagonal)
    import trimesh

    box = trimesh.creation.box(extents=[2, 2, 2])
    box = box.subdivide() if subdivided else box
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.8)
    b = ws.bind((mesh.vertices, mesh.faces), (box.vertices, box.faces), resolution=24, device=device,
                boundary=boundary)
    assert b.stats.converged and b.stats.solver.iterations <= 10
    assert b.stats.partition_of_unity_error <= 1e-5 and b.stats.linear_precision_error <= 1e-5
