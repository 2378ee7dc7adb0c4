"""Live data for the dashboards: a latest-value store and its Zenoh feeder.

The Zenoh subscriber callbacks do nothing but store the raw payload of the newest message per
(vehicle, topic) with its receive time on this host's monotonic clock, and count it — the
RingChannel(1) pattern: a slow UI never backs up Zenoh, it just sees fewer intermediate packets.
The UI's refresh timer *pulls* (:meth:`LatestStore.latest`), which decodes the msgpack payload once
per new message. Fault messages are events rather than states, so the store also keeps a short
bounded history of them (the newest ``fault_keep`` per vehicle). The plotted topics
(``history_topics``, tlm/large by default) also keep every packet received, raw, in a bounded
ring (``history_keep`` per vehicle): a history drawn from them has no gaps however slowly the UI
polls (:meth:`LatestStore.since`).

Any object that calls :meth:`LatestStore.put` is a data source: :class:`ZenohSource` (live
traffic), or a test / an archive reader putting decoded dicts directly (in-memory source).
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgpack

from monitors.common import VEHICLE_RE, monitor_config, vehicle_of

#: Topics a monitor subscribes to (CONTRACT §2 outputs of the filter node).
TOPICS = ("tlm/large", "tlm/medium", "tlm/small", "fault", "diag")


@dataclass
class Snapshot:
    """The newest message of one (vehicle, topic) as the UI sees it at a pull."""

    msg: dict[str, Any] | None  # decoded payload (None: nothing yet, or undecodable)
    age_s: float | None  # receiver monotonic now − receive time of that message
    count: int  # messages received so far
    rate_hz: float  # receive rate over the last ``rate_window_s``
    bad: int  # undecodable payloads seen at pulls
    recv: float | None  # receive time (monotonic) of the newest message


class _Slot:
    __slots__ = ("data", "recv", "count", "times", "first", "dec_count", "dec_msg", "bad")

    def __init__(self) -> None:
        self.data: Any = None
        self.recv: float | None = None
        self.first: float | None = None
        self.count = 0
        self.times: deque[float] = deque(maxlen=1024)
        self.dec_count = -1
        self.dec_msg: dict[str, Any] | None = None
        self.bad = 0


def decode(payload: Any) -> dict[str, Any] | None:
    """A msgpack map payload (bytes) or an already decoded dict → dict, else None."""
    if isinstance(payload, dict):
        return payload
    try:
        m = msgpack.unpackb(bytes(payload), raw=False, strict_map_key=False)
    except Exception:
        return None
    return m if isinstance(m, dict) else None


class LatestStore:
    """Thread-safe newest-message store per (vehicle, topic), plus liveliness and fault events.

    ``clock``: the receiver's monotonic clock (injectable for tests). Writers (Zenoh callbacks)
    call :meth:`put`/:meth:`set_alive` only; readers pull with :meth:`latest`, :meth:`faults`.
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, rate_window_s: float = 5.0,
                 fault_keep: int = 100, history_topics: tuple[str, ...] = ("tlm/large",),
                 history_keep: int = 4096) -> None:
        self.clock = clock
        self.rate_window_s = rate_window_s
        self._lock = threading.Lock()
        self._slots: dict[tuple[str, str], _Slot] = {}
        self._alive: dict[str, bool] = {}
        self._faults: dict[str, deque[tuple[int, float, Any]]] = {}
        self._fault_n: dict[str, int] = {}
        self._fault_keep = fault_keep
        self.history_topics, self.history_keep = history_topics, history_keep
        self._hist: dict[tuple[str, str], deque[tuple[int, Any]]] = {}
        self.version = 0  # bumped on every put (cheap change detection)

    # -- writers (any thread) ------------------------------------------------------------------
    def put(self, vehicle: str, topic: str, payload: Any, now: float | None = None) -> None:
        """Store the newest message (raw msgpack bytes or a decoded dict) of vehicle/topic."""
        t = self.clock() if now is None else now
        with self._lock:
            slot = self._slots.get((vehicle, topic))
            if slot is None:
                slot = self._slots[(vehicle, topic)] = _Slot()
                slot.first = t
            slot.data, slot.recv = payload, t
            slot.count += 1
            slot.times.append(t)
            if topic in self.history_topics:
                self._hist.setdefault((vehicle, topic), deque(maxlen=self.history_keep)).append(
                    (slot.count, payload))
            if topic == "fault":
                n = self._fault_n[vehicle] = self._fault_n.get(vehicle, 0) + 1
                self._faults.setdefault(vehicle, deque(maxlen=self._fault_keep)).append(
                    (n, t, payload))
            self.version += 1

    def set_alive(self, vehicle: str, alive: bool) -> None:
        with self._lock:
            self._alive[vehicle] = alive
            self.version += 1

    # -- readers (UI thread) -------------------------------------------------------------------
    def vehicles(self) -> list[str]:
        """Vehicles seen in traffic or liveliness, sorted."""
        with self._lock:
            return sorted({v for v, _t in self._slots} | set(self._alive))

    def alive(self, vehicle: str) -> bool | None:
        """Liveliness of the vehicle's filter node (None: never seen a token)."""
        with self._lock:
            return self._alive.get(vehicle)

    def latest(self, vehicle: str, topic: str, now: float | None = None) -> Snapshot:
        t = self.clock() if now is None else now
        with self._lock:
            slot = self._slots.get((vehicle, topic))
            if slot is None:
                return Snapshot(None, None, 0, 0.0, 0, None)
            if slot.dec_count != slot.count:
                slot.dec_msg = decode(slot.data)
                if slot.dec_msg is None:
                    slot.bad += 1
                slot.dec_count = slot.count
            w = self.rate_window_s
            k = sum(1 for x in slot.times if t - x <= w)
            span = min(w, t - (slot.first or t))
            rate = k / span if span > 0.2 else 0.0
            return Snapshot(slot.dec_msg, t - slot.recv if slot.recv is not None else None,
                            slot.count, rate, slot.bad, slot.recv)

    def faults(self, vehicle: str, after: int = 0) -> list[tuple[int, float, dict[str, Any]]]:
        """Fault messages numbered > ``after`` still held: (number, receive time, message)."""
        with self._lock:
            items = [(n, t, p) for n, t, p in self._faults.get(vehicle, ()) if n > after]
        out = []
        for n, t, p in items:
            m = decode(p)
            if m is not None:
                out.append((n, t, m))
        return out

    def since(self, vehicle: str, topic: str, after: int = 0) -> list[tuple[int, dict[str, Any]]]:
        """Every packet of a history topic numbered > ``after`` still in the ring, oldest first:
        (number = the topic's count when it arrived, decoded message); undecodable ones dropped."""
        with self._lock:
            items = [(n, p) for n, p in self._hist.get((vehicle, topic), ()) if n > after]
        return [(n, m) for n, p in items if (m := decode(p)) is not None]

    def last_flags(self, vehicle: str) -> tuple[int | None, str | None]:
        """Flags of the most recently received of tlm/small, tlm/medium, tlm/large and fault,
        and the topic they came from."""
        best: tuple[float, int | None, str] | None = None
        for topic in ("tlm/small", "tlm/medium", "tlm/large", "fault"):
            s = self.latest(vehicle, topic)
            if s.msg is not None and s.recv is not None and "flags" in s.msg:
                try:
                    f = int(s.msg["flags"])
                except (TypeError, ValueError):
                    continue
                if best is None or s.recv >= best[0]:
                    best = (s.recv, f, topic)
        return (best[1], best[2]) if best else (None, None)


