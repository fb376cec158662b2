"""A cage editor without a screen: handles moved and turned, the rest of the cage following by a scheme, the mesh
deformed at once, undo and redo, poses keyed on a timeline and saved through the writers ``animate`` uses.

The browser editor (:mod:`.server`, ``warp-stokes edit``) drives one of these; scripts and tests drive it the same
way. Its state is the current cage pose, the handles pinned where they are, the keys and the history.

How the rest follows (:class:`~warp_stokes.geometry.cage_follow.CageFollow`): the moved handles and the pinned ones
are the constraints, every other handle is solved for from the *rest* cage: ``"none"`` leaves them where they are,
``"laplacian"`` makes the displacement from the rest cage bi-Laplacian smooth, ``"arap"`` keeps each handle's
neighbourhood as rigid as possible. A handle moved before and not pinned is solved for again: pin what should stay.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..binding import Binding, load_binding
from ..binding.deform import deform_on_host
from ..binding.inbetween import inbetween
from ..errors import WarpStokesError
from ..io.poses import Poses, load_poses

__all__ = ["CageEditor", "SCHEMES", "rotation_matrix"]

#: how the handles that are neither moved nor pinned follow a move
SCHEMES = ("none", "laplacian", "arap")
#: the most steps :meth:`CageEditor.undo` can go back
HISTORY = 500


def rotation_matrix(rotation) -> np.ndarray:
    """A 3 x 3 rotation from a rotation matrix or a rotation vector (axis times angle, radians).

    Examples
    --------
    >>> np.round(rotation_matrix([0, 0, np.pi / 2]) @ [1, 0, 0], 12) + 0.0
    array([0., 1., 0.])
    """
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape == (3, 3):
        if not np.all(np.isfinite(r)) or not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise WarpStokesError("rotation: a 3 x 3 matrix must be a rotation (orthonormal, determinant +1)")
        return r
    if r.shape != (3,) or not np.all(np.isfinite(r)):
        raise WarpStokesError(f"rotation: give a 3 x 3 rotation matrix or a rotation vector of 3 numbers, got shape "
                              f"{r.shape}")
    angle = float(np.linalg.norm(r))
    if angle == 0.0:
        return np.eye(3)
    k = r / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * cross + (1.0 - np.cos(angle)) * cross @ cross


@dataclass(frozen=True)
class _State:
    """What undo and redo restore."""

    cage: np.ndarray
    pinned: tuple
    keys: tuple  # ((frame, cage), ...) in frame order
    frame: float


class CageEditor:
    """Edit a bound character by its cage.

    Parameters
    ----------
    binding : Binding or path of a binding file
    poses : optional, a pose sequence to start from (a path ``animate`` takes, a :class:`~warp_stokes.io.Poses`, or
        an (F, L, 3) array): every pose becomes a key at its frame, and the editor starts at the first
    scheme : str, the default of :meth:`move` (one of :data:`SCHEMES`)
    interpolation : "linear" | "spline", how :meth:`timeline` in-betweens keys

    Attributes
    ----------
    binding : Binding
    cage : (L, 3) float64, the current cage pose (a copy)
    pinned : tuple of int, handles held where they are when others move
    frame : float, the current frame of the timeline

    Examples
    --------
    >>> ed = CageEditor("arm.npz")                                            # doctest: +SKIP
    >>> ed.pin(range(10))                                                     # doctest: +SKIP
    >>> ed.move([40], offset=[0.0, 0.1, 0.0], scheme="arap")                  # doctest: +SKIP
    >>> ed.key(0); ed.seek(24); ed.move([40], rotation=[0, 0, 0.5]); ed.key(24)  # doctest: +SKIP
    >>> ed.save("edited.usda")                                                # doctest: +SKIP
    """

    def __init__(self, binding, poses=None, scheme: str = "arap", interpolation: str = "linear"):
        from ..geometry.cage_follow import CageFollow

        self.binding_path = None
        if not isinstance(binding, Binding):
            self.binding_path = os.fspath(binding)
            binding = load_binding(self.binding_path, device="cpu")
        self.binding = binding
        self.scheme = _scheme(scheme)
        if interpolation not in ("linear", "spline"):
            raise WarpStokesError(f"interpolation must be linear or spline, got {interpolation!r}")
        self.interpolation = interpolation
        self.follow = CageFollow(binding.cage_vertices, binding.cage_faces)
        self.rest = np.array(binding.cage_vertices, dtype=np.float64)
        self.diagonal = float(np.linalg.norm(np.ptp(self.rest, axis=0)))
        self._cage = self.rest.copy()
        self._pinned: tuple = ()
        self._keys: dict = {}
        self.frame = 0.0
        self._undo: list[_State] = []
        self._redo: list[_State] = []
        self._changes = 0
        self.poses_name = None
        #: the file the poses were read from (a save never replaces it), where they came from one
        self.poses_path = os.fspath(poses) if isinstance(poses, (str, os.PathLike)) else None
        if poses is not None:
            loaded = self._poses(poses)
            self.poses_name = loaded.name
            self._keys = {float(f): p.copy() for f, p in zip(loaded.frames, loaded.positions)}
            self.frame = float(loaded.frames[0])
            self._cage = loaded.positions[0].copy()

    # -- state ---------------------------------------------------------------------------------------------------

    @property
    def cage(self) -> np.ndarray:
        return self._cage.copy()

    @property
    def pinned(self) -> tuple:
        return self._pinned

    @property
    def keys(self) -> dict:
        """Frame -> keyed cage pose (copies), in frame order."""
        return {f: self._keys[f].copy() for f in sorted(self._keys)}

    def mesh(self) -> np.ndarray:
        """The mesh deformed by the current cage: (V, 3) float32."""
        return self.deform(self._cage)

    def deform(self, cage) -> np.ndarray:
        """The mesh deformed by ``cage`` ((L, 3)): one product of the weights with the pose, on the host, as
        ``deform`` and ``animate`` compute it on a CPU."""
        return deform_on_host(self.binding.weights, cage)

    def _state(self) -> _State:
        return _State(self._cage.copy(), self._pinned, tuple((f, self._keys[f].copy()) for f in sorted(self._keys)),
                      self.frame)

    def _restore(self, state: _State) -> None:
        self._cage = state.cage.copy()
        self._pinned = state.pinned
        self._keys = {f: c.copy() for f, c in state.keys}
        self.frame = state.frame

    @property
    def unsaved(self) -> int:
        """Steps (moves, pins, keys, undos ...) since the last :meth:`save` (or the start)."""
        return self._changes

    def _record(self) -> None:
        self._changes += 1
        self._undo.append(self._state())
        del self._undo[:-HISTORY]
        self._redo.clear()

    def checkpoint(self) -> None:
        """Make the current state one :meth:`undo` goes back to (where a drag of many small moves starts)."""
        self._record()

    def undo(self) -> bool:
        """Go back one step (a move, a pin, a key, a reset); False when there is none."""
        return self._step(self._undo, self._redo)

    def redo(self) -> bool:
        """Go forward one undone step; False when there is none."""
        return self._step(self._redo, self._undo)

    def _step(self, source: list, other: list) -> bool:
        """Restore the last state of ``source``, keeping the current one on ``other``."""
        if not source:
            return False
        self._changes += 1
        other.append(self._state())
        self._restore(source.pop())
        return True

    def reset(self) -> np.ndarray:
        """The cage back to its rest pose (undoable); the keys stay."""
        self._record()
        self._cage = self.rest.copy()
        return self.cage

    # -- editing -------------------------------------------------------------------------------------------------

    def handles(self, handles) -> np.ndarray:
        """``handles`` as a checked array of distinct handle numbers."""
        ids = np.asarray(list(handles) if not isinstance(handles, (int, np.integer)) else [handles])
        if ids.size == 0:
            return ids.astype(np.int64)
        if ids.ndim != 1 or not np.issubdtype(ids.dtype, np.integer):
            raise WarpStokesError(f"handles: give handle numbers (integers), got {handles!r}"[:200])
        n = len(self.rest)
        bad = ids[(ids < 0) | (ids >= n)]
        if bad.size:
            raise WarpStokesError(f"handle {int(bad[0])} is not one of the cage's {n} handles (0 to {n - 1})")
        if len(np.unique(ids)) != len(ids):
            raise WarpStokesError("handles: each handle once")
        return ids.astype(np.int64)

    def pin(self, handles) -> tuple:
        """Hold ``handles`` where they are when other handles move (added to the pinned ones)."""
        ids = self.handles(handles)
        self._record()
        self._pinned = tuple(sorted(set(self._pinned) | set(int(i) for i in ids)))
        return self._pinned

    def unpin(self, handles=None) -> tuple:
        """Let ``handles`` (default: all) follow again."""
        ids = None if handles is None else self.handles(handles)
        self._record()
        self._pinned = () if ids is None else tuple(h for h in self._pinned if h not in set(int(i) for i in ids))
        return self._pinned

    def targets(self, handles, offset=(0.0, 0.0, 0.0), rotation=None, about=None) -> np.ndarray:
        """Where a move takes ``handles``: turned by ``rotation`` about ``about`` (default: their centroid in the
        current pose), then moved by ``offset``."""
        ids = self.handles(handles)
        offset = np.asarray(offset, dtype=np.float64)
        if offset.shape != (3,) or not np.all(np.isfinite(offset)):
            raise WarpStokesError(f"offset: give 3 finite numbers, got {np.asarray(offset).tolist()!r}"[:200])
        now = self._cage[ids]
        if rotation is None:
            return now + offset
        turn = rotation_matrix(rotation)
        centre = now.mean(axis=0) if about is None else np.asarray(about, dtype=np.float64)
        if centre.shape != (3,) or not np.all(np.isfinite(centre)):
            raise WarpStokesError("about: give 3 finite numbers")
        return (now - centre) @ turn.T + centre + offset

    def move(self, handles, offset=(0.0, 0.0, 0.0), rotation=None, scheme: str | None = None,
             about=None) -> np.ndarray:
        """Move (and turn) ``handles``; the pinned handles stay; the others follow by ``scheme``.

        Parameters
        ----------
        handles : int or sequence of int, the handles moved
        offset : (3,) translation, in the cage's units
        rotation : optional, a 3 x 3 rotation matrix or a rotation vector (radians), about ``about``
        scheme : "none" | "laplacian" | "arap" (default: the editor's)
        about : optional (3,) centre of the rotation (default: the moved handles' centroid)

        Returns
        -------
        (L, 3) float64, the new cage pose (also :attr:`cage`)
        """
        ids = self.handles(handles)
        if ids.size == 0:
            raise WarpStokesError("move: select at least one handle")
        return self.place(ids, self.targets(ids, offset, rotation, about), scheme)

    def place(self, handles, positions, scheme: str | None = None, record: bool = True,
              iterations: int | None = None) -> np.ndarray:
        """Put ``handles`` at ``positions`` ((k, 3)); the pinned handles stay; the others follow by ``scheme``.
        ``record=False`` leaves the history alone (a drag: :meth:`checkpoint` once where it starts); ``iterations``
        caps ARAP's iterations from the current pose (a drag's step; default: until it converges)."""
        ids = self.handles(handles)
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        if len(positions) != len(ids) or not np.all(np.isfinite(positions)):
            raise WarpStokesError(f"place: {len(ids)} handles need {len(ids)} finite positions")
        scheme = _scheme(self.scheme if scheme is None else scheme)
        held = np.array([h for h in self._pinned if h not in set(ids.tolist())], dtype=np.int64)
        constrained = np.concatenate([ids, held])
        targets = np.concatenate([positions, self._cage[held]])
        more = {} if iterations is None else {"iterations": int(iterations)}
        cage = self.follow.solve(constrained, targets, scheme, start=self._cage, **more)
        if record:
            self._record()
        self._cage = cage
        return self.cage

    def set_cage(self, cage) -> np.ndarray:
        """Make ``cage`` ((L, 3)) the current pose (undoable)."""
        cage = np.asarray(cage, dtype=np.float64)
        if cage.shape != self.rest.shape or not np.all(np.isfinite(cage)):
            raise WarpStokesError(f"a cage pose of this binding has shape {self.rest.shape} and finite coordinates")
        self._record()
        self._cage = cage.copy()
        return self.cage

    # -- the timeline --------------------------------------------------------------------------------------------

    def key(self, frame: float | None = None) -> float:
        """Key the current cage at ``frame`` (default: the current frame); returns the frame."""
        frame = self.frame if frame is None else _frame(frame)
        self._record()
        self._keys[frame] = self._cage.copy()
        self.frame = frame
        return frame

    def unkey(self, frame: float | None = None) -> bool:
        """Remove the key at ``frame`` (default: the current frame); False when there is none."""
        frame = self.frame if frame is None else _frame(frame)
        if frame not in self._keys:
            return False
        self._record()
        del self._keys[frame]
        return True

    def pose_at(self, frame: float) -> np.ndarray:
        """The timeline's cage at ``frame``: the keys in-betweened (held before the first and after the last); the
        current cage when nothing is keyed."""
        frame = _frame(frame)
        if not self._keys:
            return self.cage
        frames = np.array(sorted(self._keys))
        if len(frames) == 1 or frame <= frames[0]:
            return self._keys[float(frames[0])].copy()
        if frame >= frames[-1]:
            return self._keys[float(frames[-1])].copy()
        if frame in self._keys:
            return self._keys[frame].copy()
        keys = Poses(np.stack([self._keys[float(f)] for f in frames]), frames, "keys")
        return _between(keys, frame, self.interpolation)  # the segment's formula alone, as inbetween evaluates it

    def seek(self, frame: float) -> np.ndarray:
        """Go to ``frame``: the cage becomes the timeline's pose there. Where that replaces a pose not keyed, the
        seek is a step of the history (undo brings the pose back)."""
        frame = _frame(frame)
        pose = self.pose_at(frame)
        if self.pending_pose():
            self._record()
        self._cage = pose
        self.frame = frame
        return self.cage

    def pending_pose(self) -> bool:
        """Whether the current cage differs from what the keys give at the current frame: an edit not keyed yet
        (never, with no key: the current cage is then what is saved)."""
        return bool(self._keys) and not np.array_equal(self._cage, self.pose_at(self.frame))

    def timeline(self) -> Poses:
        """The poses to write: every integer frame from the first key to the last, in-betweened (the keys exactly);
        one key, or none, gives one pose (the key's, or the current cage at the current frame)."""
        if len(self._keys) >= 2:
            frames = np.array(sorted(self._keys))
            keys = Poses(np.stack([self._keys[float(f)] for f in frames]), frames, "the editor's keys")
            return inbetween(keys, interpolation=self.interpolation)
        if self._keys:
            (frame, cage), = self._keys.items()
            return Poses(cage[None].copy(), np.array([frame]), "the editor's key")
        return Poses(self._cage[None].copy(), np.array([self.frame]), "the editor's pose")

    def save(self, path, **options) -> Poses:
        """Write :meth:`timeline` to ``path``: ``.npy`` (poses, F x L x 3, which ``animate`` numbers 1, 2, ...), ``.npz`` (``poses`` and ``frames``, read
        back by ``animate``), USD (``.usd``/``.usda``/``.usdc``: the deformed mesh as ``animate`` writes it) or a glTF
        skin (``.glb``/``.gltf``); atomically, never over the binding or a file it was bound from.

        Parameters
        ----------
        path : str or os.PathLike
        **options : passed to :func:`~warp_stokes.io.write_animation` (USD) or
            :func:`~warp_stokes.binding.write_skin` (a skin: ``.glb``, ``.gltf``, or USD with ``skeleton=True``)

        Returns
        -------
        Poses, what was written
        """
        from ..io.inputs import inputs_of
        from ..io.outputs import atomic_output, writing

        path = os.fspath(path)
        if self.pending_pose():  # saving the keys alone would drop the edit on the screen
            raise WarpStokesError(f"{path}: the pose at frame {self.frame:g} is not keyed: key it (or undo the edit) "
                                  "before saving")
        poses = self.timeline()
        ext = os.path.splitext(path)[1].lower()
        sources = [p for p in (self.binding_path, self.poses_path) if p]
        inputs = inputs_of(*sources, *self.binding.sources, error=WarpStokesError)
        with writing([path], inputs):
            if ext in (".npy", ".npz"):
                if options:
                    raise WarpStokesError(f"{path}: poses take no options ({', '.join(options)})")
                with atomic_output(path, ext) as tmp, open(tmp, "wb") as fh:
                    if ext == ".npy":
                        np.save(fh, poses.positions)
                    else:
                        np.savez(fh, poses=poses.positions, frames=poses.frames)
            elif ext in (".glb", ".gltf") or (options.pop("skeleton", False) and ext in _USD):
                from ..binding import write_skin

                write_skin(path, self.binding, poses, **options)
            elif ext in _USD:
                from ..io import write_animation

                write_animation(path, self.binding, poses, **options)
            else:
                raise WarpStokesError(f"{path}: save poses as .npy or .npz, the mesh as USD (.usd, .usda, .usdc) or "
                                      "a glTF skin (.glb, .gltf)")
        self._changes = 0
        return poses

    def _poses(self, poses) -> Poses:
        if isinstance(poses, Poses):
            return poses
        if isinstance(poses, np.ndarray):
            array = np.asarray(poses, dtype=np.float64)
            if array.ndim == 2:
                array = array[None]
            if array.shape[1:] != self.rest.shape or not np.all(np.isfinite(array)):
                raise WarpStokesError(f"poses of shape {poses.shape}: the cage needs (F, {len(self.rest)}, 3), finite")
            return Poses(array, np.arange(1, len(array) + 1, dtype=np.float64), "poses")  # as a .npy file's
        return load_poses(os.fspath(poses), self.binding.cage_faces, self.binding.n_handles,
                          self.binding.cage_source_index)


_USD = (".usd", ".usda", ".usdc")


def _scheme(scheme) -> str:
    if scheme not in SCHEMES:
        raise WarpStokesError(f"scheme must be one of {', '.join(SCHEMES)}, got {scheme!r}")
    return scheme


def _frame(frame) -> float:
    try:
        value = float(frame)
    except (TypeError, ValueError):
        raise WarpStokesError(f"a frame is a number, got {frame!r}") from None
    if not np.isfinite(value):
        raise WarpStokesError(f"a frame is a finite number, got {frame!r}")
    return value


def _between(keys: Poses, frame: float, interpolation: str) -> np.ndarray:
    """The in-betweened pose at a frame between two keys: the formula :func:`inbetween` evaluates, on that segment
    alone (a seek costs the same however many frames the keys span)."""
    frames = keys.frames
    at = int(np.searchsorted(frames, frame))
    a, b = frames[at - 1], frames[at]
    if interpolation == "linear":
        t = (frame - a) / (b - a)
        return (1.0 - t) * keys.positions[at - 1] + t * keys.positions[at]
    # the spline through all keys, evaluated at the frame: in-between with a step count that lands on it is not
    # general, so evaluate the same natural spline directly
    from ..binding.inbetween import _natural_second_derivatives

    m = _natural_second_derivatives(frames, keys.positions)
    h = b - a
    t = (frame - a) / h
    s = 1.0 - t
    return (s * keys.positions[at - 1] + t * keys.positions[at]
            + ((s**3 - s) * m[at - 1] + (t**3 - t) * m[at]) * h**2 / 6.0)
