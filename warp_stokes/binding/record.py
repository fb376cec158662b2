"""What a binding file records beside its arrays, checked whole on load: every field of its settings, stats, parts
and asset by type and range, so that a file edited by hand or written by another tool is one error naming the file
and the field, never a traceback in a later command or a value that command takes on trust."""

from __future__ import annotations

import math
import numbers

from ..arguments import shown
from ..errors import BindingError

__all__ = ["check_metadata"]


class _Field:
    """A check of one value: ``test(value) -> bool`` and what it expects, in words."""

    def __init__(self, test, expected: str):
        self.test, self.expected = test, expected

    def __call__(self, value, where: str, path: str) -> None:
        if not self.test(value):
            raise BindingError(f"{path}: the binding's {where} must be {self.expected}, got {_short(value)}")


def _short(value) -> str:
    text = shown(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_real(v) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def real(low=None, low_open: bool = False) -> _Field:
    bound = "" if low is None else f" {'>' if low_open else '>='} {low:g}"
    return _Field(lambda v: _is_real(v) and (low is None or (v > low if low_open else v >= low)),
                  f"a finite number{bound}")


def integer(low=None, high=None) -> _Field:
    bound = (f" >= {low}" if low is not None else "") + (f" <= {high}" if high is not None else "")
    return _Field(lambda v: _is_int(v) and (low is None or v >= low) and (high is None or v <= high),
                  f"an integer{bound}")


TEXT = _Field(lambda v: isinstance(v, str), "text")
FLAG = _Field(lambda v: isinstance(v, bool), "true or false")
HEX = _Field(lambda v: isinstance(v, str) and len(v) == 64 and all(c in "0123456789abcdef" for c in v),
             "a SHA-256 digest in hex")


def one_of(*choices) -> _Field:
    return _Field(lambda v: v in choices and isinstance(v, str), "one of " + ", ".join(repr(c) for c in choices))


def optional(field: _Field) -> _Field:
    return _Field(lambda v: v is None or field.test(v), f"{field.expected} or null")


def list_of(field: _Field, length: int | None = None) -> _Field:
    return _Field(lambda v: isinstance(v, list) and (length is None or len(v) == length)
                  and all(field.test(x) for x in v),
                  f"a list of {'' if length is None else f'{length} '}items each {field.expected}")


def table(field: _Field) -> _Field:
    return _Field(lambda v: isinstance(v, dict) and all(isinstance(k, str) and field.test(x) for k, x in v.items()),
                  f"a record of named items each {field.expected}")


RECORD = _Field(lambda v: isinstance(v, dict), "a record")
LIST = _Field(lambda v: isinstance(v, list), "a list")
MATRIX = list_of(list_of(real(), 4), 4)

#: the settings every binding of format 1 carries and the commands read; (field, required)
SETTINGS = {
    "method": (one_of("stokes", "harmonic", "mvc"), True),
    "resolution": (optional(integer(1, 1 << 16)), True),
    "tol": (optional(real(0, low_open=True)), False),
    "max_iterations": (optional(integer(1)), False),
    "solver": (optional(one_of("multigrid", "jacobi")), False),
    "boundary": (optional(TEXT), False),
    "sampling": (optional(one_of("hermite", "trilinear")), False),
    "boundary_settings": (optional(RECORD), False),
    "mesh": (TEXT, True),
    "cage": (TEXT, True),
    "cage_prim": (optional(TEXT), False),
    "mesh_prims": (optional(list_of(TEXT)), False),
    "rest_time": (optional(real()), False),
    "cage_flipped": (FLAG, False),
    "cage_handles": (TEXT, False),
    "warp_version": (TEXT, False),
    "warp_stokes_version": (TEXT, False),
}
#: the local boundary data's parameters (``LocalData``), which ``show`` rebuilds a solve from
BOUNDARY_SETTINGS = {"model": (TEXT, True), "radius": (real(0), True), "falloff": (real(0), True),
                     "least_norm_share": (real(0), False), "fold_radius": (real(0), False),
                     "fold_degrees": (real(0), False)}
STATS = {
    "device": (TEXT, True),
    "method": (one_of("stokes", "harmonic", "mvc"), False),
    "handles": (integer(1), True),
    "vertices": (integer(0), True),
    "converged": (FLAG, True),
    "grid_shape": (optional(list_of(integer(1), 3)), False),
    "spacing": (real(0, low_open=True), False),
    "iterations": (integer(0), False),
    "residual": (real(0), False),
    "identity_error": (real(0), False),
    "partition_of_unity_error": (real(0), False),
    "linear_precision_error": (real(0), False),
    "memory_estimate_bytes": (integer(0), False),
    "chunks": (integer(0), False),
    "threads": (integer(1), False),
    "seconds": (table(real(0)), False),
    "warnings": (list_of(TEXT), False),
    "resolution": (RECORD, False),
    "made_cage": (RECORD, False),
}
#: the typed report of format 2 (:class:`warp_stokes.binding.stats.BindStats`): every field, nested records whole
STATS_2 = {
    "format": (integer(2, 2), True),
    "device": (TEXT, True),
    "method": (one_of("stokes", "harmonic", "mvc"), True),
    "handles": (integer(1), True),
    "vertices": (integer(0), True),
    "vertices_outside_cage": (integer(0), True),
    "vertices_beyond_band": (integer(0), True),
    "vertices_in_thin_features": (integer(0), True),
    "grid": (optional(RECORD), True),
    "resolution": (optional(RECORD), True),
    "solver": (optional(RECORD), True),
    "memory_estimate_bytes": (integer(0), True),
    "partition_of_unity_error": (real(0), True),
    "linear_precision_error": (real(0), True),
    "seconds": (table(real(0)), True),
    "warnings": (list_of(TEXT), True),
    "made_cage": (optional(RECORD), True),
}
GRID = {"shape": (list_of(integer(1), 3), True), "spacing": (real(0, low_open=True), True),
        "interior_nodes": (integer(0), True), "ring_nodes": (integer(0), True), "cut_off_nodes": (integer(0), True),
        "band_nodes": (integer(0), True)}
RESOLUTION = {"requested": (_Field(lambda v: v == "auto" or _is_int(v), "'auto' or an integer"), True),
              **{key: (optional(integer(1)), True) for key in ("chosen", "needed", "cap", "thin_parts",
                                                                "memory_fits", "memory_budget_bytes")}}
SOLVER = {
    "preconditioner": (one_of("multigrid", "jacobi"), True),
    "levels": (list_of(integer(0)), True),
    "chunks": (integer(1), True),
    "threads": (integer(1), True),
    "iterations": (integer(0), True),
    "restarts": (integer(0), True),
    "rounds": (LIST, True),
    "residual": (real(0), True),
    "identity_error": (real(0), True),
    "converged": (FLAG, True),
    "chunk_iterations": (list_of(integer(0)), True),
    "chunk_rounds": (list_of(LIST), True),
    "preconditioners": (list_of(TEXT), True),
    "recoveries": (list_of(RECORD), True),
    "coarsest_operator": (optional(RECORD), True),
    "multigrid_seconds": (RECORD, True),
    "devices": (optional(list_of(RECORD)), True),
}

PART = {
    "path": (TEXT, True),
    "vertices": (integer(0), True),
    "normals": (optional(one_of("vertex", "faceVarying", "uniform", "varying", "constant")), False),
    "to_world": (MATRIX, False),
}
ASSET = {
    "path": (TEXT, True),
    "up_axis": (one_of("Y", "Z"), False),
    "meters_per_unit": (real(0, low_open=True), False),
    "default_prim": (optional(TEXT), False),
    "time_codes_per_second": (real(0, low_open=True), False),
    "rest_time": (optional(real()), False),
}
TOP = {
    "format": (TEXT, True),
    "version": (TEXT, False),
    "settings": (RECORD, True),
    "stats": (RECORD, True),
    "cage_fingerprint": (HEX, True),
    "mesh_fingerprint": (HEX, True),
    "parts": (optional(list_of(RECORD)), False),
    "asset": (optional(RECORD), False),
    "sources": (optional(list_of(TEXT)), False),
    "batch_inputs": (optional(HEX), False),
    "looks": (optional(RECORD), False),  # (its fields: warp_stokes.io.looks.Looks.from_record)
}


def _record(value: dict, fields: dict, where: str, path: str) -> None:
    for key, (field, required) in fields.items():
        if key not in value:
            if required:
                raise BindingError(f"{path}: the binding's {where}{key} is missing")
            continue
        field(value[key], f"{where}{key}", path)


def check_metadata(meta, path: str, n_vertices: int, n_handles: int) -> None:
    """Every field a binding's metadata holds, checked by type and range, and against the arrays (``n_vertices``,
    ``n_handles``): the settings the weights were made with, the stats, each part and the asset.

    Raises
    ------
    BindingError, naming the file and the field

    Examples
    --------
    >>> check_metadata({"format": "warp-stokes-binding/1", "settings": {}}, "b.npz", 3, 4)
    Traceback (most recent call last):
    ...
    warp_stokes.errors.BindingError: b.npz: the binding's stats is missing
    """
    if not isinstance(meta, dict):
        raise BindingError(f"{path}: the binding's metadata is not a record (a {type(meta).__name__})")
    _record(meta, TOP, "", path)
    settings, stats = meta["settings"], meta["stats"]
    _record(settings, SETTINGS, "settings.", path)
    grid = settings["method"] != "mvc"
    if grid and settings["resolution"] is None:
        raise BindingError(f"{path}: the binding's settings.resolution must be an integer for method "
                           f"{settings['method']!r}, got null")
    if settings.get("boundary_settings") is not None:
        _record(settings["boundary_settings"], BOUNDARY_SETTINGS, "settings.boundary_settings.", path)
        from ..geometry.local_data import LocalData

        unknown = set(settings["boundary_settings"]) - set(LocalData.__dataclass_fields__)
        if unknown:
            raise BindingError(f"{path}: the binding's settings.boundary_settings has unknown fields "
                               f"{sorted(unknown)}")
    _check_stats(stats, path)
    if stats["handles"] != n_handles or stats["vertices"] != n_vertices:
        raise BindingError(f"{path}: the binding's stats count {stats['vertices']} vertices and {stats['handles']} "
                           f"handles; its weights are of {n_vertices} vertices and {n_handles} handles")
    for k, part in enumerate(meta.get("parts") or []):
        _record(part, PART, f"parts[{k}].", path)
    if meta.get("parts") is not None and sum(p["vertices"] for p in meta["parts"]) != n_vertices:
        raise BindingError(f"{path}: the stored parts' vertex counts do not add up to the mesh's")
    if meta.get("asset") is not None:
        _record(meta["asset"], ASSET, "asset.", path)


def _check_stats(stats: dict, path: str) -> None:
    """A binding's stats: the flat record of format 1 (no ``format``), or the typed report of format 2, whole."""
    if "format" not in stats:
        _record(stats, STATS, "stats.", path)
        return
    if stats["format"] != 2:
        raise BindingError(f"{path}: the binding's stats are of format {_short(stats['format'])}; this version of "
                           "warp-stokes reads formats 1 and 2 (bind again, or update warp-stokes)")
    _exactly(stats, STATS_2, "stats.", path)
    for name, fields in (("grid", GRID), ("resolution", RESOLUTION), ("solver", SOLVER)):
        if stats[name] is not None:
            _exactly(stats[name], fields, f"stats.{name}.", path)


def _exactly(value: dict, fields: dict, where: str, path: str) -> None:
    """``value`` holds the fields of ``fields``, each checked, and no other."""
    unknown = set(value) - set(fields)
    if unknown:
        raise BindingError(f"{path}: the binding's {where[:-1]} has unknown fields {sorted(unknown)}")
    _record(value, fields, where, path)
