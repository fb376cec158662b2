"""The looks of a mesh file, read at bind time (see :mod:`.looks` for what is recorded and why): a glTF's materials,
textures, samplers and images as they are, with the material of each primitive; an OBJ's ``.mtl`` materials
(``Kd``, ``d``/``Tr``, ``Ns``, ``map_Kd``) turned into glTF materials, with the material of each face.

Looks that cannot be read whole (an ``.mtl`` missing, an image missing or damaged, a glTF's material pointing
nowhere) never stop a bind, whose business is the geometry: what cannot be kept is left out with one warning naming
the file, and the output is written with what is left (a material without its texture, or none).
"""

from __future__ import annotations

import hashlib
import os
import warnings

import numpy as np

from ..errors import WarpStokesError
from .door import read_input, reason
from .gltf_file import GltfDamaged, GltfFile
from .looks import ImageSource, Looks, image_type, material_problem, texture_slots

__all__ = ["gltf_looks", "gltf_primitives", "position_count", "texture_coordinates", "mtl_looks",
           "obj_dependencies"]


def _warn(message: str) -> None:
    warnings.warn(message, stacklevel=4)


def _image_source(name, data: bytes, mime, file: str, named: str, index) -> ImageSource:
    return ImageSource(name, image_type(data, mime), hashlib.sha256(data).hexdigest(), len(data),
                       os.path.realpath(file), named, index)


# ----------------------------------------------------------------------------------------------------------------
# glTF
# ----------------------------------------------------------------------------------------------------------------

def _extensions_used(*groups) -> list[str]:
    """The extension names that appear in the given glTF objects (their ``extensions`` keys), in order."""
    names: dict = {}

    def walk(value):
        if isinstance(value, dict):
            for key, item in value.items():
                if key == "extensions" and isinstance(item, dict):
                    names.update(dict.fromkeys(item))
                walk(item)
        elif isinstance(value, list):
            for item in value:
                walk(item)

    for group in groups:
        walk(group)
    return list(names)


def gltf_looks(gltf: GltfFile, named: str) -> Looks | None:
    """The looks of a glTF file read (None where it has no materials): its materials, textures and samplers as
    they are, each image by reference (see :mod:`.looks`). ``named``: the file as the bind was given it.

    A material or texture pointing at something the file does not have leaves the looks out (a warning); an image
    that cannot be read leaves that image out, and the textures that use it.
    """
    try:
        materials = gltf.entries("materials")
        if not materials:
            return None
        textures, samplers = gltf.entries("textures"), gltf.entries("samplers")
        image_entries = gltf.entries("images")
        for k, material in enumerate(materials):
            problem = material_problem(material)
            if problem is not None:
                raise gltf.damaged(f"material {k}: {problem}")
            for holder, key in texture_slots(material):
                index = holder[key]["index"]
                if not (isinstance(index, int) and 0 <= index < len(textures)):
                    raise gltf.damaged(f"material {k}'s {key} names texture {index!r} of {len(textures)}")
        for k, sampler in enumerate(samplers):
            if not all(isinstance(v, int) and not isinstance(v, bool) for key, v in sampler.items()
                       if key in ("magFilter", "minFilter", "wrapS", "wrapT")):
                raise gltf.damaged(f"sampler {k}'s filters and wraps are not integers")
        for k, texture in enumerate(textures):
            sampler = texture.get("sampler")
            if sampler is not None and not (isinstance(sampler, int) and 0 <= sampler < len(samplers)):
                raise gltf.damaged(f"texture {k} names sampler {sampler!r} of {len(samplers)}")
            source = texture.get("source")
            if source is not None and not (isinstance(source, int) and 0 <= source < len(image_entries)):
                raise gltf.damaged(f"texture {k} names image {source!r} of {len(image_entries)}")
    except GltfDamaged as exc:
        _warn(f"{gltf.path}: its materials are left out ({exc.detail})")
        return None
    images = []
    for k, entry in enumerate(image_entries):
        try:
            data, mime, own_file = gltf.image(k)
        except WarpStokesError as exc:  # (a GltfDamaged among them: its detail, the file named once)
            _warn(f"{gltf.path}: image {k} of its materials cannot be read ({reason(getattr(exc, 'detail', exc))}); "
                  "its textures are left out")
            images.append(None)
            continue
        label = entry.get("name") if isinstance(entry.get("name"), str) else None
        if own_file is None:
            images.append(_image_source(label, data, mime, gltf.path, named, k))
        else:
            beside = os.path.join(os.path.dirname(named), os.path.relpath(own_file, os.path.dirname(gltf.path)))
            images.append(_image_source(label or os.path.basename(own_file), data, mime, own_file, beside, None))
    second = [f"material {k}'s {key}" for k, material in enumerate(materials)
              for holder, key in texture_slots(material) if holder[key].get("texCoord", 0) != 0]
    if second:  # the binding keeps one set of UVs, TEXCOORD_0
        _warn(f"{gltf.path}: {second[0]}{' and others use' if len(second) > 1 else ' uses'} a second set of "
              "texture coordinates, which is not kept: placed by the first set in the outputs")
    looks = Looks(gltf.path, materials, textures, samplers, [], _extensions_used(materials, textures, samplers))
    return _without_unread(looks, images)


