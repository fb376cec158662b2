"""USD assets in and a layer over them out: many mesh prims bound in one solve, in world space; the animation as
overrides only, composed over the asset and read back with pxr. Also OBJ/glTF sources written standalone with
their polygons, UVs and per-frame normals."""

import os
import warnings

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdShade, UsdValidation

import warp_stokes as ws
from conftest import EXAMPLE, cli, float32_rounding
from usd_assets import BAND, BODY, CAGE, TIMES, box_quads, cage_animation, write_asset

RESOLUTION = 16


@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    folder = tmp_path_factory.mktemp("asset")
    mesh, cage = ws.load_surface(EXAMPLE / "arm.obj"), ws.load_surface(EXAMPLE / "arm_cage.obj")
    diagonal = float(np.linalg.norm(np.ptp(cage.vertices, axis=0)))
    centre = cage.vertices.mean(axis=0)  # inside the arm's cage (checked in test_bind_many_prims...)
    geometry = write_asset(folder / "char.usda", mesh, cage, centre, 0.03 * diagonal)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(folder / "char.usda", cage_prim=CAGE, resolution=RESOLUTION, device="cpu")
    return folder / "char.usda", binding, geometry, diagonal


def _errors(stage):
    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    return [e.GetMessage() for e in context.Validate(stage) if e.GetType() == UsdValidation.ValidationErrorType.Error]


def _world(stage, path, time):
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath(path))
    matrix = np.array(UsdGeom.XformCache(time).GetLocalToWorldTransform(mesh.GetPrim()))
    return np.asarray(mesh.GetPointsAttr().Get(time), dtype=np.float64) @ matrix[:3, :3] + matrix[3, :3]


def test_bind_many_prims_in_one_solve_in_world_space(asset):
    path, binding, geometry, diagonal = asset
    assert [p["path"] for p in binding.parts] == [BODY, BAND]  # every mesh but the cage, in stage order
    assert [p["vertices"] for p in binding.parts] == [len(geometry["body"]), 8]
    assert [p["normals"] for p in binding.parts] == ["vertex", "faceVarying"]
    np.testing.assert_allclose(binding.mesh_vertices, np.concatenate([geometry["body"], geometry["band"]]),
                               atol=1e-5 * diagonal)  # world space: the prims' transforms applied
    np.testing.assert_allclose(binding.cage_vertices, geometry["poses"][0], atol=1e-5 * diagonal)
    assert binding.stats.vertices_outside_cage == 0 and binding.stats.converged
    assert binding.stats.linear_precision_error < 1e-5 and binding.stats.partition_of_unity_error < 1e-5
    assert binding.asset["path"] == os.path.abspath(path) and binding.asset["rest_time"] == TIMES[0]
    assert binding.settings["cage_prim"] == CAGE and binding.settings["mesh_prims"] == [BODY, BAND]
    assert binding.mesh_face_counts.tolist() == [3] * (len(binding.mesh_faces) - 12) + [4] * 6


def test_one_named_prim_and_a_separate_cage_file(asset, tmp_path):
    path, whole, geometry, _ = asset
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        band = ws.bind(path, path, cage_prim=CAGE, mesh_prims=[BAND], resolution=RESOLUTION, device="cpu")
    assert [p["path"] for p in band.parts] == [BAND]
    # the same grid and solve, so the same weights at the same points
    np.testing.assert_allclose(band.weights, whole.weights[whole.part_slices()[1]], atol=1e-6)
    with pytest.raises(ws.MeshError, match=r"char.usda: no prim /Char/Geo/Missing \(mesh prims: /Char/Geo/Body"):
        ws.bind(path, cage_prim=CAGE, mesh_prims=["/Char/Geo/Missing"], resolution=8, device="cpu")
    with pytest.raises(ws.MeshError, match="/Char/Geo is a Xform, not a Mesh"):
        ws.bind(path, cage_prim=CAGE, mesh_prims=["/Char/Geo"], resolution=8, device="cpu")
    with pytest.raises(ws.CageError, match="no prim /Char/Nope"):
        ws.bind(path, cage_prim="/Char/Nope", resolution=8, device="cpu")
    with pytest.raises(ws.CageError, match="a USD cage needs its prim path"):
        ws.bind(EXAMPLE / "arm.obj", path, resolution=8, device="cpu")
    with pytest.raises(ws.CageError, match="no cage"):
        ws.bind(path, resolution=8, device="cpu")


