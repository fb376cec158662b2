"""A mesh bound to a cage: :func:`bind` (load -> grid -> solve -> sample), the :class:`Binding` it returns (weights
that deform the mesh, saved as ``.npz``), the sampling and deformation kernels' launch code, and
:func:`inbetween` (frames between key cage poses), and :func:`write_skin` (the binding as a UsdSkel or glTF skin)."""

from .deform import deform_vertices
from .inbetween import inbetween
from .pipeline import bind
from .stats import identity_errors
from .sample import sample_weights
from .skin import SkinError, SkinReport, SkinWeights, skin_error, skin_weights, write_skin
from .store import FORMAT, Binding, load_binding

__all__ = ["bind", "identity_errors", "Binding", "load_binding", "FORMAT", "sample_weights", "deform_vertices",
           "inbetween", "write_skin", "skin_weights", "skin_error", "SkinWeights", "SkinError", "SkinReport"]
