"""In-betweening of key cage poses: the function against independent references, and `animate --key-frames /
--inbetween / --interpolation` as a user runs it, read back with pxr."""

import warnings

import numpy as np
import pytest
from pxr import Usd, UsdGeom

import warp_stokes as ws
from conftest import EXAMPLE, REPO, cli
from warp_stokes.cli import main


def random_keys(n_keys=5, n_handles=4, seed=0):
    return np.random.default_rng(seed).normal(size=(n_keys, n_handles, 3))


def natural_spline_reference(keys, values, t):
    """The natural cubic spline through (keys, values) at t, by a dense solve for each interval's four polynomial
    coefficients in (t - key): through both end keys, C1 and C2 at the interior keys, zero second derivative at
    the first and last key. Independent of the tridiagonal second-derivative form the package solves."""
    n = len(keys) - 1
    h = np.diff(keys)
    rows, rhs = [], []

    def row(i, coefficients):
        r = np.zeros(4 * n)
        r[4 * i:4 * i + 4] = coefficients
        return r

    for i in range(n):  # through the interval's two keys
        rows += [row(i, [1, 0, 0, 0]), row(i, [1, h[i], h[i] ** 2, h[i] ** 3])]
        rhs += [values[i], values[i + 1]]
    for i in range(n - 1):  # first and second derivatives continuous at key i + 1
        rows.append(row(i, [0, 1, 2 * h[i], 3 * h[i] ** 2]) - row(i + 1, [0, 1, 0, 0]))
        rows.append(row(i, [0, 0, 2, 6 * h[i]]) - row(i + 1, [0, 0, 2, 0]))
        rhs += [np.zeros_like(values[0])] * 2
    rows += [row(0, [0, 0, 2, 0]), row(n - 1, [0, 0, 2, 6 * h[-1]])]  # natural ends
    rhs += [np.zeros_like(values[0])] * 2
    flat = np.stack(rhs).reshape(4 * n, -1)
    coefficients = np.linalg.solve(np.array(rows), flat).reshape(n, 4, -1)
    interval = np.clip(np.searchsorted(keys, t, side="right") - 1, 0, n - 1)
    s = (t - keys[interval])[:, None]
    c = coefficients[interval]
    return (c[:, 0] + s * (c[:, 1] + s * (c[:, 2] + s * c[:, 3]))).reshape((len(t),) + values.shape[1:])


# --- the function ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("interpolation", ["linear", "spline"])
@pytest.mark.parametrize("steps", [None, 0, 1, 7])
def test_keys_are_reproduced_exactly(interpolation, steps):
    keys = random_keys()
    frames = np.array([0.0, 3, 4.5, 11, 20])
    out = ws.inbetween(ws.Poses(keys, frames, "keys", 30.0), steps=steps, interpolation=interpolation)
    at_keys = np.searchsorted(out.frames, frames)
    np.testing.assert_array_equal(out.frames[at_keys], frames)
    np.testing.assert_array_equal(out.positions[at_keys], keys)
    assert np.all(np.diff(out.frames) > 0)
    assert out.time_codes_per_second == 30.0 and out.name == f"keys, in-between ({interpolation})"


def test_linear_midpoints_are_averages_and_steps_are_even():
    keys = random_keys(3)
    out = ws.inbetween(ws.Poses(keys, np.array([1.0, 2, 3]), "keys"), key_frames=[0, 10, 13], steps=1)
    np.testing.assert_allclose(out.frames, [0, 5, 10, 11.5, 13])
    np.testing.assert_allclose(out.positions[1], (keys[0] + keys[1]) / 2, atol=1e-14)
    np.testing.assert_allclose(out.positions[3], (keys[1] + keys[2]) / 2, atol=1e-14)
    out = ws.inbetween(ws.Poses(keys, np.array([0.0, 10, 13]), "keys"), steps=2)  # fractional time codes
    np.testing.assert_allclose(out.frames, [0, 10 / 3, 20 / 3, 10, 11, 12, 13])
    np.testing.assert_allclose(out.positions[2], keys[0] / 3 + 2 * keys[1] / 3, atol=1e-14)


def test_steps_zero_returns_the_keys():
    keys = random_keys()
    for interpolation in ("linear", "spline"):
        out = ws.inbetween(ws.Poses(keys, np.arange(5.0), "keys"), steps=0, interpolation=interpolation)
        np.testing.assert_array_equal(out.positions, keys)
        np.testing.assert_array_equal(out.frames, np.arange(5.0))


