"""Recording ``radical/<vehicle>/**`` samples to an MCAP archive (the work of `radical record`).

:func:`record` subscribes to the vehicle's keys, queues the samples from Zenoh's callback threads
(bounded; back-pressure, then drop and count) and writes them in the caller's thread with their
payload unchanged, log_time = publish_time = the bus time in ns read by :func:`bus_time_ns`
(CONTRACT §1.2, §4), channels with the contract's schemas; end-of-stream markers are compared with
the messages recorded (``lost``). Semantics and the command line: :mod:`replayer.record`.
"""

from __future__ import annotations

import json
import math
import os
import queue
import re
import threading
import time
from collections.abc import Iterable
from typing import Any

import msgpack

from radical_rt.contract.conventions import t_to_ns
from radical_rt.contract.schemas import SCHEMAS, schema_name
from radical_rt.io.archive import ArchiveWriter
from replayer.sessions import VEHICLE_RE

_TOPIC_RE = re.compile(r"^[A-Za-z0-9_*$-]+(/[A-Za-z0-9_*$-]+)*$")
_SKIP = ("alive", "cmd")
_MAX_NS = int(1.8e19)


class RecordError(Exception):
    """A recording cannot start; ``str(e)`` is one line."""


def check_vehicle(vehicle: str) -> str:
    """``vehicle`` if it is a vehicle name ([a-z0-9_-]+) or ``*`` (all vehicles), else RecordError."""
    if vehicle != "*" and not (isinstance(vehicle, str) and VEHICLE_RE.match(vehicle)):
        raise RecordError(f"vehicle {vehicle!r} must match [a-z0-9_-]+ or be '*' (all vehicles)")
    return vehicle


def parse_topics(topics: Iterable[str] | str | None) -> list[str] | None:
    """``"siru,/tlm/small"`` or a list → ``["siru", "tlm/small"]`` (None: everything)."""
    if topics is None:
        return None
    items = topics.split(",") if isinstance(topics, str) else list(topics)
    out = []
    for t in items:
        t = t.strip().strip("/")
        if not t:
            continue
        if not _TOPIC_RE.match(t):
            raise RecordError(f"bad topic {t!r} (like siru, tlm/small, tlm/*)")
        if t.split("/")[0] in _SKIP:
            raise RecordError(f"topic {t!r}: liveliness and command keys are not recorded")
        out.append(t)
    if not out:
        raise RecordError("--topics is empty")
    return out


def bus_time_ns(data: bytes) -> int | None:
    """Bus time (ns) from a msgpack map's top-level ``t_bus`` or ``t`` (last element of a list);
    None if there is none or it is not a valid MCAP time. Other values are skipped, not built."""
    try:
        up = msgpack.Unpacker(raw=False, strict_map_key=False)
        up.feed(data)
        for _ in range(up.read_map_header()):
            k = up.unpack()
            if k != "t_bus" and k != "t":
                up.skip()
                continue
            v = up.unpack()
            if isinstance(v, list | tuple):
                v = v[-1] if v else None
            if isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) \
                    and 0 <= v < 1.8e10:
                return t_to_ns(float(v))
    except Exception:  # not a map, torn payload, ...
        return None
    return None


class _RecordWriter(ArchiveWriter):
    """ArchiveWriter whose channels take the schema of their contract topic: ``/<V>/tlm/small``
    gets ``radical.tlm.small`` in a wildcard recording (plus channel metadata ``vehicle``)."""

    def __init__(self, *a: Any, wildcard: bool = False, **kw: Any) -> None:
        super().__init__(*a, **kw)
        self._wildcard = wildcard
        self._schema_ids: dict[str, int] = {}

    def _channel(self, topic: str) -> int:
        cid = self._channels.get(topic)
        if cid is not None:
            return cid
        meta: dict[str, str] = {}
        base = topic
        if self._wildcard:
            _, vehicle, rest = topic.split("/", 2)
            base, meta = "/" + rest, {"vehicle": vehicle}
        schema = SCHEMAS.get(base)
        sid = 0
        if schema is not None:
            sid = self._schema_ids.get(base, 0)
            if not sid:
                sid = self._schema_ids[base] = self._w.register_schema(
                    schema_name(base), "jsonschema", json.dumps(schema, sort_keys=True).encode())
        cid = self._channels[topic] = self._w.register_channel(topic, "msgpack", sid, meta)
        self._seq[cid] = 0
        return cid


