"""The one node a fleet worker runs: a :class:`~radical_rt.apps.node.FilterNode` whose set of
vehicles changes while it runs, with a handover that neither loses nor repeats an input
(docs/fleet.md, "Handover").

One input FIFO and ONE filter loop serve every vehicle the worker holds or serves (a loop
thread per vehicle would compete for the GIL). Each vehicle has its own subscription
``radical/<V>/*`` into that FIFO, declared when the worker starts holding or taking it and
undeclared when it lets it go, so a worker receives only what it holds or serves. A vehicle is
in one of three states, changed only by the filter loop when it reaches a marker in the FIFO:

* **held** (:meth:`FleetNode.hold`): its inputs are kept in arrival order, not fed (a handover's
  next owner holds them from before it says so);
* **serving** (marker ``@serve``, put by :meth:`FleetNode.serve_vehicle` after the worker
  restored the replica): the held inputs the old owner already fed are dropped (those up to and
  including the one with the final checkpoint's digest; when none matches, the cut came before
  the hold began and all are new), the rest are fed, and from then on the vehicle's inputs are
  fed as they come; its command queryables and liveliness token are declared;
* **cut** (marker ``@cut``, :meth:`FleetNode.cut`): everything queued before the marker has
  been fed, nothing after it will be; the digest of the last input fed goes with the final
  checkpoint to the next owner.

Why nothing is lost: the next owner declares its hold token only after its subscription, and
the old owner places its marker only after it has seen that token; a sample routed before the
new subscription reached the old owner before the token (one link, in order) and so lies before
the marker; a sample routed after it reaches both, and the digest removes the doubles.

Periodic checkpoints are staggered: each served vehicle is written every ``checkpoint_every_s``,
one vehicle per housekeeping step, at a phase of its own (50 vehicles written at once would
stall the loop by tens of milliseconds).
"""

from __future__ import annotations

import hashlib
import logging
import threading
from collections import deque
from typing import Any

from radical_rt.apps import commands
from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_vehicle import Vehicle, note_reject
from radical_rt.io import checkpoint as ckpt
from radical_rt.io.zenoh_transport import ZenohTransport
from radical_rt.stream.eos import EOS_TOPIC
from radical_rt.stream.processor import INPUT_TOPICS, StreamProcessor
from radical_rt.stream.stream_guard import MAX_PAYLOAD_BYTES

log = logging.getLogger("radical.fleet")
_FED = frozenset((*INPUT_TOPICS, EOS_TOPIC))
HELD, SERVING, CUT = "held", "serving", "cut"


def input_digest(topic: str, payload: bytes) -> bytes:
    """16 bytes of BLAKE2b over an input's topic and payload (it identifies one message)."""
    return hashlib.blake2b(topic.encode() + b"\x00" + payload, digest_size=16).digest()


def stagger(name: str) -> float:
    """A fixed fraction in [0, 1) per vehicle name: the phase of its periodic checkpoint."""
    return int.from_bytes(hashlib.blake2b(name.encode(), digest_size=8).digest(), "big") / 2.0**64


class Slot:
    """What the fleet node keeps for one vehicle it holds or serves (see the module docstring).
    ``held`` and the state are touched by the filter loop only, once the slot is registered."""

    def __init__(self, vehicle: Vehicle, held_bound: int) -> None:
        self.vehicle, self.state = vehicle, HELD
        self.held: deque[tuple[str, bytes]] = deque()
        self.held_bytes, self.held_bound, self.held_dropped = 0, held_bound, 0
        self.sub: Any = None  # its subscription into the node's FIFO
        self.handles: list[Any] = []  # its queryables and liveliness token while serving
        self.last_fed: tuple[str, bytes] | None = None  # (topic, payload) of the last input fed
        self.skipped = 0  # held inputs dropped at the switch (the old owner had fed them)
        self.next_ckpt = float("inf")
        self.served, self.done = threading.Event(), threading.Event()

    def keep(self, key: str, data: bytes) -> None:
        """Filter loop: hold one input (over the bound: dropped and counted)."""
        if self.held_bytes + len(data) > self.held_bound:
            self.held_dropped += 1
            return
        self.held.append((key, data))
        self.held_bytes += len(data)

    def skip_through(self, digest: bytes | None) -> int:
        """Drop the held inputs up to and including the one whose digest is ``digest``; how
        many (0: none matched, all are new)."""
        prefix = self.vehicle.prefix
        for i, (key, data) in enumerate(self.held):
            topic = key[len(prefix):]
            if digest is not None and topic in _FED and input_digest(topic, data) == digest:
                for _ in range(i + 1):
                    self.held.popleft()
                return i + 1
        return 0


