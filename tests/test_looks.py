"""Materials and textures kept (issue 49): a textured input's looks come out of ``animate`` and ``deform`` as the
input had them. Each test runs the command line as a user does (in process, ``main(argv)``) and reads the outputs
back with the consumers' libraries: pygltflib for glTF (materials, textures, images and samplers counted, each
primitive's material, the images' bytes) and pxr for USD (``UsdShade.MaterialBindingAPI.ComputeBoundMaterial`` per
mesh or face subset, a ``UsdPreviewSurface`` whose ``UsdUVTexture`` reads a file identical to the input's image).

Inputs: the glTF sample Fox (``../shared/data/fox_gltf``: one material, one embedded PNG) with a cage made for it,
and characters made in code (:mod:`looks_inputs`): several parts and materials, glTF/GLB with images embedded or
beside them, and OBJ files with ``.mtl`` libraries.
"""

from __future__ import annotations

import base64
import json
import os
import shutil

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from conftest import DATA, box_cage, write_obj
from looks_inputs import CAGE_HI, CAGE_LO, LooksCase, write_gltf_case, write_obj_case
from warp_stokes.cli import main

pygltflib = pytest.importorskip("pygltflib")
FOX = DATA / "fox_gltf" / "Fox.glb"


# ----------------------------------------------------------------------------------------------------------------
# reading the outputs back as consumers do
# ----------------------------------------------------------------------------------------------------------------

def gltf_looks(path) -> dict:
    """What pygltflib reads of a glTF file's looks: counts, each mesh's primitives' materials (by mesh name), the
    material names, and each image's bytes."""
    gltf = pygltflib.GLTF2().load(str(path))
    if str(path).endswith(".glb"):
        blobs = {0: gltf.binary_blob()}
    else:
        blobs = {k: base64.b64decode(b.uri.split(",", 1)[1]) for k, b in enumerate(gltf.buffers)}
    images = []
    for image in gltf.images:
        if image.uri is not None:  # an image file beside it (an input's)
            images.append((path.parent / image.uri).read_bytes())
            continue
        view = gltf.bufferViews[image.bufferView]
        images.append(blobs[view.buffer][view.byteOffset or 0 : (view.byteOffset or 0) + view.byteLength])
    return {"counts": (len(gltf.materials), len(gltf.textures), len(gltf.images), len(gltf.samplers)),
            "primitives": {m.name: [p.material for p in m.primitives] for m in gltf.meshes},
            "names": [m.name for m in gltf.materials], "images": images, "gltf": gltf}


def source_images(path) -> list[bytes]:
    """The bytes of each image of an input glTF, by pygltflib."""
    gltf = pygltflib.GLTF2().load(str(path))
    blob = gltf.binary_blob() if str(path).endswith(".glb") else None
    found = []
    for image in gltf.images:
        if image.uri is not None and not image.uri.startswith("data:"):
            found.append((path.parent / image.uri).read_bytes())
            continue
        view = gltf.bufferViews[image.bufferView]
        data = blob if blob is not None else base64.b64decode(gltf.buffers[view.buffer].uri.split(",", 1)[1])
        found.append(data[(view.byteOffset or 0) : (view.byteOffset or 0) + view.byteLength])
    return found


def usd_looks(path) -> dict:
    """What pxr reads of a stage's looks: the materials (by name), and for each mesh (by name) the (faces or None
    for the whole mesh, material name, diffuse image's bytes or None) of each binding, by
    ``ComputeBoundMaterial``; each bound material checked to be a UsdPreviewSurface whose texture is a
    UsdUVTexture reading the ``st`` primvar."""
    from pxr import Usd, UsdGeom, UsdShade

    stage = Usd.Stage.Open(str(path))
    materials = sorted(p.GetName() for p in stage.Traverse() if p.IsA(UsdShade.Material))
    meshes = {}
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh) or prim.GetName() == "Cage":
            continue
        subsets = UsdShade.MaterialBindingAPI(prim).GetMaterialBindSubsets()
        targets = [(list(s.GetIndicesAttr().Get()), s.GetPrim()) for s in subsets] or [(None, prim)]
        bound = []
        for faces, target in targets:
            material, _ = UsdShade.MaterialBindingAPI(target).ComputeBoundMaterial()
            if not material:
                bound.append((faces, None, None))
                continue
            shader = material.ComputeSurfaceSource()[0]
            assert shader.GetIdAttr().Get() == "UsdPreviewSurface"
            bound.append((faces, material.GetPrim().GetName(), _diffuse_image(shader)))
        meshes[prim.GetName()] = bound
    return {"materials": materials, "meshes": meshes}


