"""A binding as a skin: the K largest weights per vertex, the error of truncation measured against an independent
skinning, and the skins read back with what consumers use: pxr's UsdSkel (BakeSkinning, validation) for the USD
rig, pygltflib and numpy skinning for the glTF skin, and the command line (in process, ``main(argv)``)."""

import base64
import os
import warnings

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom, UsdSkel, UsdValidation

import warp_stokes as ws
from conftest import EXAMPLE, cli, one_error_line
from usd_assets import BAND, BODY, CAGE, TIMES, write_asset
from warp_stokes.binding.skin import skin_points

pygltflib = pytest.importorskip("pygltflib")


@pytest.fixture(scope="module")
def arm(bindings):
    return bindings("arm"), ws.Poses(np.load(EXAMPLE / "bend_poses.npy"), np.arange(1.0, 25.0), "bend_poses")


@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    """The test asset (meshes under rotated and scaled Xforms, Z-up in centimetres, a quad part with UVs and face-
    varying normals, a time-sampled cage prim) and its binding."""
    folder = tmp_path_factory.mktemp("skin_asset")
    mesh, cage = ws.load_surface(EXAMPLE / "arm.obj"), ws.load_surface(EXAMPLE / "arm_cage.obj")
    diagonal = float(np.linalg.norm(np.ptp(cage.vertices, axis=0)))
    write_asset(folder / "char.usda", mesh, cage, cage.vertices.mean(axis=0), 0.03 * diagonal)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(folder / "char.usda", cage_prim=CAGE, resolution=16, device="cpu")
    poses = ws.load_poses(folder / "char.usda", binding.cage_faces, binding.n_handles, cage_prim=CAGE)
    return folder / "char.usda", binding, poses


def _diagonal(binding):
    return float(np.linalg.norm(np.ptp(binding.mesh_vertices, axis=0)))


def _deformed64(binding, positions):
    """The cage deformation in float64 (the reference a skin is measured against)."""
    return np.einsum("vl,fld->fvd", binding.weights.astype(np.float64), np.asarray(positions, dtype=np.float64))


def _validation_errors(stage):
    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    return [e.GetMessage() for e in context.Validate(stage) if e.GetType() == UsdValidation.ValidationErrorType.Error]


def _baked_world(path, prims, times):
    """pxr's own skinning of the rig, baked on a fresh stage: world-space points of ``prims`` (concatenated) per
    time."""
    stage = Usd.Stage.Open(str(path))
    assert UsdSkel.BakeSkinning(stage.Traverse())
    out = []
    for t in times:
        cache = UsdGeom.XformCache(Usd.TimeCode(t))
        frame = []
        for prim_path in prims:
            prim = stage.GetPrimAtPath(prim_path)
            local = np.asarray(UsdGeom.Mesh(prim).GetPointsAttr().Get(Usd.TimeCode(t)), dtype=np.float64)
            matrix = np.array(cache.GetLocalToWorldTransform(prim))
            frame.append(local @ matrix[:3, :3] + matrix[3, :3])
        out.append(np.concatenate(frame))
    return np.stack(out)


def test_skin_weights_keep_the_largest_and_sum_to_one(arm):
    binding, _ = arm
    every = ws.skin_weights(binding)
    assert every.complete and every.influences == binding.n_handles
    np.testing.assert_array_equal(every.dense(), binding.weights.astype(np.float64))
    eight = ws.skin_weights(binding, 8)
    magnitude = np.abs(binding.weights)
    kept = np.take_along_axis(magnitude, eight.indices.astype(np.int64), axis=1)
    assert (kept.min(axis=1) >= np.sort(magnitude, axis=1)[:, -8] - 1e-7).all()  # the 8 largest, largest first
    assert (np.diff(np.abs(eight.weights), axis=1) <= 1e-7).all()
    np.testing.assert_allclose(eight.weights.sum(axis=1), 1.0, atol=1e-6)
    assert (binding.weights < 0).any()  # Stokes weights go negative: the non-negative skin removes them
    positive = ws.skin_weights(binding, 8, non_negative=True)
    assert (positive.weights >= 0).all() and positive.non_negative
    np.testing.assert_allclose(positive.weights.sum(axis=1), 1.0, atol=1e-6)
    for k in (0, binding.n_handles + 1):
        with pytest.raises(ws.WarpStokesError, match="influences must be an integer between 1 and"):
            ws.skin_weights(binding, k)


