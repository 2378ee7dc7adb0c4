"""One vehicle served by the node (:class:`Vehicle`: its StreamProcessor, its counters, what
:func:`radical_rt.apps.commands.apply` calls on it), the rejections the node counts for it
(:func:`note_reject`; the inputs its FIFO dropped: :func:`report_fifo_losses`), and the msgpack
encoding of the node's outputs and replies (:func:`packb`). The node itself is
:class:`radical_rt.apps.node.FilterNode`.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import defaultdict
from typing import TYPE_CHECKING, Any

import msgpack
import numpy as np

from radical_rt.apps.batch import make_summary
from radical_rt.apps.link_watch import LinkWatch
from radical_rt.apps.node_clock import ClockNotice
from radical_rt.stream.processor import INPUT_TOPICS, StreamProcessor

if TYPE_CHECKING:
    from radical_rt.apps.node import FilterNode

log = logging.getLogger("radical.node")
VEHICLE_RE = re.compile(r"^[a-z0-9_-]+$")


def packb(msg: Any) -> bytes:
    """msgpack with numpy scalars/arrays converted (outputs are mostly plain Python already)."""
    return msgpack.packb(msg, use_bin_type=True, default=_np_default)


def _np_default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot serialize {type(obj).__name__}")



class Vehicle:
    """One vehicle served by the node: its StreamProcessor and its counters."""

    def __init__(self, node: FilterNode, name: str, sp: StreamProcessor) -> None:
        if not VEHICLE_RE.match(name):
            raise ValueError(f"vehicle name {name!r} must match [a-z0-9_-]+")
        self.node, self.name, self.sp = node, name, sp
        self.prefix = f"radical/{name}/"
        self.lock = threading.Lock()  # guards the counters below (read by status/diag)
        self.received: dict[str, int] = defaultdict(int)
        self.overflow: dict[str, int] = defaultdict(int)
        self.overflow_bytes: dict[str, int] = defaultdict(int)
        self.fed: dict[str, int] = defaultdict(int)  # loop thread only
        self.commands_applied = 0
        self.published: dict[str, int] = defaultdict(int)
        self.clock_notice = ClockNotice(name)
        # end of stream (docs/node.md, "End of stream"): received at the last marker, markers,
        # inputs a marker reported sent but never received, releases after an idle time
        self.at_eos: dict[str, int] = {}
        self.eos_seen = self.reported_lost = self.idle_releases = 0
        self.last_input_mono = 0.0
        self.holding = False  # inputs taken since the last release of everything
        self.link = LinkWatch(node.stale_after_s) if node.stale_after_s else None
        self.last_checkpoint_mono: float | None = None  # this vehicle's state last written
        self.fleet_info: dict[str, Any] | None = None  # set by a fleet worker (diag, status)

    # ---- called by commands.apply (filter loop thread)
    def status(self) -> dict[str, Any]:
        """The ``status`` command's reply: estimates, σ, flags, counters, summary, node info."""
        e, sp = self.sp.engine, self.sp
        return {"vehicle": self.name, "t": float(e.t), "mode": e.mode, "flags": int(sp.flags),
                "flag_names": sp.flag_names(), "q_body_from_inertial": e.q.tolist(),
                "est": e.estimates(), "sigma": e.sigmas(),
                "excluded": [int(i) for i in np.nonzero(e.excluded)[0]],
                "counters": sp.counters(), "rejected": dict(sp.rejected),
                "summary": make_summary(sp), "node": self.node_info()}

    def write_checkpoint(self) -> str:
        """Write the node's checkpoint (every vehicle) now; its path."""
        return self.node.write_checkpoint()

    def end_stream(self, next_start: str | None) -> dict[str, Any]:
        """The ``end_stream`` command: everything held released and published, the summary taken,
        then (``next_start`` not None) the next stream prepared."""
        self.node.publish(self, self.sp.end_stream(None))
        summary = make_summary(self.sp)
        if next_start is not None:
            self.node.publish(self, self.sp.end_stream(next_start))
        return {"summary": summary, "next": next_start or "none"}

    def node_info(self) -> dict[str, Any]:
        """The node's counters for this vehicle (the ``node`` field of diag and status)."""
        with self.lock:
            received, overflow = dict(self.received), dict(self.overflow)
            overflow_bytes = dict(self.overflow_bytes)
        n = self.node
        return {"received": received, "fed": dict(self.fed), "queue_overflow": overflow,
                "queue_overflow_bytes": overflow_bytes,
                "queue_depth": n.queue_depth(), "queue_size": n.queue_size,
                "queue_bytes": n.queue_bytes, "queue_bytes_used": n.queue_bytes_used(),
                "commands_applied": self.commands_applied, "published": dict(self.published),
                "commands": n.audit.summary(self.name),
                "security": n.auth.describe() if n.auth is not None else {"auth": "none"},
                "fleet": self.fleet_info,
                "eos": self.eos_seen, "reported_lost": self.reported_lost,
                "idle_releases": self.idle_releases,
                "link_lost": bool(self.sp.link_lost), "stale_after_s": n.stale_after_s,
                "checkpoint": str(n.checkpoint_path) if n.checkpoint_path else None,
                "checkpoints_written": n.checkpoints_written,
                "checkpoint_failures": n.checkpoint_failures, "checkpoint_error": n.checkpoint_error,
                "last_checkpoint_age_s": (time.monotonic() - self.last_checkpoint_mono)
                if self.last_checkpoint_mono is not None else None}



def note_reject(sp: StreamProcessor, topic: str, reason: str, message: str, count: int = 1) -> None:
    """Count a rejection the StreamProcessor did not see itself (same bookkeeping as its own)."""
    sp.rejected[reason] += count
    sp.last_reject_t = sp.t_max
    sp.last_reject = f"{topic}: {message}"


def report_fifo_losses(vehicles: dict[str, Vehicle], inbox: Any) -> None:
    """Filter loop, between messages: take the inputs the FIFO dropped since the last call (full:
    ``queue_overflow``, with their bytes where the FIFO counts them; over the size bound:
    ``too_large``) and count them in the vehicles they were for."""
    take_drops = getattr(inbox, "take_drops", None)  # counts with their bytes
    dropped, nbytes = take_drops() if take_drops else (inbox.take_dropped(), None)
    if dropped:
        _report_overflows(vehicles, dropped, nbytes=nbytes)
    take_oversize = getattr(inbox, "take_oversize", None)
    oversize = take_oversize() if take_oversize is not None else None
    if oversize:
        _report_overflows(vehicles, oversize, "too_large", "payload over the size bound")


def _report_overflows(vehicles: dict[str, Vehicle], dropped: dict[str, int],
                      reason: str = "queue_overflow", what: str = "queue full",
                      nbytes: dict[str, int] | None = None) -> None:
    """Count and log dropped inputs per vehicle and topic (``dropped``, ``nbytes``: samples and
    payload bytes per key); keys of vehicles not served and non-input topics are ignored."""
    for key, n in dropped.items():
        v = vehicles.get(key.split("/", 2)[1])
        topic = key[len(v.prefix):] if v is not None else ""
        if v is None or topic not in INPUT_TOPICS:
            continue
        if reason == "queue_overflow":
            with v.lock:
                v.overflow[topic] += n
                v.overflow_bytes[topic] += (nbytes or {}).get(key, 0)
        note_reject(v.sp, "input", reason, f"{what}: {n} message(s) dropped", count=n)
        log.warning("%s: %s, %d %s message(s) dropped", v.name, what, n, topic)
