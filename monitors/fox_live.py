"""Live Foxglove / Lichtblick bridge: ``radical monitor foxglove --vehicle V [--port P]``.

A Foxglove WebSocket server (the official ``foxglove-sdk``, bound to 127.0.0.1 only) that
republishes a filter node's outputs live, in the schemas of ``radical export --foxglove``
(:mod:`monitors.fox_convert`): ``/tlm/small``, ``/tlm/medium``, ``/tlm/large``, ``/fault``,
``/diag`` as JSON, plus ``/tf/body``, ``/tf/st1``, ``/tf/st2`` (``foxglove.FrameTransform``),
``/log/faults`` (``foxglove.Log``: fault-flag changes, and the node's liveliness token appearing
or going away) and ``/paper/calibration`` (paper units). Open ``ws://127.0.0.1:P`` in the
Foxglove app or Lichtblick ("Foxglove WebSocket" connection).

The derived channels are advertised at start; a source channel when its first message arrives,
with the contract schema merged with that first message's shape (later extra fields still reach
the panels). Message
timestamps are bus time (as in the archives), not wall time.

Zenoh: a peer session made by :func:`radical_rt.io.zconfig.make_config` (loopback endpoints,
multicast off; default: connect to the node's ``tcp/127.0.0.1:7448``). Its callbacks only queue
the payloads; one worker thread decodes, converts and logs them (a slow browser never blocks
Zenoh: the SDK drops the oldest data message for a client whose queue is full).
"""

from __future__ import annotations

import json
import queue
import signal
import sys
import threading
import time
from typing import Any

import msgpack

from monitors.common import monitor_config, vehicle_of
from monitors.fox_convert import DERIVED_SCHEMAS, LOG_TOPIC, FoxgloveConverter, stamp
from monitors.fox_schema import LOG_LEVELS, SchemaBuilder, known_schema

OUTPUT_TOPICS = ("tlm/small", "tlm/medium", "tlm/large", "fault", "diag")


