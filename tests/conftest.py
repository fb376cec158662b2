"""Shared fixtures: the real mesh/cage pairs of ../shared/data and the bundled example."""

import os
import warnings
from pathlib import Path

import numpy as np
import pytest
import warp as wp

import warp_stokes as ws

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "arm"
DATA = Path(os.environ.get("WARP_STOKES_DATA", REPO.parent / "shared" / "data"))

# (mesh, cage) pairs used by the acceptance tests
PAIRS = {
    "arm": (DATA / "arm_supercages" / "arm.obj", DATA / "arm_supercages" / "arm_cage.obj"),
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


@pytest.fixture(scope="session")
def arm_cage():
    return ws.check_cage(EXAMPLE / "arm_cage.obj")


@pytest.fixture(scope="session")
def bindings():
    """Bindings of the real pairs on the CPU, computed once per session (name -> Binding)."""
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
