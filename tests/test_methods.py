"""bind(method=...): Stokes, harmonic and mean value coordinates through the same Binding, and every command that
takes a binding working with each (the command line in process, ``main(argv)``)."""

import json
import warnings

import numpy as np
import pytest
from pxr import Usd, UsdGeom

import warp_stokes as ws
from conftest import EXAMPLE, cli, float32_rounding

MESH, CAGE = EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj"


@pytest.fixture(scope="module")
def bindings():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the arm's cage has folded edges (a warning, checked elsewhere)
        return {m: ws.bind(MESH, CAGE, resolution=16, device="cpu", method=m) for m in ("stokes", "harmonic", "mvc")}


def test_every_method_gives_exact_cage_coordinates(bindings):
    cage = ws.check_cage(CAGE)
    for method, binding in bindings.items():
        w = binding.weights.astype(np.float64)
        assert binding.settings["method"] == method and binding.stats.method == method
        assert np.abs(w.sum(axis=1) - 1).max() <= 1e-5, method
        assert np.linalg.norm(w @ cage.vertices - binding.mesh_vertices, axis=1).max() <= 1e-5 * cage.diagonal
        assert binding.stats.converged
    # three different fields
    for a, b in (("stokes", "harmonic"), ("stokes", "mvc"), ("harmonic", "mvc")):
        assert np.abs(bindings[a].weights - bindings[b].weights).max() > 1e-2, (a, b)


def test_mvc_binding_is_mean_value_coordinates_at_the_vertices(bindings):
    binding = bindings["mvc"]
    direct = ws.mean_value_coordinates(ws.check_cage(CAGE), binding.mesh_vertices, device="cpu")
    # the float64 coordinates stored as float32: one rounding (half an eps) of each
    assert np.abs(binding.weights - direct).max() <= float32_rounding(np.abs(direct).max(), 1)
    assert binding.settings["resolution"] is None and binding.stats.grid is None and binding.stats.solver is None
    assert "mean value coordinates" in repr(binding)


def test_harmonic_binding_samples_the_harmonic_solve(bindings):
    """The harmonic binding's weights at the vertices against the solver's own nodal solution, sampled
    independently: trilinear interpolation of the node values by numpy."""
    from test_solve import to_dense

    cage = ws.check_cage(CAGE)
    grid = ws.voxelize(cage, 16, device="cpu")
    field = ws.boundary_field(grid, cage, device="cpu", data="local")  # bind's default data
    ws.solve_biharmonic(grid, field, handles=cage.vertices, device="cpu", equation="laplace")
    q = to_dense(grid, field, np.zeros(grid.shape + (cage.n_handles, 4)))[..., 0]
    trilinear = ws.bind(MESH, CAGE, resolution=16, device="cpu", method="harmonic", sampling="trilinear")
    cell = (trilinear.mesh_vertices - grid.centre - grid.origin) / grid.spacing
    base = np.floor(cell).astype(int)
    frac = cell - base
    expected = np.zeros_like(trilinear.weights, dtype=np.float64)
    for corner in np.ndindex(2, 2, 2):
        weight = np.prod(np.where(np.array(corner) == 1, frac, 1 - frac), axis=1)
        expected += weight[:, None] * q[tuple((base + corner).T)]
    assert np.abs(trilinear.weights - expected).max() <= 1e-5


def test_unknown_method_is_one_error():
    with pytest.raises(ws.WarpStokesError, match="method must be 'stokes', 'harmonic' or 'mvc'"):
        ws.bind(MESH, CAGE, resolution=8, device="cpu", method="laplace")


@pytest.mark.parametrize("method", ["harmonic", "mvc"])
def test_commands_take_bindings_of_every_method(method, tmp_path):
    out = tmp_path / f"arm_{method}.npz"
    run = cli("bind", MESH, CAGE, "--method", method, "--resolution", "16", "-o", out, "--device", "cpu")
    assert run.returncode == 0, run.stderr
    assert ("harmonic coordinates" if method == "harmonic" else "mean value coordinates") in run.stdout
    binding = ws.load_binding(out, device="cpu")
    assert binding.settings["method"] == method
    poses = np.load(EXAMPLE / "bend_poses.npy")
    np.save(tmp_path / "pose.npy", poses[-1])
    run = cli("deform", out, tmp_path / "pose.npy", "-o", tmp_path / "d.obj")
    assert run.returncode == 0, run.stderr
    import trimesh

    deformed = trimesh.load(tmp_path / "d.obj", process=False)
    assert np.abs(deformed.vertices - binding.deform(poses[-1])).max() <= 1e-4
    run = cli("animate", out, EXAMPLE / "bend_poses.npy", "-o", tmp_path / "a.usda")
    assert run.returncode == 0, run.stderr
    stage = Usd.Stage.Open(str(tmp_path / "a.usda"))
    mesh = next(UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    times = mesh.GetPointsAttr().GetTimeSamples()
    assert np.abs(np.array(mesh.GetPointsAttr().Get(times[-1])) - binding.deform(poses[-1])).max() <= 1e-4
    frames = tmp_path / "frames.npy"
    np.save(frames, binding.deform(poses[:5]))
    run = cli("encode", out, frames, "-o", tmp_path / "enc.npy")
    assert run.returncode == 0, run.stderr
    diagonal = ws.check_cage(CAGE).diagonal
    assert np.abs(np.load(tmp_path / "enc.npy") - poses[:5]).max() <= 1e-3 * diagonal


def test_manifest_method_key(tmp_path):
    manifest = {"assets": [{"mesh": str(MESH), "cage": str(CAGE), "resolution": 12, "method": "harmonic"},
                           {"name": "arm_mvc", "mesh": str(MESH), "cage": str(CAGE), "method": "mvc"}]}
    (tmp_path / "m.json").write_text(json.dumps(manifest))
    results = ws.run_batch(tmp_path / "m.json", tmp_path / "out", device="cpu", progress=None)
    assert [r.status for r in results] == ["ok", "ok"]
    assert ws.load_binding(tmp_path / "out" / "arm.npz").settings["method"] == "harmonic"
    assert ws.load_binding(tmp_path / "out" / "arm_mvc.npz").settings["method"] == "mvc"
    manifest["assets"][0]["method"] = "blender"
    (tmp_path / "bad.json").write_text(json.dumps(manifest))
    with pytest.raises(ws.WarpStokesError, match="'method' must be"):
        ws.read_manifest(tmp_path / "bad.json")