def test_binding_of_an_asset_saves_and_loads(asset, tmp_path):
    _, binding, _, _ = asset
    binding.save(tmp_path / "b.npz")
    loaded = ws.load_binding(tmp_path / "b.npz", device="cpu")
    assert loaded.parts == binding.parts and loaded.asset == binding.asset
    np.testing.assert_array_equal(loaded.mesh_face_counts, binding.mesh_face_counts)
    np.testing.assert_array_equal(loaded.mesh_face_indices, binding.mesh_face_indices)


def test_cage_animation_from_the_asset(asset):
    path, binding, geometry, diagonal = asset
    poses = ws.load_poses(path, binding.cage_faces, binding.n_handles, cage_prim=CAGE)
    assert poses.frames.tolist() == list(TIMES) and poses.time_codes_per_second == 30
    np.testing.assert_allclose(poses.positions, geometry["poses"], atol=1e-5 * diagonal)  # world space
    with pytest.raises(ws.BindingError, match=f"{BODY}'s points have no time samples"):
        ws.load_poses(path, binding.cage_faces, binding.n_handles, cage_prim=BODY)


def test_layer_over_the_asset_holds_only_overrides_and_composes(asset, tmp_path):
    path, binding, geometry, diagonal = asset
    poses = ws.load_poses(path, binding.cage_faces, binding.n_handles, cage_prim=CAGE)
    out_dir = tmp_path / "shots" / "s010"
    out_dir.mkdir(parents=True)
    out = ws.write_animation(out_dir / "anim.usd", binding, poses)
    assert sorted(os.listdir(out_dir)) == ["anim.usd"]

    layer = Sdf.Layer.FindOrOpen(out)
    assert list(layer.subLayerPaths) == [os.path.relpath(path, out_dir)]  # relative: the folder can move
    assert not os.path.isabs(layer.subLayerPaths[0])
    specs = []
    layer.Traverse(Sdf.Path.absoluteRootPath, lambda p: specs.append(p) if p.IsPrimPath() else None)
    assert specs and all(layer.GetPrimAtPath(p).specifier == Sdf.SpecifierOver for p in specs)
    authored = {str(p.name) for s in specs for p in layer.GetPrimAtPath(s).properties}
    assert authored == {"points", "extent", "normals"}
    assert layer.defaultPrim == "Char"

    stage, source = Usd.Stage.Open(out), Usd.Stage.Open(str(path))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode(), stage.GetTimeCodesPerSecond()) == (101, 104, 30)
    assert not _errors(source) and not _errors(stage)
    # the first sample is the rest pose: the asset's own points, in each prim's local space
    for prim in (BODY, BAND):
        rest = np.asarray(UsdGeom.Mesh(source.GetPrimAtPath(prim)).GetPointsAttr().Get(TIMES[0]))
        first = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath(prim)).GetPointsAttr().Get(TIMES[0]))
        scale = np.linalg.norm(np.ptp(rest, axis=0)) / np.linalg.norm(np.ptp(geometry["body"], axis=0))
        assert np.abs(first - rest).max() <= 1e-5 * diagonal * max(scale, 1.0)
    # every frame: the deformation in world space, and extents that contain the points
    deformed = binding.deform(poses.positions)
    for k, t in enumerate(TIMES):
        world = np.concatenate([_world(stage, BODY, t), _world(stage, BAND, t)])
        np.testing.assert_allclose(world, deformed[k], atol=1e-5 * diagonal)
        for prim in (BODY, BAND):
            mesh = UsdGeom.Mesh(stage.GetPrimAtPath(prim))
            points = np.asarray(mesh.GetPointsAttr().Get(t))
            lo, hi = np.asarray(mesh.GetExtentAttr().Get(t))
            assert (points >= lo - 1e-6).all() and (points <= hi + 1e-6).all()
    # topology, UVs, material binding and transforms come from the asset unchanged
    for prim in (BODY, BAND):
        ours, theirs = UsdGeom.Mesh(stage.GetPrimAtPath(prim)), UsdGeom.Mesh(source.GetPrimAtPath(prim))
        for attr in ("GetFaceVertexCountsAttr", "GetFaceVertexIndicesAttr"):
            assert list(getattr(ours, attr)().Get()) == list(getattr(theirs, attr)().Get())
        assert ours.ComputeLocalToWorldTransform(102) == theirs.ComputeLocalToWorldTransform(102)
    st = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(BAND)).GetPrimvar("st")
    assert st.GetInterpolation() == UsdGeom.Tokens.faceVarying and len(st.Get()) == 24
    material, _ = UsdShade.MaterialBindingAPI(stage.GetPrimAtPath(BAND)).ComputeBoundMaterial()
    assert material.GetPath() == "/Char/Looks/Cloth"


