"""``warp-stokes encode`` of a rigged character, as a user runs it: the Fox's Walk encoded with a cage made for it
(``encode auto``, the real command), then with that binding given (``encode B.npz Fox.glb``), a UsdSkel asset, and
the one-line errors of a wrong animation name or options that do not fit the input."""

from __future__ import annotations

import re

import numpy as np
import pytest

import warp_stokes as ws
from conftest import DATA, warp_stokes
from rigged_assets import write_usd_skel
from warp_stokes.cli import main

FOX = DATA / "fox_gltf" / "Fox.glb"
ERROR = re.compile(r"RMS error over the cage's diagonal: mean (\S+), max (\S+) \(frame \S+\); largest vertex error "
                   r"(\S+) \(frame \S+\)")


@pytest.fixture(scope="module")
def fox_walk(tmp_path_factory):
    """``warp-stokes encode auto Fox.glb --animation Walk`` (a subprocess, on the CPU at resolution 16): its run
    and the folder it wrote in."""
    if not FOX.exists():
        pytest.skip(f"test data not found: {FOX} (set WARP_STOKES_DATA)")
    folder = tmp_path_factory.mktemp("x")
    proc = warp_stokes("encode", "auto", str(FOX), "--animation", "Walk", "-o", str(folder / "fox_walk.npy"),
                       "--resolution", "16", "--device", "cpu")
    return proc, folder


def test_encode_auto_of_the_fox_walk_runs_and_prints_its_error(fox_walk):
    proc, folder = fox_walk
    assert proc.returncode == 0, proc.stderr
    assert "18 cage poses of" in proc.stdout and "Fox.glb:Walk" in proc.stdout
    rms, worst, largest = (float(x) for x in ERROR.search(proc.stdout).groups())
    assert 0 < rms <= worst <= largest < 0.1  # the Fox's walk, carried by a cage of ~100 handles
    poses = np.load(folder / "fox_walk.npy")
    binding = ws.load_binding(folder / "fox_walk.binding.npz")
    assert poses.shape == (18, binding.n_handles, 3) and binding.n_vertices == 1728
    assert (folder / "fox_walk.cage.obj").is_file()


def test_encode_with_the_binding_given_takes_the_glb_as_its_frames(fox_walk, tmp_path, capsys):
    _, folder = fox_walk
    binding = str(folder / "fox_walk.binding.npz")
    out = tmp_path / "walk.usda"
    assert main(["encode", binding, str(FOX), "--animation", "Walk", "-o", str(out), "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "18 cage poses" in printed and ERROR.search(printed)
    poses = ws.load_poses(out, ws.load_binding(binding).cage_faces)
    assert poses.frames.tolist() == list(range(18)) and poses.time_codes_per_second == 24  # 24 fps keys: frames
    # sampled at a rate instead of at the keys: 0 to 17/24 s every 1/48 s
    assert main(["encode", binding, str(FOX), "--animation", "Walk", "--fps", "48", "-o", str(tmp_path / "w.npy"),
                 "--device", "cpu"]) == 0
    assert np.load(tmp_path / "w.npy").shape[0] == 35


def test_a_wrong_animation_name_is_one_line_listing_the_animations(fox_walk, tmp_path, capsys):
    _, folder = fox_walk
    binding = str(folder / "fox_walk.binding.npz")
    for extra, expected in ((["--animation", "Jump"], "no animation 'Jump'; its animations: Survey, Walk, Run"),
                            ([], "3 animations (Survey, Walk, Run); name one (--animation)")):
        assert main(["encode", binding, str(FOX), *extra, "-o", str(tmp_path / "p.npy")]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and expected in err and "Fox.glb" in err
    assert not (tmp_path / "p.npy").exists()


def test_options_that_do_not_fit_the_input_are_refused(arm_npz, tmp_path, capsys):
    frames = tmp_path / "frames.npy"
    np.save(frames, np.zeros((2, ws.load_binding(arm_npz).n_vertices, 3)))
    assert main(["encode", str(arm_npz), str(frames), "--animation", "Walk", "-o", str(tmp_path / "p.npy")]) == 2
    assert "an animation and its rate are read from a rigged glTF/GLB or USD file" in capsys.readouterr().err
    assert main(["encode", str(arm_npz), str(frames), "--resolution", "16", "-o", str(tmp_path / "p.npy")]) == 2
    assert "--resolution is the resolution of the bind 'encode auto' makes" in capsys.readouterr().err


def test_encode_auto_of_a_usdskel_asset(tmp_path, capsys):
    asset = write_usd_skel(tmp_path / "char.usda")
    out = tmp_path / "char_poses.npy"
    assert main(["encode", "auto", asset, "--animation", "Twist", "-o", str(out), "--resolution", "16",
                 "--device", "cpu"]) == 0
    printed = capsys.readouterr().out
    assert "7 cage poses" in printed  # the joints keyed every 2 time codes, the blend shape and the prop at 5
    rms = float(ERROR.search(printed).group(1))
    assert rms < 0.05
