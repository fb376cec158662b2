"""The browser editor: a :class:`~warp_stokes.edit.editor.CageEditor` shown and driven through a local viser page.

The page shows the deformed mesh (in its materials' colours where the binding has looks), the cage as wires with a
sphere per handle (a click selects or deselects it), a gizmo at the selection that moves and turns it (the mesh
follows while it is dragged), a picked handle's weights as colours (a diverging scale: red positive, blue
negative, white zero, on the mesh), and a panel: the selection as text, the scheme, pinning, a move by an offset, undo / redo /
reset, the timeline (frame, key, remove key, play) and saving.

viser is an optional extra (``pip install "warp-stokes[edit]"``); its web client ships inside its wheel, so the
page needs nothing from the network. The server listens on 127.0.0.1 unless another host is given.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time

import numpy as np

from ..errors import WarpStokesError
from .editor import SCHEMES, CageEditor

__all__ = ["EditorServer", "require_viser", "weight_colours", "material_colours"]

SELECTED = (255, 170, 0)
PINNED = (200, 40, 40)
FREE = (60, 60, 60)
MESH = (180, 180, 190)
#: ARAP iterations per pointer move while the gizmo is dragged (libigl's default); converged at release
DRAG_ITERATIONS = 10


def require_viser():
    """The viser module, or one line saying how to install it."""
    try:
        import viser
    except ImportError:
        raise WarpStokesError("the editor needs viser: pip install 'warp-stokes[edit]'") from None
    return viser


def weight_colours(weights: np.ndarray) -> np.ndarray:
    """(V, 3) uint8 colours of one handle's weights on a diverging scale symmetric about zero: white at 0, red at
    the largest magnitude when positive, blue when negative (so negative weights show).

    Examples
    --------
    >>> weight_colours(np.array([1.0, 0.0, -0.5])).tolist()
    [[255, 0, 0], [255, 255, 255], [127, 127, 255]]
    """
    w = np.asarray(weights, dtype=np.float64)
    scale = float(np.max(np.abs(w))) if w.size else 0.0
    t = np.clip(w / scale, -1.0, 1.0) if scale > 0 else np.zeros_like(w)
    out = np.full((len(w), 3), 255.0)
    pos, neg = t > 0, t < 0
    out[pos, 1] = out[pos, 2] = 255.0 * (1.0 - t[pos])
    out[neg, 0] = out[neg, 1] = 255.0 * (1.0 + t[neg])
    return np.floor(out + 1e-9).astype(np.uint8)


def material_colours(binding) -> tuple[np.ndarray, list]:
    """Each mesh triangle's material group and each group's RGB (uint8): a material's base colour factor times the
    mean colour of its base colour texture where the image can be read; one grey group without looks."""
    import warnings

    triangles = len(binding.mesh_faces)
    looks, per_polygon = binding.looks, binding.mesh_face_materials
    counts = binding.mesh_face_counts
    if looks is None or per_polygon is None or int(np.sum(counts - 2)) != triangles:
        return np.zeros(triangles, dtype=np.int64), [MESH]
    per_triangle = np.repeat(per_polygon, counts - 2)
    with warnings.catch_warnings():  # an image not found: the material's own colour (saving says so, not this)
        warnings.simplefilter("ignore")
        resolved = looks.resolved(has_uvs=binding.mesh_uvs is not None)
    means = [_mean_colour(data) for _, data in resolved.images]
    colours = []
    for material in resolved.materials:
        pbr = material.get("pbrMetallicRoughness") or {}
        factor = np.asarray((pbr.get("baseColorFactor") or [1.0, 1.0, 1.0])[:3], dtype=np.float64)
        slot = pbr.get("baseColorTexture") or {}
        texture = resolved.textures[slot["index"]] if "index" in slot else {}
        source = texture.get("source")
        mean = means[source] if source is not None and means[source] is not None else np.ones(3)
        colours.append(tuple(int(round(c)) for c in np.clip(255.0 * factor * mean, 0, 255)))
    groups = np.where(per_triangle >= 0, per_triangle, len(colours))
    return groups, colours + [MESH]


def _mean_colour(data: bytes):
    """An image's mean RGB in [0, 1], or None where Pillow cannot decode it."""
    try:
        from PIL import Image

        with Image.open(io.BytesIO(data)) as image:
            image = image.convert("RGB")
            if max(image.size) > 256:  # a box filter keeps the mean; a large texture need not be read whole
                image = image.resize((256, 256), Image.Resampling.BOX)
            pixels = np.asarray(image, dtype=np.float64) / 255.0
    except Exception:  # a format the viewer cannot decode: the material's factor alone
        return None
    return pixels.reshape(-1, 3).mean(axis=0)


