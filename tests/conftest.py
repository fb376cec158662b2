"""Shared fixtures and helpers: the Warp device(s) to test on, the real mesh/cage pairs of ../shared/data, the bundled
example and small cages built in code, and one Ray cluster for the tests that run on a running cluster.

Test modules import helpers from here (``from conftest import ...``), never from one another. The modules with a test
that takes ``ray_cluster`` run one after another, where the first of them comes in the usual order, so that the
session's Ray cluster is started once and shut down after the last test on it, not left idle in between."""

import contextlib
import importlib
import io
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import warp as wp

import warp_stokes as ws

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "arm"
DATA = Path(os.environ.get("WARP_STOKES_DATA", REPO.parent / "shared" / "data"))

# (mesh, cage) pairs used by the acceptance tests; the arm is bundled (byte-for-byte the shared data's), so its tests
# also run where ../shared is absent (CI)
PAIRS = {
    "arm": (EXAMPLE / "arm.obj", EXAMPLE / "arm_cage.obj"),
    "smpl": (DATA / "smpl_humanoid_neuralcages" / "model_rpose.obj",
             DATA / "smpl_humanoid_neuralcages" / "cage_rpose.obj"),
    "ogre": (DATA / "ogre_qmvc" / "Ogre.obj", DATA / "ogre_qmvc" / "cage_tri.obj"),
}


def pair(name):
    mesh, cage = PAIRS[name]
    if not mesh.exists():
        pytest.skip(f"test data not found: {mesh} (set WARP_STOKES_DATA)")
    return mesh, cage


def cuda_available() -> bool:
    ws.device.init_warp()  # quiet: no CUDA-driver warning on a machine without a GPU
    return wp.is_cuda_available()


# The devices a test taking the `device` fixture runs on: the CPU always, and the first CUDA device when there is
# one (marked `cuda`, so that `-m "not cuda"` leaves it out). Without a GPU (CI) the CUDA parameter is absent, not
# skipped: each such test runs once, on the CPU.
DEVICES = ["cpu"] + ([pytest.param("cuda:0", marks=pytest.mark.cuda)] if cuda_available() else [])


@pytest.fixture(scope="module", params=DEVICES)
def device(request):
    """The Warp device a test runs on, "cpu" or "cuda:0"; arrays a test or its helpers make must be on it.

    Module-scoped so that module fixtures (a grid, a hierarchy, a binding) can be made once per device; not
    session-scoped, since pytest would then regroup the tests of all modules by device and set up the module
    fixtures that do not take the device once more for each group."""
    return request.param


def _takes_ray_cluster(item) -> bool:
    return "ray_cluster" in getattr(item, "fixturenames", ())


def pytest_collection_modifyitems(config, items):
    """The modules with tests on the session's Ray cluster run one after another (each module whole, in its own
    order), from where the first of them is; tests marked `cuda` (pyproject's marker) are skipped on a machine without
    a CUDA device."""
    on_ray = {item.path for item in items if _takes_ray_cluster(item)}
    if on_ray:
        first = next(k for k, item in enumerate(items) if item.path in on_ray)
        rest = [item for item in items if item.path not in on_ray]
        items[:] = rest[:first] + [item for item in items if item.path in on_ray] + rest[first:]
        _RAY["last"] = [item for item in items if _takes_ray_cluster(item)][-1]
    if cuda_available():
        return
    skip = pytest.mark.skip(reason="no CUDA device")
    for item in items:
        if item.get_closest_marker("cuda") is not None:
            item.add_marker(skip)


_RAY = {}  # "cluster": the session's Ray cluster while it runs; "last": the last test on it


