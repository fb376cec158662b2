"""USD in and out: assets' mesh and cage prims (:mod:`.asset`), and animated USD written as a layer over the asset
(:mod:`.layer`) or as a standalone stage (:mod:`.standalone`), by :func:`write_animation` (:mod:`.write`).

pxr (usd-core) is imported by the functions that use it, not here: loading the package stays fast.
"""

from .common import FRAMES_PER_CHUNK
from .standalone import write_cage_poses
from .write import write_animation

__all__ = ["write_animation", "write_cage_poses", "FRAMES_PER_CHUNK"]
