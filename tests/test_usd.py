"""Animated USD export, read back with pxr, and cage poses in from OBJ frames, arrays and USD."""

import os
import warnings

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdValidation

import warp_stokes as ws
from conftest import EXAMPLE, float32_rounding, pair, write_obj
from warp_stokes.cli import main


@pytest.fixture(scope="module")
def arm(device):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=20, device=device)


def cage_poses(binding, n_frames=5):
    """Rest pose, then the cage bent about its centre by growing angles, scaled and moved."""
    rest = binding.cage_vertices
    centre = rest.mean(axis=0)
    out = []
    for k in range(n_frames):
        a = 0.15 * k
        rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        bend = np.where((rest[:, 1] > centre[1])[:, None], (rest - centre) @ rot.T + centre, rest)
        out.append(bend * (1 + 0.02 * k) + [0.5 * k, 0, 0])
    return np.stack(out)


def test_round_trip_points_topology_time_codes_and_extents(arm, tmp_path):
    positions = cage_poses(arm)
    frames = np.array([1001.0, 1002, 1003, 1005, 1008])
    path = ws.write_animation(tmp_path / "arm.usd", arm, ws.Poses(positions, frames, "generated"), fps=30)
    assert sorted(os.listdir(tmp_path)) == ["arm.usd"]  # no temporary left behind
    stage = Usd.Stage.Open(str(path))
    assert stage.GetStartTimeCode() == 1001 and stage.GetEndTimeCode() == 1008
    assert stage.GetTimeCodesPerSecond() == 30
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/Root"
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh"))
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [3] * len(arm.mesh_faces)
    np.testing.assert_array_equal(np.asarray(mesh.GetFaceVertexIndicesAttr().Get()), arm.mesh_faces.ravel())
    assert mesh.GetFaceVertexIndicesAttr().GetNumTimeSamples() == 0  # topology authored once
    assert mesh.GetPointsAttr().GetTimeSamples() == list(frames)
    expected = arm.deform(positions)
    for k, t in enumerate(frames):
        points = np.asarray(mesh.GetPointsAttr().Get(t))
        # float32 sums of 58 products W c' (~150 here), one call against another: 8 eps of their size
        np.testing.assert_allclose(points, expected[k], rtol=0,
                                   atol=float32_rounding((np.abs(arm.weights) @ np.abs(positions[k])).max()))
        lo, hi = np.asarray(mesh.GetExtentAttr().Get(t))
        np.testing.assert_array_equal(lo, points.min(0))  # the min and max of these same float32 points
        np.testing.assert_array_equal(hi, points.max(0))
    assert stage.GetPrimAtPath("/Root/Cage").IsValid() is False


def test_write_animation_takes_what_load_poses_reads(arm, tmp_path):
    """An array (frames 1, 2, ...), a single pose, or a file of poses, as users have them; a wrong shape is one error."""
    positions = cage_poses(arm, 3)
    np.save(tmp_path / "p.npy", positions)
    cases = ((positions, [1.0, 2.0, 3.0]), (positions[1], [1.0]), (tmp_path / "p.npy", [1.0, 2.0, 3.0]))
    for k, (poses, frames) in enumerate(cases):
        stage = Usd.Stage.Open(ws.write_animation(tmp_path / f"a{k}.usda", arm, poses))
        points = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh")).GetPointsAttr()
        assert points.GetTimeSamples() == frames
        last = positions[1] if len(frames) == 1 else positions[-1]
        # a batch of frames against one frame: float32 sums in another order
        np.testing.assert_allclose(np.asarray(points.Get(frames[-1])), arm.deform(last), rtol=0,
                                   atol=float32_rounding((np.abs(arm.weights) @ np.abs(last)).max()))
    with pytest.raises(ws.BindingError, match=r"poses must have shape \(frames, 58, 3\)"):
        ws.write_animation(tmp_path / "b.usda", arm, positions[:, :10])
    assert not (tmp_path / "b.usda").exists()


def test_stage_passes_all_registered_validators(arm, tmp_path):
    path = ws.write_animation(tmp_path / "arm.usda", arm, ws.Poses(cage_poses(arm, 3), np.arange(1.0, 4.0), "g"),
                              with_cage=True, with_weights=True)
    stage = Usd.Stage.Open(str(path))
    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    errors = [e for e in context.Validate(stage) if e.GetType() == UsdValidation.ValidationErrorType.Error]
    assert not errors, [e.GetMessage() for e in errors]


