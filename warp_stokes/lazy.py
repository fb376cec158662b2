"""Names of a package imported when first used (PEP 562), so that importing the package stays light: the command
line's start-up, its signal handling and a USD layer stack's check need none of the writers, numpy or pxr."""

import importlib

__all__ = ["lazy_names"]


def lazy_names(package: str, homes: dict):
    """A module ``__getattr__`` for ``package`` that imports each name of ``homes`` (name -> relative module) when it
    is first asked for, and keeps it.

    Examples
    --------
    >>> getattr_ = lazy_names("warp_stokes", {"WarpStokesError": ".errors"})
    >>> getattr_("WarpStokesError").__name__
    'WarpStokesError'
    """
    import sys

    def __getattr__(name: str):
        if name in homes:
            value = getattr(importlib.import_module(homes[name], package), name)
            setattr(sys.modules[package], name, value)  # once: later lookups do not come here
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
