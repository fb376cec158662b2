"""Small USD assets built with pxr, as pipelines hold a character: meshes under transformed Xforms, one with quads,
UVs, authored normals and a bound material, and a time-sampled cage prim."""

from __future__ import annotations

import numpy as np

import warp_stokes as ws

#: where the test asset's prims are
BODY, BAND, CAGE = "/Char/Geo/Body", "/Char/Geo/Band", "/Char/Rig/Cage"
TIMES = (101.0, 102.0, 104.0)


def _matrix(translate, angle_deg, scale):
    from pxr import Gf

    rotation = Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(0, 0, 1), angle_deg))
    return Gf.Matrix4d().SetScale(Gf.Vec3d(scale, scale, scale)) * rotation * Gf.Matrix4d().SetTranslate(
        Gf.Vec3d(*translate))


def _local(world: np.ndarray, to_world) -> np.ndarray:
    inverse = np.linalg.inv(np.array(to_world))
    return world @ inverse[:3, :3] + inverse[3, :3]


def box_quads(centre, size):
    """A cube of 8 points and 6 outward quads, its UVs per corner and its hard-edged (per-face) normals."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    quads = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])
    normals = np.repeat(np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1.0]]), 4, axis=0)
    st = np.array([[0, 0], [1, 0], [1, 1], [0, 1.0]])
    return np.asarray(centre) + 0.5 * size * corners, quads, np.tile(st, (6, 1)), normals


def cage_animation(rest: np.ndarray):
    """The rest cage, then bent about its centre and moved: one (L, 3) per time of TIMES."""
    centre = rest.mean(axis=0)
    out = [rest]
    for k in range(1, len(TIMES)):
        a = 0.2 * k
        rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        bent = np.where((rest[:, 1] > centre[1])[:, None], (rest - centre) @ rot.T + centre, rest)
        out.append(bent + [0.05 * k * np.ptp(rest[:, 0]), 0, 0])
    return out


def write_asset(path, mesh: ws.Surface, cage: ws.Surface, band_centre, band_size) -> dict:
    """Write the asset; returns the world-space rest geometry of each prim and the cage's animation."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    stage.SetTimeCodesPerSecond(30)
    stage.SetStartTimeCode(TIMES[0])
    stage.SetEndTimeCode(TIMES[-1])
    char = UsdGeom.Xform.Define(stage, "/Char")
    stage.SetDefaultPrim(char.GetPrim())
    UsdGeom.Xformable(char).AddTransformOp().Set(_matrix((3, -2, 1), 30, 2.0))
    geo = UsdGeom.Xform.Define(stage, "/Char/Geo")
    UsdGeom.Xformable(geo).AddTransformOp().Set(_matrix((0.5, 0, 0), -10, 0.5))
    UsdGeom.Xform.Define(stage, "/Char/Rig")
    cache = UsdGeom.XformCache()

    body = UsdGeom.Mesh.Define(stage, BODY)
    body_to_world = cache.GetLocalToWorldTransform(body.GetPrim())
    body.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(_local(mesh.vertices, body_to_world).astype(np.float32)))
    body.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(mesh.faces)))
    body.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(mesh.faces.astype(np.int32).ravel()))
    body.CreateSubdivisionSchemeAttr("none")
    import trimesh

    local = _local(mesh.vertices, body_to_world)
    body.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(
        trimesh.Trimesh(local, mesh.faces, process=False).vertex_normals.astype(np.float32)))
    body.SetNormalsInterpolation(UsdGeom.Tokens.vertex)

    points, quads, st, normals = box_quads(band_centre, band_size)
    band = UsdGeom.Mesh.Define(stage, BAND)
    band_to_world = cache.GetLocalToWorldTransform(band.GetPrim())
    band.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(_local(points, band_to_world).astype(np.float32)))
    band.CreateFaceVertexCountsAttr(Vt.IntArray([4] * len(quads)))
    band.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(quads.astype(np.int32).ravel()))
    band.CreateSubdivisionSchemeAttr("none")
    band.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(normals.astype(np.float32)))  # rotation-free: see _matrix
    band.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
    primvar = UsdGeom.PrimvarsAPI(band).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                      UsdGeom.Tokens.faceVarying)
    primvar.Set(Vt.Vec2fArray.FromNumpy(st.astype(np.float32)))
    for prim, pts in ((body, local), (band, _local(points, band_to_world))):
        prim.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, pts.min(0))), Gf.Vec3f(*map(float, pts.max(0)))]))
    material = UsdShade.Material.Define(stage, "/Char/Looks/Cloth")
    shader = UsdShade.Shader.Define(stage, "/Char/Looks/Cloth/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.8, 0.2, 0.1))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(band.GetPrim()).Bind(material)

    rig = UsdGeom.Mesh.Define(stage, CAGE)
    cage_to_world = cache.GetLocalToWorldTransform(rig.GetPrim())
    rig.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(cage.faces)))
    rig.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(cage.faces.astype(np.int32).ravel()))
    rig.CreateSubdivisionSchemeAttr("none")
    UsdGeom.Imageable(rig).CreatePurposeAttr(UsdGeom.Tokens.guide)
    poses = cage_animation(cage.vertices)
    for t, pose in zip(TIMES, poses):
        local_pose = _local(pose, cage_to_world)
        rig.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(local_pose.astype(np.float32)), t)
        rig.GetExtentAttr().Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, local_pose.min(0))),
                                               Gf.Vec3f(*map(float, local_pose.max(0)))]), t)
    stage.GetRootLayer().Save()
    return {"body": mesh.vertices, "band": points, "quads": quads, "poses": np.stack(poses)}
