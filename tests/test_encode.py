"""Encoding mesh sequences as cage poses: known poses recovered, the smoothness term against a direct solve, and the
command as a user runs it."""

import warnings

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, cli, float32_rounding, warp_stokes, write_obj
from warp_stokes.binding.encode import encode_poses
from warp_stokes.io.frames import load_mesh_frames


@pytest.fixture(scope="module")
def arm(device):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=16, device=device)


def known_poses(binding, n=4, seed=0):
    rng = np.random.default_rng(seed)
    scale = 0.02 * np.linalg.norm(np.ptp(binding.cage_vertices, axis=0))
    return binding.cage_vertices + scale * rng.normal(size=(n, *binding.cage_vertices.shape))


def test_frames_made_by_the_binding_give_back_their_poses(arm):
    poses = known_poses(arm)
    frames = ws.Poses(arm.deform(poses).astype(np.float64), np.array([3.0, 4, 5, 9]), "made")
    encoded, rms = encode_poses(arm, frames)
    diagonal = np.linalg.norm(np.ptp(arm.cage_vertices, axis=0))
    assert np.abs(encoded.positions - poses).max() <= 1e-5 * diagonal
    # the frames are float32 deformations: the fit's residual is their rounding, relative to the diagonal
    assert rms.max() <= float32_rounding(np.abs(frames.positions).max() / diagonal)
    assert encoded.frames.tolist() == [3, 4, 5, 9]


def test_smoothness_is_the_regularised_least_squares_solution(arm):
    poses = known_poses(arm, n=5, seed=1)
    noisy = arm.deform(poses).astype(np.float64)
    noisy += np.random.default_rng(2).normal(scale=0.3, size=noisy.shape)
    frames = ws.Poses(noisy, np.arange(1.0, 6.0), "noisy")
    smooth = 50.0
    encoded, rms = encode_poses(arm, frames, smoothness=smooth)
    # the same normal equations assembled whole and solved directly, one coordinate at a time
    w = arm.weights.astype(np.float64)
    n, handles = len(poses), arm.n_handles
    steps = np.diff(np.eye(n), axis=0)
    system = np.kron(np.eye(n), w.T @ w) + smooth * np.kron(steps.T @ steps, np.eye(handles))
    for axis in range(3):
        rhs = np.concatenate([w.T @ noisy[f, :, axis] for f in range(n)])
        direct = np.linalg.solve(system, rhs).reshape(n, handles)
        np.testing.assert_allclose(encoded.positions[..., axis], direct, atol=1e-8 * np.abs(direct).max())
    plain, plain_rms = encode_poses(arm, frames)
    jitter = lambda p: np.sum(np.diff(p, axis=0) ** 2)  # noqa: E731
    assert jitter(encoded.positions) < jitter(plain.positions) and rms.mean() >= plain_rms.mean()


def test_encode_command(arm, tmp_path):
    binding = tmp_path / "arm.npz"
    arm.save(binding)
    poses = known_poses(arm, n=3, seed=3)
    folder = tmp_path / "capture"
    folder.mkdir()
    for k, frame in enumerate(arm.deform(poses)):
        write_obj(folder / f"frame_{k + 10}.obj", frame, arm.mesh_faces)
    run = ["encode", binding, folder]
    result = warp_stokes(*run, "-o", tmp_path / "poses.npy")  # as a user runs it: the installed command
    assert result.returncode == 0, result.stderr
    assert "3 cage poses" in result.stdout
    diagonal = np.linalg.norm(np.ptp(arm.cage_vertices, axis=0))
    assert np.abs(np.load(tmp_path / "poses.npy") - poses).max() <= 1e-4 * diagonal  # OBJ text: 6 digits
    result = cli(*run, "-o", tmp_path / "poses.usda", "--smooth", "0.1")  # then in process
    assert result.returncode == 0, result.stderr
    back = ws.load_poses(tmp_path / "poses.usda", arm.cage_faces, arm.n_handles)  # what animate reads
    assert back.frames.tolist() == [10.0, 11.0, 12.0] and back.positions.shape == poses.shape
    write_obj(folder / "frame_99.obj", np.vstack([arm.mesh_vertices, [[0.0, 0.0, 0.0]]]), arm.mesh_faces)
    result = cli(*run, "-o", tmp_path / "bad.npy")
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert "frame_99.obj: the frame has 2090 vertices, the bound mesh 2089" in result.stderr
    assert not (tmp_path / "bad.npy").exists()


def test_frames_from_arrays_and_usd(arm, tmp_path):
    from pxr import Usd, UsdGeom, Vt

    frames = arm.deform(known_poses(arm, n=2)).astype(np.float64)
    np.save(tmp_path / "f.npy", frames)
    assert load_mesh_frames(tmp_path / "f.npy", arm.mesh_faces, arm.n_vertices).positions.shape == frames.shape
    stage = Usd.Stage.CreateNew(str(tmp_path / "f.usda"))
    mesh = UsdGeom.Mesh.Define(stage, "/Capture")
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(arm.mesh_faces)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(arm.mesh_faces.astype(np.int32).ravel()))
    for t, frame in zip((7.0, 8.0), frames):
        mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(frame.astype(np.float32)), t)
    stage.GetRootLayer().Save()
    loaded = load_mesh_frames(tmp_path / "f.usda", arm.mesh_faces, arm.n_vertices)
    assert loaded.frames.tolist() == [7.0, 8.0]
    np.testing.assert_allclose(loaded.positions, frames, rtol=0,  # USD points are float32: one rounding
                               atol=float32_rounding(np.abs(frames).max(), 1))
    with pytest.raises(ws.BindingError, match=r"f.npy: frames must have shape \(frames, 58, 3\)"):
        load_mesh_frames(tmp_path / "f.npy", arm.mesh_faces, 58)


def test_device_products_equal_the_host_ones(arm, device, monkeypatch):
    """W^T W and W^T P summed by the Warp kernels (blocks of vertices, float64 atomics; frames in batches) against
    numpy's float64 products, with more frames than a batch and far from the origin."""
    from warp_stokes.binding import encode

    frames = arm.deform(known_poses(arm, n=7, seed=4)).astype(np.float64) + 500.0
    monkeypatch.setattr(encode, "FRAME_BYTES", 3 * 24 * arm.n_vertices)  # batches of 3 frames: 3 + 3 + 1
    gram, projected = encode.normal_equations(arm.weights, frames, device=device, kernels=True)
    w = arm.weights.astype(np.float64)
    np.testing.assert_allclose(gram, w.T @ w, rtol=1e-10, atol=1e-10 * np.abs(w.T @ w).max())
    reference = np.einsum("vl,fvd->lfd", w, frames)
    assert np.abs(projected - reference).max() <= 1e-6 * np.abs(reference).max()
    host = encode.normal_equations(arm.weights, frames, device="cpu", kernels=False)
    np.testing.assert_allclose(host[0], w.T @ w, rtol=1e-12)
