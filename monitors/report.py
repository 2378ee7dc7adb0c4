"""Paper-style report from output archives: Tables 2–7 (Markdown + CSV) and Figures 4–8 (PNG).

    radical report OUT.mcap [OUT2.mcap ...] -o DIR [--labels warm,cold] [--max-points N]

Reads the telemetry of archives written by ``radical process`` or ``radical record``
(``/tlm/large``, else ``/tlm/medium``; ``/fault``; ``/diag`` temperatures; ``/truth/params`` when
present) and writes into DIR:

* ``tables.md`` (all six tables) and ``table<N>_<group>.md`` / ``.csv`` for N = 2..7 — the
  paper's layout: one row per archive, per gyro (or axis) the estimate and its 1σ, paper units;
  with truth (``/truth/params`` at the end time) also the truth and error/σ per element;
* ``fig4_<label>.png`` (attitude 1σ; parity residual ±1σ; ST1, ST2 residuals ±1σ; ST2 alignment
  estimates and σ), ``fig5_<label>.png`` (b, λ, μ estimates and σ), ``fig6_<label>.png`` (δu, δv
  estimates and σ) per archive; with two or more archives ``fig7.png`` (δu, δv side by side) and
  ``fig8.png`` (ST2 misalignment side by side, with the ST2 baseplate temperature when ``/diag``
  carries it);
* ``index.html`` showing all of it (relative links, no external resources);
* ``calibration_report.html``: one self-contained file (figures inline) with run metadata,
  Tables 2–7 with σ, convergence times, residual statistics and NIS, edits and faults
  (:mod:`monitors.calreport`).

The tables use the last telemetry packet of each archive; figures decimate to ``--max-points``
packets per archive (the last one is always kept). Exit status 0, or 2 with a one-line error
(missing file, not an MCAP archive, no telemetry channels, bad option).
"""

from __future__ import annotations

import argparse
import csv
import html
import io
import math
import os
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from monitors.common import (
    ARCSEC,
    DIGITS,
    GROUP_LABELS,
    ORDER,
    PAPER_UNITS,
    TABLE_NUMBER,
    TITLES,
    element_names,
    flag_label,
    group_paper,
    safe_name,
)
from radical_rt.contract.conventions import SI_PER_PAPER_UNIT
from radical_rt.contract.flags import GYRO_FAILED
from radical_rt.contract.paper_table import rows as paper_rows
from radical_rt.io.outpaths import output_dir

TLM_TOPICS = ("/tlm/large", "/tlm/medium")
GAP_S = 60.0  # larger jumps of the packet time are stream breaks, collapsed in the figures


class ReportError(Exception):
    """A report cannot be made; ``str(e)`` is one line."""


# ------------------------------------------------------------------------------------ loading
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


# ------------------------------------------------------------------------------------ tables
def _fmt(v: float | None, digits: int) -> str:
    if v is None or not math.isfinite(v):
        return "—"
    return f"{v:.{digits}f}".replace("-", "−")


def _si(group: str, vals: list[float]) -> list[float]:
    return [v * SI_PER_PAPER_UNIT[group] for v in vals]


def table_rows(data: list[ArchiveData], group: str) -> tuple[list[str], list[dict[str, Any]]]:
    """Element names and per-archive rows for one group (paper units), with err/σ from
    :func:`radical_rt.contract.paper_table.rows` when truth is known."""
    out = []
    names: list[str] = []
    for d in data:
        if group not in d.final_est:
            out.append({"label": d.label, "path": d.path, "t_end": d.t_end, "elements": []})
            continue
        n = len(d.final_est[group])
        names = names if len(names) >= n else element_names(group, n)
        truth = d.truth_final if d.truth_final and group in d.truth_final else None
        # paper_table.rows wants every group; give it this one and placeholders for the rest
        est = {g: [0.0] * (3 if g == "phi2" else n) for g in ORDER}
        sig = {g: [1.0] * (3 if g == "phi2" else n) for g in ORDER}
        est[group], sig[group] = _si(group, d.final_est[group]), _si(group, d.final_sig[group])
        tr = {group: _si(group, truth[group])} if truth else None
        if tr and len(tr[group]) != n:
            tr = None
        elements = [r for r in paper_rows(est, sig, tr) if r["group"] == group]
        for r, e, s in zip(elements, d.final_est[group], d.final_sig[group], strict=True):
            r["estimate"], r["sigma"] = e, s  # exactly the packet's values (no round trip)
        out.append({"label": d.label, "path": d.path, "t_end": d.t_end, "elements": elements,
                    "flags": d.last.get("flags")})
    return names, out


