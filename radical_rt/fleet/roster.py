"""The fleet's roster, shared by its workers over Zenoh (issue #19; docs/fleet.md, "Roster").

Why replicated like the checkpoints (:mod:`radical_rt.fleet.replica`): no store process that
must itself survive. Every live worker holds the whole roster; a worker that joins asks every
holder (``get(..., every=True)``) and merges the answers.

Keys under the fleet prefix ``radical-fleet/<F>/``:

* ``roster/<V>``: puts (BLOCK) of one **edit record** of vehicle V, a msgpack map
  ``{"v": 1, "fleet", "vehicle", "op": "add" | "remove", "clock", "by", "src", "t_wall"}``;
* ``roster-state/<worker>``: each holder's queryable; it answers with everything it holds,
  ``{"v": 1, "fleet", "worker", "clock", "vehicles": [...], "records": [...]}``.

**Merge rule: last writer wins per vehicle, by ``(clock, by, op, src, t_wall)``**, where
``clock`` is a Lamport clock: every holder keeps the highest clock it has seen, and a new edit
gets that plus one (a tool first reads every holder's clock). The roster is the set of vehicles
whose winning record is an ``add``. Why a Lamport clock rather than the wall time: an edit made
after another one was seen always wins, whatever the clocks of the machines say (a worker's
clock 2 s behind would otherwise lose a remove made after its add). Concurrent edits (the same
clock: neither saw the other) are ordered by their origin ``by``, a name unique per tool run or
worker, then by ``op`` (``remove`` > ``add``): a total order on the records, so every holder
that has seen the same records picks the same winners, in whatever order they arrived (the
merge is commutative, associative and idempotent: the holders converge).

The static names (``--vehicle``, ``--roster FILE``) are records with clock 0 (``src:
"static"``): any edit beats them, so ``remove`` of a static name works; a worker publishes its
static names that the fleet does not know yet when it starts, so workers started with different
files still agree. A remove is kept (a tombstone): the vehicle stays out until an ``add``, also
when its inputs keep flowing (discovery adds only names the roster has never seen) and when a
worker restarts with the name in its file. All is lost when every worker stops: then the files
are the roster again.

Anti-entropy: an edit a worker missed (a partition, a lost link) would leave it behind for
good, so each worker also pulls, every ``SYNC_S`` (10 s), the whole roster of one other live
worker, in turn (:meth:`Roster.sync`, from the worker's controller; the query in a short thread
of its own). After a partition heals, every worker has pulled every other one within
``SYNC_S`` × (workers − 1), and the merge rule makes the result the same everywhere.

Thread safety: sample and query callbacks come on Zenoh threads; the records are under one lock
and ``on_change()`` (the worker's wake-up) is called after a change, outside it.
"""

from __future__ import annotations

import logging
import os
import re
import secrets
import socket
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from typing import Any

import msgpack

from radical_rt.fleet.replica import fleet_prefix
from radical_rt.io.transport import Transport

log = logging.getLogger("radical.fleet")
NAME = re.compile(r"^[a-z0-9_-]+$")  # CONTRACT §2
OPS = ("add", "remove")
SOURCES = ("static", "cli", "discover")


def origin_id(kind: str) -> str:
    """A name unique to this process for the ``by`` of its edits: kind, host, pid, random."""
    host = re.sub(r"[^a-z0-9-]", "-", socket.gethostname().lower())[:24] or "host"
    return f"{kind}-{host}-{os.getpid()}-{secrets.token_hex(3)}"


@dataclass(frozen=True)
class Edit:
    """One edit of one vehicle's roster entry."""

    vehicle: str
    op: str  # add | remove
    clock: int  # Lamport clock (0: a static name)
    by: str  # origin: a worker id or a tool run's origin_id
    src: str = "cli"  # static | cli | discover
    t_wall: float = 0.0

    def order(self) -> tuple[int, str, str, str, float]:
        """The merge order: the greater record wins (see the module docstring)."""
        return (self.clock, self.by, self.op, self.src, self.t_wall)

    def pack(self, fleet: str) -> dict[str, Any]:
        return {"v": 1, "fleet": fleet, **asdict(self)}

    @classmethod
    def unpack(cls, m: Any, fleet: str) -> Edit:
        """An edit from a received map; ValueError if it is malformed or another fleet's."""
        if not isinstance(m, dict) or m.get("fleet") != fleet:
            raise ValueError(f"not an edit of fleet {fleet}: {str(m)[:80]}")
        e = cls(str(m["vehicle"]), str(m["op"]), m["clock"], str(m["by"]),
                str(m.get("src", "cli")), float(m.get("t_wall", 0.0)))
        if not NAME.match(e.vehicle) or e.op not in OPS or e.src not in SOURCES \
                or not isinstance(e.clock, int) or isinstance(e.clock, bool) or e.clock < 0:
            raise ValueError(f"bad edit {m!r}")
        return e