@pytest.mark.parametrize("influences,non_negative", [(None, False), (None, True), (8, False), (4, True)])
def test_skin_error_is_the_distance_of_an_independent_skinning(arm, influences, non_negative):
    binding, poses = arm
    skin = ws.skin_weights(binding, influences, non_negative)
    error = ws.skin_error(binding, skin, poses.positions)
    skinned = skin_points(binding.mesh_vertices, skin, binding.cage_vertices, poses.positions)
    distance = np.linalg.norm(skinned - _deformed64(binding, poses.positions), axis=2) / _diagonal(binding)
    # both float64: they differ by rounding of sums of ~L terms of the coordinates' size
    assert error.max == pytest.approx(distance.max(), abs=1e-9)
    assert error.rms == pytest.approx(np.sqrt(np.mean(distance**2)), abs=1e-9)
    assert int(np.argmax(distance.max(axis=1))) == error.frame or distance.max(axis=1)[error.frame] == \
        pytest.approx(distance.max(), abs=1e-9)
    if skin.complete:  # every weight: the skin is the deformation (to the binding's linear precision)
        assert error.max < 1e-5
    else:
        assert error.max > 1e-4  # the bend moves the arm by a third of its length: truncation shows


def test_usd_rig_is_played_by_pxr_as_the_deformation(arm, tmp_path):
    binding, poses = arm
    path = tmp_path / "arm_rig.usda"
    report = ws.write_skin(path, binding, poses, with_cage=True)
    assert report.influences == binding.n_handles and report.error.max < 1e-5 and report.frames == 24
    stage = Usd.Stage.Open(str(path))
    assert not _validation_errors(stage)
    root = stage.GetPrimAtPath("/Root")
    assert root.IsA(UsdSkel.Root) and stage.GetDefaultPrim() == root
    skeleton = UsdSkel.Skeleton(stage.GetPrimAtPath("/Root/CageSkeleton"))
    joints = list(skeleton.GetJointsAttr().Get())
    assert joints[:2] == ["handle_000", "handle_001"] and len(joints) == binding.n_handles
    bind = np.array(skeleton.GetBindTransformsAttr().Get())
    np.testing.assert_allclose(bind[:, 3, :3], binding.cage_vertices)
    mesh = UsdGeom.Mesh(stage.GetPrimAtPath("/Root/Mesh"))
    assert not mesh.GetPointsAttr().GetTimeSamples()  # a rig, not baked points
    indices = UsdSkel.BindingAPI(mesh).GetJointIndicesPrimvar()
    assert indices.GetElementSize() == binding.n_handles and indices.GetInterpolation() == UsdGeom.Tokens.vertex
    animation = UsdSkel.Animation(stage.GetPrimAtPath("/Root/CageAnimation"))
    assert animation.GetTranslationsAttr().GetTimeSamples() == list(poses.frames)
    assert stage.GetRootLayer().customLayerData["warpStokes"]["influences"] == binding.n_handles
    # pxr's skinning equals the deformation within 1e-5 of the diagonal; the cage, bound rigidly, follows the poses
    baked = _baked_world(path, ["/Root/Mesh"], poses.frames)
    assert np.linalg.norm(baked - binding.deform(poses.positions), axis=2).max() / _diagonal(binding) < 1e-5
    cage = _baked_world(path, ["/Root/Cage"], poses.frames)
    np.testing.assert_allclose(cage, poses.positions, atol=1e-5 * _diagonal(binding))
    # the SkelRoot's extent holds the animation
    lo_hi = np.array(UsdGeom.Boundable(root).GetExtentAttr().Get(Usd.TimeCode(poses.frames[-1])))
    assert (baked[-1] >= lo_hi[0] - 1e-4).all() and (baked[-1] <= lo_hi[1] + 1e-4).all()


