"""Input and output: every file read through one door (:mod:`.door`) and written through another (:mod:`.outputs`),
the inputs' full set (:mod:`.inputs`), meshes and cages (:mod:`.load`), cage poses (:mod:`.poses`), rigged
animation (:mod:`.skinned`), animated USD (:mod:`.usd`).

Nothing here solves anything: these modules read what users have and write what pipelines take. The names below are
imported when first used (PEP 562): the command line's start-up and its signal handling need none of numpy.
"""

from ..lazy import lazy_names

_HOME = {"atomic_output": ".outputs", "Surface": ".load", "load_surface": ".load", "Poses": ".poses",
         "load_poses": ".poses", "load_frames": ".skinned", "pose_vertices": ".poses", "same_triangles": ".poses",
         "write_animation": ".usd"}

__all__ = ["atomic_output", "Surface", "load_surface", "Poses", "load_poses", "load_frames", "pose_vertices",
           "same_triangles", "write_animation"]

__getattr__ = lazy_names(__name__, _HOME)