def test_cage_weights_and_text_format(arm, tmp_path):
    positions = cage_poses(arm, 3)
    path = ws.write_animation(tmp_path / "arm.usda", arm, ws.Poses(positions, np.arange(1.0, 4.0), "g"),
                              with_cage=True, with_weights=True, up_axis="Z", meters_per_unit=0.01)
    assert open(path).read(8) == "#usda 1."
    stage = Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    cage = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Cage"))
    # USD points are float32: one rounding (half an eps) of the float64 pose
    np.testing.assert_allclose(np.asarray(cage.GetPointsAttr().Get(2.0)), positions[1], rtol=0,
                               atol=float32_rounding(np.abs(positions[1]).max(), 1))
    primvar = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath("/Root/Mesh")).GetPrimvar("stokesWeights")
    assert primvar.GetInterpolation() == UsdGeom.Tokens.vertex and primvar.GetElementSize() == arm.n_handles
    np.testing.assert_array_equal(np.asarray(primvar.Get()).reshape(arm.weights.shape), arm.weights)


def test_poses_from_obj_frames_sorted_naturally(arm, tmp_path):
    positions = cage_poses(arm, 4)
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, number in enumerate([2, 10, 1, 33]):
        write_obj(folder / f"frame_{number}.obj", positions[k], arm.cage_faces)
    poses = ws.load_poses(folder, arm.cage_faces)
    np.testing.assert_array_equal(poses.frames, [1, 2, 10, 33])
    np.testing.assert_allclose(poses.positions, positions[[2, 0, 1, 3]], atol=1e-9)
    # a frame with another vertex count is named in the error
    write_obj(folder / "frame_40.obj", positions[0][:-1], arm.cage_faces[(arm.cage_faces < 57).all(1)])
    with pytest.raises(ws.BindingError, match="frame_40.obj: the pose has 57 vertices, the bound cage has 58"):
        ws.load_poses(folder, arm.cage_faces)
    os.unlink(folder / "frame_40.obj")
    faces = arm.cage_faces.copy()
    faces[[0, 1]] = faces[[1, 0]][:, [0, 2, 1]]
    write_obj(folder / "frame_41.obj", positions[0], faces)
    with pytest.raises(ws.BindingError, match="frame_41.obj: the pose's faces differ"):
        ws.load_poses(folder, arm.cage_faces)


def test_poses_from_arrays_and_usd(arm, tmp_path):
    positions = cage_poses(arm, 3)
    np.save(tmp_path / "p.npy", positions)
    np.testing.assert_array_equal(ws.load_poses(tmp_path / "p.npy", arm.cage_faces).positions, positions)
    np.savez(tmp_path / "p.npz", poses=positions, frames=[5, 6, 9])
    assert list(ws.load_poses(tmp_path / "p.npz", arm.cage_faces).frames) == [5, 6, 9]
    np.save(tmp_path / "bad.npy", positions[:, :-1])
    with pytest.raises(ws.BindingError, match=r"bad.npy: poses must have shape \(frames, 58, 3\)"):
        ws.load_poses(tmp_path / "bad.npy", arm.cage_faces)
    # a USD file whose cage has time-sampled points: the one written with --with-cage
    path = ws.write_animation(tmp_path / "anim.usdc", arm, ws.Poses(positions, np.array([3.0, 4, 8]), "g"),
                              with_cage=True)
    poses = ws.load_poses(path, arm.cage_faces, arm.n_handles)
    np.testing.assert_array_equal(poses.frames, [3, 4, 8])
    np.testing.assert_allclose(poses.positions, positions, rtol=0,  # float32 in USD: one rounding
                               atol=float32_rounding(np.abs(positions).max(), 1))
    with pytest.raises(ws.BindingError, match="no such file"):
        ws.load_poses(tmp_path / "missing.usd", arm.cage_faces)


def test_smpl_rest_to_t_pose(tmp_path, device):
    mesh_path, cage_path = pair("smpl")
    rest_cage = ws.load_surface(cage_path)
    t_cage = ws.load_surface(cage_path.parent / "cage_tpose.obj")
    t_mesh = ws.load_surface(mesh_path.parent / "model_tpose.obj")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = ws.bind(mesh_path, cage_path, resolution=32, device=device)
    steps = np.linspace(0, 1, 6)
    positions = np.stack([(1 - s) * rest_cage.vertices + s * t_cage.vertices for s in steps])
    path = ws.write_animation(tmp_path / "smpl.usd", b, ws.Poses(positions, np.arange(1.0, 7.0), "interp"))
    stage = Usd.Stage.Open(str(path))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh"))
    last = np.asarray(mesh.GetPointsAttr().Get(6.0), dtype=np.float64)
    diag = np.linalg.norm(t_mesh.vertices.max(0) - t_mesh.vertices.min(0))
    rms = np.sqrt(np.mean(np.sum((last - t_mesh.vertices) ** 2, axis=1))) / diag
    print(f"SMPL rest -> T-pose: RMS distance to the real T-pose mesh = {100 * rms:.2f}% of the diagonal")
    assert rms < 0.03, f"RMS {100 * rms:.2f}% of the diagonal"
    first = np.asarray(mesh.GetPointsAttr().Get(1.0))
    np.testing.assert_allclose(first, b.mesh_vertices, atol=1e-5 * diag)


