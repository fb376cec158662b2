"""OBJ files read directly and fast: the common all-triangles file by regular expressions at C speed, the rest
(polygons, negative indices, normals, texture coordinates) by vectorised passes over the records."""

from __future__ import annotations

import re
import warnings

import numpy as np

from ..errors import MeshError

__all__ = ["read_obj"]


def _records(lines: list, tag: str) -> tuple[np.ndarray, np.ndarray]:
    """All tokens of the lines starting with `tag` (tag tokens removed) and each line's token count, in one
    vectorised pass: 50k-line files take milliseconds instead of a Python loop per line."""
    tokens = np.array("\n".join(ln for ln in lines if ln.startswith(tag + " ")).split())
    if len(tokens) == 0:
        return tokens, np.zeros(0, dtype=np.int64)
    starts = np.flatnonzero(tokens == tag)
    counts = np.diff(np.append(starts, len(tokens))) - 1
    return tokens[np.setdiff1d(np.arange(len(tokens)), starts, assume_unique=True)], counts


# a literal newline first is what makes these fast (4 ms for the ogre's 26k lines, against 14 ms with ^ and re.M)
_VERTEX_LINE = re.compile(r"\nv[ \t]([^\n]*)")
_FACE_LINE = re.compile(r"\nf[ \t]([^\n]*)")


def _read_obj_triangles(text: str):
    """The common case at C speed (numpy's text parser; the ogre's 26k vertices in 0.04 s instead of 0.15 s): every
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
    vertices (V, 3), polygons (an (F, k) array or a list of index lists, 0-based), per-vertex normals or None,
    face-varying UVs ``(st, st_indices)`` or None

    Raises
    ------
    MeshError
        An unreadable file, vertex or face, naming the line.
    """
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            text = fh.read()
    except OSError as exc:
        raise MeshError(f"{path}: cannot read it ({exc.strerror or exc})") from None
    fast = _read_obj_triangles(text)
    if fast is not None:
        return fast
    lines = text.replace("\t", " ").splitlines()  # tabs separate tokens as spaces do (read so on the fast path too)
    tokens, counts = _records(lines, "v")
    if len(counts) == 0:
        return np.zeros((0, 3)), [], None, None
    try:
        if (counts < 3).any():
            raise ValueError
        firsts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        verts = tokens[firsts[:, None] + np.arange(3)].astype(np.float64).reshape(-1, 3)
    except ValueError:  # find the offending line for the message
        for line_no, ln in enumerate(lines, 1):
            if ln.startswith("v "):
                try:
                    if len([float(x) for x in ln.split()[1:4]]) != 3:
                        raise ValueError
                except ValueError:
                    raise MeshError(f"{path}: line {line_no}: unreadable vertex {ln.strip()!r}") from None
        raise
    normals = None
    if any(ln.startswith("vn ") for ln in lines):
        try:
            normals = _obj_normals(lines, [(0, ln) for ln in lines if ln.startswith("f ")], len(verts))
        except MeshError as exc:
            raise MeshError(f"{path}: {exc}") from None
    tokens, counts = _records(lines, "f")
    try:
        indices = np.char.partition(tokens, "/")[:, 0].astype(np.int64) if len(tokens) else np.zeros(0, np.int64)
        if (counts < 3).any():
            raise ValueError
    except (ValueError, OverflowError):
        for line_no, ln in enumerate(lines, 1):
            if ln.startswith("f "):
                try:
                    corners = [int(tok.split("/", 1)[0]) for tok in ln.split()[1:]]
                    if len(corners) < 3 or max(abs(c) for c in corners) > len(verts):
                        raise ValueError
                except ValueError:
                    raise MeshError(f"{path}: line {line_no}: unreadable face {ln.strip()!r} (three or more vertex "
                                    f"indices within the file's {len(verts)} vertices)") from None
        raise
    uvs = None
    if any(ln.startswith("vt ") for ln in lines):
        uvs = _obj_uvs(lines, tokens)
        if uvs is None:
            warnings.warn(f"{path}: the texture coordinates (vt) are dropped: not every face corner names one, or "
                          "one is out of range", stacklevel=3)
    if len(indices) and indices.min() > 0 and len(np.unique(counts)) == 1:
        return verts, indices.reshape(len(counts), counts[0]) - 1, normals, uvs  # the common case
    polys = np.split(indices, np.cumsum(counts)[:-1]) if len(indices) else []
    if len(indices) and indices.min() < 0:
        # negative indices count back from the last vertex read before the face
        face_lines = [n for n, ln in enumerate(lines, 1) if ln.startswith("f ")]
        vertex_lines = np.array([n for n, ln in enumerate(lines, 1) if ln.startswith("v ")])
        seen = np.searchsorted(vertex_lines, face_lines)
        polys = [np.where(p > 0, p, s + p + 1) for p, s in zip(polys, seen)]
    return verts, [list(p - 1) for p in polys], normals, uvs


def _obj_uvs(lines: list, face_tokens: np.ndarray) -> tuple | None:
    """Face-varying texture coordinates: the ``vt`` table and, per face corner, its ``v/vt[/vn]`` index (None
    unless every corner names one)."""
    tokens, counts = _records(lines, "vt")
    if len(counts) == 0 or (counts < 2).any() or len(face_tokens) == 0:
        return None
    firsts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    try:
        st = tokens[firsts[:, None] + np.arange(2)].astype(np.float64).reshape(-1, 2)
        refs = np.char.partition(np.char.partition(face_tokens, "/")[:, 2], "/")[:, 0]
        if (refs == "").any():
            return None
        st_indices = refs.astype(np.int64)
    except ValueError:
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


def _obj_normals(lines: list, face_lines: list, n_vertices: int) -> np.ndarray | None:
    """Per-vertex normals from `vn` records and the `v//vn` or `v/vt/vn` face tokens (None if incomplete)."""
    records = [(n, ln.split()[1:4]) for n, ln in enumerate(lines, 1) if ln.startswith("vn ")]
    try:
        table = np.array([r for _, r in records], dtype=np.float64).reshape(-1, 3)
    except ValueError:  # a record with fewer than three numbers, or words
        line_no, bad = next((n, r) for n, r in records if len(r) != 3 or not all(_is_number(x) for x in r))
        raise MeshError(f"line {line_no}: unreadable normal 'vn {' '.join(bad)}'") from None
    sums = np.zeros((n_vertices, 3))
    for _, ln in face_lines:
        for tok in ln.split()[1:]:
            parts = tok.split("/")
            if len(parts) < 3 or not parts[2]:
                return None
            v, vn = int(parts[0]), int(parts[2])
            v = v - 1 if v > 0 else n_vertices + v
            vn = vn - 1 if vn > 0 else len(table) + vn
            if not (0 <= v < n_vertices and 0 <= vn < len(table)):
                return None
            sums[v] += table[vn]
    length = np.linalg.norm(sums, axis=1)
    if (length == 0).any():
        return None
    return sums / length[:, None]
