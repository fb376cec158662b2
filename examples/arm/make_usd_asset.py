"""Write ``arm.usda`` beside this file: the bundled arm as a USD asset, the way pipelines hold a character.

    python examples/arm/make_usd_asset.py

``/Arm`` (the default prim) holds the skin mesh ``/Arm/Geo/Skin`` (the arm's 2,089 vertices, authored vertex
normals) and the cage ``/Arm/Rig/Cage`` (purpose guide) whose points are time-sampled at frames 1 to 24 with the
poses of ``bend_poses.npy`` (frame 1 is the rest pose). ``/Arm/Geo`` carries a transform, so that the mesh's local
space differs from the world space in which it is bound. Y up, centimetres, 24 time codes per second.
"""

from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

HERE = Path(__file__).resolve().parent


def _read_obj(path):
    vertices, faces = [], []
    for line in open(path):
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            faces.append([int(tok.split("/")[0]) - 1 for tok in line.split()[1:]])
    return np.array(vertices), np.array(faces)


def _extent(points):
    return Vt.Vec3fArray([Gf.Vec3f(*map(float, points.min(0))), Gf.Vec3f(*map(float, points.max(0)))])


def _vertex_normals(points, faces):
    face_normals = np.cross(points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]])
    normals = np.zeros_like(points)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face_normals)
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def write(path=HERE / "arm.usda"):
    skin_points, skin_faces = _read_obj(HERE / "arm.obj")
    cage_points, cage_faces = _read_obj(HERE / "arm_cage.obj")
    poses = np.load(HERE / "bend_poses.npy")
    layer = Sdf.Layer.CreateNew(str(path))
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetTimeCodesPerSecond(24)
    stage.SetFramesPerSecond(24)
    stage.SetStartTimeCode(1)
    stage.SetEndTimeCode(len(poses))
    arm = UsdGeom.Xform.Define(stage, "/Arm")
    stage.SetDefaultPrim(arm.GetPrim())
    geo = UsdGeom.Xform.Define(stage, "/Arm/Geo")
    offset = Gf.Vec3d(0.0, -100.0, 0.0)  # the skin is modelled 100 units lower and moved up into the cage
    geo.AddTranslateOp().Set(-offset)
    skin = UsdGeom.Mesh.Define(stage, "/Arm/Geo/Skin")
    local = skin_points + np.array(offset)
    skin.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(local.astype(np.float32)))
    skin.CreateExtentAttr(_extent(local))
    skin.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(skin_faces)))
    skin.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(skin_faces.astype(np.int32).ravel()))
    skin.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    skin.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(_vertex_normals(local, skin_faces).astype(np.float32)))
    skin.SetNormalsInterpolation(UsdGeom.Tokens.vertex)
    skin.CreateDisplayColorPrimvar().Set(Vt.Vec3fArray([Gf.Vec3f(0.8, 0.6, 0.5)]))
    UsdGeom.Xform.Define(stage, "/Arm/Rig")
    cage = UsdGeom.Mesh.Define(stage, "/Arm/Rig/Cage")
    cage.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(cage_faces)))
    cage.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(cage_faces.astype(np.int32).ravel()))
    cage.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    cage.CreatePurposeAttr(UsdGeom.Tokens.guide)
    for frame, pose in enumerate(poses, start=1):
        cage.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(pose.astype(np.float32)), frame)
        cage.GetExtentAttr().Set(_extent(pose), frame)
    layer.Save()
    return path


if __name__ == "__main__":
    print(f"wrote {write()}")
