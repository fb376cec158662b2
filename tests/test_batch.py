"""Batch binding from a manifest: good and bad assets, summary, exit code, no partial files, re-runs."""

import json
import os
import re

import numpy as np
import pytest

import warp_stokes as ws
from warp_stokes.cli import main
from conftest import EXAMPLE, cli, write_obj


def poses_npy(path, cage, n_frames=3, drop=0):
    rest = cage.vertices[: len(cage.vertices) - drop]
    np.save(path, np.stack([rest * (1 + 0.05 * k) for k in range(n_frames)]))


@pytest.fixture
def manifest(tmp_path):
    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    (tmp_path / "in").mkdir()
    poses_npy(tmp_path / "in" / "grow.npy", cage)
    poses_npy(tmp_path / "in" / "short.npy", cage, drop=1)
    write_obj(tmp_path / "in" / "open_cage.obj", cage.vertices, cage.faces[1:])
    arm, arm_cage = os.path.relpath(EXAMPLE / "arm.obj", tmp_path), os.path.relpath(EXAMPLE / "arm_cage.obj", tmp_path)
    text = f"""
[defaults]
resolution = 16

[[asset]]
name = "arm_a"
mesh = "{arm}"
cage = "{arm_cage}"
poses = "in/grow.npy"

[[asset]]
name = "arm_b"
mesh = "{arm}"
cage = "{arm_cage}"
poses = "in/grow.npy"
resolution = 20

[[asset]]
name = "open"
mesh = "{arm}"
cage = "in/open_cage.obj"
poses = "in/grow.npy"

[[asset]]
name = "arm_c"
mesh = "{arm}"
cage = "{arm_cage}"
poses = "in/grow.npy"

[[asset]]
name = "short_pose"
mesh = "{arm}"
cage = "{arm_cage}"
poses = "in/short.npy"
"""
    path = tmp_path / "assets.toml"
    path.write_text(text)
    return path


def test_batch_keeps_going_and_reports(manifest, tmp_path, capsys, device):
    out = tmp_path / "out"
    rc = main(["batch", str(manifest), "-o", str(out), "--device", device])
    captured = capsys.readouterr()
    assert rc == 1
    files = sorted(os.listdir(out))
    assert files == ["arm_a.npz", "arm_a.usd", "arm_b.npz", "arm_b.usd", "arm_c.npz", "arm_c.usd", "summary.json"]
    document = json.loads((out / "summary.json").read_text())
    assert document["warp_stokes_version"] == ws.__version__
    summary = {r["name"]: r for r in document["assets"]}
    # what each asset warned of is kept with it (resolution 16 is too coarse for the arm's folded edges)
    assert any("does not yet cut off the thin wedges" in w for w in summary["arm_a"]["warnings"])
    assert [summary[n]["status"] for n in ("arm_a", "arm_b", "open", "arm_c", "short_pose")] == [
        "ok", "ok", "failed", "ok", "failed"]
    assert "open_cage.obj: the cage is not closed" in summary["open"]["error"]
    assert "short.npy: poses must have shape (frames, 58, 3)" in summary["short_pose"]["error"]
    assert summary["arm_b"]["resolution"] == 20 and summary["arm_a"]["handles"] == 58
    assert summary["arm_a"]["vertices"] == 2089
    # the summary lists only what was written
    assert summary["open"]["outputs"] == [] and summary["short_pose"]["outputs"] == []
    assert [os.path.basename(p) for p in summary["arm_b"]["outputs"]] == ["arm_b.npz", "arm_b.usd"]
    # the table and the progress lines
    assert "open" in captured.out and "failed" in captured.out and "3 of 5 assets done, 2 failed" in captured.out
    # how soon and how fast: the failed count as bound (they were tried)
    assert re.search(r"first asset done \d+\.\d s after the start; then \d+ assets a minute \(5 bound\)", captured.out)
    assert "arm_b: binding at resolution 20" in captured.err
    # the warnings at the end name their asset, once per asset (the resolutions 16 and 20 are too coarse for the
    # arm's folded edges; the cage's note on the folds is recorded, not warned of)
    warned = [line for line in captured.err.splitlines() if "does not yet cut off the thin wedges" in line]
    assert sorted(line.split(": ")[1] for line in warned) == ["arm_a", "arm_b", "arm_c"], warned
    # what was written is whole: the bindings load and the USD files hold every frame
    from pxr import Usd, UsdGeom

    b = ws.load_binding(out / "arm_a.npz", device=device)
    stage = Usd.Stage.Open(str(out / "arm_a.usd"))
    assert UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh")).GetPointsAttr().GetTimeSamples() == [1.0, 2.0, 3.0]
    assert b.settings["resolution"] == 16