def _gyro_failed(flags: Any, i: int) -> bool:
    """True when gyro i's GYRO_<A+i>_FAILED bit (radical_rt.contract.flags.GYRO_FAILED) is set."""
    return isinstance(flags, int) and i < len(GYRO_FAILED) and bool(flags & int(GYRO_FAILED[i]))


def table_markdown(data: list[ArchiveData], group: str) -> str:
    names, trows = table_rows(data, group)
    dg, unit = DIGITS[group], PAPER_UNITS[group]
    sym = GROUP_LABELS[group].split()[0]
    lines = [f"### {TITLES[group]}, {unit}", ""]
    head = ["Archive", "t_end [s]"]
    for nm in names:
        head += [f"{nm} {sym}", "σ"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in trows:
        cells = [r["label"], _fmt(r["t_end"], 2)]
        for i in range(len(names)):
            e = r["elements"][i] if i < len(r["elements"]) else None
            cells += [_fmt(e["estimate"], dg), _fmt(e["sigma"], dg + 1)] if e else ["—", "—"]
            if e and group != "phi2" and _gyro_failed(r.get("flags"), i):
                cells[-2] = f"FAILED {cells[-2]}"
        lines.append("| " + " | ".join(cells) + " |")
    if any(r["elements"] and "truth" in r["elements"][0] for r in trows):
        lines += ["", f"Truth (/truth/params at t_end) and error/σ, {unit}:", ""]
        head = ["Archive"]
        for nm in names:
            head += [f"{nm} truth", "err/σ"]
        lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for r in trows:
            if not (r["elements"] and "truth" in r["elements"][0]):
                continue
            cells = [r["label"]]
            for e in r["elements"]:
                cells += [_fmt(e["truth"], dg), _fmt(e["err_sigma"], 2)]
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def table_csv(data: list[ArchiveData], group: str) -> str:
    """CSV, one row per archive: label, archive, t_end_s, then per element estimate and sigma
    (and truth, err_sigma when any archive has truth); full precision, paper units in headers."""
    names, trows = table_rows(data, group)
    unit = PAPER_UNITS[group]
    has_truth = any(r["elements"] and "truth" in r["elements"][0] for r in trows)
    head = ["label", "archive", "t_end_s"]
    for nm in names:
        head += [f"{nm} estimate [{unit}]", f"{nm} sigma [{unit}]"]
    if has_truth:
        for nm in names:
            head += [f"{nm} truth [{unit}]", f"{nm} err/sigma"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head)
    for r in trows:
        el = r["elements"]
        row: list[Any] = [r["label"], r["path"], repr(float(r["t_end"]))]
        for i in range(len(names)):
            row += [repr(el[i]["estimate"]), repr(el[i]["sigma"])] if i < len(el) else ["", ""]
        if has_truth:
            for i in range(len(names)):
                ok = i < len(el) and "truth" in el[i]
                row += [repr(el[i]["truth"]), repr(el[i]["err_sigma"])] if ok else ["", ""]
        w.writerow(row)
    return buf.getvalue()


def table_files(group: str) -> tuple[str, str]:
    stem = f"table{TABLE_NUMBER[group]}_{group}"
    return stem + ".md", stem + ".csv"


# ------------------------------------------------------------------------------------ figures
GYRO_COLORS = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown",
               "tab:pink", "tab:gray"]


def _elapsed_min(t: np.ndarray, t0: float) -> tuple[np.ndarray, list[float]]:
    """Minutes since t0 with stream breaks (jumps > GAP_S) collapsed; break positions (min)."""
    if len(t) == 0:
        return t, []
    dt = np.diff(t, prepend=t[0])
    step = float(np.median(dt[1:])) if len(dt) > 1 else 0.0
    big = dt > max(GAP_S, 10 * step)
    dt = np.where(big, step, dt)
    x = (t[0] - t0 + np.cumsum(dt)) / 60.0
    return x, [float(v) for v in x[big]]


