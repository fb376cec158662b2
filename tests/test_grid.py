import numpy as np
import pytest
import trimesh
import warp as wp
from scipy import ndimage

import warp_stokes as ws
from conftest import PAIRS, box_cage, pair, slit_cage
from warp_stokes.kernels import labels as L


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_inside_test_agrees_with_trimesh_contains(name, device):
    _, cage_path = pair(name)
    cage = ws.check_cage(cage_path)
    grid = ws.voxelize(cage, resolution=24, device=device, boundary="mvc")  # labels by the winding number alone
    nodes = np.stack(np.meshgrid(*[np.arange(s) for s in grid.shape], indexing="ij"), -1).reshape(-1, 3)
    points = grid.centre + grid.origin + grid.spacing * nodes
    mesh = trimesh.Trimesh(cage.vertices, cage.faces, process=False)
    reference = mesh.contains(points)
    ours = grid.labels.ravel() == L.INTERIOR
    # ray-cast containment is ambiguous on the surface itself: leave out nodes within 1e-4 of the diagonal
    distance = np.abs(trimesh.proximity.signed_distance(mesh, points))
    clear = distance > 1e-4 * cage.diagonal
    assert clear.mean() > 0.99
    assert ours.sum() > 100
    mismatch = (ours != reference) & clear
    assert mismatch.sum() == 0, f"{mismatch.sum()} of {clear.sum()} nodes disagree with trimesh"


def test_ring_and_band_match_morphological_dilation(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=20, device=device, boundary="mvc")  # no node cut off
    interior = grid.labels == L.INTERIOR
    stencil = ndimage.generate_binary_structure(3, 2)  # the 18 face and edge neighbours + centre
    ring = ndimage.binary_dilation(interior, structure=stencil) & ~interior
    band = ndimage.binary_dilation(interior, structure=np.ones((3, 3, 3)), iterations=ws.geometry.grid.BAND_WIDTH)
    band &= ~interior & ~ring
    np.testing.assert_array_equal(grid.labels == L.RING, ring)
    np.testing.assert_array_equal(grid.labels == L.BAND, band)
    assert grid.n_interior == interior.sum() and grid.n_ring == ring.sum() and grid.n_band == band.sum()
    # numbering: interior, then ring, then band; index is the inverse of active_ijk
    i, j, k = grid.active_ijk.T
    np.testing.assert_array_equal(grid.index[i, j, k], np.arange(grid.n_active))
    assert (grid.labels[i[: grid.n_interior], j[: grid.n_interior], k[: grid.n_interior]] == L.INTERIOR).all()
    assert (grid.index >= 0).sum() == grid.n_active


def test_grid_covers_the_cage_with_margin(arm_cage, device):
    grid = ws.voxelize(arm_cage, resolution=32, device=device)
    lo = grid.centre + grid.origin
    hi = lo + grid.spacing * (np.array(grid.shape) - 1)
    margin = ws.geometry.grid.MARGIN * grid.spacing * (1 - 1e-9)
    assert (arm_cage.vertices.min(0) - lo >= margin).all() and (hi - arm_cage.vertices.max(0) >= margin).all()
    extent = arm_cage.vertices.max(0) - arm_cage.vertices.min(0)
    assert np.isclose(grid.spacing, extent.max() / 32)


def test_box_interior_is_exact(device):
    v, f = box_cage(hi=(1.0, 0.5, 0.25), lo=(-1.0, -0.5, -0.25))
    grid = ws.voxelize(ws.check_cage((v, f)), resolution=16, device=device)
    pos = grid.node_positions(np.arange(grid.n_interior)) + grid.centre
    assert (np.abs(pos) < [1.0, 0.5, 0.25]).all()
    # the box spans 16 x 8 x 4 cells: nodes on its surface are not interior, all others are
    assert grid.n_interior == 15 * 7 * 3


@pytest.mark.parametrize("resolution", [4, 5000, 16.5, "64"])
def test_bad_resolution(arm_cage, resolution, device):
    with pytest.raises(ws.ResolutionError, match="resolution"):
        ws.voxelize(arm_cage, resolution=resolution, device=device)


def test_grid_from_mask_rejects_interior_at_the_edge(device):
    mask = np.zeros((12, 12, 12), bool)
    mask[2:6, 5:7, 5:7] = True
    with pytest.raises(ws.ResolutionError, match="away from the mask's edge"):
        ws.grid_from_mask(mask, device=device)


