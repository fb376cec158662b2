"""A glTF file's JSON document and binary data, read through the one door in (:mod:`.door`): the document (a
``.gltf``'s text or a ``.glb``'s JSON chunk), its buffers (a ``.glb``'s binary chunk, data URIs, files beside it)
and the bytes of each image. :mod:`.looks_in` reads a glTF's materials and images with it at bind time, and
:mod:`.looks` reads an embedded image again at write time.

Every way the file can be damaged is one :class:`GltfDamaged` in words; the caller decides what it means (the
materials left out with a warning, or an error naming the file).
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import struct
from urllib.parse import unquote

import numpy as np

from ..errors import MeshError
from .door import read_input, reason

__all__ = ["GltfFile", "GltfDamaged", "data_uri", "GLB_MAGIC"]

GLB_MAGIC = b"glTF"
_JSON_CHUNK, _BIN_CHUNK = 0x4E4F534A, 0x004E4942
# accessor component types: numpy type, and the divisor of a normalized integer
_COMPONENTS = {5126: (np.float32, None), 5121: (np.uint8, 255.0), 5123: (np.uint16, 65535.0),
               5120: (np.int8, 127.0), 5122: (np.int16, 32767.0), 5125: (np.uint32, None)}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


class GltfDamaged(Exception):
    """What is wrong with a glTF's document, buffers or images, in words."""


def data_uri(uri: str) -> tuple[str, bytes]:
    """The media type and bytes of a base64 ``data:`` URI.

    Examples
    --------
    >>> data_uri("data:image/png;base64,iVBORw==")
    ('image/png', b'\\x89PNG')
    """
    head, _, payload = uri.partition(",")
    if not head.startswith("data:") or not head.endswith(";base64"):
        raise GltfDamaged(f"a data URI that is not base64 ({head[:40]})")
    try:
        return head[5:-7], base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise GltfDamaged(f"a data URI that is not base64 ({reason(exc)})") from None


def _glb_chunks(data: bytes) -> tuple[bytes, bytes | None]:
    """The JSON chunk and the binary chunk (or None) of a GLB file's bytes."""
    if len(data) < 20:
        raise GltfDamaged("a GLB file shorter than its header")
    _, version, length = struct.unpack_from("<4sII", data, 0)
    if version != 2:
        raise GltfDamaged(f"GLB version {version}; glTF 2.0 is read")
    if length > len(data):
        raise GltfDamaged(f"its header says {length} bytes, the file has {len(data)}")
    chunks, offset = [], 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + size > length:
            raise GltfDamaged("a chunk runs past the end of the file")
        chunks.append((kind, data[offset + 8 : offset + 8 + size]))
        offset += 8 + size
    if not chunks or chunks[0][0] != _JSON_CHUNK:
        raise GltfDamaged("the first chunk is not JSON")
    binary = chunks[1][1] if len(chunks) > 1 and chunks[1][0] == _BIN_CHUNK else None
    return chunks[0][1], binary


