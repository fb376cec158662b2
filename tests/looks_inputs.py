"""Small textured characters made in code, for the looks tests: a few boxes ("parts"), each with its own UVs and a
material, written as a glTF/GLB file (images embedded or beside it, the parts as nodes or as the primitives of one
mesh) or as an OBJ file with a ``.mtl`` library; the images are tiny PNG files written with numpy and zlib.

Every part lies inside :data:`CAGE` (a box from -2 to 2), so a binding needs no made cage.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["png", "LooksCase", "write_gltf_case", "write_obj_case", "CAGE_LO", "CAGE_HI"]

CAGE_LO, CAGE_HI = (-2.0, -2.0, -2.0), (2.0, 2.0, 2.0)


def png(colour, size: int = 4) -> bytes:
    """A ``size`` x ``size`` PNG of one RGB colour (0-255) with a darker diagonal (so no two images are alike
    by accident of their colour alone)."""
    pixels = np.tile(np.asarray(colour, dtype=np.uint8), (size, size, 1))
    pixels[np.arange(size), np.arange(size)] //= 2
    raw = b"".join(b"\0" + row.tobytes() for row in pixels)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def box_part(centre, half: float = 0.3):
    """A box as 24 vertices (4 per side, each side its own UV square), their UVs and 12 outward triangles."""
    corners = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], float) * half + centre
    sides = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    vertices = np.concatenate([corners[list(side)] for side in sides])
    uvs = np.tile([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]], (6, 1)) * 0.9 + 0.05
    triangles = np.array([[4 * k, 4 * k + 1, 4 * k + 2] for k in range(6)] +
                         [[4 * k, 4 * k + 2, 4 * k + 3] for k in range(6)])
    return vertices, uvs, triangles


@dataclass(frozen=True)
class LooksCase:
    """A character to make: ``part_materials`` gives each part's material (None: none), ``textured`` whether each
    material has a base colour image; ``embedded``: glTF images inside the file (else PNG files beside it);
    ``one_mesh``: the glTF parts as primitives of one mesh (else one node and mesh each)."""

    part_materials: tuple
    textured: tuple
    embedded: bool = True
    one_mesh: bool = False

    @property
    def colours(self) -> list:
        return [((60 * k + 40) % 256, (90 * k + 120) % 256, (150 + 30 * k) % 256) for k in range(len(self.textured))]

    def images(self) -> list[bytes]:
        """The PNG of each textured material, in the materials' order."""
        return [png(colour) for colour, textured in zip(self.colours, self.textured) if textured]

    def obj_materials(self) -> list:
        """Each part's material as an OBJ file has it: ``usemtl`` holds until the next, so a part without a
        material of its own takes the one before it."""
        current, found = None, []
        for material in self.part_materials:
            current = material if material is not None else current
            found.append(current)
        return found

    def parts(self) -> list:
        n = len(self.part_materials)
        return [box_part(np.array([-1.2 + 2.4 * k / max(n - 1, 1), 0.1 * k, 0.0])) for k in range(n)]


