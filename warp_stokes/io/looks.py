"""A mesh's looks: its materials, the textures and samplers they use, and where each image is, as a binding records
them at bind time and the writers read them back.

Where the looks come from, and why so
-------------------------------------
The bind records the looks (:mod:`.looks_in` reads them from a glTF's materials or an OBJ's ``.mtl`` files): in
the binding file, which material every polygon uses (the array ``mesh_face_materials``) and the material
definitions themselves (glTF's material objects; an ``.mtl``'s ``Kd``, ``d`` and ``map_Kd`` turned into one), and
each image by reference: the file that holds it (an image file, or the glTF that embeds it, and the image's number
there), its SHA-256 and size. The image's bytes are read again when an output is written, and used only where their
digest is still the recorded one.

Why not read the mesh's file again at write time: which face uses which material would then depend on reading that
file the same way again, and a file edited since the bind (a material added, a primitive moved) would put a texture
on the wrong faces without a sign. Recorded, the assignment belongs to the binding's own polygons, fixed with them.
Why not the images' bytes in the binding: a character's textures are often many times its weights, and a binding is
read whole by every ``deform``. By reference with a digest, an image that moved, vanished or changed since the bind
is found out: the output is then written without that texture (its material's colour kept), with one warning naming
the image and the place looked, never a crash or another image in its place. An image is looked for where the bind
read it (its real path), then where it was named from the bind's working folder (a project folder moved whole).

Within the record everything is in glTF's terms (glTF 2.0 material objects, textures, samplers), the richer of the
two inputs, so a glTF output carries the input's materials as they were; :mod:`.usd.looks` turns them into
``UsdPreviewSurface`` materials.
"""

from __future__ import annotations

import hashlib
import math
import os
import warnings
from dataclasses import dataclass, field

from ..errors import BindingError, WarpStokesError
from .door import read_input, reason

__all__ = ["ImageSource", "Looks", "ResolvedLooks", "texture_slots", "image_type", "without_images",
           "material_problem", "IMAGE_SUFFIXES"]

#: the images USD's UsdUVTexture reads, and the name ending an image file written beside a layer gets
IMAGE_SUFFIXES = {"image/png": ".png", "image/jpeg": ".jpg"}


def image_type(data: bytes, stated: str | None = None) -> str:
    """An image's media type: the one its file states, else the one its first bytes show (PNG, JPEG, WebP, KTX2).

    Examples
    --------
    >>> image_type(b"\\x89PNG\\r\\n\\x1a\\n...")
    'image/png'
    """
    if stated:
        return stated
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "image/png"
    if data[:3] == b"\xff\xd8\xff":
        return "image/jpeg"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "image/webp"
    if data[:12] == b"\xabKTX 20\xbb\r\n\x1a\n":
        return "image/ktx2"
    return "application/octet-stream"


def texture_slots(value, path=()):
    """Every texture reference in a glTF material (or any part of one): (the dict holding it, its key) for each
    ``*Texture`` object with an ``index`` (``baseColorTexture``, ``normalTexture``, an extension's
    ``clearcoatTexture`` ...).

    Examples
    --------
    >>> material = {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}, "normalTexture": {"index": 1}}
    >>> sorted(key for _, key in texture_slots(material))
    ['baseColorTexture', 'normalTexture']
    """
    if isinstance(value, dict):
        for key, item in list(value.items()):
            if key.endswith("Texture") and isinstance(item, dict) and "index" in item:
                yield value, key
            else:
                yield from texture_slots(item)
    elif isinstance(value, list):
        for item in value:
            yield from texture_slots(item)


def _numbers(value, count: int) -> bool:
    return isinstance(value, list) and len(value) == count and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)


#: a glTF material's fields the writers read, and what each must be (the others are carried as they are)
_MATERIAL_FIELDS = {
    "name": (lambda v: isinstance(v, str), "text"),
    "pbrMetallicRoughness": (lambda v: isinstance(v, dict), "an object"),
    "emissiveFactor": (lambda v: _numbers(v, 3), "3 numbers"),
    "alphaMode": (lambda v: v in ("OPAQUE", "MASK", "BLEND"), "OPAQUE, MASK or BLEND"),
    "alphaCutoff": (lambda v: _numbers([v], 1), "a number"),
    "doubleSided": (lambda v: isinstance(v, bool), "true or false"),
}
#: the same of its ``pbrMetallicRoughness``
_PBR_FIELDS = {
    "baseColorFactor": (lambda v: _numbers(v, 4), "4 numbers"),
    "metallicFactor": (lambda v: _numbers([v], 1), "a number"),
    "roughnessFactor": (lambda v: _numbers([v], 1), "a number"),
}