class GltfFile:
    """A glTF or GLB file as read: ``document`` (its JSON) and the bytes of its buffers and images on demand.

    Parameters
    ----------
    path : str, the file (named in messages; external buffers and images are read beside it)
    data : bytes, optional, its contents when already read

    Raises
    ------
    MeshError, where the file cannot be read (missing, not a regular file); GltfDamaged, where its contents are
    not a glTF document
    """

    def __init__(self, path: str, data: bytes | None = None):
        self.path = os.fspath(path)
        data = read_input(self.path, MeshError, "glTF") if data is None else data
        self.binary = None
        if data[:4] == GLB_MAGIC:
            text, self.binary = _glb_chunks(data)
        else:
            text = data
        try:
            self.document = json.loads(text)
        except (ValueError, RecursionError) as exc:  # (a UnicodeDecodeError is a ValueError)
            raise GltfDamaged(f"its JSON is not readable ({reason(exc)})") from None
        if not isinstance(self.document, dict):
            raise GltfDamaged("its JSON is not an object")
        self._buffers: dict[int, bytes] = {}

    def entries(self, key: str) -> list:
        """The document's list ``key`` ("materials", "images", ...): empty where absent, GltfDamaged where not a
        list of objects."""
        value = self.document.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise GltfDamaged(f"'{key}' is not a list of objects")
        return value

    def _entry(self, key: str, index) -> dict:
        entries = self.entries(key)
        if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(entries):
            raise GltfDamaged(f"{key[:-1]} {index!r} is named, but there are {len(entries)} {key}")
        return entries[index]

    def external(self, uri: str) -> str:
        """The path of a file a URI names, beside the glTF."""
        return os.path.join(os.path.dirname(os.path.abspath(self.path)), unquote(uri))

    def buffer(self, index: int) -> bytes:
        """The bytes of buffer ``index``: the GLB's binary chunk, a data URI, or a file beside the glTF."""
        if index not in self._buffers:
            entry = self._entry("buffers", index)
            uri = entry.get("uri")
            if uri is None:
                if self.binary is None or index != 0:
                    raise GltfDamaged(f"buffer {index} has no URI and no binary chunk holds it")
                data = self.binary
            elif not isinstance(uri, str):
                raise GltfDamaged(f"buffer {index}'s URI is not text")
            elif uri.startswith("data:"):
                data = data_uri(uri)[1]
            else:
                data = read_input(self.external(uri), MeshError, f"glTF buffer ({self.path})")
            self._buffers[index] = data
        return self._buffers[index]

    def view(self, index) -> bytes:
        """The bytes of buffer view ``index``."""
        view = self._entry("bufferViews", index)
        offset, length = view.get("byteOffset", 0), view.get("byteLength")
        if not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (offset, length)):
            raise GltfDamaged(f"buffer view {index} has no byte offset and length")
        data = self.buffer(view.get("buffer"))
        if offset + length > len(data):
            raise GltfDamaged(f"buffer view {index} runs past the end of its buffer")
        return data[offset : offset + length]

    def image(self, index) -> tuple[bytes, str | None, str | None]:
        """Image ``index``: its bytes, its media type where the file says it, and the path of the file of its own it
        is in (None for an image inside the glTF: a buffer view or a data URI)."""
        entry = self._entry("images", index)
        uri, mime = entry.get("uri"), entry.get("mimeType")
        mime = mime if isinstance(mime, str) else None
        if uri is None:
            return self.view(entry.get("bufferView")), mime, None
        if not isinstance(uri, str) or not uri:
            raise GltfDamaged(f"image {index}'s URI is not text")
        if uri.startswith("data:"):
            kind, data = data_uri(uri)
            return data, mime or kind or None, None
        path = self.external(uri)
        return read_input(path, MeshError, f"glTF image ({self.path})"), mime, path

    def accessor(self, index) -> np.ndarray:
        """Accessor ``index``'s values, (count, width) float64 (normalized integers scaled to [0, 1] or [-1, 1]);
        a sparse accessor or one without a buffer view is GltfDamaged (the caller goes without it)."""
        accessor = self._entry("accessors", index)
        kind, width = _COMPONENTS.get(accessor.get("componentType")), _WIDTHS.get(accessor.get("type"))
        count, offset = accessor.get("count"), accessor.get("byteOffset", 0)
        if kind is None or width is None or "sparse" in accessor or "bufferView" not in accessor or not all(
                isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in (count, offset)):
            raise GltfDamaged(f"accessor {index} is not one read here")
        dtype, divisor = np.dtype(kind[0]).newbyteorder("<"), kind[1]
        view = self.view(accessor["bufferView"])
        stride = self._entry("bufferViews", accessor["bufferView"]).get("byteStride") or dtype.itemsize * width
        if count and offset + stride * (count - 1) + dtype.itemsize * width > len(view):
            raise GltfDamaged(f"accessor {index} runs past the end of its buffer view")
        values = np.ndarray((count, width), dtype=dtype, buffer=view, offset=offset, strides=(stride, dtype.itemsize))
        values = values.astype(np.float64)
        if divisor is not None and accessor.get("normalized", kind[0] in (np.uint8, np.uint16)):
            values = np.maximum(values / divisor, -1.0)
        return values
