"""Vehicles discovered from their input keys (``radical node --fleet F --discover [TOPIC]``;
docs/fleet.md, "Discovery").

Exactly one live worker discovers: the owner, by the same rendezvous hashing as the vehicles
(:mod:`radical_rt.fleet.ownership`), of the pseudo-vehicle ``@discover`` (``@`` is no vehicle
name, so it collides with none). Only that worker subscribes to ``radical/*/<TOPIC>``; when it
leaves or dies, the worker that scores next takes the subscription over at its next look at the
fleet. A name seen there that the roster has never held (no record at all: a removed vehicle
stays removed) is added to the shared roster like ``radical fleet add``, marked ``discover``.

Cost: the subscriber receives every vehicle's TOPIC stream. ``siru`` is the default because it
is the one input topic every source sends (CONTRACT §4: ``/siru`` and at least one tracker are
required); ``temp`` (1 Hz in the simulator) is ten times cheaper than ``siru`` or ``st1`` (10 Hz)
where every source sends it. The sample callback only counts, checks the name and remembers a
new one; the roster edit is made by :meth:`Discovery.follow` on the worker's controller thread.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from radical_rt.fleet.ownership import owner
from radical_rt.fleet.roster import NAME, Roster
from radical_rt.io.transport import Transport

PSEUDO = "@discover"  # the pseudo-vehicle whose owner discovers
TOPICS = ("siru", "st1", "st2", "temp")


class Discovery:
    """Discovery of new vehicles for worker ``me`` (see the module docstring). wake(): asks
    the controller to call :meth:`follow` soon (a new name was seen)."""

    def __init__(self, transport: Transport, roster: Roster, me: str, topic: str = "siru",
                 wake: Callable[[], None] = lambda: None) -> None:
        if topic not in TOPICS:
            raise ValueError(f"discovery topic must be one of {TOPICS}, got {topic!r}")
        self.t, self.roster, self.me, self.topic, self._wake = transport, roster, me, topic, wake
        self._lock = threading.Lock()
        self._sub: Any = None
        self._pending: set[str] = set()
        self.samples = 0  # samples delivered to this worker's discovery subscription
        self.discovered: list[str] = []
        self.active_since: float | None = None  # monotonic s
        self.handovers = 0  # times this worker started discovering

    def follow(self, live: set[str]) -> None:
        """Controller thread: subscribe when this worker owns ``@discover`` among ``live``,
        unsubscribe when it no longer does; add the new names seen to the roster."""
        mine = owner(PSEUDO, set(live) | {self.me}) == self.me
        if mine and self._sub is None:
            self._sub = self.t.subscribe(f"radical/*/{self.topic}", self._on_sample)
            self.active_since, self.handovers = time.monotonic(), self.handovers + 1
        elif not mine and self._sub is not None:
            self.stop()
        with self._lock:
            new, self._pending = sorted(self._pending), set()
        new = [v for v in new if not self.roster.knows(v)]
        if new:
            self.roster.edit("add", new, src="discover")
            self.discovered += new

    def active(self) -> bool:
        return self._sub is not None

    def stop(self) -> None:
        if self._sub is not None:
            self._sub.undeclare()
            self._sub, self.active_since = None, None

    def status(self) -> dict[str, Any]:
        since = self.active_since
        with self._lock:
            n = self.samples
        return {"topic": self.topic, "active": since is not None, "samples": n,
                "active_s": None if since is None else time.monotonic() - since,
                "discovered": list(self.discovered)}

    def _on_sample(self, key: str, _data: bytes) -> None:
        parts = key.split("/")
        v = parts[1] if len(parts) == 3 else ""
        with self._lock:
            self.samples += 1
            new = NAME.match(v) is not None and v not in self._pending
        if new and not self.roster.knows(v):
            with self._lock:
                self._pending.add(v)
            self._wake()
