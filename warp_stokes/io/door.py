"""One door in: every file the package reads is opened here.

A file is read only when it is a regular file (a link to one included): pipes, devices, sockets and folders are
refused before anything blocks or reads without end, and a file is read within the size it has when opened. Every
failure is one :class:`~warp_stokes.errors.WarpStokesError` (of the caller's kind) naming the file. Within a
:func:`reading` scope (a command, a batch asset) every file read is recorded, so that the door out
(:mod:`warp_stokes.io.outputs`) refuses to replace any of them.
"""

from __future__ import annotations

import contextlib
import contextvars
import io
import json
import os
import stat

from ..errors import WarpStokesError

__all__ = ["file_kind", "checked_input", "open_input", "read_input", "input_bytes", "read_numpy", "reading",
           "files_read", "record_read", "path_text", "gltf_dependencies", "reason"]

# the real paths of the files read in the current command (see ``reading``); None outside one
_READ: contextvars.ContextVar = contextvars.ContextVar("warp_stokes_files_read", default=None)


def file_kind(mode: int) -> str:
    """What a file of ``mode`` is, in words ("a pipe", "a folder", ...).

    Examples
    --------
    >>> file_kind(os.stat("/dev/null").st_mode)
    'a character device'
    """
    return ("a regular file" if stat.S_ISREG(mode) else "a folder" if stat.S_ISDIR(mode) else
            "a character device" if stat.S_ISCHR(mode) else "a block device" if stat.S_ISBLK(mode) else
            "a pipe" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else "not a file")


def record_read(path: str) -> None:
    """Record ``path`` as read in the current :func:`reading` scope (for readers that open files themselves: USD)."""
    read = _READ.get()
    if read is not None:
        read.add(os.path.realpath(path))


@contextlib.contextmanager
def reading():
    """A scope (one command, one batch asset) that records every file read through this module, so that the door out
    refuses to replace any of them even where the command did not know it would read it.

    Examples
    --------
    >>> with reading():
    ...     files_read()
    frozenset()
    """
    token = _READ.set(set())
    try:
        yield
    finally:
        _READ.reset(token)


def files_read() -> frozenset:
    """The real paths read in the current :func:`reading` scope (empty outside one)."""
    return frozenset(_READ.get() or ())


def path_text(path) -> str:
    """A path as text (bytes decoded as the file system does)."""
    return os.fsdecode(path) if isinstance(path, bytes) else os.fspath(path)


def checked_input(path, error=WarpStokesError, what: str = "file", folder: bool = False) -> str:
    """``path`` as a string when it names a regular file (or, with ``folder``, a folder) that exists: otherwise one
    ``error`` naming it and what it is.

    Parameters
    ----------
    path : str | os.PathLike
    error : the WarpStokesError subclass to raise (MeshError for a mesh, BindingError for poses, ...)
    what : str, what the file should hold, for the message ("mesh", "poses", ...)
    folder : bool, a folder is accepted too (frames)

    Returns
    -------
    str

    Examples
    --------
    >>> try:
    ...     checked_input("/dev/zero", what="mesh")
    ... except WarpStokesError as exc:
    ...     print(exc)
    /dev/zero: a character device, not a mesh file
    """
    path = path_text(path)
    if "\0" in path:
        raise error(f"{path!r}: a file name cannot hold a NUL character")
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        if os.path.islink(path):
            raise error(f"{path}: a link to nothing ({os.readlink(path)})") from None
        raise error(f"{path}: no such file" + (" or folder" if folder else "")) from None
    except OSError as exc:  # a name too long, a loop of links, a folder we may not enter
        raise error(f"{path}: cannot read it ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode) and folder:
        return path
    if not stat.S_ISREG(mode):
        if stat.S_ISDIR(mode):
            raise error(f"{path}: a folder, not a {what} file")
        raise error(f"{path}: {file_kind(mode)}, not a {what} file")
    return path


@contextlib.contextmanager
def open_input(path, error=WarpStokesError, what: str = "file"):
    """A regular file opened for reading (binary), for readers that seek in it (zip archives, numpy's arrays): the
    check of :func:`checked_input` made again on the open file, so that one swapped in meanwhile is refused too.

    Raises
    ------
    ``error``, one line naming the file: missing, not a regular file, unreadable

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.NamedTemporaryFile(suffix=".txt") as tmp, open_input(tmp.name) as fh:
    ...     fh.read()
    b''
    """
    path = checked_input(path, error, what)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)  # (O_NONBLOCK: a pipe swapped in after the check does not block the open)
    except OSError as exc:
        raise error(f"{path}: cannot read it ({exc.strerror or exc})") from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        raise error(f"{path}: {file_kind(mode)}, not a {what} file")
    with os.fdopen(fd, "rb") as fh:
        try:
            yield fh
        except OSError as exc:
            raise error(f"{path}: cannot read it ({exc.strerror or exc})") from None
    record_read(path)


