"""OBJ files read directly and fast: the common all-triangles file by regular expressions at C speed, the rest
(polygons, negative indices, normals, texture coordinates) by vectorised passes over the records."""

from __future__ import annotations

import re
import warnings

import numpy as np

from ..errors import MeshError
from .door import read_input

__all__ = ["read_obj", "read_obj_with_usage", "obj_usage", "obj_libraries"]


def _bodies(text: str, tag: str) -> list:
    """The text after ``tag`` of every record with that tag (``text`` starts with a newline; tabs are spaces)."""
    return re.findall("\n" + tag + " ([^\n]*)", text)


def _numbered(text: str, tag: str):
    """(line number, line) of every record with ``tag``: for naming the line of an unreadable one."""
    return ((line_no, ln) for line_no, ln in enumerate(text[1:].split("\n"), 1) if ln.startswith(tag + " "))


def _counts(bodies: list) -> np.ndarray:
    """Each record's token count."""
    return np.fromiter(map(len, map(str.split, bodies)), dtype=np.int64, count=len(bodies))


def _firsts(bodies: list, k: int, dtype) -> np.ndarray:
    """(R, k) the first ``k`` tokens of every record (each has at least ``k``), as ``dtype``: C-speed passes over the
    joined text, 50k-line files in milliseconds; ValueError for a record that has fewer or an unreadable one."""
    counts = _counts(bodies)
    if (counts < k).any():
        raise ValueError
    tokens = " ".join(bodies).split()
    if (counts == k).all():
        return np.array(tokens, dtype=dtype).reshape(-1, k)
    firsts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    return np.array(tokens, dtype=object)[firsts[:, None] + np.arange(k)].astype(dtype)


# a literal newline first is what makes these fast (about three times faster than ^ with re.M)
_VERTEX_LINE = re.compile(r"\nv[ \t]([^\n]*)")
_FACE_LINE = re.compile(r"\nf[ \t]([^\n]*)")


def _read_obj_triangles(text: str):
    """The common case at C speed (numpy's text parser: a few times faster than the reader it replaced): every
    face a triangle of plain positive indices, no normals or texture coordinates. None otherwise."""
    if "\nvn " in text or text.startswith("vn ") or "\nvt " in text or text.startswith("vt "):
        return None
    text = "\n" + text  # the first line's record too
    vertices, triangles = _VERTEX_LINE.findall(text), _FACE_LINE.findall(text)
    if not vertices or not triangles:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # numpy warns, not raises, on some malformed input: take the slow path
            verts = np.loadtxt(vertices, dtype=np.float64, ndmin=2)
            faces = np.loadtxt(triangles, dtype=np.int64, ndmin=2)
    except (ValueError, OverflowError, UserWarning):  # ragged rows (polygons of other sizes), v/vt/vn corners,
        return None  # unreadable numbers, indices beyond 64 bits: the slow path finds them
    # loadtxt skips empty and comment-only records ("v # ..."): every record must have given one row
    if len(verts) != len(vertices) or len(faces) != len(triangles):
        return None
    if verts.shape[1] < 3 or faces.shape[1] != 3 or faces.min() < 1:
        return None
    return np.ascontiguousarray(verts[:, :3]), faces - 1, None, None


def read_obj(path: str) -> tuple[np.ndarray, np.ndarray | list, np.ndarray | None, tuple | None]:
    """Read an OBJ's ``v``, ``f``, ``vn`` and ``vt`` records directly, keeping file order and the polygons as written
    (trimesh re-orders or splits vertices in some OBJ files, at texture seams; users need file order).

    Returns
    -------
    vertices (V, 3), polygons (0-based: an (F, k) array where all have k corners, else ``(counts, corners)``, each
    polygon's corner count and all corners in order, as USD lays them out), per-vertex normals or None, face-varying
    UVs ``(st, st_indices)`` or None

    Raises
    ------
    MeshError
        An unreadable file, vertex or face, naming the line.
    """
    return read_obj_with_usage(path)[:4]


