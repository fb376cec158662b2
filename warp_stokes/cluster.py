"""Ray, the optional engine that spreads batches and binds over processes, GPUs and hosts."""

from __future__ import annotations

from .errors import WarpStokesError

__all__ = ["require_ray", "start_ray"]


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