def test_a_solve_short_of_its_tolerance_is_written_and_one_without_exact_weights_is_not(tmp_path, monkeypatch,
                                                                                        capsys):
    # what bind does: weights exact to 10 tol but a residual float32 cannot bring below tol 1e-9 are written and
    # said so (exit code 1); a solve whose weights break partition of unity fails the asset and writes nothing
    arm, arm_cage = EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj"
    manifest = tmp_path / "m.toml"
    manifest.write_text(f'[[asset]]\nname = "strict"\nmesh = "{arm}"\ncage = "{arm_cage}"\nresolution = 16\n'
                        f'tol = 1e-9\n')
    out = tmp_path / "out"
    rc = main(["batch", str(manifest), "-o", str(out), "--device", "cpu"])
    captured = capsys.readouterr()
    (strict,) = json.loads((out / "summary.json").read_text())["assets"]
    assert rc == 1 and strict["status"] == "not converged" and (out / "strict.npz").exists()
    assert strict["error"].startswith("the solver did not reach tol 1e-09") and strict["outputs"]
    assert "1 written without reaching the solver's tolerance" in captured.out
    assert ws.load_binding(out / "strict.npz").stats.partition_of_unity_error <= 1e-6
    # run again, it is redone and said so again (not skipped as up to date: exit code 0 would hide it)
    assert main(["batch", str(manifest), "-o", str(out), "--device", "cpu"]) == 1
    assert json.loads((out / "summary.json").read_text())["assets"][0]["status"] == "not converged"

    from warp_stokes.solver import solve

    monkeypatch.setattr(solve, "ACCEPTABLE", 1e-3)  # no solve is exact enough: every asset's weights refused
    rc = main(["batch", str(manifest), "-o", str(out), "--device", "cpu", "--force"])
    (strict,) = json.loads((out / "summary.json").read_text())["assets"]
    assert rc == 1 and strict["status"] == "failed" and strict["outputs"] == []
    assert strict["error"].startswith("the solver could not bring partition of unity and linear precision")
    assert sorted(os.listdir(out)) == ["strict.npz", "summary.json"]  # the earlier run's binding, untouched


