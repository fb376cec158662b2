"""Rigged animation in from USD: ``ws.load_frames`` of a UsdSkel asset (pxr's skinning queries) against
``UsdSkel.BakeSkinning`` of a copy (pxr's baking: points and transforms written per time sample), blend shapes, an
unskinned prop and a rigidly skinned one included; another animation bound by name (in memory: the asset is not
changed); errors naming what the file has."""

from __future__ import annotations

import hashlib
import shutil

import numpy as np
import pytest
from pxr import Usd, UsdGeom, UsdSkel

import warp_stokes as ws
from rigged_assets import write_usd_skel
from warp_stokes.io.scene import load_scene

MESHES = ("/Char/Body", "/Char/Prop", "/Char/Hat")


def baked(path, copy, times, animation=None) -> np.ndarray:
    """The meshes' world-space points at ``times`` after ``UsdSkel.BakeSkinning`` of a copy of the asset (with
    ``animation`` bound to the skeleton first)."""
    shutil.copy(path, copy)
    stage = Usd.Stage.Open(str(copy))
    if animation is not None:
        UsdSkel.BindingAPI(stage.GetPrimAtPath("/Char/Skel")).GetAnimationSourceRel().SetTargets([animation])
    assert UsdSkel.BakeSkinning(Usd.PrimRange(stage.GetPseudoRoot()))
    frames = []
    for t in times:
        parts = []
        for prim_path in MESHES:
            prim = stage.GetPrimAtPath(prim_path)
            points = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(t), dtype=np.float64)
            matrix = np.array(UsdGeom.XformCache(t).GetLocalToWorldTransform(prim))
            parts.append(points @ matrix[:3, :3] + matrix[3, :3])
        frames.append(np.concatenate(parts))
    return np.stack(frames)


def deviation(frames, reference) -> float:
    return float(np.abs(frames - reference).max() / np.linalg.norm(np.ptp(reference.reshape(-1, 3), axis=0)))


def test_usd_skinning_matches_usdskels_own_baking(tmp_path):
    path = write_usd_skel(tmp_path / "char.usda")
    before = hashlib.sha256(open(path, "rb").read()).hexdigest()
    frames = ws.load_frames(path)
    # every time something moves: the joints (0, 2, ..., 10), the blend shape weight (5), the prop (0, 10)
    assert frames.frames.tolist() == [0, 2, 4, 5, 6, 8, 10] and frames.time_codes_per_second == 24
    assert frames.positions.shape[1] == len(load_scene(path).surface().vertices)  # the meshes bind reads
    assert deviation(frames.positions, baked(path, tmp_path / "baked.usda", frames.frames)) <= 1e-5
    twist = ws.load_frames(path, animation="Twist", fps=12)  # every 2 time codes at 24 per second
    assert twist.frames.tolist() == [0, 2, 4, 6, 8, 10]
    reference = baked(path, tmp_path / "twist.usda", twist.frames, animation="/Char/Twist")
    assert deviation(twist.positions, reference) <= 1e-5
    assert not np.allclose(twist.positions, frames.positions[[0, 1, 2, 4, 5, 6]])  # another animation indeed
    assert hashlib.sha256(open(path, "rb").read()).hexdigest() == before  # read only


def test_usd_errors_name_the_file_and_list_its_animations(tmp_path):
    path = write_usd_skel(tmp_path / "char.usda")
    with pytest.raises(ws.BindingError, match=r"char.usda: no animation 'Walk'; its animations \(SkelAnimation "
                                              r"prims\): /Char/Bend, /Char/Twist$"):
        ws.load_frames(path, animation="Walk")
    with pytest.raises(ws.BindingError, match=r"mesh prims are named, but it is not a USD file"):
        ws.load_frames(_static_gltf(tmp_path), mesh_prims=["/x"])
    still = tmp_path / "still.usda"
    stage = Usd.Stage.CreateNew(str(still))
    mesh = UsdGeom.Mesh.Define(stage, "/Still")
    mesh.CreatePointsAttr([(0, 0, 0), (1, 0, 0), (0, 1, 0)])
    mesh.CreateFaceVertexCountsAttr([3])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2])
    stage.GetRootLayer().Save()
    with pytest.raises(ws.BindingError, match=r"still.usda: none of its meshes is skinned to a skeleton \(UsdSkel\); "
                                              "its animations: none"):
        ws.load_frames(still)


def _static_gltf(tmp_path):
    from rigged_assets import SkinnedGltf, cylinder

    gltf = SkinnedGltf()
    points, faces = cylinder()
    gltf.node("Still", root=True, mesh=gltf.mesh("Still", [dict(points=points, faces=faces)]))
    return gltf.save(tmp_path / "still.glb")
