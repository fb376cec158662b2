"""One bind spread over several devices (Ray tasks, each a share of the handles): on the CPU here, two worker
processes standing for two GPUs. The weights against a bind on one device, the command as a user runs it (it starts
its own Ray cluster), the benchmark, and the one-line errors. Few: each start of Ray takes seconds on 2 cores, so the
binds in this process and the benchmark join the session's cluster (tests/conftest.py: ray_cluster)."""

import os
import subprocess
import sys

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, cli
from warp_stokes.binding.spread import spread_devices

ARM, ARM_CAGE = EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj"


def bind_command(*args, env=None):
    return subprocess.run([sys.executable, "-m", "warp_stokes.cli", "bind", str(ARM), str(ARM_CAGE), *map(str, args)],
                          capture_output=True, text=True, env={**os.environ, **(env or {})}, timeout=600)


def test_device_lists_name_a_spread_bind():
    assert spread_devices("cuda:0,cuda:1") == ["cuda:0", "cuda:1"]
    assert spread_devices(["cpu", "cpu"]) == ["cpu", "cpu"] and spread_devices("cuda:all") == ["cuda:all"]
    assert spread_devices("cpu") is None and spread_devices(None) is None and spread_devices(["cuda:1"]) is None
    for bad in ("cpu,cuda:0", "cuda:0,", "gpu,gpu", "cuda:all,cuda:0"):
        with pytest.raises(ws.WarpStokesError, match="name several devices of one kind"):
            spread_devices(bad)


def test_a_bind_spread_over_two_workers_gives_the_weights_of_one_device(tmp_path, ray_cluster):
    ray = pytest.importorskip("ray")
    from warp_stokes.binding.columns import grid_columns
    from warp_stokes.binding.plan import GridPlan

    one = ws.bind(ARM, ARM_CAGE, resolution=20, device="cpu")
    assert ws.bind(ARM, ARM_CAGE, resolution=12, device=["cpu"]).stats.device == "cpu"  # a list of one device
    ray.init(address=ray_cluster)  # a running cluster (two nodes): the binds use it and leave it running
    try:
        two = ws.bind(ARM, ARM_CAGE, resolution=20, device=["cpu", "cpu"])
        # what a share warns of in its worker is warned of by the bind (a tolerance float32 cannot reach)
        with pytest.warns(UserWarning, match="float32 accuracy limit") as caught:
            ws.bind(ARM, ARM_CAGE, resolution=20, device="cpu,cpu", tol=1e-9)
        assert sum("float32 accuracy limit" in str(w.message) for w in caught) == 2  # one per share
        # and a share that cannot give exact weights fails the bind with its own error
        with pytest.raises(ws.ConvergenceError, match="reached its iteration limit"):
            ws.bind(ARM, ARM_CAGE, resolution=20, device="cpu,cpu", max_iterations=1)
        # every GPU of a cluster that has none: the command (in process, on this cluster: no other one started for
        # it) says so in one line, exit 2, no file
        failed = cli("bind", ARM, ARM_CAGE, "-o", tmp_path / "no.npz", "--resolution", "16", "--device", "cuda:all")
        assert failed.returncode == 2 and "the Ray cluster has no GPU" in failed.stderr, failed.stderr[-2000:]
        assert failed.stderr.strip().count("\n") == 0 and not (tmp_path / "no.npz").exists()
        assert ray.is_initialized()
    finally:
        ray.shutdown()
    shares = two.stats.solver.devices
    assert [s["handles"] for s in shares] == [[0, 29], [29, 58]] and shares[0]["pid"] != shares[1]["pid"]
    assert two.stats.solver.chunks == 2 and two.stats.converged and two.stats.grid.shape == one.stats.grid.shape
    assert two.stats.partition_of_unity_error < 1e-5 and two.stats.linear_precision_error < 1e-5
    # the same numbers as the shares solved in this process, one after another; within the solver's tolerance of
    # the bind that solves all handles at once
    cage = ws.check_cage(ARM_CAGE)
    here = [grid_columns(cage, one.mesh_vertices, 20, GridPlan.of("cpu"), handles=slice(a, b)).weights
            for a, b in ([0, 29], [29, 58])]
    np.testing.assert_array_equal(two.weights, np.concatenate(here, axis=1))
    assert np.abs(two.weights - one.weights).max() < 1e-5


def test_the_command_spreads_a_bind_and_says_what_it_cannot(tmp_path, arm_npz):
    pytest.importorskip("ray")
    out = tmp_path / "arm.npz"
    done = bind_command("-o", out, "--resolution", "16", "--device", "cpu,cpu")
    assert done.returncode == 0, done.stderr[-2000:]
    binding = ws.load_binding(out, device="cpu")
    assert len(binding.stats.solver.devices) == 2 and binding.stats.partition_of_unity_error < 1e-5
    alone = ws.load_binding(arm_npz, device="cpu")  # the session's bind of the arm at 16 on one device
    assert np.abs(binding.weights - alone.weights).max() < 1e-5
    # a mixed list: one line, exit 2, no file (in process; every GPU of a cluster that has none is refused above,
    # on a running cluster)
    failed = cli("bind", ARM, ARM_CAGE, "-o", tmp_path / "no.npz", "--resolution", "16", "--device", "cpu,cuda:0")
    assert failed.returncode == 2 and "of one kind" in failed.stderr, failed.stderr[-2000:]
    assert failed.stderr.strip().count("\n") == 0 and not (tmp_path / "no.npz").exists()


def test_without_ray_a_spread_bind_is_one_line_and_exit_2(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as where Ray is not installed: `import ray` fails
    failed = cli("bind", ARM, ARM_CAGE, "-o", tmp_path / "a.npz", "--resolution", "16", "--device", "cpu,cpu")
    assert failed.returncode == 2 and 'needs Ray, an optional extra: pip install "warp-stokes[ray]"' in failed.stderr
    assert failed.stderr.strip().count("\n") == 0 and not (tmp_path / "a.npz").exists()


def test_bench_spread_tabulates_a_spread_bind_against_one_device(capsys, ray_cluster):
    # the harness that measures issue 15's target on a host with several GPUs, here on the CPU with two shares: its
    # own run and table, in this process on the session's cluster (the script joins a running one)
    ray = pytest.importorskip("ray")
    from pathlib import Path

    benchmarks = str(Path(__file__).resolve().parents[1] / "benchmarks")
    sys.path.insert(0, benchmarks)
    try:
        import bench_spread
    finally:
        sys.path.remove(benchmarks)
    ray.init(address=ray_cluster)
    try:
        assert bench_spread.main(["--device", "cpu", "--pair", "arm", "--resolutions", "16", "--shares", "2"]) == 0
        assert ray.is_initialized()  # the cluster it joined, left to this process
    finally:
        ray.shutdown()
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("| 16 | 58 |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[4] == "2" and float(cells[-2]) < 1e-5 and cells[-1] == "-"  # no GPU to be busy