def read_obj_with_usage(path: str):
    """:func:`read_obj`'s four, and a fifth: the materials the file uses (:func:`obj_usage`), or None."""
    # -sig: a byte-order mark is no part of line 1; universal newlines as text mode reads them
    text = read_input(path, MeshError, "mesh").decode("utf-8-sig", errors="replace")
    text = text.replace("\r\n", "\n").replace("\r", "\n")
    read = _read_records(path, text)
    polygons = read[1]
    return (*read, obj_usage("\n" + text, len(polygons[0]) if isinstance(polygons, tuple) else len(polygons)))


def _read_records(path: str, text: str):
    """:func:`read_obj` of the file's text (newlines made plain)."""
    fast = _read_obj_triangles(text)
    if fast is not None:
        return fast
    # lines end where Python's splitlines ends them (form feeds, vertical tabs and Unicode line breaks too)
    text = "\n" + "\n".join(text.replace("\t", " ").splitlines())
    vertex_bodies = _bodies(text, "v")
    if not vertex_bodies:
        return np.zeros((0, 3)), [], None, None
    try:
        verts = _firsts(vertex_bodies, 3, np.float64)
    except ValueError:  # find the offending line for the message
        for line_no, ln in _numbered(text, "v"):
            try:
                if len([float(x) for x in ln.split()[1:4]]) != 3:
                    raise ValueError
            except ValueError:
                raise MeshError(f"{path}: line {line_no}: unreadable vertex {ln.strip()!r}") from None
        raise
    face_bodies = _bodies(text, "f")
    corners = " ".join(face_bodies)
    counts = _counts(face_bodies)
    try:
        # a corner is v, v/vt, v//vn or v/vt/vn: its vertex is what comes before the first slash
        indices = np.array((re.sub(r"/\S*", "", corners) if "/" in corners else corners).split(), dtype=np.int64)
        if (counts < 3).any() or len(indices) != counts.sum():
            raise ValueError
    except (ValueError, OverflowError):
        for line_no, ln in _numbered(text, "f"):
            try:
                ids = [int(tok.split("/", 1)[0]) for tok in ln.split()[1:]]
                if len(ids) < 3 or max(abs(c) for c in ids) > len(verts):
                    raise ValueError
            except ValueError:
                raise MeshError(f"{path}: line {line_no}: unreadable face {ln.strip()!r} (three or more vertex "
                                f"indices within the file's {len(verts)} vertices)") from None
        raise
    if len(indices) and indices.min() < 0:
        # negative indices count back from the last vertex read before the face
        tags = re.findall(r"\n([vf]) ", text)
        seen = np.cumsum(np.array(tags) == "v")[np.array(tags) == "f"]
        indices = np.where(indices > 0, indices, np.repeat(seen, counts) + indices + 1)
    normals = None
    if "\nvn " in text:
        try:
            normals = _obj_normals(text, corners, indices, len(verts))
        except MeshError as exc:
            raise MeshError(f"{path}: {exc}") from None
    uvs = None
    if "\nvt " in text:
        uvs = _obj_uvs(text, corners, len(indices))
        if uvs is None:
            warnings.warn(f"{path}: the texture coordinates (vt) are dropped: not every face corner names one, or "
                          "one is out of range", stacklevel=3)
    if len(counts) == 0:
        return verts, [], normals, uvs
    if len(np.unique(counts)) == 1:
        return verts, indices.reshape(len(counts), counts[0]) - 1, normals, uvs  # the common case
    return verts, (counts, indices - 1), normals, uvs


