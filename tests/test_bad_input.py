"""Bad input meets a one-line error naming the file and what is wrong, exit code 2, and no output (issue 30, a second
round): USD time codes per second that are not a positive number, a time sample that is not finite, a point set
written where a format needs triangles, a manifest with a mistyped table or a value out of range. Each case runs
the command line in process (``main(argv)``, its exit code and output captured: a fresh process would add only its
start); tests/test_cli_failures.py and the other command tests run ``warp-stokes`` as a user does."""

import json
import os

import numpy as np
import pytest

from conftest import EXAMPLE, cli, one_error_line

MESH, CAGE = str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj")


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
def test_usd_poses_whose_rate_is_not_a_positive_number_are_refused(tmp_path, arm_npz, rate):
    # -24 was written as framesPerSecond -24 (USD refused to reopen it, the file stayed); inf exited 0
    poses = usd_poses(tmp_path / "poses.usda", rate)
    out = tmp_path / "o.usda"
    proc = cli("animate", str(arm_npz), str(poses), "--cage-prim", "/Arm/Rig/Cage", "-o", str(out), "--device", "cpu")
    assert proc.returncode == 2 and not out.exists() and os.listdir(tmp_path) == ["poses.usda"]
    assert one_error_line(proc) == (f"warp-stokes: error: {poses}: timeCodesPerSecond is {rate:g}, not a positive "
                                    "number of time codes per second")


def test_fps_that_is_not_finite_is_refused(tmp_path, arm_npz):
    proc = cli("animate", str(arm_npz), str(EXAMPLE / "bend_poses.npy"), "--fps", "inf", "-o", str(tmp_path / "o.usda"))
    assert proc.returncode == 2 and os.listdir(tmp_path) == []
    assert one_error_line(proc).endswith("argument --fps: must be > 0, got inf")


