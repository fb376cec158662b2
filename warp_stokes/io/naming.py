"""Names as people number them: ``frame_2`` before ``frame_10`` (frames in a folder, a glTF scene's nodes)."""

import re

__all__ = ["natural_key"]


def natural_key(name: str):
    """Sort key that orders embedded numbers by value: ``frame_2`` before ``frame_10``.

    Examples
    --------
    >>> sorted(["frame_10.obj", "frame_2.obj", "Frame_1.obj"], key=natural_key)
    ['Frame_1.obj', 'frame_2.obj', 'frame_10.obj']
    """
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]
