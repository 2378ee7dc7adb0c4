"""The FDI monitor's running state in a checkpoint (issue 23: "resume that continues … FDI
state"): :func:`capture` encodes :meth:`radical_rt.fdi.monitor.FaultMonitor.get_state` (sample history,
tracker history, snapshots, detector statistics, the alarm in progress and its hypothesis bank,
the alarm and isolation records) into msgpack-able values; :func:`check` validates every field
against the node's own engine (shapes, dtypes, ranges, finiteness, time order, consecutive tracker
sequence numbers, UD positivity of the snapshots, the bank's arrays against a bank built from the
stored snapshot) and returns the value :meth:`FaultMonitor.set_state` takes. Field errors are
:class:`~radical_rt.io.ckpt_validate.CheckpointFieldError` naming the field.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from radical_rt.io import ckpt_validate as cv

T_MAX = 1e12  # |time| [s]
TESTS = ("instant", "persistence", "cusum")
MAX_RECORDS = 1000  # alarm and isolation records kept in a checkpoint
SNAP_ARRAYS = {"q": (-1.0, 1.0), "omega": (-100.0, 100.0), "xp": (-10.0, 10.0),
               "U": (-1e12, 1e12), "d": (0.0, 1e12), "N": (-1.0 - 1e-9, 1.0 + 1e-9)}


def _enc(v: Any) -> Any:
    """numpy arrays → {"dtype", "shape", "data"}, tuples → lists, numpy scalars → Python."""
    if isinstance(v, np.ndarray):
        a = np.ascontiguousarray(v)
        return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes()}
    if isinstance(v, dict):
        return {str(k): _enc(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_enc(x) for x in v]
    if isinstance(v, np.generic):
        return v.item()
    return v


def capture(fdi, history: bool = True) -> dict[str, Any]:
    """The monitor's running state, msgpack-able (``history``: see ``get_state``)."""
    return _enc(fdi.get_state(history))


