"""The paced publication of archives' input channels over Zenoh (the work of `radical replay`).

:func:`check_inputs` opens every archive once and plans the replay (topics present, the window
[start, end) in log_time ns); :func:`replay` publishes the messages on ``radical/<vehicle>/<topic>``
with absolute deadlines on ``time.monotonic`` (message i due at ``wall_0 + (log_time_i −
log_time_0) / rate``), reads ahead in idle time (:class:`_ReadAhead`), ends each archive with an
end-of-stream marker and reports pacing [s] and delivery. Semantics and the command line:
:mod:`replayer.replay`; sessions: :mod:`replayer.sessions`.
"""

from __future__ import annotations

import collections
import functools
import gc
import logging
import math
import os
import sys
import threading
import time
import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import msgpack

from radical_rt.io.archive import INPUT_TOPICS, ArchiveReader, TruncatedArchiveWarning
from radical_rt.stream.eos import EOS_TOPIC, make_eos
from replayer.sessions import SLICE_S, ReplayError, check_vehicle

log = logging.getLogger("radical.replay")

ENCODING = "application/msgpack"  # Zenoh has no predefined msgpack encoding constant


@dataclass
class _Source:
    path: str
    topics: list[str]  # input topics present in the archive
    start_ns: int | None  # window [start_ns, end_ns) in log_time
    end_ns: int | None
    span_s: float  # window length in archive seconds (for the progress bar)


def _window(r: ArchiveReader, start: float | None, end: float | None) -> tuple[int | None, int | None, float]:
    t0 = r.start_ns or 0
    lo = t0 + round(start * 1e9) if start is not None else None
    hi = t0 + round(end * 1e9) if end is not None else None
    a = max(lo if lo is not None else t0, t0)
    b = min(hi if hi is not None else (r.end_ns or t0) + 1, (r.end_ns or t0) + 1)
    return lo, hi, max(b - a, 0) / 1e9


def check_inputs(paths: Sequence[str | os.PathLike[str]], start: float | None = None,
                 end: float | None = None, topics: Iterable[str] = INPUT_TOPICS,
                 ) -> tuple[list[_Source], list[str]]:
    """Open every archive once (fail fast, before any Zenoh session): the replay plan and the
    warnings (one line each, e.g. a truncated archive). Raises ReplayError / ArchiveError."""
    if not paths:
        raise ReplayError("no archive given")
    for name, v in (("--start", start), ("--end", end)):
        if v is not None and not (math.isfinite(v) and v >= 0):
            raise ReplayError(f"{name} must be a finite number of seconds >= 0, got {v!r}")
    if start is not None and end is not None and end <= start:
        raise ReplayError(f"--end ({end:g} s) must be after --start ({start:g} s)")
    wanted = list(topics)
    sources, notes = [], []
    for p in paths:
        path = os.fspath(p)
        if os.path.isdir(path):
            raise ReplayError(f"{path}: is a directory, not an MCAP archive")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with ArchiveReader(path) as r:
                present = [t for t in wanted if r.message_counts.get(t)]
                if not present:
                    raise ReplayError(f"{path}: no input channel to replay (none of "
                                      f"{', '.join(wanted)} has messages)")
                lo, hi, span = _window(r, start, end)
        notes += [" ".join(str(w.message).split()) for w in caught]
        sources.append(_Source(path, present, lo, hi, span))
    return sources, notes


def _wait_matching(pubs: dict[str, Any], keys: dict[str, str], timeout: float,
                   stop_event: threading.Event | None, strict: bool = True) -> float:
    """Poll until every publisher has a matching subscriber; returns the wait (s). After
    ``timeout`` s: ReplayError if ``strict``, else return (the caller counts what is missed)."""
    t0 = time.monotonic()
    while True:
        missing = [keys[t] for t, p in pubs.items() if not p.matching_status.matching]
        if not missing:
            return time.monotonic() - t0
        if stop_event is not None and stop_event.is_set():
            raise ReplayError("stopped while waiting for subscribers")
        if time.monotonic() - t0 >= timeout:
            if not strict:
                return time.monotonic() - t0
            raise ReplayError(f"no subscriber for {', '.join(missing)} within {timeout:.3g} s")
        time.sleep(0.01)


