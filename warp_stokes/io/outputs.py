"""One door out: every file the package writes goes through :func:`atomic_output`, and the files of one command go
through one :class:`OutputGroup`.

- Each output is written under a temporary name in its own folder (``.wst~PID~HOST~RANDOM~NAME``, a pattern only
  this package makes) and renamed into place when complete; in a group, all outputs are renamed together once every
  one is written, and a rename that fails puts back the outputs already renamed (their earlier contents, or none).
- An output is refused before any work when it is one of the command's inputs (:class:`~.inputs.InputSet`, and at
  the rename every file read so far in the command: :func:`~.inputs.reading`), or exists and is not a regular file.
- An existing output keeps its permission mode; a new one gets what a new file would (``0o666 & ~umask``).
- Temporary files are removed on failure, on Ctrl-C and, under :func:`interrupt_on_signals`, on SIGTERM and SIGHUP;
  those of this host's processes that died (``kill -9``) are removed by the next write into their folder. Files not
  named in this package's pattern are never touched.
- Messages name the output, never the temporary file.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import re
import secrets
import shutil
import signal
import socket
import stat
from typing import TYPE_CHECKING

from ..errors import WarpStokesError
from .door import file_kind, files_read

if TYPE_CHECKING:  # (the inputs' module imports the USD readers; the door out needs none of them)
    from .inputs import InputSet

__all__ = ["atomic_output", "OutputGroup", "writing", "together", "output_folder", "check_output_target",
           "temporary_path", "is_temporary", "remove_stale_temporaries", "remove_temporaries_of", "process_alive",
           "host_name", "Interrupted", "interrupt_on_signals", "same_file"]

_GROUP: contextvars.ContextVar = contextvars.ContextVar("warp_stokes_output_group", default=None)
_TEMPORARY = re.compile(r"^\.wst~(?P<pid>\d+)~(?P<host>[A-Za-z0-9.-]*)~[0-9a-f]{8}~")
_TEMPORARY_MAX = 160  # bytes of a temporary file's name: the file system's 255, less room for a writer's own suffix
_CLEANED: set = set()  # folders whose stale temporaries this process has removed


def host_name(name: str | None = None) -> str:
    """A host's name (this host's by default) as temporary files carry it: letters, digits, dots and dashes, 32 at
    most."""
    return re.sub(r"[^A-Za-z0-9.-]", "-", socket.gethostname() if name is None else name)[:32]


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host (another user's included)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    except OverflowError:
        return False
    return True


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


def temporary_path(path) -> str:
    """A new temporary name beside ``path``: this package's pattern, this process and host, and the output's name
    (shortened to fit the file system's name limit, its extension kept: writers choose the format by it).

    Examples
    --------
    >>> is_temporary(temporary_path("out/arm.npz"))
    True
    >>> temporary_path("out/arm [take 2].usda").endswith("~arm__take_2_.usda")
    True
    """
    folder, name = os.path.split(os.fspath(path))
    prefix = f".wst~{os.getpid()}~{host_name()}~{secrets.token_hex(4)}~"
    # the output's name in letters, digits, dots, dashes and underscores: every writer (USD's included, which takes
    # UTF-8 names only and reads brackets as package paths) can open it, whatever bytes the output's name holds
    stem, ext = os.path.splitext(name)
    stem, ext = re.sub(r"[^A-Za-z0-9._-]", "_", stem), re.sub(r"[^A-Za-z0-9.]", "_", ext)
    room = _TEMPORARY_MAX - len(prefix)  # writers add their own suffixes (USD's safe output file does)
    ext = ext[: room // 2]
    return os.path.join(folder, prefix + stem[: room - len(ext)] + ext)


def is_temporary(name) -> bool:
    """Whether a file name is one of this package's temporary files."""
    return _TEMPORARY.match(os.path.basename(os.fspath(name))) is not None


def remove_stale_temporaries(folder) -> list[str]:
    """Remove this package's temporary files in ``folder`` whose process, on this host, is gone (a write killed by
    ``kill -9``); nothing else. Returns the paths removed.

    Examples
    --------
    >>> remove_stale_temporaries("out")   # doctest: +SKIP
    ['out/.wst~4242~host~0a1b2c3d~arm.npz']
    """
    folder = os.fspath(folder) or "."
    removed, host = [], host_name()
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = _TEMPORARY.match(entry.name)
        if match and match["host"] == host and not process_alive(int(match["pid"])):
            with contextlib.suppress(OSError):
                os.unlink(entry.path)
                removed.append(entry.path)
    return removed


def remove_temporaries_of(folder, processes) -> list[str]:
    """Remove this package's temporary files in ``folder`` written by ``processes`` (``(host, pid)`` pairs: the
    workers of a batch that has finished, on any host), and this host's stale ones; nothing else."""
    wanted = {(host_name(host), int(pid)) for host, pid in processes}
    removed = remove_stale_temporaries(folder)
    with contextlib.suppress(OSError):
        for entry in os.scandir(os.fspath(folder) or "."):
            match = _TEMPORARY.match(entry.name)
            if match and (match["host"], int(match["pid"])) in wanted:
                with contextlib.suppress(OSError):
                    os.unlink(entry.path)
                    removed.append(entry.path)
    return removed


def check_output_target(path, inputs: InputSet | None = None) -> None:
    """Refuse, before any work, an output that would replace what the user owns: one of ``inputs`` (or a file read
    so far in this command), or an existing path that is not a regular file (a device, a pipe, a socket, a folder,
    or a link to one: renaming the finished file over it would replace it, ``/dev/null`` included when run as root).

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
            raise WarpStokesError(f"{path}: the output exists and is not a regular file ({file_kind(mode)}); choose "
                                  "another output")
    whose = inputs.meets(path) if inputs is not None else None
    if whose is None:
        real = os.path.realpath(path)
        whose = next((f"the input {read}" for read in files_read() if read == real or
                      (os.path.exists(path) and same_file(path, read))), None)
    if whose is not None:
        raise WarpStokesError(f"{path}: the output would replace {whose}; choose another output")


def _check_folder(folder: str, output: str) -> None:
    """``folder`` exists and takes new files (a real file is made and removed: root passes ``os.access`` in read-only
    and virtual folders); errors name ``output``. This package's stale temporaries there are removed, once."""
    if not os.path.isdir(folder):
        raise WarpStokesError(f"{output}: the output folder {folder} does not exist")
    probe = temporary_path(os.path.join(folder, "probe"))
    try:
        os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
    except OSError as exc:
        raise WarpStokesError(f"{output}: the output folder {folder} takes no new files ({exc.strerror})") from None
    finally:
        _remove(probe)
    if folder not in _CLEANED:
        _CLEANED.add(folder)
        remove_stale_temporaries(folder)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _reworded(exc: BaseException, tmp: str, path: str) -> BaseException | None:
    """``exc`` as the error to raise for the output ``path``: the temporary name replaced by the output's in a
    WarpStokesError, an OSError or a USD error (a RuntimeError) turned into one line; None to re-raise as it is."""
    text = " ".join(str(exc).split()).replace(tmp, path).replace(os.path.basename(tmp), os.path.basename(path))
    if isinstance(exc, WarpStokesError):  # rebuilt only where it names the temporary file
        return type(exc)(text) if os.path.basename(tmp) in str(exc) else None
    if isinstance(exc, OSError):
        return WarpStokesError(f"{path}: could not write it: {exc.strerror or text}")
    if isinstance(exc, (RuntimeError, UnicodeError)):  # pxr's Tf.ErrorException; a name USD cannot hold
        return WarpStokesError(f"{path}: could not write it: {text[:200]}")
    return None


class OutputGroup:
    """The files one command writes: checked before any work, written under temporary names, and renamed together
    when every one is complete (see the module docstring). Used through :func:`writing`.

    Parameters
    ----------
    paths : the outputs
    inputs : :class:`~.inputs.InputSet`, optional, the command's inputs, none of which an output may replace
    """

    def __init__(self, paths, inputs: InputSet | None = None):
        self.paths: list[str] = []
        self.inputs = inputs
        self.written: dict[str, str] = {}  # output -> its finished temporary file
        self._open: set = set()
        for path in paths:
            self.add(path)

    def add(self, path, after=None) -> None:
        """One more output of the group (a file a writer finds it needs: an image beside a layer), checked as the
        others were: refused where named twice, where it is a folder or one of the inputs. It is renamed into place
        right after the output ``after`` where that is given (a batch renames its binding last), else last."""
        path = os.fspath(path)
        if any(os.path.realpath(p) == os.path.realpath(path) for p in self.paths):
            raise WarpStokesError(f"{path}: named twice among the outputs")
        if os.path.isdir(path):
            raise WarpStokesError(f"{path}: the output is a folder, not a file")
        _check_folder(os.path.dirname(os.path.abspath(path)), path)
        check_output_target(path, self.inputs)
        place = len(self.paths) if after is None else self.paths.index(self._key(after)) + 1
        self.paths.insert(place, path)

    def holds(self, path) -> bool:
        real = os.path.realpath(os.fspath(path))
        return any(os.path.realpath(p) == real for p in self.paths)

    def _key(self, path) -> str:
        real = os.path.realpath(os.fspath(path))
        return next(p for p in self.paths if os.path.realpath(p) == real)

    @contextlib.contextmanager
    def temporary(self, path):
        """A temporary file for ``path``, kept for :meth:`commit` when the body completes, removed otherwise."""
        key = self._key(path)
        tmp = temporary_path(key)
        try:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        except OSError as exc:
            raise WarpStokesError(f"{key}: could not write it: {exc.strerror or exc}") from None
        self._open.add(tmp)
        try:
            yield tmp
        except BaseException as exc:
            _remove(tmp)
            self._open.discard(tmp)
            better = _reworded(exc, tmp, key)
            if better is not None:
                raise better from None
            raise
        if key in self.written:
            _remove(self.written.pop(key))
        self.written[key] = tmp

    def commit(self) -> None:
        """Rename every written output into place, all or none: a failing rename puts back what was renamed before
        it. Outputs of the group that were not written are left as they are."""
        pending = [(p, self.written[p]) for p in self.paths if p in self.written]
        for path, _ in pending:
            check_output_target(path, self.inputs)  # again: a file may have appeared, or been read, meanwhile
        done, backups = [], []
        try:
            for path, tmp in pending:
                existing = os.stat(path).st_mode if os.path.exists(path) else None
                os.chmod(tmp, stat.S_IMODE(existing) if existing is not None else 0o666 & ~_umask())
                backup = None
                if existing is not None and len(pending) > 1:
                    backup = _backup(path)
                    backups.append(backup)
                os.replace(tmp, path)
                done.append((path, backup))
        except BaseException as exc:  # a failed rename, or Ctrl-C / SIGTERM among the renames: all put back
            for path, backup in reversed(done):
                with contextlib.suppress(OSError):
                    if backup is None:
                        os.unlink(path)
                    else:
                        os.replace(backup, path)
            if not isinstance(exc, OSError):
                raise
            failed = pending[len(done)][0]
            others = f"; the other outputs are as they were ({len(done)} put back)" if len(pending) > 1 else ""
            raise WarpStokesError(f"{failed}: could not write it: {exc.strerror or exc}{others}") from None
        finally:
            for backup in backups:
                _remove(backup)
            for _, tmp in pending:
                _remove(tmp)
            self.written.clear()

    def discard(self) -> None:
        for tmp in list(self.written.values()) + list(self._open):
            _remove(tmp)
        self.written.clear()
        self._open.clear()


def _backup(path: str) -> str:
    """A second name for an output about to be replaced, to put it back if a later rename of its group fails."""
    backup = temporary_path(path)
    try:
        os.link(path, backup)
    except OSError:  # a file system without hard links
        shutil.copy2(path, backup)
    return backup


def _remove(path: str) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


@contextlib.contextmanager
def writing(paths, inputs: InputSet | None = None):
    """Write the outputs ``paths`` of one command together: each checked now (before any work: see
    :class:`OutputGroup`), every :func:`atomic_output` of one of them inside the block written to a temporary file,
    and all renamed into place when the block completes; nothing of them is left when it raises.

    Examples
    --------
    >>> with writing(["out/B.cage.obj", "out/B.npz"], inputs_of("arm.obj")):   # doctest: +SKIP
    ...     write_cage_file("out/B.cage.obj", v, f)
    ...     binding.save("out/B.npz")
    """
    group = OutputGroup(paths, inputs)
    token = _GROUP.set(group)
    try:
        yield group
    except BaseException:
        group.discard()
        raise
    finally:
        _GROUP.reset(token)
    group.commit()


@contextlib.contextmanager
def together(paths):
    """Write ``paths`` (an output and the files that go with it: a layer and its images) in one group: the
    enclosing :func:`writing` group where it holds the first of them (the others are added to it, and renamed with
    it when the command's outputs are), else a group of their own (:func:`writing`).

    Examples
    --------
    >>> with together(["walk.usda", "walk.texture0.png"]):   # doctest: +SKIP
    ...     write_layer_and_images()
    """
    paths = [os.fspath(p) for p in paths]
    group = _GROUP.get()
    if group is not None and paths and group.holds(paths[0]):
        for path in reversed(paths[1:]):  # each right after the first: in their order, before the group's others
            if not group.holds(path):
                group.add(path, after=paths[0])
        yield group
        return
    with writing(paths) as own:
        yield own


@contextlib.contextmanager
def atomic_output(path, suffix: str = ""):
    """Yield a temporary path to write the output ``path`` to: renamed into place when the block completes (or, for
    an output of the enclosing :func:`writing` group, when the group does), removed when it raises. The output is
    checked first (:func:`check_output_target`); errors raised inside name ``path``, never the temporary file.

    ``suffix`` is kept for writers that choose a format by the name: the temporary name ends in the output's name.

    Examples
    --------
    >>> with atomic_output("out.npz") as tmp:   # doctest: +SKIP
    ...     np.savez(tmp, weights=w)
    """
    group = _GROUP.get()
    if group is not None and group.holds(path):
        with group.temporary(path) as tmp:
            yield tmp
        return
    with writing([path]) as own, own.temporary(path) as tmp:
        yield tmp


@contextlib.contextmanager
def output_folder(path):
    """A command's output folder (``sweep``, ``batch``): refused before any work when it exists and is not a folder,
    or its parent does not exist, or it takes no new files; made when missing, and removed again when the block
    raises and it is still empty (a failed command leaves nothing behind).

    Examples
    --------
    >>> with output_folder("out") as folder:   # doctest: +SKIP
    ...     write_sweep(rows, folder)
    """
    path = os.fspath(path)
    if os.path.lexists(path) and not os.path.isdir(path):
        raise WarpStokesError(f"{path}: the output exists and is not a folder")
    parent = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(parent):
        raise WarpStokesError(f"{path}: the output folder's parent {parent} does not exist")
    made = not os.path.isdir(path)
    if made:
        try:
            os.mkdir(path)
        except OSError as exc:
            raise WarpStokesError(f"{path}: could not make the output folder ({exc.strerror or exc})") from None
    try:
        _check_folder(os.path.abspath(path), path)
        yield path
    except BaseException:
        if made:
            with contextlib.suppress(OSError):
                os.rmdir(path)
        raise


class Interrupted(BaseException):
    """SIGTERM or SIGHUP, raised where the process is so that every write's clean-up runs (as for Ctrl-C)."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def interrupt_on_signals(signums=(signal.SIGTERM, signal.SIGHUP)):
    """Within the block, the signals ``signums`` raise :class:`Interrupted` (in the main thread; elsewhere nothing
    changes), so that temporary files are removed as on Ctrl-C."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, frame):
        raise Interrupted(signum)

    previous = {}
    for signum in signums:
        with contextlib.suppress(ValueError, OSError):
            previous[signum] = signal.signal(signum, interrupt)
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
