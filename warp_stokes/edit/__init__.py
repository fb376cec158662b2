"""Editing a bound character by its cage: :class:`CageEditor` (handles moved and turned, the rest of the cage
following, the mesh deformed, poses keyed and saved), and the browser editor that drives it
(:class:`~warp_stokes.edit.server.EditorServer`, ``warp-stokes edit``; viser, the ``edit`` extra).

The names below are imported when first used (PEP 562): importing the package loads neither numpy nor viser."""

from ..lazy import lazy_names

_HOME = {"CageEditor": ".editor", "SCHEMES": ".editor", "rotation_matrix": ".editor",
         "EditorServer": ".server", "weight_colours": ".server"}

__all__ = [*_HOME]

__getattr__ = lazy_names(__name__, _HOME)