def test_usd_rig_over_an_asset_is_an_override_that_pxr_plays(asset, tmp_path):
    path, binding, poses = asset
    before = path.read_bytes()
    out = tmp_path / "rig.usda"
    report = ws.write_skin(out, binding, poses, influences=4, with_cage=True)
    assert path.read_bytes() == before
    layer = Sdf.Layer.FindOrOpen(str(out))
    # the asset's prims are overrides in the layer; only the skeleton and its animation are defined there
    specs = {p: layer.GetPrimAtPath(Sdf.Path(p)).specifier for p in (BODY, BAND, CAGE, "/Char/Geo")}
    assert set(specs.values()) == {Sdf.SpecifierOver}
    # the SkelRoot is the meshes' common parent (rotated and scaled in the asset), the joints in its space: the
    # meshes' geom bind transforms are their transforms relative to it (here none), as Blender's importer reads them
    assert layer.GetPrimAtPath(Sdf.Path("/Char/Geo")).typeName == "SkelRoot"
    stage = Usd.Stage.Open(str(out))
    assert not _validation_errors(stage)
    for prim in (BODY, BAND):
        bind = UsdSkel.BindingAPI(stage.GetPrimAtPath(prim)).GetGeomBindTransformAttr().Get()
        np.testing.assert_allclose(np.array(bind), np.eye(4), atol=1e-12)
    assert not UsdGeom.Xformable(stage.GetPrimAtPath("/Char/Geo/CageSkeleton")).GetResetXformStack()
    body = UsdGeom.Mesh(stage.GetPrimAtPath(BODY))
    assert body.GetNormalsAttr().Get() is None  # blocked: translation-only joints leave normals stale
    # pxr's skinning of the truncated rig is as far from the deformation as reported (float32 rounding aside)
    baked = _baked_world(out, [BODY, BAND], poses.frames)
    diagonal = _diagonal(binding)
    distance = np.linalg.norm(baked - binding.deform(poses.positions), axis=2).max() / diagonal
    assert report.error.max > 1e-3 and distance == pytest.approx(report.error.max, abs=1e-5)
    np.testing.assert_allclose(_baked_world(out, [CAGE], poses.frames), poses.positions, atol=1e-5 * diagonal)
    # all influences: within 1e-5 of the diagonal
    exact = tmp_path / "rig_all.usd"
    ws.write_skin(exact, binding, poses)
    baked = _baked_world(exact, [BODY, BAND], poses.frames)
    assert np.linalg.norm(baked - binding.deform(poses.positions), axis=2).max() / diagonal < 1e-5


def _read_gltf(path):
    """Accessors of a glTF file decoded with numpy: (gltf, accessor reader)."""
    gltf = pygltflib.GLTF2.load(str(path))
    blob = gltf.binary_blob() if str(path).endswith(".glb") else base64.b64decode(gltf.buffers[0].uri.split(",")[1])
    dtypes = {5126: np.float32, 5121: np.uint8, 5123: np.uint16, 5125: np.uint32}
    widths = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}

    def read(index):
        accessor = gltf.accessors[index]
        view = gltf.bufferViews[accessor.bufferView]
        width, dtype = widths[accessor.type], np.dtype(dtypes[accessor.componentType])
        start = view.byteOffset + (accessor.byteOffset or 0)
        return np.frombuffer(blob, dtype, accessor.count * width, start).reshape(accessor.count, width)

    return gltf, read


def _gltf_skinned(path):
    """Every mesh node of a glTF skin skinned on the CPU at every key time, as glTF defines it (joint matrix =
    joint's global transform x inverse bind matrix): (rest positions, skinned (T, N, 3), times, UVs), all parts
    concatenated, in glTF space."""
    gltf, read = _read_gltf(path)
    skin = gltf.skins[0]
    inverse_bind = read(skin.inverseBindMatrices).reshape(-1, 4, 4).transpose(0, 2, 1).astype(np.float64)
    animation = gltf.animations[0]
    times = read(animation.samplers[0].input)[:, 0]
    local = np.zeros((len(times), len(skin.joints), 4, 4)) + np.eye(4)
    for channel in animation.channels:
        assert channel.target.path == "translation"
        local[:, skin.joints.index(channel.target.node), :3, 3] = read(animation.samplers[channel.sampler].output)
    parent = np.array(gltf.nodes[skin.skeleton].matrix or np.eye(4).ravel()).reshape(4, 4).T
    joint_matrix = parent @ local @ inverse_bind  # (T, L, 4, 4)
    rest, skinned, uvs = [], [], []
    for node in gltf.scenes[gltf.scene].nodes:
        if gltf.nodes[node].mesh is None:
            continue
        assert gltf.nodes[node].skin == 0 and gltf.nodes[node].matrix is None
        attributes = gltf.meshes[gltf.nodes[node].mesh].primitives[0].attributes
        points = read(attributes.POSITION).astype(np.float64)
        sets = [s for s in range(4) if getattr(attributes, f"JOINTS_{s}", None) is not None]
        joints = np.concatenate([read(getattr(attributes, f"JOINTS_{s}")) for s in sets], axis=1).astype(np.int64)
        weights = np.concatenate([read(getattr(attributes, f"WEIGHTS_{s}")) for s in sets], axis=1).astype(float)
        assert (weights >= 0).all()
        np.testing.assert_allclose(weights.sum(axis=1), 1.0, atol=1e-6)
        homogeneous = np.concatenate([points, np.ones((len(points), 1))], axis=1)
        moved = np.einsum("vk,tvkij,vj->tvi", weights, joint_matrix[:, joints], homogeneous)[..., :3]
        rest.append(points)
        skinned.append(moved)
        uvs.append(None if attributes.TEXCOORD_0 is None else read(attributes.TEXCOORD_0))
    return np.concatenate(rest), np.concatenate(skinned, axis=1), times, uvs, parent