def test_every_integer_frame_and_the_non_integer_keys():
    keys = random_keys(3)
    out = ws.inbetween(ws.Poses(keys, np.arange(3.0), "keys"), key_frames=[0.5, 3, 7.25])
    np.testing.assert_array_equal(out.frames, [0.5, 1, 2, 3, 4, 5, 6, 7, 7.25])
    np.testing.assert_allclose(out.positions[1], keys[0] + (keys[1] - keys[0]) * 0.5 / 2.5, atol=1e-14)


@pytest.mark.parametrize("frames", [[0.0, 1, 2, 3, 4], [0.0, 0.5, 4, 4.75, 12], [-10.0, -2, 5, 100, 101]])
def test_spline_matches_a_dense_solve_of_the_natural_spline_conditions(frames):
    keys, frames = random_keys(), np.array(frames)
    out = ws.inbetween(ws.Poses(keys, frames, "keys"), steps=9, interpolation="spline")
    np.testing.assert_allclose(out.positions, natural_spline_reference(frames, keys, out.frames), atol=1e-10)


def test_spline_is_c2_with_natural_ends():
    """Measured on the output alone: finite differences of a fine sampling across the interior keys and at the ends."""
    keys, frames = random_keys(4), np.array([0.0, 1, 3.5, 4])
    steps = 2000  # the two-sided differences at a key straddle it: they see a jump in slope or curvature
    out = ws.inbetween(ws.Poses(keys, frames, "keys"), steps=steps, interpolation="spline")
    at_keys = np.searchsorted(out.frames, frames)
    p, t = out.positions, out.frames
    for k in at_keys[1:-1]:
        left = (p[k] - p[k - 1]) / (t[k] - t[k - 1])
        right = (p[k + 1] - p[k]) / (t[k + 1] - t[k])
        second_left = (p[k] - 2 * p[k - 1] + p[k - 2]) / (t[k] - t[k - 1]) ** 2
        second_right = (p[k + 2] - 2 * p[k + 1] + p[k]) / (t[k + 1] - t[k]) ** 2
        assert np.abs(left - right).max() < 1e-2  # O(step) apart, where a C0-only curve would differ by O(1)
        assert np.abs(second_left - second_right).max() < 5e-2
    scale = np.abs(natural_spline_reference(frames, keys, np.linspace(0, 4, 50))).max()
    for k, direction in ((0, 1), (len(t) - 1, -1)):  # zero curvature at the ends
        second = (p[k] - 2 * p[k + direction] + p[k + 2 * direction]) / (t[k + direction] - t[k]) ** 2
        assert np.abs(second).max() < 1e-1 * scale


def test_spline_reproduces_linear_motion_and_equals_linear_with_two_keys():
    rng = np.random.default_rng(1)
    start, velocity = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    frames = np.array([0.0, 2, 3, 9, 10.5])
    keys = start + frames[:, None, None] * velocity
    out = ws.inbetween(ws.Poses(keys, frames, "keys"), steps=5, interpolation="spline")
    np.testing.assert_allclose(out.positions, start + out.frames[:, None, None] * velocity, atol=1e-12)
    two = ws.Poses(random_keys(2), np.array([0.0, 7]), "keys")
    spline, linear = (ws.inbetween(two, interpolation=i) for i in ("spline", "linear"))
    np.testing.assert_allclose(spline.positions, linear.positions, atol=1e-14)


@pytest.mark.parametrize("n_keys, kwargs, message", [
    (1, {}, "at least 2 key poses, got 1"),
    (3, {"key_frames": [0, 10]}, "2 key frame numbers for 3 key poses"),
    (3, {"key_frames": [0, 10, 10]}, "strictly increasing"),
    (3, {"key_frames": [0, 12, 5]}, "strictly increasing"),
    (3, {"key_frames": [0, np.nan, 5]}, "finite"),
    (3, {"key_frames": [0, np.inf, 5]}, "finite"),
    (3, {"key_frames": ["a", "b", "c"]}, "must be numbers"),
    (3, {"steps": -1}, "integer >= 0, got -1"),
    (3, {"steps": 2.5}, "integer >= 0, got 2.5"),
    (3, {"steps": True}, "integer >= 0"),
    (3, {"interpolation": "cubic"}, "interpolation must be one of linear, spline, got 'cubic'"),
    (3, {"steps": 60_000}, "more than 100,000"),
    (3, {"key_frames": [0, 1, 1e9]}, "more than 100,000"),
])
def test_bad_arguments_are_one_line_errors(n_keys, kwargs, message):
    poses = ws.Poses(random_keys(n_keys), np.arange(float(n_keys)), "keys")
    with pytest.raises(ws.WarpStokesError) as info:
        ws.inbetween(poses, **kwargs)
    assert message in str(info.value) and "\n" not in str(info.value)


