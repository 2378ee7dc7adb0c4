"""Fleet workers on an in-memory bus (radical_rt.apps.fleet_worker): every vehicle served by
exactly one worker, a joiner takes its share from the final checkpoints of the old owners, a
crashed worker's vehicles are taken over from the replica with the loss reported, and never two
ownership tokens for one vehicle at once."""

from __future__ import annotations

import threading
import time

import msgpack
import pytest

from radical_rt.apps.fleet_worker import FleetWorker
from radical_rt.apps.node_setup import build_processors
from radical_rt.fleet.ownership import assign
from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport
from tests.support.fleet import FleetWatch
from tests.support.node import input_messages, wait_for

VEHICLES = ["v1", "v2", "v3", "v4", "v5"]


def _make(name: str):
    return build_processors([name])[name]


@pytest.fixture()
def fleet():
    bus = InMemoryBus()
    client = InMemoryTransport(bus)
    watch = FleetWatch(client, "f1")
    workers: list[FleetWorker] = []

    def add(wid: str) -> FleetWorker:
        w = FleetWorker(InMemoryTransport(bus), "f1", VEHICLES, _make, worker_id=wid,
                        checkpoint_every_s=0.2).start()
        workers.append(w)
        return w

    yield bus, client, watch, add
    for w in workers:
        w.stop()


def _served(workers) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for w in workers:
        for v in w.serving:
            out.setdefault(v, []).append(w.id)
    return out


def _settled(workers) -> bool:
    live = {w.id for w in workers}
    want = assign(VEHICLES, live)
    return _served(workers) == {v: [want[v]] for v in VEHICLES}


def _status(client, v: str) -> dict:
    [r] = client.get(f"radical/{v}/cmd", msgpack.packb({"cmd": "status"}), timeout=5)
    return msgpack.unpackb(r, raw=False, strict_map_key=False)


def test_join_and_crash(fleet, archives):
    bus, client, watch, add = fleet
    a, b = add("w-a"), add("w-b")
    wait_for(lambda: _settled([a, b]), 20, what="two workers to share the roster")
    msgs = input_messages(archives["a60"])[:300]
    for topic, _, data in msgs:
        for v in VEHICLES:
            client.put(f"radical/{v}/{topic}", data, block=True)
    for w in (a, b):
        assert w.node.wait_idle(30)
    t_before = {v: _status(client, v)["t"] for v in VEHICLES}
    assert all(t > 0 for t in t_before.values())
    wait_for(lambda: all(a.replica.latest(v) and b.replica.latest(v) for v in VEHICLES), 10,
             what="replicas of every vehicle on both workers")

    c = add("w-c")  # a join: the vehicles c now scores highest on move from their old owner
    wait_for(lambda: _settled([a, b, c]), 20, what="the join to settle")
    moved = [t for t in c.takeovers]
    assert moved and all(t["source"] == "handover" and t["replica_worker"] in ("w-a", "w-b")
                         and not t.get("loss_flagged") for t in moved)  # handed over: no loss
    for t in moved:  # from the old owner's final checkpoint: the state it had when it let go
        assert _status(client, t["vehicle"])["t"] == pytest.approx(t_before[t["vehicle"]])

    b_vehicles = sorted(b.serving)
    b.t.close()  # a crash: b's tokens go with its session, nothing is handed over
    wait_for(lambda: _settled([a, c]), 20, what="the survivors to take b's vehicles")
    taken = {t["vehicle"]: t for w in (a, c) for t in w.takeovers if t["vehicle"] in b_vehicles
             and t["taken_unix"] > 0 and t["replica_worker"] == "w-b"}
    assert set(taken) == set(b_vehicles)
    for v, t in taken.items():
        st = _status(client, v)
        assert st["node"]["fleet"]["source"] == "replica" and st["node"]["fleet"]["lost_s"] >= 0
        assert t["loss_flagged"] and st["counters"]["input_gaps"] == 1  # the crash's loss
    assert watch.most == 1  # never two owners of one vehicle at once (claims are not owners)


def _engine_view(sp) -> tuple:
    e = sp.engine
    return (e.t, e.mode, e.q.tolist(), e.estimates(), e.sigmas(), sp.counters())


def test_a_join_and_a_clean_leave_hand_over_bit_for_bit(fleet, archives):
    """Inputs keep flowing while a worker joins and later leaves: every vehicle ends exactly
    where one node fed the same messages ends (nothing lost, nothing fed twice)."""
    bus, client, watch, add = fleet
    msgs = input_messages(archives["a60"])[:2400]
    ref = {}
    for v in VEHICLES:
        sp = _make(v)
        for topic, _, data in msgs:
            sp.feed(topic, data)
        ref[v] = _engine_view(sp)
    a = add("w-a")
    wait_for(lambda: _settled([a]), 20, what="the first worker")
    done = threading.Event()

    def publish() -> None:
        for i, (topic, _, data) in enumerate(msgs):
            for v in VEHICLES:
                client.put(f"radical/{v}/{topic}", data, block=True)
            if i % 20 == 0:
                time.sleep(0.01)
        done.set()

    th = threading.Thread(target=publish)
    th.start()
    time.sleep(0.5)
    b = add("w-b")  # joins while inputs flow
    wait_for(lambda: _settled([a, b]), 20, what="the join")
    time.sleep(0.3)
    b.stop()  # leaves while inputs flow
    wait_for(lambda: _settled([a]), 20, what="the leave")
    th.join()
    assert done.is_set()
    assert a.node.wait_idle(30)
    moved = {t["vehicle"] for t in b.takeovers}
    assert moved and all(t["source"] == "handover" for t in b.takeovers)
    back = [t for t in a.takeovers if t["vehicle"] in moved and t["replica_worker"] == "w-b"]
    assert {t["vehicle"] for t in back} == moved and all(t["source"] == "handover" for t in back)
    for v in VEHICLES:
        assert _engine_view(a.node.processor(v)) == ref[v], v
    assert watch.most == 1
