"""Meshes out as mesh files: a cage (formats that keep the handles' order) and a deformed mesh, each written whole or
not at all through :func:`~warp_stokes.io.outputs.atomic_output`."""

from __future__ import annotations

import os

from ..errors import WarpStokesError
from .outputs import atomic_output

__all__ = ["CAGE_FORMATS", "MESH_FORMATS", "write_cage_file", "write_mesh_file"]

#: formats that keep a cage's vertex order (STL is a triangle soup)
CAGE_FORMATS = ("obj", "ply", "off")
#: formats a deformed mesh is written in
MESH_FORMATS = ("obj", "ply", "off", "stl", "glb")


def _format(path: str, formats) -> str:
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    if ext not in formats:
        raise WarpStokesError(f"{path}: unsupported format {ext!r} (use {', '.join(formats[:-1])} or {formats[-1]})")
    return ext


def write_cage_file(path, vertices, faces) -> None:
    """A cage as a mesh file (obj, ply or off by the extension: formats that keep the handles' order).

    Examples
    --------
    >>> import os, tempfile, trimesh
    >>> path = os.path.join(tempfile.mkdtemp(), "tet.obj")
    >>> write_cage_file(path, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> trimesh.load(path, process=False).is_watertight
    True
    """
    write_mesh_file(path, vertices, faces, CAGE_FORMATS)


def write_mesh_file(path, vertices, faces, formats=MESH_FORMATS) -> None:
    """A mesh as a file of one of ``formats``, chosen by the extension (point sets only where the format holds
    points: obj, ply, off).

    Examples
    --------
    >>> import os, tempfile
    >>> path = os.path.join(tempfile.mkdtemp(), "tri.ply")
    >>> write_mesh_file(path, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    >>> os.path.getsize(path) > 0
    True
    """
    import numpy as np
    import trimesh

    path = os.fspath(path)
    ext = _format(path, formats)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0 and ext in ("stl", "glb"):  # they keep triangles only: a file of no vertices
        raise WarpStokesError(f"{path}: the mesh has no faces (a point set), which {ext} cannot hold; write obj, ply "
                              "or off")
    mesh = trimesh.Trimesh(vertices=np.asarray(vertices, dtype=np.float64), faces=faces, process=False)
    with atomic_output(path) as tmp:
        mesh.export(tmp, file_type=ext)