@pytest.fixture
def ray_cluster():
    """The address of the session's Ray cluster: a simulated two-node cluster on this host
    (``ray.cluster_utils.Cluster``, one CPU per node), started by the first test that takes it and shut down after
    the last test that takes it (its idle processes take CPU). A test joins it (``ray.init(address=...)``,
    or ``ray_address=``) and leaves it with ``ray.shutdown()``, which disconnects and leaves it running. Starting Ray
    takes seconds on 2 cores. A command that starts a cluster of its own (the subprocesses of tests/test_batch_ray.py
    and test_spread.py, as a user runs them) still does, also while this one runs: the address that a plain
    ``ray.init()`` would join instead is removed."""
    ray = pytest.importorskip("ray")
    if "cluster" not in _RAY:
        from ray.cluster_utils import Cluster

        _RAY["cluster"] = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
        _RAY["cluster"].add_node(num_cpus=1)
        _RAY["cluster"].wait_for_nodes()
        # Cluster writes its address where ray.init() without one looks first (/tmp/ray/ray_current_cluster):
        # removed, as it is when the cluster shuts down
        for module in ("ray._common.utils", "ray._private.utils"):
            with contextlib.suppress(ImportError, AttributeError):
                importlib.import_module(module).reset_ray_address()
                break
    yield _RAY["cluster"].address
    if ray.is_initialized():  # a test that failed before it left the cluster
        ray.shutdown()


def _shut_down_ray_cluster():
    cluster = _RAY.pop("cluster", None)
    if cluster is not None:
        cluster.shutdown()


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item, nextitem):
    """The session's Ray cluster is shut down once the last test on it is done."""
    if item is _RAY.get("last"):
        _shut_down_ray_cluster()


def pytest_sessionfinish(session):
    _shut_down_ray_cluster()


@pytest.fixture(scope="session")
def arm_cage():
    return ws.check_cage(EXAMPLE / "arm_cage.obj")


@pytest.fixture(scope="session")
def bindings():
    """Bindings of the real pairs on the CPU, computed once per session (name -> Binding).

    Not parametrised over `device`: the three real pairs would be bound again per device and every test that reads
    these bindings (weights, save/load, deform, quality) would run again per device; tests/test_cuda.py compares
    the CPU and CUDA weights of the real pairs instead."""
    cache = {}
    resolutions = {"arm": 24, "smpl": 24, "ogre": 24}

    def get(name):
        if name not in cache:
            mesh, cage = pair(name)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cache[name] = ws.bind(mesh, cage, resolution=resolutions[name], device="cpu")
        return cache[name]

    return get


def warp_stokes(*args, timeout=300):
    """The ``warp-stokes`` command as a user runs it: a subprocess (the installed script, else ``python -m``)."""
    exe = shutil.which("warp-stokes")
    args = [str(a) for a in args]
    command = [exe, *args] if exe else [sys.executable, "-m", "warp_stokes.cli", *args]
    return subprocess.run(command, capture_output=True, text=True, timeout=timeout)


def cli(*args, cwd=None):
    """The ``warp-stokes`` command in this process (``main(argv)``): what :func:`warp_stokes` returns (its exit code,
    stdout and stderr as a ``CompletedProcess``), without the second or more a fresh process spends importing Warp and
    loading the kernels. For the tests where a process of its own adds nothing; each command keeps a test that runs
    it as a user does (:func:`warp_stokes`), and the tests of what only a process shows (a signal, the first lines
    Warp prints, the installed script) keep theirs."""
    from warp_stokes.cli import main

    out, err = io.StringIO(), io.StringIO()
    here = os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            rc = main([str(a) for a in args])  # its exit code (it raises no SystemExit: that would fail the test)
    finally:
        os.chdir(here)
    return subprocess.CompletedProcess(["warp-stokes", *map(str, args)], rc, out.getvalue(), err.getvalue())


