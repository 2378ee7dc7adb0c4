"""Measurements of the clock robustness matrix (issue 17) on one synthesized archive and the
output of ``radical process`` on it. SI inside (s), µs / ppm / ms only in the returned rows.

* :func:`clock_run`: :class:`radical_rt.clock.siru_clock.SiruClock` (the default configuration, as the batch
  engine builds it) streamed over the archive's ``/siru`` messages; per message its bus time
  and ``locked``; per released sample its time, tag (``clock.last_tt``) and whether the clock
  was locked before and after its message; the frequency estimate every 10 s.
* :func:`lock_times`: time to lock per segment of the run (segments begin at the run start and
  at each injected discontinuity: a counter reset or the end of a data gap).
* :func:`timeline`: reconstructed sample times against ``/truth/siru_time`` (matched by tag, in
  order), with the constant offset removed, and the jitter's own contribution: the RMS
  deviation of the true sample times from their own best straight line over the sample index,
  which no line estimate can remove.
* :func:`flag_seconds`: seconds each fault flag was raised, from the output's ``/fault``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import msgpack
import numpy as np

from perf.bench_clock import match_truth, read_archive
from radical_rt.clock.clock_config import ClockConfig
from radical_rt.clock.siru_clock import SiruClock
from radical_rt.contract.flags import Flag
from radical_rt.io.archive import ArchiveReader

FREQ_EVERY_MSGS = 100  # frequency estimate sampled every 100 /siru messages (10 s)
EVENT_PRE_S, EVENT_POST_S = 1.0, 10.0  # CLOCK_ANOMALY allowed around an injected discontinuity


def read_input(path: str | Path) -> dict:
    """``/siru`` messages as column arrays, truth sample tags and times, and the metadata truth
    (``truth_counts``, ``siru_timing``)."""
    data = read_archive(path)
    data["timing"] = json.loads(data.pop("meta")["siru_timing"])
    return data


def clock_run(msgs: list) -> dict:
    """Stream the reads through a fresh default clock (see the module docstring)."""
    clock = SiruClock(ClockConfig())
    t_msg, lk_msg, ts, tts, lks, f_t, f_ppm = [], [], [], [], [], [], []
    for i, m in enumerate(msgs):
        before = clock.locked
        b = clock.push(*m)
        after = clock.locked
        t_msg.append(float(m[0][-1]))
        lk_msg.append(after)
        ts.append(b.t)
        tts.append(clock.last_tt)
        lks.append(np.full(len(b.t), before and after))
        if i % FREQ_EVERY_MSGS == FREQ_EVERY_MSGS - 1:
            f_t.append(t_msg[-1])
            f_ppm.append(float(clock.telemetry()["freq_offset_ppm"]))
    b = clock.flush()
    ts.append(b.t)
    tts.append(clock.last_tt)
    lks.append(np.zeros(len(b.t), bool))
    tel = clock.telemetry()
    return {"t_msg": np.asarray(t_msg), "locked_msg": np.asarray(lk_msg, bool),
            "t": np.concatenate(ts), "tt": np.concatenate(tts), "locked": np.concatenate(lks),
            "freq_t": np.asarray(f_t), "freq_ppm": np.asarray(f_ppm), "telemetry": tel,
            "counters": clock.counters}


def lock_times(t_msg: np.ndarray, locked: np.ndarray, t0: float, t_end: float,
               events: list[float]) -> list[dict]:
    """Per segment [start, end) of the run split at ``events`` (s): ``delay_s``, the time from
    the segment's start to the first message from which the clock stays locked to the
    segment's end (None if it is not locked at the end), and the segment's length."""
    edges = [t0, *[e for e in events if t0 < e < t_end], t_end]
    out = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        sel = (t_msg >= a) & (t_msg < b)
        lk, tm = locked[sel], t_msg[sel]
        delay = None
        if lk.size and lk[-1]:
            bad = np.flatnonzero(~lk)
            delay = float((tm[0] if bad.size == 0 else tm[bad[-1] + 1]) - a)
        out.append({"start_s": a, "length_s": b - a, "delay_s": delay})
    return out


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if x.size else math.nan


def timeline(run: dict, tt_true: np.ndarray, t_true: np.ndarray) -> dict:
    """Reconstructed time-line errors, µs (see the module docstring): over the samples released
    while locked (``locked_*``) and over all (``all_*``); ``offset_us`` the removed mean;
    ``jitter_us`` the truth's own RMS deviation from its best line over the same samples."""
    real = run["tt"] >= 0
    idx = match_truth(run["tt"][real], tt_true)
    ok = idx >= 0
    err = run["t"][real][ok] - t_true[idx[ok]]
    lk = run["locked"][real][ok]
    out = {"n_samples": int(err.size), "n_unmatched": int((~ok).sum()),
           "locked_fraction": float(lk.mean()) if lk.size else 0.0,
           "all_rms_us": 1e6 * _rms(err - err.mean()) if err.size else None}
    if lk.sum() < 10:
        return {**out, "offset_us": None, "locked_rms_us": None, "locked_max_us": None,
                "jitter_us": None}
    e = err[lk]
    off = float(e.mean())
    k = idx[ok][lk].astype(float)
    tr = t_true[idx[ok][lk]]
    coef = np.polyfit(k - k.mean(), tr, 1)
    resid = tr - np.polyval(coef, k - k.mean())
    return {**out, "offset_us": 1e6 * off, "locked_rms_us": 1e6 * _rms(e - off),
            "locked_max_us": 1e6 * float(np.max(np.abs(e - off))), "jitter_us": 1e6 * _rms(resid)}


