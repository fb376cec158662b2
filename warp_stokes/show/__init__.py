"""Pictures of a binding, headless (matplotlib's Agg backend) and deterministic: a handle's weight on an axis-aligned
slice through the cage (:mod:`.weights`), and the bound mesh, deformed by a cage pose, coloured per triangle by
conformal distortion or by its distance to a reference mesh (:mod:`.mesh`): the paper's weight slices and
encoding-error maps."""

from .common import AXES, binding_method, cross_section
from .mesh import VIEWS, MeshColours, cage_edges, mesh_colours, show_mesh, view_frame
from .weights import WeightSlice, show_weights, symmetric_scale, weight_slice

__all__ = ["WeightSlice", "MeshColours", "weight_slice", "symmetric_scale", "cross_section", "show_weights",
           "mesh_colours", "cage_edges", "view_frame", "show_mesh", "binding_method", "AXES", "VIEWS"]
