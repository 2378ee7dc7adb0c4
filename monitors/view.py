"""Display model shared by the TUI and the web dashboard: telemetry packets → rows of strings and
flat numeric columns, in the paper's units (deg/hr, ppm, arcsec). Pure functions of the contract's
messages; no I/O, no UI toolkit."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from monitors.common import (
    ARCSEC,
    GROUP_LABELS,
    ORDER,
    PAPER_UNITS,
    element_names,
    flag_label,
    fmt_est_sigma,
    group_paper,
    residual_kinds,
)
from radical_rt.contract.flags import GYRO_FAILED


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _map(v: Any) -> dict[str, Any]:
    return v if isinstance(v, dict) else {}


def _vec(v: Any) -> list[float]:
    return [_num(x) for x in v] if isinstance(v, list | tuple) else []


def n_gyro(msg: dict[str, Any] | None) -> int:
    """Number of gyros in a packet's estimates (4 if unknown)."""
    est = (msg or {}).get("est")
    if isinstance(est, dict):
        for g in ("b", "lam", "mu", "du", "dv"):
            if isinstance(est.get(g), list):
                return len(est[g])
    return 4


def param_rows(msg: dict[str, Any] | None) -> list[tuple[str, str, list[str]]]:
    """Per group: (label, unit, ["est ± σ" per element]) from a tlm/large (or medium) packet."""
    est = (msg or {}).get("est")
    sig = (msg or {}).get("sigma")
    est = est if isinstance(est, dict) else {}
    sig = sig if isinstance(sig, dict) else {}
    out = []
    for g in ORDER:
        e = group_paper(g, est.get(g)) if isinstance(est.get(g), list) else []
        s = group_paper(g, sig.get(g)) if isinstance(sig.get(g), list) else []
        cells = [fmt_est_sigma(g, e[i], s[i] if i < len(s) else None) for i in range(len(e))]
        out.append((GROUP_LABELS[g], PAPER_UNITS[g], cells))
    return out


def column_names(n: int) -> list[str]:
    """Header of the parameter columns: Gyro A / x, Gyro B / y, Gyro C / z, Gyro D, ..."""
    axes = ["x", "y", "z"]
    return [f"{name[-1]}" + (f" / {axes[i]}" if i < 3 else "")
            for i, name in enumerate(element_names("b", n))]


#: Width (characters) of one parameter cell: the widest "est ± σ" of any group for a 4-digit
#: negative estimate and a 3-digit σ at the group's paper digits (λ ≈ -1004.6 ± 350.00 ppm in a
#: cold start), so a table laid out before any data arrives does not truncate; wider values
#: widen the column (the TUI updates cells with ``update_width``).
CELL_WIDTH = max(len(fmt_est_sigma(g, -9999.0, 999.0)) for g in ORDER)

#: Default seconds without any packet of the shown vehicle before the dashboards raise the
#: stale-data alarm (receiver's monotonic clock).
STALE_S = 5.0


def gyro_status(msg: dict[str, Any] | None, flags: int | None = None) -> list[str]:
    """Per gyro: ``"FAILED"`` (its GYRO_<X>_FAILED bit is set in ``flags``, else the packet's
    flags), ``"excluded"`` (in the packet's optional ``excluded`` index list), else ``"ok"``."""
    m = msg or {}
    n = n_gyro(m)
    f = flags if flags is not None else m.get("flags")
    bits = int(f) if isinstance(f, int | float) else 0
    ex = {int(i) for i in m.get("excluded") or [] if isinstance(i, int | float)}
    return ["FAILED" if i < len(GYRO_FAILED) and bits & int(GYRO_FAILED[i])
            else "excluded" if i in ex else "ok" for i in range(n)]