class _Clock:
    """Maps bus times of one archive to its figure x axis (elapsed minutes, breaks collapsed)."""

    def __init__(self, t: np.ndarray) -> None:
        self.t = t
        self.t0 = float(t[0]) if len(t) else 0.0
        self.x, self.breaks = _elapsed_min(t, self.t0)

    def __call__(self, ts: np.ndarray) -> np.ndarray:
        if len(self.t) < 2:
            return (ts - self.t0) / 60.0
        return np.interp(ts, self.t, self.x, left=np.nan, right=np.nan) if len(ts) else ts


def _mark_breaks(ax: Any, clock: _Clock) -> None:
    for b in clock.breaks:
        ax.axvline(b, color="k", lw=0.8, ls="--", alpha=0.6)


def _lines(ax: Any, x: np.ndarray, y: np.ndarray, names: list[str], *, log: bool = False,
           truth: tuple[np.ndarray, np.ndarray] | None = None, legend: bool = True) -> None:
    if not np.isfinite(y).any():
        ax.text(0.5, 0.5, "not in telemetry", ha="center", va="center", transform=ax.transAxes,
                color="0.4")
        return
    for i in range(y.shape[1]):
        c = GYRO_COLORS[i % len(GYRO_COLORS)]
        ax.plot(x, y[:, i], color=c, lw=1.1, label=names[i] if i < len(names) else str(i))
        if truth is not None and i < truth[1].shape[1]:
            ax.plot(truth[0], truth[1][:, i], color=c, lw=0.9, ls=":", alpha=0.9)
    if log:
        ax.set_yscale("log")
    ax.grid(True, which="both" if log else "major", alpha=0.3)
    if legend and y.shape[1] > 1:
        ax.legend(fontsize=7, ncol=min(y.shape[1], 4), loc="best", framealpha=0.7)


def _robust_ylim(ax: Any, x: np.ndarray, ys: list[Any]) -> None:
    """Estimates: leave out the first 5 % of the run when it dwarfs the rest (cold-start
    transients), so the converged part stays readable; the transient is then clipped.
    ys: arrays on x, or (x_i, y_i) pairs on their own x."""
    if len(x) < 20:
        return
    x0, x1 = x[0], x[0] + 0.05 * (x[-1] - x[0])
    full, tail = [], []
    for item in ys:
        xi, yi = item if isinstance(item, tuple) else (x, item)
        yi = np.asarray(yi).reshape(len(xi), -1)
        ok = np.isfinite(yi) & np.isfinite(np.asarray(xi))[:, None]
        full.append(yi[ok])
        late = ok & (np.asarray(xi) >= x1)[:, None] & (np.asarray(xi) >= x0)[:, None]
        tail.append(yi[late])
    f, t = np.concatenate(full), np.concatenate(tail)
    if not len(f) or not len(t):
        return
    lo, hi = float(t.min()), float(t.max())
    span_full, span = float(f.max() - f.min()), hi - lo
    if span > 0 and span_full > 4 * span:
        pad = 0.08 * span
        ax.set_ylim(lo - pad, hi + pad)
        ax.text(0.01, 0.03, "initial transient clipped", transform=ax.transAxes, ha="left",
                va="bottom", fontsize=7, color="0.4")


def _est_sigma_pair(axe: Any, axs: Any, d: ArchiveData, g: str, clock: _Clock, tag: str) -> None:
    names = element_names(g, d.est[g].shape[1])
    unit = PAPER_UNITS[g]
    tr = None
    if g in d.truth and len(d.truth_t):
        tr = (clock(d.truth_t), d.truth[g])
    _lines(axe, clock.x, d.est[g], names, truth=tr)
    _robust_ylim(axe, clock.x, [d.est[g]] + ([tr] if tr else []))
    axe.set_ylabel(f"{GROUP_LABELS[g]} [{unit}]")
    axe.set_title(f"({tag[0]}) {GROUP_LABELS[g]} estimates" + (" (dotted: truth)" if tr else ""),
                  fontsize=9, loc="left")
    sig = d.sig[g]
    pos = np.where(sig > 0, sig, np.nan)
    _lines(axs, clock.x, pos, names, log=bool(np.isfinite(pos).any()), legend=False)
    axs.set_ylabel(f"σ {GROUP_LABELS[g]} [{unit}]")
    axs.set_title(f"({tag[1]}) {GROUP_LABELS[g]} standard deviations", fontsize=9, loc="left")
    for ax in (axe, axs):
        _mark_breaks(ax, clock)