def record(out_path: str | os.PathLike[str], vehicle: str, session: Any,
           duration: float | None = None, topics: Iterable[str] | str | None = None,
           stop_event: threading.Event | None = None, *, ready_event: threading.Event | None = None,
           queue_size: int = 65536, block_s: float = 0.25, flush_every_s: float = 0.5,
           chunk_size: int = 256 * 1024) -> dict[str, Any]:
    """Record ``radical/<vehicle>/**`` (or only ``topics``) into ``out_path`` until
    ``stop_event`` is set or ``duration`` seconds have passed; the calling thread is the writer.

    ``ready_event`` is set once the subscribers are declared. Returns ``path``, ``counts``
    (messages per MCAP topic), ``messages``, ``dropped`` (queue full for ``block_s``),
    ``skipped`` (liveliness/command keys, deletes), ``time_fallbacks`` (messages logged at receive
    time), ``queue_max`` (queue high-water mark) and ``wall_s``.
    """
    check_vehicle(vehicle)
    wanted = parse_topics(topics)
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise RecordError(f"duration must be > 0 s, got {duration!r}")
    if not (queue_size >= 1 and block_s >= 0 and flush_every_s > 0):
        raise RecordError("queue_size must be >= 1, block_s >= 0 and flush_every_s > 0")
    wildcard = vehicle == "*"
    from radical_rt import __version__

    writer = _RecordWriter(out_path, wildcard=wildcard, chunk_size=chunk_size,
                           scenario={"name": "record", "vehicle": vehicle, "seed": "",
                                     "generator": f"radical-rt record {__version__}"})
    stop = stop_event if stop_event is not None else threading.Event()
    q: queue.Queue[tuple[str, bytes, int, bool]] = queue.Queue(maxsize=queue_size)
    drops = [0]
    drop_lock = threading.Lock()

    import zenoh

    put_kind = zenoh.SampleKind.PUT

    def on_sample(sample: Any) -> None:  # zenoh's callback thread: enqueue only
        try:
            item = (str(sample.key_expr), sample.payload.to_bytes(), time.monotonic_ns(),
                    sample.kind == put_kind)
            if block_s > 0:
                q.put(item, timeout=block_s)
            else:
                q.put_nowait(item)
        except queue.Full:
            with drop_lock:
                drops[0] += 1

    prefix = f"radical/{vehicle}"
    keys = [f"{prefix}/**"] if wanted is None else [f"{prefix}/{t}" for t in wanted]
    subs: list[Any] = []
    counts: dict[str, int] = {}
    skipped = fallbacks = qmax = 0
    eos_seen = lost = 0
    since: dict[tuple[str, str], int] = {}  # (vehicle, topic) → recorded since its last marker
    anchors: dict[str, tuple[int, int]] = {}  # vehicle -> (bus ns, receive monotonic ns)

    def handle(item: tuple[str, bytes, int, bool]) -> None:
        nonlocal skipped, fallbacks, eos_seen, lost
        key, data, t_recv, is_put = item
        parts = key.split("/", 2)
        if len(parts) < 3 or parts[0] != "radical" or not is_put \
                or parts[2].split("/")[0] in _SKIP:
            skipped += 1
            return
        veh, rest = parts[1], parts[2]
        if rest == "eos":
            eos_seen += 1
            lost += _eos_lost(data, veh, since)
            return
        since[(veh, rest)] = since.get((veh, rest), 0) + 1
        topic = f"/{veh}/{rest}" if wildcard else f"/{rest}"
        t = bus_time_ns(data)
        if t is not None:
            anchors[veh] = (t, t_recv)
        else:
            fallbacks += 1
            a = anchors.get(veh)
            if a is not None:
                t = a[0] + (t_recv - a[1])
            else:
                t = time.time_ns() - (time.monotonic_ns() - t_recv)
            t = min(max(t, 0), _MAX_NS)
        writer.write_raw(topic, data, t)
        counts[topic] = counts.get(topic, 0) + 1

    t0 = time.monotonic()
    try:
        try:
            for k in keys:
                subs.append(session.declare_subscriber(k, on_sample))
        except Exception as e:
            raise RecordError(f"cannot subscribe to {k}: {e}") from None
        if ready_event is not None:
            ready_event.set()
        deadline = t0 + duration if duration is not None else None
        last_flush, flushed = time.monotonic(), 0

        while True:
            now = time.monotonic()
            if stop.is_set() or (deadline is not None and now >= deadline):
                break
            wait = 0.1 if deadline is None else max(min(0.1, deadline - now), 0.0)
            try:
                item = q.get(timeout=wait)
            except queue.Empty:
                item = None
            if item is not None:
                qmax = max(qmax, q.qsize() + 1)
                handle(item)
            now = time.monotonic()
            if writer.message_count != flushed and now - last_flush >= flush_every_s:
                writer.flush()
                last_flush, flushed = now, writer.message_count
    finally:
        for s in subs:
            try:
                s.undeclare()
            except Exception:  # session already closed
                pass
        try:
            while True:  # what was received before the undeclare is kept
                handle(q.get_nowait())
        except queue.Empty:
            pass
        finally:
            writer.close()
    return {"path": os.fspath(out_path), "counts": dict(sorted(counts.items())),
            "messages": sum(counts.values()), "dropped": drops[0], "skipped": skipped,
            "time_fallbacks": fallbacks, "queue_max": qmax, "wall_s": time.monotonic() - t0,
            "eos": eos_seen, "lost": lost}


def _eos_lost(data: bytes, veh: str, since: dict[tuple[str, str], int]) -> int:
    """Messages an end-of-stream marker reports sent that were not recorded since the vehicle's
    previous marker (the per-topic counts restart); 0 for a marker that does not decode."""
    try:
        counts = msgpack.unpackb(data, raw=False, strict_map_key=False).get("counts", {})
        items = [(str(t), int(n)) for t, n in counts.items()]
    except Exception:  # not a map, or counts not a map of integers
        return 0
    lost = 0
    for t, n in items:
        lost += max(0, n - since.pop((veh, t), 0))
    return lost
