"""The fleet's shared roster (radical_rt.fleet.roster, roster_edit, discovery) on an in-memory
bus: static names as the base, edits converge on every holder including a late joiner, the
last-writer-wins rule settles concurrent edits whatever their arrival order, a tool's edit is
confirmed by every live worker, and exactly one worker discovers vehicles from input keys."""

from __future__ import annotations

import random

import msgpack
import pytest

from radical_rt.fleet.discovery import PSEUDO, Discovery
from radical_rt.fleet.ownership import owner
from radical_rt.fleet.roster import Edit, Roster, edit_key
from radical_rt.fleet.roster_edit import edit_roster
from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport

F = "f1"


def _holder(bus, wid: str, static=()) -> Roster:
    t = InMemoryTransport(bus)
    t.liveliness_token(f"radical-fleet/{F}/worker/{wid}")
    return Roster(t, F, wid, static).start()


def test_static_base_edits_and_a_late_joiner_converge():
    bus = InMemoryBus()
    a = _holder(bus, "w-a", ["v1", "v2"])
    b = _holder(bus, "w-b", ["v2", "v3"])  # another file: its extra name joins the fleet's roster
    assert a.vehicles() == b.vehicles() == ["v1", "v2", "v3"]
    tool = InMemoryTransport(bus)
    res = edit_roster(tool, F, "add", ["v9", "v8"], by="cli-x", timeout=2.0)
    assert res.ok and res.live == ["w-a", "w-b"] and res.acked == ["w-a", "w-b"]
    assert res.owners == {v: owner(v, ["w-a", "w-b"]) for v in ("v8", "v9")}
    assert res.edits[0].clock == 1  # after the static names (clock 0)
    res = edit_roster(tool, F, "remove", ["v1"], by="cli-x", timeout=2.0)  # a static name
    assert res.ok and res.edits[0].clock == 2 and res.unchanged == []
    want = ["v2", "v3", "v8", "v9"]
    assert a.vehicles() == b.vehicles() == want
    c = _holder(bus, "w-c", ["v1"])  # joins later, with the removed name in its file
    assert c.vehicles() == want  # fetched from the others; the remove beats its static name
    assert a.vehicles() == b.vehicles() == want
    st = c.status()
    assert st["entries"]["v1"]["state"] == "removed" and st["entries"]["v9"]["state"] == "added"
    assert st["entries"]["v3"]["state"] == "static" and st["clock"] == 2
    assert c.edit("add", ["v1"])[0].clock == 3  # a holder's own edit continues the clock
    assert edit_roster(tool, F, "add", ["v1", "v7"], by="cli-y", timeout=2.0).unchanged == ["v1"]
    want = sorted([*want, "v7"])
    assert a.vehicles() == b.vehicles() == c.vehicles() == ["v1", *want]


def test_concurrent_edits_resolve_by_the_rule_in_any_arrival_order():
    """Edits with the same clock (neither saw the other) are ordered by origin, then op; a
    later clock always wins. Every holder picks the same winners whatever the arrival order."""
    rng = random.Random(19)
    edits = []
    for k in range(40):
        v = f"v{k % 8}"
        edits.append(Edit(v, rng.choice(["add", "remove"]), rng.randint(1, 4),
                          rng.choice(["cli-a", "cli-b", "w-0"]), "cli", 0.0))
    want = {}
    for e in edits:
        if e.vehicle not in want or e.order() > want[e.vehicle].order():
            want[e.vehicle] = e
    holders, tools = [], []
    for i in range(3):  # one bus each: every holder receives the edits in its own order
        bus = InMemoryBus()
        holders.append(_holder(bus, f"w-{i}"))
        tools.append(InMemoryTransport(bus))
        order = edits[:]
        rng.shuffle(order)
        for e in order:
            tools[i].put(edit_key(F, e.vehicle), msgpack.packb(e.pack(F)))
    expect = sorted(v for v, e in want.items() if e.op == "add")
    assert all(h.vehicles() == expect for h in holders)
    assert all({e.vehicle: e for e in h.edits()} == want for h in holders)
    tie = [Edit("vx", "add", 7, "cli-b"), Edit("vx", "remove", 7, "cli-a")]
    for i, tool in enumerate(tools):
        for e in (tie if i % 2 else tie[::-1]):
            tool.put(edit_key(F, "vx"), msgpack.packb(e.pack(F)))
    assert all("vx" in h.vehicles() for h in holders)  # same clock: the greater origin wins


