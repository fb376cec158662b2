"""warp-stokes show: the pictures as a user makes them (the command, its PNG decoded and checked), and
the numbers behind them checked against what holds independently of the drawing: partition of unity and linear
precision of the slices of all handles, the binding's own weights at vertices on the plane, mean value coordinates
at the pixel centres, and the conformal distortion of the deformation."""

import warnings

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, box_cage, cli, warp_stokes, write_obj
from warp_stokes.binding import pipeline
from warp_stokes.quality import conformal_distortion
from warp_stokes.show import cage_edges, cross_section, mesh_colours, view_frame, weight_slice

imread = pytest.importorskip("matplotlib.image").imread


def show(*args):
    """`warp-stokes show` in process (``main(argv)``, its output captured); the first test runs it as a subprocess."""
    return cli("show", *args)


def assert_drawn(path):
    """A real PNG with a picture on it: many colours, and far from all white."""
    rgb = imread(path)[..., :3]
    colours = np.unique(np.round(rgb.reshape(-1, 3) * 255).astype(int), axis=0)
    assert len(colours) > 50, len(colours)
    assert (rgb.min(axis=-1) < 0.9).mean() > 0.05  # more than the frame and the text is drawn
    return rgb


def pixel_centres(s):
    """The world positions (rows, columns, 3) of a slice's pixel centres, from its extent and shape alone."""
    rows, columns = s.image.shape
    e = s.extent
    u = e[0] + (np.arange(columns) + 0.5) * (e[1] - e[0]) / columns
    v = e[2] + (np.arange(rows) + 0.5) * (e[3] - e[2]) / rows
    points = np.empty((rows, columns, 3))
    points[..., 3 - sum(s.plane_axes)] = s.position
    points[..., s.plane_axes[0]] = u[None, :]
    points[..., s.plane_axes[1]] = v[:, None]
    return points


@pytest.fixture(scope="module")
def arm(arm_npz):
    """The bundled arm bound at resolution 16 on the CPU (the session's binding file, read only), and its file."""
    return arm_npz, ws.load_binding(arm_npz, device="cpu")


def test_the_weight_slice_command_draws_the_same_picture_every_time(arm, tmp_path):
    path, binding = arm
    first, second = tmp_path / "weights.png", tmp_path / "again.png"
    # the command as a user runs it (a subprocess of the installed command), then again in this process
    result = warp_stokes("show", path, "--handle", 5, "--slice", "y=0.5", "-o", first, "--device", "cpu")
    assert result.returncode == 0, result.stderr
    assert show(path, "--handle", 5, "--slice", "y=0.5", "-o", second, "--device", "cpu").returncode == 0
    assert first.read_bytes() == second.read_bytes()  # deterministic, to the byte
    rgb = assert_drawn(first)
    assert rgb.shape[:2] == (520, 640)
    # what the command reports is the slice: its range and its count of nodes inside the cage
    s = weight_slice(binding, 5, "y", 0.5, device="cpu")
    inside = s.image[~np.isnan(s.image)]
    assert f"weights {inside.min():.6g} to {inside.max():.6g} at {inside.size} nodes inside the cage" in result.stdout
    assert "(stokes)" in result.stdout and inside.min() < 0 < inside.max()  # a negative lobe, drawn blue


def test_a_slice_agrees_with_the_bound_weights_at_vertices_on_its_plane(arm):
    """Vertices within a tenth of a cell of the plane: the slice's nodes interpolated bilinearly there give the
    binding's (Hermite-sampled) weights to 0.02 at resolution 16."""
    _, binding = arm
    s = weight_slice(binding, 5, "z", 0.3, device="cpu")
    rows, columns = s.image.shape
    h = (s.extent[1] - s.extent[0]) / columns
    assert h == pytest.approx((s.extent[3] - s.extent[2]) / rows)  # square pixels, one per node
    p = binding.mesh_vertices[np.abs(binding.mesh_vertices[:, 2] - s.position) < 0.1 * h]
    x = (p[:, 0] - s.extent[0]) / h - 0.5
    y = (p[:, 1] - s.extent[2]) / h - 0.5
    i, j = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - i, y - j
    im = s.image
    value = (im[j, i] * (1 - fx) * (1 - fy) + im[j, i + 1] * fx * (1 - fy) + im[j + 1, i] * (1 - fx) * fy
             + im[j + 1, i + 1] * fx * fy)
    bound = binding.weights[np.abs(binding.mesh_vertices[:, 2] - s.position) < 0.1 * h, 5]
    known = ~np.isnan(value)
    assert known.sum() >= 5 and bound[known].max() > 0.1
    assert np.abs(value[known] - bound[known]).max() < 0.02
    # the same node seen from a slice across another axis has the same value: one lattice, one solve
    node = np.argwhere(~np.isnan(im))[0]
    centre = pixel_centres(s)[tuple(node)]
    lo, hi = binding.cage_vertices.min(axis=0), binding.cage_vertices.max(axis=0)
    across = weight_slice(binding, 5, "x", (centre[0] - lo[0]) / (hi[0] - lo[0]), device="cpu")
    k = np.unravel_index(np.argmin(np.linalg.norm(pixel_centres(across) - centre, axis=-1)), across.image.shape)
    assert np.linalg.norm(pixel_centres(across)[k] - centre) < 1e-6 * h
    assert across.image[k] == im[tuple(node)]


