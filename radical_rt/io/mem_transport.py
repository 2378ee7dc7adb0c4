"""The in-memory transport: :class:`InMemoryTransport` instances that share an
:class:`InMemoryBus` exchange samples, queries and liveliness tokens in one process, with Zenoh's
semantics and no network (the protocol: :mod:`radical_rt.io.transport`).

A bus is synchronous (callbacks run in the publisher's thread) or threaded (one delivery thread per
subscriber / queryable, in order, like the Zenoh Python binding). :class:`MemInbox` is the bounded
input FIFO (samples and payload bytes) of this bus; :class:`radical_rt.io.zinbox.ZByteInbox`
reuses it on a Zenoh subscriber.
"""

from __future__ import annotations

import functools
import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from radical_rt.io.transport import (
    KeyedQueryHandler,
    QueryHandler,
    SampleCallback,
    TransportError,
    key_intersects,
    key_matches,
)

log = logging.getLogger("radical.transport")


class _Worker:
    """One delivery thread running submitted calls in order (threaded bus)."""

    def __init__(self, name: str) -> None:
        self.q: queue.SimpleQueue = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.thread.start()

    def submit(self, fn: Callable[[], Any]) -> None:
        self.q.put(fn)

    def _run(self) -> None:
        while (fn := self.q.get()) is not None:
            try:
                fn()
            except Exception:  # a callback error must not kill delivery (as in Zenoh)
                log.exception("in-memory delivery callback failed")

    def stop(self) -> None:
        self.q.put(None)


class _Decl:
    def __init__(self, bus: InMemoryBus, kind: str, key: str, fn: Any, owner: Any = None) -> None:
        self.bus, self.kind, self.key, self.fn = bus, kind, key, fn
        self.owner = owner  # set for remote-only subscribers: samples from it are not delivered
        self.worker = (_Worker(f"inmem-{kind}-{key}") if bus.threaded and kind not in ("token", "lsub")
                       else None)

    def undeclare(self) -> None:
        self.bus.remove(self)


class MemInbox:
    """:class:`Inbox` of the in-memory bus: a deque with a condition, bounded in samples
    (``capacity``) and in payload bytes (``capacity_bytes``; None: no byte bound). When it is
    full, the delivering thread waits up to ``wait_s`` for room (back-pressure), then drops and
    counts. A payload larger than the whole byte bound is dropped at once."""

    _WAKE = object()

    def __init__(self, capacity: int, wait_s: float, capacity_bytes: int | None = None) -> None:
        self.capacity, self.wait_s = capacity, wait_s
        self.capacity_bytes = capacity_bytes
        self.nbytes = 0  # payload bytes waiting
        self._items: deque = deque()
        self._cond = threading.Condition()
        self._dropped: dict[str, int] = {}
        self._dropped_bytes: dict[str, int] = {}
        self.decl: _Decl | None = None  # the bus subscription feeding it

    def _room(self, n: int) -> bool:
        return len(self._items) < self.capacity and (
            self.capacity_bytes is None or self.nbytes + n <= self.capacity_bytes)

    def push(self, key: str, data: bytes) -> None:
        n = len(data)
        with self._cond:
            if not self._room(n) and (
                    (self.capacity_bytes is not None and n > self.capacity_bytes)
                    or not self._cond.wait_for(lambda: self._room(n), timeout=self.wait_s)):
                self._dropped[key] = self._dropped.get(key, 0) + 1
                self._dropped_bytes[key] = self._dropped_bytes.get(key, 0) + n
                return
            self._items.append((key, data))
            self.nbytes += n
            self._cond.notify_all()

    def _pop(self, block: bool):
        with self._cond:
            if block:
                self._cond.wait_for(lambda: self._items)
            if not self._items:
                return None
            item = self._items.popleft()
            self._cond.notify_all()  # room for a waiting push
            if item is self._WAKE:
                return None
            self.nbytes -= len(item[1])
            return item

    def push_control(self, key: str, data: bytes = b"") -> None:
        """Queue a control item (a fleet node's cut or serve marker) behind everything queued
        now, whatever the bounds: it must not be dropped, and it carries no input."""
        with self._cond:
            self._items.append((key, data))
            self.nbytes += len(data)
            self._cond.notify_all()

    def drop_through(self, match: Any) -> int | None:
        """Drop the waiting samples up to and including the first for which ``match(key,
        payload)`` is true and return how many; None (nothing dropped) if none matches."""
        with self._cond:
            for i, item in enumerate(self._items):
                if item is not self._WAKE and match(*item):
                    for _ in range(i + 1):
                        it = self._items.popleft()
                        if it is not self._WAKE:
                            self.nbytes -= len(it[1])
                    self._cond.notify_all()
                    return i + 1
        return None

    def try_recv(self) -> tuple[str, bytes] | None:
        return self._pop(False)

    def recv(self) -> tuple[str, bytes] | None:
        return self._pop(True)

    def wake(self) -> None:
        with self._cond:
            self._items.append(self._WAKE)
            self._cond.notify_all()

    def pending(self) -> int:
        """Samples waiting (exact on this bus)."""
        with self._cond:
            return sum(1 for it in self._items if it is not self._WAKE)

    def take_dropped(self) -> dict[str, int]:
        with self._cond:
            out, self._dropped = self._dropped, {}
        return out

    def take_drops(self) -> tuple[dict[str, int], dict[str, int]]:
        """(samples, payload bytes) dropped since the last call, per key, taken together."""
        with self._cond:
            out = self._dropped, self._dropped_bytes
            self._dropped, self._dropped_bytes = {}, {}
        return out

    def queued_bytes(self) -> int:
        """Payload bytes waiting now."""
        with self._cond:
            return self.nbytes

    def undeclare(self) -> None:
        if self.decl is not None:
            self.decl.undeclare()
            self.decl = None


