"""Input and output: meshes and cages from files, whole-or-nothing output files, cage poses, animated USD.

Nothing here solves anything: these modules read what users have and write what pipelines take.
"""

from .files import atomic_output
from .load import Surface, load_surface
from .poses import Poses, load_poses, pose_vertices, same_triangles
from .usd import write_animation

__all__ = ["atomic_output", "Surface", "load_surface", "Poses", "load_poses", "pose_vertices", "same_triangles",
           "write_animation"]
