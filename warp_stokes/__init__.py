"""warp-stokes: Stokes cage coordinates on a voxel grid, solved for all handles at once with NVIDIA Warp.

>>> import warp_stokes as ws
>>> b = ws.bind("arm.obj", "arm_cage.obj", resolution=64)   # doctest: +SKIP
>>> deformed = b.deform(new_cage_vertices)                    # doctest: +SKIP
"""

import os as _os

# Installed, the kernels are the subpackage warp_stokes.kernels. In a source checkout they sit in the top-level
# kernels/ folder beside this package: let `python -m pytest` or scripts run from the checkout find them there.
_here = _os.path.dirname(_os.path.abspath(__file__))
if not _os.path.isdir(_os.path.join(_here, "kernels")) and _os.path.isfile(
    _os.path.join(_here, _os.pardir, "kernels", "__init__.py")
):
    __path__.append(_os.path.dirname(_here))  # noqa: F821 (the package's own __path__)

__version__ = "0.2.0"

# The public names, imported on first use (PEP 562): `warp-stokes --help` and `--version` start without importing
# Warp, numpy or trimesh; `import warp_stokes as ws; ws.bind(...)` works as if they were imported here.
_PUBLIC = {
    ".errors": ["WarpStokesError", "MeshError", "CageError", "BindingError", "ResolutionError", "ConvergenceError"],
    ".device": ["Backend", "resolve_device", "device_name"],
    ".io": ["Surface", "load_surface", "Poses", "load_poses", "load_frames", "write_animation"],
    ".geometry": ["Cage", "check_cage", "signed_volume", "Grid", "voxelize", "wedge_resolution", "grid_from_mask",
                  "classify_points", "LocalData", "MeanValueData", "COMPLEMENT_COLUMNS", "mean_value_coordinates",
                  "boundary_field", "make_cage", "MadeCage"],
    ".solver": ["Multigrid", "coarsen", "MemoryEstimate", "estimate_memory", "available_memory", "plan_chunks",
                "SolveReport", "solve_biharmonic", "apply_operator", "Jacobi", "Preconditioner"],
    ".binding": ["Binding", "bind", "load_binding", "sample_weights", "deform_vertices", "inbetween", "write_skin",
                 "skin_weights", "skin_error", "SkinWeights", "SkinError", "SkinReport"],
    ".quality": ["deformation_quality", "mean_value_quality"],
    ".batch": ["read_manifest", "run_batch"],
    ".edit": ["CageEditor"],
}
_HOME = {name: module for module, names in _PUBLIC.items() for name in names}
_SUBPACKAGES = {"errors", "device", "threads", "memory", "kernel_cache", "cluster", "io", "geometry", "solver",
                "binding", "quality", "batch", "edit", "cli", "kernels"}

__all__ = [
    "bind", "load_binding", "Binding",
    "load_surface", "Surface", "check_cage", "Cage", "signed_volume", "make_cage", "MadeCage",
    "voxelize", "wedge_resolution", "grid_from_mask", "Grid", "classify_points",
    "mean_value_coordinates", "boundary_field", "COMPLEMENT_COLUMNS", "LocalData", "MeanValueData",
    "solve_biharmonic", "apply_operator", "SolveReport", "Multigrid", "Jacobi", "Preconditioner", "coarsen",
    "sample_weights", "deform_vertices", "deformation_quality", "mean_value_quality",
    "MemoryEstimate", "estimate_memory", "available_memory", "plan_chunks",
    "Backend", "resolve_device", "device_name",
    "Poses", "load_poses", "load_frames", "write_animation", "inbetween", "read_manifest", "run_batch", "CageEditor",
    "write_skin", "skin_weights", "skin_error", "SkinWeights", "SkinError", "SkinReport",
    "WarpStokesError", "MeshError", "CageError", "BindingError", "ResolutionError", "ConvergenceError",
]


def __getattr__(name: str):
    import importlib

    if name in _HOME:
        value = getattr(importlib.import_module(_HOME[name], __name__), name)
        globals()[name] = value  # once: later lookups do not come here
        return value
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_HOME) | _SUBPACKAGES)