def _diffuse_image(shader):
    """The bytes of the image a UsdPreviewSurface's diffuseColor reads through a UsdUVTexture, or None."""
    from pxr import UsdShade

    diffuse = shader.GetInput("diffuseColor")
    if not diffuse.HasConnectedSource():
        return None
    texture = UsdShade.Shader(diffuse.GetConnectedSource()[0].GetPrim())
    assert texture.GetIdAttr().Get() == "UsdUVTexture"
    reader = UsdShade.Shader(texture.GetInput("st").GetConnectedSource()[0].GetPrim())
    assert reader.GetIdAttr().Get() == "UsdPrimvarReader_float2" and reader.GetInput("varname").Get() == "st"
    asset = texture.GetInput("file").Get()
    assert asset.resolvedPath, f"{asset.path} does not resolve"
    with open(asset.resolvedPath, "rb") as fh:
        return fh.read()


# ----------------------------------------------------------------------------------------------------------------
# the Fox
# ----------------------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def fox(tmp_path_factory):
    """The Fox bound to a cage made for it (``bind Fox.glb auto``, resolution 12, CPU) and three poses."""
    if not FOX.exists():
        pytest.skip(f"test data not found: {FOX} (set WARP_STOKES_DATA)")
    folder = tmp_path_factory.mktemp("fox")
    here = os.getcwd()
    os.chdir(folder)
    try:
        assert main(["bind", str(FOX), "auto", "-o", "fox.npz", "--handles", "40", "--resolution", "12",
                     "--device", "cpu", "--quiet"]) == 0
    finally:
        os.chdir(here)
    import warp_stokes as ws

    cage = ws.load_binding(folder / "fox.npz", device="cpu").cage_vertices
    np.save(folder / "poses.npy", np.stack([cage, cage + [0.0, 5.0, 0.0], cage * 1.1]))
    np.save(folder / "pose.npy", cage + [2.0, 0.0, 0.0])
    return folder


def test_fox_as_a_glb_skin_and_a_posed_glb_keeps_its_material_and_texture(fox, tmp_path, capsys):
    source = gltf_looks(FOX)
    out, posed = tmp_path / "fox.glb", tmp_path / "fox_posed.glb"
    assert main(["animate", str(fox / "fox.npz"), str(fox / "poses.npy"), "-o", str(out), "--device", "cpu"]) == 0
    assert main(["deform", str(fox / "fox.npz"), str(fox / "pose.npy"), "-o", str(posed), "--device", "cpu"]) == 0
    assert "warning" not in capsys.readouterr().err
    for written in (out, posed):
        looks = gltf_looks(written)
        assert looks["counts"] == source["counts"] == (1, 1, 1, 1)
        assert looks["names"] == ["fox_material"]
        assert all(material == 0 for primitives in looks["primitives"].values() for material in primitives)
        assert looks["images"] == source_images(FOX)
        material = looks["gltf"].materials[0]
        assert material.pbrMetallicRoughness.baseColorTexture.index == 0
        assert material.pbrMetallicRoughness.roughnessFactor == pytest.approx(0.58)
        assert looks["gltf"].samplers[0].minFilter == 9987  # the input's sampler, as it was


@pytest.mark.parametrize("skeleton", [False, True])
def test_fox_as_a_usd_stage_keeps_its_material_and_texture(fox, tmp_path, capsys, skeleton):
    out = tmp_path / "fox.usda"
    assert main(["animate", str(fox / "fox.npz"), str(fox / "poses.npy"), "-o", str(out), "--device", "cpu"]
                + (["--skeleton"] if skeleton else [])) == 0
    assert "warning" not in capsys.readouterr().err
    looks = usd_looks(out)
    assert looks["materials"] == ["fox_material"]
    assert looks["meshes"] == {"Mesh": [(None, "fox_material", source_images(FOX)[0])]}
    assert sorted(os.listdir(tmp_path)) == ["fox.image0.png", "fox.usda"]


# ----------------------------------------------------------------------------------------------------------------
# characters made in code: two materials, OBJ with .mtl
# ----------------------------------------------------------------------------------------------------------------