class FoxgloveBridge:
    """Zenoh ``radical/<vehicle>/…`` outputs → Foxglove WebSocket server on 127.0.0.1:port."""

    def __init__(self, vehicle: str, port: int = 8765, listen: str | None = None,
                 connect: str | None = None, zenoh_config: str | None = None,
                 queue_size: int = 10000, auth: Any = None) -> None:
        self.vehicle, self.port = vehicle, port
        self.listen, self.connect, self.zenoh_config = listen, connect, zenoh_config
        self.auth = auth  # radical_rt.io.zauth.SessionAuth (--auth DIR --role ROLE) or None
        self._q: queue.Queue[tuple[str, Any]] = queue.Queue(maxsize=queue_size)
        self._stop = threading.Event()
        self._conv = FoxgloveConverter()
        self._channels: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.dropped = 0
        self.undecodable = 0
        self.session: Any = None
        self.server: Any = None
        self._decls: list[Any] = []
        self._worker: threading.Thread | None = None
        self._last_ns = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> FoxgloveBridge:
        import foxglove
        import zenoh


        self._ctx = foxglove.Context()
        self.server = foxglove.start_server(name=f"radical-rt {self.vehicle}", host="127.0.0.1",
                                            port=self.port, context=self._ctx)
        for topic in DERIVED_SCHEMAS:  # known schemas: advertised at once (panels can be set up)
            if "truth" not in topic:  # the node publishes no truth
                self._channels[topic] = self._channel(topic, {})
        cfg = monitor_config(self.listen, self.connect, self.zenoh_config, self.auth)
        try:
            self.session = zenoh.open(cfg)
        except Exception:
            self.server.stop()
            raise
        v = self.vehicle

        def on_sample(sample: Any) -> None:
            vt = vehicle_of(str(sample.key_expr))
            if vt is not None and vt[1] in OUTPUT_TOPICS:
                self._put(("/" + vt[1], sample.payload.to_bytes()))

        def on_token(sample: Any) -> None:
            self._put(("alive", sample.kind == zenoh.SampleKind.PUT))

        for key in (f"radical/{v}/tlm/*", f"radical/{v}/fault", f"radical/{v}/diag"):
            self._decls.append(self.session.declare_subscriber(key, on_sample))
        self._decls.append(self.session.liveliness().declare_subscriber(
            f"radical/{v}/alive/filter", on_token, history=True))
        self._worker = threading.Thread(target=self._run, name="foxglove-bridge", daemon=True)
        self._worker.start()
        return self

    def close(self) -> None:
        self._stop.set()
        for d in self._decls:
            try:
                d.undeclare()
            except Exception:
                pass
        self._decls.clear()
        if self._worker is not None:
            self._worker.join(timeout=2.0)
        if self.session is not None:
            try:
                self.session.close()
            except Exception:
                pass
            self.session = None
        if self.server is not None:
            self.server.stop()
            self.server = None

    # ------------------------------------------------------------------ data path
    def _put(self, item: tuple[str, Any]) -> None:
        try:
            self._q.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                topic, payload = self._q.get(timeout=0.1)
            except queue.Empty:
                continue
            try:
                self.handle(topic, payload)
            except Exception as e:  # one bad message never stops the bridge
                self.undecodable += 1
                print(f"radical monitor foxglove: {topic}: {type(e).__name__}: {e}",
                      file=sys.stderr)

    def handle(self, topic: str, payload: Any) -> None:
        """Convert one Zenoh payload (or a liveliness change) and log it to the server."""
        if topic == "alive":
            text = f"filter node {self.vehicle} " + ("alive" if payload else "gone")
            self._log(LOG_TOPIC, {"timestamp": stamp(self._last_ns),
                                  "level": LOG_LEVELS["INFO" if payload else "WARNING"],
                                  "message": text, "name": "radical.liveliness", "file": "",
                                  "line": 0}, self._last_ns)
            return
        msg = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        if not isinstance(msg, dict):
            self.undecodable += 1
            return
        t = msg.get("t")
        ns = max(int(round(float(t) * 1e9)), 0) if isinstance(t, int | float) else self._last_ns
        self._last_ns = max(self._last_ns, ns)
        for out_topic, jm in self._conv.convert(topic, ns, msg):
            self._log(out_topic, jm, ns)

    def _log(self, topic: str, msg: dict[str, Any], ns: int) -> None:
        ch = self._channels.get(topic)
        if ch is None:
            ch = self._channels[topic] = self._channel(topic, msg)
        ch.log(json.dumps(msg, separators=(",", ":"), allow_nan=False).encode(), log_time=ns)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def _channel(self, topic: str, first: dict[str, Any]) -> Any:
        import foxglove

        if topic in DERIVED_SCHEMAS:
            name, schema = DERIVED_SCHEMAS[topic]
        else:
            known = known_schema(topic)
            b = SchemaBuilder("radical." + topic.lstrip("/").replace("/", "."),
                              (known or {}).get("description") or f"{topic} (SI units)", known)
            b.observe(first)
            schema = b.schema()
            name = schema["title"]
        sch = foxglove.Schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode())
        return foxglove.Channel(topic, schema=sch, message_encoding="json", context=self._ctx)


def serve(vehicle: str, port: int, listen: str | None, connect: str | None,
          zenoh_config: str | None, duration: float | None = None, auth: Any = None) -> int:
    """Run the bridge until SIGINT/SIGTERM (or ``duration`` s); exit status."""
    try:
        bridge = FoxgloveBridge(vehicle, port, listen, connect, zenoh_config, auth=auth).start()
    except Exception as e:
        print(f"radical monitor foxglove: cannot start: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    print(f"radical monitor foxglove: ws://127.0.0.1:{bridge.server.port} (vehicle {vehicle}); "
          "open it in Foxglove or Lichtblick", flush=True)
    t_end = None if duration is None else time.monotonic() + duration
    try:
        while not stop.wait(1.0):
            if t_end is not None and time.monotonic() >= t_end:
                break
    finally:
        bridge.close()
        n = sum(bridge.counts.values())
        print(f"radical monitor foxglove: {n} messages on {len(bridge.counts)} channels, "
              f"{bridge.dropped} dropped, {bridge.undecodable} undecodable", flush=True)
    return 0