def material_problem(material: dict) -> str | None:
    """What is wrong with a glTF material object for the writers (a field of the wrong type), or None.

    Examples
    --------
    >>> material_problem({"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1]}})
    'pbrMetallicRoughness.baseColorFactor is not 4 numbers'
    """
    pbr = material.get("pbrMetallicRoughness")
    checks = [(key, value, _MATERIAL_FIELDS) for key, value in material.items()]
    checks += [(f"pbrMetallicRoughness.{key}", value, _PBR_FIELDS) for key, value in
               (pbr.items() if isinstance(pbr, dict) else ())]
    for key, value, fields in checks:
        test, expected = fields.get(key.rsplit(".", 1)[-1], (None, None))
        if test is not None and not test(value):
            return f"{key} is not {expected}"
    return None


def _texture_images(texture: dict) -> list:
    """The images a glTF texture names: its ``source`` and its extensions' (KHR_texture_basisu, EXT_texture_webp)."""
    names = [texture.get("source")] if "source" in texture else []
    for extension in (texture.get("extensions") or {}).values():
        if isinstance(extension, dict) and "source" in extension:
            names.append(extension["source"])
    return names


@dataclass(frozen=True)
class ImageSource:
    """Where one image of the looks is, and what it was at bind time.

    Attributes
    ----------
    name : str or None, the image's name in its file (glTF) or its file name
    mime : str, its media type ("image/png", "image/jpeg", ...)
    sha256 : str, the digest of its bytes at bind time
    size : int, its bytes
    file : str, the real path of the file holding it: the image file, or the glTF that embeds it
    named : str, that file as the bind named it (relative to the folder it ran in, where it was given so)
    index : int or None, for an image inside a glTF (a buffer view, a data URI): its number there
    """

    name: str | None
    mime: str
    sha256: str
    size: int
    file: str
    named: str
    index: int | None = None

    def record(self) -> dict:
        return {"name": self.name, "mime": self.mime, "sha256": self.sha256, "size": self.size, "file": self.file,
                "named": self.named, "index": self.index}

    def read(self, containers: dict) -> tuple[bytes | None, str]:
        """The image's bytes where a place it may be holds them with the recorded digest, else None; and what was
        found (for the warning). ``containers``: glTF files read so far, by path (an embedded image's file is read
        once for all its images)."""
        from .gltf_file import GltfFile

        found = []
        for place in dict.fromkeys([self.file, os.path.abspath(self.named)]):
            if not os.path.exists(place):
                found.append(f"not at {place}")
                continue
            try:
                if self.index is None:
                    data = read_input(place, WarpStokesError, "image")
                else:
                    if place not in containers:
                        containers[place] = GltfFile(place)
                    data = containers[place].image(self.index)[0]
            except WarpStokesError as exc:  # (a GltfDamaged among them: its detail, the file named once)
                found.append(f"{place} unreadable ({reason(getattr(exc, 'detail', exc))})")
                continue
            if hashlib.sha256(data).hexdigest() == self.sha256:
                return data, ""
            found.append(f"{place} changed since the bind")
        return None, "; ".join(found)


@dataclass(frozen=True)
class ResolvedLooks:
    """Looks with their images read, ready to write: ``images`` holds (ImageSource, bytes) for each image found
    with its recorded digest; the textures of images not found are left out and every index renumbered to match.
    ``materials``, ``textures``, ``samplers`` and ``extensions`` are as in :class:`Looks`."""

    materials: list
    textures: list
    samplers: list
    images: list
    extensions: list


@dataclass(frozen=True)
class Looks:
    """A mesh's materials, in glTF 2.0's terms, and where their images are (see the module docstring).

    Attributes
    ----------
    source : str, the file they were read from (for messages)
    materials : list of dict, glTF material objects (an ``.mtl``'s materials turned into such)
    textures, samplers : list of dict, glTF texture and sampler objects, as the materials' indices name them
    images : list of ImageSource, as the textures' ``source`` indices name them
    extensions : list of str, the glTF extensions the materials and textures use (``KHR_texture_transform`` ...)
    libraries : list of str, the real paths of the files the materials were read from besides the mesh's (an OBJ's
        ``.mtl`` files): the binding's sources hold them, the looks' record does not
    """

    source: str
    materials: list
    textures: list = field(default_factory=list)
    samplers: list = field(default_factory=list)
    images: list = field(default_factory=list)
    extensions: list = field(default_factory=list)
    libraries: list = field(default_factory=list)

    def record(self) -> dict:
        """The looks as a binding file records them (JSON)."""
        return {"source": self.source, "materials": self.materials, "textures": self.textures,
                "samplers": self.samplers, "images": [image.record() for image in self.images],
                "extensions": self.extensions}

    def files(self) -> list[str]:
        """The real paths the looks are read from: the images' files and the material libraries."""
        return sorted({image.file for image in self.images} | set(self.libraries))

    @classmethod
    def from_record(cls, record, path: str) -> "Looks":
        """The looks a binding file records, checked whole: a field of the wrong type, or an index that names no
        texture, sampler or image, is one BindingError naming the file and the field."""
        return _checked_looks(record, path)

    def resolved(self, has_uvs: bool = True) -> ResolvedLooks:
        """The looks with their images read (see :meth:`ImageSource.read`): each image not found as recorded is
        left out with one warning naming it and where it was looked for, and the textures that use it with it; all
        textures are left out (with a warning) where the mesh has no texture coordinates to place them."""
        containers: dict = {}
        kept: list = []
        for k, image in enumerate(self.images):
            data, why = image.read(containers) if has_uvs else (None, "")
            if data is None and has_uvs:
                warnings.warn(f"{self.source}: image {image.name or k} of its materials is not found as the bind "
                              f"recorded it ({why}); written without it (the material's own colour kept)",
                              stacklevel=3)
            kept.append(data)
        if not has_uvs and self.textures:
            warnings.warn(f"{self.source}: the bound mesh has no texture coordinates; its materials are written "
                          "without their textures", stacklevel=3)
        return without_images(self, kept, has_uvs)