@pytest.mark.parametrize("influences,ext", [(4, ".glb"), (8, ".gltf")])
def test_gltf_skin_skinned_with_numpy_is_as_far_as_reported(arm, tmp_path, influences, ext):
    binding, poses = arm
    path = tmp_path / f"arm{ext}"
    report = ws.write_skin(path, binding, poses, influences=influences)
    assert report.non_negative and report.influences == influences
    rest, skinned, times, _, parent = _gltf_skinned(path)
    np.testing.assert_allclose(parent, np.eye(4))  # an OBJ's binding: no unit or axis conversion
    np.testing.assert_allclose(times, poses.frames / 24.0, rtol=1e-6)
    assert len(rest) == binding.n_vertices  # no UVs: no vertex split
    np.testing.assert_allclose(rest, binding.mesh_vertices, atol=1e-5 * _diagonal(binding))
    distance = np.linalg.norm(skinned - binding.deform(poses.positions), axis=2).max() / _diagonal(binding)
    assert distance == pytest.approx(report.error.max, abs=1e-5)
    gltf, _ = _read_gltf(path)
    assert gltf.asset.extras["maxError"] == pytest.approx(report.error.max)
    import trimesh

    scene = trimesh.load_scene(str(path))  # a generic reader takes the geometry
    assert sum(len(g.vertices) for g in scene.geometry.values()) == binding.n_vertices


def test_gltf_skin_of_an_asset_is_in_metres_y_up_with_its_uvs(asset, tmp_path):
    path, binding, poses = asset
    out = tmp_path / "char.glb"
    report = ws.write_skin(out, binding, poses, influences=8)
    rest, skinned, times, uvs, parent = _gltf_skinned(out)
    # the asset is Z-up in centimetres: the skeleton's root node turns it to Y-up metres
    to_gltf = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]) * 0.01
    np.testing.assert_allclose(parent[:3, :3], to_gltf, atol=1e-12)
    np.testing.assert_allclose(times, np.asarray(TIMES) / 30.0, rtol=1e-6)
    assert len(rest) == binding.n_vertices  # both parts, in the binding's order
    world = skinned @ np.linalg.inv(to_gltf).T  # back to the binding's world space
    distance = np.linalg.norm(world - binding.deform(poses.positions), axis=2).max() / _diagonal(binding)
    assert distance == pytest.approx(report.error.max, abs=1e-5)


