"""The cage animation as a glTF 2.0 skin (``.glb`` binary or ``.gltf`` text with an embedded buffer), written with
pygltflib: one joint node per handle under a ``CageSkeleton`` node, inverse bind matrices ``translate(-c_l)``, an
animation of the joints' translations, and one skinned mesh per bound part with ``JOINTS_n`` / ``WEIGHTS_n`` in sets
of four (glTF weights are non-negative).

glTF is Y-up in metres: the ``CageSkeleton`` node carries the asset's conversion (Z-up turned to Y-up, and its
metres per unit) when the binding is of a USD asset; joints and rest points stay in the binding's world space, so the
skin is ``p + sum_l w_l (c'_l - c_l)`` in that space, then converted. Texture coordinates are per vertex in glTF:
a vertex with several UVs (a seam) is split, its weights copied.

A posed mesh (``deform -o OUT.glb``) is written the same way without the skin (:func:`write_gltf_mesh`). Both carry
the input's materials, textures, samplers and images as the binding recorded them (:mod:`.looks`): a part's
polygons are split into one primitive per material, the primitives sharing the part's vertices.
"""

from __future__ import annotations

import numpy as np

from ..errors import WarpStokesError
from .outputs import atomic_output
from .load import fan_triangles, polygons_by_part

__all__ = ["write_gltf_skin", "write_gltf_mesh", "GLTF_EXTENSIONS"]

GLTF_EXTENSIONS = (".glb", ".gltf")

# glTF component types and the numpy dtypes they hold
_FLOAT, _UNSIGNED_BYTE, _UNSIGNED_SHORT, _UNSIGNED_INT = 5126, 5121, 5123, 5125
_COMPONENT = {np.dtype(np.float32): _FLOAT, np.dtype(np.uint8): _UNSIGNED_BYTE, np.dtype(np.uint16): _UNSIGNED_SHORT,
              np.dtype(np.uint32): _UNSIGNED_INT}
_TYPE = {1: "SCALAR", 3: "VEC3", 2: "VEC2", 4: "VEC4", 16: "MAT4"}
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


class _Buffer:
    """One binary buffer of 4-byte aligned views, and the accessors over them."""

    def __init__(self, gltf):
        self.gltf, self.chunks, self.length = gltf, [], 0

    def view(self, data: np.ndarray, target: int | None = None) -> int:
        from pygltflib import BufferView

        raw = np.ascontiguousarray(data).tobytes()
        self.chunks.append(raw + b"\0" * (-len(raw) % 4))
        self.gltf.bufferViews.append(BufferView(buffer=0, byteOffset=self.length, byteLength=len(raw), target=target))
        self.length += len(self.chunks[-1])
        return len(self.gltf.bufferViews) - 1

    def accessor(self, data: np.ndarray, target: int | None = None, bounds: bool = False, view: int | None = None,
                 offset: int = 0, count: int | None = None) -> int:
        """An accessor of ``data`` (N, width) (or N for scalars), in a new view unless ``view`` is given."""
        from pygltflib import Accessor

        data = np.asarray(data)
        width = 1 if data.ndim == 1 else int(np.prod(data.shape[1:]))
        rows = data.reshape(len(data), width)
        accessor = Accessor(bufferView=self.view(data, target) if view is None else view, byteOffset=offset,
                            componentType=_COMPONENT[data.dtype], count=len(data) if count is None else count,
                            type=_TYPE[width])
        if bounds:
            accessor.min, accessor.max = rows.min(axis=0).tolist(), rows.max(axis=0).tolist()
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def blob(self) -> bytes:
        return b"".join(self.chunks)