def test_normals_are_time_sampled_and_match_the_deformed_mesh(asset, tmp_path):
    import trimesh

    path, binding, _, _ = asset
    poses = ws.load_poses(path, binding.cage_faces, binding.n_handles, cage_prim=CAGE)
    stage = Usd.Stage.Open(ws.write_animation(tmp_path / "anim.usda", binding, poses))
    _, quads, _, _ = box_quads(np.zeros(3), 1.0)
    for t in TIMES:
        band = UsdGeom.Mesh(stage.GetPrimAtPath(BAND))
        assert band.GetNormalsAttr().GetTimeSamples() == list(TIMES)
        points, normals = np.asarray(band.GetPointsAttr().Get(t)), np.asarray(band.GetNormalsAttr().Get(t))
        # hard edges stay hard: every corner of a quad has the quad's own normal (Newell's formula)
        for q, quad in enumerate(quads):
            p = points[quad]
            newell = np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0)
            np.testing.assert_allclose(normals[4 * q : 4 * q + 4], np.tile(newell / np.linalg.norm(newell), (4, 1)),
                                       atol=1e-4)  # float32 points: quads planar to ~1e-6
        body = UsdGeom.Mesh(stage.GetPrimAtPath(BODY))
        points = np.asarray(body.GetPointsAttr().Get(t), dtype=np.float64)
        faces = np.asarray(body.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3)
        reference = trimesh.Trimesh(points, faces, process=False)
        area_weighted = np.zeros_like(points)
        for corner in range(3):
            np.add.at(area_weighted, faces[:, corner], reference.face_normals * reference.area_faces[:, None])
        area_weighted /= np.linalg.norm(area_weighted, axis=1, keepdims=True)
        np.testing.assert_allclose(np.asarray(body.GetNormalsAttr().Get(t)), area_weighted, atol=1e-4)


def test_layer_refuses_what_it_cannot_honour(asset, tmp_path):
    path, binding, _, _ = asset
    poses = ws.load_poses(path, binding.cage_faces, binding.n_handles, cage_prim=CAGE)
    with pytest.raises(ws.WarpStokesError, match="keeps its up axis Z"):
        ws.write_animation(tmp_path / "a.usd", binding, poses, up_axis="Y")
    moved = ws.Binding(binding.weights, binding.cage_vertices, binding.cage_faces, binding.mesh_vertices,
                       binding.mesh_faces, binding.settings, binding.stats, device="cpu", parts=binding.parts,
                       asset={**binding.asset, "path": str(tmp_path / "gone.usda")})
    with pytest.raises(ws.WarpStokesError, match="gone.usda: the binding's USD asset is not there"):
        ws.write_animation(tmp_path / "a.usd", moved, poses)
    out = ws.write_animation(tmp_path / "a.usd", moved, poses, asset=path, with_cage=True)  # --asset
    stage = Usd.Stage.Open(out)
    np.testing.assert_allclose(_world(stage, CAGE, TIMES[2]), poses.positions[2], atol=1e-4)
    assert not os.listdir(tmp_path) == []


def test_usd_workflow_from_the_command_line(asset, tmp_path):
    path, _, geometry, diagonal = asset
    bound = cli("bind", path, "--cage-prim", CAGE, "-o", tmp_path / "b.npz", "--resolution", RESOLUTION, "--device",
                "cpu")
    assert bound.returncode == 0, bound.stderr
    assert "2 meshes" in bound.stdout
    animated = cli("animate", tmp_path / "b.npz", path, "--cage-prim", CAGE, "-o", tmp_path / "anim.usdc", "--device",
                   "cpu")
    assert animated.returncode == 0, animated.stderr
    assert "3 frames (101 to 104) at 30 fps" in animated.stdout
    stage = Usd.Stage.Open(str(tmp_path / "anim.usdc"))
    np.testing.assert_allclose(_world(stage, BAND, TIMES[0]), geometry["band"], atol=1e-5 * diagonal)
    bad = cli("bind", path, "--cage-prim", "/Char/Nope", "-o", tmp_path / "c.npz", "--device", "cpu")
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "no prim /Char/Nope" in bad.stderr
    assert not (tmp_path / "c.npz").exists()