class EditorServer:
    """A viser server showing and editing one :class:`CageEditor`.

    Parameters
    ----------
    editor : CageEditor
    host : str, the address to listen on (127.0.0.1: this machine only)
    port : int, the port (the next free one when it is taken)
    output : str, optional, where the panel's Save button writes (a path :meth:`CageEditor.save` takes)

    Attributes
    ----------
    url : str, the page's address
    selection : tuple of int, the selected handles
    picked : int or None, the handle whose weights are shown

    Examples
    --------
    >>> server = EditorServer(CageEditor("arm.npz"), port=8080)    # doctest: +SKIP
    >>> server.select([40]); server.move_selection([0, 0.1, 0])     # doctest: +SKIP
    """

    def __init__(self, editor: CageEditor, host: str = "127.0.0.1", port: int = 8080, output: str | None = None):
        viser = require_viser()
        self.editor = editor
        self.output = output
        self.lock = threading.RLock()
        self.selection: tuple = ()
        self.picked: int | None = None
        self.updates = 0
        with contextlib.redirect_stdout(io.StringIO()):  # viser's banner: the command prints the address itself
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        # the page's share button would relay the session through viser's public server: local means local
        self.server.gui.configure_theme(show_share_button=False)
        self.url = f"http://{f'[{host}]' if ':' in host else host}:{self.server.get_port()}"
        self._dragging = None
        self._playing = False
        self._build_scene()
        self._build_panel()
        self.update()

    # -- scene ---------------------------------------------------------------------------------------------------

    def _build_scene(self) -> None:
        ed, scene = self.editor, self.server.scene
        diagonal = ed.diagonal
        # +y up (a Z-up asset's +z), the camera on the horizontal axis along which the cage is thinner: the
        # character's broad side faces it (a four-legged one is seen from the side, a standing one from the front)
        up = 2 if (ed.binding.asset or {}).get("up_axis") == "Z" else 1
        scene.set_up_direction("+z" if up == 2 else "+y")
        extent = np.ptp(ed.rest, axis=0)
        across = min((a for a in range(3) if a != up), key=lambda a: extent[a])
        centre = 0.5 * (ed.rest.min(axis=0) + ed.rest.max(axis=0))
        camera = self.server.initial_camera
        camera.look_at = centre
        camera.position = centre + 1.2 * diagonal * np.eye(3)[across]
        camera.near, camera.far = 0.01 * diagonal, 100.0 * diagonal
        self.radius = 0.012 * diagonal
        faces = ed.binding.mesh_faces
        groups, colours = material_colours(ed.binding)
        self._parts = []  # (vertex ids, mesh handle)
        mesh = ed.mesh()
        for g, colour in enumerate(colours):
            tri = faces[groups == g]
            if not len(tri):
                continue
            ids, local = np.unique(tri, return_inverse=True)
            handle = scene.add_mesh_simple(f"/mesh/part_{g}", mesh[ids], local.reshape(-1, 3), color=colour,
                                           side="double")
            self._parts.append((ids, handle))
        edges = np.unique(np.sort(np.concatenate([ed.binding.cage_faces[:, [0, 1]], ed.binding.cage_faces[:, [1, 2]],
                                                  ed.binding.cage_faces[:, [2, 0]]]), axis=1), axis=0)
        self._edges = edges
        self._wires = scene.add_line_segments("/cage/wires", ed.cage[edges], (40, 40, 40),
                                              thickness=0.003 * diagonal)
        self._spheres = []
        self._sent_cage, self._sent_colours = ed.cage, [FREE] * len(ed.rest)
        for h, position in enumerate(ed.cage):
            sphere = scene.add_icosphere(f"/cage/handles/{h}", radius=self.radius, color=FREE, position=position)
            sphere.on_click(lambda event, h=h: self._clicked(h))
            self._spheres.append(sphere)
        self._gizmo = scene.add_transform_controls("/gizmo", scale=0.15 * diagonal, visible=False)
        self._gizmo.on_update(self._gizmo_moved)
        self._weights = None  # the mesh coloured by the picked handle's weights, made when shown

    def _build_panel(self) -> None:
        gui = self.server.gui
        self._status = gui.add_markdown("Click a handle to select it.")
        self._selected = gui.add_text("Selected handles", initial_value="")
        self._selected.on_update(lambda _: self._typed_selection())
        self._scheme = gui.add_dropdown("Rest of the cage follows", options=SCHEMES, initial_value=self.editor.scheme)
        self._scheme.on_update(lambda _: setattr(self.editor, "scheme", self._scheme.value))
        pin = gui.add_button("Pin selected")
        pin.on_click(lambda _: self._act(lambda: self.editor.pin(self.selection), "pinned"))
        unpin = gui.add_button("Unpin all")
        unpin.on_click(lambda _: self._act(lambda: self.editor.unpin(), "unpinned"))
        self._offset = gui.add_vector3("Offset", initial_value=(0.0, 0.0, 0.0), step=0.001)
        move = gui.add_button("Move selected by offset")
        move.on_click(lambda _: self._act(lambda: self.move_selection(self._offset.value), "moved"))
        self._show_weights = gui.add_checkbox("Show picked handle's weights", initial_value=False)
        self._show_weights.on_update(lambda _: self._refresh_weights())
        for label, action in (("Undo", self.editor.undo), ("Redo", self.editor.redo), ("Reset", self.editor.reset)):
            button = gui.add_button(label)
            button.on_click(lambda _, action=action, label=label: self._act(action, label.lower()))
        with gui.add_folder("Timeline"):
            self._frame = gui.add_number("Frame", initial_value=float(self.editor.frame), step=1.0)
            self._frame.on_update(lambda _: self._seek(self._frame.value))
            key = gui.add_button("Key current pose")
            key.on_click(lambda _: self._act(lambda: self.editor.key(self._frame.value), "keyed"))
            unkey = gui.add_button("Remove key")
            unkey.on_click(lambda _: self._act(lambda: self.editor.unkey(self._frame.value), "key removed"))
            self._play = gui.add_checkbox("Play", initial_value=False)
            self._play.on_update(lambda _: self._start_playing())
            self._keys = gui.add_markdown(self._keys_text())
        with gui.add_folder("Save"):
            # the output the command was given, not one typed in the page: a page served to other machines must not
            # write where its visitors choose
            gui.add_markdown(f"Saves to `{self.output}`" if self.output else "No output given (-o)")
            save = gui.add_button("Save")
            save.on_click(lambda _: self._act(self._save, "saved"))

    # -- actions -------------------------------------------------------------------------------------------------

    def _act(self, action, said: str) -> None:
        """Run a panel action; its error is said in the status line, not raised into the server's thread, and so
        are its warnings (a skin's error, an image left out)."""
        import warnings

        with self.lock:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    action()
                except (WarpStokesError, OSError) as exc:
                    self._status.content = f"**error:** {exc}"
                    return
            notes = list(dict.fromkeys(str(w.message) for w in caught))
            self._status.content = said + "".join(f"  \n**warning:** {note}" for note in notes)
            self.update()

    def _save(self) -> None:
        if not self.output:
            raise WarpStokesError("no output: start the editor with -o OUT")
        self.editor.save(self.output)

    def select(self, handles, picked: int | None = None) -> tuple:
        """Make ``handles`` the selection (the gizmo goes to their centroid); ``picked``: the handle whose weights
        are shown (default: the last selected)."""
        with self.lock:
            self.selection = tuple(int(h) for h in self.editor.handles(handles))
            if picked is not None or self.selection:
                self.picked = self.selection[-1] if picked is None else int(picked)
            self._selected.value = ", ".join(str(h) for h in self.selection)
            self._status.content = f"selected {self._selected.value}" if self.selection else "nothing selected"
            self.update()
            return self.selection

    def _clicked(self, handle: int) -> None:
        with self.lock:
            chosen = list(self.selection)
            chosen.remove(handle) if handle in chosen else chosen.append(handle)
            self.select(chosen, picked=handle)

    def _typed_selection(self) -> None:
        text = self._selected.value.replace(",", " ").split()
        try:
            wanted = [int(t) for t in text]
            if tuple(wanted) != self.selection:
                self.select(wanted)
        except (ValueError, WarpStokesError) as exc:
            self._status.content = f"**error:** selected handles: {exc}"

    def move_selection(self, offset, rotation=None) -> np.ndarray:
        """Move the selection by ``offset`` (and turn it by ``rotation``) with the editor's scheme; the page follows."""
        with self.lock:
            if not self.selection:
                raise WarpStokesError("select a handle first")
            cage = self.editor.move(self.selection, offset, rotation)
            self.update()
            return cage

    def _gizmo_moved(self, event) -> None:
        """A drag of the gizmo: the selection follows its translation and rotation from where the drag began, one
        undo step per drag."""
        with self.lock:
            if not self.selection:
                return
            phase = getattr(event, "phase", "update")
            if self._dragging is None and phase != "start":
                return  # viser may hand a drag's last updates over after its end: the drag is over
            if phase == "start":
                self._dragging = (self.editor.cage, np.array(self._gizmo.position), np.array(self._gizmo.wxyz))
                self.editor.checkpoint()
            start_cage, start_position, start_wxyz = self._dragging
            turn = _quaternion_matrix(self._gizmo.wxyz) @ _quaternion_matrix(start_wxyz).T
            ids = np.array(self.selection)
            targets = (start_cage[ids] - start_position) @ turn.T + np.array(self._gizmo.position)
            try:
                # while dragging, a few ARAP iterations from the last pose keep up with the pointer; at the end the
                # pose is solved to convergence
                self.editor.place(ids, targets, record=False,
                                  iterations=None if phase == "end" else DRAG_ITERATIONS)
            except WarpStokesError as exc:
                self._status.content = f"**error:** {exc}"
            self.update(gizmo=False)
            if phase == "end":
                self._dragging = None

    def _seek(self, frame) -> None:
        with self.lock:
            try:
                self.editor.seek(frame)
            except WarpStokesError as exc:
                self._status.content = f"**error:** {exc}"
            self.update()

    def _start_playing(self) -> None:
        if not self._play.value or self._playing:
            return
        self._playing = True
        threading.Thread(target=self._play_loop, daemon=True).start()

    def _play_loop(self, fps: float = 24.0) -> None:
        try:
            while self._play.value:
                keys = sorted(self.editor.keys)
                if len(keys) < 2:
                    self._status.content = "play: key at least two frames"
                    self._play.value = False
                    break
                frame = self.editor.frame + 1.0
                if frame > keys[-1] or frame < keys[0]:
                    frame = keys[0]
                self._frame.value = frame  # seeks through its callback
                time.sleep(1.0 / fps)
        finally:
            self._playing = False

    def _refresh_weights(self, mesh: np.ndarray | None = None) -> None:
        """The weights view: the deformed mesh with vertex colours (sent whole, so only while it is shown) in place
        of the plain mesh."""
        import trimesh

        show = bool(self._show_weights.value) and self.picked is not None
        for _, handle in self._parts:
            handle.visible = not show
        if not show:
            if self._weights is not None:
                self._weights.remove()
                self._weights = None
            return
        binding = self.editor.binding
        coloured = trimesh.Trimesh(self.editor.mesh() if mesh is None else mesh, binding.mesh_faces, process=False,
                                   vertex_colors=weight_colours(binding.weights[:, self.picked]))
        self._weights = self.server.scene.add_mesh_trimesh("/weights", coloured)

    def _keys_text(self) -> str:
        keys = sorted(self.editor.keys)
        return "Keys: " + (", ".join(f"{k:g}" for k in keys) if keys else "none")

    # -- the page ------------------------------------------------------------------------------------------------

    def update(self, gizmo: bool = True) -> float:
        """Send the current mesh, cage, selection and keys to the page; returns the seconds it took on this side."""
        start = time.perf_counter()
        with self.lock:
            ed = self.editor
            mesh, cage = ed.mesh(), ed.cage
            with self.server.atomic():
                for ids, handle in self._parts:
                    handle.vertices = mesh[ids]
                self._wires.points = cage[self._edges]
                chosen, pinned = set(self.selection), set(ed.pinned)
                colours = [SELECTED if h in chosen else PINNED if h in pinned else FREE for h in range(len(cage))]
                # only what changed: a move of one handle with no scheme sends one sphere, not all of them
                moved = np.flatnonzero(np.any(cage != self._sent_cage, axis=1))
                for h in moved:
                    self._spheres[h].position = cage[h]
                for h in np.flatnonzero([c != s for c, s in zip(colours, self._sent_colours)]):
                    self._spheres[h].color = colours[h]
                self._sent_cage, self._sent_colours = cage, colours
                if gizmo:
                    self._gizmo.visible = bool(self.selection)
                    if self.selection:
                        self._gizmo.position = cage[list(self.selection)].mean(axis=0)
                        self._gizmo.wxyz = (1.0, 0.0, 0.0, 0.0)
                self._keys.content = self._keys_text()
                if float(self._frame.value) != ed.frame:
                    self._frame.value = ed.frame
                self._refresh_weights(mesh)
            self.server.flush()
            self.updates += 1
        return time.perf_counter() - start

    def stop(self) -> None:
        self._play.value = False
        with contextlib.redirect_stdout(io.StringIO()):  # viser says it stopped; the command says so itself
            self.server.stop()


def _quaternion_matrix(wxyz) -> np.ndarray:
    w, x, y, z = (float(v) for v in wxyz)
    n = w * w + x * x + y * y + z * z
    if n == 0.0:
        return np.eye(3)
    s = 2.0 / n
    return np.array([[1 - s * (y * y + z * z), s * (x * y - z * w), s * (x * z + y * w)],
                     [s * (x * y + z * w), 1 - s * (x * x + z * z), s * (y * z - x * w)],
                     [s * (x * z - y * w), s * (y * z + x * w), 1 - s * (x * x + y * y)]])
