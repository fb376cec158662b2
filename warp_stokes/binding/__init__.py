"""A mesh bound to a cage: :func:`bind` (load -> grid -> solve -> sample), the :class:`Binding` it returns (weights
that deform the mesh, saved as ``.npz``), the sampling and deformation kernels' launch code, and
:func:`inbetween` (frames between key cage poses), and :func:`write_skin` (the binding as a UsdSkel or glTF skin).

The names below are imported when first used (PEP 562): a command that loads a binding and deforms it on a CPU
imports neither the bind's stages nor the skin writers."""

from ..lazy import lazy_names
# the function, not its module of the same name (which importing it would leave here): imported now, it is light
from .inbetween import inbetween

_HOME = {"bind": ".pipeline", "identity_errors": ".stats", "Binding": ".store", "load_binding": ".store",
         "FORMAT": ".store", "sample_weights": ".sample", "deform_vertices": ".deform",
         "write_skin": ".skin", "skin_weights": ".skin", "skin_error": ".skin", "SkinWeights": ".skin",
         "SkinError": ".skin", "SkinReport": ".skin"}

__all__ = [*_HOME, "inbetween"]

__getattr__ = lazy_names(__name__, _HOME)