# --- as a user: animate ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def arm(tmp_path_factory):
    """The bundled arm bound once on the CPU, saved where the command reads it, and 3 key poses as a .npy."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=16, device="cpu")
    folder = tmp_path_factory.mktemp("inbetween")
    binding.save(folder / "arm.npz")
    keys = np.load(EXAMPLE / "bend_poses.npy")[[0, 11, 23]]
    np.save(folder / "keys.npy", keys)
    return binding, folder, keys


def mesh_points(path):
    """The written mesh's points per time code: {time: (V, 3)}."""
    stage = Usd.Stage.Open(str(path))  # held: its prims are invalid once it is gone
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh")).GetPointsAttr()
    return {t: np.asarray(points.Get(t), dtype=np.float64) for t in points.GetTimeSamples()}


def test_animate_with_key_frames_and_a_spline(arm, tmp_path):
    binding, folder, keys = arm
    out = tmp_path / "out.usda"
    proc = cli("animate", folder / "arm.npz", folder / "keys.npy", "-o", out, "--key-frames", "0,10,30",
               "--interpolation", "spline", "--device", "cpu", cwd=REPO)
    assert proc.returncode == 0, proc.stderr
    assert "31 frames (0 to 30)" in proc.stdout
    written = mesh_points(out)
    assert list(written) == [float(t) for t in range(31)]
    diagonal = np.linalg.norm(np.ptp(binding.mesh_vertices, axis=0))
    for key, t in zip(keys, (0, 10, 30)):
        np.testing.assert_allclose(written[t], binding.deform(key), atol=1e-5 * diagonal)
    between = ws.inbetween(ws.Poses(keys, np.array([0.0, 10, 30]), "keys"), interpolation="spline")
    for t in (4, 17):
        np.testing.assert_allclose(written[t], binding.deform(between.positions[t]), atol=1e-5 * diagonal)
    # a spline, not straight lines: frame 17 is off the linear in-between
    linear = ws.inbetween(ws.Poses(keys, np.array([0.0, 10, 30]), "keys"))
    assert np.abs(written[17] - binding.deform(linear.positions[17])).max() > 1e-3 * diagonal


def test_animate_with_inbetween_steps(arm, tmp_path, capsys):
    binding, folder, keys = arm
    out = tmp_path / "out.usd"
    rc = main(["animate", str(folder / "arm.npz"), str(folder / "keys.npy"), "-o", str(out), "--inbetween", "3",
               "--device", "cpu"])
    assert rc == 0 and "9 frames (1 to 3)" in capsys.readouterr().out  # a .npy's poses are frames 1, 2, 3
    written = mesh_points(out)
    assert list(written) == [1, 1.25, 1.5, 1.75, 2, 2.25, 2.5, 2.75, 3]
    diagonal = np.linalg.norm(np.ptp(binding.mesh_vertices, axis=0))
    np.testing.assert_allclose(written[2.5], binding.deform((keys[1] + keys[2]) / 2), atol=1e-5 * diagonal)
    np.testing.assert_allclose(written[3], binding.deform(keys[2]), atol=1e-5 * diagonal)


@pytest.mark.parametrize("args, message", [
    (["--key-frames", "0,10"], "--key-frames: 2 frame numbers for 3 poses"),
    (["--key-frames", "0,10,5"], "argument --key-frames: '0,10,5': the frame numbers must be strictly increasing"),
    (["--key-frames", "0,ten,30"], "argument --key-frames: '0,ten,30' is not a comma-separated list of numbers"),
    (["--key-frames", "0,nan,30"], "finite frame numbers"),
    (["--inbetween", "-1"], "argument --inbetween: must be an integer >= 0, got -1"),
    (["--inbetween", "1.5"], "argument --inbetween: '1.5' is not an integer"),
    (["--interpolation", "spline"], "--interpolation needs --key-frames or --inbetween"),
    (["--inbetween", "1", "--interpolation", "cubic"], "argument --interpolation: invalid choice"),
    (["--key-frames", "0,1,1000000"], "more than 100,000"),
])
def test_bad_key_frames_exit_2_with_one_line(arm, tmp_path, capsys, args, message):
    _, folder, _ = arm
    out = tmp_path / "out.usda"
    rc = main(["animate", str(folder / "arm.npz"), str(folder / "keys.npy"), "-o", str(out), "--device", "cpu"]
              + args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0], err
    assert not out.exists()
