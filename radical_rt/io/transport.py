"""The transport seam of the streaming node: a small protocol, Zenoh 1.x, and an in-memory bus.

The node only needs five things from a middleware, all with raw ``bytes`` payloads:

* ``subscribe(key, callback, remote_only=False)``: ``callback(key, payload)`` for every sample on a
  key expression (``remote_only``: not the samples this transport publishes itself);
* ``inbox(key, capacity, wait_s)``: the same samples (other transports' only) pulled by the caller
  from a bounded FIFO (:class:`Inbox`): ``try_recv()``, a blocking ``recv()`` that another thread
  can end with ``wake()``, and the samples dropped because the FIFO was full. No callback thread
  takes the GIL per sample: the node's filter loop reads its inputs this way;
* ``put(key, payload, block=False, remote_only=False)``: publish (``block=True`` = BLOCK
  congestion control, for data that must not be lost; otherwise DROP; ``remote_only``: not
  delivered to this transport's own subscribers and inboxes);
* ``queryable(key, handler)``: ``handler(payload) -> reply bytes`` answers queries on a key;
* ``liveliness_token(key)``: a token visible while the session lives;
* ``close()``.

Clients (tests, tools) also use ``get(key, payload, timeout) -> [reply bytes]``. Every declaration
returns a handle with ``undeclare()``.

:class:`ZenohTransport` maps this onto an eclipse-zenoh 1.x session made by
:func:`radical_rt.io.zconfig.make_config` (loopback endpoints only, multicast scouting off).
:class:`InMemoryTransport` connects transports that share an :class:`InMemoryBus` in one process,
with Zenoh's key-expression wildcards ``*`` (one chunk) and ``**`` (any number of chunks); a bus is
either synchronous (callbacks run in the publisher's thread) or threaded (one delivery thread per
subscriber / queryable, in order, like the Zenoh Python binding).
"""

from __future__ import annotations

import functools
import logging
import queue
import re
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from radical_rt.io import zconfig

log = logging.getLogger("radical.transport")

SampleCallback = Callable[[str, bytes], None]
QueryHandler = Callable[[bytes], bytes]


class TransportError(RuntimeError):
    """The transport could not be opened or an operation on it failed (message says why)."""


class Handle(Protocol):
    def undeclare(self) -> None: ...


class Inbox(Protocol):
    """A bounded FIFO of ``(key, payload)`` samples pulled by one consumer thread."""

    def try_recv(self) -> tuple[str, bytes] | None:
        """The next sample, or None at once if there is none."""

    def recv(self) -> tuple[str, bytes] | None:
        """The next sample, waiting for it (GIL released); None after :meth:`wake`."""

    def wake(self) -> None:
        """End one blocked (or the next) :meth:`recv` with None (any thread)."""

    def take_dropped(self) -> dict[str, int]:
        """Samples dropped since the last call because the FIFO was full, per key."""

    def undeclare(self) -> None:
        """Stop receiving (call from the consumer thread, or once it has stopped)."""


class Transport(Protocol):
    """What the node needs from a middleware (see module docstring)."""

    def subscribe(self, key: str, callback: SampleCallback, remote_only: bool = False) -> Handle: ...

    def inbox(self, key: str, capacity: int, wait_s: float = 1.0,
              capacity_bytes: int | None = None) -> Inbox: ...

    def put(self, key: str, payload: bytes, block: bool = False,
            remote_only: bool = False) -> None: ...

    def queryable(self, key: str, handler: QueryHandler) -> Handle: ...

    def liveliness_token(self, key: str) -> Handle: ...

    def get(self, key: str, payload: bytes = b"", timeout: float = 5.0) -> list[bytes]: ...

    def close(self) -> None: ...


# ------------------------------------------------------------------------------------ key exprs
def key_matches(expr: str, key: str) -> bool:
    """Whether a concrete key matches a key expression with ``*`` and ``**`` chunks."""
    return _match(expr.split("/"), key.split("/"))


def _match(e: list[str], k: list[str]) -> bool:
    if not e:
        return not k
    if e[0] == "**":
        return any(_match(e[1:], k[i:]) for i in range(len(k) + 1))
    if not k:
        return False
    return (e[0] == "*" or e[0] == k[0]) and _match(e[1:], k[1:])


# ------------------------------------------------------------------------------------ in memory
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
        self.worker = _Worker(f"inmem-{kind}-{key}") if bus.threaded and kind != "token" else None

    def undeclare(self) -> None:
        self.bus._remove(self)


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
        self._decl: _Decl | None = None

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
        if self._decl is not None:
            self._decl.undeclare()
            self._decl = None