harmonic = pytest.mark.skipif("harmonic" not in getattr(pipeline, "METHODS", {}),
                              reason="bind(method='harmonic') is not there yet")


@pytest.mark.parametrize("method, axes", [("stokes", "xyz"), pytest.param("harmonic", "z", marks=harmonic)])
def test_the_slices_of_all_handles_are_partition_of_unity_and_reproduce_positions(method, axes):
    """On a box cage (8 handles) at resolution 16: at every node inside the cage the handles' slices sum to 1 and
    reproduce the node's position (the exactness of the discrete solution, 1e-5), which also checks that each
    pixel is where the image says it is."""
    cage, mesh = box_cage((-1.0, -0.6, -0.8), (1.3, 0.9, 0.7)), box_cage((-0.5, -0.3, -0.4), (0.6, 0.5, 0.3))
    binding = ws.bind(mesh, cage, resolution=16, device="cpu", **({} if method == "stokes" else {"method": method}))
    diagonal = np.linalg.norm(np.ptp(binding.cage_vertices, axis=0))
    for axis in axes:
        slices = [weight_slice(binding, handle, axis, 0.37, device="cpu") for handle in range(8)]
        assert {s.method for s in slices} == {method} and {s.resolution for s in slices} == {16}
        stack = np.stack([s.image for s in slices])
        inside = ~np.isnan(stack[0])
        assert inside.sum() > 50 and (np.isnan(stack) == ~inside).all()
        assert np.abs(stack[:, inside].sum(axis=0) - 1).max() < 1e-5
        positions = np.einsum("lrc,ld->rcd", np.nan_to_num(stack), binding.cage_vertices)
        assert np.abs(positions[inside] - pixel_centres(slices[0])[inside]).max() < 1e-5 * diagonal
        a = "xyz".index(axis)
        assert abs(slices[0].position - (-1.0, -0.6, -0.8)[a] - 0.37 * (2.3, 1.5, 1.5)[a]) <= 0.5 * 2.3 / 16 + 1e-12
        # the box's outline: a rectangle around the slice's inside
        outline = slices[0].outline.reshape(-1, 2)
        assert outline.min(axis=0) == pytest.approx(np.array((-1.0, -0.6, -0.8))[list(slices[0].plane_axes)])
        assert outline.max(axis=0) == pytest.approx(np.array((1.3, 0.9, 0.7))[list(slices[0].plane_axes)])
    if method == "harmonic":  # another equation than the Stokes one: other weights
        stokes = ws.bind(mesh, cage, resolution=16, device="cpu")
        assert np.nanmax(np.abs(weight_slice(stokes, 0, axis, 0.37, device="cpu").image - stack[0])) > 1e-3


def test_mean_value_slices_are_the_coordinates_at_the_pixel_centres(arm, tmp_path):
    path, _ = arm
    binding = ws.load_binding(path, device="cpu")
    binding.settings["method"] = "mvc"  # the weights are not read: a slice of MVC needs the cage alone
    s = weight_slice(binding, 7, "x", 0.3, device="cpu", pixels=64)
    assert s.resolution is None and max(s.image.shape) == 64
    lo, hi = binding.cage_vertices.min(axis=0), binding.cage_vertices.max(axis=0)
    assert s.extent == pytest.approx((lo[1], hi[1], lo[2], hi[2]))
    assert s.position == pytest.approx(lo[0] + 0.3 * (hi[0] - lo[0]))
    points = pixel_centres(s).reshape(-1, 3)
    with warnings.catch_warnings():  # the arm's cage folds back at 4 edges: a note shown when it was bound
        warnings.simplefilter("ignore")
        cage = ws.check_cage((binding.cage_vertices, binding.cage_faces))
    inside, _ = ws.classify_points(cage, points, device="cpu")
    assert (np.isnan(s.image.ravel()) == ~inside).all() and inside.sum() > 100
    expected = ws.mean_value_coordinates(cage, points[inside], device="cpu")[:, 7]
    assert np.abs(s.image.ravel()[inside] - expected).max() < 1e-12
    # the command, on a binding that says it is MVC
    binding.save(tmp_path / "mvc.npz")
    result = show(tmp_path / "mvc.npz", "--handle", 7, "--slice", "x=0.3", "-o", tmp_path / "mvc.png", "--device",
                  "cpu")
    assert result.returncode == 0, result.stderr
    assert "(mvc)" in result.stdout and "pixels inside the cage" in result.stdout
    assert_drawn(tmp_path / "mvc.png")


