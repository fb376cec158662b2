"""Writing output files whole or not at all, and never over what the user owns: a temporary name in the target
folder, renamed when complete; an output that is an input, or that exists and is not a regular file, refused."""

from __future__ import annotations

import contextlib
import glob
import os
import socket
import stat
import tempfile

from ..errors import WarpStokesError

__all__ = ["atomic_output", "same_file", "check_output_target", "remove_stale_temporaries", "process_alive",
           "write_cage_file"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def same_file(a, b) -> bool:
    """Whether two paths name the same file: the same inode where both exist, else the same real path (an output not
    written yet at an input's place).

    Examples
    --------
    >>> same_file("a/../b.txt", "b.txt")
    True
    """
    a, b = os.fspath(a), os.fspath(b)
    if os.path.exists(a) and os.path.exists(b):
        return os.path.samefile(a, b)
    return os.path.realpath(a) == os.path.realpath(b)


def check_output_target(path, inputs=()) -> None:
    """Refuse, before any work, an output that would replace what the user owns: one of ``inputs`` (paths, None
    skipped), or an existing path that is not a regular file (a device, a pipe, a socket, a folder, or a link to
    one: renaming the finished file over it would replace it, ``/dev/null`` included when run as root).

    Raises
    ------
    WarpStokesError, one line naming the output and what it is

    Examples
    --------
    >>> try:
    ...     check_output_target("/dev/null")
    ... except WarpStokesError as exc:
    ...     print(exc)
    /dev/null: the output exists and is not a regular file (a character device); choose another output
    """
    path = os.fspath(path)
    if os.path.lexists(path):
        try:
            mode = os.stat(path).st_mode
        except OSError:  # a dangling link: writing through it would replace the link
            raise WarpStokesError(f"{path}: the output is a link to nothing ({os.readlink(path)}); choose another "
                                  "output") from None
        if not stat.S_ISREG(mode):
            kind = ("a folder" if stat.S_ISDIR(mode) else "a character device" if stat.S_ISCHR(mode) else
                    "a block device" if stat.S_ISBLK(mode) else "a pipe" if stat.S_ISFIFO(mode) else
                    "a socket" if stat.S_ISSOCK(mode) else "not a file")
            raise WarpStokesError(f"{path}: the output exists and is not a regular file ({kind}); choose another "
                                  "output")
    for source in inputs:
        if source and same_file(path, source):
            raise WarpStokesError(f"{path}: the output is the input {os.fspath(source)}; choose another output name")


def _prefix(path: str) -> str:
    """The temporary files of ``path``: this host's and process's, named after the output."""
    return f".tmp-{socket.gethostname()}-{os.getpid()}-{os.path.basename(path)}-"


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host (another user's included)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def remove_stale_temporaries(path) -> list[str]:
    """Remove the temporary files that an earlier write of ``path`` left when its process was killed (``kill -9``
    during a save): those of this host whose process is gone. Returns the paths removed.

    Examples
    --------
    >>> remove_stale_temporaries("out/arm.npz")   # doctest: +SKIP
    ['out/.tmp-host-4242-arm.npz-k3j2h1.npz']
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    host = socket.gethostname()
    removed = []
    pattern = os.path.join(glob.escape(folder), f".tmp-{glob.escape(host)}-*-{glob.escape(os.path.basename(path))}-*")
    for candidate in glob.glob(pattern):
        pid = os.path.basename(candidate)[len(f".tmp-{host}-"):].split("-", 1)[0]
        if pid.isdigit() and not process_alive(int(pid)):
            with contextlib.suppress(OSError):
                os.unlink(candidate)
                removed.append(candidate)
    return removed


@contextlib.contextmanager
def atomic_output(path, suffix: str = ""):
    """Yield a temporary path beside ``path``; on success it is renamed to ``path`` with the permissions a newly
    created file would get (``mkstemp`` makes it private), on failure it is removed. An existing ``path`` that is not
    a regular file is refused (:func:`check_output_target`); temporary files of earlier writes of ``path`` whose
    process was killed are removed first.

    Examples
    --------
    >>> with atomic_output("out.npz", ".npz") as tmp:   # doctest: +SKIP
    ...     np.savez(tmp, weights=w)
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise WarpStokesError(f"{path}: the folder {folder} does not exist")
    check_output_target(path)
    remove_stale_temporaries(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=_prefix(path), suffix=suffix, dir=folder)
    except OSError as exc:  # a folder that takes no new files (/proc, read-only): name the output
        raise WarpStokesError(f"{path}: could not write it: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        try:
            yield tmp
            os.chmod(tmp, 0o666 & ~_umask())
            check_output_target(path)  # again: it may have appeared while the file was written
            os.replace(tmp, path)
        except OSError as exc:  # a full disk, a vanished folder: name the output, not the temporary file
            raise WarpStokesError(f"{path}: could not write it: {exc.strerror or exc}") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def write_cage_file(path, vertices, faces) -> None:
    """A cage as a mesh file (its format from the extension: obj, ply or off, which keep the handles' order), written
    whole or not at all.

    Examples
    --------
    >>> import os, tempfile, trimesh
    >>> path = os.path.join(tempfile.mkdtemp(), "tet.obj")
    >>> write_cage_file(path, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> trimesh.load(path, process=False).is_watertight
    True
    """
    import trimesh

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    with atomic_output(path, "." + ext) as tmp:
        trimesh.Trimesh(vertices=vertices, faces=faces, process=False).export(tmp, file_type=ext)