def _residual_panel(fig: Any, cell: Any, d: ArchiveData, kind: str, clock: _Clock, title: str) -> None:
    r = d.resid.get(kind)
    if r is None:
        ax = fig.add_subplot(cell)
        ax.text(0.5, 0.5, f"no {kind} residuals in telemetry", ha="center", va="center",
                transform=ax.transAxes, color="0.4")
        ax.set_title(title, fontsize=9, loc="left")
        ax.set_xlabel("time [min]")
        return
    m = r["innov"].shape[1]
    groups = [list(range(m))] if m != 3 else [[0, 1], [2]]  # cross-boresight x, y | boresight z
    sub = cell.subgridspec(len(groups), 1, hspace=0.08)
    labels = ["x", "y", "z"] if m == 3 else [f"p{i + 1}" for i in range(m)]
    axes: list[Any] = []
    for j, comps in enumerate(groups):
        ax = fig.add_subplot(sub[j], sharex=axes[0] if axes else None)
        axes.append(ax)
        for i in comps:
            c = GYRO_COLORS[i % len(GYRO_COLORS)]
            ax.plot(clock.x, r["innov"][:, i], ".", ms=1.6, color=c, alpha=0.6,
                    label=f"{labels[i]} residual")
            ax.plot(clock.x, r["sigma"][:, i], color=c, lw=0.9)
            ax.plot(clock.x, -r["sigma"][:, i], color=c, lw=0.9)
        _robust_ylim(ax, clock.x, [r["sigma"][:, comps], -r["sigma"][:, comps],
                                   r["innov"][:, comps]])
        ax.grid(True, alpha=0.3)
        ax.set_ylabel("arcsec")
        ax.legend(fontsize=7, loc="upper right", markerscale=4, ncol=len(comps), framealpha=0.7)
        _mark_breaks(ax, clock)
        if j < len(groups) - 1:
            ax.tick_params(labelbottom=False)
    axes[0].set_title(title + " and ±1σ bounds", fontsize=9, loc="left")
    axes[-1].set_xlabel("time [min]")


def _title(fig: Any, text: str, d: ArchiveData | None = None) -> None:
    sub = ""
    if d is not None:
        sub = f"\n{d.label}: {os.path.basename(d.path)}, {len(d.t)} of {d.n_packets} {d.topic} " \
              f"packets, t = {d.t[0]:.1f}…{d.t_end:.1f} s"
    fig.suptitle(text + sub, fontsize=10)


def figure4(d: ArchiveData, path: Path) -> None:
    import matplotlib.pyplot as plt

    clock = _Clock(d.t)
    fig = plt.figure(figsize=(12, 12.5))
    gs = fig.add_gridspec(3, 2, hspace=0.32, wspace=0.22, left=0.07, right=0.98, top=0.92,
                          bottom=0.05)
    ax = fig.add_subplot(gs[0, 0])
    att = np.where(d.att_sigma > 0, d.att_sigma, np.nan)
    _lines(ax, clock.x, att, ["x", "y", "z"], log=bool(np.isfinite(att).any()))
    ax.set_title("(a) attitude 1σ bounds", fontsize=9, loc="left")
    ax.set_ylabel("arcsec")
    ax.set_xlabel("time [min]")
    _mark_breaks(ax, clock)
    _residual_panel(fig, gs[0, 1], d, "parity", clock, "(b) null-space (parity) residual")
    _residual_panel(fig, gs[1, 0], d, "st1", clock, "(c) ST1 residuals")
    _residual_panel(fig, gs[1, 1], d, "st2", clock, "(d) ST2 residuals")
    if "phi2" in d.est:
        _component_axes(fig, gs[2, 0], d, "phi2", clock, "(e) ST2 alignment δa2 estimates")
        _sigma_axes(fig.add_subplot(gs[2, 1]), d, "phi2", clock,
                    "(f) ST2 alignment δa2 standard deviations")
    _title(fig, "Figure 4 analog: attitude, residuals and ST2 alignment", d)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def figure_groups(d: ArchiveData, groups: list[str], path: Path, title: str) -> None:
    import matplotlib.pyplot as plt

    groups = [g for g in groups if g in d.est]
    clock = _Clock(d.t)
    fig, axes = plt.subplots(max(len(groups), 1), 2, figsize=(12, 3.6 * max(len(groups), 1) + 0.8),
                             squeeze=False, sharex=True)
    tags = "abcdefghij"
    for i, g in enumerate(groups):
        _est_sigma_pair(axes[i, 0], axes[i, 1], d, g, clock, tags[2 * i:2 * i + 2])
    for a in axes[-1]:
        a.set_xlabel("time [min]")
    _title(fig, title, d)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _robust_range(x: np.ndarray, y: np.ndarray) -> tuple[float, float] | None:
    """Range of y after the first 5 % of the run (None if nothing finite)."""
    cut = x >= x[0] + 0.05 * (x[-1] - x[0]) if len(x) >= 20 else np.ones(len(x), bool)
    v = y[cut][np.isfinite(y[cut])]
    return (float(v.min()), float(v.max())) if len(v) else None