def _without_unread(looks: Looks, images: list) -> Looks:
    """``looks`` whose images are ``images``, where None stands for one that could not be read: it is left out, and
    the textures that use it."""
    from .looks import without_images

    present = [None if image is None else b"" for image in images]  # (what the pruning keeps: not None)
    resolved = without_images(Looks(looks.source, looks.materials, looks.textures, looks.samplers, images,
                             looks.extensions), present, True)
    return Looks(looks.source, resolved.materials, resolved.textures, resolved.samplers,
                 [image for image, _ in resolved.images], resolved.extensions)


def gltf_primitives(gltf: GltfFile) -> dict:
    """The glTF primitive each of trimesh's geometries is: geometry name -> (mesh, primitive, material or None).

    trimesh names one geometry per primitive of triangles, strips, lines or points, in file order, by the mesh's
    name made unique (``Mesh``, ``Mesh_1``, ...); its own function makes the names here the same way. The caller
    checks each against the geometry's vertex count: a trimesh that names them otherwise is found out, not trusted.
    """
    from trimesh.util import unique_name

    try:
        return _primitive_names(gltf, unique_name)
    except (TypeError, AttributeError, ValueError) as exc:  # a name or a primitive not as glTF lays them out
        raise gltf.damaged(f"its meshes are not as glTF lays them out ({reason(exc)})") from None


def _primitive_names(gltf: GltfFile, unique_name) -> dict:
    names: dict = {}
    counts: dict = {}
    for m, mesh in enumerate(gltf.entries("meshes")):
        primitives = mesh.get("primitives")
        for p, primitive in enumerate(primitives if isinstance(primitives, list) else []):
            if not isinstance(primitive, dict) or primitive.get("mode", 4) not in (0, 1, 4, 5):
                continue  # trimesh skips the other modes without naming them
            name = unique_name(mesh.get("name", "GLTF"), names, counts=counts)
            material = primitive.get("material")
            names[name] = (m, p, material if isinstance(material, int) and not isinstance(material, bool) else None)
    return names


def position_count(gltf: GltfFile, mesh: int, primitive: int):
    """The vertex count of a primitive's ``POSITION`` accessor (None where the file does not say)."""
    try:
        attributes = gltf.entries("meshes")[mesh]["primitives"][primitive].get("attributes") or {}
        return gltf.entries("accessors")[attributes["POSITION"]].get("count")
    except (GltfDamaged, KeyError, IndexError, TypeError, AttributeError):
        return None


def texture_coordinates(gltf: GltfFile, mesh: int, primitive: int) -> np.ndarray | None:
    """A primitive's ``TEXCOORD_0`` as (V, 2) UVs with v up (glTF's runs down the image), or None where it has none
    or they cannot be read."""
    try:
        attributes = gltf.entries("meshes")[mesh]["primitives"][primitive].get("attributes") or {}
        if "TEXCOORD_0" not in attributes:
            return None
        stored = gltf.entry("accessors", attributes["TEXCOORD_0"])  # unsigned bytes and shorts: normalised unless
        unsigned = stored.get("componentType") in (5121, 5123)   # the file says otherwise (as glTF's UVs are)
        uv = gltf.accessor(attributes["TEXCOORD_0"], normalized=bool(stored.get("normalized", unsigned)))
    except (WarpStokesError, KeyError, IndexError, TypeError, AttributeError):
        return None
    if uv.ndim != 2 or uv.shape[1] != 2 or not np.isfinite(uv).all():
        return None
    return np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)


# ----------------------------------------------------------------------------------------------------------------
# OBJ and MTL
# ----------------------------------------------------------------------------------------------------------------

# options of map_Kd and their argument counts (-o, -s, -t take one to three numbers)
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-boost": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1,
                "-clamp": 1, "-bm": 1, "-imfchan": 1, "-type": 1, "-cc": 1}


def _map_file(body: str) -> str:
    """The file name of a ``map_Kd`` record's body (its options skipped; a name may hold spaces)."""
    tokens = body.split()
    k = 0
    while k < len(tokens) and tokens[k].lower() in _MAP_OPTIONS:
        most = _MAP_OPTIONS[tokens[k].lower()]
        k += 1
        taken = 0
        while taken < most and k < len(tokens) - 1:
            try:
                float(tokens[k])
            except ValueError:
                if taken:  # -o, -s, -t: fewer numbers than three
                    break
            k += 1
            taken += 1
    return " ".join(tokens[k:]).replace("\\", "/")


def _numbers(body: str, count: int):
    try:
        values = [float(x) for x in body.split()[:count]]
    except ValueError:
        return None
    return values if len(values) == count and all(np.isfinite(values)) else None


