"""The geometry of a bind: the checked cage, the voxel grid inside it, and the boundary data on its ring and band
(mean value coordinates, local data), and how a cage follows a few moved handles (CageFollow).

The names below are imported when first used (PEP 562): a module that needs one small part (a cage's diagonal, its
topology) does not load every kernel of the grid and the boundary data."""

from ..lazy import lazy_names

_HOME = {"COMPLEMENT_COLUMNS": ".boundary", "boundary_field": ".boundary", "mean_value_coordinates": ".boundary",
         "Cage": ".cage", "check_cage": ".cage", "crossing_faces": ".cage", "folded_edges": ".cage",
         "signed_volume": ".cage", "Grid": ".grid", "grid_from_mask": ".grid", "voxelize": ".grid",
         "wedge_resolution": ".resolution", "classify_points": ".inside", "LocalData": ".local_data",
         "MeanValueData": ".local_data", "MadeCage": ".cage_making", "make_cage": ".cage_making",
         "CageFollow": ".cage_follow", "FollowResult": ".cage_follow"}

__all__ = list(_HOME)

__getattr__ = lazy_names(__name__, _HOME)