def _component_axes(fig: Any, cell: Any, d: ArchiveData, g: str, clock: _Clock, title: str,
                    temps: bool = False) -> list[Any]:
    """One stacked axes per element of group g (estimates, dotted truth), in a gridspec cell."""
    n = d.est[g].shape[1]
    names = element_names(g, n)
    sub = cell.subgridspec(n, 1, hspace=0.1)
    axes: list[Any] = []
    tr_x = clock(d.truth_t) if g in d.truth and len(d.truth_t) else None
    for i in range(n):
        ax = fig.add_subplot(sub[i], sharex=axes[0] if axes else None)
        axes.append(ax)
        c = GYRO_COLORS[i % len(GYRO_COLORS)]
        ax.plot(clock.x, d.est[g][:, i], color=c, lw=1.1, label=f"{names[i]} estimate")
        ys: list[Any] = [d.est[g][:, i]]
        if tr_x is not None:
            ax.plot(tr_x, d.truth[g][:, i], color="k", lw=0.9, ls=":", label="truth")
            ys.append((tr_x, d.truth[g][:, i]))
        _robust_ylim(ax, clock.x, ys)
        ax.grid(True, alpha=0.3)
        ax.set_ylabel(f"{names[i].split('-')[0]} [{PAPER_UNITS[g]}]", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.yaxis.get_major_formatter().set_useOffset(False)
        if temps and "st2_baseplate_C" in d.temps:
            tw = ax.twinx()
            tw.plot(clock(d.temp_t), d.temps["st2_baseplate_C"], color="0.45", lw=0.9, ls="-.",
                    label="ST2 baseplate °C")
            tw.tick_params(labelsize=6, colors="0.45")
            if i == 0:
                tw.set_ylabel("°C", fontsize=7, color="0.45")
                tw.legend(fontsize=6, loc="lower right", framealpha=0.7)
        ax.legend(fontsize=6, loc="upper right", framealpha=0.7, ncol=2)
        _mark_breaks(ax, clock)
        if i < n - 1:
            ax.tick_params(labelbottom=False)
    axes[0].set_title(title, fontsize=9, loc="left")
    axes[-1].set_xlabel("time [min]")
    return axes


def _sigma_axes(ax: Any, d: ArchiveData, g: str, clock: _Clock, title: str) -> None:
    sig = np.where(d.sig[g] > 0, d.sig[g], np.nan)
    _lines(ax, clock.x, sig, element_names(g, sig.shape[1]), log=bool(np.isfinite(sig).any()))
    ax.set_ylabel(f"σ {GROUP_LABELS[g]} [{PAPER_UNITS[g]}]")
    ax.set_title(title, fontsize=9, loc="left")
    ax.set_xlabel("time [min]")
    _mark_breaks(ax, clock)


def figure_side_by_side(data: list[ArchiveData], groups: list[str], path: Path, title: str,
                        temps: bool = False) -> None:
    """One column per archive; per group a row of estimates and a row of σ, same y limits
    across the columns (ST2 misalignment: one stacked axes per axis, with the ST2 baseplate
    temperature when ``temps``)."""
    import matplotlib.pyplot as plt

    groups = [g for g in groups if any(g in d.est for d in data)]
    heights: list[float] = []
    for g in groups:
        heights += [3.0 if g != "phi2" else 5.4, 2.6]
    ncol = len(data)
    fig = plt.figure(figsize=(5.4 * ncol + 0.6, sum(heights) + 1.2))
    gs = fig.add_gridspec(len(heights), ncol, height_ratios=heights, hspace=0.42, wspace=0.25,
                          left=0.07, right=0.95, top=1 - 0.9 / (sum(heights) + 1.2), bottom=0.05)
    est_axes: dict[str, list[list[Any]]] = {g: [] for g in groups}
    sig_axes: dict[str, list[Any]] = {g: [] for g in groups}
    for j, d in enumerate(data):
        clock = _Clock(d.t)
        for i, g in enumerate(groups):
            if g not in d.est:
                ax = fig.add_subplot(gs[2 * i, j])
                ax.text(0.5, 0.5, f"no {GROUP_LABELS[g]} in {d.label}", transform=ax.transAxes,
                        ha="center")
                continue
            if g == "phi2":
                axes = _component_axes(fig, gs[2 * i, j], d, g, clock,
                                       f"{d.label}: {GROUP_LABELS[g]} estimates", temps=temps)
            else:
                ax = fig.add_subplot(gs[2 * i, j])
                tr = (clock(d.truth_t), d.truth[g]) if g in d.truth and len(d.truth_t) else None
                _lines(ax, clock.x, d.est[g], element_names(g, d.est[g].shape[1]), truth=tr)
                ax.set_ylabel(f"{GROUP_LABELS[g]} [{PAPER_UNITS[g]}]")
                ax.set_title(f"{d.label}: {GROUP_LABELS[g]} estimates"
                             + (" (dotted: truth)" if tr else ""), fontsize=9, loc="left")
                ax.set_xlabel("time [min]")
                _mark_breaks(ax, clock)
                axes = [ax]
            est_axes[g].append([clock.x, d.est[g], axes])
            sa = fig.add_subplot(gs[2 * i + 1, j])
            _sigma_axes(sa, d, g, clock, f"{d.label}: {GROUP_LABELS[g]} standard deviations")
            sig_axes[g].append(sa)
    for g in groups:  # same y limits across the columns: robust for estimates, full for σ
        cols = est_axes[g]
        if not cols:
            continue
        per_axis = len(cols[0][2])
        for k in range(per_axis):
            rng = [r for x, y, _a in cols
                   if (r := _robust_range(x, y if per_axis == 1 else y[:, k:k + 1])) is not None]
            if rng:
                lo, hi = min(r[0] for r in rng), max(r[1] for r in rng)
                pad = 0.08 * (hi - lo) if hi > lo else max(abs(lo) * 0.01, 1e-9)
                for _x, _y, axes in cols:
                    axes[k].set_ylim(lo - pad, hi + pad)
        logs = [a for a in sig_axes[g] if a.get_yscale() == "log"]
        lims = [a.get_ylim() for a in logs]
        lims = [v for v in lims if v[0] > 0 and v[1] > v[0]]
        if lims:
            for a in logs:
                a.set_ylim(min(v[0] for v in lims), max(v[1] for v in lims))
    fig.suptitle(title + "\n" + "  |  ".join(f"{d.label}: {os.path.basename(d.path)}" for d in data),
                 fontsize=10)
    fig.savefig(path, dpi=90)
    plt.close(fig)


# ------------------------------------------------------------------------------------ html
_CSS = """body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.5em;
color:#222;max-width:1400px}table{border-collapse:collapse;margin:.4em 0 1.2em;font-size:13px}
th,td{border:1px solid #bbb;padding:3px 7px;text-align:right}th{background:#eef}
td:first-child,th:first-child{text-align:left}img{max-width:100%;border:1px solid #ccc;
margin:.3em 0 1.2em}h2{border-bottom:2px solid #99c;margin-top:1.6em}.note{color:#a50}
code{background:#f4f4f4;padding:0 3px}"""


def md_table_to_html(md: str) -> str:
    out, in_table = [], False
    for line in md.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if all(set(c) <= {"-"} for c in cells):
                continue
            tag = "th" if not in_table else "td"
            if not in_table:
                out.append("<table>")
                in_table = True
            out.append("<tr>" + "".join(f"<{tag}>{html.escape(c)}</{tag}>" for c in cells) + "</tr>")
        else:
            if in_table:
                out.append("</table>")
                in_table = False
            if line.startswith("### "):
                out.append(f"<h3>{html.escape(line[4:])}</h3>")
            elif line.strip():
                out.append(f"<p>{html.escape(line)}</p>")
    if in_table:
        out.append("</table>")
    return "\n".join(out)


def write_index(out: Path, data: list[ArchiveData], tables_md: dict[str, str],
                figures: list[tuple[str, str]]) -> None:
    h = ["<!DOCTYPE html><html><head><meta charset='utf-8'><title>RADICAL-RT report</title>",
         f"<style>{_CSS}</style></head><body>", "<h1>RADICAL-RT calibration report</h1>",
         "<h2>Archives</h2><table><tr><th>label</th><th>archive</th><th>source</th>"
         "<th>packets</th><th>t start [s]</th><th>t end [s]</th><th>mode</th><th>flags at end</th>"
         "<th>fault messages</th><th>truth</th></tr>"]
    for d in data:
        h.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in (
            d.label, d.path, d.topic, d.n_packets, f"{d.t[0]:.2f}", f"{d.t_end:.2f}",
            d.last.get("mode", "?"), flag_label(d.last.get("flags")), d.n_faults,
            "yes" if d.truth_final else "no")) + "</tr>")
    h.append("</table>")
    for d in data:
        for n in d.notes:
            h.append(f"<p class='note'>{html.escape(d.label)}: {html.escape(n)}</p>")
    h.append("<p>Units: " + ", ".join(f"{GROUP_LABELS[g]} [{u}]" for g, u in PAPER_UNITS.items())
             + ". Tables: last telemetry packet of each archive. Files: " + ", ".join(
                 f"<a href='{html.escape(md)}'>{html.escape(md)}</a> / "
                 f"<a href='{html.escape(cs)}'>{html.escape(cs)}</a>"
                 for md, cs in (table_files(g) for g in tables_md)) + ".</p>")
    h.append("<h2>Tables 2–7</h2>")
    for g in tables_md:
        h.append(md_table_to_html(tables_md[g]))
    h.append("<h2>Figures</h2>")
    for name, caption in figures:
        h.append(f"<h3>{html.escape(caption)}</h3><a href='{html.escape(name)}'>"
                 f"<img src='{html.escape(name)}' alt='{html.escape(caption)}'></a>")
    for d in data:
        if d.faults:
            h.append(f"<h2>Fault messages: {html.escape(d.label)} ({d.n_faults})</h2><table>"
                     "<tr><th>t [s]</th><th>flags</th><th>set</th><th>cleared</th></tr>")
            for f in d.faults[:50]:
                h.append("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in (
                    f"{float(f.get('t', math.nan)):.3f}", flag_label(f.get("flags")),
                    ", ".join(map(str, f.get("set") or [])),
                    ", ".join(map(str, f.get("cleared") or [])))) + "</tr>")
            h.append("</table>")
            if d.n_faults > 50:
                h.append(f"<p>… {d.n_faults - 50} more</p>")
    h.append(f"<p style='color:#888'>generated by radical report, "
             f"{time.strftime('%Y-%m-%d %H:%M:%S')}</p></body></html>")
    (out / "index.html").write_text("\n".join(h) + "\n", encoding="utf-8")