def test_a_time_sample_that_is_not_finite_is_named(tmp_path, arm_npz):
    poses = usd_poses(tmp_path / "poses.usda", nan_at=3.0)
    proc = cli("animate", str(arm_npz), str(poses), "--cage-prim", "/Arm/Rig/Cage", "-o", str(tmp_path / "o.usda"),
               "--device", "cpu")
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
    proc = cli("bind", str(points), CAGE, "-o", str(bound), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    pose = tmp_path / "pose.npy"
    np.save(pose, np.load(EXAMPLE / "bend_poses.npy")[-1])
    for ext in ("stl", "glb"):
        proc = cli("deform", str(bound), str(pose), "-o", str(tmp_path / f"x.{ext}"), "--device", "cpu")
        assert proc.returncode == 2 and not (tmp_path / f"x.{ext}").exists()
        assert one_error_line(proc).endswith(f"x.{ext}: the bound mesh has no faces (a point set), which {ext} "
                                             "cannot hold; write obj, ply or off")
    proc = cli("deform", str(bound), str(pose), "-o", str(tmp_path / "x.ply"), "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    import trimesh

    assert len(trimesh.load(tmp_path / "x.ply", process=False).vertices) == len(vertices[::10])
    proc = cli("show", str(bound), "--pose", str(pose), "-o", str(tmp_path / "s.png"))
    assert proc.returncode == 2 and not (tmp_path / "s.png").exists()
    assert "the bound mesh has no faces (a point set): there are no triangles to colour" in one_error_line(proc)


@pytest.mark.parametrize("text, message", [
    ("[default]\nresolution = 16\n", "unknown top-level key(s) ['default']; known: 'defaults', 'asset' (TOML) or "
                                    "'assets' (JSON)"),
    ("[[assets]]\nmesh = \"x.obj\"\ncage = \"c.obj\"\n",
     "both 'asset' and 'assets' lists; give the assets in one of them"),
    ("[defaults]\nresolution = 0\n", "asset 1: 'resolution' must be \"auto\" or an integer from 8 to 2048, got 0"),
    ("[defaults]\nresolution = 99999999999999999999\n",
     "asset 1: 'resolution' must be \"auto\" or an integer from 8 to 2048, got 99999999999999999999"),
    ("[defaults]\ntol = nan\n", "asset 1: 'tol' must be in (0, 0.1], got nan"),
    ("[defaults]\nfps = inf\n", "asset 1: 'fps' must be a positive number, got inf"),
    ("[defaults]\nwith_cage = 1\n", "asset 1: 'with_cage' has the wrong type (int)"),
    ("[[asset]]\nmesh = \"x.obj\"\ncage = \"auto\"\nposes = \"p.npy\"\n",
     "asset 1: 'poses' move a cage's handles, and cage \"auto\" has none until it is made; bind it, then animate "
     "poses of the made cage (<name>.cage.obj)"),
    ("[[asset]]\nmesh = \"x.usda\"\ncage = \"auto\"\ncage_prim = \"/C\"\n",
     "asset 1: cage \"auto\" and 'cage_prim': give one of them"),
    ("[defaults]\nhandles = 40\n", "asset 1: 'handles' shape a made cage: set cage = \"auto\""),
    ("[[asset]]\nmesh = \"x.obj\"\ncage = \"auto\"\nhandles = 4\n", "asset 1: 'handles' must be at least 8, got 4"),
    ("[[asset]]\nmesh = \"x.obj\"\ncage = \"auto\"\noffset = 0.9\n",
     "asset 1: 'offset' must be a fraction of the diagonal in (0, 0.5], got 0.9"),
])
def test_a_manifest_is_checked_whole_before_any_work(tmp_path, text, message):
    manifest = tmp_path / "m.toml"
    manifest.write_text(text + f'[[asset]]\nmesh = "{MESH}"\ncage = "{CAGE}"\n')
    out = tmp_path / "out"
    proc = cli("batch", str(manifest), "-o", str(out), "--device", "cpu")
    assert proc.returncode == 2 and not out.exists()
    assert one_error_line(proc) == f"warp-stokes: error: {manifest}: {message}"


@pytest.mark.parametrize("kind", ["strings", "records", "objects in an archive", "string frame numbers"])
def test_arrays_that_hold_no_numbers_are_refused(tmp_path, arm_npz, kind):
    # strings, a structured dtype, an object array inside .npz (it would need unpickling): tracebacks before
    path = tmp_path / ("p.npz" if "archive" in kind or "frame" in kind else "p.npy")
    if kind == "strings":
        np.save(path, np.array([["a", "b", "c"]] * 58))
    elif kind == "records":
        np.save(path, np.zeros((58,), dtype=[("x", "f8"), ("y", "f8"), ("z", "f8")]))
    elif kind == "objects in an archive":
        np.savez(path, poses=np.array([[1, "a", None]] * 58, dtype=object))
    else:
        np.savez(path, poses=np.load(EXAMPLE / "bend_poses.npy")[:2], frames=np.array(["one", "two"]))
    out = tmp_path / "o.usda"
    for command in (("animate", str(arm_npz), str(path), "-o", str(out)),
                    ("deform", str(arm_npz), str(path), "-o", str(tmp_path / "d.obj")),
                    ("encode", str(arm_npz), str(path), "-o", str(tmp_path / "e.npy"))):
        if command[0] == "deform" and path.suffix == ".npz":
            continue  # deform takes one pose: a cage file or a .npy
        proc = cli(*command, "--device", "cpu")
        line = one_error_line(proc)
        assert proc.returncode == 2 and line.startswith(f"warp-stokes: error: {path}: "), (command, proc.stderr)
        assert "must be numbers, not an array of" in line or "cannot read it as a numpy" in line, line
        assert sorted(os.listdir(tmp_path)) == [path.name]


@pytest.mark.parametrize("record, message", [
    ("vn x y z", "line 2090: unreadable normal 'vn x y z'"),
    ("vn 1 2", "line 2090: unreadable normal 'vn 1 2'"),
    ("f 1 2 99999999999999999999999", "line 2090: unreadable face 'f 1 2 99999999999999999999999' (three or more "
                                      "vertex indices within the file's 2089 vertices)"),
])
def test_obj_records_that_cannot_be_read_are_named(tmp_path, record, message):
    # a ValueError and an OverflowError traceback before: now the file and the line
    vertices = [line for line in open(MESH) if line.startswith("v ")]
    faces = [line for line in open(MESH) if line.startswith("f ")]
    if record.startswith("vn"):
        faces = [" ".join(f"{c}//1" for c in line.split()[1:]) for line in faces]
        faces = [f"f {line}\n" for line in faces]
    mesh = tmp_path / "m.obj"
    mesh.write_text("".join(vertices) + record + "\n" + "".join(faces))
    proc = cli("bind", str(mesh), CAGE, "-o", str(tmp_path / "b.npz"), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 2 and not (tmp_path / "b.npz").exists()
    assert one_error_line(proc) == f"warp-stokes: error: {mesh}: {message}"


def test_tab_separated_records_are_read_beside_texture_coordinates(tmp_path):
    # "v<TAB>x y z" in a file with vt records took the slow path, which knew only spaces: "no vertices"
    lines = [line for line in open(MESH) if line.startswith(("v ", "f "))]
    text = "".join(line.replace("v ", "v\t", 1) if line.startswith("v ") else line for line in lines)
    mesh = tmp_path / "tabs.obj"
    mesh.write_text("vt 0 0\n" + text)
    out = tmp_path / "b.npz"
    proc = cli("bind", str(mesh), CAGE, "-o", str(out), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    import warp_stokes as ws

    assert ws.load_binding(out).n_vertices == 2089


def tampered(source, target, change):
    """A copy of the binding ``source`` at ``target`` with ``change(arrays, meta)`` applied (its result, where not
    None, is the new metadata) and the fingerprints recomputed (what a careless tool, or an attacker, writes)."""
    from warp_stokes.binding.store import fingerprint

    with np.load(source, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    meta = json.loads(str(arrays.pop("meta")))
    meta = change(arrays, meta) or meta
    if isinstance(meta, dict):
        try:
            meta["cage_fingerprint"] = fingerprint(arrays["cage_vertices"], arrays["cage_faces"])
            meta["mesh_fingerprint"] = fingerprint(arrays["mesh_vertices"], arrays["mesh_faces"])
        except (ValueError, TypeError):  # arrays of strings: no fingerprint to recompute
            pass
    np.savez(target, meta=np.array(json.dumps(meta)), **arrays)
    return target


def _set(arrays, key, value):
    arrays[key] = value


@pytest.mark.parametrize("change, message", [
    (lambda a, m: m.pop("settings") and None, "the binding's settings is missing"),
    (lambda a, m: [1, 2], "the binding's metadata is not a record (a list)"),
    (lambda a, m: m["parts"].__setitem__(0, {"path": "/x", "vertices": "abc"}) if m.get("parts") else
     m.__setitem__("parts", [{"path": "/x", "vertices": "abc"}]),
     "the binding's parts[0].vertices must be an integer >= 0, got 'abc'"),
    (lambda a, m: m.__setitem__("asset", "hero.usd"), "the binding's asset must be a record or null, got 'hero.usd'"),
    (lambda a, m: _set(a, "weights", a["weights"].astype(str)), "the binding's weights must be numbers in 2089 rows "
                                                                 "of 58; got <U"),
    (lambda a, m: _set(a, "mesh_normals", np.zeros((5, 3))), "the binding's mesh_normals must be numbers in 2089 "
                                                              "rows of 3; got float64 of shape (5, 3)"),
    (lambda a, m: _set(a, "mesh_faces", a["mesh_faces"] + 10**6), "the binding's mesh_faces run from 1000000 to"),
    (lambda a, m: _set(a, "mesh_faces", -a["mesh_faces"]), "the binding's mesh_faces run from -2088 to 0, outside "
                                                           "[0, 2089)"),
    (lambda a, m: a["weights"].__setitem__((3, 4), np.nan), "the binding's weights are not all finite"),
    (lambda a, m: _set(a, "mesh_face_indices", a["mesh_face_indices"] + 5000),
     "the binding's mesh_face_indices run from"),
])
def test_a_malformed_binding_is_one_error_and_writes_nothing(tmp_path, arm_npz, change, message):
    # KeyError / TypeError / ValueError tracebacks before, or (with the fingerprints recomputed) an OBJ with
    # out-of-range faces, a USD with negative indices, NaN points
    bad = tampered(arm_npz, tmp_path / "bad.npz", change)
    pose = tmp_path / "pose.npy"
    np.save(pose, np.load(EXAMPLE / "bend_poses.npy")[-1])
    for command in (("deform", str(bad), str(pose), "-o", str(tmp_path / "x.obj")),
                    ("animate", str(bad), str(EXAMPLE / "bend_poses.npy"), "-o", str(tmp_path / "x.usda"))):
        proc = cli(*command, "--device", "cpu")
        assert proc.returncode == 2, proc.stderr
        line = one_error_line(proc)
        assert line.startswith(f"warp-stokes: error: {bad}: {message}"), line
        assert sorted(os.listdir(tmp_path)) == ["bad.npz", "pose.npy"]
