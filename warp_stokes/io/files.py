"""Writing output files whole or not at all: a temporary name in the target folder, renamed when complete."""

from __future__ import annotations

import contextlib
import os
import tempfile

from ..errors import WarpStokesError

__all__ = ["atomic_output"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(path, suffix: str = ""):
    """Yield a temporary path beside ``path``; on success it is renamed to ``path`` with the permissions a newly
    created file would get (``mkstemp`` makes it private), on failure it is removed.

    Examples
    --------
    >>> with atomic_output("out.npz", ".npz") as tmp:   # doctest: +SKIP
    ...     np.savez(tmp, weights=w)
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise WarpStokesError(f"{path}: the folder {folder} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=suffix, dir=folder)
    except OSError as exc:  # a folder that takes no new files (/proc, read-only): name the output
        raise WarpStokesError(f"{path}: could not write it: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        try:
            yield tmp
            os.chmod(tmp, 0o666 & ~_umask())
            os.replace(tmp, path)
        except OSError as exc:  # a full disk, a vanished folder: name the output, not the temporary file
            raise WarpStokesError(f"{path}: could not write it: {exc.strerror or exc}") from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
