"""A glTF 2.0 file as it is stored, read through the one door in (:mod:`.door`), without pygltflib (an optional
extra): the JSON (a ``.gltf``'s text or a ``.glb``'s JSON chunk, the GLB's chunks parsed once), its buffers (the
GLB's binary chunk, data URIs, files named beside it, each read when first used), its buffer views, the bytes of each
image, and its accessors as numpy arrays (strided views, normalised integers, sparse substitutions, every component
type).

Every way the file can be damaged is one :class:`GltfDamaged`: one line naming the file. The callers decide what it
means: :mod:`.skinned` makes it the :class:`~warp_stokes.errors.BindingError` of the frames it reads (what
:mod:`.gltf_pose` makes of the animation and skinning), while :mod:`.looks_in`, :mod:`.scene` and :mod:`.looks`
leave the materials out with a warning.
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import struct
from urllib.parse import unquote

import numpy as np

from ..errors import WarpStokesError
from .door import read_input, reason

__all__ = ["GltfFile", "GltfDamaged", "data_uri", "GLB_MAGIC", "MAX_ELEMENTS"]

GLB_MAGIC = b"glTF"
_JSON_CHUNK, _BINARY_CHUNK = 0x4E4F534A, 0x004E4942
#: component types and their little-endian numpy types
_COMPONENTS = {5120: np.dtype("<i1"), 5121: np.dtype("<u1"), 5122: np.dtype("<i2"), 5123: np.dtype("<u2"),
               5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: the most elements an accessor may have: one without a buffer view is zeros made here, and a count beyond this
#: (2^28, a mesh of 268 million vertices) would take the memory rather than be a character
MAX_ELEMENTS = 1 << 28
#: extensions whose data this reader cannot decode: refused, not read as zeros
_COMPRESSIONS = ("KHR_draco_mesh_compression", "EXT_meshopt_compression", "KHR_meshopt_compression")


class GltfDamaged(WarpStokesError):
    """A glTF file, or a part of it, that cannot be read: one line naming the file. ``detail`` is the same without
    the glTF's name (for messages that name it themselves); a file the door could not read is named in both."""

    def __init__(self, message: str, detail: str | None = None):
        super().__init__(message)
        self.detail = message if detail is None else detail


def data_uri(uri: str) -> tuple[str, bytes]:
    """The media type and bytes of a ``data:`` URI (base64, or percent-encoded text); ValueError where it is not
    one.

    Examples
    --------
    >>> data_uri("data:image/png;base64,iVBORw==")
    ('image/png', b'\\x89PNG')
    >>> data_uri("data:,a%20b")
    ('', b'a b')
    """
    head, _, payload = uri.partition(",")
    if not head.startswith("data:"):
        raise ValueError(f"not a data URI ({head[:40]})")
    if not head.endswith(";base64"):
        return head[5:].split(";")[0], unquote(payload).encode()
    try:
        return head[5:-7], base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise ValueError(f"not base64 ({reason(exc)})") from None


def _component(value) -> np.dtype | None:
    """The numpy type of glTF component type ``value``, None where it is not one."""
    return _COMPONENTS.get(value) if isinstance(value, int) else None


def _count(value) -> int | None:
    """``value`` where it is a whole number >= 0 (not a bool), else None."""
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else None