def test_animate_command(arm, tmp_path, capsys, device):
    binding = tmp_path / "arm.npz"
    arm.save(binding)
    np.save(tmp_path / "poses.npy", cage_poses(arm, 4))
    out = tmp_path / "arm.usda"
    rc = main(["animate", str(binding), str(tmp_path / "poses.npy"), "-o", str(out), "--fps", "12",
               "--with-cage", "--device", device])
    assert rc == 0 and "4 frames" in capsys.readouterr().out
    stage = Usd.Stage.Open(str(out))
    assert stage.GetTimeCodesPerSecond() == 12 and stage.GetPrimAtPath("/Root/Cage").IsValid()
    rc = main(["animate", str(binding), str(tmp_path / "missing"), "-o", str(tmp_path / "x.usd")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "missing: no such file" in err[0]
    assert not (tmp_path / "x.usd").exists()


def test_normals_from_the_mesh_file_are_kept_and_follow_the_frames(tmp_path, device):
    import trimesh

    arm = ws.load_surface(EXAMPLE / "arm.obj")
    normals = trimesh.Trimesh(arm.vertices, arm.faces, process=False).vertex_normals
    path = tmp_path / "arm_normals.obj"
    with open(path, "w") as fh:
        fh.writelines(f"v {x} {y} {z}\n" for x, y, z in arm.vertices)
        fh.writelines(f"vn {x} {y} {z}\n" for x, y, z in normals)
        fh.writelines(f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}\n" for a, b, c in arm.faces)
    surface = ws.load_surface(path)
    np.testing.assert_allclose(surface.normals, normals, atol=1e-9)
    assert ws.load_surface(EXAMPLE / "arm.obj").normals is None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = ws.bind(path, EXAMPLE / "arm_cage.obj", resolution=16, device=device)
    b.save(tmp_path / "b.npz")
    b = ws.load_binding(tmp_path / "b.npz", device=device)
    np.testing.assert_allclose(b.mesh_normals, normals, atol=1e-9)
    usd = ws.write_animation(tmp_path / "n.usda", b, ws.Poses(cage_poses(b, 2), np.array([1.0, 2.0]), "g"))
    stage = Usd.Stage.Open(str(usd))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh"))
    assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    assert mesh.GetNormalsAttr().GetTimeSamples() == [1.0, 2.0]  # recomputed per frame, not a stale rest value
    # frame 1 is the rest pose: its normals agree with the file's (weighted by angle there, by area here)
    agreement = np.sum(np.asarray(mesh.GetNormalsAttr().Get(1.0)) * normals, axis=1)
    assert np.median(agreement) > 0.999
    rest = trimesh.Trimesh(b.deform(cage_poses(b, 1)[0]), b.mesh_faces, process=False)
    area_weighted = np.zeros_like(rest.vertices)
    for corner in range(3):
        np.add.at(area_weighted, rest.faces[:, corner], rest.face_normals * rest.area_faces[:, None])
    area_weighted /= np.linalg.norm(area_weighted, axis=1, keepdims=True)
    np.testing.assert_allclose(np.asarray(mesh.GetNormalsAttr().Get(1.0)), area_weighted, atol=1e-4)


def test_bad_pose_inputs_are_named(arm, tmp_path):
    np.save(tmp_path / "empty.npy", np.zeros((0, 58, 3)))
    with pytest.raises(ws.BindingError, match="empty.npy: there are no poses"):
        ws.load_poses(tmp_path / "empty.npy", arm.cage_faces)
    np.savez(tmp_path / "dup.npz", poses=cage_poses(arm, 2), frames=[1, 1])
    with pytest.raises(ws.BindingError, match="dup.npz: frame numbers must be finite, distinct"):
        ws.load_poses(tmp_path / "dup.npz", arm.cage_faces)
    np.savez(tmp_path / "short.npz", poses=cage_poses(arm, 3), frames=[1, 2])
    with pytest.raises(ws.BindingError, match=r"short.npz: 'frames' has shape \(2,\)"):
        ws.load_poses(tmp_path / "short.npz", arm.cage_faces)
    (tmp_path / "broken.usda").write_text("#usda 1.0\n( this is not usd\n")
    with pytest.raises(ws.BindingError, match="broken.usda: cannot read it as USD"):
        ws.load_poses(tmp_path / "broken.usda", arm.cage_faces)


def test_outputs_get_the_usual_permissions(arm, tmp_path):
    old = os.umask(0o022)
    try:
        arm.save(tmp_path / "b.npz")
    finally:
        os.umask(old)
    assert (os.stat(tmp_path / "b.npz").st_mode & 0o777) == 0o644
