"""Nothing a user owns is ever overwritten (issue 30, data loss): a batch's outputs never replace its inputs (files,
the manifest, the layers a USD asset is made of), animate never writes over a layer of its asset, an output that
is not a regular file (a device, a pipe, a link to one) is refused, and a save killed with SIGKILL leaves nothing
that a later save does not remove. Each case runs the command line, in process (``main(argv)``, its output
captured) where a fresh process adds nothing, as a subprocess where another process is the subject."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from conftest import EXAMPLE, cli, one_error_line, warp_stokes
from warp_stokes.io.outputs import host_name, is_temporary

MESH, CAGE = str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj")


def digest(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def test_a_batch_never_writes_over_its_inputs(tmp_path):
    # an asset named like its USD file, written into that file's folder; a poses file where a binding would go;
    # a JSON manifest named summary.json in the output folder: each refused before any work, the file untouched
    assets = tmp_path / "assets"
    assets.mkdir()
    shutil.copy(EXAMPLE / "arm.usda", assets / "hero.usd")
    (assets / "hero.toml").write_text('[[asset]]\nname = "hero"\nmesh = "hero.usd"\ncage_prim = "/Arm/Rig/Cage"\n'
                                      'poses = "hero.usd"\nresolution = 16\n')
    before = digest(assets / "hero.usd")
    proc = cli("batch", str(assets / "hero.toml"), "-o", str(assets), "--device", "cpu")
    assert proc.returncode == 2
    assert one_error_line(proc) == (f"warp-stokes: error: {assets / 'hero.usd'}: asset 'hero''s output would replace "
                                    f"the mesh of asset 'hero' {assets / 'hero.usd'}; write the batch to another "
                                    "folder or rename the asset")
    assert digest(assets / "hero.usd") == before and not (assets / "hero.npz").exists()

    out = tmp_path / "out"
    out.mkdir()
    shutil.copy(EXAMPLE / "bend_poses.npy", out / "armp.npz")  # poses saved where the binding would be written
    manifest = tmp_path / "m.toml"
    manifest.write_text(f'[[asset]]\nname = "armp"\nmesh = "{MESH}"\ncage = "{CAGE}"\nposes = "out/armp.npz"\n')
    before = digest(out / "armp.npz")
    proc = cli("batch", str(manifest), "-o", str(out), "--device", "cpu")
    assert proc.returncode == 2 and "would replace the poses of asset 'armp'" in one_error_line(proc)
    assert digest(out / "armp.npz") == before

    summary = out / "summary.json"
    summary.write_text(json.dumps({"assets": [{"name": "a", "mesh": MESH, "cage": CAGE, "resolution": 16}]}))
    proc = cli("batch", str(summary), "-o", str(out), "--device", "cpu")
    assert proc.returncode == 2 and "the batch's summary would replace the manifest" in one_error_line(proc)
    assert json.loads(summary.read_text())["assets"][0]["name"] == "a"


def test_animate_never_writes_over_a_layer_of_its_asset(tmp_path):
    # root.usda sublayers ./arm.usda, which holds the geometry: -o arm.usda is refused (the check covers the
    # asset's whole layer stack, not its root file only), and the layer is left as it was
    shutil.copy(EXAMPLE / "arm.usda", tmp_path / "arm.usda")
    (tmp_path / "root.usda").write_text('#usda 1.0\n(\n    subLayers = [@./arm.usda@]\n)\n')
    binding = tmp_path / "r.npz"
    proc = cli("bind", str(tmp_path / "root.usda"), "--cage-prim", "/Arm/Rig/Cage", "-o", str(binding), "--resolution",
               "16", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    before = digest(tmp_path / "arm.usda")
    proc = cli("animate", str(binding), str(tmp_path / "root.usda"), "--cage-prim", "/Arm/Rig/Cage", "-o",
               str(tmp_path / "arm.usda"), "--device", "cpu")
    assert proc.returncode == 2
    # (the binding records the layers it was bound from: it names one of its sources)
    assert one_error_line(proc) == (f"warp-stokes: error: {tmp_path / 'arm.usda'}: the output would replace a source "
                                    f"of the input {binding} ({tmp_path / 'arm.usda'}); choose another output")
    # a binding that records no sources (written before it did): the layer stack of the poses' USD file says it
    import numpy as np

    with np.load(binding) as data:
        arrays = dict(data)
    meta = json.loads(str(arrays["meta"]))
    del meta["sources"]
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "old.npz", **arrays)
    proc = cli("animate", str(tmp_path / "old.npz"), str(tmp_path / "root.usda"), "--cage-prim", "/Arm/Rig/Cage", "-o",
               str(tmp_path / "arm.usda"), "--device", "cpu")
    assert proc.returncode == 2
    assert one_error_line(proc) == (f"warp-stokes: error: {tmp_path / 'arm.usda'}: the output would replace a layer "
                                    f"of the input {tmp_path / 'root.usda'} ({tmp_path / 'arm.usda'}); choose another "
                                    "output")
    assert digest(tmp_path / "arm.usda") == before


@pytest.mark.parametrize("kind", ["fifo", "link to /dev/null", "dangling link"])
def test_an_output_that_is_not_a_regular_file_is_refused(tmp_path, kind):
    target = tmp_path / "out.npz"
    if kind == "fifo":
        os.mkfifo(target)
        expected = "the output exists and is not a regular file (a pipe)"
    elif kind == "link to /dev/null":
        os.symlink("/dev/null", target)
        expected = "the output exists and is not a regular file (a character device)"
    else:
        os.symlink(tmp_path / "nowhere", target)
        expected = "the output is a link to nothing"
    proc = cli("bind", MESH, CAGE, "-o", str(target), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 2 and one_error_line(proc).startswith(f"warp-stokes: error: {target}: {expected}")
    if kind == "fifo":
        assert os.path.exists(target) and not os.path.isfile(target) and not os.path.islink(target)
    else:
        assert os.path.islink(target)
    assert os.path.exists("/dev/null") and not os.path.isfile("/dev/null")


def test_the_temporary_file_of_a_killed_save_is_removed_by_the_next(tmp_path):
    # a bind killed with SIGKILL while it saves leaves its temporary file (nothing can remove it then): the next
    # save of the same output removes what a dead process of this host left, never a live one's
    out = tmp_path / "arm.npz"
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    host = host_name()
    stale = tmp_path / f".wst~{dead.pid}~{host}~0a1b2c3d~arm.npz"
    live = tmp_path / f".wst~{os.getpid()}~{host}~4e5f6a7b~arm.npz"
    other = tmp_path / f".wst~{dead.pid}~{host}~8c9d0e1f~other.npz"
    elsewhere = tmp_path / f".wst~{dead.pid}~another-host~8c9d0e1f~arm.npz"
    notes = tmp_path / ".tmp-notes.txt"  # the user's, in no pattern of the package's
    for path in (stale, live, other, elsewhere, notes):
        path.write_bytes(b"half a binding")
    # in a process of its own, as a user runs it: the live pid above (this one's) is then another process's
    proc = warp_stokes("bind", MESH, CAGE, "-o", str(out), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    assert not stale.exists() and not other.exists() and out.exists()
    assert live.exists() and elsewhere.exists() and notes.exists()
    # and a real kill: SIGKILL in the middle of a save, then a bind of the same output cleans up
    script = ("import os, signal, sys, numpy as np, warp_stokes as ws\n"
              "b = ws.bind(sys.argv[1], sys.argv[2], resolution=16, device='cpu')\n"
              "real = np.savez\n"
              "def killed(*args, **kw):\n"
              "    real(*args, **kw)\n"
              "    os.kill(os.getpid(), signal.SIGKILL)\n"
              "np.savez = np.savez_compressed = killed\n"
              "b.save(sys.argv[3])\n")
    victim = subprocess.run([sys.executable, "-c", script, MESH, CAGE, str(tmp_path / "k.npz")], capture_output=True)
    assert victim.returncode == -signal.SIGKILL
    left = [p for p in os.listdir(tmp_path) if is_temporary(p) and p.endswith("~k.npz")]
    assert len(left) == 1 and not (tmp_path / "k.npz").exists()
    time.sleep(0.1)
    proc = cli("bind", MESH, CAGE, "-o", str(tmp_path / "k.npz"), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 0 and not [p for p in os.listdir(tmp_path) if p.endswith("~k.npz")]


def test_a_binding_carries_its_format_s_extension(tmp_path):
    # bind -o x.obj wrote the .npz binding under an OBJ name, which mesh readers then took for an empty scene
    proc = cli("bind", MESH, CAGE, "-o", str(tmp_path / "x.obj"), "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 2
    assert one_error_line(proc) == f"warp-stokes: error: {tmp_path / 'x.obj'}: a binding is written as .npz"
    assert os.listdir(tmp_path) == []
