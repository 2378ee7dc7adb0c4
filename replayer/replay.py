"""Publish an archive's input channels over Zenoh, paced by their bus time (`radical replay`).

The input channels of each archive (``/siru``, ``/st1``, ``/st2``, ``/temp``; CONTRACT §4) are
published on ``radical/<vehicle>/<topic>`` (§2) in log_time order with the MCAP payloads unchanged
(the msgpack bytes as stored). Pacing uses absolute deadlines on ``time.monotonic``: message i is
due at ``wall_0 + (log_time_i − log_time_0) / rate``, so a late message never shifts the ones
after it (no drift). ``--fast`` publishes as fast as the subscribers keep up: every publisher uses
``CongestionControl.BLOCK`` (always, not only with ``--fast``), so a slow subscriber slows the
replay down instead of losing samples.

Several archives are replayed in sequence as disjoint streams: each keeps its own time line, the
first message of the next archive is due when the previous archive's last one was (plus ``--gap``
wall seconds). ``--start``/``--end`` are seconds relative to each archive's start (its first
message on any channel), the window is [start, end).

Examples::

    radical replay run.mcap --vehicle messenger                  # real time, to the default node
    radical replay run.mcap --vehicle messenger --rate 10 --wait-node 30
    radical replay a.mcap b.mcap --vehicle messenger --fast --connect tcp/127.0.0.1:7448
    radical replay run.mcap --vehicle messenger --start 600 --end 1200 --no-progress

Sessions: with ``--connect`` only (or neither option: the node's default endpoint) the replayer
is a Zenoh client of that endpoint (the node, a peer, routes between its clients, e.g. to a
connected ``radical record``); with ``--listen`` it is a peer. A client cannot open before its
endpoint is up: it fails at once, or retries for the ``--wait-node``/``--wait-subscribers`` time.

Each archive ends with an end-of-stream marker on ``radical/<vehicle>/eos`` (docs/replay_record.md)
that carries the messages sent per topic; messages put while a publisher had no matching
subscriber, or whose put failed, are reported as not delivered.

A node serving ``--vehicle`` is required: replay waits up to ``--wait-node`` (default 10 s) for
its liveliness token ``radical/<vehicle>/alive/filter`` and fails with exit status 1, naming the
vehicles the nodes there do serve, if none appears. ``--no-wait-node`` (or ``--wait-subscribers``,
e.g. for a recorder alone) publishes without that check.

Exit status: 0 done, 1 run-time failure (no node within the timeout, Zenoh error), 2 bad input
(missing or unreadable archive, no input channel, bad option), 3 done but some messages were
not delivered, 130 interrupted.
"""

from __future__ import annotations

import argparse
import collections
import functools
import gc
import json
import logging
import math
import os
import re
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import msgpack

from radical_rt.io.archive import INPUT_TOPICS, ArchiveError, ArchiveReader, TruncatedArchiveWarning
from radical_rt.stream.eos import EOS_TOPIC, make_eos

log = logging.getLogger("radical.replay")

VEHICLE_RE = re.compile(r"^[a-z0-9_-]+$")
ENCODING = "application/msgpack"  # Zenoh has no predefined msgpack encoding constant
DEFAULT_WAIT_S = 10.0
_SLICE_S = 0.2  # longest uninterrupted sleep: a stop request is seen within this


class ReplayError(Exception):
    """A replay cannot start or go on; ``str(e)`` is one line."""


def node_token_key(vehicle: str) -> str:
    """The filter node's liveliness token for ``vehicle`` (CONTRACT §2)."""
    return f"radical/{vehicle}/alive/filter"


def check_vehicle(vehicle: str) -> str:
    if not isinstance(vehicle, str) or not VEHICLE_RE.match(vehicle):
        raise ReplayError(f"vehicle {vehicle!r} must match [a-z0-9_-]+")
    return vehicle


# --------------------------------------------------------------------------------- archives
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


