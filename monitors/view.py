"""Display model shared by the TUI and the web dashboard: telemetry packets → rows of strings and
flat numeric columns, in the paper's units (deg/hr, ppm, arcsec). Pure functions of the contract's
messages; no I/O, no UI toolkit."""

from __future__ import annotations

import math
from typing import Any

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
    cols = ["t", "att_x", "att_y", "att_z", "clk_ppm", "clk_tag_ms", "clk_offset_ms"]
    for i in range(p):
        cols += [f"par{i}", f"par{i}_s", f"par{i}_sn"]
    for k in ("st1", "st2"):
        for a in "xyz":
            cols += [f"{k}_{a}", f"{k}_{a}_s", f"{k}_{a}_sn"]
    for g in ORDER:
        for i in range(3 if g == "phi2" else n):
            cols += [f"{g}{i}", f"{g}{i}_s"]
    return cols


def tlm_row(msg: dict[str, Any], shape: dict[str, int]) -> dict[str, float]:
    """One row of the web plots' source from a tlm/large packet (paper units; NaN if absent).
    σ ≤ 0 becomes NaN (log axes)."""
    row = dict.fromkeys(tlm_columns(shape), math.nan)
    row["t"] = _num(msg.get("t"))
    for a, v in zip("xyz", _vec(msg.get("att_sigma")), strict=False):
        row[f"att_{a}"] = v / ARCSEC if v > 0 else math.nan
    c = _map(msg.get("clock"))
    row["clk_ppm"] = _num(c.get("freq_offset_ppm"))
    row["clk_tag_ms"] = _num(c.get("tag_error_sigma_s")) * 1e3
    row["clk_offset_ms"] = _num(c.get("offset_s")) * 1e3
    res = _map(msg.get("residuals"))
    for k, names in (("parity", [f"par{i}" for i in range(shape["parity"])]),
                     ("st1", [f"st1_{a}" for a in "xyz"]), ("st2", [f"st2_{a}" for a in "xyz"])):
        r = _map(res.get(k))
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