def _obj_uvs(text: str, corners: str, n_corners: int) -> tuple | None:
    """Face-varying texture coordinates: the ``vt`` table and, per face corner, its ``v/vt[/vn]`` index (None
    unless every corner names one in range)."""
    bodies = _bodies(text, "vt")
    refs = re.findall(r"(?<!\S)[^\s/]+/([^\s/]*)", corners)  # a corner's second field (from its start)
    if not bodies or len(refs) != n_corners or n_corners == 0 or "" in refs:
        return None
    try:
        st = _firsts(bodies, 2, np.float64)
        st_indices = np.array(refs, dtype=np.int64)
    except (ValueError, OverflowError):
        return None
    st_indices = np.where(st_indices > 0, st_indices - 1, len(st) + st_indices)
    if st_indices.min() < 0 or st_indices.max() >= len(st):
        return None
    return st, st_indices


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _obj_normals(text: str, corners: str, indices: np.ndarray, n_vertices: int) -> np.ndarray | None:
    """Per-vertex normals from `vn` records and the `v//vn` or `v/vt/vn` face corners (None if incomplete): each
    vertex's corner normals summed and normalised. ``indices``: the corners' vertices, 1-based."""
    bodies = _bodies(text, "vn")
    try:
        table = _firsts(bodies, 3, np.float64)
    except ValueError:  # a record with fewer than three numbers, or words
        for line_no, ln in _numbered(text, "vn"):
            record = ln.split()[1:4]
            if len(record) != 3 or not all(_is_number(x) for x in record):
                raise MeshError(f"line {line_no}: unreadable normal 'vn {' '.join(record)}'") from None
        raise
    refs = re.findall(r"(?<!\S)[^\s/]+/[^\s/]*/([^\s/]+)", corners)  # a corner's third field
    if len(refs) != len(indices) or len(indices) == 0:
        return None
    try:
        vn = np.array(refs, dtype=np.int64)
    except (ValueError, OverflowError):
        return None
    v = np.where(indices > 0, indices - 1, n_vertices + indices)
    vn = np.where(vn > 0, vn - 1, len(table) + vn)
    if v.min() < 0 or v.max() >= n_vertices or vn.min() < 0 or vn.max() >= len(table):
        return None
    sums = np.zeros((n_vertices, 3))
    np.add.at(sums, v, table[vn])
    length = np.linalg.norm(sums, axis=1)
    if (length == 0).any():
        return None
    return sums / length[:, None]


_MATERIAL_RECORDS = re.compile(r"\n(f)[ \t]|\nusemtl[ \t]+([^\n]*)")
_LIBRARY_RECORD = re.compile(r"\nmtllib[ \t]+([^\n]*)")


def obj_libraries(text: str) -> list[str]:
    """The material libraries an OBJ's text (starting with a newline) names in its ``mtllib`` records, as named
    (several to a record; one name may hold spaces where the record names one ``.mtl``).

    Examples
    --------
    >>> obj_libraries("\\nmtllib a.mtl b.mtl\\nmtllib my skin.mtl\\nv 0 0 0")
    ['a.mtl', 'b.mtl', 'my skin.mtl']
    """
    libraries = []
    for body in _LIBRARY_RECORD.findall(text):
        body = body.strip()
        libraries += [body] if body.lower().count(".mtl") <= 1 else re.findall(r"\S+?\.mtl", body, re.I)
    return libraries


def obj_usage(text: str, n_faces: int):
    """The materials an OBJ's text (starting with a newline) uses: (its ``mtllib`` names, the ``usemtl`` names in
    order of first use, each face's number among those (-1 before any ``usemtl``)); None where it names none."""
    if "usemtl" not in text and "mtllib" not in text:
        return None
    libraries = obj_libraries(text)
    marks = _MATERIAL_RECORDS.findall(text)
    is_face = np.fromiter((f == "f" for f, _ in marks), dtype=bool, count=len(marks))
    if int(is_face.sum()) != n_faces:
        return None  # records this reading does not count as the mesh's reader does: left out, not guessed
    uses = np.flatnonzero(~is_face)
    names = [marks[k][1].strip() for k in uses]
    used = list(dict.fromkeys(names))
    number = {name: k for k, name in enumerate(used)}
    use_material = np.array([number[name] for name in names], dtype=np.int64)
    last_use = np.searchsorted(uses, np.flatnonzero(is_face)) - 1  # the usemtl before each face, -1 for none
    face_material = np.where(last_use >= 0, use_material[np.maximum(last_use, 0)] if len(uses) else -1, -1)
    return libraries, used, face_material.astype(np.int64)