def _percentiles(late: list[float]) -> dict[str, float | int] | None:
    if not late:
        return None
    import numpy as np

    a = np.asarray(late)
    p50, p99 = np.percentile(a, [50, 99])
    return {"n": int(a.size), "p50_s": float(p50), "p99_s": float(p99), "max_s": float(a.max()),
            "mean_s": float(a.mean()), "late_1ms": int((a > 1e-3).sum())}


class _ReadAhead:
    """An archive's message iterator with a look-ahead buffer filled in idle time.

    Most pulls cost microseconds, but the one that reaches a new MCAP chunk decompresses and
    parses all of it (~20 ms for 1 MiB). :meth:`fill` pulls ahead only while the next deadline is
    further away than the slowest pull seen so far (+1 ms), so chunk loads happen in gaps between
    messages instead of delaying one. The first message is read at construction (opening and
    the first chunk load happen before the replay starts)."""

    MAX = 20000  # buffered messages (bounded memory)

    def __init__(self, it: Iterator[tuple[str, int, bytes]]) -> None:
        self._it, self.done = it, False
        self._buf: collections.deque[tuple[str, int, bytes]] = collections.deque()
        self.cost = self._pull()

    def _pull(self) -> float:
        t0 = time.perf_counter()
        item = next(self._it, None)
        if item is None:
            self.done = True
        else:
            self._buf.append(item)
        return time.perf_counter() - t0

    def pop(self) -> tuple[str, int, bytes] | None:
        if not self._buf and not self.done:
            self._pull()
        return self._buf.popleft() if self._buf else None

    def fill(self, until: float, cost: float) -> float:
        """Pull ahead while ``until`` (monotonic s) is more than ``cost`` + 1 ms away; returns
        the updated worst pull cost."""
        while not self.done and len(self._buf) < self.MAX \
                and until - time.monotonic() > cost + 0.001:
            cost = max(cost, self._pull())
        return cost


def _sleep_until(deadline: float, stop_event: threading.Event | None) -> bool:
    """Sleep until ``deadline`` (monotonic s) in slices; False if stopped first."""
    while True:
        if stop_event is not None and stop_event.is_set():
            return False
        left = deadline - time.monotonic()
        if left <= 0:
            return True
        time.sleep(min(left, SLICE_S))


