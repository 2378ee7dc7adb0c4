"""The input FIFOs of :class:`radical_rt.io.zenoh_transport.ZenohTransport`: :class:`ZInbox`, pulled
from a Zenoh ``FifoChannel``, and :class:`ZByteInbox`, bounded in bytes as well as in samples
(issue 23, "a byte bound on the input queue").

A Zenoh ``FifoChannel`` (:class:`ZInbox`) counts samples only: its bytes are
bounded by ``capacity`` × the largest Zenoh message, and a slow consumer fed large junk can hold
gigabytes in it. :class:`ZByteInbox` instead takes each sample in a subscriber callback and looks
at its length *before* copying it into Python:

* a payload over ``max_payload`` bytes is dropped uncopied and counted (``take_oversize``,
  reported as ``too_large``, as before);
* a payload that does not fit (``capacity`` samples or ``capacity_bytes`` payload bytes already
  waiting) makes the session's receive thread wait up to ``wait_s`` for room (back-pressure,
  as a full ``FifoChannel`` did), then is dropped and counted per key, in messages
  (``take_dropped``, or both with ``take_drops``) and bytes; a payload larger than the whole byte
  budget is dropped at once;
* otherwise it is copied (``bytes``) and queued; the consumer pulls it with ``try_recv`` /
  ``recv`` exactly as from the in-memory FIFO.

At any time the queued payload bytes are ≤ ``capacity_bytes``; the transient extra is one payload
(≤ ``max_payload``) per Zenoh receive thread being copied. The cost: the callback takes the GIL
once per sample on a Zenoh thread (the pulled ``FifoChannel`` did not), which competes with the
filter loop. The callback is declared ``indirect=False`` (run in the receive thread itself, an
API the binding marks unstable): the default hands samples to a Python thread through an
unbounded channel, which would hold the flood again (docs/node.md, "Losses and bounds"; ``--queue-bytes 0`` restores the pulled FIFO).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any

from radical_rt.io.mem_transport import MemInbox

if TYPE_CHECKING:
    from radical_rt.io.zenoh_transport import ZenohTransport

log = logging.getLogger("radical.transport")


class ZInbox:
    """:class:`~radical_rt.io.transport.Inbox` on a Zenoh subscriber with a
    ``FifoChannel(capacity)`` handler.

    A full channel blocks the session's receive thread (back-pressure on BLOCK publishers; DROP
    publishers drop in their own queues), so nothing is dropped here. The subscriber also takes
    samples of its own session, so that :meth:`wake` can end a blocked ``recv`` with a
    session-local put on ``wake_key`` (it never leaves the process); the owner publishes its own
    data with ``remote_only`` (it would otherwise come back into this FIFO).
    """

    def __init__(self, transport: ZenohTransport, key: str, capacity: int,
                 max_payload: int | None = None) -> None:
        z = transport.zenoh
        self._t, self._z = transport, z
        self.max_payload = max_payload  # larger payloads are dropped uncopied (take_oversize)
        self._oversize: dict[str, int] = {}
        self.wake_key = _wake_key(key)
        self._sub: Any = transport.session.declare_subscriber(key, z.handlers.FifoChannel(capacity))

    def _item(self, s: Any) -> tuple[str, bytes] | None:
        key = str(s.key_expr)
        if key == self.wake_key:
            return None
        if self.max_payload is not None and len(s.payload) > self.max_payload:
            self._oversize[key] = self._oversize.get(key, 0) + 1  # never copied into Python
            return None
        return key, s.payload.to_bytes()

    def try_recv(self) -> tuple[str, bytes] | None:
        while (s := self._sub.try_recv()) is not None:
            item = self._item(s)
            if item is not None:
                return item
        return None

    def recv(self) -> tuple[str, bytes] | None:
        try:
            return self._item(self._sub.recv())
        except Exception as exc:  # undeclared subscriber or closed session
            log.debug("inbox recv: %s", exc)
            return None

    def take_oversize(self) -> dict[str, int]:
        """Samples dropped since the last call because they exceeded max_payload, per key."""
        out, self._oversize = self._oversize, {}
        return out

    def wake(self) -> None:
        try:
            self._t.session.put(self.wake_key, b"",
                                allowed_destination=self._z.Locality.SESSION_LOCAL)
        except Exception as exc:  # closed session: nothing is waiting any more
            log.debug("inbox wake: %s", exc)

    def take_dropped(self) -> dict[str, int]:
        return {}

    def undeclare(self) -> None:
        if self._sub is not None:
            try:
                self._sub.undeclare()
            except Exception as exc:
                log.debug("inbox undeclare: %s", exc)
            self._sub = None


def _wake_key(expr: str) -> str:
    """A concrete key matched by ``expr`` that no vehicle or topic uses (upper case)."""
    chunks = ["WAKE" if c in ("*", "**") else c for c in expr.split("/")]
    chunks[-1] = "WAKE"
    return "/".join(chunks)


class ZByteInbox(MemInbox):
    """:class:`~radical_rt.io.transport.Inbox` on a Zenoh callback subscriber, bounded in samples
    and payload bytes (see the module docstring)."""

    def __init__(self, transport: Any, key: str, capacity: int, wait_s: float,
                 capacity_bytes: int, max_payload: int | None = None) -> None:
        if capacity_bytes < 1:
            raise ValueError("capacity_bytes must be ≥ 1")
        super().__init__(capacity, wait_s, capacity_bytes)
        self.max_payload = max_payload
        self._oversize: dict[str, int] = {}
        # indirect=False: the callback runs in Zenoh's receive thread. The default (indirect)
        # callback hands every sample to a Python thread through an unbounded channel, which
        # holds the flood this FIFO is meant to bound (measured: 200 MB for 8 MiB queued)
        handler = transport.zenoh.handlers.Callback(self.on_sample, indirect=False)
        self._sub: Any = transport.session.declare_subscriber(key, handler)

    def on_sample(self, s: Any) -> None:
        """The subscriber callback (a Zenoh thread): size first, copy only what is queued."""
        try:
            key = str(s.key_expr)
            n = len(s.payload)
            if self.max_payload is not None and n > self.max_payload:
                with self._cond:
                    self._oversize[key] = self._oversize.get(key, 0) + 1
                return
            with self._cond:
                if not self._room(n) and (
                        n > self.capacity_bytes
                        or not self._cond.wait_for(lambda: self._room(n), timeout=self.wait_s)):
                    self._dropped[key] = self._dropped.get(key, 0) + 1
                    self._dropped_bytes[key] = self._dropped_bytes.get(key, 0) + n
                    return
                self._items.append((key, s.payload.to_bytes()))
                self.nbytes += n
                self._cond.notify_all()
        except Exception:  # never let a sample kill Zenoh's delivery
            log.exception("input sample could not be queued")

    def take_oversize(self) -> dict[str, int]:
        """Samples dropped since the last call because they exceeded max_payload, per key."""
        with self._cond:
            out, self._oversize = self._oversize, {}
        return out

    def undeclare(self) -> None:
        if self._sub is not None:
            try:
                self._sub.undeclare()
            except Exception as exc:  # already closed session
                log.debug("inbox undeclare: %s", exc)
            self._sub = None