def write_gltf_case(path, case: LooksCase) -> None:
    """The case as a glTF (``.gltf``: JSON with its buffer as a data URI) or GLB file, materials named ``mat0``,
    ``mat1`` ... and parts ``part0`` ... (nodes) or primitives of the one mesh ``body``."""
    import pygltflib
    from pygltflib import (GLTF2, Accessor, Attributes, Buffer, BufferView, Image, Material, Mesh, Node,
                           PbrMetallicRoughness, Primitive, Sampler, Scene, Texture, TextureInfo)

    path = Path(path)
    gltf = GLTF2(asset=pygltflib.Asset(version="2.0"))
    blob = bytearray()

    def view(data: bytes) -> int:
        gltf.bufferViews.append(BufferView(buffer=0, byteOffset=len(blob), byteLength=len(data)))
        blob.extend(data + b"\0" * (-len(data) % 4))
        return len(gltf.bufferViews) - 1

    def accessor(array: np.ndarray, kind: str, component: int) -> int:
        accessor = Accessor(bufferView=view(array.tobytes()), componentType=component, count=len(array), type=kind)
        if kind == "VEC3":
            accessor.min, accessor.max = array.min(axis=0).tolist(), array.max(axis=0).tolist()
        gltf.accessors.append(accessor)
        return len(gltf.accessors) - 1

    gltf.samplers.append(Sampler(magFilter=9728, minFilter=9728, wrapS=33071, wrapT=10497))
    images = iter(case.images())
    for k, (colour, textured) in enumerate(zip(case.colours, case.textured)):
        pbr = PbrMetallicRoughness(baseColorFactor=[1.0, 1.0, 1.0, 1.0] if textured else
                                   [c / 255 for c in colour] + [1.0], metallicFactor=0.0, roughnessFactor=0.7)
        if textured:
            data = next(images)
            if case.embedded:
                gltf.images.append(Image(name=f"image{k}", mimeType="image/png", bufferView=view(data)))
            else:
                (path.parent / f"{path.stem}_tex{k}.png").write_bytes(data)
                gltf.images.append(Image(uri=f"{path.stem}_tex{k}.png"))
            gltf.textures.append(Texture(sampler=0, source=len(gltf.images) - 1))
            pbr.baseColorTexture = TextureInfo(index=len(gltf.textures) - 1)
        gltf.materials.append(Material(name=f"mat{k}", pbrMetallicRoughness=pbr))
    primitives = []
    for material, (vertices, uvs, triangles) in zip(case.part_materials, case.parts()):
        flipped = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], axis=1)  # glTF's v runs down the image
        attributes = Attributes(POSITION=accessor(vertices.astype(np.float32), "VEC3", 5126),
                                TEXCOORD_0=accessor(flipped.astype(np.float32), "VEC2", 5126))
        primitives.append(Primitive(attributes=attributes, material=material, mode=4,
                                    indices=accessor(triangles.astype(np.uint16).ravel(), "SCALAR", 5123)))
    if case.one_mesh:
        gltf.meshes.append(Mesh(name="body", primitives=primitives))
        gltf.nodes.append(Node(name="body", mesh=0))
    else:
        for k, primitive in enumerate(primitives):
            gltf.meshes.append(Mesh(name=f"part{k}", primitives=[primitive]))
            gltf.nodes.append(Node(name=f"part{k}", mesh=k))
    gltf.scenes.append(Scene(nodes=list(range(len(gltf.nodes)))))
    gltf.scene = 0
    gltf.buffers.append(Buffer(byteLength=len(blob)))
    gltf.set_binary_blob(bytes(blob))
    if path.suffix == ".glb":
        gltf.save_binary(str(path))
    else:
        gltf.convert_buffers(pygltflib.BufferFormat.DATAURI)
        gltf.save_json(str(path))


def write_obj_case(path, case: LooksCase) -> None:
    """The case as one OBJ file (each part an ``o`` group after its ``usemtl``) and ``NAME.mtl`` beside it: ``Kd``
    the material's colour, ``map_Kd`` its PNG beside it where textured."""
    path = Path(path)
    lines, mtl = [f"mtllib {path.stem}.mtl"], []
    offset = 0
    for k, (material, (vertices, uvs, triangles)) in enumerate(zip(case.part_materials, case.parts())):
        lines.append(f"o part{k}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
        lines += [f"vt {u:.6f} {v:.6f}" for u, v in uvs]
        if material is not None:
            lines.append(f"usemtl mat{material}")
        lines += ["f " + " ".join(f"{i + offset + 1}/{i + offset + 1}" for i in triangle) for triangle in triangles]
        offset += len(vertices)
    for k, (colour, textured) in enumerate(zip(case.colours, case.textured)):
        mtl += [f"newmtl mat{k}", "Kd " + " ".join(f"{c / 255:.6f}" for c in colour), "Ns 50", "d 1"]
        if textured:
            mtl.append(f"map_Kd -s 1 1 1 {path.stem}_tex{k}.png")
            (path.parent / f"{path.stem}_tex{k}.png").write_bytes(png(colour))
    path.write_text("\n".join(lines) + "\n")
    (path.parent / f"{path.stem}.mtl").write_text("\n".join(mtl) + "\n")