def test_gltf_skin_splits_vertices_at_uv_seams(tmp_path):
    from usd_assets import box_quads

    cage = ws.load_surface(EXAMPLE / "arm_cage.obj")
    diagonal = float(np.linalg.norm(np.ptp(cage.vertices, axis=0)))
    points, quads, st, _ = box_quads(cage.vertices.mean(axis=0), 0.03 * diagonal)
    st = st + np.repeat(np.arange(6), 4)[:, None] * [0.1, 0.0]  # every face its own UVs: each corner in 3 seams
    with open(tmp_path / "box.obj", "w") as fh:
        fh.writelines(f"v {x} {y} {z}\n" for x, y, z in points)
        fh.writelines(f"vt {u} {v}\n" for u, v in st)
        for q, quad in enumerate(quads):
            fh.write("f " + " ".join(f"{v + 1}/{4 * q + c + 1}" for c, v in enumerate(quad)) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(tmp_path / "box.obj", EXAMPLE / "arm_cage.obj", resolution=16, device="cpu")
    report = ws.write_skin(tmp_path / "box.glb", binding,
                           np.stack([binding.cage_vertices, binding.cage_vertices * 1.1]))
    rest, skinned, _, uvs, _ = _gltf_skinned(tmp_path / "box.glb")
    corners = np.array([[*points[v], u, 1 - w]  # glTF's v runs down the image
                        for quad, face_st in zip(quads, st.reshape(6, 4, 2)) for v, (u, w) in zip(quad, face_st)])
    written = np.concatenate([rest, uvs[0]], axis=1)
    gap = np.linalg.norm(written[:, None] - corners[None], axis=2)
    assert len(rest) == 24 and sorted(np.argmin(gap, axis=1)) == list(range(24)) and gap.min(axis=1).max() < 1e-4
    gltf, read = _read_gltf(tmp_path / "box.glb")
    triangles = read(gltf.meshes[0].primitives[0].indices).reshape(-1, 3)
    assert len(triangles) == 12  # two per quad
    # split vertices move together, as far from the deformation as reported
    deformed = binding.deform(binding.cage_vertices * 1.1)
    copy_of = np.argmin(np.linalg.norm(rest[:, None] - binding.mesh_vertices[None], axis=2), axis=1)
    for corner in range(8):
        np.testing.assert_allclose(skinned[1][copy_of == corner], skinned[1][copy_of == corner][:1].repeat(3, 0),
                                   atol=1e-9 * diagonal)
    distance = np.linalg.norm(skinned[1] - deformed[copy_of], axis=1).max() / _diagonal(binding)
    assert distance == pytest.approx(report.error.max, abs=1e-5)


def test_animate_writes_skins_from_the_command_line(arm_npz, tmp_path):
    poses = str(EXAMPLE / "bend_poses.npy")
    rig = tmp_path / "rig.usd"
    proc = cli("animate", str(arm_npz), poses, "-o", str(rig), "--skeleton", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    assert "UsdSkel stage" in proc.stdout and "all influences" in proc.stdout and "of the diagonal" in proc.stdout
    # Stokes weights go negative: what consumers that drop them play is measured and said
    assert "consumers that drop negative weights (Blender) play it" in proc.stdout
    binding = ws.load_binding(arm_npz, device="cpu")
    positions = np.load(poses)
    baked = _baked_world(rig, ["/Root/Mesh"], np.arange(1.0, 25.0))
    assert np.linalg.norm(baked - binding.deform(positions), axis=2).max() / _diagonal(binding) < 1e-5
    glb = tmp_path / "arm.glb"
    proc = cli("animate", str(arm_npz), poses, "-o", str(glb), "--influences", "4", "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    assert "glTF skin" in proc.stdout and "4 influences per vertex, non-negative" in proc.stdout
    reported = float(proc.stdout.split("max ")[1].split(",")[0])
    _, skinned, *_ = _gltf_skinned(glb)
    distance = np.linalg.norm(skinned - binding.deform(positions), axis=2).max() / _diagonal(binding)
    assert distance == pytest.approx(reported, rel=0.01, abs=1e-5)
    # a skin further than --max-error is refused, in one line, and nothing is written
    refused = tmp_path / "refused.glb"
    proc = cli("animate", str(arm_npz), poses, "-o", str(refused), "--influences", "4", "--max-error",
               f"{reported / 2:g}", "--device", "cpu")
    assert proc.returncode == 2 and "keep more influences" in one_error_line(proc)
    assert not refused.exists() and not [p for p in os.listdir(tmp_path) if "refused" in p]


@pytest.mark.parametrize("args,message", [
    (["-o", "x.usd", "--influences", "4"], "add --skeleton"),
    (["-o", "x.usd", "--skeleton", "--with-weights"], "carries its weights"),
    (["-o", "x.glb", "--with-cage"], "takes no cage"),
    (["-o", "x.glb", "--influences", "99"], "between 1 and the cage's 58 handles"),
    (["-o", "x.fbx", "--skeleton"], "must end in .usd"),
])
def test_animate_refuses_skin_options_it_cannot_honour(arm_npz, tmp_path, args, message):
    args = [str(tmp_path / a) if a.startswith("x.") else a for a in args]
    proc = cli("animate", str(arm_npz), str(EXAMPLE / "bend_poses.npy"), *args, "--device", "cpu")
    assert proc.returncode == 2 and message in one_error_line(proc)
    assert not os.listdir(tmp_path)


def test_batch_writes_skins_and_records_their_error(tmp_path):
    import json

    manifest = tmp_path / "skins.toml"
    manifest.write_text(f"""
[defaults]
resolution = 16
mesh = "{EXAMPLE / 'arm.obj'}"
cage = "{EXAMPLE / 'arm_cage.obj'}"
poses = "{EXAMPLE / 'bend_poses.npy'}"

[[asset]]
name = "arm_glb"
skin = "glb"
influences = 4

[[asset]]
name = "arm_rig"
skin = "usd"
""")
    proc = cli("batch", str(manifest), "-o", str(tmp_path / "out"), "--device", "cpu")
    assert proc.returncode == 0, proc.stderr
    assert sorted(os.listdir(tmp_path / "out")) == ["arm_glb.glb", "arm_glb.npz", "arm_rig.npz", "arm_rig.usd",
                                                    "summary.json"]
    records = {a["name"]: a for a in json.loads((tmp_path / "out" / "summary.json").read_text())["assets"]}
    assert records["arm_glb"]["skin_error"]["influences"] == 4 and records["arm_glb"]["skin_error"]["max"] > 1e-3
    assert records["arm_rig"]["skin_error"]["influences"] == 58 and records["arm_rig"]["skin_error"]["max"] < 1e-5
    binding = ws.load_binding(tmp_path / "out" / "arm_rig.npz", device="cpu")
    baked = _baked_world(tmp_path / "out" / "arm_rig.usd", ["/Root/Mesh"], np.arange(1.0, 25.0))
    deformed = binding.deform(np.load(EXAMPLE / "bend_poses.npy"))
    assert np.linalg.norm(baked - deformed, axis=2).max() / _diagonal(binding) < 1e-5


@pytest.mark.parametrize("entry,message", [
    ('skin = "fbx"', "'skin' must be one of"),
    ("influences = 4", "'influences' set without 'skin'"),
    ('skin = "glb"\nwith_cage = true', "only a USD rig carries the cage"),
    ('skin = "usd"\ninfluences = 0', "'influences' must be a positive integer"),
])
def test_batch_refuses_skin_keys_before_any_work(tmp_path, entry, message):
    manifest = tmp_path / "bad.toml"
    manifest.write_text(f'[[asset]]\nmesh = "{EXAMPLE / "arm.obj"}"\ncage = "{EXAMPLE / "arm_cage.obj"}"\n'
                        f'poses = "{EXAMPLE / "bend_poses.npy"}"\n{entry}\n')
    proc = cli("batch", str(manifest), "-o", str(tmp_path / "out"), "--device", "cpu")
    assert proc.returncode == 2 and message in one_error_line(proc)
    assert not (tmp_path / "out").exists() or not os.listdir(tmp_path / "out")


def test_usd_rig_is_the_deformation_where_the_skel_root_moves(tmp_path):
    """The joints are in the SkelRoot's space per time code: a root animated in the asset (turning and moving) leaves
    the skinned points where the deformation puts them in world space."""
    from pxr import Gf

    mesh, cage = ws.load_surface(EXAMPLE / "arm.obj"), ws.load_surface(EXAMPLE / "arm_cage.obj")
    diagonal = float(np.linalg.norm(np.ptp(cage.vertices, axis=0)))
    path = tmp_path / "moving.usda"
    write_asset(path, mesh, cage, cage.vertices.mean(axis=0), 0.03 * diagonal)
    stage = Usd.Stage.Open(str(path))
    op = UsdGeom.Xformable(stage.GetPrimAtPath("/Char/Geo")).GetOrderedXformOps()[0]
    rest = op.Get()
    for k, t in enumerate(TIMES):
        op.Set(Gf.Matrix4d(rest) * Gf.Matrix4d().SetRotate(Gf.Rotation(Gf.Vec3d(1, 0, 0), 7.0 * k)) *
               Gf.Matrix4d().SetTranslate(Gf.Vec3d(0.3 * k, 0, 0)), t)
    stage.GetRootLayer().Save()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        binding = ws.bind(path, cage_prim=CAGE, resolution=16, device="cpu")
    poses = ws.load_poses(path, binding.cage_faces, binding.n_handles, cage_prim=CAGE)
    ws.write_skin(tmp_path / "rig.usda", binding, poses)
    baked = _baked_world(tmp_path / "rig.usda", [BODY, BAND], poses.frames)
    assert np.linalg.norm(baked - binding.deform(poses.positions), axis=2).max() / _diagonal(binding) < 1e-5
