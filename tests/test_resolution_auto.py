"""resolution="auto" (the default): a grid that fits the cage, capped per device, said in the stats and the table."""

import json
import warnings

import pytest

import warp_stokes as ws
from conftest import EXAMPLE, cli, one_error_line, warp_stokes
from warp_stokes.binding.stats import ResolutionChoice
from warp_stokes.geometry import grid as grid_module
from warp_stokes.geometry import resolution as resolution_module


def test_auto_resolution_resolves_the_arms_folded_edges_within_the_cap():
    cage = ws.check_cage(EXAMPLE / "arm_cage.obj")
    needed = resolution_module.wedge_resolution(cage, device="cpu")
    assert needed is not None and needed > resolution_module.AUTO_RESOLUTION  # the arm's cage folds back at 4 edges
    cap = resolution_module.AUTO_RESOLUTION_CAP["cpu"]
    assert resolution_module.auto_resolution(cage, device="cpu") == (needed, needed, cap)
    import trimesh

    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])  # no folded edge: the least resolution
    assert resolution_module.auto_resolution(ws.check_cage((box.vertices, box.faces)), device="cpu")[0] == 64
    assert resolution_module.auto_resolution(cage, boundary="mvc", device="cpu")[0] == 64  # MVC cuts nothing off
    for bad in ("fine", 4, 4096, 64.0, True):
        with pytest.raises(ws.ResolutionError, match="resolution must be"):
            resolution_module.check_resolution(bad)