class ZenohSource:
    """Feeds a :class:`LatestStore` from ``radical/<vehicle>/{tlm/*,fault,diag}`` and the
    liveliness tokens ``radical/<vehicle>/alive/filter`` (vehicle ``None``: all vehicles).

    The session is made by :func:`radical_rt.io.zconfig.make_config` (loopback endpoints, multicast
    scouting off); with neither listen nor connect it connects to the node's default endpoint.
    """

    def __init__(self, store: LatestStore, vehicle: str | None = None, listen: str | None = None,
                 connect: str | None = None, zenoh_config: str | None = None,
                 auth: Any = None) -> None:
        if vehicle is not None and not VEHICLE_RE.match(vehicle):
            raise ValueError(f"vehicle {vehicle!r} must match [a-z0-9_-]+")
        self.store, self.vehicle = store, vehicle
        self.listen, self.connect, self.zenoh_config = listen, connect, zenoh_config
        self.auth = auth  # radical_rt.io.zauth.SessionAuth (--auth DIR --role ROLE) or None
        self.session: Any = None
        self._decls: list[Any] = []

    def start(self) -> ZenohSource:
        import zenoh

        cfg = monitor_config(self.listen, self.connect, self.zenoh_config, self.auth)
        self.session = zenoh.open(cfg)
        v = self.vehicle or "*"
        store = self.store

        def on_sample(sample: Any) -> None:
            vt = vehicle_of(str(sample.key_expr))
            if vt is not None and vt[1] in TOPICS:
                store.put(vt[0], vt[1], sample.payload.to_bytes())

        def on_token(sample: Any) -> None:
            vt = vehicle_of(str(sample.key_expr))
            if vt is not None:
                store.set_alive(vt[0], sample.kind == zenoh.SampleKind.PUT)

        for key in (f"radical/{v}/tlm/*", f"radical/{v}/fault", f"radical/{v}/diag"):
            self._decls.append(self.session.declare_subscriber(key, on_sample))
        self._decls.append(self.session.liveliness().declare_subscriber(
            f"radical/{v}/alive/filter", on_token, history=True))
        return self

    def close(self) -> None:
        for d in self._decls:
            try:
                d.undeclare()
            except Exception:
                pass
        self._decls.clear()
        if self.session is not None:
            try:
                self.session.close()
            except Exception:
                pass
            self.session = None


def pick_vehicle(store: LatestStore, wanted: str | None) -> str | None:
    """The vehicle to show: the one asked for, else the first one seen (alive ones first)."""
    if wanted:
        return wanted
    vs = store.vehicles()
    alive = [v for v in vs if store.alive(v)]
    return (alive or vs)[0] if (alive or vs) else None

