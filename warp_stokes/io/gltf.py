"""The cage animation as a glTF 2.0 skin (``.glb`` binary or ``.gltf`` text with an embedded buffer), written with
pygltflib: one joint node per handle under a ``CageSkeleton`` node, inverse bind matrices ``translate(-c_l)``, an
animation of the joints' translations, and one skinned mesh per bound part with ``JOINTS_n`` / ``WEIGHTS_n`` in sets
of four (glTF weights are non-negative).

glTF is Y-up in metres: the ``CageSkeleton`` node carries the asset's conversion (Z-up turned to Y-up, and its
metres per unit) when the binding is of a USD asset; joints and rest points stay in the binding's world space, so the
skin is ``p + sum_l w_l (c'_l - c_l)`` in that space, then converted. Texture coordinates are per vertex in glTF:
a vertex with several UVs (a seam) is split, its weights copied.
"""

from __future__ import annotations

import numpy as np

from ..errors import WarpStokesError
from .outputs import atomic_output
from .load import fan_triangles, polygons_by_part

__all__ = ["write_gltf_skin", "GLTF_EXTENSIONS"]

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
    vertex, UVs per glTF vertex or None, triangles over glTF vertices)."""
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
    triangles, _ = fan_triangles(binding.mesh_face_counts[faces], np.asarray(corner_vertex).ravel())
    return source, uvs, triangles


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
    """
    try:
        import pygltflib
    except ImportError:
        raise WarpStokesError(f"{path}: writing glTF needs pygltflib: pip install 'warp-stokes[gltf]'") from None
    from pygltflib import GLTF2, Asset, Attributes, Buffer, Mesh, Node, Primitive, Scene

    if np.any(skin.weights < 0):
        raise WarpStokesError(f"{path}: glTF skins take non-negative weights only")
    n_handles = binding.n_handles
    gltf = GLTF2(asset=Asset(generator="warp-stokes", version="2.0", extras=metadata))
    buffer = _Buffer(gltf)
    _add_skeleton(gltf, buffer, binding, joints)

    k = skin.influences
    sets = -(-k // 4)
    padded_indices = np.zeros((len(skin.indices), 4 * sets), dtype=np.uint8 if n_handles <= 256 else np.uint16)
    padded_weights = np.zeros((len(skin.indices), 4 * sets), dtype=np.float32)
    padded_indices[:, :k], padded_weights[:, :k] = skin.indices, skin.weights
    padded_indices[padded_weights == 0] = 0  # glTF: joints of zero weight set to zero

    slices = binding.part_slices()
    polygons = polygons_by_part(binding.mesh_face_counts, binding.mesh_face_indices, slices)
    mesh_nodes = []
    for p, (part, rows, (faces, corners)) in enumerate(zip(binding.parts, slices, polygons)):
        source, uvs, triangles = _part_primitive(binding, rows, faces, corners)
        attributes = Attributes(POSITION=buffer.accessor(binding.mesh_vertices[source].astype(np.float32),
                                                         _ARRAY_BUFFER, bounds=True))
        if binding.mesh_normals is not None:
            normals = binding.mesh_normals[source]
            length = np.linalg.norm(normals, axis=1, keepdims=True)
            normals = np.where(length > 0, normals / np.where(length > 0, length, 1), [[0.0, 0.0, 1.0]])
            attributes.NORMAL = buffer.accessor(normals.astype(np.float32), _ARRAY_BUFFER)
        if uvs is not None:
            flipped = np.stack([uvs[:, 0], 1.0 - uvs[:, 1]], axis=1)  # glTF's v runs down the image
            attributes.TEXCOORD_0 = buffer.accessor(flipped.astype(np.float32), _ARRAY_BUFFER)
        for s in range(sets):
            setattr(attributes, f"JOINTS_{s}",
                    buffer.accessor(padded_indices[source, 4 * s : 4 * s + 4], _ARRAY_BUFFER))
            setattr(attributes, f"WEIGHTS_{s}",
                    buffer.accessor(padded_weights[source, 4 * s : 4 * s + 4], _ARRAY_BUFFER))
        index_type = np.uint16 if len(source) < 65535 else np.uint32
        primitive = Primitive(attributes=attributes, mode=4,
                              indices=buffer.accessor(triangles.astype(index_type).ravel(), _ELEMENT_ARRAY_BUFFER))
        name = str(part["path"]).rstrip("/").split("/")[-1] or f"Mesh{p}"
        gltf.meshes.append(Mesh(name=name, primitives=[primitive]))
        gltf.nodes.append(Node(name=name, mesh=len(gltf.meshes) - 1, skin=0))
        mesh_nodes.append(len(gltf.nodes) - 1)

    _add_animation(gltf, buffer, path, positions, frames, rate)
    gltf.scenes.append(Scene(name="Scene", nodes=[0] + mesh_nodes))
    gltf.scene = 0

    blob = buffer.blob()
    gltf.buffers.append(Buffer(byteLength=len(blob)))
    gltf.set_binary_blob(blob)
    with atomic_output(path, ext) as tmp:
        if ext == ".glb":
            gltf.save_binary(tmp)
        else:
            gltf.convert_buffers(pygltflib.BufferFormat.DATAURI)
            gltf.save_json(tmp)
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