@pytest.fixture
def work(tmp_path, monkeypatch):
    """A working folder with the cage every made character fits in, and two poses of it."""
    vertices, faces = box_cage(CAGE_LO, CAGE_HI)
    write_obj(tmp_path / "cage.obj", vertices, faces)
    np.save(tmp_path / "poses.npy", np.stack([vertices, vertices * 1.1 + [0.0, 0.2, 0.0]]))
    monkeypatch.chdir(tmp_path)
    return tmp_path


def bind_and_write(name: str, outputs=("out.glb", "out.usda")) -> None:
    assert main(["bind", name, "cage.obj", "-o", "b.npz", "--resolution", "8", "--device", "cpu", "--quiet"]) == 0
    for output in outputs:
        assert main(["animate", "b.npz", "poses.npy", "-o", output, "--device", "cpu"]) == 0


@pytest.mark.parametrize("name,case", [
    ("two.glb", LooksCase((0, 1), (True, False), embedded=True)),
    ("two.gltf", LooksCase((1, 0), (True, True), embedded=False, one_mesh=True)),
])
def test_a_two_material_gltf_keeps_both_on_their_parts(work, capsys, name, case):
    write_gltf_case(work / name, case)
    bind_and_write(name)
    assert "warning" not in capsys.readouterr().err
    source = gltf_looks(work / name)
    out = gltf_looks(work / "out.glb")
    assert out["counts"] == source["counts"] and out["names"] == ["mat0", "mat1"]
    assert out["images"] == source_images(work / name) == case.images()
    parts = sorted(out["primitives"])
    assert [out["primitives"][p] for p in parts] == [[m] for m in case.part_materials]
    usd = usd_looks(work / "out.usda")
    assert usd["materials"] == ["mat0", "mat1"]
    images = dict(zip(range(len(case.textured)), _images_by_material(case)))
    for part, material in zip(sorted(usd["meshes"]), case.part_materials):
        assert usd["meshes"][part] == [(None, f"mat{material}", images[material])]


def _images_by_material(case: LooksCase) -> list:
    images = iter(case.images())
    return [next(images) if textured else None for textured in case.textured]


def test_an_obj_with_a_material_library_keeps_its_colours_and_textures(work, capsys):
    case = LooksCase((0, 1, 2), (True, False, True))
    write_obj_case(work / "char.obj", case)
    bind_and_write("char.obj", ("out.glb", "out.usda", "out.gltf"))
    assert "warning" not in capsys.readouterr().err
    for glb in ("out.glb", "out.gltf"):
        out = gltf_looks(work / glb)
        assert out["counts"] == (3, 2, 2, 0) and out["names"] == ["mat0", "mat1", "mat2"]
        assert out["images"] == case.images() and out["primitives"] == {"char.obj": [0, 1, 2]}
        plain = out["gltf"].materials[1].pbrMetallicRoughness  # Kd, no map_Kd: the colour itself
        assert plain.baseColorTexture is None
        assert plain.baseColorFactor == pytest.approx([c / 255 for c in case.colours[1]] + [1.0], abs=1e-6)
    usd = usd_looks(work / "out.usda")
    assert usd["materials"] == ["mat0", "mat1", "mat2"]
    images = _images_by_material(case)
    # one mesh, a subset of its faces per material: each box's 12 triangles
    assert usd["meshes"]["Mesh"] == [(list(range(12 * k, 12 * k + 12)), f"mat{k}", images[k]) for k in range(3)]


