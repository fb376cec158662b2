"""The reproductions of issue 47, each as a user meets it, closed where its kind is decided: one door in
(``warp_stokes.io.door``), the inputs' full set (``warp_stokes.io.inputs``), one door out
(``warp_stokes.io.outputs``), bindings checked whole (``warp_stokes.binding.record``), options checked where they
enter (``warp_stokes.arguments``). ``tests/test_hostile_input.py`` draws the same classes at random; these are the
cases as reported, kept so that each stays closed. The command line runs in process (``main(argv)``) unless a signal
or a fresh process is the point."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, write_obj
from warp_stokes.cli import main


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """The issue's folder: copies of the arm's files, ``b.npz`` (of the OBJ) and ``u.npz`` (of the USD asset), both
    at resolution 8, a poses file that sublayers a file of the user's, and OBJ frames."""
    folder = tmp_path_factory.mktemp("issue47")
    for name in ("arm.obj", "arm_cage.obj", "bend_poses.npy", "arm.usda"):
        shutil.copy(EXAMPLE / name, folder / name)
    here = os.getcwd()
    os.chdir(folder)
    try:
        assert main(["bind", "arm.obj", "arm_cage.obj", "-o", "b.npz", "--resolution", "8", "--device", "cpu",
                     "--quiet"]) == 0
        assert main(["bind", "arm.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "u.npz", "--resolution", "8",
                     "--device", "cpu", "--quiet"]) == 0
    finally:
        os.chdir(here)
    (folder / "t.usda").write_text('#usda 1.0\ndef "Mine" {}\n')
    (folder / "p.usda").write_text("#usda 1.0\n(\n    subLayers = [@./t.usda@, @./arm.usda@]\n)\n")
    binding = ws.load_binding(folder / "b.npz", device="cpu")
    (folder / "fr").mkdir()
    for k, vertices in enumerate(binding.deform(np.load(folder / "bend_poses.npy")[::8])):
        write_obj(folder / "fr" / f"frame_{k}.obj", vertices, binding.mesh_faces)
    np.save(folder / "bent.npy", np.load(folder / "bend_poses.npy")[-1])
    return folder


@pytest.fixture
def here(tmp_path, base, monkeypatch):
    """A fresh copy of the issue's folder, the working directory."""
    folder = tmp_path / "w"
    shutil.copytree(base, folder, symlinks=True)
    monkeypatch.chdir(folder)
    return folder


def run(capsys, *argv) -> tuple[int, str]:
    """``warp-stokes ARGV`` in process (on the CPU unless ARGV names a device): its exit code and its one error line
    ("" when none)."""
    rc = main([*argv] if "--device" in argv else [*argv, "--device", "cpu"])
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith(("warning:", "["))]
    assert rc != 2 or len(err) == 1, err
    return rc, err[-1] if err else ""


def contents(folder) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ----- 1: an output in an input's layer stack (sublayers, clips), for the poses as for the asset ---------------------