def euler_321(q: Any) -> np.ndarray:
    """3-2-1 (yaw about z, pitch about y', roll about x'') angles in degrees, (N, 3) as [yaw,
    pitch, roll] (scipy "ZYX"), of rotations q_body_from_inertial (N, 4) or (4,), scalar last;
    rows that are not finite with a nonzero norm stay NaN."""
    from scipy.spatial.transform import Rotation

    q = np.asarray(q, float).reshape(-1, 4)
    out = np.full((len(q), 3), np.nan)
    ok = np.isfinite(q).all(axis=1) & (np.linalg.norm(q, axis=1) > 0)
    if ok.any():
        out[ok] = Rotation.from_quat(q[ok]).as_euler("ZYX", degrees=True)
    return out


def euler_321_deg(q: list[float]) -> list[float]:
    """:func:`euler_321` of one scalar-last ``q_body_from_inertial`` as [yaw, pitch, roll] [deg];
    [] when q is not 4 finite numbers with a nonzero norm."""
    if len(q) != 4:
        return []
    ypr = euler_321(q)[0]
    return [] if np.isnan(ypr).any() else [float(v) for v in ypr]


def current_lines(msg: dict[str, Any] | None, flags: int | None = None) -> list[tuple[str, str]]:
    """(label [unit], value) of the current state from the newest tlm packet (large, medium or
    small): attitude quaternion and 3-2-1 Euler angles, body rate, tracker latency ± 1σ, SIRU
    clock, mode, stream index (when the packet has one), flags and per-gyro status. SI in, display units out (deg, deg/s, ms, ppm)."""
    m = msg or {}
    out: list[tuple[str, str]] = []
    q = _vec(m.get("q_body_from_inertial"))
    ypr = euler_321_deg(q)
    if ypr:
        out.append(("q body←inertial [x y z w]", " ".join(f"{v:+.6f}" for v in q)))
        out.append(("Euler 3-2-1 yaw pitch roll [deg]", " ".join(f"{v:+.3f}" for v in ypr)))
    w = _vec(m.get("omega_body"))
    if len(w) == 3:
        out.append(("rate ω body x y z [deg/s]", " ".join(f"{math.degrees(v):+.4f}" for v in w)))
    lat = _map(m.get("latency"))
    if "estimate_s" in lat:
        out.append(("tracker latency ± 1σ [ms]", f"{_num(lat['estimate_s']) * 1e3:.2f} ± "
                                                 f"{_num(lat.get('sigma_s')) * 1e3:.2f}"))
    c = _map(m.get("clock"))
    if c:
        state = f"{c.get('mode', '?')}, {'locked' if c.get('locked') else 'unlocked'}"
        out.append(("SIRU clock [ppm]", f"{state}, {_num(c.get('freq_offset_ppm')):+.3f} ppm"))
    out.append(("mode", str(m.get("mode", "?"))))
    if isinstance(m.get("stream"), int):  # optional stream index (absent in older packets)
        out.append(("stream", str(m["stream"])))
    f = flags if flags is not None else m.get("flags")
    out.append(("flags", flag_label(f if isinstance(f, int) else None)))
    if m.get("est") is not None or flags is not None:
        names = [n[-1] for n in element_names("b", n_gyro(m))]
        out.append(("gyros", "  ".join(f"{a} {s}" for a, s in zip(names, gyro_status(m, f),
                                                                    strict=False))))
    return out


def clock_lines(msg: dict[str, Any] | None) -> list[tuple[str, str]]:
    """(label, value) pairs of the SIRU clock state of a tlm/large packet."""
    c = (msg or {}).get("clock")
    if not isinstance(c, dict):
        return [("clock", "no clock telemetry")]
    out = [("mode", str(c.get("mode", "?"))), ("locked", str(c.get("locked", "?"))),
           ("anomaly", str(c.get("anomaly", "?")))]
    if "freq_offset_ppm" in c:
        out.append(("freq offset", f"{_num(c['freq_offset_ppm']):.3f} ppm"))
    if "offset_s" in c:
        out.append(("offset", f"{_num(c['offset_s']) * 1e3:.3f} ms"))
    if "tag_error_sigma_s" in c:
        out.append(("tag error 1σ", f"{_num(c['tag_error_sigma_s']) * 1e3:.3f} ms"))
    cc = c.get("counters")
    if isinstance(cc, dict):
        keys = ["repeated", "missing", "wraps", "resets", "anomalies"]
        out.append(("counters", " ".join(f"{k}={cc[k]}" for k in keys if k in cc)))
    return out


