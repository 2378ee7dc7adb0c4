"""Field checks of node checkpoints: every value is validated before anything is used.

A checkpoint's vehicle state (:mod:`radical_rt.io.checkpoint`) is untrusted input: a damaged or
forged file must be refused with one clear line, never crash, hang or silently freeze the filter.
The helpers here raise :class:`CheckpointFieldError` naming the field (``engine.d``,
``clock.I[7]``, ...) and why. Bounds are generous physical limits (SI): they only exclude values
no run can produce (NaN, ±inf where the engine needs finite numbers, indices out of range, counts
beyond 2**53, UD factors that are not factors).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

INT_MAX = 2**53  # counters and indices: exact in float64, no int64 overflow in arithmetic
MAX_ROWS = 100_000  # queued rows of any kind (parity sums, gyro samples, tracker samples)
MAX_MAP = 256  # entries of a counter map
MAX_KEY = 64  # characters of a counter name


class CheckpointFieldError(ValueError):
    """A checkpoint field that is missing, of the wrong type or shape, or out of range."""


def need(doc: Any, key: str, where: str) -> Any:
    """doc[key] of a map, or CheckpointFieldError."""
    if not isinstance(doc, dict):
        raise CheckpointFieldError(f"{where}: expected a map, got {type(doc).__name__}")
    if key not in doc:
        raise CheckpointFieldError(f"{where}.{key}: missing")
    return doc[key]


def number(v: Any, where: str, lo: float = -math.inf, hi: float = math.inf,
           finite: bool = True, integer: bool = False) -> float | int:
    """A number (not bool) in [lo, hi]; finite unless ``finite`` is False (NaN never)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise CheckpointFieldError(f"{where}: expected a number, got {type(v).__name__}")
    if integer and not isinstance(v, int):
        raise CheckpointFieldError(f"{where}: expected an integer, got {v!r}")
    try:
        f = float(v)
    except OverflowError:
        raise CheckpointFieldError(f"{where}: {v} is out of range") from None
    if math.isnan(f) or (finite and not math.isfinite(f)):
        raise CheckpointFieldError(f"{where}: must be finite, got {v!r}")
    if not lo <= f <= hi:
        raise CheckpointFieldError(f"{where}: must be in [{lo:g}, {hi:g}], got {v!r}")
    return int(v) if integer else f


def boolean(v: Any, where: str) -> bool:
    if not isinstance(v, bool):
        raise CheckpointFieldError(f"{where}: expected true/false, got {type(v).__name__}")
    return v


def choice(v: Any, where: str, options: tuple[str, ...]) -> str:
    if not isinstance(v, str) or v not in options:
        raise CheckpointFieldError(f"{where}: must be one of {options}, got {str(v)[:40]!r}")
    return v


def array(doc: Any, where: str, dtype: str, shape: tuple[int, ...], lo: float = -math.inf,
          hi: float = math.inf, finite: bool = True) -> np.ndarray:
    """A stored array {"dtype", "shape", "data"} (EngineState.get_state form) with exactly this
    dtype and shape, every element in [lo, hi] (finite unless ``finite`` is False; NaN never)."""
    dt, shp, data = need(doc, "dtype", where), need(doc, "shape", where), need(doc, "data", where)
    want = np.dtype(dtype)
    if not isinstance(dt, str) or dt != want.str:
        raise CheckpointFieldError(f"{where}: dtype must be {want.str!r}, got {str(dt)[:20]!r}")
    if not isinstance(shp, list) or [int(s) if isinstance(s, int) and not isinstance(s, bool)
                                     else None for s in shp] != list(shape):
        raise CheckpointFieldError(f"{where}: shape must be {list(shape)}, got {str(shp)[:40]}")
    if not isinstance(data, bytes) or len(data) != want.itemsize * int(np.prod(shape)):
        raise CheckpointFieldError(f"{where}: data must be {want.itemsize * int(np.prod(shape))} "
                                   f"bytes")
    a = np.frombuffer(data, dtype=want).reshape(shape).copy()
    return values(a, where, lo, hi, finite)


def values(a: np.ndarray, where: str, lo: float = -math.inf, hi: float = math.inf,
           finite: bool = True) -> np.ndarray:
    """Range check of a numeric array (bool arrays pass)."""
    if a.dtype == np.bool_ or a.size == 0:
        return a
    f = a.astype(np.float64)
    if np.isnan(f).any() or (finite and not np.isfinite(f).all()):
        raise CheckpointFieldError(f"{where}: must be finite")
    out = ((f < lo) | (f > hi)) & np.isfinite(f)  # ±inf (where allowed) is not a range error
    if out.any():
        bad = f[out][0]
        raise CheckpointFieldError(f"{where}: values must be in [{lo:g}, {hi:g}], got {bad:g}")
    return a


def num_list(v: Any, where: str, size: int | None = None, lo: float = -math.inf,
             hi: float = math.inf, finite: bool = True, integer: bool = False) -> np.ndarray:
    """A plain list of numbers (msgpack list) → array, every element checked."""
    if not isinstance(v, list) or (size is not None and len(v) != size) or len(v) > MAX_ROWS:
        n = "a list" if size is None else f"a list of {size}"
        raise CheckpointFieldError(f"{where}: expected {n} numbers")
    out = [number(x, f"{where}[{i}]", lo, hi, finite, integer) for i, x in enumerate(v)]
    return np.asarray(out, np.int64 if integer else np.float64)


def counter_map(v: Any, where: str, floats: bool = False) -> dict[str, Any]:
    """{name: int ≥ 0} (or finite float ≥ 0), bounded in size."""
    if not isinstance(v, dict) or len(v) > MAX_MAP:
        raise CheckpointFieldError(f"{where}: expected a map of at most {MAX_MAP} counters")
    out: dict[str, Any] = {}
    for k, x in v.items():
        if not isinstance(k, str) or not 0 < len(k) <= MAX_KEY:
            raise CheckpointFieldError(f"{where}: counter names must be strings of 1..{MAX_KEY}")
        out[k] = number(x, f"{where}.{k}", 0, INT_MAX if not floats else 1e300,
                        integer=not floats)
    return out


def unit_upper(U: np.ndarray, where: str) -> None:
    """U must be unit upper triangular (ones on the diagonal, zeros below)."""
    if not (np.all(np.diag(U) == 1.0) and not np.tril(U, -1).any()):
        raise CheckpointFieldError(f"{where}: must be unit upper triangular")


def unit_quaternion(q: np.ndarray, where: str) -> None:
    if abs(float(np.linalg.norm(q)) - 1.0) > 1e-6:
        raise CheckpointFieldError(f"{where}: must be a unit quaternion")
