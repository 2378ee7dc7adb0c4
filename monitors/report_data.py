"""Loading for ``radical report``: what a report needs from one output archive (:class:`ArchiveData`,
paper units), read by :func:`load_archive` from its telemetry (``/tlm/large``, else
``/tlm/medium``; decimated to ``max_points`` packets for the figures, the last packet exactly),
``/truth/params``, the ``/diag`` temperatures and ``/fault``; and the report's one-line error
(:class:`ReportError`).
"""

from __future__ import annotations

import math
import os
import warnings
from dataclasses import dataclass, field
from typing import Any

import msgpack
import numpy as np

from monitors.common import ARCSEC, ORDER, group_paper

TLM_TOPICS = ("/tlm/large", "/tlm/medium")


class ReportError(Exception):
    """A report cannot be made; ``str(e)`` is one line."""


@dataclass
class ArchiveData:
    """What a report needs from one output archive (paper units unless noted)."""

    path: str
    label: str
    topic: str  # /tlm/large or /tlm/medium
    n_packets: int
    scenario: dict[str, str]
    t: np.ndarray  # bus time of the decimated packets (s)
    est: dict[str, np.ndarray]  # group -> (N, n)
    sig: dict[str, np.ndarray]
    att_sigma: np.ndarray  # (N, 3) arcsec
    resid: dict[str, dict[str, np.ndarray]]  # kind -> innov/sigma (N, m) arcsec
    flags: np.ndarray  # (N,) int
    last: dict[str, Any]  # the last packet, decoded, SI
    final_est: dict[str, list[float]]  # last packet, paper units
    final_sig: dict[str, list[float]]
    truth_final: dict[str, list[float]] | None = None  # /truth/params at the end time
    truth_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    truth: dict[str, np.ndarray] = field(default_factory=dict)
    temp_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    temps: dict[str, np.ndarray] = field(default_factory=dict)
    faults: list[dict[str, Any]] = field(default_factory=list)
    n_faults: int = 0
    notes: list[str] = field(default_factory=list)

    @property
    def t_end(self) -> float:
        return float(self.last.get("t", self.t[-1] if len(self.t) else math.nan))

    @property
    def groups(self) -> list[str]:
        return [g for g in ORDER if g in self.final_est]


def _unpack(data: bytes) -> dict[str, Any] | None:
    try:
        m = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception:
        return None
    return m if isinstance(m, dict) else None


def _stride_raw(reader: Any, topic: str, count: int, max_points: int
                ) -> tuple[list[tuple[int, bytes]], tuple[int, bytes] | None]:
    """Every k-th raw message of a topic (k so that ≤ max_points remain) and the last one."""
    k = max(1, math.ceil(count / max(max_points, 1)))
    picked: list[tuple[int, bytes]] = []
    last: tuple[int, bytes] | None = None
    i = 0
    for _topic, t_ns, data in reader.iter_raw(topic):
        last = (t_ns, data)
        if i % k == 0:
            picked.append(last)
        i += 1
    if last is not None and (i - 1) % k != 0:
        picked.append(last)
    return picked, last


def _vec(m: dict[str, Any] | None, path: tuple[str, ...], n: int) -> np.ndarray:
    """A numeric list at ``m[path...]`` as float array of length n (NaN where absent)."""
    v: Any = m
    for p in path:
        v = v.get(p) if isinstance(v, dict) else None
    out = np.full(n, np.nan)
    if isinstance(v, list | tuple):
        for i, x in enumerate(v[:n]):
            try:
                out[i] = float(x)
            except (TypeError, ValueError):
                pass
    elif isinstance(v, int | float) and n >= 1:
        out[0] = float(v)
    return out


def _width(msgs: list[dict[str, Any]], path: tuple[str, ...]) -> int:
    w = 0
    for m in msgs:
        v: Any = m
        for p in path:
            v = v.get(p) if isinstance(v, dict) else None
        if isinstance(v, list | tuple):
            w = max(w, len(v))
    return w