def _to_gltf_space(asset: dict | None) -> np.ndarray | None:
    """The 4 x 4 (column vectors) that takes the binding's world space to glTF's Y-up metres, None for identity."""
    if not asset:
        return None
    matrix = np.eye(4)
    if asset.get("up_axis") == "Z":
        matrix[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # (x, y, z) -> (x, z, -y): Z-up to Y-up
    matrix[:3, :3] *= float(asset.get("meters_per_unit") or 1.0)
    return None if np.allclose(matrix, np.eye(4)) else matrix


def _part_primitive(binding, rows: slice, faces: np.ndarray, corners: np.ndarray):
    """The glTF vertices of one part (its vertices split where a vertex has several UVs), as (source vertex per glTF
    vertex, UVs per glTF vertex or None, triangles over glTF vertices, the polygon among ``faces`` of each
    triangle)."""
    vertex = binding.mesh_face_indices[corners]
    if binding.mesh_uvs is not None:
        st, st_indices = binding.mesh_uvs
        pairs = np.stack([vertex, st_indices[corners]], axis=1)
        unique, corner_vertex = np.unique(pairs, axis=0, return_inverse=True)
        source, uvs = unique[:, 0], st[unique[:, 1]]
    else:
        source, corner_vertex = np.unique(vertex, return_inverse=True)
        uvs = None
    # vertices of the part that no polygon uses are still the part's: kept, so a point cloud part is not lost
    unused = np.setdiff1d(np.arange(rows.start, rows.stop), source)
    if len(unused):
        source = np.concatenate([source, unused])
        uvs = None if uvs is None else np.concatenate([uvs, np.zeros((len(unused), 2))])
    triangles, polygon = fan_triangles(binding.mesh_face_counts[faces], np.asarray(corner_vertex).ravel())
    return source, uvs, triangles, polygon


def _primitives(binding, buffer: "_Buffer", attributes, faces: np.ndarray, triangles: np.ndarray,
                polygon: np.ndarray, n_vertices: int) -> list:
    """The part's primitives over its one set of ``attributes``: one per material its polygons use (glTF gives a
    primitive one material), in the materials' order, polygons without one first."""
    from pygltflib import Primitive

    index_type = np.uint16 if n_vertices < 65535 else np.uint32
    if binding.looks is None or binding.mesh_face_materials is None:
        material_of = np.full(len(triangles), -1)
    else:
        material_of = binding.mesh_face_materials[faces][polygon]
    primitives = []
    for material in np.unique(material_of) if len(material_of) else [-1]:
        chosen = triangles[material_of == material]
        primitives.append(Primitive(attributes=attributes, mode=4, material=None if material < 0 else int(material),
                                    indices=buffer.accessor(chosen.astype(index_type).ravel(), _ELEMENT_ARRAY_BUFFER)))
    return primitives


def _add_meshes(gltf, buffer: "_Buffer", binding, positions: np.ndarray, normals, skin_sets=None) -> list:
    """One mesh node per bound part (its primitives: :func:`_primitives`) at ``positions`` (V, 3), with ``normals``
    (V, 3) or None and, for a skin, ``skin_sets`` (the padded joints and weights, each (V, 4 * sets)); returns the
    nodes."""
    from pygltflib import Attributes, Mesh, Node

    slices = binding.part_slices()
    polygons = polygons_by_part(binding.mesh_face_counts, binding.mesh_face_indices, slices)
    mesh_nodes = []
    for p, (part, rows, (faces, corners)) in enumerate(zip(binding.parts, slices, polygons)):
        source, uvs, triangles, polygon = _part_primitive(binding, rows, faces, corners)
        attributes = Attributes(POSITION=buffer.accessor(positions[source].astype(np.float32), _ARRAY_BUFFER,
                                                         bounds=True))
        if normals is not None:
            unit = normals[source]
            length = np.linalg.norm(unit, axis=1, keepdims=True)
            unit = np.where(length > 0, unit / np.where(length > 0, length, 1), [[0.0, 0.0, 1.0]])
            attributes.NORMAL = buffer.accessor(unit.astype(np.float32), _ARRAY_BUFFER)
        if uvs is not None:
            flipped = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], axis=1)  # glTF's v runs down the image
            attributes.TEXCOORD_0 = buffer.accessor(flipped.astype(np.float32), _ARRAY_BUFFER)
        if skin_sets is not None:
            indices, weights = skin_sets
            for s in range(indices.shape[1] // 4):
                setattr(attributes, f"JOINTS_{s}", buffer.accessor(indices[source, 4 * s : 4 * s + 4], _ARRAY_BUFFER))
                setattr(attributes, f"WEIGHTS_{s}", buffer.accessor(weights[source, 4 * s : 4 * s + 4], _ARRAY_BUFFER))
        name = str(part["path"]).rstrip("/").split("/")[-1] or f"Mesh{p}"
        gltf.meshes.append(Mesh(name=name, primitives=_primitives(binding, buffer, attributes, faces, triangles,
                                                                  polygon, len(source))))
        gltf.nodes.append(Node(name=name, mesh=len(gltf.meshes) - 1, skin=None if skin_sets is None else 0))
        mesh_nodes.append(len(gltf.nodes) - 1)
    return mesh_nodes


def _add_looks(gltf, buffer: "_Buffer", binding):
    """The binding's images, each image's bytes in a buffer view, and its looks as the file takes them
    (:mod:`.looks`: images not found as recorded left out, with their textures), or None where it has none."""
    from pygltflib import Image

    if binding.looks is None:
        return None
    looks = binding.looks.resolved(binding.mesh_uvs is not None)
    for image, data in looks.images:
        view = buffer.view(np.frombuffer(data, dtype=np.uint8))
        gltf.images.append(Image(name=image.name, mimeType=image.mime, bufferView=view))
    return looks


def _pygltflib(path):
    try:
        import pygltflib
    except ImportError:
        raise WarpStokesError(f"{path}: writing glTF needs pygltflib: pip install 'warp-stokes[gltf]'") from None
    return pygltflib


def _save(gltf, buffer: "_Buffer", path, ext: str, looks) -> None:
    """Write the file (``.glb`` binary, ``.gltf`` text with the buffer as a data URI): pygltflib's document with the
    materials, textures and samplers of ``looks`` put in as the input had them (JSON as read: pygltflib's own types
    would drop or refuse what they do not know, an extension's fields among them), and the buffer's bytes."""
    import base64
    import json
    import struct

    blob = buffer.blob()
    document = json.loads(gltf.to_json())
    if looks is not None:
        for key in ("materials", "textures", "samplers"):
            if getattr(looks, key):
                document[key] = getattr(looks, key)
        if looks.extensions:
            document["extensionsUsed"] = list(looks.extensions)
    document["buffers"] = [{"byteLength": len(blob)}]
    if ext == ".gltf":
        document["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    text = json.dumps(document, separators=(",", ":")).encode()
    with atomic_output(path, ext) as tmp, open(tmp, "wb") as fh:
        if ext == ".gltf":
            fh.write(text)
            return
        text += b" " * (-len(text) % 4)  # GLB: chunks 4-byte aligned, the JSON padded with spaces
        fh.write(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + 8 + len(blob)))
        fh.write(struct.pack("<II", len(text), 0x4E4F534A) + text)
        fh.write(struct.pack("<II", len(blob), 0x004E4942) + blob)


def write_gltf_mesh(path, ext, binding, vertices, metadata: dict | None = None) -> str:
    """The bound mesh at ``vertices`` (V, 3) (a deformed pose) as a glTF file with no skin: a mesh node per part,
    its polygons split by material into primitives, UVs, vertex normals of the posed polygons, and the input's
    materials (:mod:`.looks`)."""
    from .normals import NormalsPlan

    pygltflib = _pygltflib(path)
    gltf = pygltflib.GLTF2(asset=pygltflib.Asset(generator="warp-stokes", version="2.0", extras=metadata or {}))
    buffer = _Buffer(gltf)
    looks = _add_looks(gltf, buffer, binding)
    vertices = np.asarray(vertices, dtype=np.float64)
    normals = NormalsPlan(binding.mesh_face_counts, binding.mesh_face_indices, "vertex", len(vertices))(vertices)
    nodes = _add_meshes(gltf, buffer, binding, vertices, normals)
    conversion = _to_gltf_space(binding.asset)
    if conversion is not None:  # a USD asset's: Y-up in metres, as glTF is
        gltf.nodes.append(pygltflib.Node(name="Root", children=nodes, matrix=conversion.T.ravel().tolist()))
        nodes = [len(gltf.nodes) - 1]
    gltf.scenes.append(pygltflib.Scene(name="Scene", nodes=nodes))
    gltf.scene = 0
    _save(gltf, buffer, path, ext, looks)
    return path


def _seconds(path, frames, rate: float) -> np.ndarray:
    """The frames' times in seconds as glTF keeps them (float32), refused unless finite and increasing there: a
    frame rate or frame numbers that float32 cannot tell apart would make a file that glTF readers refuse."""
    seconds = np.asarray(frames, dtype=np.float64) / float(rate)
    with np.errstate(over="ignore"):
        kept = seconds.astype(np.float32)
    if not np.isfinite(kept).all() or len(np.unique(kept)) != len(kept):
        raise WarpStokesError(f"{path}: the frames' times in seconds ({frames.min():g} to {frames.max():g} at {rate:g} "
                              "fps) do not fit glTF's float32 times as distinct finite numbers; renumber the frames "
                              "or choose another --fps")
    return kept


def write_gltf_skin(path, ext, binding, skin, joints, positions, frames, rate, metadata: dict) -> str:
    """Write the skin and the poses' animation as glTF; see :func:`warp_stokes.binding.skin.write_skin`.

    ``skin`` must be non-negative; its influences are padded to a multiple of four with zero weights on joint 0.
    The input's materials, textures and images come along (:mod:`.looks`), each primitive with its material.
    """
    pygltflib = _pygltflib(path)
    if np.any(skin.weights < 0):
        raise WarpStokesError(f"{path}: glTF skins take non-negative weights only")
    n_handles = binding.n_handles
    gltf = pygltflib.GLTF2(asset=pygltflib.Asset(generator="warp-stokes", version="2.0", extras=metadata))
    buffer = _Buffer(gltf)
    _add_skeleton(gltf, buffer, binding, joints)
    looks = _add_looks(gltf, buffer, binding)

    k = skin.influences
    sets = -(-k // 4)
    padded_indices = np.zeros((len(skin.indices), 4 * sets), dtype=np.uint8 if n_handles <= 256 else np.uint16)
    padded_weights = np.zeros((len(skin.indices), 4 * sets), dtype=np.float32)
    padded_indices[:, :k], padded_weights[:, :k] = skin.indices, skin.weights
    padded_indices[padded_weights == 0] = 0  # glTF: joints of zero weight set to zero
    mesh_nodes = _add_meshes(gltf, buffer, binding, binding.mesh_vertices, binding.mesh_normals,
                             (padded_indices, padded_weights))

    _add_animation(gltf, buffer, path, positions, frames, rate)
    gltf.scenes.append(pygltflib.Scene(name="Scene", nodes=[0] + mesh_nodes))
    gltf.scene = 0
    _save(gltf, buffer, path, ext, looks)
    return path


def _add_skeleton(gltf, buffer: _Buffer, binding, joints) -> None:
    """The ``CageSkeleton`` node (node 0, carrying the conversion to glTF's space), a joint node per handle at its
    rest position (nodes 1 to L) and the skin over them, with inverse bind matrices ``translate(-c_l)``."""
    from pygltflib import Node, Skin

    n_handles = binding.n_handles
    rest_cage = np.asarray(binding.cage_vertices, dtype=np.float64)
    root = Node(name="CageSkeleton", children=list(range(1, n_handles + 1)))
    conversion = _to_gltf_space(binding.asset)
    if conversion is not None:
        root.matrix = conversion.T.ravel().tolist()  # column-major
    gltf.nodes.append(root)
    for name, position in zip(joints, rest_cage.astype(np.float32)):
        gltf.nodes.append(Node(name=name, translation=position.tolist()))
    inverse_bind = np.broadcast_to(np.eye(4, dtype=np.float32), (n_handles, 4, 4)).copy()
    inverse_bind[:, 3, :3] = -rest_cage  # column-major storage of translate(-c): the translation is elements 12-14
    gltf.skins.append(Skin(name="CageSkin", joints=list(range(1, n_handles + 1)), skeleton=0,
                           inverseBindMatrices=buffer.accessor(inverse_bind.reshape(n_handles, 16))))


def _add_animation(gltf, buffer: _Buffer, path, positions, frames, rate: float) -> None:
    """The joints' translations over the frames (``positions`` (F, L, 3)), one sampler and channel per joint, their
    outputs in one buffer view."""
    from pygltflib import Animation, AnimationChannel, AnimationChannelTarget, AnimationSampler

    times = buffer.accessor(_seconds(path, frames, rate), bounds=True)
    translations = np.ascontiguousarray(np.asarray(positions, dtype=np.float32).transpose(1, 0, 2))  # (L, F, 3)
    view = buffer.view(translations)
    animation = Animation(name="CageAnimation")
    for joint in range(len(translations)):
        output = buffer.accessor(translations[joint], view=view, offset=joint * translations[joint].nbytes)
        animation.samplers.append(AnimationSampler(input=times, output=output, interpolation="LINEAR"))
        animation.channels.append(AnimationChannel(sampler=joint, target=AnimationChannelTarget(node=joint + 1,
                                                                                                 path="translation")))
    gltf.animations.append(animation)