class FleetNode(FilterNode):
    """One filter loop for a changing set of vehicles (see the module docstring).

    inbox_key: the key of the FIFO's own subscription (the worker's private key; the vehicles'
    subscriptions are added per vehicle). Other options: :class:`FilterNode`.
    """

    MIN_VEHICLES = 0
    # periodic replica checkpoints are only restored as a new stream (a crash): without the FDI
    # history (ckpt.capture); a handover's final checkpoint carries it (FleetWorker._release)
    CHECKPOINT_HISTORY = False
    SERVE, CUT = "@serve", "@cut"  # the markers' topics (no input topic starts with @)

    def __init__(self, transport: Any, *, inbox_key: str, **kw: Any) -> None:
        if kw.get("queue_bytes", 1) is None:
            raise ValueError("a fleet node needs a byte-bounded input FIFO (queue_bytes)")
        super().__init__(transport, {}, **kw)
        self.inbox_key = inbox_key
        self.slots: dict[str, Slot] = {}  # replaced, never changed in place (read by the loop)
        self._next_any = float("inf")  # the earliest periodic checkpoint due

    # ------------------------------------------------------------------ controller thread
    def open_inbox(self) -> None:
        kw: dict[str, Any] = {"capacity_bytes": self.queue_bytes}
        if isinstance(self.transport, ZenohTransport):
            kw["max_payload"] = self.max_payload_bytes or MAX_PAYLOAD_BYTES
        self._inbox = self.transport.inbox(self.inbox_key, self.queue_size, self.queue_wait_s, **kw)

    def hold(self, name: str, sp: StreamProcessor) -> None:
        """Subscribe to ``name``'s inputs and hold them (not fed) until :meth:`serve_vehicle`."""
        if name in self.slots:
            raise ValueError(f"{name} is already held or served here")
        if self.max_payload_bytes is not None:
            sp.max_payload_bytes = self.max_payload_bytes
        slot = Slot(Vehicle(self, name, sp), self.queue_bytes or 1 << 26)
        self.slots = {**self.slots, name: slot}
        slot.sub = self.transport.inbox_subscribe(self._inbox, slot.vehicle.prefix + "*")

    def processor(self, name: str) -> StreamProcessor:
        """The StreamProcessor of a held or served vehicle."""
        return self.slots[name].vehicle.sp

    def vehicle(self, name: str) -> Vehicle | None:
        """The Vehicle of a held or served vehicle (None: neither)."""
        slot = self.slots.get(name)
        return slot.vehicle if slot is not None else None

    def replace_processor(self, name: str, sp: StreamProcessor) -> None:
        """A held vehicle starts again from ``sp`` (a replica that could not be restored)."""
        slot = self.slots[name]
        if slot.state != HELD:
            raise RuntimeError(f"{name} is not held")
        slot.vehicle.sp = sp

    def serve_vehicle(self, name: str, digest: bytes | None = None,
                      fleet_info: dict[str, Any] | None = None, timeout: float = 10.0) -> int:
        """Serve a held vehicle: its held inputs up to ``digest`` dropped, the rest fed, then
        its inputs as they come. Waits up to ``timeout`` s for the loop; the number dropped."""
        slot = self.slots[name]
        slot.vehicle.fleet_info = fleet_info
        self._push(slot, self.SERVE, digest or b"")
        if not slot.served.wait(timeout):
            log.warning("%s: the filter loop did not reach the switch in %g s", name, timeout)
        return slot.skipped

    def cut(self, name: str, timeout: float = 10.0) -> bytes | None:
        """Stop feeding ``name`` at the end of what is queued now; the digest of the last input
        fed. TimeoutError if the loop does not reach the marker within ``timeout`` s."""
        slot = self.slots[name]
        self._push(slot, self.CUT)
        if not slot.done.wait(timeout):
            raise TimeoutError(f"{name}: the filter loop did not reach the cut")
        return input_digest(*slot.last_fed) if slot.last_fed is not None else None

    def drop(self, name: str) -> None:
        """Forget a held or cut vehicle: its subscription undeclared (a served one: cut first)."""
        slot = self.slots.get(name)
        if slot is None:
            return
        if slot.state == SERVING:
            raise RuntimeError(f"{name} is served: cut it first")
        if slot.sub is not None:
            slot.sub.undeclare()
        self.slots = {k: s for k, s in self.slots.items() if k != name}

    def stop(self, drain_s: float = 2.0, final_checkpoint: bool = True) -> None:
        for slot in self.slots.values():
            for h in [slot.sub, *slot.handles]:
                if h is not None:
                    h.undeclare()
            slot.sub, slot.handles = None, []
        super().stop(drain_s, final_checkpoint)

    def _push(self, slot: Slot, marker: str, data: bytes = b"") -> None:
        box = self._inbox
        if box is None or not hasattr(box, "push_control"):
            raise RuntimeError("a fleet node needs a byte-bounded input FIFO (queue_bytes)")
        box.push_control(slot.vehicle.prefix + marker, data)

    # ------------------------------------------------------------------ filter loop thread
    def take_input(self, key: str, data: bytes) -> None:
        slot = self.slots.get(key.split("/", 2)[1])
        if slot is None:
            return
        topic = key[len(slot.vehicle.prefix):]
        if topic[:1] == "@":
            self._on_marker(slot, topic, data)
        elif slot.state == SERVING:
            self.take_vehicle_input(slot.vehicle, topic, data)
            if topic in _FED:
                slot.last_fed = (topic, data)  # (its digest is computed at the cut only)
        elif slot.state == HELD:
            slot.keep(key, data)

    def _on_marker(self, slot: Slot, topic: str, data: bytes) -> None:
        v = slot.vehicle
        if topic == self.SERVE and slot.state == HELD:
            slot.skipped = slot.skip_through(data or None)
            if slot.held_dropped:
                note_reject(v.sp, "input", "queue_overflow",
                            f"{slot.held_dropped} input(s) dropped while held", slot.held_dropped)
            slot.state = SERVING
            self.vehicles = {**self.vehicles, v.name: v}
            held, slot.held, slot.held_bytes = slot.held, deque(), 0
            for key, payload in held:
                self.take_input(key, payload)
            slot.handles = self.declare_vehicle(v)
            slot.next_ckpt = self._mono() + self.checkpoint_every_s * stagger(v.name)
            self._next_any = min(self._next_any, slot.next_ckpt)
            slot.served.set()
        elif topic == self.CUT and slot.state != CUT:
            for h in slot.handles:
                h.undeclare()
            slot.handles, slot.state = [], CUT
            self.vehicles = {k: x for k, x in self.vehicles.items() if k != v.name}
            slot.done.set()

    def checkpoint_step(self) -> None:
        """The most overdue served vehicle's periodic checkpoint, when one is due."""
        now = self._mono()
        if now < self._next_any:
            return
        due = [s for s in self.slots.values() if s.state == SERVING]
        slot = min(due, key=lambda s: s.next_ckpt, default=None)
        if slot is not None and slot.next_ckpt <= now:
            try:
                self.write_checkpoint([slot.vehicle.name])
                self.checkpoint_error = None
                slot.next_ckpt = now + self.checkpoint_every_s
            except (commands.CommandError, ckpt.CheckpointError, OSError) as exc:
                self.checkpoint_failures += 1
                if self.checkpoint_error is None:
                    log.error("periodic checkpoint of %s failed (will retry): %s",
                              slot.vehicle.name, exc)
                self.checkpoint_error = str(exc)
                slot.next_ckpt = now + min(self.CHECKPOINT_RETRY_S, self.checkpoint_every_s)
        self._next_any = min((s.next_ckpt for s in due), default=float("inf"))