def without_images(looks: Looks, image_bytes: list, has_uvs: bool) -> ResolvedLooks:
    """``looks`` without the images whose bytes are None and the textures that use them (all textures without
    ``has_uvs``), every index renumbered."""
    import copy

    image_number, images = {}, []
    for k, (image, data) in enumerate(zip(looks.images, image_bytes)):
        if data is not None:
            image_number[k] = len(images)
            images.append((image, data))
    texture_number, textures = {}, []
    for k, texture in enumerate(looks.textures):
        if has_uvs and all(name in image_number for name in _texture_images(texture)):
            texture = copy.deepcopy(texture)
            if "source" in texture:
                texture["source"] = image_number[texture["source"]]
            for extension in (texture.get("extensions") or {}).values():
                if isinstance(extension, dict) and "source" in extension:
                    extension["source"] = image_number[extension["source"]]
            texture_number[k] = len(textures)
            textures.append(texture)
    materials = copy.deepcopy(looks.materials)
    for holder, key in list(texture_slots(materials)):
        if holder[key]["index"] in texture_number:
            holder[key]["index"] = texture_number[holder[key]["index"]]
        else:
            del holder[key]
    return ResolvedLooks(materials, textures, copy.deepcopy(looks.samplers), images, list(looks.extensions))


def _is_index(value, count: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value < count


def _checked_looks(record, path: str) -> Looks:
    """:meth:`Looks.from_record`."""

    def refuse(where: str, expected: str):
        raise BindingError(f"{path}: the binding's looks.{where} must be {expected}")

    if not isinstance(record, dict):
        refuse("", "a record")
    lists = {}
    for key in ("materials", "textures", "samplers", "images"):
        value = record.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            refuse(key, "a list of records")
        lists[key] = value
    if not isinstance(record.get("source", ""), str):
        refuse("source", "text")
    extensions = record.get("extensions", [])
    if not isinstance(extensions, list) or not all(isinstance(e, str) for e in extensions):
        refuse("extensions", "a list of names")
    images = [_checked_image(entry, f"images[{k}]", refuse) for k, entry in enumerate(lists["images"])]
    for k, texture in enumerate(lists["textures"]):
        if not all(_is_index(name, len(images)) for name in _texture_images(texture)):
            refuse(f"textures[{k}]", f"a texture whose images are among the {len(images)} images")
        if "sampler" in texture and not _is_index(texture["sampler"], len(lists["samplers"])):
            refuse(f"textures[{k}].sampler", f"one of the {len(lists['samplers'])} samplers")
    for k, material in enumerate(lists["materials"]):
        problem = material_problem(material)
        if problem is not None:
            refuse(f"materials[{k}]", f"a glTF material ({problem})")
        for holder, key in texture_slots(material):
            if not _is_index(holder[key]["index"], len(lists["textures"])):
                refuse(f"materials[{k}] ({key})", f"a texture among the {len(lists['textures'])} textures")
    return Looks(record.get("source", ""), lists["materials"], lists["textures"], lists["samplers"], images,
                 extensions)


def _checked_image(entry: dict, where: str, refuse) -> ImageSource:
    texts = {"mime": entry.get("mime"), "file": entry.get("file"), "named": entry.get("named")}
    for key, value in texts.items():
        if not isinstance(value, str) or not value or "\0" in value:
            refuse(f"{where}.{key}", "text")
    digest = entry.get("sha256")
    if not (isinstance(digest, str) and len(digest) == 64 and all(c in "0123456789abcdef" for c in digest)):
        refuse(f"{where}.sha256", "a SHA-256 digest in hex")
    if not (isinstance(entry.get("size"), int) and not isinstance(entry.get("size"), bool) and entry["size"] >= 0):
        refuse(f"{where}.size", "an integer >= 0")
    index = entry.get("index")
    if index is not None and not _is_index(index, 1 << 31):
        refuse(f"{where}.index", "an integer >= 0 or null")
    name = entry.get("name")
    if name is not None and not isinstance(name, str):
        refuse(f"{where}.name", "text or null")
    return ImageSource(name, texts["mime"], digest, entry["size"], texts["file"], texts["named"], index)
