"""One batch at a time per output folder: a lock file holding the owner's pid, taken over when its process is gone."""

from __future__ import annotations

import contextlib
import os

from ..errors import WarpStokesError
from ..io.files import process_alive

__all__ = ["LOCK_NAME", "folder_lock"]

LOCK_NAME = ".warp-stokes.lock"


@contextlib.contextmanager
def folder_lock(outdir: str):
    """Hold ``outdir``'s batch lock: created exclusively with this process's pid; a lock whose process is gone
    is taken over; one held by a live process is a WarpStokesError naming it."""
    path = os.path.join(outdir, LOCK_NAME)
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            try:
                with open(path, encoding="utf-8") as fh:
                    owner = int(fh.read().strip() or 0)
            except (OSError, ValueError):
                owner = 0
            if owner and owner != os.getpid() and process_alive(owner):
                raise WarpStokesError(
                    f"{outdir}: another batch (pid {owner}) is writing to this folder; wait for it to finish "
                    f"(or remove {path} if that process is not a warp-stokes batch)") from None
            os.unlink(path)  # stale: its batch was killed
            continue
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(str(os.getpid()))
        break
    else:
        raise WarpStokesError(f"{outdir}: could not take the batch lock {path}")
    try:
        yield path
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