def _mtl_materials(path: str) -> list[tuple[str, dict, str | None]]:
    """(name, glTF material, texture file as named or None) of every ``newmtl`` in an ``.mtl`` file."""
    text = read_input(path, WarpStokesError, "material library").decode("utf-8-sig", errors="replace")
    found, current = [], None
    for line in text.splitlines():
        key, _, body = line.strip().replace("\t", " ").partition(" ")
        body = body.strip()
        if key == "newmtl":
            current = [body or f"material{len(found)}", {"metallicFactor": 0.0}, None, 1.0]
            found.append(current)
        elif current is None:
            continue
        elif key == "Kd" and _numbers(body, 3):
            current[1]["baseColorFactor"] = [min(max(v, 0.0), 1.0) for v in _numbers(body, 3)]
        elif key in ("d", "Tr") and _numbers(body, 1):
            alpha = min(max(_numbers(body, 1)[0], 0.0), 1.0)
            current[3] = alpha if key == "d" else 1.0 - alpha
        elif key == "Ns" and _numbers(body, 1):  # Blinn-Phong exponent to roughness: sqrt(2 / (Ns + 2))
            current[1]["roughnessFactor"] = float(np.sqrt(2.0 / (max(_numbers(body, 1)[0], 0.0) + 2.0)))
        elif key == "map_Kd" and _map_file(body):
            current[2] = _map_file(body)
    materials = []
    for name, pbr, texture, alpha in found:
        pbr["baseColorFactor"] = pbr.get("baseColorFactor", [0.8, 0.8, 0.8]) + [alpha]
        material = {"name": name, "pbrMetallicRoughness": pbr}
        if alpha < 1.0:
            material["alphaMode"] = "BLEND"
        materials.append((name, material, texture))
    return materials


def mtl_looks(obj_path: str, libraries: list[str], used: list[str]) -> tuple[Looks | None, list[int]]:
    """The looks of an OBJ file: the materials of its ``mtllib`` files (named relative to the OBJ), in the order
    they are defined, and a grey one for each name ``usemtl`` uses that none defines; and the number of each name
    in ``used`` among them.

    Returns
    -------
    Looks or None (no material at all), and for each of ``used`` its material's number
    """
    folder = os.path.dirname(obj_path)
    definitions: dict = {}
    read = []
    for library in libraries:
        path = os.path.join(folder, library.replace("\\", "/"))
        try:
            materials = _mtl_materials(path)
        except WarpStokesError as exc:
            _warn(f"{obj_path}: its material library cannot be read ({exc}); its materials are grey")
            continue
        read.append(os.path.realpath(path))
        for name, material, texture in materials:
            definitions.setdefault(name, (material, texture, os.path.dirname(path)))
    missing = [name for name in dict.fromkeys(used) if name not in definitions]
    if missing and libraries:
        _warn(f"{obj_path}: {len(missing)} material(s) it uses are defined in no material library "
              f"({', '.join(missing[:3])}{', ...' if len(missing) > 3 else ''}); they are grey")
    for name in missing:
        definitions[name] = ({"name": name, "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.8, 1.0],
                                                                      "metallicFactor": 0.0}}, None, folder)
    if not definitions:
        return None, []
    materials, textures, images, texture_of_file = [], [], [], {}
    for name, (material, texture, base) in definitions.items():
        if texture is not None:
            file = os.path.join(base, texture)
            if file not in texture_of_file:  # one texture per image file, however many materials use it
                image = _read_image_file(obj_path, file)
                texture_of_file[file] = None if image is None else len(textures)
                if image is not None:
                    images.append(image)
                    textures.append({"source": len(images) - 1})
            if texture_of_file[file] is not None:
                material["pbrMetallicRoughness"]["baseColorTexture"] = {"index": texture_of_file[file]}
        materials.append(material)
    numbers = {name: k for k, name in enumerate(definitions)}
    return Looks(obj_path, materials, textures, [], images, [], read), [numbers[name] for name in used]


def obj_dependencies(path: str, error=WarpStokesError) -> list[str]:
    """The files an OBJ's materials would be read from: its ``mtllib`` files (beside it) and the images their
    ``map_Kd`` records name, for the inputs' full set (:func:`~.inputs.inputs_of`); the OBJ is decoded only where
    its bytes hold an ``mtllib``."""
    from .obj import obj_libraries

    data = read_input(path, error, "mesh")
    if b"mtllib" not in data:
        return []
    found = []
    for library in obj_libraries("\n" + data.decode("utf-8", errors="replace")):
        mtl = os.path.join(os.path.dirname(path), library.replace("\\", "/"))
        found.append(mtl)
        if os.path.isfile(mtl):
            try:
                materials = _mtl_materials(mtl)
            except WarpStokesError:  # its reader says so, when it is read
                continue
            found += [os.path.join(os.path.dirname(mtl), texture) for _, _, texture in materials if texture]
    return found


def _read_image_file(obj_path: str, file: str) -> ImageSource | None:
    """An image file a material names, by reference (None, with a warning, where it cannot be read)."""
    try:
        data = read_input(file, WarpStokesError, "image")
    except WarpStokesError as exc:
        _warn(f"{obj_path}: a texture of its materials cannot be read ({exc}); that material is written without it")
        return None
    return _image_source(os.path.basename(file), data, None, file, file, None)