# ------------------------------------------------------------------------------------ zenoh
def tool_config(listen: str | None, connect: str | None, role: str,
                config_file: str | None = None) -> tuple[Any, str, str]:
    """``(zenoh.Config, mode, description)`` for a tool (replay, record).

    Endpoints are ``zconfig.endpoints`` (neither option: connect to the node's default). A tool
    that listens is a peer; a tool that only connects is a **client** of that endpoint: the node
    is a peer, and a peer routes for its clients but does not relay between two peers that both
    only connect to it, so two peer tools (``radical replay`` → ``radical record``) would not see
    each other through the node."""
    from radical_rt.io import zconfig

    lst, con = zconfig.endpoints(listen, connect, role=role)
    mode = "peer" if lst else "client"
    cfg = zconfig.make_config(mode, listen=lst, connect=con, config_file=config_file)
    where = ", ".join([f"listening on {e}" for e in lst] + [f"connecting to {e}" for e in con])
    return cfg, mode, where


def open_session(cfg: Any, mode: str, deadline: float | None = None,
                 stop_event: threading.Event | None = None,
                 on_retry: Callable[[str], None] | None = None) -> Any:
    """``zenoh.open(cfg)``. A client cannot open before its endpoint is up: it retries every
    0.2 s until ``deadline`` (monotonic s; None: one attempt; ``math.inf``: until
    ``stop_event``), calling ``on_retry(error)`` after each failure. ReplayError when it gives up."""
    import zenoh

    while True:
        try:
            return zenoh.open(cfg)
        except Exception as e:  # zenoh.ZError
            err = " ".join(str(e).split(" at /")[0].split())
            if mode != "client" or deadline is None:
                raise ReplayError(f"cannot open a Zenoh {mode} session: {err}") from None
            if on_retry is not None:
                on_retry(err)
            if stop_event is not None and stop_event.is_set():
                raise ReplayError(f"stopped before connecting ({err})") from None
            if time.monotonic() + 0.2 > deadline:
                raise ReplayError(f"cannot connect: {err}") from None
            if stop_event is not None:
                stop_event.wait(0.2)
            else:
                time.sleep(0.2)


def wait_for_node(session: Any, vehicle: str, timeout: float,
                  stop_event: threading.Event | None = None) -> float:
    """Block until the node's liveliness token ``radical/<vehicle>/alive/filter`` is alive
    (already present or appearing later). Returns the wait (s); ReplayError on timeout."""
    import zenoh

    key, seen = node_token_key(check_vehicle(vehicle)), threading.Event()

    def on_token(sample: Any) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            seen.set()

    t0 = time.monotonic()
    sub = session.liveliness().declare_subscriber(key, on_token, history=True)
    try:
        while not seen.wait(min(_SLICE_S, max(t0 + timeout - time.monotonic(), 0.0))):
            if stop_event is not None and stop_event.is_set():
                raise ReplayError("stopped while waiting for the node")
            if time.monotonic() >= t0 + timeout:
                raise ReplayError(f"no filter node for vehicle {vehicle!r}: liveliness token "
                                  f"{key} not seen within {timeout:g} s")
    finally:
        sub.undeclare()
    return time.monotonic() - t0


def served_vehicles(session: Any, timeout: float = 1.0) -> list[str]:
    """Vehicles whose node liveliness token ``radical/<V>/alive/filter`` is alive now (sorted;
    [] if the query fails)."""
    try:
        replies = session.liveliness().get("radical/*/alive/filter", timeout=timeout)
        keys = {str(r.ok.key_expr) for r in replies if r.ok is not None}
    except Exception:  # noqa: BLE001 - a diagnostic only
        return []
    return sorted(k.split("/")[1] for k in keys if k.count("/") == 3)


def _wait_matching(pubs: dict[str, Any], keys: dict[str, str], timeout: float,
                   stop_event: threading.Event | None) -> float:
    t0 = time.monotonic()
    while True:
        missing = [keys[t] for t, p in pubs.items() if not p.matching_status.matching]
        if not missing:
            return time.monotonic() - t0
        if stop_event is not None and stop_event.is_set():
            raise ReplayError("stopped while waiting for subscribers")
        if time.monotonic() - t0 >= timeout:
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
        time.sleep(min(left, _SLICE_S))