def test_rerun_skips_up_to_date_assets_unless_forced(manifest, tmp_path, device, monkeypatch):
    out = tmp_path / "out"
    first = {r.name: r.status for r in ws.run_batch(manifest, out, device=device, progress=None)}
    record = {r["name"]: r for r in json.loads((out / "summary.json").read_text())["assets"]}["arm_a"]
    again = {r.name: r.status for r in ws.run_batch(manifest, out, device=device, progress=None)}
    assert again == {"arm_a": "skipped", "arm_b": "skipped", "open": "failed", "arm_c": "skipped",
                     "short_pose": "failed"}
    # a skipped asset keeps the record of the run that wrote its files (it was lost: vertices null, no warnings)
    kept = {r["name"]: r for r in json.loads((out / "summary.json").read_text())["assets"]}["arm_a"]
    assert kept["status"] == "skipped" and record["status"] == "ok"
    assert {k: kept[k] for k in ("vertices", "handles", "seconds", "warnings", "pid", "device")} == {
        k: record[k] for k in ("vertices", "handles", "seconds", "warnings", "pid", "device")}
    assert kept["vertices"] == 2089 and kept["warnings"]
    assert first["arm_a"] == "ok"
    # a touched input is not a changed one (what an asset read is compared by contents): still up to date
    future = os.path.getmtime(out / "arm_a.npz") + 10
    os.utime(tmp_path / "in" / "grow.npy", (future, future))
    os.utime(manifest, (future, future))
    touched = {r.name: r.status for r in ws.run_batch(manifest, out, device=device, progress=None)}
    assert touched["arm_a"] == "skipped" and touched["arm_b"] == "skipped"
    # new contents redo every asset that reads them
    poses = np.load(tmp_path / "in" / "grow.npy")
    np.save(tmp_path / "in" / "grow.npy", poses * 1.001)
    redone = {r.name: r.status for r in ws.run_batch(manifest, out, device=device, progress=None)}
    assert redone["arm_a"] == "ok" and redone["arm_c"] == "ok"
    forced = {r.name: r.status for r in ws.run_batch(manifest, out, force=True, device=device, progress=None)}
    assert forced["arm_b"] == "ok"
    # a changed setting in the manifest redoes its asset, not the others
    manifest.write_text(manifest.read_text().replace("resolution = 20", "resolution = 18"))
    changed = {r.name: r.status for r in ws.run_batch(manifest, out, device=device, progress=None)}
    assert changed["arm_b"] == "ok" and changed["arm_a"] == "skipped"
    assert ws.load_binding(out / "arm_b.npz").settings["resolution"] == 18
    # outputs of another version of warp-stokes (other weights, possibly) are redone too
    assert ws.load_binding(out / "arm_b.npz").settings["warp_stokes_version"] == ws.__version__
    from warp_stokes.batch import asset as batch_asset

    monkeypatch.setattr(batch_asset, "__version__", "0.0.1")
    older = {r.name: r.status for r in ws.run_batch(manifest, out, device=device, progress=None)}
    assert older["arm_b"] == "ok" and older["arm_a"] == "ok"


def test_json_manifest_and_manifest_errors(tmp_path, device):
    good = {"assets": [{"mesh": str(EXAMPLE / "arm.obj"), "cage": str(EXAMPLE / "arm_cage.obj"),
                        "resolution": 16}]}
    (tmp_path / "m.json").write_text(json.dumps(good))
    assets = ws.read_manifest(tmp_path / "m.json")
    assert assets[0].name == "arm" and assets[0].poses is None
    results = ws.run_batch(tmp_path / "m.json", tmp_path / "out", device=device, progress=None)
    assert [r.status for r in results] == ["ok"] and sorted(os.listdir(tmp_path / "out")) == ["arm.npz",
                                                                                              "summary.json"]
    bad = {"assets": [{"mesh": "a.obj", "cage": "b.obj", "colour": "red"}]}
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    with pytest.raises(ws.WarpStokesError, match=r"bad.json: asset 1: unknown key\(s\) \['colour'\]"):
        ws.read_manifest(tmp_path / "bad.json")
    (tmp_path / "twice.toml").write_text('[[asset]]\nmesh = "a.obj"\ncage = "c.obj"\n[[asset]]\nmesh = "a.obj"\n'
                                         'cage = "d.obj"\n')
    with pytest.raises(ws.WarpStokesError, match="the name 'a' is used twice"):
        ws.read_manifest(tmp_path / "twice.toml")
    (tmp_path / "types.toml").write_text('defaults = 3\n[[asset]]\nmesh = "a.obj"\ncage = "c.obj"\n')
    with pytest.raises(ws.WarpStokesError, match="'defaults' must be a table"):
        ws.read_manifest(tmp_path / "types.toml")
    (tmp_path / "types2.toml").write_text('[[asset]]\nmesh = "a.obj"\ncage = "c.obj"\nposes = 3\nresolution = "64"\n')
    with pytest.raises(ws.WarpStokesError, match="asset 1: 'poses' must be a path"):
        ws.read_manifest(tmp_path / "types2.toml")
    (tmp_path / "broken.toml").write_text("[[asset]\n")
    rc = main(["batch", str(tmp_path / "broken.toml"), "-o", str(tmp_path / "o2")])
    assert rc == 2