# ------------------------------------------------------------------------------------ check
def _opt_time(v: Any, where: str) -> float:
    """A time that may be NaN (stored as None) or ±inf."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return math.nan
    return cv.number(v, where, -math.inf, math.inf, finite=False)


def _plain(v: Any, where: str, depth: int = 0) -> Any:
    """A record of plain values (numbers, strings, bools, None, lists, maps), bounded."""
    if depth > 6:
        raise cv.CheckpointFieldError(f"{where}: nested too deep")
    if v is None or isinstance(v, (bool, str)):
        if isinstance(v, str) and len(v) > 200:
            raise cv.CheckpointFieldError(f"{where}: string too long")
        return v
    if isinstance(v, (int, float)):
        return cv.number(v, where, -1e300, 1e300, finite=False)
    if isinstance(v, list) and len(v) <= 64:
        return [_plain(x, f"{where}[{i}]", depth + 1) for i, x in enumerate(v)]
    if isinstance(v, dict) and len(v) <= 64 and all(isinstance(k, str) for k in v):
        return {k: _plain(x, f"{where}.{k[:20]}", depth + 1) for k, x in v.items()}
    raise cv.CheckpointFieldError(f"{where}: not a plain record value")


def _alarm(v: Any, where: str) -> dict[str, Any]:
    rec = _plain(v, where)
    if not isinstance(rec, dict):
        raise cv.CheckpointFieldError(f"{where}: expected a map")
    cv.number(cv.need(rec, "t_alarm", where), where + ".t_alarm", -T_MAX, T_MAX)
    cv.number(cv.need(rec, "t_onset_est", where), where + ".t_onset_est", -T_MAX, T_MAX)
    cv.choice(cv.need(rec, "test", where), where + ".test", TESTS)
    return rec


def _rows(doc: Any, where: str, dtype: str, cols: tuple[int, ...], lo: float, hi: float,
          finite: bool = True) -> np.ndarray:
    shp = cv.need(doc, "shape", where)
    if not (isinstance(shp, list) and len(shp) == 1 + len(cols) and isinstance(shp[0], int)
            and 0 <= shp[0] <= cv.MAX_ROWS):
        raise cv.CheckpointFieldError(f"{where}: expected at most {cv.MAX_ROWS} rows")
    if shp[0] == 0 and cv.need(doc, "data", where) == b"":  # an empty buffer (never appended)
        return np.zeros((0, *cols), np.dtype(dtype))
    return cv.array(doc, where, dtype, (shp[0], *cols), lo, hi, finite)


def _snapshot(s: Any, where: str, eng) -> dict[str, Any]:
    out: dict[str, Any] = {
        "t": cv.number(cv.need(s, "t", where), where + ".t", -T_MAX, T_MAX),
        "trk_seq": cv.number(cv.need(s, "trk_seq", where), where + ".trk_seq", 0, cv.INT_MAX,
                             integer=True)}
    gen = cv.num_list(cv.need(s, "gen", where), where + ".gen", 3, 0, cv.INT_MAX, integer=True)
    out["gen"] = tuple(int(g) for g in gen)
    for k, (lo, hi) in SNAP_ARRAYS.items():
        ref = getattr(eng, k)
        out[k] = cv.array(cv.need(s, k, where), f"{where}.{k}", "<f8", ref.shape, lo, hi)
    cv.unit_quaternion(out["q"], where + ".q")
    cv.unit_upper(out["U"], where + ".U")
    if not (out["d"] > 0).all():
        raise cv.CheckpointFieldError(f"{where}.d: the UD diagonal must be > 0")
    return out


def _trackers(v: Any, trk_seq: int) -> dict[str, np.ndarray]:
    """The tracker history: columns seq, t, tracker, q, n_stars (this version's
    TrackerBuffer.get_state), or the earlier list of rows [seq, t, tracker, q, n_stars]; either
    way the columns for ``set_state``, each value checked (consecutive sequence numbers up to
    trk_seq, unit quaternions)."""
    w = "fdi.monitor.trk"
    if isinstance(v, list):
        v = _tracker_rows(v)
    if not isinstance(v, dict):
        raise cv.CheckpointFieldError(f"{w}: expected the tracker sample columns")
    seq = _rows(cv.need(v, "seq", w), w + ".seq", "<i8", (), 1, trk_seq)
    m = len(seq)
    out = {"seq": seq, "t": cv.array(cv.need(v, "t", w), w + ".t", "<f8", (m,), -T_MAX, T_MAX),
           "tracker": cv.array(cv.need(v, "tracker", w), w + ".tracker", "<i8", (m,), 1, 2),
           "q": cv.array(cv.need(v, "q", w), w + ".q", "<f8", (m, 4), -1.0, 1.0),
           "n_stars": cv.array(cv.need(v, "n_stars", w), w + ".n_stars", "<i8", (m,), 0,
                               2**31 - 1)}
    if m > 1 and not (np.diff(seq) == 1).all():
        raise cv.CheckpointFieldError(f"{w}.seq: sequence numbers must be consecutive")
    if m and (np.abs(np.linalg.norm(out["q"], axis=1) - 1.0) > 1e-6).any():
        raise cv.CheckpointFieldError(f"{w}.q: must be unit quaternions")
    return out


def _tracker_rows(v: list) -> dict[str, Any]:
    """The list-of-rows form (checkpoints before the columns) as encoded columns."""
    if len(v) > cv.MAX_ROWS:
        raise cv.CheckpointFieldError("fdi.monitor.trk: expected a list of tracker samples")
    cols: dict[str, list] = {"seq": [], "t": [], "tracker": [], "q": [], "n_stars": []}
    for i, row in enumerate(v):
        w = f"fdi.monitor.trk[{i}]"
        if not isinstance(row, list) or len(row) != 5:
            raise cv.CheckpointFieldError(f"{w}: expected [seq, t, tracker, q, n_stars]")
        cols["seq"].append(int(cv.number(row[0], w + ".seq", 1, cv.INT_MAX, integer=True)))
        cols["t"].append(cv.number(row[1], w + ".t", -T_MAX, T_MAX))
        cols["tracker"].append(int(cv.number(row[2], w + ".tracker", 1, 2, integer=True)))
        cols["q"].append(cv.array(row[3], w + ".q", "<f8", (4,), -1.0, 1.0))
        cols["n_stars"].append(int(cv.number(row[4], w + ".n_stars", 0, 2**31 - 1,
                                             integer=True)))
    m = len(v)
    arrays = {"seq": np.array(cols["seq"], np.int64), "t": np.array(cols["t"], np.float64),
              "tracker": np.array(cols["tracker"], np.int64),
              "q": np.array(cols["q"], np.float64).reshape(m, 4),
              "n_stars": np.array(cols["n_stars"], np.int64)}
    return {k: _enc(a) for k, a in arrays.items()}


def check(m: Any, sp) -> dict[str, Any]:
    """Validate a :func:`capture` value against ``sp``'s engine; the value for ``set_state``."""
    from radical_rt.fdi.fdi_detect import ParityDetector
    from radical_rt.fdi.fdi_hypotheses import HypothesisBank

    eng, n = sp.engine, sp.engine.n_gyro
    w = "fdi.monitor"
    if not isinstance(m, dict):
        raise cv.CheckpointFieldError(f"{w}: expected a map")
    st: dict[str, Any] = {
        "state": cv.choice(cv.need(m, "state", w), w + ".state",
                           ("waiting", "monitoring", "alarm", "three-gyro", "flagged", "disabled")),
        "last_nu": _opt_time(cv.need(m, "last_nu", w), w + ".last_nu"),
        "last_rho": _opt_time(cv.need(m, "last_rho", w), w + ".last_rho"),
        "_next_check": _opt_time(cv.need(m, "_next_check", w), w + "._next_check"),
        "_sum_seen": cv.boolean(cv.need(m, "_sum_seen", w), w + "._sum_seen"),
        "_t_decided": _opt_time(cv.need(m, "_t_decided", w), w + "._t_decided"),
        "trk_seq": int(cv.number(cv.need(m, "trk_seq", w), w + ".trk_seq", 0, cv.INT_MAX,
                                 integer=True)),
        "alarm_is_last": cv.boolean(cv.need(m, "alarm_is_last", w), w + ".alarm_is_last"),
        "counts": cv.counter_map(cv.need(m, "counts", w), w + ".counts")}
    gen = cv.need(m, "gen", w)
    st["gen"] = None if gen is None else [int(g) for g in cv.num_list(
        gen, w + ".gen", 3, 0, cv.INT_MAX, integer=True)]
    for k in ("failed", "flagged_only"):
        st[k] = [int(g) for g in cv.num_list(cv.need(m, k, w), f"{w}.{k}", None, 0, n - 1,
                                             integer=True)]
    for k in ("alarms", "isolations"):
        recs = cv.need(m, k, w)
        if not isinstance(recs, list) or len(recs) > MAX_RECORDS:
            raise cv.CheckpointFieldError(f"{w}.{k}: expected at most {MAX_RECORDS} records")
        st[k] = [(_alarm if k == "alarms" else _plain)(r, f"{w}.{k}[{i}]")
                 for i, r in enumerate(recs)]
    a = cv.need(m, "alarm", w)
    st["alarm"] = None if a is None else _alarm(a, w + ".alarm")
    if st["alarm_is_last"] and (not st["alarms"] or st["alarms"][-1] != st["alarm"]):
        raise cv.CheckpointFieldError(f"{w}.alarm: differs from the last alarm record")
    st["parity_log"] = _rows(cv.need(m, "parity_log", w), w + ".parity_log", "<f8", (2,),
                             -T_MAX, T_MAX)
    g = cv.need(m, "gbuf", w)
    f = _rows(cv.need(g, "f", w + ".gbuf"), w + ".gbuf.f", "<f8", (3 + n,), -T_MAX, T_MAX)
    r = len(f)
    st["gbuf"] = {"f": f,
                  "status": cv.array(cv.need(g, "status", w + ".gbuf"), w + ".gbuf.status",
                                     "<i8", (r,), 0, 2**31 - 1),
                  "bridged": cv.array(cv.need(g, "bridged", w + ".gbuf"), w + ".gbuf.bridged",
                                      "|b1", (r,))}
    if r:
        if r > 1 and not (np.diff(f[:, 0]) >= 0).all():
            raise cv.CheckpointFieldError(f"{w}.gbuf.f: samples must be in time order")
        cv.values(f[:, 1], w + ".gbuf.f (dt)", 0.0, 1e6)
        cv.values(f[:, 2], w + ".gbuf.f (var_extra)", 0.0, 1.0)
        cv.values(f[:, 3:], w + ".gbuf.f (dtheta)", -10.0, 10.0)
    st["trk"] = _trackers(cv.need(m, "trk", w), st["trk_seq"])
    snaps = cv.need(m, "snaps", w)
    if not isinstance(snaps, list) or len(snaps) > 1000:
        raise cv.CheckpointFieldError(f"{w}.snaps: expected a list of at most 1000 snapshots")
    st["snaps"] = [_snapshot(s, f"{w}.snaps[{i}]", eng) for i, s in enumerate(snaps)]
    if any(b["t"] < a["t"] for a, b in zip(st["snaps"], st["snaps"][1:], strict=False)):
        raise cv.CheckpointFieldError(f"{w}.snaps: must be in time order")
    d = cv.need(m, "det", w)
    if d is None:
        st["det"] = None
    else:
        st["det"] = {k: (_opt_time(cv.need(d, k, w + ".det"), f"{w}.det.{k}")
                         if k.startswith("t_") else None) for k in ParityDetector.STATE}
        for k in ("s_pos", "s_neg"):
            st["det"][k] = cv.number(cv.need(d, k, w + ".det"), f"{w}.det.{k}", 0.0, 1e300)
        for k in ("run", "quiet"):
            st["det"][k] = int(cv.number(cv.need(d, k, w + ".det"), f"{w}.det.{k}", 0,
                                         cv.INT_MAX, integer=True))
        st["det"]["guarded"] = cv.boolean(cv.need(d, "guarded", w + ".det"), w + ".det.guarded")
    st["bank"] = _bank(cv.need(m, "bank", w), w + ".bank", eng, st, HypothesisBank)
    return st


