"""The Zenoh transport: :class:`ZenohTransport`, the node's transport protocol
(:mod:`radical_rt.io.transport`) on one eclipse-zenoh 1.x session made by
:func:`radical_rt.io.zconfig.make_config` (loopback endpoints only, multicast scouting off).

Its input FIFOs (:class:`radical_rt.io.zinbox.ZInbox`, :class:`radical_rt.io.zinbox.ZByteInbox`)
are in :mod:`radical_rt.io.zinbox`.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Sequence
from typing import Any

from radical_rt.io import zconfig
from radical_rt.io.transport import KeyedQueryHandler, QueryHandler, SampleCallback, TransportError
from radical_rt.io.zinbox import ZByteInbox, ZInbox

log = logging.getLogger("radical.transport")


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
        ``wait_s``, then drops and counts). Without: the pulled ``FifoChannel`` (:class:`radical_rt.io.zinbox.ZInbox`, bounded in
        samples only; a full one back-pressures the session; docs/node.md "Losses and bounds")."""
        if capacity_bytes is not None:
            return ZByteInbox(self, key, capacity, wait_s, capacity_bytes, max_payload)
        return ZInbox(self, key, capacity, max_payload)

    def inbox_subscribe(self, box: ZByteInbox, key: str) -> _ZHandle:
        """One more subscription on ``key`` feeding the byte-bounded FIFO ``box`` (a fleet
        worker's one FIFO for the vehicles it holds or serves; its size checks apply)."""
        handler = self.zenoh.handlers.Callback(box.on_sample, indirect=False)
        return self._keep(self.session.declare_subscriber(key, handler))

    def queryable(self, key: str, handler: QueryHandler | KeyedQueryHandler,
                  keyed: bool = False) -> _ZHandle:
        def on_query(q: Any) -> None:
            with q:  # dropping the query ends the getter's reply stream
                try:
                    payload = q.payload.to_bytes() if q.payload is not None else b""
                    reply = handler(str(q.key_expr), payload) if keyed else handler(payload)
                    if reply is not None:  # None: nothing to say (no reply)
                        q.reply(q.key_expr, reply, encoding=self.zenoh.Encoding(self.ENCODING))
                except Exception as exc:  # never leave a getter waiting for its timeout
                    log.exception("query handler failed")
                    q.reply_err(str(exc).encode())

        return self._keep(self.session.declare_queryable(key, on_query))

    def liveliness_token(self, key: str) -> _ZHandle:
        return self._keep(self.session.liveliness().declare_token(key))

    def liveliness_subscribe(self, key: str, callback: Any) -> _ZHandle:
        """``callback(token_key, alive)`` for every token matching ``key``: those alive now
        (history), then each one that appears or goes (a session that dies: after its lease)."""
        put = self.zenoh.SampleKind.PUT

        def on_token(s: Any) -> None:
            callback(str(s.key_expr), s.kind == put)

        return self._keep(self.session.liveliness().declare_subscriber(key, on_token, history=True))

    def connected(self) -> bool:
        """Whether the session has a link to a router or a peer now."""
        info = self.session.info
        return bool(list(info.routers_zid())) or bool(list(info.peers_zid()))

    MATCH_WAIT_S = 2.0  # longest wait for a matching queryable before a get

    def get(self, key: str, payload: bytes = b"", timeout: float = 5.0,
            every: bool = False) -> list[bytes]:
        """Query ``key``. A session that has just connected may not know the routes to the
        queryables yet (a get then returns no reply at once: issue 23, a client right after the
        node's "ready" line): first wait, up to min(timeout, MATCH_WAIT_S), until a querier on
        the key has a matching queryable. every: ask every matching queryable and keep every
        reply (Zenoh's default asks the best matching one only)."""
        z = self.zenoh
        kw: dict[str, Any] = ({"target": z.QueryTarget.ALL, "consolidation": z.ConsolidationMode.NONE}
                              if every else {})
        querier = self.session.declare_querier(key, timeout=timeout, **kw)
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