def _write_quad_obj(path, points, quads, st, normals):
    with open(path, "w") as fh:
        fh.writelines(f"v {x} {y} {z}\n" for x, y, z in points)
        fh.writelines(f"vt {u} {v}\n" for u, v in st)
        fh.writelines(f"vn {x} {y} {z}\n" for x, y, z in normals)
        for q, quad in enumerate(quads):
            fh.write("f " + " ".join(f"{v + 1}/{4 * q + c + 1}/{4 * q + c + 1}" for c, v in enumerate(quad)) + "\n")


def test_standalone_output_keeps_quads_uvs_and_writes_normals_per_frame(tmp_path):
    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    diagonal = float(np.linalg.norm(np.ptp(cage.vertices, axis=0)))
    points, quads, st, normals = box_quads(cage.vertices.mean(axis=0), 0.03 * diagonal)
    _write_quad_obj(tmp_path / "box.obj", points, quads, st, normals)
    surface = ws.load_surface(tmp_path / "box.obj")
    assert surface.face_counts.tolist() == [4] * 6 and len(surface.faces) == 12
    np.testing.assert_allclose(surface.uvs[0][surface.uvs[1]], st)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(tmp_path / "box.obj", EXAMPLE / "arm_cage.obj", resolution=RESOLUTION, device="cpu")
    binding.save(tmp_path / "b.npz")
    binding = ws.load_binding(tmp_path / "b.npz", device="cpu")
    poses = ws.Poses(np.stack(cage_animation(cage.vertices)), np.array(TIMES), "generated")
    stage = Usd.Stage.Open(ws.write_animation(tmp_path / "box.usd", binding, poses))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh"))
    assert list(mesh.GetFaceVertexCountsAttr().Get()) == [4] * 6
    assert np.asarray(mesh.GetFaceVertexIndicesAttr().Get()).reshape(6, 4).tolist() == quads.tolist()
    primvar = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert primvar.GetInterpolation() == UsdGeom.Tokens.faceVarying
    np.testing.assert_allclose(np.asarray(primvar.ComputeFlattened()), st)
    assert mesh.GetNormalsAttr().GetTimeSamples() == list(TIMES)
    assert mesh.GetNormalsInterpolation() == UsdGeom.Tokens.vertex
    last = np.asarray(mesh.GetPointsAttr().Get(TIMES[-1]))
    # float32 sums of products W c' (~150): the chunk of frames in one product, one frame alone in another (other
    # BLAS kernels, other orders): 8 eps of their size
    np.testing.assert_allclose(last, binding.deform(poses.positions[-1]), rtol=0,
                               atol=float32_rounding((np.abs(binding.weights) @ np.abs(poses.positions[-1])).max()))
    outward = np.asarray(mesh.GetNormalsAttr().Get(TIMES[-1]))
    assert (np.sum(outward * (last - last.mean(axis=0)), axis=1) > 0).all()  # corners' normals point out
    assert not _errors(stage)