def replay(paths: Sequence[str | os.PathLike[str]] | str | os.PathLike[str], vehicle: str,
           session: Any, rate: float | None = 1.0, start: float | None = None,
           end: float | None = None, progress: bool = False, *,
           wait_subscribers: float | None = None, settle: float = 0.0, gap: float = 0.0,
           stop_event: threading.Event | None = None,
           topics: Iterable[str] = INPUT_TOPICS, freeze_gc: bool = True) -> dict[str, Any]:
    """Publish the input channels of ``paths`` (in sequence) on ``radical/<vehicle>/<topic>``.

    ``rate``: archive seconds per wall second (1 = real time); ``None`` = as fast as the
    subscribers keep up (BLOCK congestion control). ``start``/``end``: window in seconds from each
    archive's start. ``wait_subscribers``: first wait up to that many seconds until every
    publisher has a matching subscriber (ReplayError if not). ``settle`` (used when
    ``wait_subscribers`` is None): the same wait, at most that many seconds, without the error —
    a node known to be alive has subscribers whose routes may reach a new session a moment after
    its token; publishers still unmatched after it count their puts as not delivered.
    ``gap``: wall seconds between two archives (paced mode). ``stop_event``: set it to stop early. ``freeze_gc`` (paced mode): one
    garbage collection before the first message, then ``gc.freeze()`` until the end, so that no
    full collection of a large heap (tens of ms) delays a message.

    Returns ``counts`` (messages per MCAP topic), ``messages``, ``files``, ``wall_s`` (first to
    last publish), ``archive_s`` (archive time replayed), ``achieved_rate`` (archive_s / wall_s),
    ``rate``, ``stopped``, and ``pacing`` (None with ``rate=None``): for each message the actual
    publish time minus its scheduled time (s): ``n``, ``p50_s``, ``p99_s``, ``max_s``,
    ``mean_s``, ``late_1ms`` (messages more than 1 ms late).
    """
    import zenoh
    from tqdm import tqdm

    check_vehicle(vehicle)
    if rate is not None and not (math.isfinite(rate) and rate > 0):
        raise ReplayError(f"rate must be a finite number > 0, got {rate!r}")
    if not (math.isfinite(gap) and gap >= 0):
        raise ReplayError(f"gap must be >= 0 s, got {gap!r}")
    path_list = [paths] if isinstance(paths, str | os.PathLike) else list(paths)
    sources, notes = check_inputs(path_list, start, end, topics)
    for n in notes:  # once per archive (re-opening below is silent)
        warnings.warn(n, TruncatedArchiveWarning, stacklevel=2)

    used = [t for t in INPUT_TOPICS if any(t in s.topics for s in sources)]
    used += sorted({t for s in sources for t in s.topics} - set(used))
    keys = {t: f"radical/{vehicle}/{t.lstrip('/')}" for t in used}
    pubs = {t: session.declare_publisher(k, encoding=zenoh.Encoding(ENCODING),
                                         congestion_control=zenoh.CongestionControl.BLOCK)
            for t, k in keys.items()}
    counts = dict.fromkeys(used, 0)
    # delivery: messages put while a publisher had no matching subscriber (nobody received them)
    # and puts that failed; the end-of-stream markers sent (radical_rt.stream.eos)
    matched = {t: bool(p.matching_status.matching) for t, p in pubs.items()}
    listeners = [p.declare_matching_listener(functools.partial(_on_matching, matched, t))
                 for t, p in pubs.items() if hasattr(p, "declare_matching_listener")]
    unmatched, failed = dict.fromkeys(used, 0), dict.fromkeys(used, 0)
    eos_pub = session.declare_publisher(f"radical/{vehicle}/{EOS_TOPIC}",
                                        encoding=zenoh.Encoding(ENCODING),
                                        congestion_control=zenoh.CongestionControl.BLOCK)
    eos_sent = 0
    late: list[float] = []
    archive_s, stopped = 0.0, False
    first_pub = last_pub = None
    total = sum(s.span_s for s in sources)
    bar = tqdm(total=round(total, 1), unit="s", desc=f"replay {vehicle}", file=sys.stderr,
               disable=not progress, leave=False, dynamic_ncols=True,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s archive "
                          "[{elapsed}<{remaining}{postfix}]")
    readers: list[ArchiveReader] = []
    frozen = False
    try:
        # Open every archive and read its first message now: the switch from one archive to the
        # next then costs no file opening or chunk decompression at a deadline.
        streams: list[_ReadAhead] = []
        for src in sources:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", TruncatedArchiveWarning)
                readers.append(ArchiveReader(src.path))
            streams.append(_ReadAhead(readers[-1].iter_raw(src.topics, src.start_ns, src.end_ns)))
        pull_cost = max(s.cost for s in streams)  # the first pull loaded a chunk: a fair bound
        if wait_subscribers is not None or settle > 0:
            strict = wait_subscribers is not None
            _wait_matching(pubs, keys, wait_subscribers if strict else settle, stop_event, strict)
            # the polled status is current now; the listener's callback (another thread) may
            # come later, and a put before it would be counted as undelivered
            for t, p in pubs.items():
                matched[t] = bool(p.matching_status.matching)
        if rate is not None and freeze_gc:
            # A full (generation 2) collection scans every object of the process: tens of ms in a
            # large process (35 ms for 92k objects under pytest). Collect once now and move what
            # exists into the permanent generation, so collections during the replay only scan
            # what it allocates.
            gc.collect()
            gc.freeze()
            frozen = True
        base: float | None = None  # wall time (monotonic) at which the next archive starts
        for i, src in enumerate(sources):
            if rate is None and i and gap and not _sleep_until(time.monotonic() + gap, stop_event):
                stopped = True
                break
            t_ref = t_last = None
            src_counts = dict.fromkeys(used, 0)
            shown, next_post = 0.0, 0.0
            stream = streams[i]
            while (item := stream.pop()) is not None:
                topic, t_ns, data = item
                if t_ref is None:
                    t_ref = t_ns
                    if base is None:
                        base = time.monotonic()
                if rate is not None and base is not None:
                    due = base + (t_ns - t_ref) * 1e-9 / rate
                    pull_cost = stream.fill(due, pull_cost)  # read ahead in the idle time
                    if not _sleep_until(due, stop_event):
                        stopped = True
                        break
                    now = time.monotonic()
                    late.append(now - due)
                elif stop_event is not None and stop_event.is_set():
                    stopped = True
                    break
                else:
                    now = time.monotonic()
                try:
                    pubs[topic].put(data)
                except Exception as exc:  # a closed session: counted, reported, not fatal here
                    failed[topic] += 1
                    if failed[topic] == 1:
                        log.warning("replay: put on %s failed: %s", keys[topic], exc)
                    continue
                if not matched[topic]:  # the listener's thread may lag: ask the session
                    matched[topic] = bool(pubs[topic].matching_status.matching)
                    unmatched[topic] += not matched[topic]
                counts[topic] += 1
                src_counts[topic] += 1
                t_last = t_ns
                if first_pub is None:
                    first_pub = now
                last_pub = now
                if progress:
                    pos = (t_ns - t_ref) * 1e-9
                    bar.update(pos - shown)
                    shown = pos
                    if now >= next_post:
                        wall = now - first_pub
                        speed = f", {(archive_s + pos) / wall:.2f}x" if wall > 0.2 else ""
                        bar.set_postfix_str(f"t_bus {t_ns * 1e-9:.2f} s{speed}",
                                            refresh=False)
                        next_post = now + 0.25
            if t_ref is not None and t_last is not None:
                span = (t_last - t_ref) * 1e-9
                archive_s += span
                if rate is not None and base is not None:
                    base = base + span / rate + gap
            bar.update(max(src.span_s - shown, 0.0))
            if stopped:
                break
            if t_ref is not None:  # the end-of-stream marker, behind the stream's last message
                last = i == len(sources) - 1
                eos = make_eos(src_counts, "none" if last else "warm", source=src.path,
                               t_bus=(t_last or t_ref) * 1e-9)
                try:
                    eos_pub.put(msgpack.packb(eos))
                    eos_sent += 1
                except Exception as exc:
                    log.warning("replay: end-of-stream marker not sent: %s", exc)
    finally:
        if frozen:
            gc.unfreeze()
        bar.close()
        for r in readers:
            r.close()
        for lst in listeners:
            try:
                lst.undeclare()
            except Exception:  # session already closed
                pass
        for p in [*pubs.values(), eos_pub]:
            try:
                p.undeclare()
            except Exception:  # session already closed
                pass
    wall = (last_pub - first_pub) if first_pub is not None and last_pub is not None else 0.0
    return {"counts": counts, "messages": sum(counts.values()),
            "files": [s.path for s in sources], "wall_s": wall, "archive_s": archive_s,
            "achieved_rate": archive_s / wall if wall > 0 else None, "rate": rate,
            "stopped": stopped, "pacing": _percentiles(late) if rate is not None else None,
            "unmatched": unmatched, "failed": failed, "eos_sent": eos_sent,
            "not_delivered": sum(unmatched.values()) + sum(failed.values())}


def _on_matching(matched: dict[str, bool], topic: str, status: Any) -> None:
    matched[topic] = bool(status.matching)
