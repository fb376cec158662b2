"""USD in and out: a file's layer stack checked (:mod:`.layers`), assets' mesh and cage prims (:mod:`.asset`), and
animated USD written as a layer over the asset (:mod:`.layer`) or as a standalone stage (:mod:`.standalone`), by
:func:`write_animation` (:mod:`.write`).

pxr (usd-core) is imported by the functions that use it, and the writers when first named (PEP 562): reading a
layer stack does not load them, and loading the package stays fast.
"""

from ...lazy import lazy_names

_HOME = {"FRAMES_PER_CHUNK": ".common", "write_cage_poses": ".standalone", "write_animation": ".write"}

__all__ = ["write_animation", "write_cage_poses", "FRAMES_PER_CHUNK"]

__getattr__ = lazy_names(__name__, _HOME)
