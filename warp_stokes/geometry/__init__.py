"""The geometry of a bind: the checked cage, the voxel grid inside it, and the boundary data on its ring and band
(mean value coordinates, local data)."""

from .boundary import COMPLEMENT_COLUMNS, boundary_field, mean_value_coordinates
from .cage import Cage, check_cage, crossing_faces, folded_edges, signed_volume
from .grid import Grid, grid_from_mask, voxelize
from .resolution import wedge_resolution
from .inside import classify_points
from .local_data import LocalData, MeanValueData
from .make_cage import MadeCage, make_cage

__all__ = ["COMPLEMENT_COLUMNS", "boundary_field", "mean_value_coordinates", "Cage", "check_cage", "crossing_faces",
           "folded_edges", "signed_volume", "Grid", "classify_points", "grid_from_mask", "voxelize", "wedge_resolution",
           "LocalData", "MeanValueData", "MadeCage", "make_cage"]