def load_archive(path: str, label: str, max_points: int = 1500) -> ArchiveData:
    """Read one output archive (decimated for figures; the last packet exactly)."""
    from radical_rt.io.archive import ArchiveError, ArchiveReader

    if not os.path.exists(path):
        raise ReportError(f"{path}: no such file")
    if os.path.isdir(path):
        raise ReportError(f"{path}: is a directory, not an MCAP archive")
    notes: list[str] = []
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            reader = ArchiveReader(path)
        notes += [" ".join(str(w.message).split()) for w in caught]
    except ArchiveError as e:
        raise ReportError(str(e)) from None
    try:
        with reader:
            topic = next((t for t in TLM_TOPICS if reader.message_counts.get(t)), None)
            if topic is None:
                have = ", ".join(t for t in reader.topics if reader.message_counts.get(t)) or "none"
                raise ReportError(f"{path}: no telemetry channels (/tlm/large or /tlm/medium with "
                                  f"messages; channels present: {have})")
            count = reader.message_counts[topic]
            picked, last_raw = _stride_raw(reader, topic, count, max_points)
            msgs, times = [], []
            for t_ns, data in picked:
                m = _unpack(data)
                if m is not None and isinstance(m.get("est"), dict):
                    msgs.append(m)
                    times.append(float(m["t"]) if isinstance(m.get("t"), int | float) else t_ns * 1e-9)
            if not msgs:
                raise ReportError(f"{path}: {topic} has no decodable packet with estimates")
            last = _unpack(last_raw[1]) if last_raw else None
            if last is None or not isinstance(last.get("est"), dict):
                last = msgs[-1]
                notes.append("last telemetry packet undecodable: using the last readable one")
            t_end_ns = round(float(last.get("t", times[-1])) * 1e9)
            truth_final, truth_t, truth = _load_truth(reader, t_end_ns, max_points)
            temp_t, temps = _load_temps(reader, max_points)
            faults, n_faults = _load_faults(reader)
            scenario = dict(reader.scenario)
    except ArchiveError as e:
        raise ReportError(str(e)) from None

    groups = [g for g in ORDER if g in last["est"]]
    est = {g: np.array([group_paper(g, _vec(m, ("est", g), _width([last], ("est", g))))
                        for m in msgs]) for g in groups}
    sig = {g: np.array([group_paper(g, _vec(m, ("sigma", g), _width([last], ("est", g))))
                        for m in msgs]) for g in groups}
    att = np.array([_vec(m, ("att_sigma",), 3) for m in msgs]) / ARCSEC
    resid: dict[str, dict[str, np.ndarray]] = {}
    kinds: list[str] = []
    for m in msgs:
        res = m.get("residuals")
        for k in (res if isinstance(res, dict) else {}):
            if k not in kinds:
                kinds.append(k)
    for k in kinds:
        w = _width(msgs, ("residuals", k, "innov"))
        if w:
            resid[k] = {q: np.array([_vec(m, ("residuals", k, q), w) for m in msgs]) / ARCSEC
                        for q in ("innov", "sigma")}
    flags = np.array([int(m.get("flags", 0) or 0) for m in msgs], dtype=np.int64)
    final_est = {g: group_paper(g, last["est"][g]) for g in groups}
    sg_raw = last.get("sigma")
    sg: dict[str, Any] = sg_raw if isinstance(sg_raw, dict) else {}
    final_sig = {g: group_paper(g, sg[g]) if g in sg else [math.nan] * len(final_est[g])
                 for g in groups}
    if topic != "/tlm/large":
        notes.append(f"no /tlm/large: estimates from {topic}, no σ or residuals")
    return ArchiveData(path=path, label=label, topic=topic, n_packets=count, scenario=scenario,
                       t=np.array(times), est=est, sig=sig, att_sigma=att, resid=resid,
                       flags=flags, last=last, final_est=final_est, final_sig=final_sig,
                       truth_final=truth_final, truth_t=truth_t, truth=truth, temp_t=temp_t,
                       temps=temps, faults=faults, n_faults=n_faults, notes=notes)


def _load_truth(reader: Any, t_end_ns: int, max_points: int):
    n = reader.message_counts.get("/truth/params", 0)
    if not n:
        return None, np.zeros(0), {}
    picked, _ = _stride_raw(reader, "/truth/params", n, max_points)
    at_end = None
    for _topic, _t_ns, data in reader.iter_raw("/truth/params", end_ns=t_end_ns + 1):
        at_end = data
    if at_end is None:  # truth starts after the last packet: take the first
        at_end = picked[0][1]
    final = None
    m = _unpack(at_end)
    if m is not None:
        final = {g: group_paper(g, m[g]) for g in ORDER if isinstance(m.get(g), list)}
    ts: list[float] = []
    series: dict[str, list[Any]] = {g: [] for g in ORDER}
    for t_ns, data in picked:
        m = _unpack(data)
        if m is None:
            continue
        ts.append(float(m.get("t_bus", t_ns * 1e-9)))
        for g in ORDER:
            series[g].append(group_paper(g, m.get(g)) if isinstance(m.get(g), list) else None)
    truth = {}
    for g, vals in series.items():
        if vals and all(v is not None and len(v) == len(vals[0]) for v in vals):
            truth[g] = np.array(vals)
    return final or None, np.array(ts), truth


def _load_temps(reader: Any, max_points: int):
    n = reader.message_counts.get("/diag", 0)
    if not n:
        return np.zeros(0), {}
    picked, _ = _stride_raw(reader, "/diag", n, max_points)
    ts: list[float] = []
    vals: dict[str, list[float]] = {}
    for t_ns, data in picked:
        m = _unpack(data)
        temps = m.get("temps") if m else None
        if m is None or not isinstance(temps, dict):
            continue
        i = len(ts)
        ts.append(float(m.get("t", t_ns * 1e-9)))
        for k, v in temps.items():
            if isinstance(v, int | float):
                vals.setdefault(k, [math.nan] * i).append(float(v))
        for lst in vals.values():
            if len(lst) < len(ts):
                lst.append(math.nan)
    return np.array(ts), {k: np.array(v) for k, v in vals.items()}


def _load_faults(reader: Any, keep: int = 200):
    out: list[dict[str, Any]] = []
    n = 0
    for _topic, t_ns, data in reader.iter_raw("/fault"):
        n += 1
        if len(out) < keep:
            m = _unpack(data)
            if m is not None:
                m.setdefault("t", t_ns * 1e-9)
                out.append(m)
    return out, n