def test_the_bundled_example_binds_by_default_without_a_warning(tmp_path):
    """The README's command, as a subprocess: no warning, and the table says which resolution auto chose."""
    proc = warp_stokes("bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(tmp_path / "arm.npz"),
                       "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    assert "warning" not in proc.stderr.lower(), proc.stderr
    needed = resolution_module.wedge_resolution(ws.check_cage(EXAMPLE / "arm_cage.obj"), device="cpu")
    assert f"resolution {needed}, auto: the cage's folded edges need {needed}" in proc.stdout
    b = ws.load_binding(tmp_path / "arm.npz", device="cpu")
    assert b.settings["resolution"] == needed
    assert b.stats.resolution == ResolutionChoice("auto", chosen=needed, needed=needed,
                                                  cap=resolution_module.AUTO_RESOLUTION_CAP["cpu"])
    # the fold is recorded as a note, not warned of
    assert any("folds back on itself" in note for note in b.stats.warnings)


def test_a_capped_auto_resolution_warns_once_saying_what_to_give(monkeypatch):
    monkeypatch.setattr(resolution_module, "AUTO_RESOLUTION", 16)
    monkeypatch.setattr(resolution_module, "AUTO_RESOLUTION_CAP", {"cpu": 24, "cuda": 24})
    needed = resolution_module.wedge_resolution(ws.check_cage(EXAMPLE / "arm_cage.obj"), device="cpu")
    with pytest.warns(UserWarning) as caught:
        b = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", device="cpu")
    folded = [str(w.message) for w in caught if "folded edges" in str(w.message)]
    assert len(folded) == 1
    assert f"resolution 'auto' stops at 24 on this device; give --resolution {needed}" in folded[0]
    assert b.settings["resolution"] == 24 and b.stats.resolution.needed == needed


def test_the_cap_is_the_solving_devices_and_advice_names_what_auto_cannot_reach(monkeypatch):
    cage = ws.check_cage(EXAMPLE / "arm_cage.obj")
    monkeypatch.setattr(resolution_module, "AUTO_RESOLUTION_CAP", {"cpu": 24, "cuda": 256})
    needed = resolution_module.wedge_resolution(cage, device="cpu")
    # a bind spread over GPUs from a host without one: the GPUs' cap
    assert resolution_module.auto_resolution(cage, device="cpu", kind="cuda") == (needed, needed, 256)
    assert resolution_module.auto_resolution(cage, device="cpu")[0] == 24
    # a number below what the folds need, on a device whose auto cannot reach it either: the number to give
    with pytest.warns(UserWarning) as caught:
        ws.bind(EXAMPLE / "arm.obj", cage, resolution=16, device="cpu")
    folded = [str(w.message) for w in caught if "folded edges" in str(w.message)]
    assert len(folded) == 1 and folded[0].endswith(f"give --resolution {needed} (resolution= in Python)")


def test_a_skipped_asset_keeps_the_resolution_auto_chose(tmp_path, monkeypatch):
    from warp_stokes.cli import main

    monkeypatch.setattr(resolution_module, "AUTO_RESOLUTION", 16)
    monkeypatch.setattr(resolution_module, "AUTO_RESOLUTION_CAP", {"cpu": 16, "cuda": 16})
    manifest = tmp_path / "m.toml"
    manifest.write_text(f'[[assets]]\nname = "arm"\nmesh = "{EXAMPLE / "arm.obj"}"\ncage = "{EXAMPLE / "arm_cage.obj"}"\n')
    for status in ("ok", "skipped"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            assert main(["batch", str(manifest), "-o", str(tmp_path / "out"), "--device", "cpu"]) == 0
        record = json.loads((tmp_path / "out" / "summary.json").read_text())["assets"][0]
        assert (record["status"], record["resolution"]) == (status, 16)


def test_a_manifest_takes_auto_and_refuses_other_words(tmp_path):
    for value, ok in (('"auto"', True), ('"fine"', False), ("64", True)):
        manifest = tmp_path / "m.toml"
        manifest.write_text(f'[defaults]\nresolution = {value}\n\n[[assets]]\nmesh = "{EXAMPLE / "arm.obj"}"\n'
                            f'cage = "{EXAMPLE / "arm_cage.obj"}"\n')
        if ok:
            assets = ws.batch.read_manifest(manifest)
            assert assets[0].resolution == json.loads(value)
        else:
            with pytest.raises(ws.batch.ManifestError, match=r"'resolution' must be \"auto\" or an integer"):
                ws.batch.read_manifest(manifest)


def test_the_command_line_takes_auto_or_a_number(tmp_path):
    proc = cli("bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(tmp_path / "a.npz"),
               "--resolution", "fine")
    assert proc.returncode == 2 and "--resolution: 'fine' is neither auto nor an integer" in one_error_line(proc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert "auto" in cli("bind", "--help").stdout


def test_auto_goes_finer_for_a_cage_too_thin_and_for_the_meshs_thin_parts(monkeypatch):
    """Within the cap: a slab with no node inside at the least resolution, and a dumbbell whose neck's vertices
    fall in cells without an inside node, are bound at a resolution that resolves them, without a warning."""
    import shapes

    monkeypatch.setattr(resolution_module, "AUTO_RESOLUTION", 16)
    monkeypatch.setattr(resolution_module, "AUTO_RESOLUTION_CAP", {"cpu": 64, "cuda": 64})
    slab = shapes.slab_pair(0.05, rotation=None)
    with pytest.raises(ws.ResolutionError, match="no grid node lies inside the cage at resolution 16"):
        ws.bind(slab.mesh, slab.cage, resolution=16, device="cpu")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        b = ws.bind(slab.mesh, slab.cage, device="cpu")
    assert b.settings["resolution"] == b.stats.resolution.chosen == 64
    assert b.stats.partition_of_unity_error < 1e-5
    neck = shapes.dumbbell_pair(0.1, rotation=None)
    with pytest.warns(UserWarning, match="thinner than about two grid cells at resolution 16"):
        ws.bind(neck.mesh, neck.cage, resolution=16, device="cpu")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        b = ws.bind(neck.mesh, neck.cage, device="cpu")
    choice = b.stats.resolution
    assert 16 < choice.chosen == choice.thin_parts <= 64 and b.settings["resolution"] == choice.chosen
    # beyond the cap: the error names a resolution to give
    with pytest.raises(ws.ResolutionError, match="no grid node lies inside the cage at resolution 64 .* try resolution 256"):
        ws.bind(shapes.slab_pair(0.01, rotation=None).mesh, shapes.slab_pair(0.01, rotation=None).cage, device="cpu")


def _one_handle_bytes(cage, n_vertices, resolution):
    """What the memory plan asks for to solve one handle (with the columns that check it) at ``resolution``."""
    from warp_stokes.geometry.boundary import COMPLEMENT_COLUMNS
    from warp_stokes.geometry.local_data import local_data_bytes
    from warp_stokes.solver.budget import estimate_memory
    from warp_stokes.solver.hierarchy import coarsen

    grid = grid_module.voxelize(cage, resolution, device="cpu")
    estimate = estimate_memory(grid, n_vertices, levels=coarsen(grid, "cpu"), device="cpu",
                               n_handles=cage.n_handles, boundary_bytes=local_data_bytes(cage))
    return estimate.total(1 + COMPLEMENT_COLUMNS)


def test_auto_binds_at_the_finest_grid_the_memory_budget_holds_and_says_so_once(arm_cage):
    """A budget too small for the resolution auto wants: a coarser grid that fits (never a refusal while one at 16 or
    more does), one warning naming the budget, what the cage asks for and why, recorded in the stats."""
    mesh = ws.load_surface(EXAMPLE / "arm.obj")
    needed = resolution_module.wedge_resolution(arm_cage, device="cpu")
    one_handle = {n: _one_handle_bytes(arm_cage, len(mesh.vertices), n) for n in (24, 32)}
    assert one_handle[24] < one_handle[32]
    budget = (one_handle[24] + one_handle[32]) // 2
    with pytest.raises(ws.ResolutionError, match=f"resolution {needed} .* MiB .* or less would fit"):
        ws.bind(mesh, arm_cage, resolution=needed, device="cpu", memory_budget=budget)
    with pytest.warns(UserWarning) as caught:
        b = ws.bind(mesh, arm_cage, device="cpu", memory_budget=budget)
    said = [str(w.message) for w in caught]
    assert len(said) == 1, said
    choice = b.stats.resolution
    assert 24 <= choice.chosen == choice.memory_fits == b.settings["resolution"] < 32
    assert choice.needed == needed and choice.memory_budget_bytes == budget
    assert _one_handle_bytes(arm_cage, len(mesh.vertices), choice.chosen) <= budget
    assert b.stats.memory_estimate_bytes <= budget
    assert (f"resolution 'auto' bound at {choice.chosen}, the finest grid that fits the memory budget "
            f"({budget / 2**20:.1f} MiB); the cage asks for {needed} (its folded edges need resolution {needed})"
            in said[0] and "--memory-gb" in said[0])
    assert said[0] in b.stats.warnings  # recorded with the binding
    assert b.stats.partition_of_unity_error < 1e-5
    # no grid of 16 or more fits: the budget's own error, naming what would be needed
    with pytest.raises(ws.ResolutionError, match="memory budget"):
        ws.bind(mesh, arm_cage, device="cpu", memory_budget=_one_handle_bytes(arm_cage, len(mesh.vertices), 16) - 1)
