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
* ``queryable(key, handler, keyed=False)``: ``handler(payload) -> reply bytes`` answers queries on
  a key expression (``keyed=True``: ``handler(query_key, payload)``, the query's own key; a
  handler that returns None sends no reply);
* ``liveliness_token(key)``: a token visible while the session lives;
* ``liveliness_subscribe(key, callback)``: ``callback(token_key, alive)`` for the tokens matching
  ``key`` alive now, then for each that appears or goes (fleets: who is alive, who owns what);
* ``close()``.

Clients (tests, tools) also use ``get(key, payload, timeout, every=False) -> [reply bytes]``
(``every``: every matching queryable answers, not only the best matching one). Every declaration
returns a handle with ``undeclare()``.

This module owns the protocol, its error and the key-expression matching. Two implementations:
:class:`radical_rt.io.zenoh_transport.ZenohTransport` maps it onto an eclipse-zenoh 1.x session
made by :func:`radical_rt.io.zconfig.make_config` (loopback endpoints only, multicast scouting
off; its input FIFOs are in :mod:`radical_rt.io.zinbox`).
:class:`radical_rt.io.mem_transport.InMemoryTransport` connects transports that share an
:class:`~radical_rt.io.mem_transport.InMemoryBus` in one process, with Zenoh's key-expression
wildcards ``*`` (one chunk) and ``**`` (any number of chunks); a bus is either synchronous
(callbacks run in the publisher's thread) or threaded (one delivery thread per subscriber /
queryable, in order, like the Zenoh Python binding).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, Protocol

SampleCallback = Callable[[str, bytes], None]
QueryHandler = Callable[[bytes], bytes | None]
KeyedQueryHandler = Callable[[str, bytes], bytes | None]


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

    def inbox_subscribe(self, box: Any, key: str) -> Handle: ...

    def put(self, key: str, payload: bytes, block: bool = False,
            remote_only: bool = False) -> None: ...

    def queryable(self, key: str, handler: QueryHandler | KeyedQueryHandler,
                  keyed: bool = False) -> Handle: ...

    def liveliness_token(self, key: str) -> Handle: ...

    def liveliness_subscribe(self, key: str, callback: Callable[[str, bool], None]) -> Handle: ...

    def get(self, key: str, payload: bytes = b"", timeout: float = 5.0,
            every: bool = False) -> list[bytes]: ...

    def close(self) -> None: ...


# ------------------------------------------------------------------------------------ key exprs
def key_matches(expr: str, key: str) -> bool:
    """Whether a concrete key matches a key expression with ``*`` and ``**`` chunks."""
    return _match(expr.split("/"), key.split("/"))


def key_intersects(a: str, b: str) -> bool:
    """Whether two key expressions (each with ``*`` and ``**`` chunks) share a key: a query
    ``x/*`` reaches a queryable ``x/y``, and a query ``x/y`` one on ``x/*``."""
    return _inter(tuple(a.split("/")), tuple(b.split("/")))


@functools.lru_cache(maxsize=4096)
def _inter(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    if not a or not b:
        return all(c == "**" for c in a + b)
    if a[0] == "**":
        return _inter(a[1:], b) or _inter(a, b[1:])
    if b[0] == "**":
        return _inter(a, b[1:]) or _inter(a[1:], b)
    return (a[0] == b[0] or "*" in (a[0], b[0])) and _inter(a[1:], b[1:])


def _match(e: list[str], k: list[str]) -> bool:
    if not e:
        return not k
    if e[0] == "**":
        return any(_match(e[1:], k[i:]) for i in range(len(k) + 1))
    if not k:
        return False
    return (e[0] == "*" or e[0] == k[0]) and _match(e[1:], k[1:])