def test_gltf_scene_nodes_are_bound_in_world_space(tmp_path):
    import trimesh

    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    centre, diagonal = cage.vertices.mean(axis=0), float(np.linalg.norm(np.ptp(cage.vertices, axis=0)))
    scene = trimesh.Scene()
    box = trimesh.creation.box(extents=[0.02 * diagonal] * 3)
    for k, offset in enumerate((-0.01, 0.01)):
        transform = trimesh.transformations.rotation_matrix(0.3 * (k + 1), [0, 0, 1])
        transform[:3, 3] = centre + [offset * diagonal, 0, 0]
        scene.add_geometry(box, node_name=f"part{k}", geom_name=f"box{k}", transform=transform)
    scene.export(tmp_path / "parts.glb")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(tmp_path / "parts.glb", EXAMPLE / "arm_cage.obj", resolution=RESOLUTION, device="cpu")
    assert [p["path"] for p in binding.parts] == ["part0", "part1"]
    expected = np.concatenate([trimesh.transformations.transform_points(
        box.vertices, scene.graph.get(f"part{k}")[0]) for k in range(2)])
    np.testing.assert_allclose(binding.mesh_vertices, expected, atol=1e-5 * diagonal)
    poses = ws.Poses(np.stack(cage_animation(cage.vertices)), np.array(TIMES), "generated")
    stage = Usd.Stage.Open(ws.write_animation(tmp_path / "parts.usda", binding, poses))
    assert [c.GetName() for c in stage.GetPrimAtPath("/Root").GetChildren()] == ["part0", "part1"]
    second = np.asarray(UsdGeom.Mesh(stage.GetPrimAtPath("/Root/part1")).GetPointsAttr().Get(TIMES[1]))
    np.testing.assert_allclose(second, binding.deform(poses.positions[1])[binding.part_slices()[1]], rtol=0,
                               atol=float32_rounding((np.abs(binding.weights) @ np.abs(poses.positions[1])).max()))


@pytest.mark.parametrize("ext", [".usd", ".usda"])
def test_long_animations_are_written_in_chunks_and_read_back_whole(asset, tmp_path, ext):
    from warp_stokes.io.usd import FRAMES_PER_CHUNK

    path, binding, geometry, diagonal = asset
    n = 2 * FRAMES_PER_CHUNK + 17  # binary layers are saved and reloaded after each chunk but the last
    blend = np.linspace(0.0, 1.0, n)[:, None, None]
    poses = ws.Poses(geometry["poses"][0] + blend * (geometry["poses"][2] - geometry["poses"][0]),
                     np.arange(1.0, n + 1), "blend")
    out = ws.write_animation(tmp_path / f"long{ext}", binding, poses)
    assert sorted(os.listdir(tmp_path)) == [f"long{ext}"]
    stage = Usd.Stage.Open(out)
    assert Sdf.Layer.FindOrOpen(out).subLayerPaths[0] == os.path.relpath(path, tmp_path)
    body = UsdGeom.Mesh(stage.GetPrimAtPath(BODY))
    assert body.GetPointsAttr().GetTimeSamples() == list(poses.frames)
    assert body.GetNormalsAttr().GetNumTimeSamples() == n
    deformed = binding.deform(poses.positions)
    for k in (0, FRAMES_PER_CHUNK - 1, FRAMES_PER_CHUNK, n - 1):
        world = np.concatenate([_world(stage, BODY, k + 1.0), _world(stage, BAND, k + 1.0)])
        np.testing.assert_allclose(world, deformed[k], atol=1e-5 * diagonal)


def test_broken_usd_meshes_are_named(tmp_path):
    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    c = cage.vertices.mean(axis=0)
    text = f"""#usda 1.0
def Mesh "Bad"
{{
    point3f[] points = [({c[0]}, {c[1]}, {c[2]}), ({c[0] + 1}, {c[1]}, {c[2]}), ({c[0]}, {c[1] + 1}, {c[2]})]
    int[] faceVertexCounts = [3, 4]
    int[] faceVertexIndices = [0, 1, 2, 0, 1, 2, 9]
}}
def Mesh "Empty"
{{
}}
"""
    (tmp_path / "bad.usda").write_text(text)
    with pytest.raises(ws.MeshError, match=r"bad.usda:/Bad: face 1 refers to vertex 9, but there are only 3 points"):
        ws.bind(tmp_path / "bad.usda", EXAMPLE / "arm_cage.obj", mesh_prims=["/Bad"], resolution=8, device="cpu")
    with pytest.raises(ws.MeshError, match="bad.usda: /Empty has no points"):
        ws.bind(tmp_path / "bad.usda", EXAMPLE / "arm_cage.obj", mesh_prims=["/Empty"], resolution=8, device="cpu")
    (tmp_path / "text.usda").write_text("#usda 1.0\n( not usd\n")
    with pytest.raises(ws.MeshError, match="text.usda: cannot read it as USD"):
        ws.bind(tmp_path / "text.usda", EXAMPLE / "arm_cage.obj", resolution=8, device="cpu")