class InMemoryBus:
    """A process-local "network" shared by :class:`InMemoryTransport` instances."""

    def __init__(self, threaded: bool = False) -> None:
        self.threaded = threaded
        self._lock = threading.Lock()
        self._decls: list[_Decl] = []

    def add(self, d: _Decl) -> _Decl:
        """Register a declaration (subscriber, queryable, token or liveliness subscriber)."""
        with self._lock:
            self._decls.append(d)
        if d.kind == "token":
            self._tell(d.key, True)
        return d

    def remove(self, d: _Decl) -> None:
        """Forget a declaration and stop its delivery thread."""
        with self._lock:
            found = d in self._decls
            if found:
                self._decls.remove(d)
        if d.worker:
            d.worker.stop()
        if found and d.kind == "token":
            self._tell(d.key, False)

    def _tell(self, token: str, alive: bool) -> None:
        """Liveliness subscribers learn that a token appeared or went (in the caller's thread)."""
        for d in self.find("lsub", token):
            d.fn(token, alive)

    def find(self, kind: str, key: str) -> list[_Decl]:
        """The declarations of one kind whose key expression matches ``key`` (queryables: whose
        key expression intersects the query's, which may hold wildcards too)."""
        match = key_intersects if kind == "qbl" else key_matches
        with self._lock:
            return [d for d in self._decls if d.kind == kind and match(d.key, key)]

    def sync(self, timeout: float = 10.0) -> bool:
        """Threaded bus: wait until every delivery submitted so far has run (True if it did)."""
        with self._lock:
            workers = [d.worker for d in self._decls if d.worker is not None]
        events = []
        for w in workers:
            ev = threading.Event()
            w.submit(ev.set)
            events.append(ev)
        end = time.monotonic() + timeout
        return all(ev.wait(max(0.0, end - time.monotonic())) for ev in events)

    def alive(self, expr: str = "**") -> list[str]:
        """Keys of the liveliness tokens alive now that match ``expr``."""
        with self._lock:
            return sorted(d.key for d in self._decls if d.kind == "token" and key_matches(expr, d.key))


class InMemoryTransport:
    """A :class:`Transport` on an :class:`InMemoryBus` (same semantics as Zenoh, no network)."""

    def __init__(self, bus: InMemoryBus | None = None) -> None:
        self.bus = bus or InMemoryBus()
        self._mine: list[_Decl] = []
        self.closed = False

    def _declare(self, kind: str, key: str, fn: Any, owner: Any = None) -> _Decl:
        if self.closed:
            raise TransportError("transport closed")
        d = self.bus.add(_Decl(self.bus, kind, key, fn, owner))
        self._mine.append(d)
        return d

    def subscribe(self, key: str, callback: SampleCallback, remote_only: bool = False) -> _Decl:
        return self._declare("sub", key, callback, self if remote_only else None)

    def inbox(self, key: str, capacity: int, wait_s: float = 1.0,
              capacity_bytes: int | None = None) -> MemInbox:
        box = MemInbox(capacity, wait_s, capacity_bytes)
        box.decl = self.subscribe(key, box.push, remote_only=True)
        return box

    def inbox_subscribe(self, box: MemInbox, key: str) -> _Decl:
        """One more subscription on ``key`` feeding ``box`` (see ZenohTransport)."""
        return self.subscribe(key, box.push, remote_only=True)

    def queryable(self, key: str, handler: QueryHandler | KeyedQueryHandler,
                  keyed: bool = False) -> _Decl:
        fn = handler if keyed else (lambda _key, payload: handler(payload))
        return self._declare("qbl", key, fn)

    def liveliness_token(self, key: str) -> _Decl:
        return self._declare("token", key, None)

    def liveliness_subscribe(self, key: str, callback: Any) -> _Decl:
        """``callback(token_key, alive)`` for every token matching ``key``: those alive now
        (history), then each one that appears or goes."""
        d = self._declare("lsub", key, callback)
        for tok in self.bus.alive(key):
            callback(tok, True)
        return d

    def put(self, key: str, payload: bytes, block: bool = False, remote_only: bool = False) -> None:
        if self.closed:
            raise TransportError("transport closed")
        data = bytes(payload)
        for d in self.bus.find("sub", key):
            if d.owner is self or (remote_only and d in self._mine):
                continue
            if d.worker:
                d.worker.submit(functools.partial(d.fn, key, data))
            else:
                d.fn(key, data)

    def get(self, key: str, payload: bytes = b"", timeout: float = 5.0,
            every: bool = True) -> list[bytes]:
        if self.closed:
            raise TransportError("transport closed")
        replies: list[bytes] = []
        for d in self.bus.find("qbl", key):
            if d.worker is None:
                r = d.fn(key, bytes(payload))
                if r is not None:  # None: the queryable does not reply
                    replies.append(bytes(r))
                continue
            done = threading.Event()
            box: list[bytes] = []

            def call(d: _Decl = d, box: list[bytes] = box, done: threading.Event = done) -> None:
                try:
                    r = d.fn(key, bytes(payload))
                    if r is not None:
                        box.append(bytes(r))
                finally:
                    done.set()

            d.worker.submit(call)
            if done.wait(timeout) and box:
                replies.append(box[0])
        return replies

    def close(self) -> None:
        for d in self._mine:
            d.undeclare()
        self._mine.clear()
        self.closed = True