def freq_after_lock(run: dict, eps_ppm: float, t_lock: float | None) -> dict:
    """Frequency error (ppm) at the end and its largest |value| after the lock time."""
    final = float(run["telemetry"]["freq_offset_ppm"]) - eps_ppm
    after = run["freq_ppm"][run["freq_t"] >= t_lock] - eps_ppm if t_lock is not None else []
    return {"freq_est_ppm": final + eps_ppm, "freq_err_ppm": final,
            "freq_err_max_after_lock_ppm": float(np.max(np.abs(after))) if len(after) else None,
            "freq_range_ppm": run["telemetry"].get("freq_offset_range_ppm")}


def flag_seconds(out_path: str | Path, t_end: float) -> tuple[dict[str, float], dict[str, int],
                                                                list[tuple[float, float, int]]]:
    """Seconds each flag was raised and how often it rose, from the ``/fault`` messages of an
    output archive (each carries the new ``flags`` at its time ``t``); and the intervals
    (start, end, flags) between changes."""
    changes: list[tuple[float, int]] = []
    with ArchiveReader(out_path) as r:
        for _topic, _ns, data in r.iter_raw(topics=["/fault"]):
            m = msgpack.unpackb(data, raw=False)
            changes.append((float(m["t"]), int(m["flags"])))
    names = {f: str(f.name) for f in Flag}
    secs = dict.fromkeys(names.values(), 0.0)
    rises = dict.fromkeys(names.values(), 0)
    spans, prev = [], 0
    for i, (t, fl) in enumerate(changes):
        t_next = changes[i + 1][0] if i + 1 < len(changes) else t_end
        spans.append((t, max(t_next, t), fl))
        for f in Flag:
            if fl & f:
                secs[names[f]] += max(t_next - t, 0.0)
                if not prev & f:
                    rises[names[f]] += 1
        prev = fl
    return secs, rises, spans


def unexpected_anomaly_s(spans, events: list[tuple[float, float]]) -> float:
    """Seconds of CLOCK_ANOMALY outside the windows [a − 1 s, b + 10 s] of the injected
    discontinuities (a, b) (a counter reset: a = b; a data gap: its start and end)."""
    total = 0.0
    for t0, t1, fl in spans:
        if not fl & Flag.CLOCK_ANOMALY:
            continue
        cuts = [(t0, t1)]
        for a, b in events:
            lo, hi = a - EVENT_PRE_S, b + EVENT_POST_S
            cuts = [piece for s, e in cuts for piece in ((s, min(e, lo)), (max(s, hi), e))
                    if piece[1] > piece[0]]
        total += sum(e - s for s, e in cuts)
    return total


def param_z(summary: dict, archive: str | Path) -> dict:
    """Worst |error|/σ of the 23 parameters against the archive's last /truth/params."""
    from monitors.compare import load_truth, z_scores

    z = [v for vs in z_scores(summary, load_truth(archive)).values() for v in vs]
    bad = [abs(v) for v in z if math.isfinite(v)]
    return {"n_params": len(z), "max_abs_z": max(bad) if bad else None,
            "n_within_3sigma": int(sum(b <= 3.0 for b in bad))}


def true_wraps(t_true: np.ndarray, lead_s: float, bus_period_s: float, t_start_s: float,
               sep_s: float) -> list[float]:
    """True times [s] of the sawtooth wraps: where a sample time, moved by the mean read lead,
    crosses a bus tick (``(t_k + lead − t_start) mod T_bus`` jumps by more than T_bus/2). The
    sample jitter can make one crossing flicker: crossings closer than ``sep_s`` count once."""
    t = np.sort(np.asarray(t_true, float))
    u = np.mod(t + lead_s - t_start_s, bus_period_s)
    times: list[float] = []
    for x in t[1:][np.abs(np.diff(u)) > bus_period_s / 2]:
        if not times or x - times[-1] > sep_s:
            times.append(float(x))
    return times