def test_every_texture_of_a_material_maps_onto_the_preview_surface(work):
    """A material with base colour, metallic-roughness, normal, emissive and occlusion textures and an alpha mask:
    each UsdPreviewSurface input is fed by a UsdUVTexture of the right channel, colour space and factor."""
    from pxr import Usd, UsdShade

    write_gltf_case(work / "full.glb", LooksCase((0,), (True,)))
    gltf = pygltflib.GLTF2().load(str(work / "full.glb"))
    material = gltf.materials[0]
    material.normalTexture = pygltflib.NormalMaterialTexture(index=0, scale=0.5)
    material.emissiveTexture, material.emissiveFactor = pygltflib.TextureInfo(index=0), [1.0, 0.5, 0.0]
    material.occlusionTexture = pygltflib.OcclusionTextureInfo(index=0, strength=0.8)
    material.pbrMetallicRoughness.metallicRoughnessTexture = pygltflib.TextureInfo(index=0)
    material.alphaMode, material.alphaCutoff = "MASK", 0.3
    gltf.save_binary(str(work / "full.glb"))
    bind_and_write("full.glb", ("out.usda",))
    stage = Usd.Stage.Open(str(work / "out.usda"))
    surface = UsdShade.Shader(stage.GetPrimAtPath("/Root/Looks/mat0/PreviewSurface"))
    fed = {}
    for name in ("diffuseColor", "metallic", "roughness", "normal", "emissiveColor", "occlusion", "opacity"):
        source, channel, _ = surface.GetInput(name).GetConnectedSource()
        texture = UsdShade.Shader(source.GetPrim())
        fed[name] = (source.GetPrim().GetName(), channel, texture.GetInput("sourceColorSpace").Get(),
                     tuple(round(x, 3) for x in texture.GetInput("scale").Get()))
    assert fed == {"diffuseColor": ("BaseColorTexture", "rgb", "sRGB", (1.0, 1.0, 1.0, 1.0)),
                   "opacity": ("BaseColorTexture", "a", "sRGB", (1.0, 1.0, 1.0, 1.0)),
                   "metallic": ("MetallicRoughnessTexture", "b", "raw", (1.0, 0.7, 0.0, 1.0)),
                   "roughness": ("MetallicRoughnessTexture", "g", "raw", (1.0, 0.7, 0.0, 1.0)),
                   "normal": ("NormalTexture", "rgb", "raw", (1.0, 1.0, 2.0, 1.0)),
                   "emissiveColor": ("EmissiveTexture", "rgb", "sRGB", (1.0, 0.5, 0.0, 1.0)),
                   "occlusion": ("OcclusionTexture", "r", "raw", (0.8, 0.8, 0.8, 1.0))}
    assert surface.GetInput("opacityThreshold").Get() == pytest.approx(0.3)
    assert sorted(os.listdir(work)).count("out.image0.png") == 1  # one file for the five textures


def test_deform_to_glb_keeps_the_parts_and_their_materials(work, capsys):
    case = LooksCase((1, 0), (False, True), embedded=True)
    write_gltf_case(work / "two.glb", case)
    bind_and_write("two.glb", ())
    np.save(work / "pose.npy", np.load(work / "poses.npy")[1])
    assert main(["deform", "b.npz", "pose.npy", "-o", "posed.glb", "--device", "cpu"]) == 0
    out = gltf_looks(work / "posed.glb")
    assert out["counts"] == (2, 1, 1, 1) and out["primitives"] == {"part0": [1], "part1": [0]}
    assert out["images"] == case.images()


def test_a_materials_extensions_are_carried_as_they_are_and_a_damaged_material_left_out(work, capsys):
    write_gltf_case(work / "ext.glb", LooksCase((0, 1), (True, False)))
    gltf = pygltflib.GLTF2().load(str(work / "ext.glb"))
    gltf.materials[0].extensions = {"KHR_materials_emissive_strength": {"emissiveStrength": 2.5}}
    gltf.materials[0].pbrMetallicRoughness.baseColorTexture.extensions = {
        "KHR_texture_transform": {"scale": [2.0, 2.0]}}
    gltf.extensionsUsed = ["KHR_materials_emissive_strength", "KHR_texture_transform"]
    gltf.save_binary(str(work / "ext.glb"))
    bind_and_write("ext.glb", ("out.glb",))
    out = gltf_looks(work / "out.glb")["gltf"]
    assert out.materials[0].extensions == {"KHR_materials_emissive_strength": {"emissiveStrength": 2.5}}
    assert out.materials[0].pbrMetallicRoughness.baseColorTexture.extensions == {
        "KHR_texture_transform": {"scale": [2.0, 2.0]}}
    assert sorted(out.extensionsUsed) == ["KHR_materials_emissive_strength", "KHR_texture_transform"]
    gltf.materials[1].doubleSided = "yes"  # not true or false: trimesh reads the mesh, the material is damaged
    gltf.save_binary(str(work / "ext.glb"))
    capsys.readouterr()
    bind_and_write("ext.glb", ("bad.glb",))
    assert "ext.glb: its materials are left out (material 1: doubleSided is not true or false)" in \
        capsys.readouterr().err
    assert gltf_looks(work / "bad.glb")["counts"] == (0, 0, 0, 0)