def test_classify_points(arm_cage, device):
    centre = arm_cage.vertices.mean(0)
    far = centre + 10 * arm_cage.diagonal
    inside, distance = ws.classify_points(arm_cage, np.array([far, arm_cage.vertices[0]]), device=device)
    assert not inside[0]
    assert distance[0] > 9 * arm_cage.diagonal and distance[1] < 1e-5 * arm_cage.diagonal


@pytest.mark.parametrize("patch,max_length", [((2, 2), 1), ((2, 2), 64), ((1, 1), 5), ((3, 2), 1000)])
def test_interior_patches_cover_each_interior_node_once(arm_cage, patch, max_length, device):
    grid = ws.voxelize(arm_cage, 24, device=device)
    items = grid.interior_patches(patch, max_length)
    assert items.dtype == np.int32 and items.shape[1] == 4
    i0, j0, k0, length = items.T
    assert (length >= 1).all() and (length <= max_length).all()
    assert (i0 % patch[0] == 0).all() and (j0 % patch[1] == 0).all()
    # every node an item walks, counted: each interior node exactly once
    covered = np.zeros(grid.shape, dtype=np.int64)
    for i, j, k, n in items:
        covered[i : i + patch[0], j : j + patch[1], k : k + n] += 1
    interior = np.zeros(grid.shape, dtype=bool)
    interior[tuple(grid.active_ijk[: grid.n_interior].T)] = True
    assert covered.max() == 1 and covered[interior].min() == 1
    # and an item's every plane holds an interior node of its patch (no empty planes walked)
    for i, j, k, n in items:
        assert interior[i : i + patch[0], j : j + patch[1], k : k + n].any(axis=(0, 1)).all()
    # runs are split only where they must be: pieces of max_length, then the rest
    if max_length == 64:
        whole = grid.interior_patches(patch, 10**6)
        assert whole[:, 3].sum() == length.sum() and len(items) == np.sum(-(-whole[:, 3] // max_length))


@pytest.mark.parametrize("cage_name", ["arm", "slit"])
def test_patches_made_on_the_device_are_the_hosts(arm_cage, cage_name, device):
    from warp_stokes.geometry.grid import device_patches
    from warp_stokes.kernels import stencil

    cage = arm_cage if cage_name == "arm" else slit_cage()[0]  # with nodes cut off (RING inside the cage)
    grid = ws.voxelize(cage, 24, device=device)
    made = grid._device_arrays[ws.resolve_device(device).alias]  # what voxelize left for the stencil
    if ws.resolve_device(device).is_cpu:  # a CPU's node loops: each interior node's neighbour rows, as numpy finds them
        from warp_stokes.kernels import stencil_cpu

        assert "patches" not in made
        ijk = grid.active_ijk[: grid.n_interior, None, :] + np.array(stencil_cpu.OFFSETS)[None]
        np.testing.assert_array_equal(made["neighbours"].numpy(), grid.index[tuple(np.moveaxis(ijk, -1, 0))])
        assert (made["neighbours"].numpy() >= grid.n_interior).any()  # ring rows among them
    else:
        assert np.array_equal(made["patches"].numpy(), grid.interior_patches((stencil.PATCH_I, stencil.PATCH_J)))
        assert np.array_equal(made["step_patches"].numpy(), grid.interior_patches(stencil.STEP_PATCH))
    labels = wp.array(grid.labels, dtype=wp.int8, device=device)
    for patch, max_length in (((1, 1), 1), ((3, 2), 7), ((2, 5), 10**6)):
        assert np.array_equal(device_patches(labels, patch, max_length).numpy(),
                              grid.interior_patches(patch, max_length)), (patch, max_length)
    empty = wp.zeros((6, 6, 6), dtype=wp.int8, device=device)
    assert device_patches(empty, (2, 2)).shape == (0,)
    for patch, max_length in (((0, 2), 4), ((2, 2), 0)):
        with pytest.raises(ValueError, match="must be positive"):
            device_patches(labels, patch, max_length)


def test_interior_patches_reject_empty_shapes(arm_cage, device):
    grid = ws.voxelize(arm_cage, 16, device=device)
    with pytest.raises(ValueError, match="must be positive"):
        grid.interior_patches((0, 2))


def test_lattice_numbering_orders_rows_by_class_then_lattice_order(device):
    """The device numbering against numpy's: rows by class (0 to 3), then in C order of the lattice; -1 not numbered."""
    import warp as wp
    from warp_stokes.geometry.grid import lattice_counts, lattice_rows

    classes = np.random.default_rng(5).integers(-1, 4, size=(7, 5, 9)).astype(np.int8)
    on_device = wp.array(classes, dtype=wp.int8, device=device)
    counts, per_class = lattice_counts(on_device)
    assert per_class.tolist() == [int((classes == c).sum()) for c in range(4)]
    index, ijk = lattice_rows(on_device, counts, int(per_class.sum()))
    order = np.concatenate([np.flatnonzero(classes.ravel() == c) for c in range(4)])
    expected = np.full(classes.size, -1)
    expected[order] = np.arange(len(order))
    np.testing.assert_array_equal(index.numpy().ravel(), expected)
    np.testing.assert_array_equal(ijk.numpy(), np.stack(np.unravel_index(order, classes.shape), axis=1))


def test_a_grid_travels_with_its_host_arrays(arm_cage, device):
    """Pickled (Ray, multiprocessing) or copied, a grid keeps its row index and rebuilds its device arrays where it is
    used; a Grid made by hand without an index says so."""
    import copy
    import pickle

    grid = ws.voxelize(arm_cage, 16, device=device)
    for twin in (pickle.loads(pickle.dumps(grid)), copy.deepcopy(grid)):
        np.testing.assert_array_equal(twin.index, grid.index)
        np.testing.assert_array_equal(twin.device_arrays(device)["index"].numpy(), grid.index)
        assert twin.n_inside == grid.n_inside and twin.boundary == grid.boundary
    bare = ws.Grid(centre=grid.centre, origin=grid.origin, spacing=grid.spacing, resolution=16, labels=grid.labels,
                   active_ijk=grid.active_ijk, n_interior=grid.n_interior, n_ring=grid.n_ring, n_band=grid.n_band)
    with pytest.raises(ws.ResolutionError, match="no row index"):
        bare.index


def _synthetic_cages():
    import shapes

    made = [shapes.box_pair(extents=(2.0, 1.0, 0.5), rotation=np.eye(3)), shapes.box_pair(rotation=None),
            shapes.slab_pair(thickness=0.05, seed=1), shapes.star_pair(seed=3), shapes.ellipsoid_pair(noise=0.3)]
    return {p.name: ws.check_cage((p.cage_vertices, p.cage_faces)) for p in made}


@pytest.mark.parametrize("resolution", [9, 16, 31])
def test_the_cpus_inside_test_by_even_nodes_gives_every_nodes_labels(resolution, arm_cage):
    # On a CPU the nodes of even coordinates take winding numbers first; the others take their even neighbours'
    # label where those agree and no cage point is near, else their own winding number: the same labels as a winding
    # number at every node, on cages with nodes on their faces (an axis-aligned box), thin slabs, stars, odd and even
    # numbers of nodes a side
    from warp_stokes.geometry.grid import MARGIN, classify_grid_nodes
    from warp_stokes.geometry.inside import WINDING_ACCURACY, cage_mesh
    from warp_stokes.kernels import voxel

    cages = {"arm": arm_cage, **_synthetic_cages()}
    for name, cage in cages.items():
        lo, hi = cage.vertices.min(axis=0), cage.vertices.max(axis=0)
        spacing = float((hi - lo).max() / resolution)
        counts = np.ceil((hi - lo) / spacing - 1e-9).astype(int) + 1 + 2 * MARGIN
        origin = -0.5 * spacing * (counts - 1)
        mesh = cage_mesh(cage, 0.5 * (lo + hi), "cpu")
        got = classify_grid_nodes(mesh, tuple(counts), origin, spacing, ws.Backend.of("cpu", 2)).numpy()
        every = wp.empty(tuple(counts), dtype=wp.int8, device="cpu")
        wp.launch(voxel.classify_nodes, dim=tuple(counts), device="cpu", outputs=[every],
                  inputs=[mesh.id, wp.vec3(*origin.astype(np.float32)), spacing, WINDING_ACCURACY, 1e-5 * spacing,
                          0, 1])
        expected = every.numpy()
        assert (expected == L.INTERIOR).any() and (expected == L.OUTSIDE).any(), name
        np.testing.assert_array_equal(got, expected, err_msg=name)
