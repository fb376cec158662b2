"""A glTF 2.0 file's document and data as they are stored: the JSON (of a ``.gltf``, or a ``.glb``'s JSON chunk),
its buffers (a ``.glb``'s binary chunk, data URIs, files named beside it, all through the one door in) and its
accessors as numpy arrays (strided views, normalised integers, sparse substitutions), without pygltflib (an optional
extra). What glTF's animation and skinning make of them is :mod:`.gltf_pose`'s.
"""

from __future__ import annotations

import base64
import json
import os
import struct
from urllib.parse import unquote

import numpy as np

from ..errors import BindingError
from .door import read_input, reason

__all__ = ["GltfDocument", "read_gltf"]

_GLB_MAGIC, _JSON_CHUNK, _BINARY_CHUNK = b"glTF", 0x4E4F534A, 0x004E4942
#: component types and their little-endian numpy types
_COMPONENTS = {5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"), 5123: np.dtype("<u2"),
               5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: the most elements an accessor may have: one without a buffer view is zeros made here, and a count beyond this
#: (2^28, a mesh of 268 million vertices) would take the memory rather than be a character
MAX_ELEMENTS = 1 << 28
#: extensions whose data this reader cannot decode: refused, not read as zeros
_COMPRESSIONS = ("KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_meshopt_compression")


class GltfDocument:
    """A glTF file's JSON and buffers.

    Attributes
    ----------
    path : str, the file (for messages)
    json : dict, the document
    buffers : list of bytes

    Examples
    --------
    >>> doc = GltfDocument("x.gltf", {"accessors": [{"bufferView": 0, "componentType": 5126, "count": 1,
    ...                                              "type": "VEC3"}],
    ...                               "bufferViews": [{"buffer": 0, "byteLength": 12}]},
    ...                    [np.array([1, 2, 3], "<f4").tobytes()])
    >>> doc.accessor(0).tolist()
    [[1.0, 2.0, 3.0]]
    """

    def __init__(self, path: str, document: dict, buffers: list):
        self.path, self.json, self.buffers = path, document, buffers

    def entries(self, key: str) -> list:
        """The document's list under ``key`` (nodes, meshes, ...), empty when absent; a one-line error when it is not a
        list of objects."""
        value = self.json.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise BindingError(f"{self.path}: not a glTF file ('{key}' is not a list of objects)")
        return value

    def entry(self, key: str, index, what: str) -> dict:
        """Entry ``index`` of ``key``; a one-line error naming ``what`` refers to one that is not there."""
        entries = self.entries(key)
        if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(entries):
            raise BindingError(f"{self.path}: {what} refers to {key[:-1]} {index!r}, but the file has {len(entries)}")
        return entries[index]

    def accessor(self, index, what: str = "an attribute", integers: bool = False) -> np.ndarray:
        """Accessor ``index`` as an array (count,) or (count, width): float64, normalised integers scaled to [0, 1]
        or [-1, 1] as glTF says; with ``integers``, the stored integers as int64 (joint indices)."""
        accessor = self.entry("accessors", index, what)
        try:
            dtype = _COMPONENTS[accessor["componentType"]]
            width = _WIDTHS[accessor["type"]]
            count = int(accessor["count"])
        except (KeyError, TypeError, ValueError):
            raise BindingError(f"{self.path}: accessor {index} has no valid componentType, type and count") from None
        if not 0 <= count <= MAX_ELEMENTS:
            raise BindingError(f"{self.path}: accessor {index} has a count of {count}")
        if accessor["type"] in ("MAT2", "MAT3") and dtype.itemsize < 4:  # columns padded to 4 bytes: not laid flat
            raise BindingError(f"{self.path}: accessor {index} is a padded {accessor['type']} of "
                               f"{dtype.itemsize}-byte components, which this reader does not take")
        if "bufferView" in accessor:
            values = self._view_elements(accessor.get("bufferView"), int(accessor.get("byteOffset", 0)), dtype, width,
                                         count, f"accessor {index}")
        else:
            values = np.zeros((count, width), dtype=dtype)  # glTF: an accessor without a view holds zeros
        if "sparse" in accessor:
            values = self._sparse(accessor["sparse"], values, dtype, width, index)
        if integers:
            if dtype.kind == "f":
                raise BindingError(f"{self.path}: {what} (accessor {index}) holds floats, not integers")
            values = values.astype(np.int64)
        else:
            values = _as_floats(values, bool(accessor.get("normalized", False)))
        return values[:, 0] if width == 1 else values

    def _view_elements(self, view_index, offset: int, dtype: np.dtype, width: int, count: int, what: str):
        """``count`` elements of ``width`` components from a buffer view (its stride respected), as (count, width)."""
        view = self.entry("bufferViews", view_index, what)
        if any(key in (view.get("extensions") or {}) for key in _COMPRESSIONS):
            raise BindingError(f"{self.path}: buffer view {view_index} is compressed "
                               f"({', '.join(view['extensions'])}); export the file without compression")
        data = self._buffer(view.get("buffer"), what)
        start = int(view.get("byteOffset", 0)) + offset
        element = dtype.itemsize * width
        stride = int(view.get("byteStride") or element)
        end = start + (count - 1) * stride + element if count else start
        view_end = int(view.get("byteOffset", 0)) + int(view.get("byteLength", 0))
        if start < 0 or stride < element or end > min(view_end, len(data)):
            raise BindingError(f"{self.path}: {what} reads bytes {start} to {end} of buffer {view.get('buffer')}, "
                               f"beyond its view (to {view_end}) or its {len(data)} bytes")
        if count == 0:
            return np.zeros((0, width), dtype=dtype)
        raw = np.frombuffer(data, dtype=np.uint8, count=end - start, offset=start)
        rows = np.lib.stride_tricks.as_strided(raw, (count, element), (stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def _sparse(self, sparse: dict, values: np.ndarray, dtype, width: int, index: int) -> np.ndarray:
        """``values`` with a sparse accessor's substitutions."""
        try:
            count = int(sparse["count"])
            indices, substitutes = sparse["indices"], sparse["values"]
            index_type = _COMPONENTS[indices["componentType"]]
        except (KeyError, TypeError, ValueError):
            raise BindingError(f"{self.path}: accessor {index} has a sparse part without count, indices and "
                               "values") from None
        rows = self._view_elements(indices.get("bufferView"), int(indices.get("byteOffset", 0)), index_type, 1, count,
                                   f"accessor {index}'s sparse indices")[:, 0].astype(np.int64)
        new = self._view_elements(substitutes.get("bufferView"), int(substitutes.get("byteOffset", 0)), dtype, width,
                                  count, f"accessor {index}'s sparse values")
        if count and (rows.min() < 0 or rows.max() >= len(values)):
            raise BindingError(f"{self.path}: accessor {index}'s sparse indices reach beyond its {len(values)} "
                               "elements")
        values = values.copy()
        values[rows] = new
        return values

    def _buffer(self, buffer_index, what: str) -> bytes:
        if not isinstance(buffer_index, int) or not 0 <= buffer_index < len(self.buffers):
            raise BindingError(f"{self.path}: {what} refers to buffer {buffer_index!r}, but the file has "
                               f"{len(self.buffers)}")
        return self.buffers[buffer_index]


def _as_floats(values: np.ndarray, normalized: bool) -> np.ndarray:
    """Stored components as float64: normalised integers as glTF maps them (unsigned to [0, 1], signed to
    [-1, 1]), other integers as their values (KHR_mesh_quantization's positions)."""
    if values.dtype.kind == "f" or not normalized:
        return values.astype(np.float64)
    largest = float(np.iinfo(values.dtype).max)
    return np.maximum(values.astype(np.float64) / largest, -1.0)


def _glb_chunks(path: str, data: bytes) -> tuple[dict, bytes | None]:
    """A GLB's JSON and binary chunk (None when it has none)."""
    if len(data) < 20:
        raise BindingError(f"{path}: not a GLB file (only {len(data)} bytes)")
    magic, version, length = struct.unpack_from("<4sII", data)
    if magic != _GLB_MAGIC or version != 2:
        raise BindingError(f"{path}: not a glTF 2.0 binary (GLB) file")
    if length > len(data):
        raise BindingError(f"{path}: the GLB says {length} bytes, the file has {len(data)} (cut short?)")
    chunks, at = {}, 12
    while at + 8 <= length:
        size, kind = struct.unpack_from("<II", data, at)
        if at + 8 + size > length:
            raise BindingError(f"{path}: a GLB chunk reaches beyond the file (cut short?)")
        chunks.setdefault(kind, data[at + 8:at + 8 + size])
        at += 8 + size + (-size % 4)
    if _JSON_CHUNK not in chunks:
        raise BindingError(f"{path}: the GLB has no JSON chunk")
    return _json(path, chunks[_JSON_CHUNK]), chunks.get(_BINARY_CHUNK)


def _json(path: str, text: bytes) -> dict:
    try:
        document = json.loads(text)
    except (ValueError, RecursionError) as exc:  # (a UnicodeDecodeError is a ValueError)
        raise BindingError(f"{path}: not a glTF file ({reason(exc)})") from None
    if not isinstance(document, dict):
        raise BindingError(f"{path}: not a glTF file (its JSON is not an object)")
    return document


def _buffer_bytes(path: str, k: int, buffer: dict, binary: bytes | None) -> bytes:
    """Buffer ``k``'s bytes: the GLB's binary chunk (no uri), a data URI, or the file named beside ``path``."""
    uri = buffer.get("uri")
    if uri is None:
        if binary is None:
            raise BindingError(f"{path}: buffer {k} has no uri and the file no binary chunk")
        return binary
    if not isinstance(uri, str):
        raise BindingError(f"{path}: buffer {k}'s uri is not text")
    if uri.startswith("data:"):
        head, _, payload = uri.partition(",")
        try:
            return base64.b64decode(payload, validate=True) if head.endswith(";base64") else unquote(payload).encode()
        except ValueError as exc:
            raise BindingError(f"{path}: buffer {k}'s data URI is not base64 ({reason(exc)})") from None
    # exactly the file named beside it (as the meshes are read: io.load's resolver)
    return read_input(os.path.join(os.path.dirname(os.path.abspath(path)), unquote(uri)), BindingError,
                      f"glTF buffer ({path})")


def read_gltf(path: str) -> GltfDocument:
    """A ``.gltf`` or ``.glb`` file's document and buffers, read through the one door in.

    Parameters
    ----------
    path : str

    Returns
    -------
    GltfDocument

    Raises
    ------
    BindingError
        One line naming the file: not glTF 2.0, cut short, a buffer missing or not where it says.

    Examples
    --------
    >>> read_gltf("Fox.glb").entries("animations")[0]["name"]   # doctest: +SKIP
    'Survey'
    """
    data = read_input(path, BindingError, "glTF")
    if data[:4] == _GLB_MAGIC:
        document, binary = _glb_chunks(path, data)
    else:
        document, binary = _json(path, data), None
    version = str((document.get("asset") or {}).get("version", "")) if isinstance(document.get("asset"), dict) else ""
    if not version.startswith("2."):
        raise BindingError(f"{path}: not a glTF 2.0 file (asset version {version or 'missing'})")
    raw_buffers = document.get("buffers", [])
    if not isinstance(raw_buffers, list) or not all(isinstance(b, dict) for b in raw_buffers):
        raise BindingError(f"{path}: not a glTF file ('buffers' is not a list of objects)")
    buffers = [_buffer_bytes(path, k, b, binary) for k, b in enumerate(raw_buffers)]
    return GltfDocument(path, document, buffers)