def one_error_line(proc) -> str:
    """The command's stderr, asserted to be one line."""
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.fixture(scope="session")
def arm_npz(tmp_path_factory):
    """The bundled arm bound at resolution 16 on the CPU by ``warp-stokes bind`` (a subprocess): a binding file for
    the command tests to read, never to change."""
    out = tmp_path_factory.mktemp("bound") / "arm.npz"
    proc = warp_stokes("bind", str(EXAMPLE / "arm.obj"), str(EXAMPLE / "arm_cage.obj"), "-o", str(out),
                       "--resolution", "16", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    return out


def write_obj(path, vertices, faces):
    """A triangle mesh as an OBJ file (1-based faces), the way users' tools write one."""
    with open(path, "w") as fh:
        fh.writelines(f"v {x} {y} {z}\n" for x, y, z in vertices)
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)


def box_cage(lo=(-1.0, -1.0, -1.0), hi=(1.0, 1.0, 1.0)):
    """An axis-aligned box as (vertices, outward triangles)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
    v = lo + v * (hi - lo)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return v, np.array(tris)


def u_cage(gap: float = 0.2) -> ws.Cage:
    """A U extruded along z: two prongs `gap` apart in space but 4 + gap apart along the cage (via the gap's floor)."""
    import trimesh

    pts = np.array([(0, 0), (1, 0), (1 + gap, 0), (2 + gap, 0), (0, 1), (1, 1), (1 + gap, 1), (2 + gap, 1), (0, 3),
                    (1, 3), (1 + gap, 3), (2 + gap, 3)], float)
    quads = [(0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (4, 5, 9, 8), (6, 7, 11, 10)]
    tris = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    m = trimesh.creation.extrude_triangulation(pts, tris, height=1.0)
    return ws.check_cage((m.vertices, m.faces), name="u-cage")


def slit_cage(half_width: float = 0.09, depth: float = 1.2):
    """A 2 x 2 x 2 box with a V-shaped slit cut into its top (z = 1) along y, `depth` deep and `2 half_width` wide at
    the top (walls about 9 degrees apart: the cage folds back at the slit's floor), rotated so that no grid node lies
    on a face. Returns (cage, rotation, lip): `lip` are the two handles on the slit's +x lip."""
    import trimesh

    profile = np.array([(-1, -1), (1, -1), (1, 1), (half_width, 1), (0, 1 - depth), (-half_width, 1), (-1, 1)], float)
    tip = 4  # the slit's floor sees every other corner: a fan from it triangulates the profile
    fan = np.array([(tip, j, i) for i, j in zip(range(7), [1, 2, 3, 4, 5, 6, 0]) if tip not in (i, j)])
    m = trimesh.creation.extrude_triangulation(profile, fan, height=2.0)
    vertices = m.vertices[:, [0, 2, 1]] - np.array([0.0, 1.0, 0.0])  # extruded along y, the profile in x-z
    faces = m.faces[:, ::-1]  # swapping two axes mirrors: restore the outward orientation
    rotation = np.linalg.qr(np.random.default_rng(3).normal(size=(3, 3)))[0]
    cage = ws.check_cage((vertices @ rotation.T, faces), name="slit")
    lip = np.flatnonzero(np.isclose(vertices[:, 0], half_width) & np.isclose(vertices[:, 2], 1.0))
    return cage, rotation, lip


F32_EPS = float(np.finfo(np.float32).eps)  # 1.19e-7
F64_EPS = float(np.finfo(np.float64).eps)  # 2.2e-16


def float32_rounding(scale, factor=8.0):
    """A tolerance for float32 results of magnitude ``scale`` computed in another order (another BLAS, a kernel
    against numpy, another process): ``factor`` float32 epsilons of it. ``scale`` is the magnitude of the values
    compared, or of the terms they sum (``(|w| @ |x|).max()``), taken from the data in the test; ``factor`` is
    said where it is used (8 covers sums in another order; 1 a single rounding to float32)."""
    return factor * F32_EPS * float(scale)


def float64_rounding(scale, factor=8.0):
    """:func:`float32_rounding` for float64 results."""
    return factor * F64_EPS * float(scale)