def replay(paths: Sequence[str | os.PathLike[str]] | str | os.PathLike[str], vehicle: str,
           session: Any, rate: float | None = 1.0, start: float | None = None,
           end: float | None = None, progress: bool = False, *,
           wait_subscribers: float | None = None, gap: float = 0.0,
           stop_event: threading.Event | None = None,
           topics: Iterable[str] = INPUT_TOPICS, freeze_gc: bool = True) -> dict[str, Any]:
    """Publish the input channels of ``paths`` (in sequence) on ``radical/<vehicle>/<topic>``.

    ``rate``: archive seconds per wall second (1 = real time); ``None`` = as fast as the
    subscribers keep up (BLOCK congestion control). ``start``/``end``: window in seconds from each
    archive's start. ``wait_subscribers``: first wait up to that many seconds until every
    publisher has a matching subscriber (ReplayError if not). ``gap``: wall seconds between two
    archives (paced mode). ``stop_event``: set it to stop early. ``freeze_gc`` (paced mode): one
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
        if wait_subscribers is not None:
            _wait_matching(pubs, keys, wait_subscribers, stop_event)
            # the polled status is matched now; the listener's callback (another thread) may
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
                if not matched[topic]:
                    unmatched[topic] += 1
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


# -------------------------------------------------------------------------------------- CLI
def _wait_arg(text: str) -> float:
    v = float(text)
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"timeout must be > 0 s, got {text!r}")
    return v


def _rate_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid rate {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"rate must be > 0, got {text!r}")
    return v


#: the subcommand's line in `radical --help`
HELP = "publish an archive's input channels over Zenoh"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="IN.mcap",
                   help="archive(s), replayed in sequence as disjoint streams")
    p.add_argument("--vehicle", required=True, help="vehicle name ([a-z0-9_-]+): keys "
                   "radical/<vehicle>/{siru,st1,st2,temp}")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=_rate_arg, default=1.0, metavar="X",
                      help="archive seconds per wall second (default 1: real time)")
    pace.add_argument("--fast", action="store_true",
                      help="as fast as the subscribers keep up (no sample dropped)")
    p.add_argument("--start", type=float, default=None, metavar="S",
                   help="start S seconds after each archive's start")
    p.add_argument("--end", type=float, default=None, metavar="S",
                   help="stop S seconds after each archive's start (exclusive)")
    p.add_argument("--gap", type=float, default=0.0, metavar="S",
                   help="wall seconds between two archives (default 0)")
    p.add_argument("--listen", metavar="EP", help="listen on EP (tcp/127.0.0.1:PORT)")
    p.add_argument("--connect", metavar="EP", help="connect to EP (default: the node's "
                   "default endpoint tcp/127.0.0.1:7448)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="Zenoh JSON5 file loaded first (endpoints and scouting still enforced)")
    p.add_argument("--wait-node", nargs="?", type=_wait_arg, const=DEFAULT_WAIT_S, default=None,
                   metavar="TIMEOUT", help="wait up to TIMEOUT (default 10 s) for the node's "
                   "liveliness token and for subscribers on every published key before starting. "
                   "Without this option replay still requires a node serving --vehicle: it waits "
                   "up to 10 s for its token and fails (exit 1) if none appears")
    p.add_argument("--no-wait-node", action="store_true",
                   help="publish without checking that a node serves --vehicle (e.g. to a "
                        "recorder only; --wait-subscribers also skips the check)")
    p.add_argument("--wait-subscribers", nargs="?", type=_wait_arg, const=DEFAULT_WAIT_S,
                   default=None, metavar="TIMEOUT", help="wait (default 10 s) for subscribers on "
                   "every published key (e.g. a recorder), without requiring a node")
    p.add_argument("--linger", type=float, default=2.0, metavar="S",
                   help="keep the session open S seconds after the last message so queued "
                        "messages are delivered (default 2)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")


def _err(msg: str) -> None:
    print(f"radical replay: error: {' '.join(str(msg).split())}", file=sys.stderr)


def _summary_line(res: dict[str, Any]) -> str:
    per = ", ".join(f"{t.lstrip('/')} {n}" for t, n in res["counts"].items())
    rate = res["achieved_rate"]
    text = (f"replayed {res['messages']} messages ({per}) from {len(res['files'])} archive(s): "
            f"{res['archive_s']:.2f} s of archive in {res['wall_s']:.2f} s"
            + (f" ({rate:.2f}x)" if rate else ""))
    pc = res["pacing"]
    if pc:
        text += (f"; pacing error p50 {pc['p50_s'] * 1e3:.3f} ms, p99 {pc['p99_s'] * 1e3:.3f} ms, "
                 f"max {pc['max_s'] * 1e3:.3f} ms")
    nd = res.get("not_delivered", 0)
    if nd:
        lost = {t.lstrip("/"): res["unmatched"][t] + res["failed"][t] for t in res["unmatched"]
                if res["unmatched"][t] + res["failed"][t]}
        text += f"; NOT DELIVERED {nd} ({lost}: no subscriber or failed put)"
    return text + (" (stopped early)" if res["stopped"] else "")


def run(args: argparse.Namespace) -> int:
    import zenoh

    from radical_rt.io import zconfig

    # archive warnings are printed here as one line each, not by logging's last-resort handler
    archive_log = logging.getLogger("radical_rt.io.archive")
    if not any(isinstance(h, logging.NullHandler) for h in archive_log.handlers):
        archive_log.addHandler(logging.NullHandler())
    try:
        check_vehicle(args.vehicle)
        sources, notes = check_inputs(args.inputs, args.start, args.end)
        if not (math.isfinite(args.gap) and args.gap >= 0):
            raise ReplayError(f"--gap must be >= 0 s, got {args.gap!r}")
        cfg, mode, where = tool_config(args.listen, args.connect, "replay", args.zenoh_config)
    except (ReplayError, ArchiveError, zconfig.ZenohConfigError) as e:
        _err(str(e))
        return 2
    except Exception as e:  # e.g. an unreadable --zenoh-config file
        _err(f"{type(e).__name__}: {e}")
        return 2
    for n in notes:
        print(f"radical replay: warning: {n}", file=sys.stderr)

    stop = threading.Event()
    old = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, lambda *_: stop.set())
    hint = f"is `radical node --vehicle {args.vehicle}` running there?"
    # a node serving the vehicle is required unless told otherwise (bounded default wait)
    node_wait = args.wait_node
    if node_wait is None and not args.no_wait_node and args.wait_subscribers is None:
        node_wait = DEFAULT_WAIT_S
    try:
        zenoh.try_init_log_from_env()
        t_start = time.monotonic()
        wait_s = max(args.wait_node or 0.0, args.wait_subscribers or 0.0)
        try:
            session = open_session(cfg, mode, t_start + wait_s if wait_s else None, stop)
        except ReplayError as e:
            if stop.is_set():
                print("radical replay: interrupted", file=sys.stderr)
                return 130
            within = f" within {wait_s:g} s" if wait_s else ""
            _err(f"{e} ({where}{within}); {hint}")
            return 1
        try:
            if node_wait is not None:
                left = max(t_start + node_wait - time.monotonic(), 0.1)
                try:
                    wait_for_node(session, args.vehicle, left, stop)
                except ReplayError:
                    if stop.is_set():
                        print("radical replay: interrupted", file=sys.stderr)
                        return 130
                    others = served_vehicles(session)
                    seen = (f"; nodes there serve: {', '.join(others)}" if others
                            else "; no node seen there")
                    _err(f"no filter node for vehicle {args.vehicle!r}: liveliness token "
                         f"{node_token_key(args.vehicle)} not seen within {node_wait:g} s "
                         f"({where}){seen}; {hint} (--no-wait-node publishes anyway)")
                    return 1
                waited = time.monotonic() - t_start
                print(f"radical replay: node {node_token_key(args.vehicle)} alive "
                      f"(waited {waited:.2f} s)", file=sys.stderr)
            wait_subs = None
            if wait_s:
                wait_subs = max(t_start + wait_s - time.monotonic(), 0.1)
            try:
                with warnings.catch_warnings():  # already reported above
                    warnings.simplefilter("ignore", TruncatedArchiveWarning)
                    res = replay([s.path for s in sources], args.vehicle, session,
                                 rate=None if args.fast else args.rate, start=args.start,
                                 end=args.end, progress=not args.no_progress,
                                 wait_subscribers=wait_subs, gap=args.gap, stop_event=stop)
            except ReplayError as e:
                if stop.is_set():
                    print("radical replay: interrupted", file=sys.stderr)
                    return 130
                _err(f"{e} ({where})")
                return 1
            except ArchiveError as e:
                _err(str(e))
                return 2
        finally:
            # Zenoh has no flush: keep the session open so that messages still queued in this
            # process's transmit queue reach the subscribers before the links close.
            time.sleep(max(args.linger, 0.0))
            session.close()
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
    print(f"radical replay: {_summary_line(res)}", file=sys.stderr)
    if args.json:
        print(json.dumps(res, sort_keys=True))
    if res["stopped"]:
        return 130
    return 3 if res.get("not_delivered") else 0