def test_the_deformed_mesh_is_coloured_by_its_conformal_distortion(arm, tmp_path):
    path, binding = arm
    pose = np.load(EXAMPLE / "bend_poses.npy")[-1]
    np.save(tmp_path / "bent.npy", pose)
    first, second = tmp_path / "deformed.png", tmp_path / "again.png"
    result = show(path, "--pose", tmp_path / "bent.npy", "-o", first)
    assert result.returncode == 0, result.stderr
    assert show(path, "--pose", tmp_path / "bent.npy", "-o", second).returncode == 0
    assert first.read_bytes() == second.read_bytes()
    front = assert_drawn(first)
    # the colour bar runs from 1 (conformal) to the distortion's 99th percentile; the largest is printed too
    distortion = conformal_distortion(binding.mesh_faces, binding.mesh_vertices, binding.deform(pose))
    assert np.isfinite(distortion).all() and distortion.max() > 1.5
    assert f"{len(distortion)} triangles" in result.stdout
    assert (f"coloured from 1 to {np.percentile(distortion, 99):.6g} (the 99th percentile; the largest "
            f"{distortion.max():.6g})") in result.stdout
    assert show(path, "--pose", tmp_path / "bent.npy", "--view", "side", "-o", tmp_path / "side.png").returncode == 0
    side = assert_drawn(tmp_path / "side.png")
    assert side.shape == front.shape and not np.array_equal(side, front)