def test_a_second_batch_refuses_a_folder_in_use_and_stale_files_are_cleaned(manifest, tmp_path):
    import subprocess
    import sys

    # batches on the CPU: the locks and files are the subject, not the device
    out = tmp_path / "out"
    out.mkdir()
    # a live process holds the lock: the batch (the command line, in process) refuses the folder, one line, exit 2,
    # nothing written
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / ".warp-stokes.lock").write_text(str(holder.pid))
        proc = cli("batch", manifest, "-o", out, "--device", "cpu")
        assert proc.returncode == 2
        assert proc.stderr.strip().splitlines() == [
            f"warp-stokes: error: {out}: another batch (pid {holder.pid}) is writing to this folder; wait for it to "
            f"finish (or remove {out / '.warp-stokes.lock'} if that process is not a warp-stokes batch)"]
        assert sorted(os.listdir(out)) == [".warp-stokes.lock"]
    finally:
        holder.kill()
        holder.wait()
    # the holder is gone (a killed batch): its lock and half-written temporary files are cleared, the run completes
    from warp_stokes.io.outputs import host_name

    (out / f".wst~{holder.pid}~{host_name()}~0a1b2c3d~arm_a.usd").write_text("half")
    (out / ".tmp-arm_a.usd").write_text("a file of the user's, in no pattern of warp-stokes")
    (out / "arm_a.npz").write_text("a binding without its USD, from a killed run")
    results = {r.name: r.status for r in ws.run_batch(manifest, out, device="cpu", progress=None)}
    assert results["arm_a"] == "ok" and results["arm_c"] == "ok"
    assert sorted(os.listdir(out)) == [".tmp-arm_a.usd", "arm_a.npz", "arm_a.usd", "arm_b.npz", "arm_b.usd",
                                       "arm_c.npz", "arm_c.usd", "summary.json"]
    assert ws.load_binding(out / "arm_a.npz", device="cpu").n_handles == 58


def test_the_compile_notice_comes_once_the_folder_is_ours(manifest, tmp_path, monkeypatch):
    import io
    import subprocess
    import sys

    import warp_stokes.kernel_cache as device

    monkeypatch.setattr(device, "missing_kernels", lambda d=None, modules=(): list(modules))  # as on a fresh machine
    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        (out / ".warp-stokes.lock").write_text(str(holder.pid))
        stream = io.StringIO()
        with pytest.raises(ws.WarpStokesError, match="another batch"):
            ws.run_batch(manifest, out, device="cpu", progress=stream)
        assert stream.getvalue() == ""  # a refused folder: no promise of work
    finally:
        holder.kill()
        holder.wait()
    stream = io.StringIO()
    ws.run_batch(manifest, out, device="cpu", progress=stream)
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith("warp-stokes: compiling the kernels for cpu (first run on this machine")
    assert sum("compiling the kernels" in line for line in lines) == 1
    # a rerun with every asset up to date binds nothing: no notice
    only_good = tmp_path / "good.json"
    only_good.write_text(json.dumps({"assets": [{"mesh": str(EXAMPLE / "arm.obj"), "cage": str(EXAMPLE / "arm_cage.obj"),
                                                 "resolution": 16}]}))
    for expected in ("compiling", "skipped"):
        stream = io.StringIO()
        ws.run_batch(only_good, tmp_path / "good", device="cpu", progress=stream)
        assert expected in stream.getvalue() and ("compiling" in stream.getvalue()) == (expected == "compiling")