class GltfFile:
    """A ``.gltf`` or ``.glb`` file as read: ``document`` (its JSON), its buffers, buffer views, images and accessors.

    Parameters
    ----------
    path : str, the file (named in messages; external buffers and images are read beside it, exactly as named)
    data : bytes, optional, its contents when already read

    Raises
    ------
    GltfDamaged, one line naming the file: unreadable (missing, not a regular file), not glTF JSON, a GLB cut short

    Examples
    --------
    >>> gltf = GltfFile("x.gltf", json.dumps({
    ...     "accessors": [{"bufferView": 0, "componentType": 5126, "count": 1, "type": "VEC3"}],
    ...     "bufferViews": [{"buffer": 0, "byteLength": 12}],
    ...     "buffers": [{"uri": "data:;base64,AACAPwAAAEAAAEBA", "byteLength": 12}]}).encode())
    >>> gltf.accessor(0).tolist()
    [[1.0, 2.0, 3.0]]
    """

    def __init__(self, path, data: bytes | None = None):
        self.path = os.fspath(path)
        data = read_input(self.path, GltfDamaged, "glTF") if data is None else data
        self.binary = None
        text = self._glb_chunks(data) if data[:4] == GLB_MAGIC else data
        try:
            self.document = json.loads(text)
        except (ValueError, RecursionError) as exc:  # (a UnicodeDecodeError is a ValueError)
            raise self.damaged(f"not a glTF file ({reason(exc)})") from None
        if not isinstance(self.document, dict):
            raise self.damaged("not a glTF file (its JSON is not an object)")
        self._buffers: dict[int, bytes] = {}

    def damaged(self, detail: str) -> GltfDamaged:
        """The error that the file is damaged as ``detail`` says, naming the file."""
        return GltfDamaged(f"{self.path}: {detail}", detail)

    def _glb_chunks(self, data: bytes) -> bytes:
        """A GLB's JSON chunk; its binary chunk (the second, where there is one) kept as ``binary``."""
        if len(data) < 20:
            raise self.damaged(f"not a GLB file (only {len(data)} bytes)")
        _, version, length = struct.unpack_from("<4sII", data)
        if version != 2:
            raise self.damaged(f"not a glTF 2.0 binary (GLB) file (version {version})")
        if length > len(data):
            raise self.damaged(f"the GLB says {length} bytes, the file has {len(data)} (cut short?)")
        chunks, at = [], 12
        while at + 8 <= length:
            size, kind = struct.unpack_from("<II", data, at)
            if at + 8 + size > length:
                raise self.damaged("a GLB chunk reaches beyond the file (cut short?)")
            chunks.append((kind, data[at + 8:at + 8 + size]))
            at += 8 + size + (-size % 4)
        if not chunks or chunks[0][0] != _JSON_CHUNK:
            raise self.damaged("the GLB's first chunk is not JSON")
        if len(chunks) > 1 and chunks[1][0] == _BINARY_CHUNK:
            self.binary = chunks[1][1]
        return chunks[0][1]

    def check_version(self) -> None:
        """A GltfDamaged unless the document says it is glTF 2.x (``asset.version``)."""
        asset = self.document.get("asset")
        version = str(asset.get("version", "")) if isinstance(asset, dict) else ""
        if not version.startswith("2."):
            raise self.damaged(f"not a glTF 2.0 file (asset version {version or 'missing'})")

    # -------------------------------------------------------------------------------------------------------------
    # the document's lists
    # -------------------------------------------------------------------------------------------------------------

    def entries(self, key: str) -> list:
        """The document's list ``key`` ("nodes", "materials", ...): empty where absent, GltfDamaged where not a list
        of objects."""
        value = self.document.get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, dict) for v in value):
            raise self.damaged(f"'{key}' is not a list of objects")
        return value

    def entry(self, key: str, index, what: str | None = None) -> dict:
        """Entry ``index`` of ``key``; a GltfDamaged (naming ``what`` refers to it, where given) where it is not
        there."""
        entries = self.entries(key)
        if _count(index) is None or index >= len(entries):
            named = f"{what} refers to {key[:-1]} {index!r}" if what else f"{key[:-1]} {index!r} is named"
            raise self.damaged(f"{named}, but the file has {len(entries)} {key}")
        return entries[index]

    def external(self, uri: str) -> str:
        """The path of a file a URI names, beside the glTF."""
        return os.path.join(os.path.dirname(os.path.abspath(self.path)), unquote(uri))

    # -------------------------------------------------------------------------------------------------------------
    # bytes: buffers, buffer views, images
    # -------------------------------------------------------------------------------------------------------------

    def buffer(self, index, what: str | None = None) -> bytes:
        """The bytes of buffer ``index``: the GLB's binary chunk (buffer 0 without a URI), a data URI, or the file
        named beside the glTF (read once)."""
        uri = self.entry("buffers", index, what).get("uri")
        if index not in self._buffers:
            if uri is None:
                if self.binary is None or index != 0:
                    raise self.damaged(f"buffer {index} has no uri and no binary chunk holds it")
                data = self.binary
            elif not isinstance(uri, str):
                raise self.damaged(f"buffer {index}'s uri is not text")
            elif uri.startswith("data:"):
                try:
                    data = data_uri(uri)[1]
                except ValueError as exc:
                    raise self.damaged(f"buffer {index}'s data URI is {exc}") from None
            else:
                data = read_input(self.external(uri), GltfDamaged, f"glTF buffer ({self.path})")
            self._buffers[index] = data
        return self._buffers[index]

    def _view(self, index, what: str | None = None) -> tuple[dict, bytes, int, int]:
        """Buffer view ``index``: its entry, its buffer's bytes, and where it starts and ends in them."""
        view = self.entry("bufferViews", index, what)
        offset, length = _count(view.get("byteOffset", 0)), _count(view.get("byteLength"))
        if offset is None or length is None:
            raise self.damaged(f"buffer view {index} has no byte offset and length")
        data = self.buffer(view.get("buffer"), f"buffer view {index}")
        if offset + length > len(data):
            raise self.damaged(f"buffer view {index} runs past the end of its buffer ({offset + length} of "
                               f"{len(data)} bytes)")
        return view, data, offset, offset + length

    def view(self, index) -> bytes:
        """The bytes of buffer view ``index``."""
        _, data, start, end = self._view(index)
        return data[start:end]

    def image(self, index) -> tuple[bytes, str | None, str | None]:
        """Image ``index``: its bytes, its media type where the file says it, and the path of the file of its own it
        is in (None for an image inside the glTF: a buffer view or a data URI)."""
        entry = self.entry("images", index)
        uri, mime = entry.get("uri"), entry.get("mimeType")
        mime = mime if isinstance(mime, str) else None
        if uri is None:
            return self.view(entry.get("bufferView")), mime, None
        if not isinstance(uri, str) or not uri:
            raise self.damaged(f"image {index}'s uri is not text")
        if uri.startswith("data:"):
            try:
                kind, data = data_uri(uri)
            except ValueError as exc:
                raise self.damaged(f"image {index}'s data URI is {exc}") from None
            return data, mime or kind or None, None
        path = self.external(uri)
        return read_input(path, GltfDamaged, f"glTF image ({self.path})"), mime, path

    # -------------------------------------------------------------------------------------------------------------
    # accessors
    # -------------------------------------------------------------------------------------------------------------

    def accessor(self, index, what: str = "an attribute", integers: bool = False,
                 normalized: bool | None = None) -> np.ndarray:
        """Accessor ``index`` as an array (count,) or (count, width): float64, normalised integers scaled to [0, 1]
        or [-1, 1] as glTF says (``normalized``: instead of what the accessor says); with ``integers``, the stored
        integers as int64 (joint indices). ``what`` refers to it, for messages."""
        accessor = self.entry("accessors", index, what)
        dtype, width = _component(accessor.get("componentType")), _WIDTHS.get(str(accessor.get("type")))
        count = _count(accessor.get("count"))
        if dtype is None or width is None or count is None:
            raise self.damaged(f"accessor {index} has no valid componentType, type and count")
        if count > MAX_ELEMENTS:
            raise self.damaged(f"accessor {index} has a count of {count}")
        if accessor["type"] in ("MAT2", "MAT3") and dtype.itemsize < 4:  # columns padded to 4 bytes: not laid flat
            raise self.damaged(f"accessor {index} is a padded {accessor['type']} of {dtype.itemsize}-byte components, "
                               "which this reader does not take")
        if "bufferView" in accessor:
            values = self._elements(accessor, dtype, width, count, f"accessor {index}")
        else:
            values = np.zeros((count, width), dtype=dtype)  # glTF: an accessor without a view holds zeros
        if "sparse" in accessor:
            values = self._sparse(accessor["sparse"], values, dtype, width, index)
        if integers:
            if dtype.kind == "f":
                raise self.damaged(f"{what} (accessor {index}) holds floats, not integers")
            values = values.astype(np.int64)
        else:
            scaled = bool(accessor.get("normalized", False)) if normalized is None else normalized
            values = _as_floats(values, scaled)
        return values[:, 0] if width == 1 else values

    def _elements(self, holder: dict, dtype: np.dtype, width: int, count: int, what: str) -> np.ndarray:
        """``count`` elements of ``width`` components from ``holder``'s buffer view at its byte offset (the view's
        stride respected), as (count, width)."""
        view_index = holder.get("bufferView")
        view, data, view_start, view_end = self._view(view_index, what)
        if any(key in (view.get("extensions") or {}) for key in _COMPRESSIONS):
            raise self.damaged(f"buffer view {view_index} is compressed ({', '.join(view['extensions'])}); export "
                               "the file without compression")
        offset, stride = _count(holder.get("byteOffset", 0)), view.get("byteStride") or dtype.itemsize * width
        element = dtype.itemsize * width
        if offset is None or _count(stride) is None or stride < element:
            raise self.damaged(f"{what} has no valid byte offset and stride")
        start = view_start + offset
        end = start + (count - 1) * stride + element if count else start
        if end > view_end:
            raise self.damaged(f"{what} reads bytes {start} to {end} of buffer {view.get('buffer')}, beyond its view "
                               f"(to {view_end})")
        if count == 0:
            return np.zeros((0, width), dtype=dtype)
        raw = np.frombuffer(data, dtype=np.uint8, count=end - start, offset=start)
        rows = np.lib.stride_tricks.as_strided(raw, (count, element), (stride, 1))
        return np.ascontiguousarray(rows).view(dtype).reshape(count, width)

    def _sparse(self, sparse, values: np.ndarray, dtype: np.dtype, width: int, index: int) -> np.ndarray:
        """``values`` with a sparse accessor's substitutions."""
        parts = [sparse.get(key) for key in ("count", "indices", "values")] if isinstance(sparse, dict) else []
        if not parts or _count(parts[0]) is None or not all(isinstance(part, dict) for part in parts[1:]) or \
                _component(parts[1].get("componentType")) is None:
            raise self.damaged(f"accessor {index} has a sparse part without count, indices and values")
        count, indices, substitutes = parts
        rows = self._elements(indices, _component(indices["componentType"]), 1, count,
                              f"accessor {index}'s sparse indices")
        rows = rows[:, 0].astype(np.int64)
        new = self._elements(substitutes, dtype, width, count, f"accessor {index}'s sparse values")
        if count and (rows.min() < 0 or rows.max() >= len(values)):
            raise self.damaged(f"accessor {index}'s sparse indices reach beyond its {len(values)} elements")
        values = values.copy()
        values[rows] = new
        return values


def _as_floats(values: np.ndarray, normalized: bool) -> np.ndarray:
    """Stored components as float64: normalised integers as glTF maps them (unsigned to [0, 1], signed to
    [-1, 1]), other integers as their values (KHR_mesh_quantization's positions)."""
    if values.dtype.kind == "f" or not normalized:
        return values.astype(np.float64)
    largest = float(np.iinfo(values.dtype).max)
    return np.maximum(values.astype(np.float64) / largest, -1.0)