def test_a_texture_on_a_second_uv_set_is_said(work, capsys):
    write_gltf_case(work / "uv1.glb", LooksCase((0,), (True,)))
    gltf = pygltflib.GLTF2().load(str(work / "uv1.glb"))
    gltf.materials[0].pbrMetallicRoughness.baseColorTexture.texCoord = 1
    gltf.save_binary(str(work / "uv1.glb"))
    bind_and_write("uv1.glb", ("out.glb",))
    assert "uv1.glb: material 0's baseColorTexture uses a second set of texture coordinates, which is not kept" in \
        capsys.readouterr().err
    assert gltf_looks(work / "out.glb")["counts"] == (1, 1, 1, 1)


# ----------------------------------------------------------------------------------------------------------------
# when the looks' files moved or changed since the bind
# ----------------------------------------------------------------------------------------------------------------

def test_an_image_changed_since_the_bind_is_left_out_with_a_warning_never_replaced(work, capsys):
    write_obj_case(work / "char.obj", LooksCase((0, 1), (True, True)))
    bind_and_write("char.obj", ())
    capsys.readouterr()
    (work / "char_tex1.png").write_bytes(b"\x89PNG\r\n\x1a\nnot the same image")
    assert main(["animate", "b.npz", "poses.npy", "-o", "out.glb", "--device", "cpu"]) == 0
    assert main(["animate", "b.npz", "poses.npy", "-o", "out.usda", "--device", "cpu"]) == 0
    err = capsys.readouterr().err
    assert "image char_tex1.png of its materials is not found as the bind recorded it" in err
    assert "changed since the bind" in err
    out = gltf_looks(work / "out.glb")
    assert out["counts"] == (2, 1, 1, 0) and out["images"] == [LooksCase((0,), (True,)).images()[0]]
    assert out["gltf"].materials[1].pbrMetallicRoughness.baseColorTexture is None  # its colour kept: grey-ish
    usd = usd_looks(work / "out.usda")
    assert [(m, image is not None) for _, m, image in usd["meshes"]["Mesh"]] == [("mat0", True), ("mat1", False)]
    assert not (work / "out.char_tex1.png").exists()


def test_a_source_gone_since_the_bind_leaves_grey_materials_and_a_moved_folder_is_found(work, tmp_path, capsys,
                                                                                       monkeypatch):
    project = work / "project"
    project.mkdir()
    write_gltf_case(project / "two.glb", LooksCase((0, 1), (True, True), embedded=True))
    shutil.copy(work / "cage.obj", project / "cage.obj")
    shutil.copy(work / "poses.npy", project / "poses.npy")
    monkeypatch.chdir(project)
    bind_and_write("two.glb", ())
    moved = work / "moved"
    shutil.move(project, moved)
    monkeypatch.chdir(moved)  # the folder moved whole: the glTF found by the name the bind was given
    assert main(["animate", "b.npz", "poses.npy", "-o", "out.glb", "--device", "cpu"]) == 0
    assert "warning" not in capsys.readouterr().err
    assert gltf_looks(moved / "out.glb")["counts"] == (2, 2, 2, 1)
    os.unlink(moved / "two.glb")
    assert main(["animate", "b.npz", "poses.npy", "-o", "grey.glb", "--device", "cpu"]) == 0
    assert main(["animate", "b.npz", "poses.npy", "-o", "grey.usda", "--device", "cpu"]) == 0
    err = capsys.readouterr().err
    assert err.count("is not found as the bind recorded it") >= 2 and "not at" in err
    assert gltf_looks(moved / "grey.glb")["counts"] == (2, 0, 0, 1)
    assert {m for bound in usd_looks(moved / "grey.usda")["meshes"].values() for _, m, _ in bound} == {"mat0", "mat1"}


def test_the_material_files_are_inputs_a_binding_records_and_a_batch_digests(work):
    import warp_stokes as ws
    from warp_stokes.io.inputs import inputs_of

    write_obj_case(work / "char.obj", LooksCase((0, 1), (True, False)))
    bind_and_write("char.obj", ())
    looks_files = {str(work / "char.mtl"), str(work / "char_tex0.png")}
    assert looks_files <= set(ws.load_binding(work / "b.npz", device="cpu").sources)
    assert looks_files <= set(inputs_of(work / "b.npz").files) and looks_files <= set(inputs_of("char.obj").files)
    before = inputs_of("char.obj").digest()
    (work / "char_tex0.png").write_bytes(b"another image")
    assert inputs_of("char.obj").digest() != before  # a batch binds it again