class InMemoryBus:
    """A process-local "network" shared by :class:`InMemoryTransport` instances."""

    def __init__(self, threaded: bool = False) -> None:
        self.threaded = threaded
        self._lock = threading.Lock()
        self._decls: list[_Decl] = []

    def _add(self, d: _Decl) -> _Decl:
        with self._lock:
            self._decls.append(d)
        return d

    def _remove(self, d: _Decl) -> None:
        with self._lock:
            if d in self._decls:
                self._decls.remove(d)
        if d.worker:
            d.worker.stop()

    def _find(self, kind: str, key: str) -> list[_Decl]:
        with self._lock:
            return [d for d in self._decls if d.kind == kind and key_matches(d.key, key)]

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
        d = self.bus._add(_Decl(self.bus, kind, key, fn, owner))
        self._mine.append(d)
        return d

    def subscribe(self, key: str, callback: SampleCallback, remote_only: bool = False) -> _Decl:
        return self._declare("sub", key, callback, self if remote_only else None)

    def inbox(self, key: str, capacity: int, wait_s: float = 1.0,
              capacity_bytes: int | None = None) -> MemInbox:
        box = MemInbox(capacity, wait_s, capacity_bytes)
        box._decl = self.subscribe(key, box.push, remote_only=True)
        return box

    def queryable(self, key: str, handler: QueryHandler) -> _Decl:
        return self._declare("qbl", key, handler)

    def liveliness_token(self, key: str) -> _Decl:
        return self._declare("token", key, None)

    def put(self, key: str, payload: bytes, block: bool = False, remote_only: bool = False) -> None:
        if self.closed:
            raise TransportError("transport closed")
        data = bytes(payload)
        for d in self.bus._find("sub", key):
            if d.owner is self or (remote_only and d in self._mine):
                continue
            if d.worker:
                d.worker.submit(functools.partial(d.fn, key, data))
            else:
                d.fn(key, data)

    def get(self, key: str, payload: bytes = b"", timeout: float = 5.0) -> list[bytes]:
        if self.closed:
            raise TransportError("transport closed")
        replies: list[bytes] = []
        for d in self.bus._find("qbl", key):
            if d.worker is None:
                replies.append(bytes(d.fn(bytes(payload))))
                continue
            done = threading.Event()
            box: list[bytes] = []

            def call(d: _Decl = d, box: list[bytes] = box, done: threading.Event = done) -> None:
                try:
                    box.append(bytes(d.fn(bytes(payload))))
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


# ------------------------------------------------------------------------------------ zenoh
class _ZHandle:
    def __init__(self, obj: Any) -> None:
        self.obj = obj

    def undeclare(self) -> None:
        if self.obj is not None:
            try:
                self.obj.undeclare()
            except Exception as exc:  # already closed session: nothing left to undeclare
                log.debug("undeclare: %s", exc)
            self.obj = None