@pytest.mark.parametrize("extra", [[], ["--skeleton"]])
def test_animate_never_replaces_a_sublayer_of_its_poses(here, capsys, extra):
    before = contents(here)
    rc, err = run(capsys, "animate", "u.npz", "p.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "t.usda", *extra)
    assert rc == 2 and err == (f"warp-stokes: error: t.usda: the output would replace a layer of the input p.usda "
                               f"({here / 't.usda'}); choose another output")
    assert contents(here) == before


def test_encode_never_replaces_a_sublayer_of_its_frames(here, capsys):
    rc, err = run(capsys, "encode", "u.npz", "p.usda", "-o", "t.usda")
    assert rc == 2 and "would replace a layer of the input p.usda" in err
    assert (here / "t.usda").read_text() == '#usda 1.0\ndef "Mine" {}\n'


def test_a_value_clip_of_an_input_is_an_input(here, capsys):
    (here / "clip.usda").write_text('#usda 1.0\ndef "Clip" {}\n')
    (here / "c.usda").write_text('#usda 1.0\n(\n    subLayers = [@./arm.usda@]\n)\nover "Arm" (\n    clips = {\n'
                                 '        dictionary default = {\n            asset[] assetPaths = [@./clip.usda@]\n'
                                 '            string primPath = "/Clip"\n            double2[] active = [(0, 0)]\n'
                                 '        }\n    }\n) {}\n')
    before = contents(here)
    for argv in (["animate", "u.npz", "c.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "clip.usda"],
                 ["cage", "c.usda", "-o", "clip.usda", "--handles", "40"]):
        rc, err = run(capsys, *argv)
        assert rc == 2 and "would replace a layer of the input c.usda" in err, err
    assert contents(here) == before


# ----- 2, 3: the outputs of one command written together -------------------------------------------------------------


def test_encode_auto_writes_nothing_into_its_frames_folder(here, capsys):
    rc, err = run(capsys, "encode", "auto", "fr", "-o", "fr/poses.npy")
    assert rc == 2 and err == ("warp-stokes: error: fr/poses.cage.obj: the output would replace a frame of the input "
                               "fr (every .obj file there is read as one); choose another output")
    assert sorted(os.listdir(here / "fr")) == ["frame_0.obj", "frame_1.obj", "frame_2.obj"]


def test_encode_auto_that_fails_late_leaves_the_earlier_run_s_files(here, capsys, monkeypatch):
    # a frame of another vertex count is found after the cage was made and bound: the earlier run's cage, binding
    # and poses stay as they were (they were replaced before the fix, and the new cage left beside old poses)
    monkeypatch.setattr("warp_stokes.geometry.resolution.AUTO_RESOLUTION", 16)  # a smaller grid, as fast as the point
    rc, _ = run(capsys, "encode", "auto", "fr", "-o", "poses.npy")
    assert rc == 0
    before = contents(here)
    write_obj(here / "fr" / "frame_9.obj", np.zeros((4, 3)), np.array([[0, 1, 2], [0, 2, 3]]))
    rc, err = run(capsys, "encode", "auto", "fr", "-o", "poses.npy")
    assert rc == 2 and "fr/frame_9.obj" in err
    after = contents(here)
    assert {k: v for k, v in after.items() if k != "fr/frame_9.obj"} == before


def test_a_full_disk_leaves_the_made_cage_and_binding_of_the_earlier_run(here, capsys, monkeypatch):
    import errno

    assert run(capsys, "bind", "arm.obj", "auto", "--handles", "40", "-o", "B.npz", "--resolution", "8")[0] == 0
    before = contents(here)
    real = np.savez

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(np, "savez", full)
    rc, err = run(capsys, "bind", "arm.obj", "auto", "--handles", "60", "-o", "B.npz", "--resolution", "8")
    monkeypatch.setattr(np, "savez", real)
    assert rc == 2 and err == "warp-stokes: error: B.npz: could not write it: No space left on device"
    assert contents(here) == before  # the 40-handle cage still beside its binding


def test_a_failing_second_rename_puts_the_first_back(here, capsys, monkeypatch):
    assert run(capsys, "bind", "arm.obj", "auto", "--handles", "40", "-o", "B.npz", "--resolution", "8")[0] == 0
    before = contents(here)
    real, calls = os.replace, []

    def second_fails(src, dst, *args, **kwargs):
        calls.append(dst)
        if len(calls) == 2:
            raise OSError(5, "Input/output error")
        return real(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", second_fails)
    rc, err = run(capsys, "bind", "arm.obj", "auto", "--handles", "48", "-o", "B.npz", "--resolution", "8")
    monkeypatch.setattr(os, "replace", real)
    assert rc == 2 and err.startswith("warp-stokes: error: B.npz: could not write it: Input/output error; the other "
                                      "outputs are as they were")
    assert contents(here) == before


def test_an_existing_output_keeps_its_permission_mode(here, capsys):
    assert run(capsys, "deform", "b.npz", "bent.npy", "-o", "d.obj")[0] == 0
    os.chmod(here / "d.obj", 0o640)
    assert run(capsys, "deform", "b.npz", "bent.npy", "-o", "d.obj")[0] == 0
    assert os.stat(here / "d.obj").st_mode & 0o777 == 0o640


# ----- 4: temporary files and the batch lock --------------------------------------------------------------------------


def test_a_batch_removes_only_its_own_temporary_files(here, capsys):
    (here / "m.toml").write_text('[[asset]]\nname = "a"\nmesh = "arm.obj"\ncage = "arm_cage.obj"\nresolution = 8\n')
    (here / "out").mkdir()
    notes = here / "out" / ".tmp-notes.txt"
    notes.write_text("mine")
    from warp_stokes.io.outputs import host_name

    live = here / "out" / f".wst~{os.getpid()}~{host_name()}~0a1b2c3d~h.usd"  # another command's, writing now
    live.write_text("half")
    rc, _ = run(capsys, "batch", "m.toml", "-o", "out")
    assert rc == 0 and notes.read_text() == "mine" and live.exists()


def test_the_batch_lock_names_its_host_and_a_lock_of_another_host_is_not_taken(here, capsys):
    (here / "m.toml").write_text('[[asset]]\nname = "a"\nmesh = "arm.obj"\ncage = "arm_cage.obj"\nresolution = 8\n')
    (here / "out").mkdir()
    lock = here / "out" / ".warp-stokes.lock"
    lock.write_text(json.dumps({"host": "render-node-7", "pid": 1}))
    rc, err = run(capsys, "batch", "m.toml", "-o", "out")
    assert rc == 2 and "a batch on host render-node-7 (pid 1) holds this folder" in err
    assert json.loads(lock.read_text()) == {"host": "render-node-7", "pid": 1}
    lock.write_text(json.dumps({"host": socket.gethostname(), "pid": 2**22 + 12345}))  # this host's, gone
    assert run(capsys, "batch", "m.toml", "-o", "out")[0] == 0 and not lock.exists()


# ----- 5: the binding's own sources -----------------------------------------------------------------------------------


@pytest.mark.parametrize("output", ["arm.obj", "arm_cage.obj", "../w/arm.obj"])
def test_deform_never_replaces_what_the_binding_was_made_from(here, capsys, output):
    before = contents(here)
    rc, err = run(capsys, "deform", "b.npz", "bent.npy", "-o", output)
    assert rc == 2 and "the output would replace a source of the input b.npz" in err
    assert contents(here) == before


# ----- 6: a USD file whose layer stack cannot be read -------------------------------------------------------------


def test_an_unreadable_sublayer_is_one_error_in_every_command_and_fails_its_batch_asset_alone(here, capsys):
    (here / "broken.usda").write_text("#usda 1.0\ngarbage {{{")
    (here / "bad.usda").write_text("#usda 1.0\n(\n    subLayers = [@./broken.usda@, @./arm.usda@]\n)\n")
    before = contents(here)
    for argv in (["animate", "u.npz", "bad.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.usda"],
                 ["cage", "bad.usda", "-o", "o.obj"],
                 ["animate", "u.npz", "bend_poses.npy", "--asset", "bad.usda", "-o", "o.usda"],
                 ["bind", "bad.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.npz"]):
        rc, err = run(capsys, *argv)
        assert rc == 2 and err.startswith("warp-stokes: error: bad.usda: its layer ") and "broken.usda" in err, err
        assert "cannot read it as USD" in err
    assert contents(here) == before
    (here / "m.toml").write_text('[[asset]]\nname = "bad"\nmesh = "bad.usda"\ncage_prim = "/Arm/Rig/Cage"\n'
                                 'resolution = 8\n\n[[asset]]\nname = "good"\nmesh = "arm.obj"\n'
                                 'cage = "arm_cage.obj"\nresolution = 8\n')
    rc, _ = run(capsys, "batch", "m.toml", "-o", "out")
    summary = {a["name"]: a for a in json.loads((here / "out" / "summary.json").read_text())["assets"]}
    assert rc == 1 and summary["good"]["status"] == "ok" and (here / "out" / "good.npz").exists()
    assert summary["bad"]["status"] == "failed" and "broken.usda" in summary["bad"]["error"]


# ----- 7, 11: numbers where they enter ----------------------------------------------------------------------------


def test_frame_rates_and_times_float32_cannot_hold_are_refused(here, capsys):
    rc, err = run(capsys, "animate", "b.npz", "bend_poses.npy", "-o", "k.glb", "--fps", "1e-40")
    assert rc == 2 and err.endswith("argument --fps: must be > 0 within float32's range (1.18e-38 to 3.4e+38), got "
                                    "1e-40")
    np.savez(here / "far.npz", poses=np.load("bend_poses.npy")[:2], frames=np.array([1.0, 3e38]))
    rc, err = run(capsys, "animate", "b.npz", "far.npz", "-o", "k.glb", "--fps", "0.001")
    assert rc == 2 and "do not fit glTF's float32 times" in err
    np.savez(here / "huge.npz", poses=np.full((2, 58, 3), 1e300))
    rc, err = run(capsys, "animate", "b.npz", "huge.npz", "-o", "k.usda")
    assert rc == 2 and err.startswith("warp-stokes: error: huge.npz: frame, point 0, 0 has a coordinate beyond 1e+18")
    assert not (here / "k.glb").exists() and not (here / "k.usda").exists()


@pytest.mark.parametrize("argv, message", [
    (["bind", "arm.usda", "--cage-prim", "/Arm/Rig/Cage", "-o", "o.npz", "--rest-time", "nan"],
     "argument --rest-time: must be a finite number, got nan"),
    (["bind", "arm.obj", "arm_cage.obj", "-o", "o.npz", "--resolution", "16", "--memory-gb", "1e-9"],
     "no grid of the coarsest resolution (8) fits; give more memory"),
])
def test_option_messages_say_what_is_taken(here, capsys, argv, message):
    rc, err = run(capsys, *argv)
    assert rc == 2 and message in err, err


def test_key_frames_may_start_below_zero(here, capsys):
    np.save(here / "three.npy", np.load("bend_poses.npy")[:3])
    rc, _ = run(capsys, "animate", "b.npz", "three.npy", "--key-frames", "-10,0,10", "-o", "k.usda")
    assert rc == 0
    from pxr import Usd

    stage = Usd.Stage.Open(str(here / "k.usda"))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (-10.0, 10.0)


def test_a_truncated_binary_stl_is_one_error(here, capsys):
    import trimesh

    trimesh.load(here / "arm.obj", process=False).export(here / "arm.stl")
    data = (here / "arm.stl").read_bytes()
    (here / "arm.stl").write_bytes(data[: len(data) // 2])
    rc, err = run(capsys, "bind", "arm.stl", "arm_cage.obj", "-o", "o.npz")
    assert rc == 2 and err.startswith("warp-stokes: error: arm.stl: cannot read it as a STL file")
    assert "charset_normalizer" not in err


@pytest.mark.parametrize("influences", [2.5, True, "8"])
def test_write_skin_takes_an_integer_number_of_influences(here, influences):
    binding = ws.load_binding("b.npz", device="cpu")
    with pytest.raises(ws.WarpStokesError, match="influences must be an integer"):
        ws.write_skin("s.usda", binding, np.load("bend_poses.npy")[:2], influences=influences)
    assert not (here / "s.usda").exists()


def test_batch_errors_name_the_output_not_a_temporary_file(here, capsys):
    (here / "m.toml").write_text('[[asset]]\nname = "s"\nmesh = "arm.obj"\ncage = "arm_cage.obj"\nresolution = 8\n'
                                 'poses = "bend_poses.npy"\nskin = "glb"\nmax_error = 1e-9\n')
    rc, _ = run(capsys, "batch", "m.toml", "-o", "out")
    record = json.loads((here / "out" / "summary.json").read_text())["assets"][0]
    assert rc == 1 and record["status"] == "failed" and ".wst~" not in record["error"] and "s.glb" in record["error"]


def test_a_batch_that_cannot_start_leaves_no_folder(here, capsys):
    (here / "m.toml").write_text('[[asset]]\nname = "a"\nmesh = "arm.obj"\ncage = "arm_cage.obj"\n')
    rc, err = run(capsys, "batch", "m.toml", "-o", "out", "--device", "cuda:7")
    assert rc == 2 and not (here / "out").exists()


def test_show_error_needs_no_rtree(here, capsys, monkeypatch):
    pytest.importorskip("matplotlib")
    monkeypatch.setitem(sys.modules, "rtree", None)  # the plot extra alone: no rtree
    cage = ws.load_surface("arm_cage.obj")  # a reference of another vertex count: distances to its closest points
    write_obj(here / "ref.obj", cage.vertices, cage.faces)
    rc, err = run(capsys, "show", "b.npz", "--error", "ref.obj", "-o", "e.png")
    assert rc == 0, err
    assert (here / "e.png").stat().st_size > 0


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_leave_no_temporary_file(here, signum):
    # a long write of the animation (many frames of USD text), terminated in the middle
    np.save(here / "long.npy", np.repeat(np.load(here / "bend_poses.npy"), 40, axis=0))
    proc = subprocess.Popen([sys.executable, "-m", "warp_stokes.cli", "animate", "b.npz", "long.npy", "-o",
                             "long.usda", "--device", "cpu"], cwd=here, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not any(p.startswith(".wst~") and p.endswith("long.usda")
                                             for p in os.listdir(here)):
        time.sleep(0.01)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the write ended before the signal came")
    assert proc.returncode == 128 + signum, err
    assert err.strip().splitlines()[-1].startswith(f"warp-stokes: interrupted ({signal.Signals(signum).name})")
    assert not [p for p in os.listdir(here) if p.startswith(".wst~")] and not (here / "long.usda").exists()


# ----- 8: a binding edited by hand ----------------------------------------------------------------------------------


@pytest.mark.parametrize("edit, message", [
    (lambda m: m["asset"].__setitem__("rest_time", "abc"), "the binding's asset.rest_time must be a finite number or "
                                                           "null, got 'abc'"),
    (lambda m: m["asset"].__setitem__("meters_per_unit", "x"), "the binding's asset.meters_per_unit must be a finite "
                                                               "number > 0, got 'x'"),
    (lambda m: m["parts"][0].__setitem__("normals", "bogus"), "the binding's parts[0].normals must be one of"),
    (lambda m: m["settings"].__setitem__("resolution", "abc"), "the binding's settings.resolution must be an integer"),
    (lambda m: m.__setitem__("settings", {}), "the binding's settings.method is missing"),
])
def test_a_binding_edited_by_hand_is_checked_whole(here, capsys, edit, message):
    with np.load("u.npz") as data:
        arrays = dict(data)
    meta = json.loads(str(arrays["meta"]))
    edit(meta)
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(here / "edited.npz", **arrays)
    for argv in (["deform", "edited.npz", "bent.npy", "-o", "d.obj"],
                 ["animate", "edited.npz", "bend_poses.npy", "-o", "a.usda"]):
        rc, err = run(capsys, *argv)
        assert rc == 2 and err.startswith(f"warp-stokes: error: edited.npz: {message}"), err
    assert not (here / "d.obj").exists() and not (here / "a.usda").exists()


# ----- 9, 10: special files; another file never read in a file's place ----------------------------------------------


@pytest.mark.parametrize("slot", ["mesh", "poses", "binding", "frame"])
def test_a_pipe_or_dev_zero_is_refused_at_once(here, capsys, slot):
    for kind in ("pipe", "zero"):
        name = {"mesh": "z.obj", "poses": "z.npy", "binding": "z.npz", "frame": "fr/frame_1.obj"}[slot]
        if os.path.lexists(here / name):
            os.unlink(here / name)
        os.mkfifo(here / name) if kind == "pipe" else os.symlink("/dev/zero", here / name)
        argv = {"mesh": ["bind", name, "arm_cage.obj", "-o", "o.npz"],
                "poses": ["animate", "b.npz", name, "-o", "o.usda"],
                "binding": ["deform", name, "bent.npy", "-o", "o.obj"],
                "frame": ["encode", "b.npz", "fr", "-o", "o.npy"]}[slot]
        start = time.perf_counter()
        rc, err = run(capsys, *argv)
        what = "a pipe" if kind == "pipe" else "a character device"
        assert rc == 2 and f"{name}: {what}, not a" in err, err
        assert time.perf_counter() - start < 30


def test_a_damaged_gltf_is_never_replaced_by_its_neighbour(here, capsys):
    import trimesh

    trimesh.load(here / "arm.obj", process=False).export(here / "model.gltf")
    (here / "bad.gltf").write_text('{"asset": ')
    rc, err = run(capsys, "bind", "bad.gltf", "arm_cage.obj", "-o", "o.npz")
    assert rc == 2 and err.startswith("warp-stokes: error: bad.gltf: not a glTF file"), err
    os.unlink(here / "model.gltf")
    rc, err = run(capsys, "bind", "bad.gltf", "arm_cage.obj", "-o", "o.npz")
    assert rc == 2 and err.startswith("warp-stokes: error: bad.gltf: not a glTF file"), err


# ----- 12: what a batch is up to date with -------------------------------------------------------------------------


def test_a_batch_redoes_an_asset_whose_sublayer_changed(here, capsys):
    (here / "geo.usda").write_text((here / "arm.usda").read_text())
    (here / "hero.usda").write_text("#usda 1.0\n(\n    subLayers = [@./geo.usda@]\n)\n")
    (here / "m.toml").write_text('[[asset]]\nname = "hero"\nmesh = "hero.usda"\ncage_prim = "/Arm/Rig/Cage"\n'
                                 'resolution = 8\n')
    assert run(capsys, "batch", "m.toml", "-o", "out")[0] == 0
    assert run(capsys, "batch", "m.toml", "-o", "out")[0] == 0
    assert json.loads((here / "out" / "summary.json").read_text())["assets"][0]["status"] == "skipped"
    first = ws.load_binding(here / "out" / "hero.npz", device="cpu").mesh_vertices
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(here / "geo.usda"))  # the sublayer edited, its root file untouched
    points = layer.GetAttributeAtPath("/Arm/Geo/Skin.points")
    points.default = [tuple(p) for p in (np.asarray(points.default) * 1.01).tolist()]
    layer.Save()
    time.sleep(0.01)
    assert run(capsys, "batch", "m.toml", "-o", "out")[0] == 0
    assert json.loads((here / "out" / "summary.json").read_text())["assets"][0]["status"] == "ok"
    again = ws.load_binding(here / "out" / "hero.npz", device="cpu").mesh_vertices
    assert not np.allclose(first, again)
