"""CPU and CUDA must give the same weights. Runs where CUDA is present (skipped otherwise)."""

import warnings

import numpy as np
import pytest

import warp_stokes as ws
from conftest import EXAMPLE, float32_rounding, pair

# skipped where there is no CUDA device (conftest.py); not the `device` fixture: both devices, side by side
pytestmark = pytest.mark.cuda


@pytest.mark.parametrize("name", ["arm", "ogre"])
def test_cpu_and_cuda_weights_agree(name):
    mesh, cage = (EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj") if name == "arm" else pair(name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cpu = ws.bind(mesh, cage, resolution=24, device="cpu")
        gpu = ws.bind(mesh, cage, resolution=24, device="cuda:0")
    diff = np.abs(cpu.weights - gpu.weights).max()
    print(f"{name}: max |w_cpu - w_cuda| = {diff:.2e}; iterations cpu {cpu.stats.solver.iterations}, "
          f"cuda {gpu.stats.solver.iterations}")
    assert cpu.stats.grid.shape == gpu.stats.grid.shape
    assert cpu.stats.grid.interior_nodes == gpu.stats.grid.interior_nodes
    assert diff <= 1e-5
    pose = cpu.cage_vertices * 1.2 + 3.0
    # the weights' difference times the centred pose (deform sums w (c - centre)), and float32 sums of products
    # in other orders (BLAS against a kernel): 8 eps of their size
    offsets = np.abs(pose - pose.mean(axis=0)).sum(axis=0).max()
    np.testing.assert_allclose(cpu.deform(pose), gpu.deform(pose), rtol=0, atol=diff * offsets + float32_rounding(
        (np.abs(cpu.weights) @ np.abs(pose)).max()))


def test_a_threaded_cpu_bind_on_a_gpu_host_stays_on_the_cpu():
    """Threads that solve chunks at once on the CPU of a host whose default Warp device is a GPU: every lane's arrays
    on the CPU (Warp's default device is one for all threads: a lane's scope once restored the GPU under another
    lane, whose arrays then went there: an illegal memory access), the weights of one thread."""
    import warp as wp

    assert wp.get_device().is_cuda  # the default device, as on any GPU host
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        one = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=24, device="cpu", threads=1)
        four = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", resolution=24, device="cpu", threads=4)
    assert four.stats.solver.threads == 4 and four.stats.device == "cpu"
    np.testing.assert_allclose(four.weights, one.weights, atol=1e-6)
    assert wp.get_device().is_cuda  # and the default is left as it was


@pytest.mark.parametrize("case", [dict(resolution=24), dict(resolution=48, memory_budget=14 * 2**20),
                                  dict(resolution=24, method="harmonic")], ids=["one chunk", "chunks", "harmonic"])
def test_v_cycles_replayed_as_cuda_graphs_give_the_weights_of_plain_launches(monkeypatch, case):
    """On a GPU each V-cycle is recorded once per pair of arrays and replayed (solver.multigrid.GRAPHS): the same
    kernels, arguments and order, so the same weights bit for bit, one chunk or many (where the work vectors are
    reused or made again)."""
    import warp as wp

    import warp_stokes.solver.multigrid as multigrid

    replays = []
    launch = wp.capture_launch
    monkeypatch.setattr(multigrid.wp, "capture_launch", lambda graph, **k: (replays.append(graph), launch(graph, **k)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        monkeypatch.setattr(multigrid, "GRAPHS", False)
        plain = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", device="cuda:0", **case)
        assert not replays
        monkeypatch.setattr(multigrid, "GRAPHS", True)
        replayed = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", device="cuda:0", **case)
    assert len(replays) >= replayed.stats.solver.iterations  # recorded, and replayed at least once an iteration
    assert replayed.stats.solver.chunks == plain.stats.solver.chunks
    np.testing.assert_array_equal(replayed.weights, plain.weights)


def test_binds_in_threads_on_one_gpu_record_no_graph_under_each_other():
    """Two binds at once in threads of one process on one GPU: Warp records every launch on the device's stream
    and refuses every wait there while a graph is recorded, so neither records while the other runs (they launch
    plainly): no error, and the weights of a bind alone."""
    from concurrent.futures import ThreadPoolExecutor

    case = dict(resolution=32, memory_budget=14 * 2**20)  # chunks: many cycles on the same arrays
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        alone = ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", device="cuda:0", **case)
        with ThreadPoolExecutor(2) as pool:
            both = list(pool.map(lambda _: ws.bind(EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj", device="cuda:0",
                                                   **case), range(2)))
    for b in both:
        np.testing.assert_array_equal(b.weights, alone.weights)
