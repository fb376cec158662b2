"""Bad input meets a one-line error naming the file and what is wrong, exit code 2, and no output (issue 30, a second
round): USD time codes per second that are not a positive number, a time sample that is not finite, a point set
written where a format needs triangles, a manifest with a mistyped table or a value out of range. Each case runs
``warp-stokes`` as a subprocess."""

import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from conftest import EXAMPLE

MESH, CAGE = str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj")


def warp_stokes(*args, timeout=300):
    exe = shutil.which("warp-stokes")
    command = [exe, *args] if exe else [sys.executable, "-m", "warp_stokes.cli", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout)


def one_error_line(proc) -> str:
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.fixture(scope="module")
def binding(tmp_path_factory):
    out = tmp_path_factory.mktemp("bound") / "arm.npz"
    proc = warp_stokes("bind", MESH, CAGE, "-o", str(out), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    return out


def usd_poses(path, rate=24.0, nan_at=None):
    """The bundled asset's animated cage as a poses file, its time codes per second ``rate`` and, with ``nan_at``,
    one point of that time sample NaN."""
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.Open(str(EXAMPLE / "arm.usda"))
    stage.SetTimeCodesPerSecond(rate)
    if nan_at is not None:
        points = UsdGeom.Mesh(stage.GetPrimAtPath("/Arm/Rig/Cage")).GetPointsAttr()
        value = np.array(points.Get(nan_at))
        value[3, 1] = np.nan
        points.Set(value.tolist(), nan_at)
    stage.Export(str(path))
    return path


@pytest.mark.parametrize("rate", [-24.0, float("nan"), float("inf")])
def test_usd_poses_whose_rate_is_not_a_positive_number_are_refused(tmp_path, binding, rate):
    # -24 was written as framesPerSecond -24 (USD refused to reopen it, the file stayed); inf exited 0
    poses = usd_poses(tmp_path / "poses.usda", rate)
    out = tmp_path / "o.usda"
    proc = warp_stokes("animate", str(binding), str(poses), "--cage-prim", "/Arm/Rig/Cage", "-o", str(out),
                       "--device", "cpu")
    assert proc.returncode == 2 and not out.exists() and os.listdir(tmp_path) == ["poses.usda"]
    assert one_error_line(proc) == (f"warp-stokes: error: {poses}: timeCodesPerSecond is {rate:g}, not a positive "
                                    "number of time codes per second")


def test_fps_that_is_not_finite_is_refused(tmp_path, binding):
    proc = warp_stokes("animate", str(binding), str(EXAMPLE / "bend_poses.npy"), "--fps", "inf", "-o",
                       str(tmp_path / "o.usda"))
    assert proc.returncode == 2 and os.listdir(tmp_path) == []
    assert one_error_line(proc).endswith("argument --fps: must be > 0, got inf")


def test_a_time_sample_that_is_not_finite_is_named(tmp_path, binding):
    poses = usd_poses(tmp_path / "poses.usda", nan_at=3.0)
    proc = warp_stokes("animate", str(binding), str(poses), "--cage-prim", "/Arm/Rig/Cage", "-o",
                       str(tmp_path / "o.usda"), "--device", "cpu")
    assert proc.returncode == 2 and not (tmp_path / "o.usda").exists()
    assert one_error_line(proc) == (f"warp-stokes: error: {poses}: /Arm/Rig/Cage has points that are not finite at "
                                    "time 3")


def test_a_point_set_goes_only_where_points_can_go(tmp_path):
    # a binding of a mesh without faces: STL and GLB hold triangles only (it wrote a file of 0 vertices and said
    # "wrote 162 vertices"), show's triangles have nothing to colour (a traceback); PLY holds the points
    points = tmp_path / "points.obj"
    vertices = np.array([[float(v) for v in line.split()[1:4]] for line in open(MESH) if line.startswith("v ")])
    points.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in vertices[::10]))
    bound = tmp_path / "points.npz"
    proc = warp_stokes("bind", str(points), CAGE, "-o", str(bound), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    pose = tmp_path / "pose.npy"
    np.save(pose, np.load(EXAMPLE / "bend_poses.npy")[-1])
    for ext in ("stl", "glb"):
        proc = warp_stokes("deform", str(bound), str(pose), "-o", str(tmp_path / f"x.{ext}"), "--device", "cpu")
        assert proc.returncode == 2 and not (tmp_path / f"x.{ext}").exists()
        assert one_error_line(proc).endswith(f"x.{ext}: the bound mesh has no faces (a point set), which {ext} "
                                             "cannot hold; write obj, ply or off")
    proc = warp_stokes("deform", str(bound), str(pose), "-o", str(tmp_path / "x.ply"), "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    import trimesh

    assert len(trimesh.load(tmp_path / "x.ply", process=False).vertices) == len(vertices[::10])
    proc = warp_stokes("show", str(bound), "--pose", str(pose), "-o", str(tmp_path / "s.png"))
    assert proc.returncode == 2 and not (tmp_path / "s.png").exists()
    assert "the bound mesh has no faces (a point set): there are no triangles to colour" in one_error_line(proc)


@pytest.mark.parametrize("text, message", [
    ("[default]\nresolution = 16\n", "unknown top-level key(s) ['default']; known: 'defaults', 'asset' (TOML) or "
                                    "'assets' (JSON)"),
    ("[[assets]]\nmesh = \"x.obj\"\ncage = \"c.obj\"\n",
     "both 'asset' and 'assets' lists; give the assets in one of them"),
    ("[defaults]\nresolution = 0\n", "asset 1: 'resolution' must be an integer from 8 to 2048, got 0"),
    ("[defaults]\nresolution = 99999999999999999999\n",
     "asset 1: 'resolution' must be an integer from 8 to 2048, got 99999999999999999999"),
    ("[defaults]\ntol = nan\n", "asset 1: 'tol' must be in (0, 0.1], got nan"),
    ("[defaults]\nfps = inf\n", "asset 1: 'fps' must be a positive number, got inf"),
    ("[defaults]\nwith_cage = 1\n", "asset 1: 'with_cage' has the wrong type (int)"),
])
def test_a_manifest_is_checked_whole_before_any_work(tmp_path, text, message):
    manifest = tmp_path / "m.toml"
    manifest.write_text(text + f'[[asset]]\nmesh = "{MESH}"\ncage = "{CAGE}"\n')
    out = tmp_path / "out"
    proc = warp_stokes("batch", str(manifest), "-o", str(out), "--device", "cpu")
    assert proc.returncode == 2 and not out.exists()
    assert one_error_line(proc) == f"warp-stokes: error: {manifest}: {message}"