# ------------------------------------------------------------------------------------ driver
def make_labels(paths: list[str], labels: str | None) -> list[str]:
    if labels is not None:
        out = [s.strip() for s in labels.split(",")]
        if len(out) != len(paths) or not all(out):
            raise ReportError(f"--labels: {len(out)} label(s) for {len(paths)} archive(s); give "
                              "one non-empty label per archive, comma-separated")
        if len(set(out)) != len(out):
            raise ReportError("--labels: labels must be distinct")
        return out
    out = [Path(p).stem for p in paths]
    if len(set(out)) != len(out):
        out = [f"{i + 1}-{s}" for i, s in enumerate(out)]
    return out


def make_report(paths: list[str], out_dir: str | Path, labels: str | None = None,
                max_points: int = 1500, figures: bool = True) -> dict[str, Any]:
    """Write the report; returns {"tables": [...], "figures": [...], "index": path}."""
    labs = make_labels(paths, labels)
    data = [load_archive(p, lab, max_points) for p, lab in zip(paths, labs, strict=True)]
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ReportError(f"{out}: cannot create output directory: {e.strerror or e}") from None
    groups = [g for g in ORDER if any(g in d.final_est for d in data)]
    tables_md = {g: table_markdown(data, g) for g in groups}
    written = []
    for g in groups:
        md, cs = table_files(g)
        (out / md).write_text(tables_md[g], encoding="utf-8")
        (out / cs).write_text(table_csv(data, g), encoding="utf-8")
        written += [md, cs]
    (out / "tables.md").write_text("# RADICAL-RT calibration tables\n\n" + "\n".join(
        tables_md[g] for g in groups), encoding="utf-8")
    written.append("tables.md")
    figs: list[tuple[str, str]] = []
    if figures:
        import matplotlib

        matplotlib.use("Agg", force=True)
        for d in data:
            s = safe_name(d.label)
            figure4(d, out / f"fig4_{s}.png")
            figs.append((f"fig4_{s}.png", f"Figure 4 ({d.label}): attitude 1σ; parity, ST1, ST2 "
                         "residuals ±1σ; ST2 alignment estimates and σ"))
            figure_groups(d, ["b", "lam", "mu"], out / f"fig5_{s}.png",
                          "Figure 5 analog: gyro bias b, symmetric scale factor λ, asymmetric μ")
            figs.append((f"fig5_{s}.png", f"Figure 5 ({d.label}): b, λ, μ estimates and σ"))
            figure_groups(d, ["du", "dv"], out / f"fig6_{s}.png",
                          "Figure 6 analog: gyro axis misalignments δu, δv")
            figs.append((f"fig6_{s}.png", f"Figure 6 ({d.label}): δu, δv estimates and σ"))
        if len(data) >= 2:
            figure_side_by_side(data, ["du", "dv"], out / "fig7.png",
                                "Figure 7 analog: gyro axis misalignments δu, δv side by side")
            figs.append(("fig7.png", "Figure 7: δu, δv estimates and σ, archives side by side"))
            figure_side_by_side(data, ["phi2"], out / "fig8.png",
                                "Figure 8 analog: ST2 misalignment side by side", temps=True)
            figs.append(("fig8.png", "Figure 8: ST2 misalignment estimates and σ (with ST2 "
                         "baseplate temperature), archives side by side"))
        from monitors.report_ops import load_ops
        from monitors.report_ops_fig import figure_ops
        from monitors.report_ops_html import write_html

        ops = [load_ops(d.path, d.label, max_points) for d in data]
        for o in ops:
            figure_ops(o, out / f"ops_{safe_name(o.label)}.png")
            figs.append((f"ops_{safe_name(o.label)}.png", f"Operations ({o.label}): attitude, "
                         "rates, attitude error, latency, clock, NIS, flags; streams apart"))
        write_html(out, ops, "".join(md_table_to_html(tables_md[g]) for g in groups))
    write_index(out, data, tables_md, figs)
    from monitors.calreport import write_calibration_report

    cal = write_calibration_report(out, data, tables_md, figs)
    return {"tables": written, "figures": [f for f, _ in figs], "index": str(out / "index.html"),
            "calibration_report": str(cal),
            "archives": [{"label": d.label, "path": d.path, "packets": d.n_packets,
                          "decimated": len(d.t)} for d in data]}