class _ZInbox:
    """:class:`Inbox` on a Zenoh subscriber with a ``FifoChannel(capacity)`` handler.

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


class ZenohTransport:
    """A :class:`Transport` on one eclipse-zenoh 1.x session (loopback endpoints only).

    mode: "peer" (default), "client" or "router"; listen/connect: ``tcp/127.0.0.1:PORT`` locators;
    config_file: a Zenoh JSON5 file loaded first (endpoints and multicast are still forced by
    :func:`radical_rt.io.zconfig.make_config`); extra: more config key paths.
    """

    ENCODING = "application/msgpack"

    def __init__(self, mode: str = "peer", listen: Sequence[str] = (), connect: Sequence[str] = (),
                 config_file: str | None = None, extra: dict[str, Any] | None = None) -> None:
        import zenoh

        self.zenoh = zenoh  # the zenoh module (1.x API), for the session's helpers
        try:
            cfg = zconfig.make_config(mode, listen, connect, extra=extra, config_file=config_file)
        except zconfig.ZenohConfigError:
            raise
        except Exception as exc:  # zenoh raises ZError for unreadable/invalid files
            raise TransportError(f"bad Zenoh configuration: {_one_line(exc)}") from None
        try:
            self.session = zenoh.open(cfg)
        except Exception as exc:
            raise TransportError(f"cannot open Zenoh session ({mode}, listen={list(listen)}, "
                                 f"connect={list(connect)}): {_one_line(exc)}") from None
        self._pubs: dict[tuple[str, bool, bool], Any] = {}  # (key, block, remote_only)
        self._lock = threading.Lock()
        self._decls: list[_ZHandle] = []
        self.closed = False

    def subscribe(self, key: str, callback: SampleCallback, remote_only: bool = False) -> _ZHandle:
        def on_sample(s: Any) -> None:
            callback(str(s.key_expr), s.payload.to_bytes())

        origin = self.zenoh.Locality.REMOTE if remote_only else None
        return self._keep(self.session.declare_subscriber(key, on_sample, allowed_origin=origin))

    def _publisher(self, key: str, block: bool, remote_only: bool) -> Any:
        with self._lock:
            pub = self._pubs.get((key, block, remote_only))
            if pub is None:
                z = self.zenoh
                cc = z.CongestionControl.BLOCK if block else z.CongestionControl.DROP
                dest = z.Locality.REMOTE if remote_only else z.Locality.ANY
                pub = self.session.declare_publisher(key, encoding=z.Encoding(self.ENCODING),
                                                     congestion_control=cc,
                                                     allowed_destination=dest)
                self._pubs[(key, block, remote_only)] = pub
            return pub

    def put(self, key: str, payload: bytes, block: bool = False, remote_only: bool = False) -> None:
        pub = self._pubs.get((key, block, remote_only)) or self._publisher(key, block, remote_only)
        pub.put(payload)

    def inbox(self, key: str, capacity: int, wait_s: float = 1.0,
              capacity_bytes: int | None = None, max_payload: int | None = None) -> Any:
        """A FIFO of the samples on ``key``; payloads over max_payload bytes are dropped
        without being copied. With ``capacity_bytes``: bounded in payload bytes too
        (:class:`radical_rt.io.zinbox.ZByteInbox`, a callback subscriber; a full FIFO waits
        ``wait_s``, then drops and counts). Without: the pulled ``FifoChannel`` (bounded in
        samples only; a full one back-pressures the session; docs/node.md "Losses and bounds")."""
        if capacity_bytes is not None:
            from radical_rt.io.zinbox import ZByteInbox
            return ZByteInbox(self, key, capacity, wait_s, capacity_bytes, max_payload)
        return _ZInbox(self, key, capacity, max_payload)

    def queryable(self, key: str, handler: QueryHandler) -> _ZHandle:
        def on_query(q: Any) -> None:
            with q:  # dropping the query ends the getter's reply stream
                try:
                    reply = handler(q.payload.to_bytes() if q.payload is not None else b"")
                    q.reply(q.key_expr, reply, encoding=self.zenoh.Encoding(self.ENCODING))
                except Exception as exc:  # never leave a getter waiting for its timeout
                    log.exception("query handler failed")
                    q.reply_err(str(exc).encode())

        return self._keep(self.session.declare_queryable(key, on_query))

    def liveliness_token(self, key: str) -> _ZHandle:
        return self._keep(self.session.liveliness().declare_token(key))

    MATCH_WAIT_S = 2.0  # longest wait for a matching queryable before a get

    def get(self, key: str, payload: bytes = b"", timeout: float = 5.0) -> list[bytes]:
        """Query ``key``. A session that has just connected may not know the routes to the
        queryables yet (a get then returns no reply at once: issue 23, a client right after the
        node's "ready" line): first wait, up to min(timeout, MATCH_WAIT_S), until a querier on
        the key has a matching queryable."""
        querier = self.session.declare_querier(key, timeout=timeout)
        try:
            end = time.monotonic() + min(timeout, self.MATCH_WAIT_S)
            while not querier.matching_status.matching and time.monotonic() < end:
                time.sleep(0.005)
            return self._replies(key, querier.get(payload=payload))
        finally:
            querier.undeclare()

    def _replies(self, key: str, replies: Any) -> list[bytes]:
        out = []
        for r in replies:
            if r.ok is not None:
                out.append(r.ok.payload.to_bytes())
            else:
                err = r.err.payload.to_bytes() if r.err is not None else b""
                raise TransportError(f"query {key} failed: {err!r}")
        return out

    def alive(self, expr: str, timeout: float = 2.0) -> list[str]:
        """Keys of the liveliness tokens alive now that match ``expr``."""
        return sorted(str(r.ok.key_expr) for r in self.session.liveliness().get(expr, timeout=timeout)
                      if r.ok is not None)

    def _keep(self, obj: Any) -> _ZHandle:
        h = _ZHandle(obj)
        self._decls.append(h)
        return h

    def close(self) -> None:
        if self.closed:
            return
        for h in reversed(self._decls):
            h.undeclare()
        with self._lock:
            for pub in self._pubs.values():
                try:
                    pub.undeclare()
                except Exception as exc:
                    log.debug("publisher undeclare: %s", exc)
            self._pubs.clear()
        self.session.close()
        self.closed = True


def _one_line(exc: BaseException) -> str:
    """The error's text on one line, without the source locations zenoh's Rust errors append
    (`` at /root/.cargo/.../lib.rs:62.``)."""
    text = _RUST_LOCATION.sub("", " ".join(str(exc).split())).strip()
    return text or type(exc).__name__


_RUST_LOCATION = re.compile(r"\s+at\s+\S+\.rs:\d+(:\d+)?\.?")