def residual_lines(msg: dict[str, Any] | None) -> list[tuple[str, str]]:
    """(label, value) pairs: attitude 1σ and, per residual kind, innovations, σ and NIS (arcsec)."""
    m = msg or {}
    out = []
    att = _vec(m.get("att_sigma"))
    if att:
        out.append(("attitude 1σ", " ".join(f"{v / ARCSEC:.2f}" for v in att) + " arcsec"))
    res = _map(m.get("residuals"))
    for k in residual_kinds(res):
        r = _map(res[k])
        innov = " ".join(f"{v / ARCSEC:+.3f}" for v in _vec(r.get("innov")))
        sig = " ".join(f"{v / ARCSEC:.3f}" for v in _vec(r.get("sigma")))
        out.append((k, f"{innov} ±[{sig}] arcsec  NIS {_num(r.get('nis')):.2f} "
                       f"(mean {_num(r.get('nis_mean')):.2f})"))
    return out or [("residuals", "none in telemetry")]


def counter_lines(msg: dict[str, Any] | None) -> list[tuple[str, str]]:
    c = (msg or {}).get("counters")
    if not isinstance(c, dict):
        return [("counters", "none in telemetry")]
    return [(str(k), str(v)) for k, v in c.items()]


def fault_line(msg: dict[str, Any]) -> str:
    """One line per fault message: t, set, cleared, current flags."""
    t = _num(msg.get("t"))
    set_ = ", ".join(map(str, msg.get("set") or [])) or "-"
    cl = ", ".join(map(str, msg.get("cleared") or [])) or "-"
    return f"t={t:.3f}  set: {set_}  cleared: {cl}  → {flag_label(msg.get('flags'))}"


# --------------------------------------------------------------------------- web: flat columns
def tlm_shape(msg: dict[str, Any]) -> dict[str, int]:
    """Array sizes of a tlm/large packet that decide the web plots' columns."""
    res = _map(msg.get("residuals"))
    par = _map(res.get("parity"))
    return {"n": n_gyro(msg), "parity": max(len(_vec(par.get("innov"))), 1)}


def tlm_columns(shape: dict[str, int]) -> list[str]:
    n, p = shape["n"], shape["parity"]
    cols = ["t", "att_x", "att_y", "att_z", "clk_ppm", "clk_tag_ms", "clk_offset_ms",
            "yaw", "pitch", "roll", "w_x", "w_y", "w_z", "lat_ms", "lat_hi", "lat_lo"]
    for i in range(p):
        cols += [f"par{i}", f"par{i}_s", f"par{i}_sn"]
    for k in ("st1", "st2"):
        for a in "xyz":
            cols += [f"{k}_{a}", f"{k}_{a}_s", f"{k}_{a}_sn"]
    cols += ["st1_nis", "st2_nis", "par_nis"]
    for g in ORDER:
        for i in range(3 if g == "phi2" else n):
            cols += [f"{g}{i}", f"{g}{i}_s"]
    return cols