def test_a_binding_with_damaged_looks_is_one_error_line(work, capsys):
    write_obj_case(work / "char.obj", LooksCase((0,), (True,)))
    bind_and_write("char.obj", ())
    with np.load(work / "b.npz") as archive:
        arrays = dict(archive)
    meta = json.loads(str(arrays["meta"]))
    meta["looks"]["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["index"] = 7
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(work / "bad.npz", **arrays)
    capsys.readouterr()
    assert main(["animate", "bad.npz", "poses.npy", "-o", "out.glb", "--device", "cpu"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("warp-stokes: error: bad.npz: the binding's looks.materials[0] (baseColorTexture) must be a "
                   "texture among the 1 textures")
    assert not (work / "out.glb").exists()


def test_a_missing_material_library_binds_grey_with_a_warning(work, capsys):
    write_obj_case(work / "char.obj", LooksCase((0, 1), (True, False)))
    os.unlink(work / "char.mtl")
    bind_and_write("char.obj", ("out.usda",))
    assert "char.obj: its material library cannot be read" in capsys.readouterr().err
    usd = usd_looks(work / "out.usda")
    assert usd["materials"] == ["mat0", "mat1"] and all(image is None for _, _, image in usd["meshes"]["Mesh"])


# ----------------------------------------------------------------------------------------------------------------
# a property over made characters
# ----------------------------------------------------------------------------------------------------------------

@st.composite
def looks_cases(draw):
    """A character of 1 to 3 parts and 1 to 3 materials, each textured or not, a part possibly without one; as a
    GLB, a .gltf or an OBJ, its images embedded or beside it, its parts nodes or primitives of one mesh."""
    n_materials = draw(st.integers(1, 3))
    textured = tuple(draw(st.lists(st.booleans(), min_size=n_materials, max_size=n_materials)))
    parts = tuple(draw(st.lists(st.one_of(st.none(), st.integers(0, n_materials - 1)), min_size=1, max_size=3)))
    kind = draw(st.sampled_from(["glb", "gltf", "obj"]))
    return kind, LooksCase(parts, textured, embedded=draw(st.booleans()), one_mesh=draw(st.booleans()))


@settings(max_examples=6, derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(drawn=looks_cases())
def test_materials_and_their_bindings_survive_the_round_trip(tmp_path_factory, drawn):
    kind, case = drawn
    folder = tmp_path_factory.mktemp("case")
    vertices, faces = box_cage(CAGE_LO, CAGE_HI)
    write_obj(folder / "cage.obj", vertices, faces)
    np.save(folder / "poses.npy", np.stack([vertices, vertices * 1.1]))
    here = os.getcwd()
    os.chdir(folder)
    try:
        (write_obj_case if kind == "obj" else write_gltf_case)(folder / f"char.{kind}", case)
        bind_and_write(f"char.{kind}")
    finally:
        os.chdir(here)
    n_materials, images = len(case.textured), case.images()
    if kind == "obj":  # one part, a primitive per material its faces use (those before any usemtl first)
        expected = {"char.obj": sorted(set(case.obj_materials()), key=lambda m: -1 if m is None else m)}
    elif case.one_mesh and len(case.part_materials) > 1:  # a part per primitive, named by its number
        expected = {f"body.{k}": [m] for k, m in enumerate(case.part_materials)}
    else:
        expected = {("body" if case.one_mesh else f"part{k}"): [m] for k, m in enumerate(case.part_materials)}
    out = gltf_looks(folder / "out.glb")
    assert out["counts"][:3] == (n_materials, len(images), len(images))
    assert out["images"] == images and out["primitives"] == expected
    usd = usd_looks(folder / "out.usda")
    assert usd["materials"] == [f"mat{k}" for k in range(n_materials)]
    by_material = _images_by_material(case)
    for bound in usd["meshes"].values():
        for _, material, image in bound:
            assert material is None or image == by_material[int(material[3:])]
    bound_names = sorted({m for bound in usd["meshes"].values() for _, m, _ in bound if m is not None})
    assert bound_names == sorted({f"mat{m}" for m in (case.obj_materials() if kind == "obj" else case.part_materials)
                                  if m is not None})