def test_a_batch_killed_with_sigkill_is_completed_by_the_next_run(manifest, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    # a batch as a user runs it, in a subprocess on the CPU: what a kill leaves is the subject, not the device
    command = [sys.executable, "-m", "warp_stokes.cli", "batch", str(manifest), "-o", str(out), "--device", "cpu"]
    first = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    # killed once its first asset is being bound: whatever it leaves (a lock, temporary files, some assets)
    deadline = time.time() + 120
    while time.time() < deadline and first.poll() is None:
        if (out / ".warp-stokes.lock").exists() and "binding at resolution" in (first.stderr.readline() or ""):
            break
    first.send_signal(signal.SIGKILL)
    first.wait()
    left = set(os.listdir(out))
    assert {name for name in left if not name.startswith(".")} <= {"arm_a.npz", "arm_a.usd", "arm_b.npz", "arm_b.usd"}
    # each asset whole or missing: never a binding without its USD
    assert all((name.replace(".npz", ".usd") in left) for name in left if name.endswith(".npz"))

    again = cli(*command[3:])  # the next run, in process
    assert again.returncode == 1  # the manifest's two bad assets fail; the rest completes
    assert sorted(os.listdir(out)) == ["arm_a.npz", "arm_a.usd", "arm_b.npz", "arm_b.usd", "arm_c.npz", "arm_c.usd",
                                       "summary.json"]
    statuses = {a["name"]: a["status"] for a in json.loads((out / "summary.json").read_text())["assets"]}
    assert statuses["arm_c"] == "ok" and statuses["open"] == "failed"


def test_usd_assets_in_a_manifest(tmp_path, device):
    from pxr import Sdf, Usd, UsdGeom

    from usd_assets import BAND, CAGE, TIMES, write_asset

    mesh, cage = ws.load_surface(EXAMPLE / "arm.obj"), ws.load_surface(EXAMPLE / "arm_cage.obj")
    diagonal = float(np.linalg.norm(np.ptp(cage.vertices, axis=0)))
    (tmp_path / "assets").mkdir()
    write_asset(tmp_path / "assets" / "char.usda", mesh, cage, cage.vertices.mean(axis=0), 0.03 * diagonal)
    (tmp_path / "batch.toml").write_text(f"""
[[asset]]
name = "char"
mesh = "assets/char.usda"
cage_prim = "{CAGE}"
poses = "assets/char.usda"
resolution = 16

[[asset]]
name = "band_only"
mesh = "assets/char.usda"
cage = "assets/char.usda"
cage_prim = "{CAGE}"
mesh_prims = ["{BAND}"]
resolution = 16

[[asset]]
name = "wrong_prim"
mesh = "assets/char.usda"
cage_prim = "/Char/Nope"
resolution = 16
""")
    rc = main(["batch", str(tmp_path / "batch.toml"), "-o", str(tmp_path / "out"), "--device", device])
    assert rc == 1
    summary = {a["name"]: a for a in json.loads((tmp_path / "out" / "summary.json").read_text())["assets"]}
    assert summary["char"]["status"] == "ok" and summary["band_only"]["status"] == "ok"
    assert summary["wrong_prim"]["status"] == "failed" and "no prim /Char/Nope" in summary["wrong_prim"]["error"]
    assert ws.load_binding(tmp_path / "out" / "band_only.npz").parts[0]["path"] == BAND
    layer = Sdf.Layer.FindOrOpen(str(tmp_path / "out" / "char.usd"))
    assert list(layer.subLayerPaths) == ["../assets/char.usda"]
    stage = Usd.Stage.Open(layer)
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetStartTimeCode() == TIMES[0]
    assert UsdGeom.Mesh(stage.GetPrimAtPath(BAND)).GetPointsAttr().GetTimeSamples() == list(TIMES)
    with pytest.raises(ws.WarpStokesError, match=r"'cage' \(a path, or \"auto\" to make one\) or 'cage_prim'"):
        (tmp_path / "bad.toml").write_text('[[asset]]\nmesh = "assets/char.usda"\n')
        ws.read_manifest(tmp_path / "bad.toml")
