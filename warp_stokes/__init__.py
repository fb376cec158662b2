"""warp-stokes: Stokes cage coordinates on a voxel grid, solved for all handles at once with NVIDIA Warp.

>>> import warp_stokes as ws
>>> b = ws.bind("arm.obj", "arm_cage.obj", resolution=64)   # doctest: +SKIP
>>> deformed = b.deform(new_cage_vertices)                    # doctest: +SKIP
"""

import os as _os

import warp as wp

# Installed, the kernels are the subpackage warp_stokes.kernels. In a source checkout they sit in the top-level
# kernels/ folder beside this package: let `python -m pytest` or scripts run from the checkout find them there.
_here = _os.path.dirname(_os.path.abspath(__file__))
if not _os.path.isdir(_os.path.join(_here, "kernels")) and _os.path.isfile(
    _os.path.join(_here, _os.pardir, "kernels", "__init__.py")
):
    __path__.append(_os.path.dirname(_here))  # noqa: F821 (the package's own __path__)

# Warp prints a banner on initialisation; a library should stay quiet unless asked.
wp.config.log_level = wp.LOG_WARNING

__version__ = "0.1.0"

from .errors import BindingError, CageError, MeshError, ResolutionError, WarpStokesError  # noqa: E402
from .device import resolve_device, device_name  # noqa: E402
from .io import Surface, load_surface, Poses, load_poses, write_animation  # noqa: E402
from .geometry import (  # noqa: E402
    Cage, check_cage, signed_volume, Grid, voxelize, grid_from_mask, classify_points, LocalData, COMPLEMENT_COLUMNS,
    mean_value_coordinates, boundary_field,
)
from .solver import (  # noqa: E402
    Multigrid, coarsen, MemoryEstimate, estimate_memory, available_memory, plan_chunks, SolveReport,
    solve_biharmonic, apply_operator,
)
from .binding import Binding, bind, load_binding, sample_weights, deform_vertices  # noqa: E402
from .quality import deformation_quality, mean_value_quality  # noqa: E402
from .batch import read_manifest, run_batch  # noqa: E402

__all__ = [
    "bind", "load_binding", "Binding",
    "load_surface", "Surface", "check_cage", "Cage", "signed_volume",
    "voxelize", "grid_from_mask", "Grid", "classify_points",
    "mean_value_coordinates", "boundary_field", "COMPLEMENT_COLUMNS", "LocalData",
    "solve_biharmonic", "apply_operator", "SolveReport", "Multigrid", "coarsen",
    "sample_weights", "deform_vertices", "deformation_quality", "mean_value_quality",
    "MemoryEstimate", "estimate_memory", "available_memory", "plan_chunks",
    "resolve_device", "device_name",
    "Poses", "load_poses", "write_animation", "read_manifest", "run_batch",
    "WarpStokesError", "MeshError", "CageError", "BindingError", "ResolutionError",
]
