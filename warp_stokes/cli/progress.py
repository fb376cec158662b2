"""A bind's progress as one line on a terminal: the stage, the solver's iteration and residual, and the time."""

from __future__ import annotations

import shutil
import sys
import time

__all__ = ["ProgressLine"]

#: the solver's iterations redraw the line at most this often (seconds)
REDRAW = 0.1


class ProgressLine:
    """``progress(stage, **info)`` for :func:`warp_stokes.bind`, drawn as one line on ``stream`` (stderr) that is
    rewritten in place and cleared at the end; nothing at all when ``stream`` is not a terminal (a log, a pipe) or
    ``enabled`` is False.

    Examples
    --------
    >>> import io
    >>> out = io.StringIO()
    >>> with ProgressLine("arm.obj", out, enabled=True) as progress:
    ...     progress("solving", iteration=3, residual=2.5e-4)
    >>> "arm.obj: solving, iteration 3, residual 2.5e-04" in out.getvalue()
    True
    """

    def __init__(self, label: str, stream=None, enabled: bool | None = None):
        self.label = label
        self.stream = sys.stderr if stream is None else stream
        isatty = getattr(self.stream, "isatty", None)
        self.enabled = bool(isatty and isatty()) if enabled is None else enabled
        self.start = time.perf_counter()
        self.drawn = 0.0
        self.width = 0
        self.seen = set()  # (stage, chunk) drawn once at least

    def __call__(self, stage: str, **info) -> None:
        if not self.enabled:
            return
        now = time.perf_counter()
        # a solve's iterations at most every REDRAW seconds, but each stage of each chunk at least once
        key = (stage, info.get("chunk"))
        if "iteration" in info and now - self.drawn < REDRAW and key in self.seen:
            return
        self.seen.add(key)
        self.drawn = now
        text = f"{self.label}: {stage}"
        if "resolution" in info:
            text += f" at resolution {info['resolution']}"
        if "devices" in info:
            text += f" over {info['devices']} devices"
        if "threads" in info:
            text += f" on {info['threads']} threads"
        if "chunk" in info:
            text += f" (chunk {info['chunk']} of {info['chunks']})"
        if "iteration" in info:
            text += f", iteration {info['iteration']}, residual {info['residual']:.1e}"
        text += f"  {now - self.start:.1f} s"
        # a line wider than the terminal wraps, and a carriage return no longer reaches its start
        text = text[: max(20, shutil.get_terminal_size().columns - 1)]
        self.stream.write("\r" + text.ljust(self.width))
        self.stream.flush()
        self.width = len(text)

    def close(self) -> None:
        """Clear the line, so that what is printed next starts on a clean one."""
        if self.enabled and self.width:
            self.stream.write("\r" + " " * self.width + "\r")
            self.stream.flush()
            self.width = 0

    def __enter__(self) -> "ProgressLine":
        return self

    def __exit__(self, *exc) -> bool:
        self.close()
        return False
