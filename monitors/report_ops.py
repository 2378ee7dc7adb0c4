"""Operations view of an output archive: streams apart, attitude, latency, clock, NIS, flags.

Writes ``ops_<label>.png`` and an interactive ``report.html`` (Bokeh, resources inline, nothing
fetched at run time). Streams are told apart by the packet's ``stream`` field when present, else
by emission order (``seq``, which runs on across streams; MCAP log-time order interleaves
overlapping streams): a backwards step of the bus time ``t`` starts a new stream. Streams are drawn on
one axis, each offset to start after the previous one's end (x = elapsed minutes), with a dashed
boundary marker labelled by how the stream started (the diag messages' ``stream_info``: cold /
warm / resume, bump, first bus time; without it guessed: stream 0 cold, later ones warm).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

from monitors.common import ARCSEC

GAP_PAD_S = 30.0  # gap drawn between consecutive streams on the common axis (s)


@dataclass
class OpsData:
    """Time series of one archive (N decimated /tlm/large packets). Units noted per field."""

    label: str
    t: np.ndarray  # (N,) bus time, s
    stream: np.ndarray  # (N,) int stream index
    x: np.ndarray  # (N,) common axis, min
    boundaries: list[tuple[float, int]]  # (x min, stream index) where a stream starts
    q: np.ndarray  # (N, 4) q_body_from_inertial, scalar last
    omega: np.ndarray  # (N, 3) body rate, deg/s
    lat: np.ndarray  # (N, 2) latency estimate, sigma; ms
    clk: np.ndarray  # (N, 4) freq offset ppm, locked 0/1, repeated, missing (cumulative)
    nis: dict[str, np.ndarray] = field(default_factory=dict)  # kind -> (N,) NIS, dof
    flags: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    att_err: np.ndarray | None = None  # (N, 3) arcsec vs /truth/attitude
    fault_x: list[tuple[float, str]] = field(default_factory=list)  # (x min, flags set)
    stream_info: dict[int, dict[str, Any]] = field(default_factory=dict)  # diag stream_info


def _num(v: Any, default: float = math.nan) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return default


def split_streams(t: np.ndarray, given: list[Any]) -> np.ndarray:
    """Stream index per packet: the ``stream`` field when every packet has one, else a new
    stream at every backwards step of the bus time. t: (N,) s."""
    if given and all(isinstance(s, int) for s in given):
        return np.asarray(given, dtype=np.int64)
    s = np.zeros(len(t), dtype=np.int64)
    if len(t) > 1:
        s[1:] = np.cumsum(np.diff(t) < 0)
    return s


def common_axis(t: np.ndarray, stream: np.ndarray) -> tuple[np.ndarray, list[tuple[float, int]]]:
    """Elapsed minutes with each stream placed after the previous one (GAP_PAD_S apart)."""
    x = np.zeros(len(t))
    bounds: list[tuple[float, int]] = []
    offset = 0.0
    for k in np.unique(stream):
        idx = np.flatnonzero(stream == k)
        t0 = t[idx[0]]
        x[idx] = offset + (t[idx] - t0)
        bounds.append((offset / 60.0, int(k)))
        offset = float(x[idx].max()) + GAP_PAD_S
    return x / 60.0, bounds


def _truth_attitude(reader: Any) -> tuple[np.ndarray, np.ndarray]:
    n = reader.message_counts.get("/truth/attitude", 0)
    if not n:
        return np.zeros(0), np.zeros((0, 4))
    ts, qs = [], []
    for _tp, t_ns, data in reader.iter_raw("/truth/attitude"):
        m = msgpack.unpackb(data, raw=False, strict_map_key=False)
        q = m.get("q_body_from_inertial", m.get("q")) if isinstance(m, dict) else None
        if isinstance(q, list) and len(q) == 4:
            ts.append(_num(m.get("t_bus", t_ns * 1e-9)))
            qs.append(q)
    return np.array(ts), np.array(qs, dtype=float).reshape(-1, 4)


def attitude_error(q: np.ndarray, t: np.ndarray, t_true: np.ndarray,
                   q_true: np.ndarray) -> np.ndarray:
    """Small-angle error (3,) arcsec per packet: q_est ⊗ q_true⁻¹ at the nearest truth sample
    (scalar-last quaternions); NaN where no truth within 1 s."""
    from scipy.spatial.transform import Rotation as R

    out = np.full((len(q), 3), np.nan)
    if not len(t_true):
        return out
    j = np.clip(np.searchsorted(t_true, t), 0, len(t_true) - 1)
    ok = np.abs(t_true[j] - t) < 1.0
    if ok.any():
        e = R.from_quat(q[ok]) * R.from_quat(q_true[j[ok]]).inv()
        out[ok] = e.as_rotvec() / ARCSEC
    return out


def load_ops(path: str, label: str, max_points: int = 1500) -> OpsData:
    """Read the ops series of one output archive (decimated to about max_points)."""
    from radical_rt.io.archive import ArchiveReader

    with ArchiveReader(path) as reader:
        topic = "/tlm/large" if reader.message_counts.get("/tlm/large") else "/tlm/medium"
        n = reader.message_counts.get(topic, 0)
        k = max(1, math.ceil(n / max(max_points, 1)))
        msgs = []
        for i, (_tp, _ns, data) in enumerate(reader.iter_raw(topic)):
            if i % k == 0 or i == n - 1:
                m = msgpack.unpackb(data, raw=False, strict_map_key=False)
                if isinstance(m, dict) and isinstance(m.get("t"), int | float):
                    msgs.append(m)
        t_true, q_true = _truth_attitude(reader)
        faults = [(msgpack.unpackb(d, raw=False), ns) for _tp, ns, d in reader.iter_raw("/fault")]
        info = _stream_info(reader)
    # MCAP orders by log time, which interleaves streams whose bus times overlap; the packet
    # counter seq runs on across streams, so seq order is emission order
    if all(isinstance(m.get("seq"), int) for m in msgs):
        msgs.sort(key=lambda m: m["seq"])
    t = np.array([float(m["t"]) for m in msgs])
    stream = split_streams(t, [m.get("stream") for m in msgs])
    x, bounds = common_axis(t, stream)

    def vec(m: dict, key: str, n: int) -> list[float]:
        v = m.get(key)
        return [_num(a) for a in v[:n]] + [math.nan] * (n - len(v[:n])) \
            if isinstance(v, list) else [math.nan] * n

    q = np.array([vec(m, "q_body_from_inertial", 4) for m in msgs])
    om = np.degrees(np.array([vec(m, "omega_body", 3) for m in msgs]))
    lat = np.array([[_num((m.get("latency") or {}).get("estimate_s")) * 1e3,
                     _num((m.get("latency") or {}).get("sigma_s")) * 1e3] for m in msgs])
    clk = np.array([[_num((m.get("clock") or {}).get("freq_offset_ppm")),
                     1.0 if (m.get("clock") or {}).get("locked") else 0.0,
                     _num((m.get("counters") or {}).get("siru_repeated")),
                     _num((m.get("counters") or {}).get("siru_missing"))] for m in msgs])
    nis: dict[str, np.ndarray] = {}
    for kind in ("st1", "st2", "parity"):
        vals = [(m.get("residuals") or {}).get(kind) for m in msgs]
        if any(isinstance(v, dict) for v in vals):
            nis[kind] = np.array([_nis(v) for v in vals])
    flags = np.array([int(m.get("flags", 0) or 0) for m in msgs], dtype=np.int64)
    d = OpsData(label=label, t=t, stream=stream, x=x, boundaries=bounds, q=q, omega=om, lat=lat,
                clk=clk, nis=nis, flags=flags, stream_info=info)
    if len(t_true) and np.isfinite(q).all():
        d.att_err = attitude_error(q, t, t_true, q_true)
    for f, ns in faults if len(t) else []:
        if isinstance(f, dict):
            near = int(np.argmin(np.abs(t - _num(f.get("t", ns * 1e-9)))))
            d.fault_x.append((float(x[near]), ",".join(map(str, f.get("set") or [])) or "clear"))
    return d


def _nis(v: Any) -> float:
    """NIS of one residual entry: its ``nis`` field, else Σ(innov/σ)² ; NaN when absent."""
    if not isinstance(v, dict):
        return math.nan
    if isinstance(v.get("nis"), int | float):
        return float(v["nis"])
    i, s = np.asarray(v.get("innov") or [], float), np.asarray(v.get("sigma") or [], float)
    return float(np.sum((i / s) ** 2)) if len(i) and len(i) == len(s) and (s > 0).all() \
        else math.nan


def chi2_bounds(dof: int, p: float = 0.95) -> tuple[float, float]:
    """Two-sided chi-square bounds for a single NIS sample of ``dof`` degrees of freedom."""
    from scipy.stats import chi2

    return float(chi2.ppf((1 - p) / 2, dof)), float(chi2.ppf(1 - (1 - p) / 2, dof))


def stream_kind(k: int) -> str:
    """How stream k most likely started when the archive does not say (no diag stream_info)."""
    return "cold start" if k == 0 else "warm start"


def _stream_info(reader: Any) -> dict[int, dict[str, Any]]:
    """The first ``stream_info`` of each stream index found on /diag (docs/contract_extensions.md,
    "Streams"): {index: {"start", "bump", "t_bus_first", ...}}."""
    out: dict[int, dict[str, Any]] = {}
    if not reader.message_counts.get("/diag"):
        return out
    for _tp, _ns, data in reader.iter_raw("/diag"):
        m = msgpack.unpackb(data, raw=False, strict_map_key=False)
        si = m.get("stream_info") if isinstance(m, dict) else None
        if isinstance(si, dict) and isinstance(si.get("index"), int):
            k = si["index"]
            if k not in out or (out[k].get("t_bus_first") is None
                                and si.get("t_bus_first") is not None):
                out[k] = si
    return out


def stream_label(d: OpsData, k: int) -> str:
    """Boundary label of stream k: how it started (cold / warm / resume), the bump applied and its
    first bus time, from the archive's diag ``stream_info``; else :func:`stream_kind`'s guess."""
    si = d.stream_info.get(k)
    if not si or not isinstance(si.get("start"), str):
        return f"stream {k}: {stream_kind(k)} (guessed: no stream_info)"
    bump = si.get("bump")
    parts = [f"stream {k}: {si['start']} start"]
    if isinstance(bump, dict):
        parts.append(f"bump {bump.get('mode', '?')}")
    if isinstance(si.get("t_bus_first"), int | float):
        parts.append(f"first t_bus {float(si['t_bus_first']):.1f} s")
    return ", ".join(parts)


def fault_kind(name: str) -> str:
    """Marker class of a fault message by the flags it set: "isolation" (a GYRO_x_FAILED), "clear"
    (only cleared flags) or "fault"."""
    if "GYRO_" in name and "_FAILED" in name:
        return "isolation"
    return "clear" if name == "clear" else "fault"


def markers(d: OpsData) -> list[tuple[float, str, str]]:
    """Every vertical marker of the ops figures, (x min, kind, label); kind: "boundary",
    "isolation", "fault" or "clear". Shared by the PNG and report.html."""
    out = [(xb, "boundary", stream_label(d, k)) for xb, k in d.boundaries]
    out += [(xf, fault_kind(name), name) for xf, name in d.fault_x]
    return out