def tlm_row(msg: dict[str, Any], shape: dict[str, int]) -> dict[str, float]:
    """One row of the web plots' source from a tlm/large packet (paper units; NaN if absent):
    attitude 1σ and residuals arcsec, Euler angles deg, rates deg/s, latency (± 1σ) ms, clock
    ppm and ms, parameters in the paper's units. σ ≤ 0 becomes NaN (log axes)."""
    row = dict.fromkeys(tlm_columns(shape), math.nan)
    row["t"] = _num(msg.get("t"))
    for a, v in zip("xyz", _vec(msg.get("att_sigma")), strict=False):
        row[f"att_{a}"] = v / ARCSEC if v > 0 else math.nan
    for k, v in zip(("yaw", "pitch", "roll"), euler_321_deg(_vec(msg.get("q_body_from_inertial"))),
                    strict=False):
        row[k] = v
    for a, v in zip("xyz", _vec(msg.get("omega_body")), strict=False):
        row[f"w_{a}"] = math.degrees(v)
    lat = _map(msg.get("latency"))
    est_ms, sig_ms = _num(lat.get("estimate_s")) * 1e3, _num(lat.get("sigma_s")) * 1e3
    row["lat_ms"], row["lat_hi"], row["lat_lo"] = est_ms, est_ms + sig_ms, est_ms - sig_ms
    c = _map(msg.get("clock"))
    row["clk_ppm"] = _num(c.get("freq_offset_ppm"))
    row["clk_tag_ms"] = _num(c.get("tag_error_sigma_s")) * 1e3
    row["clk_offset_ms"] = _num(c.get("offset_s")) * 1e3
    res = _map(msg.get("residuals"))
    for k, names in (("parity", [f"par{i}" for i in range(shape["parity"])]),
                     ("st1", [f"st1_{a}" for a in "xyz"]), ("st2", [f"st2_{a}" for a in "xyz"])):
        r = _map(res.get(k))
        nis = _num(r.get("nis"))
        row["par_nis" if k == "parity" else f"{k}_nis"] = nis if nis > 0 else math.nan  # (log axis)
        for name, iv, sv in zip(names, _vec(r.get("innov")), _vec(r.get("sigma")), strict=False):
            row[name] = iv / ARCSEC
            row[f"{name}_s"], row[f"{name}_sn"] = sv / ARCSEC, -sv / ARCSEC
    est = _map(msg.get("est"))
    sig = _map(msg.get("sigma"))
    for g in ORDER:
        width = 3 if g == "phi2" else shape["n"]
        for i, v in enumerate(group_paper(g, est.get(g))[:width]):
            row[f"{g}{i}"] = v
        for i, v in enumerate(group_paper(g, sig.get(g))[:width]):
            row[f"{g}{i}_s"] = v if v > 0 else math.nan
    return row


class StreamAxis:
    """One time axis for the live plots of a vehicle whose streams may overlap in bus time: the
    first stream keeps its bus time t [s]; each later stream is placed ``pad_s`` after the
    largest x drawn so far (the live counterpart of monitors.report_ops.common_axis). A packet's
    stream is its ``stream`` field, or else a new stream starts at a backwards step of t."""

    def __init__(self, pad_s: float = 30.0) -> None:
        self.pad_s = pad_s
        self.start: dict[int, tuple[float, float]] = {}  # stream → (x of its start, its first t)
        self.k: int | None = None  # the current stream
        self.last_t = -math.inf
        self.x_max = -math.inf

    def x(self, t: float, stream: Any = None) -> float:
        """x [s] of the tlm packet at bus time t of ``stream`` (None: not given); a new stream
        index (or a backwards step without one) starts a new segment."""
        if not math.isfinite(t):
            return t
        k = stream if isinstance(stream, int) else None
        if k is None:
            k = 0 if self.k is None else self.k + (1 if t < self.last_t else 0)
        if k not in self.start:
            x0 = t if self.k is None else self.x_max + self.pad_s
            self.start[k] = (x0, t)
        self.k, self.last_t = k, t
        x = self.at(t, k)
        self.x_max = max(self.x_max, x)
        return x

    def at(self, t: float, stream: Any = None) -> float:
        """x [s] of time t in a stream already seen (the current one when not given or unknown):
        for messages that must not start a segment (fault messages)."""
        k = stream if isinstance(stream, int) and stream in self.start else self.k
        if k is None:
            return t
        x0, t0 = self.start[k]
        return x0 + (t - t0)