def test_the_encoding_error_map_colours_by_the_distance_to_a_reference(arm, tmp_path):
    path, binding = arm
    pose = np.load(EXAMPLE / "bend_poses.npy")[-1]
    np.save(tmp_path / "bent.npy", pose)
    deformed = np.asarray(binding.deform(pose), dtype=np.float64)
    diagonal = np.linalg.norm(np.ptp(binding.cage_vertices, axis=0))
    shift = np.zeros(len(deformed))
    shift[: len(deformed) // 2] = 0.01 * diagonal  # half the vertices moved by 1% of the diagonal along x
    write_obj(tmp_path / "reference.obj", deformed + shift[:, None] * [1, 0, 0], binding.mesh_faces)
    result = show(path, "--pose", tmp_path / "bent.npy", "--error", tmp_path / "reference.obj", "-o",
                  tmp_path / "error.png")
    assert result.returncode == 0, result.stderr
    assert_drawn(tmp_path / "error.png")
    assert ("distance to reference.obj / cage diagonal coloured from 0 to 0.01 (the 99th percentile; the largest 0.01)"
            in result.stdout)
    colours = mesh_colours(binding, pose, tmp_path / "reference.obj")
    expected = shift[binding.mesh_faces].mean(axis=1) / diagonal
    assert np.abs(colours.values - expected).max() < 1e-9
    # another vertex count: the distance to the reference's closest point, at most the corresponding vertex's
    write_obj(tmp_path / "extra.obj", np.vstack([deformed + shift[:, None] * [1, 0, 0], [[0, 0, 0]]]),
              binding.mesh_faces)
    closest = mesh_colours(binding, pose, tmp_path / "extra.obj").values
    assert (closest <= expected + 1e-9).all() and closest.max() > 0.002


def test_the_cage_is_drawn_over_the_mesh_posed_with_it(arm, tmp_path):
    """`--with-cage`: the cage's edges (each once: 3/2 of its faces), on the viewer's side those of a face facing
    the viewer, posed with the mesh; alone, the rest mesh in its cage, in plain grey without a colour bar."""
    path, binding = arm
    frame = view_frame("front")
    segments, front = cage_edges(binding, frame=frame)
    assert len(segments) == 3 * len(binding.cage_faces) // 2 and 0 < front.sum() < len(front)
    # the ends are the cage's vertices seen in the view, every vertex at some edge
    ends = segments.reshape(-1, 3)
    np.testing.assert_allclose(np.unique(ends, axis=0), np.unique(binding.cage_vertices @ frame.T, axis=0))
    # posed: the same edges, moved with the pose (a file of it too); seen from behind, the front and back swap
    pose = np.load(EXAMPLE / "bend_poses.npy")[-1]
    moved, _ = cage_edges(binding, pose, frame)
    keys = np.unique(np.sort(binding.cage_faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    np.testing.assert_allclose(moved, (pose @ frame.T)[keys], atol=1e-9)
    write_obj(tmp_path / "bent_cage.obj", pose, binding.cage_faces)
    np.testing.assert_allclose(cage_edges(binding, tmp_path / "bent_cage.obj", frame)[0], moved, atol=1e-5)
    _, behind = cage_edges(binding, frame=np.diag([-1.0, 1.0, -1.0]) @ frame)
    assert (behind != front).mean() > 0.5
    result = show(path, "--with-cage", "-o", tmp_path / "cage.png")
    assert result.returncode == 0, result.stderr
    assert f"{len(binding.mesh_faces)} triangles and the cage's {len(segments)} edges" in result.stdout
    plain = assert_drawn(tmp_path / "cage.png")
    assert show(path, "--pose", tmp_path / "bent_cage.obj", "--with-cage", "-o", tmp_path / "posed.png",
                "--view", "side").returncode == 0
    posed = assert_drawn(tmp_path / "posed.png")
    bare = show(path, "--pose", tmp_path / "bent_cage.obj", "--view", "side", "-o", tmp_path / "bare.png")
    assert bare.returncode == 0 and not np.array_equal(assert_drawn(tmp_path / "bare.png"), posed)
    # the plain picture has no colour bar: its colours are the greys of the shading and the cage's blue
    rgb = np.round(plain.reshape(-1, 3) * 255).astype(int)
    saturated = np.ptp(rgb, axis=1) > 60
    assert saturated.mean() < 0.05


def test_bad_input_is_one_line_and_no_picture(arm, tmp_path):
    path, binding = arm
    out = tmp_path / "out.png"
    cases = [
        (["--handle", binding.n_handles], "the binding has handles 0 to 57"),
        (["--handle", -1], "must be an integer >= 0"),
        (["--handle", 1, "--slice", "w=0.5"], "is not AXIS=FRACTION"),
        (["--handle", 1, "--slice", "z=1.5"], "is not AXIS=FRACTION"),
        (["--handle", 1, "--slice", "z"], "is not AXIS=FRACTION"),
        (["--handle", 1, "--pose", EXAMPLE / "arm_cage.obj"], "not both or neither"),
        ([], "not both or neither"),
        (["--slice", "z=0.5", "--pose", EXAMPLE / "arm_cage.obj"], "--slice goes with --handle"),
        (["--handle", 1, "--view", "top"], "--view goes with --pose"),
        (["--handle", 1, "--with-cage"], "not both or neither"),
    ]
    for arguments, message in cases:
        result = show(path, *arguments, "-o", out)
        assert result.returncode == 2 and result.stderr.count("\n") == 1 and message in result.stderr, (arguments,
                                                                                                        result.stderr)
    result = show(path, "--handle", 1, "-o", tmp_path / "out.jpg")
    assert result.returncode == 2 and "the picture is written as .png" in result.stderr
    result = show(tmp_path / "missing.npz", "--handle", 1, "-o", out)
    assert result.returncode == 2 and result.stderr.count("\n") == 1 and "missing.npz" in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written, no temporary left


def test_views_and_cross_sections():
    assert view_frame("front").tolist() == np.eye(3).tolist()
    assert view_frame("top", "Z").astype(int).tolist() == np.eye(3, dtype=int).tolist()  # Z-up seen from above
    assert view_frame("side", "Z").astype(int).tolist() == [[0, 1, 0], [0, 0, 1], [1, 0, 0]]
    for view in ("front", "side", "top"):  # right-handed: right x up = towards the viewer
        frame = view_frame(view)
        assert np.allclose(np.cross(frame[0], frame[1]), frame[2])
    with pytest.raises(ws.WarpStokesError, match="view must be one of"):
        view_frame("back")
    vertices, faces = box_cage()
    segments = cross_section(vertices, faces, 2, 0.25)  # a square of side 2 at z = 0.25
    assert len(segments) == 8 and np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1).sum() == pytest.approx(8)
    assert len(cross_section(vertices, faces, 0, 1.5)) == 0


def test_a_slice_is_solved_with_the_bindings_own_boundary_data(arm, tmp_path):
    """A binding made with other local-data parameters is sliced with them (they are recorded), not the default's."""
    _, default = arm
    custom = ws.LocalData(model="least-norm", fold_radius=0)
    path = tmp_path / "custom.npz"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=16, device="cpu", boundary=custom).save(path)
    binding = ws.load_binding(path, device="cpu")
    assert ws.LocalData(**binding.settings["boundary_settings"]) == custom
    mine = weight_slice(binding, 19, "z", 0.3, device="cpu").image
    theirs = weight_slice(default, 19, "z", 0.3, device="cpu").image
    inside = ~np.isnan(mine)
    assert inside.any() and np.abs(mine[inside] - theirs[inside]).max() > 1e-3


def test_a_slice_draws_the_nodes_cut_off_by_a_thin_wedge():
    """Nodes inside the cage that a thin wedge cuts off hold known data: the slice draws them with it, not as outside."""
    from conftest import slit_cage
    from warp_stokes.kernels import labels as L

    cage, rotation, _ = slit_cage()
    points = np.random.default_rng(0).uniform(-0.5, 0.5, size=(50, 3)) @ rotation.T
    binding = ws.bind((points, None), cage, resolution=24, device="cpu")
    grid = ws.voxelize(cage, 24, device="cpu")
    assert grid.n_cut_off > 0
    cut_off = np.zeros(grid.shape, dtype=bool)
    cut_off[tuple(grid.active_ijk[grid.n_interior: grid.n_inside].T)] = True
    k = int(np.argmax(np.bincount(grid.active_ijk[grid.n_interior: grid.n_inside, 2])))  # the z plane with most
    lo, hi = cage.vertices.min(0)[2], cage.vertices.max(0)[2]
    position = grid.centre[2] + grid.origin[2] + grid.spacing * k
    s = weight_slice(binding, 0, "z", (position - lo) / (hi - lo), device="cpu")
    assert np.isclose(s.position, position)
    inside = (grid.labels[:, :, k] == L.INTERIOR) | cut_off[:, :, k]
    assert np.isfinite(s.image).sum() == inside.sum() and cut_off[:, :, k].sum() > 0


def test_the_colour_scale_is_symmetric_and_the_slice_shows_the_mesh_and_the_handle(arm, tmp_path):
    """Pale blue means as small as pale red (a scale stretched 100x on its negative half said otherwise), and the
    picture carries the mesh's cross-section and where the handle is."""
    from warp_stokes.show import show_weights, symmetric_scale

    path, binding = arm
    s = weight_slice(binding, 19, "z", 0.3, device="cpu")
    low, high = symmetric_scale(s.image)
    assert low == -high == -np.nanmax(np.abs(s.image)) and np.nanmin(s.image) < 0.01 * high  # a tiny negative lobe
    assert symmetric_scale(np.full((2, 2), np.nan)) == (-1.0, 1.0)
    # the mesh's outline: points on the mesh's surface on the plane, inside the cage's outline's box
    assert len(s.mesh_outline) > 10
    assert np.allclose(s.mesh_outline.reshape(-1, 2).min(axis=0) >= s.outline.reshape(-1, 2).min(axis=0), True)
    corner = binding.cage_vertices[19]
    assert np.allclose(s.handle, [corner[0], corner[1], corner[2] - s.position])
    from warp_stokes.show import weights as show_module

    scales = []
    spy = lambda image: scales.append(symmetric_scale(image)) or scales[-1]  # noqa: E731
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(show_module, "symmetric_scale", spy)
        show_weights(binding, 19, tmp_path / "w.png", "z", 0.3, device="cpu")
    assert scales == [(low, high)]  # the picture's scale is this one
    assert_drawn(tmp_path / "w.png")
    help_text = show("--help").stdout
    assert "handles count from 0" in help_text


def test_a_few_extreme_triangles_do_not_paint_the_rest_one_colour(arm, tmp_path):
    """One vertex of the reference far away: its few triangles' values are huge; the colour scale ends at the 99th
    percentile (the rest keep their colours) and the largest value is reported beside it."""
    from warp_stokes.show import show_mesh

    path, binding = arm
    reference = np.asarray(binding.mesh_vertices, dtype=np.float64).copy()
    reference[0] += 1000.0 * np.linalg.norm(np.ptp(binding.cage_vertices, axis=0))
    write_obj(tmp_path / "far.obj", reference, binding.mesh_faces)
    drawn = show_mesh(binding, tmp_path / "far.png", reference=tmp_path / "far.obj")
    low, high = drawn["range"]
    assert low == 0.0 and high < 1.0 < 300.0 < drawn["max"]
    assert (drawn["values"] > high).sum() <= 0.01 * len(drawn["values"]) + 1