#: the subcommand's line in `radical --help`
HELP = "paper-style tables and figures from an output archive"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="OUT.mcap",
                   help="output archives (radical process / radical record)")
    p.add_argument("-o", "--out", "--output", dest="out", required=True, metavar="DIR",
                   type=output_dir,
                   help="output directory (created)")
    p.add_argument("--labels", metavar="L1,L2", help="one label per archive (default: file stems)")
    p.add_argument("--max-points", type=int, default=1500, metavar="N",
                   help="telemetry packets per archive kept for the figures (default 1500)")
    p.add_argument("--no-figures", action="store_true", help="tables and index only")
    p.add_argument("--pdf", action="store_true", help="also calibration_report.pdf (headless "
                   "Chromium through Playwright; both optional)")


def run(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    if args.max_points < 2:
        print("radical report: --max-points must be ≥ 2", file=sys.stderr)
        return 2
    try:
        res = make_report(args.inputs, args.out, args.labels, args.max_points,
                          figures=not args.no_figures)
    except ReportError as e:
        print(f"radical report: {e}", file=sys.stderr)
        return 2
    print(f"radical report: {len(res['tables'])} table files, {len(res['figures'])} figures, "
          f"{res['index']}, {res['calibration_report']} ({time.perf_counter() - t0:.1f} s)")
    if args.pdf:
        from monitors.calreport import write_pdf

        try:
            print(f"radical report: {write_pdf(Path(res['calibration_report']))}")
        except RuntimeError as e:
            print(f"radical report: {e}", file=sys.stderr)
            return 2
    return 0