class Records:
    """vehicle → winning edit, with the Lamport clock (not thread-safe: the caller locks)."""

    def __init__(self) -> None:
        self.won: dict[str, Edit] = {}
        self.clock = 0

    def merge(self, e: Edit) -> bool:
        """Keep ``e`` if it beats the vehicle's record; True if the roster's records changed."""
        self.clock = max(self.clock, e.clock)
        old = self.won.get(e.vehicle)
        if old is not None and e.order() <= old.order():
            return False
        self.won[e.vehicle] = e
        return True

    def vehicles(self) -> list[str]:
        return sorted(v for v, e in self.won.items() if e.op == "add")


def state_key(fleet: str, worker: str = "*") -> str:
    return fleet_prefix(fleet) + f"roster-state/{worker}"


def edit_key(fleet: str, vehicle: str = "*") -> str:
    return fleet_prefix(fleet) + f"roster/{vehicle}"


class Roster:
    """The fleet's roster as held by worker ``me`` (thread-safe; see the module docstring).

    static: the names of ``--vehicle``/``--roster FILE``; on_change(): called after the roster
    (the set or an entry) changed, e.g. the worker's wake-up."""

    SYNC_S = 10.0  # anti-entropy: pull one other live worker's roster this often

    def __init__(self, transport: Transport, fleet: str, me: str, static: Iterable[str] = (),
                 on_change: Callable[[], None] = lambda: None) -> None:
        self.t, self.fleet, self.me, self._on_change = transport, fleet, me, on_change
        self.static = sorted(set(static))
        bad = [v for v in self.static if not NAME.match(v)]
        if bad:
            raise ValueError(f"vehicle names must match [a-z0-9_-]+: {bad[:5]}")
        self._lock = threading.Lock()
        self._rec = Records()
        for v in self.static:  # the base, until the fleet's records arrive
            self._rec.merge(Edit(v, "add", 0, me, "static"))
        self._decls: list[Any] = []
        self.rejected = 0  # records refused (malformed, another fleet's)
        self._next_sync = time.monotonic() + self.SYNC_S
        self._turn = 0
        self.pulls = 0  # anti-entropy pulls done

    # ------------------------------------------------------------------ lifecycle
    def start(self, timeout: float = 2.0) -> Roster:
        """Subscribe, answer queries, fetch what the other holders hold, then publish the static
        names the fleet did not know (clock 0: they lose to any edit)."""
        self._decls = [self.t.subscribe(edit_key(self.fleet), self._on_sample, remote_only=True),
                       self.t.queryable(state_key(self.fleet, self.me), self._on_query)]
        known = self.fetch(timeout)
        for v in self.static:
            if v not in known:
                self._publish(Edit(v, "add", 0, self.me, "static", time.time()))
        return self

    def fetch(self, timeout: float = 2.0) -> set[str]:
        """Merge every other holder's records; the vehicles the others hold a record of."""
        try:
            replies = self.t.get(state_key(self.fleet), b"", timeout=timeout, every=True)
        except Exception as exc:  # no route, closed session: what we hold stands
            log.debug("fleet %s: roster fetch: %s", self.fleet, exc)
            replies = []
        known: set[str] = set()
        for data in replies:
            st = decode_state(data, self.fleet)
            if st is None or st.get("worker") == self.me:
                continue
            for e in st["edits"]:
                known.add(e.vehicle)
                self._merge(e)
        return known

    def sync(self, live: Iterable[str]) -> None:
        """Anti-entropy (controller thread, at every look): every SYNC_S, merge the roster of
        the next other live worker in turn; the query runs in a thread of its own."""
        now = time.monotonic()
        others = sorted(set(live) - {self.me})
        if now < self._next_sync or not others:
            return
        self._next_sync = now + self.SYNC_S
        worker = others[self._turn % len(others)]
        self._turn += 1
        threading.Thread(target=self.pull, args=(worker,), name=f"roster-pull-{worker}",
                         daemon=True).start()

    def pull(self, worker: str, timeout: float = 1.0) -> None:
        """Merge ``worker``'s whole roster."""
        try:
            replies = self.t.get(state_key(self.fleet, worker), b"", timeout=timeout)
        except Exception as exc:  # gone meanwhile, a closed session: the next turn
            log.debug("fleet %s: roster pull from %s: %s", self.fleet, worker, exc)
            return
        for data in replies:
            st = decode_state(data, self.fleet)
            for e in (st["edits"] if st is not None else []):
                self._merge(e)
        with self._lock:
            self.pulls += 1

    def close(self) -> None:
        for d in self._decls:
            d.undeclare()
        self._decls = []

    # ------------------------------------------------------------------ reading
    def vehicles(self) -> list[str]:
        """The roster now, sorted."""
        with self._lock:
            return self._rec.vehicles()

    def knows(self, vehicle: str) -> bool:
        """Whether the roster holds any record of ``vehicle`` (added, static or removed)."""
        with self._lock:
            return vehicle in self._rec.won

    def edits(self) -> list[Edit]:
        with self._lock:
            return sorted(self._rec.won.values(), key=lambda e: e.vehicle)

    def status(self) -> dict[str, Any]:
        """For ``fleet status``: vehicles, and per entry its source (static/added/discovered or
        removed), its clock and origin."""
        label = {"static": "static", "cli": "added", "discover": "discovered"}
        with self._lock:
            won, clock = dict(self._rec.won), self._rec.clock
        return {"clock": clock, "rejected": self.rejected,
                "vehicles": sorted(v for v, e in won.items() if e.op == "add"),
                "entries": {v: {"state": label[e.src] if e.op == "add" else "removed",
                                "clock": e.clock, "by": e.by, "t_wall": e.t_wall}
                            for v, e in sorted(won.items())}}

    # ------------------------------------------------------------------ editing
    def edit(self, op: str, vehicles: Iterable[str], src: str = "cli") -> list[Edit]:
        """Add or remove ``vehicles`` (this holder's own edit, e.g. discovery): merged here and
        published to the other holders."""
        names = sorted(set(vehicles))
        if op not in OPS or any(not NAME.match(v) for v in names):
            raise ValueError(f"bad roster edit {op} {names}")
        with self._lock:
            clock = self._rec.clock + 1
        out = [Edit(v, op, clock, self.me, src, time.time()) for v in names]
        for e in out:
            self._publish(e)
        return out

    # ------------------------------------------------------------------ internals
    def _publish(self, e: Edit) -> None:
        self._merge(e)
        try:
            self.t.put(edit_key(self.fleet, e.vehicle), msgpack.packb(e.pack(self.fleet)),
                       block=True, remote_only=True)
        except Exception as exc:  # the others fetch it from our queryable
            log.warning("fleet %s: roster edit %s %s not published: %s", self.fleet, e.op,
                        e.vehicle, exc)

    def _merge(self, e: Edit) -> None:
        with self._lock:
            before = self._rec.vehicles()
            changed = self._rec.merge(e)
            after = self._rec.vehicles() if changed else before
        if changed:
            if after != before:
                log.info("fleet %s: roster %s %s (%s by %s, clock %d)", self.fleet, e.op,
                         e.vehicle, e.src, e.by, e.clock)
            self._on_change()

    def _on_sample(self, key: str, data: bytes) -> None:
        try:
            e = Edit.unpack(msgpack.unpackb(data, raw=False), self.fleet)
        except Exception as exc:
            with self._lock:
                self.rejected += 1
            log.warning("fleet %s: roster edit refused on %s: %s", self.fleet, key, exc)
            return
        self._merge(e)

    def _on_query(self, _payload: bytes) -> bytes:
        with self._lock:
            edits, clock, vehicles = list(self._rec.won.values()), self._rec.clock, \
                self._rec.vehicles()
        return msgpack.packb({"v": 1, "fleet": self.fleet, "worker": self.me, "clock": clock,
                              "vehicles": vehicles,
                              "records": [e.pack(self.fleet) for e in edits]})


def decode_state(data: bytes, fleet: str) -> dict[str, Any] | None:
    """A holder's answer: ``worker``, ``clock``, ``vehicles`` and ``edits`` (Edit objects);
    None if it is malformed or another fleet's (bad records are skipped)."""
    try:
        m = msgpack.unpackb(data, raw=False)
        if m.get("fleet") != fleet:
            raise ValueError(f"fleet {m.get('fleet')!r}")
        edits = []
        for r in m["records"]:
            try:
                edits.append(Edit.unpack(r, fleet))
            except (ValueError, KeyError, TypeError) as exc:
                log.warning("fleet %s: roster record skipped: %s", fleet, exc)
        return {"worker": str(m["worker"]), "clock": int(m["clock"]),
                "vehicles": list(m["vehicles"]), "edits": edits}
    except Exception as exc:
        log.warning("fleet %s: roster state refused: %s", fleet, exc)
        return None