def test_what_a_review_found(asset, tmp_path):
    """The output is never the asset itself; instanced meshes are named; a cage prim may live in another USD file;
    a transform scaled to zero is one error."""
    from pxr import Gf

    path, binding, geometry, diagonal = asset
    poses = ws.load_poses(path, binding.cage_faces, binding.n_handles, cage_prim=CAGE)
    copy = tmp_path / "char.usda"
    copy.write_text(open(path).read())
    moved = ws.Binding(binding.weights, binding.cage_vertices, binding.cage_faces, binding.mesh_vertices,
                       binding.mesh_faces, binding.settings, binding.stats, device="cpu", parts=binding.parts,
                       asset={**binding.asset, "path": str(copy)})
    before = copy.read_text()
    with pytest.raises(ws.WarpStokesError, match="the output would replace the input"):
        ws.write_animation(copy, moved, poses)
    assert copy.read_text() == before
    # a cage in its own USD file, the meshes in the asset
    cage_only = tmp_path / "cage.usda"
    stage = Usd.Stage.CreateNew(str(cage_only))
    rig = UsdGeom.Mesh.Define(stage, "/Rig")  # world-space points, no transforms
    rig.CreateFaceVertexCountsAttr([3] * len(binding.cage_faces))
    rig.CreateFaceVertexIndicesAttr(binding.cage_faces.astype(int).ravel().tolist())
    for t, pose in zip(TIMES, geometry["poses"]):
        rig.GetPointsAttr().Set([Gf.Vec3f(*map(float, p)) for p in pose], t)
    stage.GetRootLayer().Save()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        separate = ws.bind(path, cage_only, cage_prim="/Rig", resolution=8, device="cpu")
    assert [p["path"] for p in separate.parts] == [BODY, BAND, CAGE]  # the asset's own cage prim is a mesh there
    with pytest.raises(ws.CageError, match="arm_cage.obj: a cage prim .* is named, but the cage is not a USD file"):
        ws.bind(path, EXAMPLE / "arm_cage.obj", cage_prim="Cage", resolution=8, device="cpu")
    # meshes inside an instance
    instanced = tmp_path / "instanced.usda"
    stage = Usd.Stage.CreateNew(str(instanced))
    holder = UsdGeom.Xform.Define(stage, "/Holder")
    holder.GetPrim().GetReferences().AddReference(str(path), "/Char")
    holder.GetPrim().SetInstanceable(True)
    stage.GetRootLayer().Save()
    with pytest.raises(ws.MeshError, match="is inside an instance"):
        ws.bind(instanced, cage_prim="/Holder/Rig/Cage", mesh_prims=["/Holder/Geo/Body"], resolution=8,
                device="cpu")
    # a parent scaled to zero at one frame
    hidden = tmp_path / "hidden.usda"
    hidden.write_text(open(path).read())
    stage = Usd.Stage.Open(str(hidden))
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/Char/Geo")).AddScaleOp(opSuffix="hide")
    op.Set(Gf.Vec3d(1, 1, 1), TIMES[0])
    op.Set(Gf.Vec3d(0, 0, 0), TIMES[2])
    stage.GetRootLayer().Save()
    with pytest.raises(ws.WarpStokesError, match=r"/Char/Geo/Body: its local-to-world transform at time 104 is "
                                                 r"singular"):
        ws.write_animation(tmp_path / "h.usd", moved, poses, asset=hidden)
    assert not (tmp_path / "h.usd").exists()


def test_normals_keep_their_side_on_clockwise_faces(tmp_path):
    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    diagonal = float(np.linalg.norm(np.ptp(cage.vertices, axis=0)))
    points, quads, st, normals = box_quads(cage.vertices.mean(axis=0), 0.03 * diagonal)
    _write_quad_obj(tmp_path / "cw.obj", points, quads[:, ::-1], st, normals)  # clockwise, normals still outward
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(tmp_path / "cw.obj", EXAMPLE / "arm_cage.obj", resolution=RESOLUTION, device="cpu")
    poses = ws.Poses(np.stack(cage_animation(cage.vertices)), np.array(TIMES), "generated")
    stage = Usd.Stage.Open(ws.write_animation(tmp_path / "cw.usd", binding, poses))
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh"))
    assert mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    first = np.asarray(mesh.GetNormalsAttr().Get(TIMES[0]))
    assert np.all(np.sum(first * binding.mesh_normals, axis=1) > 0.5)  # the file's side, not flipped
