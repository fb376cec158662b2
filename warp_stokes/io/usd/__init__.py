"""USD in and out: a file's layer stack checked (:mod:`.layers`), assets' mesh and cage prims (:mod:`.asset`), and
animated USD written as a layer over the asset (:mod:`.layer`) or as a standalone stage (:mod:`.standalone`), by
:func:`write_animation` (:mod:`.write`).

pxr (usd-core) is imported by the functions that use it, and the writers when first named (PEP 562): reading a
layer stack does not load them, and loading the package stays fast.
"""

import importlib

_HOME = {"FRAMES_PER_CHUNK": ".common", "write_cage_poses": ".standalone", "write_animation": ".write"}

__all__ = ["write_animation", "write_cage_poses", "FRAMES_PER_CHUNK"]


def __getattr__(name: str):
    if name in _HOME:
        value = getattr(importlib.import_module(_HOME[name], __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
