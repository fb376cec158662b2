"""Deformation quality of a binding: what a deformed mesh looks like, not only whether the weights are exact.

Modules: :mod:`.measures` (per triangle, edge and weight), :mod:`.coupling` (weight from distant handles),
:mod:`.compare` (two bindings), :mod:`.report` (all of them by region, and mean value coordinates beside).

Partition of unity and linear precision say nothing about folds, stretched fingers or a hand that follows the
thigh. These measures judge the deformation a set of weights gives for a cage pose, beside a reference method (mean
value coordinates evaluated at the vertices, :func:`mean_value_quality`) on the same pair:

- **conformal distortion** per triangle of the map rest mesh -> deformed mesh: sigma1 / sigma2, the ratio of the
  singular values of the triangle's 2D deformation gradient (1 for a similarity, >= 1 always; the angles a
  texture keeps);
- **dihedral-angle change** per interior edge against a reference mesh in the deformed pose, where there is one:
  |dihedral(deformed) - dihedral(reference)| in degrees, of the unsigned angles between the faces' normals (issue
  19's figures) and of the signed ones (a bend from convex to concave counts whole);
- **negative weights**: the fraction of the (vertex, handle) weights below -1e-5 (:data:`NEGATIVE_TOLERANCE`: the
  float32 noise around zero of far handles does not count), and the smallest weight;
- **distant-handle weight** per vertex: the sum of |w_l| over the handles farther along the cage's edges from the
  vertex's nearest cage face than a quarter (:data:`DISTANT_FRACTION`) of the cage's graph diameter. Weight there is
  coupling across a narrow gap between parts that are close in space but far apart along the cage (a hand hanging
  beside a thigh);
- **weight difference** against another binding of the same mesh and cage (per vertex, the largest and the RMS
  change over handles), e.g. a finer resolution.

:func:`deformation_quality` computes all of them by region (vertex subsets: a region's triangles and edges are those
with every vertex in it). Weights are read in chunks of rows and all sums are float64, so meshes of 500k vertices
need no (V, L) float64 copy. Regions specific to a data set (a body's hands, say) belong to the caller, e.g.
``benchmarks/bench_quality.py``.
"""

from .compare import vertex_weight_difference, weight_difference
from .coupling import DISTANT_FRACTION, distant_handle_weight, distant_handles, nearest_faces
from .measures import (NEGATIVE_TOLERANCE, conformal_distortion, dihedral_angles, dihedral_change,
                       negative_weight_fraction, percentile_summary, region_edges, region_triangles)
from .report import deformation_quality, mean_value_quality

__all__ = ["conformal_distortion", "dihedral_angles", "dihedral_change", "percentile_summary", "region_triangles",
           "region_edges", "negative_weight_fraction", "nearest_faces", "distant_handles", "distant_handle_weight",
           "vertex_weight_difference", "weight_difference", "deformation_quality", "mean_value_quality",
           "DISTANT_FRACTION", "NEGATIVE_TOLERANCE"]
