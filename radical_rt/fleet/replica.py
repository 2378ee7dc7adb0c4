"""Checkpoints that survive their worker: every worker of a fleet holds the latest checkpoint of
every vehicle of the fleet (docs/fleet.md, "Checkpoints").

Why replicated over Zenoh rather than a store: a store the fleet serves is one more process that
must itself survive; here the owner publishes each periodic checkpoint of a vehicle once (BLOCK
congestion control) on ``radical-fleet/<fleet>/ckpt/<vehicle>`` and every live worker keeps the
newest one in memory, so a survivor that takes a vehicle over already holds its state. A worker
that joins later asks the others (a queryable on the same keys answers with what it holds).

The payload is a msgpack envelope ``{"v": 1, "fleet", "vehicle", "worker", "seq", "t_wall",
"final", "handover", "cut", "ckpt"}`` (``final``: written as its owner let the vehicle go;
``handover``: at a cut, ``cut`` the digest of the last input it fed) where ``ckpt`` is :func:`radical_rt.io.checkpoint.dumps` of that one vehicle (schema
and SHA-256 checked on receipt). Of two checkpoints of a vehicle the one with the later
``(t_wall, worker, seq)`` is kept. Malformed or damaged envelopes are counted and ignored.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

import msgpack

from radical_rt.io import checkpoint as ckpt
from radical_rt.io.transport import Transport

log = logging.getLogger("radical.fleet")


def fleet_prefix(fleet: str) -> str:
    """Key prefix of a fleet's own keys: ``radical-fleet/<fleet>/``."""
    return f"radical-fleet/{fleet}/"


@dataclass(frozen=True)
class Replica:
    """One vehicle's newest checkpoint as held: who wrote it, when, and the bytes."""

    vehicle: str
    worker: str
    seq: int
    t_wall: float
    data: bytes  # checkpoint.dumps({vehicle: state})
    final: bool = False  # written when its owner let the vehicle go (nothing after it was lost)
    cut: bytes | None = None  # with a handover: the digest of the last input its owner fed
    handover: bool = False  # its owner stopped at a cut the next owner holds the inputs after

    def order(self) -> tuple[float, str, int]:
        return (self.t_wall, self.worker, self.seq)

    def state(self) -> dict[str, Any]:
        """The captured vehicle state (checksum verified); CheckpointError if damaged."""
        doc = ckpt.loads(self.data, f"replica of {self.vehicle} by {self.worker}")
        st = doc["vehicles"].get(self.vehicle)
        if st is None:
            raise ckpt.CheckpointError(f"replica of {self.vehicle}: holds no such vehicle")
        return st


class CheckpointReplica:
    """The fleet's checkpoint replica held by one worker (thread-safe)."""

    def __init__(self, transport: Transport, fleet: str, worker: str) -> None:
        self.t, self.fleet, self.worker = transport, fleet, worker
        self.key = fleet_prefix(fleet) + "ckpt/"
        self._lock = threading.Lock()
        self._held: dict[str, Replica] = {}
        self._seq = 0
        self.rejected = 0  # envelopes refused (malformed, damaged, another fleet's)
        self._decls = [transport.subscribe(self.key + "*", self._on_sample, remote_only=True),
                       transport.queryable(self.key + "*", self._on_query, keyed=True)]

    def publish(self, vehicle: str, state: dict[str, Any], final: bool = False,
                handover: bool = False, cut: bytes | None = None) -> Replica:
        """Hold and publish a new checkpoint of ``vehicle`` (``checkpoint.capture`` output);
        ``final``: the last one before this worker lets the vehicle go; ``handover``/``cut``:
        it stopped at a cut, ``cut`` the digest of the last input it fed (None: none)."""
        with self._lock:
            self._seq += 1
            rep = Replica(vehicle, self.worker, self._seq, time.time(),
                          ckpt.dumps({vehicle: state}), final, cut, handover)
        self._keep(rep)
        self.t.put(self.key + vehicle, self._envelope(rep), block=True, remote_only=True)
        return rep

    def latest(self, vehicle: str) -> Replica | None:
        """The newest checkpoint of ``vehicle`` held here."""
        with self._lock:
            return self._held.get(vehicle)

    def fetch(self, vehicle: str, timeout: float = 2.0) -> Replica | None:
        """The newest checkpoint of ``vehicle`` held here or by any other worker that answers."""
        try:
            replies = self.t.get(self.key + vehicle, b"", timeout=timeout, every=True)
        except Exception as exc:  # no route, closed session: what we hold is the answer
            log.debug("fetch %s: %s", vehicle, exc)
            replies = []
        for data in replies:
            rep = self._decode(data)
            if rep is not None:
                self._keep(rep)
        return self.latest(vehicle)

    def vehicles(self) -> dict[str, Replica]:
        with self._lock:
            return dict(self._held)

    def close(self) -> None:
        for d in self._decls:
            d.undeclare()
        self._decls = []

    # ------------------------------------------------------------------ internals
    def _envelope(self, rep: Replica) -> bytes:
        return msgpack.packb({"v": 1, "fleet": self.fleet, "vehicle": rep.vehicle,
                              "worker": rep.worker, "seq": rep.seq, "t_wall": rep.t_wall,
                              "final": rep.final, "handover": rep.handover, "cut": rep.cut,
                              "ckpt": rep.data}, use_bin_type=True)

    def _keep(self, rep: Replica) -> None:
        with self._lock:
            old = self._held.get(rep.vehicle)
            if old is None or rep.order() > old.order():
                self._held[rep.vehicle] = rep

    def _decode(self, data: bytes) -> Replica | None:
        try:
            m = msgpack.unpackb(data, raw=False)
            cut = m.get("cut")
            rep = Replica(str(m["vehicle"]), str(m["worker"]), int(m["seq"]),
                          float(m["t_wall"]), bytes(m["ckpt"]), m.get("final") is True,
                          bytes(cut) if isinstance(cut, bytes) else None,
                          m.get("handover") is True)
            if m.get("fleet") != self.fleet:
                raise ValueError(f"fleet {m.get('fleet')!r}")
            rep.state()  # schema and checksum, before it may replace a good one
        except Exception as exc:
            with self._lock:
                self.rejected += 1
            log.warning("fleet %s: checkpoint replica refused: %s", self.fleet, exc)
            return None
        return rep

    def _on_sample(self, key: str, data: bytes) -> None:
        rep = self._decode(data)
        if rep is not None:
            self._keep(rep)

    def _on_query(self, key: str, payload: bytes) -> bytes | None:
        vehicle = key.rsplit("/", 1)[-1]
        rep = self.latest(vehicle)
        return self._envelope(rep) if rep is not None else None  # nothing held: no reply
