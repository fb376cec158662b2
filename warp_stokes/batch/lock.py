"""One batch at a time per output folder: a lock file naming the owner's host and process, taken over only when it is
this host's and its process is gone (a lock of another host cannot be checked from here: it is refused, naming it)."""

from __future__ import annotations

import contextlib
import json
import os
import socket

from ..errors import WarpStokesError
from ..io.door import read_input
from ..io.outputs import process_alive

__all__ = ["LOCK_NAME", "folder_lock", "lock_owner"]

LOCK_NAME = ".warp-stokes.lock"


def lock_owner(path: str) -> tuple[str, int] | None:
    """The (host, pid) a lock file names; None when it names none (empty, damaged). A lock written by an earlier
    version holds a pid alone: this host's.

    Examples
    --------
    >>> lock_owner("/nonexistent/.warp-stokes.lock") is None
    True
    """
    try:  # through the one door in: a lock replaced by a pipe must not block the batch
        text = read_input(path, what="lock")[:4096].decode("utf-8", errors="replace").strip()
    except WarpStokesError:
        return None
    try:
        record = json.loads(text)
    except ValueError:
        return None
    if isinstance(record, int) and not isinstance(record, bool) and record > 0:
        return socket.gethostname(), record
    if isinstance(record, dict) and isinstance(record.get("host"), str) and isinstance(record.get("pid"), int):
        return record["host"], record["pid"]
    return None


@contextlib.contextmanager
def folder_lock(outdir: str):
    """Hold ``outdir``'s batch lock: created exclusively, naming this host and process; a lock of this host whose
    process is gone (or that names no owner) is taken over; one held by a live process, or by another host, is a
    WarpStokesError naming it."""
    path = os.path.join(outdir, LOCK_NAME)
    me = {"host": socket.gethostname(), "pid": os.getpid()}
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            owner = lock_owner(path)
            if owner is not None and owner != (me["host"], me["pid"]):
                host, pid = owner
                if host != me["host"]:
                    raise WarpStokesError(
                        f"{outdir}: a batch on host {host} (pid {pid}) holds this folder; wait for it to finish (or "
                        f"remove {path} if that batch is gone)") from None
                if process_alive(pid):
                    raise WarpStokesError(
                        f"{outdir}: another batch (pid {pid}) is writing to this folder; wait for it to finish "
                        f"(or remove {path} if that process is not a warp-stokes batch)") from None
            with contextlib.suppress(FileNotFoundError):
                os.unlink(path)  # stale: its batch was killed
            continue
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            json.dump(me, fh)
        break
    else:
        raise WarpStokesError(f"{outdir}: could not take the batch lock {path}")
    try:
        yield path
    finally:
        if lock_owner(path) == (me["host"], me["pid"]):
            with contextlib.suppress(OSError):
                os.unlink(path)
