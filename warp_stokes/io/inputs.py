"""The inputs' full set: which files a command reads, so that no output replaces one and a batch knows what it
depends on (:func:`inputs_of`): each USD file's whole layer stack, a glTF's buffers and images, an OBJ's material
libraries and their images, a folder of frames and the frames it would read, a binding's own sources. The files themselves are read through :mod:`.door`.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field

from ..errors import WarpStokesError
from .door import gltf_dependencies, open_input, path_text, read_input
from .scene import is_usd
from .usd.layers import layer_stack

__all__ = ["InputSet", "inputs_of", "file_digest", "FRAME_EXTENSIONS"]

#: the files a folder of frames (poses or meshes) is read from: ``*.obj``, in natural order
FRAME_EXTENSIONS = (".obj",)


def file_digest(path) -> str:
    """SHA-256 of a file's contents (of a folder: of its entries' names and their digests), as hex."""
    digest = hashlib.sha256()
    path = os.fspath(path)
    if os.path.isdir(path):
        for name in sorted(os.listdir(path)):
            digest.update(os.fsencode(name) + b"\0")
            child = os.path.join(path, name)
            if os.path.isfile(child):
                digest.update(file_digest(child).encode())
        return digest.hexdigest()
    digest.update(read_input(path))
    return digest.hexdigest()


@dataclass(frozen=True)
class InputSet:
    """Every file a command reads, as real paths: ``files`` (each with the input it belongs to, for messages), and
    ``folders`` whose files of the frame extensions are read (a new file there would be read next time too).

    Examples
    --------
    >>> s = InputSet({"/data/arm.obj": "the mesh /data/arm.obj"})
    >>> s.meets("/data/arm.obj")
    'the mesh /data/arm.obj'
    >>> s.meets("/data/other.obj") is None
    True
    """

    files: dict = field(default_factory=dict)
    folders: dict = field(default_factory=dict)

    def meets(self, path) -> str | None:
        """What ``path`` would replace among the inputs (a phrase for the message), or None."""
        real = os.path.realpath(path_text(path))
        if real in self.files:
            return self.files[real]
        for known in self.files:  # the same file under another name (a hard link)
            if _same_inode(real, known):
                return self.files[known]
        parent, name = os.path.split(real)
        for folder, whose in self.folders.items():
            if (parent == folder or _same_inode(parent, folder)) and name.lower().endswith(FRAME_EXTENSIONS):
                return f"a frame of {whose} (every .obj file there is read as one)"
        return None

    def union(self, other: "InputSet") -> "InputSet":
        return InputSet({**other.files, **self.files}, {**other.folders, **self.folders})

    def digest(self) -> str:
        """SHA-256 over every file's real path and contents, and each folder's frame names and contents: what a
        batch compares to know that nothing it read has changed."""
        digest = hashlib.sha256()
        for path in sorted(self.files):
            digest.update(os.fsencode(path) + b"\0")
            digest.update((file_digest(path) if os.path.isfile(path) else "missing").encode())
        for folder in sorted(self.folders):
            digest.update(os.fsencode(folder) + b"\0")
            digest.update(file_digest(folder).encode() if os.path.isdir(folder) else b"missing")
        return digest.hexdigest()


def _same_inode(a: str, b: str) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def inputs_of(*sources, error=WarpStokesError, role: str = "input") -> InputSet:
    """Every file the given inputs make a command read: a USD file's whole layer stack (sublayers, references,
    payloads, value clips, recursively, and the assets its attributes name), a ``.gltf``'s buffers and images, an
    OBJ's material libraries and their images, a folder of frames and the frame files in it, a binding's own sources
    (the files it was bound from); any other path as itself. ``None``, ``"auto"`` and objects that are not paths add nothing. A layer that cannot be read is
    one ``error`` naming it.

    Parameters
    ----------
    *sources : paths (or None)
    error : the WarpStokesError subclass for an unreadable layer
    role : str, what the sources are, for messages ("the {role} PATH")

    Returns
    -------
    InputSet

    Examples
    --------
    >>> s = inputs_of("examples/arm/arm.usda")     # doctest: +SKIP
    >>> sorted(s.files)                            # doctest: +SKIP
    ['/.../examples/arm/arm.usda']
    """
    files, folders = {}, {}
    for source in sources:
        if source is None or not isinstance(source, (str, bytes, os.PathLike)):
            continue
        path = path_text(source)
        if path == "auto":
            continue
        real = os.path.realpath(path)
        if os.path.isdir(real):
            folders[real] = f"the {role} {path}"
            continue
        files.setdefault(real, f"the {role} {path}")
        if not os.path.isfile(real):
            continue
        if is_usd(path):
            for layer in layer_stack(path, error).files:
                files.setdefault(layer, f"a layer of the {role} {path} ({layer})")
        elif path.lower().endswith(".gltf"):
            for dependency in gltf_dependencies(path, error):
                files.setdefault(os.path.realpath(dependency), f"a file of the {role} {path} ({dependency})")
        elif path.lower().endswith(".obj"):
            from .looks_in import obj_dependencies

            for dependency in obj_dependencies(path, error):
                files.setdefault(os.path.realpath(dependency), f"a material file of the {role} {path} ({dependency})")
        elif path.lower().endswith(".npz"):
            for recorded in _binding_sources(path):
                files.setdefault(recorded, f"a source of the {role} {path} ({recorded})")
    return InputSet(files, folders)


def _binding_sources(path: str) -> list[str]:
    """The files a binding records it was bound from (none for an archive that is not a binding: it is then refused
    by whatever reads it, with its own message)."""
    import zipfile

    try:  # the metadata alone: a binding's weights may be gigabytes
        with open_input(path) as fh, zipfile.ZipFile(fh) as archive:
            if "meta.npy" not in archive.namelist() or archive.getinfo("meta.npy").file_size > 1 << 24:
                return []
            import numpy as np

            meta = json.loads(str(np.load(archive.open("meta.npy"), allow_pickle=False)))
    except Exception:  # not a binding, or a damaged one: its reader says so
        return []
    if not isinstance(meta, dict):
        return []
    recorded = meta.get("sources")  # the real paths of every file it was bound from
    # and the mesh, cage and asset as named to bind (relative to where it ran): where the binding moved with
    # them (a copied folder), the files of those names beside it, or here, are taken for them
    settings, asset = meta.get("settings"), meta.get("asset")
    names = [settings.get(k) for k in ("mesh", "cage")] if isinstance(settings, dict) else []
    names += [asset.get("path")] if isinstance(asset, dict) else []
    found = list(recorded) if isinstance(recorded, list) else []
    for name in names:
        if not isinstance(name, str) or not name or name.startswith("<") or "\0" in name:
            continue
        name = name.split(":/", 1)[0]  # "asset.usda:/Prim" names a prim of the file
        for place in (name, os.path.join(os.path.dirname(os.path.abspath(path)), name)):
            if os.path.isfile(place):
                found.append(os.path.realpath(place))
    return [p for p in dict.fromkeys(found) if isinstance(p, str)]