def _bank(b: Any, w: str, eng, st: dict[str, Any], bank_type) -> dict[str, Any] | None:
    if b is None:
        return None
    if st["state"] != "alarm" or st["alarm"] is None:
        raise cv.CheckpointFieldError(f"{w}: a bank runs only during an alarm")
    from radical_rt.fdi.monitor import Snapshot
    snap = _snapshot(cv.need(b, "snap", w), w + ".snap", eng)
    t_alarm = cv.number(cv.need(b, "t_alarm", w), w + ".t_alarm", -T_MAX, T_MAX)
    ref = bank_type(eng, Snapshot(**snap), t_alarm)  # the shapes and dtypes of this engine's
    out: dict[str, Any] = {"snap": snap, "t_alarm": t_alarm}
    for k in ref.STATE_ARRAYS:
        a = getattr(ref, k)
        finite = k not in ("ll",)  # a hypothesis whose S was not positive definite has ll = −inf
        out[k] = cv.array(cv.need(b, k, w), f"{w}.{k}", a.dtype.str, a.shape, -1e300, 1e300,
                          finite)
    for k in ("Ptt", "Ppp"):
        diag = np.diagonal(out[k], axis1=-2, axis2=-1)
        if not (diag >= 0).all():
            raise cv.CheckpointFieldError(f"{w}.{k}: variances must be ≥ 0")
    out["k"] = int(cv.number(cv.need(b, "k", w), w + ".k", 0, cv.INT_MAX, integer=True))
    out["bad_s"] = int(cv.number(cv.need(b, "bad_s", w), w + ".bad_s", 0, cv.INT_MAX,
                                 integer=True))
    out["trk_seq"] = int(cv.number(cv.need(b, "trk_seq", w), w + ".trk_seq", 0, st["trk_seq"],
                                   integer=True))
    out["t_last"] = cv.number(cv.need(b, "t_last", w), w + ".t_last", snap["t"], T_MAX)
    return out