def test_bad_records_are_refused_and_no_worker_means_no_edit():
    bus = InMemoryBus()
    a = _holder(bus, "w-a", ["v1"])
    tool = InMemoryTransport(bus)
    good = Edit("v2", "add", 1, "cli-x").pack(F)
    for bad in (dict(good, fleet="f2"), dict(good, op="drop"), dict(good, vehicle="V2!"),
                dict(good, clock=-1), dict(good, clock=True), {"v": 1}):
        tool.put(edit_key(F, "v2"), msgpack.packb(bad))
    tool.put(edit_key(F, "v2"), b"\xc1")
    assert a.rejected == 7 and a.vehicles() == ["v1"]
    with pytest.raises(ValueError, match="a-z0-9"):
        edit_roster(tool, F, "add", ["Bad Name"], by="cli-x")
    res = edit_roster(InMemoryTransport(InMemoryBus()), F, "add", ["v3"], by="cli-x", timeout=0.5)
    assert not res.ok and res.edits == []  # nobody holds the roster: nothing published


def test_one_worker_discovers_and_another_takes_over():
    bus = InMemoryBus()
    ids = ["w-a", "w-b", "w-c"]
    rosters = {w: _holder(bus, w, ["v1"]) for w in ids}
    disc = {w: Discovery(rosters[w].t, rosters[w], w, "temp") for w in ids}
    for w in ids:
        disc[w].follow(set(ids))
    first = owner(PSEUDO, ids)
    assert [w for w in ids if disc[w].active()] == [first]
    assert len(bus.find("sub", "radical/anything/temp")) == 1  # one subscription in the fleet
    sensor = InMemoryTransport(bus)
    for v in ("v1", "new-1", "new-1"):
        sensor.put(f"radical/{v}/temp", msgpack.packb({"v": 1, "t_bus": 1.0}))
    sensor.put("radical/new-2/siru", b"x")  # another topic: not watched
    for w in ids:
        disc[w].follow(set(ids))
    assert all(r.vehicles() == ["new-1", "v1"] for r in rosters.values())
    assert rosters["w-b"].status()["entries"]["new-1"]["state"] == "discovered"
    assert disc[first].status()["samples"] == 3
    rest = [w for w in ids if w != first]  # the discoverer leaves: the next one takes it over
    disc[first].stop()
    rosters[first].t.close()
    for w in rest:
        disc[w].follow(set(rest))
    second = owner(PSEUDO, rest)
    assert [w for w in rest if disc[w].active()] == [second]
    assert len(bus.find("sub", "radical/anything/temp")) == 1
    res = edit_roster(sensor, F, "remove", ["new-1"], by="cli-x", timeout=1.0)
    assert set(res.acked) >= set(rest)
    sensor.put("radical/new-1/temp", b"x")  # a removed vehicle is not rediscovered
    sensor.put("radical/new-3/temp", b"x")
    disc[second].follow(set(rest))
    assert rosters[second].vehicles() == ["new-3", "v1"]


def test_an_edit_superseded_while_it_spreads_is_not_confirmed():
    """Another tool removes the vehicle right after our add reaches it (a later clock): our
    add is reported superseded, not confirmed, and every holder keeps the remove."""
    bus = InMemoryBus()
    holders = [_holder(bus, w, ["v1"]) for w in ("w-a", "w-b")]
    other = InMemoryTransport(bus)
    done = []

    def react(key: str, data: bytes) -> None:
        e = Edit.unpack(msgpack.unpackb(data, raw=False), F)
        if e.by == "cli-x" and not done:
            done.append(e)
            other.put(key, msgpack.packb(Edit(e.vehicle, "remove", e.clock + 1, "cli-z").pack(F)))

    other.subscribe(edit_key(F), react, remote_only=True)
    res = edit_roster(InMemoryTransport(bus), F, "add", ["v5"], by="cli-x", timeout=1.0)
    assert done and not res.ok
    assert res.superseded["v5"].by == "cli-z" and res.superseded["v5"].op == "remove"
    assert all(h.vehicles() == ["v1"] for h in holders)


class _Deaf(InMemoryTransport):
    """A transport whose subscriptions miss every sample while ``cut`` (a partition)."""

    cut = False

    def subscribe(self, key, callback, remote_only=False):
        return super().subscribe(key, lambda k, d: None if self.cut else callback(k, d),
                                 remote_only)


def test_an_edit_missed_in_a_partition_arrives_by_anti_entropy():
    bus = InMemoryBus()
    a = _holder(bus, "w-a", ["v1"])
    deaf = _Deaf(bus)
    deaf.liveliness_token(f"radical-fleet/{F}/worker/w-b")
    b = Roster(deaf, F, "w-b", ["v1"]).start()
    deaf.cut = True
    a.edit("add", ["v4"])  # b misses it
    b.edit("remove", ["v1"])  # a hears this one
    deaf.cut = False
    assert a.vehicles() == ["v4"] and b.vehicles() == []
    b.sync({"w-a", "w-b"})  # not yet: one pull per SYNC_S
    assert b.pulls == 0
    b.pull("w-a")  # what sync does in a thread once SYNC_S has passed
    assert b.vehicles() == a.vehicles() == ["v4"] and b.pulls == 1
