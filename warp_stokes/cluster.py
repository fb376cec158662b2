"""Ray, the optional engine that spreads batches and binds over processes, GPUs and hosts."""

from __future__ import annotations

from .errors import WarpStokesError

__all__ = ["require_ray", "start_ray", "RayInBackground"]


def require_ray(what: str = "--workers and --ray-address need"):
    """The ``ray`` module, or a WarpStokesError saying how to install it (``what`` names what needs it)."""
    try:
        import ray
    except ImportError:
        raise WarpStokesError(f'{what} Ray, an optional extra: pip install "warp-stokes[ray]"') from None
    return ray


def start_ray(ray, **options) -> None:
    """``ray.init(**options)``, a failure to start or join the cluster (a raylet that does not start, an address with
    no cluster) one WarpStokesError saying so."""
    try:
        ray.init(**options)
    except Exception as exc:  # Ray raises ConnectionError, RuntimeError and plain Exceptions
        where = f"join the Ray cluster at {options['address']}" if options.get("address") else "start Ray"
        text = " ".join(str(exc).split())[:200] or type(exc).__name__
        raise WarpStokesError(f"could not {where} ({text})") from None


class RayInBackground:
    """A local Ray cluster started on a thread of its own, so that the caller works meanwhile (a batch binds its
    first assets while Ray starts, which takes seconds). The thread stays until :meth:`stop`: Ray ties the processes
    it starts to the thread that started them, and shuts them down there.

    Examples
    --------
    >>> cluster = RayInBackground(ray, num_cpus=2)   # doctest: +SKIP
    >>> while not cluster.ready: ...                 # doctest: +SKIP
    >>> cluster.wait(); ...; cluster.stop()          # doctest: +SKIP
    """

    def __init__(self, ray, **options):
        import threading

        self._started, self._done = threading.Event(), threading.Event()
        self.error: WarpStokesError | None = None
        self._thread = threading.Thread(target=self._run, args=(ray, options), name="ray-start", daemon=True)
        self._thread.start()

    def _run(self, ray, options) -> None:
        try:
            start_ray(ray, **options)
        except WarpStokesError as exc:
            self.error = exc
            self._started.set()
            return
        self._started.set()
        self._done.wait()
        try:
            ray.shutdown()
        except Exception:  # nothing to report on a thread that ends here: the batch's results are written
            pass

    @property
    def ready(self) -> bool:
        """Whether the start has ended (started, or failed: :meth:`wait` says which)."""
        return self._started.is_set()

    def wait(self) -> None:
        """Until the cluster is up; its failure to start raised here (one WarpStokesError)."""
        self._started.wait()
        if self.error is not None:
            raise self.error

    def stop(self) -> None:
        """Shut the cluster down and end the thread; while Ray is still starting (a batch stopped by Ctrl-C, or done
        before the cluster was up) this returns at once: the thread shuts the cluster down as soon as it is up, and
        Ray's processes end with this process in any case."""
        self._done.set()
        if self._started.is_set():
            self._thread.join()
