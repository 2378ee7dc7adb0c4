"""Wire edge: decode and validate input messages (CONTRACT §3), counted rejection reasons.

Every decoder returns plain numpy values in SI or raises :class:`InputError` whose ``reason`` is a
short code used for counting (``diag.rejected``) and whose message says what was wrong. Nothing in
here touches filter state.
"""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np

from radical_rt._jit import kernel
from radical_rt.contract.conventions import SIRU_TT_WRAP

QUAT_NORM_TOL = 1e-3  # |‖q‖ − 1| above this is a non-unit quaternion
MAX_SIRU_BATCH = 10000
MAX_DTHETA_RAD = 1.0  # |dθ| of one sample beyond this (100 rad/s at 100 Hz) is not physical
MAX_N_STARS = 1000  # a tracker reporting more stars is wrong (and 2**63 would not fit an int64)


class InputError(ValueError):
    """A rejected input message; ``reason`` is a short counting key."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


def unpack(payload: bytes | dict) -> dict[str, Any]:
    """msgpack bytes → map (a dict passes through). Raises InputError for anything else."""
    if isinstance(payload, dict):
        msg = payload
    else:
        try:
            msg = msgpack.unpackb(bytes(payload), raw=False, strict_map_key=False)
        except Exception as exc:  # msgpack raises several unrelated types
            raise InputError("malformed", f"malformed msgpack: {exc}") from None
    if not isinstance(msg, dict):
        raise InputError("not_a_map", f"payload is a {type(msg).__name__}, not a map")
    if msg.get("v") != 1:
        raise InputError("bad_version", f"unsupported message version v={msg.get('v')!r}")
    return msg


def _field(msg: dict, name: str) -> Any:
    if name not in msg:
        raise InputError("missing_field", f"missing field {name!r}")
    return msg[name]


def _float(msg: dict, name: str) -> float:
    v = _field(msg, name)
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise InputError("bad_type", f"{name} must be a number, got {type(v).__name__}")
    if not math.isfinite(v):
        raise InputError("nonfinite", f"{name} is not finite")
    return float(v)


def _array(value: Any, name: str, dtype, shape_tail: tuple[int, ...] = ()) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=dtype)
    except OverflowError:
        raise InputError("bad_value", f"{name} holds a value outside the {np.dtype(dtype).name} "
                                      "range") from None
    except (TypeError, ValueError):
        raise InputError("bad_shape", f"{name} is not a rectangular numeric array") from None
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise InputError("bad_shape", f"{name} has shape {arr.shape}, expected (k, {shape_tail})")
    return arr


def decode_siru(msg: dict, n_gyro: int = 4):
    """`siru` batch → (t_bus (k,) s, tt (k,) int64, dtheta (k, n) rad, status (k,) int64)."""
    t = _array(_field(msg, "t_bus"), "t_bus", np.float64)
    k = t.shape[0]
    if k == 0 or k > MAX_SIRU_BATCH:
        raise InputError("bad_shape", f"siru batch must hold 1..{MAX_SIRU_BATCH} samples, got {k}")
    raw_tt = _field(msg, "tt")
    if not isinstance(raw_tt, (list, tuple)) or not all(type(x) is int for x in raw_tt):
        raise InputError("bad_type", "tt must be a list of integers")  # (bool is not int here)
    tt = _array(raw_tt, "tt", np.int64)
    dth = _array(_field(msg, "dtheta"), "dtheta", np.float64, (n_gyro,))
    status = _array(_field(msg, "status"), "status", np.int64)
    if not (tt.shape[0] == dth.shape[0] == status.shape[0] == k):
        raise InputError("bad_shape", f"siru columns differ in length: t_bus {k}, tt {tt.shape[0]}, "
                                      f"dtheta {dth.shape[0]}, status {status.shape[0]}")
    bad = _siru_column_check(t, tt, dth, status, SIRU_TT_WRAP, MAX_DTHETA_RAD)
    if bad:
        raise InputError(*_SIRU_BAD[bad])
    return t, tt, dth, status


_SIRU_BAD = {1: ("nonfinite", "siru t_bus or dtheta contains NaN/Inf"),
             2: ("bad_value", "siru tt outside [0, 2**32) or negative status"),
             3: ("time_backwards", "siru t_bus decreases inside the batch"),
             4: ("bad_value", f"siru |dtheta| beyond {MAX_DTHETA_RAD} rad in one sample")}


@kernel
def _siru_column_check(t, tt, dth, status, tt_wrap, max_dth):
    """0 if the columns of a siru batch are valid, else the first failing check: 1 a NaN/Inf in
    t (k,) or dth (k, n); 2 tt (k,) outside [0, tt_wrap) or a negative status (k,); 3 t decreases;
    4 |dth| > max_dth [rad]."""
    for i in range(t.shape[0]):
        if not math.isfinite(t[i]):
            return 1
        for j in range(dth.shape[1]):
            if not math.isfinite(dth[i, j]):
                return 1
    for i in range(t.shape[0]):
        if tt[i] < 0 or tt[i] >= tt_wrap or status[i] < 0:
            return 2
    for i in range(1, t.shape[0]):
        if t[i] < t[i - 1]:
            return 3
    for i in range(t.shape[0]):
        for j in range(dth.shape[1]):
            if abs(dth[i, j]) > max_dth:
                return 4
    return 0


def decode_tracker(msg: dict):
    """`st1`/`st2` sample → (t_bus s, q (4,) q_st_from_inertial, n_stars int, valid bool).

    q is normalized (‖q‖ within QUAT_NORM_TOL of 1 required). The common well-formed message
    takes a short path in plain Python; anything else goes through the checks that name the
    problem (:func:`_decode_tracker_checked`)."""
    t, q, n_stars, valid = (msg.get("t_bus"), msg.get("q"), msg.get("n_stars"), msg.get("valid"))
    if (type(t) is float and type(q) is list and len(q) == 4 and type(n_stars) is int
            and type(valid) is bool and 0 <= n_stars <= MAX_N_STARS and math.isfinite(t)):
        q0, q1, q2, q3 = q
        if type(q0) is float and type(q1) is float and type(q2) is float and type(q3) is float:
            nn = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3
            if math.isfinite(nn) and abs(math.sqrt(nn) - 1.0) <= QUAT_NORM_TOL:
                norm = math.sqrt(nn)
                return t, np.array((q0 / norm, q1 / norm, q2 / norm, q3 / norm)), n_stars, valid
    return _decode_tracker_checked(msg)


def _decode_tracker_checked(msg: dict):
    """:func:`decode_tracker` with every check and its diagnostic (InputError)."""
    t = _float(msg, "t_bus")
    q = _array(_field(msg, "q"), "q", np.float64)
    if q.shape != (4,):
        raise InputError("bad_shape", f"q must have 4 elements, got {q.shape[0]}")
    if not np.isfinite(q).all():
        raise InputError("nonfinite", "q contains NaN/Inf")
    nn = 0.0
    for x in q.tolist():  # the sum of the short path, in the same order
        nn += x * x
    norm = math.sqrt(nn)
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise InputError("non_unit_quaternion", f"‖q‖ = {norm:.6g}, expected 1")
    n_stars = _field(msg, "n_stars")
    if isinstance(n_stars, bool) or not isinstance(n_stars, int) or n_stars < 0:
        raise InputError("bad_type", f"n_stars must be a non-negative integer, got {n_stars!r}")
    if n_stars > MAX_N_STARS:
        raise InputError("bad_value", f"n_stars = {n_stars} exceeds {MAX_N_STARS}")
    valid = _field(msg, "valid")
    if not isinstance(valid, bool):
        raise InputError("bad_type", f"valid must be true/false, got {valid!r}")
    return t, np.array([x / norm for x in q.tolist()]), int(n_stars), valid


def decode_temp(msg: dict) -> tuple[float, dict[str, float]]:
    """`temp` sample → (t_bus, {name: °C}) for the fields present and finite."""
    t = _float(msg, "t_bus")
    out = {}
    for name in ("st1_baseplate_C", "st2_baseplate_C", "siru_C"):
        if name in msg:
            out[name] = _float(msg, name)
    return t, out
