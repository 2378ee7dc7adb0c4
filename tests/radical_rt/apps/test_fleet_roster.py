"""Fleet workers and their shared roster on an in-memory bus: ``fleet add`` of a new vehicle
makes its owner serve it, ``remove`` makes the owner let it go with a final checkpoint in the
replica, a late joiner holds the same roster, and with discovery one worker watches the input
keys and a vehicle that starts publishing is added and served."""

from __future__ import annotations

import msgpack

from radical_rt.apps.fleet_worker import FleetWorker
from radical_rt.apps.node_setup import build_processors
from radical_rt.fleet.discovery import PSEUDO
from radical_rt.fleet.ownership import owner
from radical_rt.fleet.roster_edit import edit_roster
from radical_rt.io import checkpoint as ckpt
from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport
from tests.support.node import input_messages, wait_for


def _make(name: str):
    return build_processors([name])[name]


def _worker(bus, wid: str, static, handover_wait_s: float = 0.5, **kw) -> FleetWorker:
    return FleetWorker(InMemoryTransport(bus), "f1", static, _make, worker_id=wid,
                       checkpoint_every_s=0.5, handover_wait_s=handover_wait_s, **kw).start()


def _servers(workers, v: str) -> list[str]:
    return [w.id for w in workers if v in w.serving]


def test_add_serves_remove_lets_go_with_a_final_checkpoint(archives):
    bus = InMemoryBus()
    client = InMemoryTransport(bus)
    # a long handover wait: a removed vehicle must be let go at once, not after it
    workers = [_worker(bus, w, ["v1", "v2"], handover_wait_s=120.0) for w in ("w-a", "w-b")]
    try:
        wait_for(lambda: all(len(_servers(workers, v)) == 1 for v in ("v1", "v2")), 20,
                 what="the static roster served")
        res = edit_roster(client, "f1", "add", ["v9"], by="cli-t", timeout=5)
        assert res.ok and res.owners["v9"] == owner("v9", ["w-a", "w-b"])
        wait_for(lambda: _servers(workers, "v9") == [res.owners["v9"]], 20, what="v9 served")
        for topic, _, data in input_messages(archives["a60"])[:200]:
            client.put(f"radical/v9/{topic}", data, block=True)
        [own] = [w for w in workers if w.id == res.owners["v9"]]
        assert own.node.wait_idle(30)
        [raw] = client.get("radical/v9/cmd", msgpack.packb({"cmd": "status"}), timeout=5)
        t_served = msgpack.unpackb(raw, raw=False, strict_map_key=False)["t"]
        assert t_served > 0

        late = _worker(bus, "w-c", ["v1"], handover_wait_s=120.0)  # joins with another file: takes the fleet's roster
        workers.append(late)
        assert late.vehicles == ["v1", "v2", "v9"]
        wait_for(lambda: all(len(_servers(workers, v)) == 1 for v in ("v1", "v2", "v9")), 20,
                 what="the join to settle")

        [last] = _servers(workers, "v9")
        res = edit_roster(client, "f1", "remove", ["v9", "v1"], by="cli-t", timeout=5)
        assert res.ok and sorted(res.acked) == ["w-a", "w-b", "w-c"]
        assert all(w.vehicles == ["v2"] for w in workers)  # a static name removed too
        wait_for(lambda: not _servers(workers, "v9") and not _servers(workers, "v1"), 20,
                 what="the owners to let v1 and v9 go")
        # (a worker forgets a vehicle as it starts letting it go: the final checkpoint follows)
        wait_for(lambda: all(getattr(w.replica.latest("v9"), "final", False) for w in workers),
                 10, what="v9's final checkpoint in every worker's replica")
        for w in workers:
            rep = w.replica.fetch("v9", timeout=1.0)
            assert rep is not None and rep.final and rep.worker == last
            fresh = _make("v9")
            ckpt.restore(fresh, rep.state())
            assert fresh.engine.t == t_served  # where its owner stopped (no input since)
        assert workers[0].status()["roster"]["entries"]["v1"]["state"] == "removed"
    finally:
        for w in workers:
            w.handover_wait_s = 0.5  # (a leaving worker waits this long for a holder)
            w.stop()


def test_discovery_adds_a_vehicle_that_starts_publishing(archives):
    bus = InMemoryBus()
    sensor = InMemoryTransport(bus)
    workers = [_worker(bus, w, ["v1"], discover="siru") for w in ("w-a", "w-b", "w-c")]
    try:
        boss = owner(PSEUDO, [w.id for w in workers])
        wait_for(lambda: [w.id for w in workers if w.discovery.active()] == [boss], 10,
                 what="one discoverer")
        msgs = [m for m in input_messages(archives["a60"]) if m[0] == "siru"][:50]
        for topic, _, data in msgs[:5]:
            sensor.put(f"radical/new-v/{topic}", data, block=True)
        wait_for(lambda: all(w.vehicles == ["new-v", "v1"] for w in workers), 10,
                 what="new-v in every worker's roster")
        wait_for(lambda: len(_servers(workers, "new-v")) == 1, 20, what="new-v served")
        assert [w.id for w in workers if w.discovery.active()] == [boss]
        # one discovery subscription in the whole fleet
        assert sum(d.key == "radical/*/siru" for d in bus.find("sub", "radical/zz/siru")) == 1
        st = [w.status() for w in workers]
        assert [s["discovery"]["active"] for s in st].count(True) == 1
        assert st[0]["roster"]["entries"]["new-v"]["state"] == "discovered"
    finally:
        for w in workers:
            w.stop()
