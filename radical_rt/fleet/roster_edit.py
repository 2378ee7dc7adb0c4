"""Editing a fleet's roster from a tool (``radical fleet add/remove``; docs/fleet.md, "Roster").

:func:`edit_roster` reads every holder's roster (``roster-state/*``, every queryable), publishes
one edit per vehicle with the next Lamport clock (:mod:`radical_rt.fleet.roster`), then polls the
holders until every live worker (its token ``worker/<id>``) holds the edit or a later one,
publishing again to those that do not yet (the edit is idempotent).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import msgpack

from radical_rt.fleet.ownership import owner
from radical_rt.fleet.replica import fleet_prefix
from radical_rt.fleet.roster import NAME, OPS, Edit, decode_state, edit_key, state_key
from radical_rt.io.transport import Transport


@dataclass
class EditResult:
    """What an edit did: the edits published (none if no worker answered), the live workers,
    those that hold the edit, the vehicles whose edit a later one superseded (vehicle → the
    winner), the owners of added vehicles by rendezvous hashing over the live workers, and the
    vehicles the edit did not change on any worker (already in, or never in, the roster)."""

    op: str
    vehicles: list[str]
    edits: list[Edit] = field(default_factory=list)
    live: list[str] = field(default_factory=list)
    acked: list[str] = field(default_factory=list)
    superseded: dict[str, Edit] = field(default_factory=dict)
    owners: dict[str, str | None] = field(default_factory=dict)
    unchanged: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return bool(self.edits and self.live and set(self.live) <= set(self.acked)
                    and not self.superseded)


def read_states(t: Transport, fleet: str, timeout: float,
                workers: Iterable[str] | None = None) -> list[dict[str, Any]]:
    """The rosters of ``workers`` (their own keys), or of every holder (None: a wildcard
    query); see :func:`radical_rt.fleet.roster.decode_state`. (Over Zenoh a wildcard query
    from a client always waits ZenohTransport.MATCH_WAIT_S first: a querier on a wildcard key
    never reports a match. A worker's own key does, and is answered in milliseconds.)"""
    keys = [state_key(fleet)] if workers is None else [state_key(fleet, w) for w in workers]
    replies = []
    for key in keys:
        try:
            replies += t.get(key, b"", timeout=timeout, every=workers is None)
        except Exception:  # no route yet, a closed session: nobody answered
            continue
    return [st for st in (decode_state(r, fleet) for r in replies) if st is not None]


def edit_roster(t: Transport, fleet: str, op: str, vehicles: Iterable[str], by: str,
                timeout: float = 5.0, poll_s: float = 0.2) -> EditResult:
    """Add or remove ``vehicles`` and wait up to ``timeout`` s for every live worker to hold
    the edit (ValueError for a bad op or name)."""
    names = sorted(set(vehicles))
    bad = [v for v in names if not NAME.match(v)]
    if op not in OPS or not names or bad:
        raise ValueError(f"vehicle names must match [a-z0-9_-]+: {bad or names}")
    res = EditResult(op, names)
    end = time.monotonic() + timeout
    lock, live = threading.Lock(), set()

    def on_worker(key: str, alive: bool) -> None:
        with lock:
            (live.add if alive else live.discard)(key.rsplit("/", 1)[-1])

    def now_live() -> list[str]:
        with lock:
            return sorted(live)

    watch = t.liveliness_subscribe(fleet_prefix(fleet) + "worker/*", on_worker)
    try:
        first = min(end, time.monotonic() + 2.0)  # the live workers' tokens, then their rosters
        while not now_live() and time.monotonic() < first:
            time.sleep(0.01)
        wait = max(0.1, min(2.0, end - time.monotonic()))
        states = read_states(t, fleet, wait, now_live() or None)
        if not states:
            return res
        clock = max(st["clock"] for st in states) + 1
        res.unchanged = [v for v in names
                         if all((v in st["vehicles"]) == (op == "add") for st in states)]
        res.edits = [Edit(v, op, clock, by, "cli", time.time()) for v in names]
        pending = list(res.edits)
        while True:
            for e in pending:
                t.put(edit_key(fleet, e.vehicle), msgpack.packb(e.pack(fleet)), block=True)
            res.live = now_live()
            states = read_states(t, fleet, max(0.1, min(2.0, end - time.monotonic())), res.live)
            res.acked, res.superseded, pending = _check(states, res.edits, set(res.live))
            if (res.live and set(res.live) <= set(res.acked)) or time.monotonic() >= end:
                break
            time.sleep(poll_s)
    finally:
        watch.undeclare()
    if op == "add":
        res.owners = {v: owner(v, res.live) for v in names}
    return res


def _check(states: list[dict[str, Any]], edits: list[Edit],
           live: set[str]) -> tuple[list[str], dict[str, Edit], list[Edit]]:
    """(workers holding every edit or a later one, vehicle → a later winner, edits some live
    worker does not hold yet)."""
    acked, superseded, missing = [], {}, set()
    for st in states:
        won = {e.vehicle: e for e in st["edits"]}
        ok = True
        for e in edits:
            w = won.get(e.vehicle)
            if w is None or w.order() < e.order():
                ok = False
                if st["worker"] in live:
                    missing.add(e.vehicle)
            elif w != e and w.op != e.op:
                superseded[e.vehicle] = w
        if ok:
            acked.append(st["worker"])
    if live - {st["worker"] for st in states}:  # a live worker did not answer: send again
        missing = {e.vehicle for e in edits}
    return sorted(acked), superseded, [e for e in edits if e.vehicle in missing]