def read_input(path, error=WarpStokesError, what: str = "file") -> bytes:
    """The bytes of a regular file, read within the size it had when opened (a file that grows is not followed).

    Raises
    ------
    ``error``, one line naming the file: missing, not a regular file, unreadable

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.NamedTemporaryFile(suffix=".txt") as fh:
    ...     _ = fh.write(b"v 0 0 0\\n"); fh.flush()
    ...     read_input(fh.name)
    b'v 0 0 0\\n'
    """
    with open_input(path, error, what) as fh:
        return fh.read(os.fstat(fh.fileno()).st_size)


def input_bytes(path, error=WarpStokesError, what: str = "file"):
    """:func:`read_input` as a binary file object (for readers that take one: trimesh)."""
    return io.BytesIO(read_input(path, error, what))


def read_numpy(path, error=WarpStokesError, what: str = "array"):
    """A ``.npy`` array, or a ``.npz`` archive as a dict of its arrays (all read now, so that a damaged member is
    this error and not a later one), without unpickling; any failure is one ``error`` naming the file. Read from
    the file itself: an archive's arrays take their own memory only.

    Examples
    --------
    >>> import tempfile
    >>> path = tempfile.mktemp(suffix=".npy"); np.save(path, np.zeros((2, 3)))   # doctest: +SKIP
    >>> read_numpy(path).shape                                                  # doctest: +SKIP
    (2, 3)
    """
    import zipfile

    import numpy as np

    with open_input(path, error, what) as fh:
        archive = fh.read(4) == b"PK\x03\x04"
        fh.seek(0)
        try:
            if not archive:
                return np.load(fh, allow_pickle=False)
            with zipfile.ZipFile(fh) as members:
                declared = sum(info.file_size for info in members.infolist())
            if declared > _memory_for_reading():  # a zip bomb, or more than this machine holds
                raise error(f"{os.fspath(path)}: its arrays would take {declared / 2**30:.1f} GiB unpacked, more "
                            "than the memory free")
            fh.seek(0)
            with np.load(fh, allow_pickle=False) as loaded:
                return {key: loaded[key] for key in loaded.files}
        except WarpStokesError:
            raise
        except Exception as exc:  # numpy and zipfile raise many types for damaged files
            kind = "archive (.npz)" if archive else "array (.npy)"
            raise error(f"{os.fspath(path)}: cannot read it as a numpy {kind} ({reason(exc)})") from None


def _memory_for_reading() -> int:
    """Bytes that reading may take: the memory available (half of it), at least 1 GiB."""
    try:
        pages = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        pages = 1 << 33
    return max(pages // 2, 1 << 30)


def gltf_dependencies(path: str, error) -> list[str]:
    """The files a ``.gltf`` names (buffers and images that are not data URIs), as paths beside it."""
    from urllib.parse import unquote

    try:
        document = json.loads(read_input(path, error, "glTF"))
    except (ValueError, RecursionError) as exc:  # (a UnicodeDecodeError is a ValueError)
        raise error(f"{path}: not a glTF file ({reason(exc)})") from None
    if not isinstance(document, dict):
        raise error(f"{path}: not a glTF file (its JSON is not an object)")
    names = []
    for key in ("buffers", "images"):
        entries = document.get(key) or []
        if not isinstance(entries, list):
            raise error(f"{path}: not a glTF file ('{key}' is not a list)")
        for entry in entries:
            uri = entry.get("uri") if isinstance(entry, dict) else None
            if isinstance(uri, str) and uri and not uri.startswith("data:"):
                names.append(os.path.join(os.path.dirname(os.path.abspath(path)), unquote(uri)))
    return names


def reason(exc) -> str:
    """An exception's message (or a text) on one line, short; a message that cannot be made text (pxr's errors
    about bytes that are not UTF-8) is the exception's type."""
    try:
        text = " ".join(str(exc).split()) or type(exc).__name__
    except Exception:
        text = f"{type(exc).__name__} (its message is not readable text)"
    return text if len(text) <= 200 else text[:197] + "..."
