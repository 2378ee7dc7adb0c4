"""The fleet worker's one filter loop (radical_rt.apps.fleet_node.FleetNode) on an in-memory
bus: vehicles held, served and cut while the loop runs, one loop thread for all of them, a
handover's digest, the bound on held inputs, staggered checkpoints, commands after a cut."""

from __future__ import annotations

import threading

import msgpack
import pytest

from radical_rt.apps import commands
from radical_rt.apps.command_queue import CommandQueue
from radical_rt.apps.fleet_node import FleetNode, input_digest
from radical_rt.apps.node_setup import build_processors
from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport
from tests.support.node import input_messages, wait_for


def _sp(name: str):
    return build_processors([name])[name]


class Clock:
    """A monotonic clock the test moves by hand."""

    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture()
def rig():
    bus = InMemoryBus()
    client = InMemoryTransport(bus)
    written: list[list[str]] = []
    clock = Clock()

    def sink(states):
        written.append(sorted(states))
        return "memory"

    node = FleetNode(InMemoryTransport(bus), inbox_key="radical-fleet/t/inbox/w",
                     checkpoint_path=sink, checkpoint_every_s=10.0, monotonic=clock)
    node.start()
    yield node, client, written, clock
    node.stop(drain_s=0.0, final_checkpoint=False)


def _feed(client, vehicle: str, msgs) -> None:
    for topic, _, data in msgs:
        client.put(f"radical/{vehicle}/{topic}", data, block=True)


def test_one_loop_serves_vehicles_that_come_and_go(rig, archives):
    node, client, _written, _clock = rig
    msgs = input_messages(archives["a60"])[:400]
    loops = lambda: sum(t.name == "radical-filter" for t in threading.enumerate())  # noqa: E731
    assert loops() == 1
    for v in ("v1", "v2", "v3"):
        node.hold(v, _sp(v))
        node.serve_vehicle(v)
    _feed(client, "v2", msgs)
    assert node.wait_idle(30)
    assert loops() == 1 and set(node.vehicles) == {"v1", "v2", "v3"}
    ref = _sp("v2")
    for topic, _, data in msgs:
        ref.feed(topic, data)
    assert node.processor("v2").engine.t == ref.engine.t > 0
    assert not node.vehicle("v1").fed  # it received nothing
    digest = node.cut("v2")
    topic, _, data = msgs[-1]
    assert digest == input_digest(topic, data)  # the last input fed
    node.drop("v2")
    _feed(client, "v2", msgs[:10])  # no longer subscribed: nothing arrives
    assert node.wait_idle(30) and set(node.vehicles) == {"v1", "v3"}
    assert node.vehicle("v2") is None


def test_held_inputs_are_fed_after_the_digest(rig, archives):
    node, client, _written, _clock = rig
    msgs = input_messages(archives["a60"])[:300]
    node.hold("v1", _sp("v1"))
    _feed(client, "v1", msgs)
    assert node.wait_idle(30)
    assert not node.vehicle("v1").fed  # held, not fed
    topic, _, data = msgs[99]  # the old owner fed up to here
    dropped = node.serve_vehicle("v1", input_digest(topic, data))
    assert dropped == 100
    assert node.wait_idle(30)
    ref = _sp("v1")
    for topic, _, data in msgs[100:]:
        ref.feed(topic, data)
    assert node.processor("v1").engine.t == ref.engine.t
    assert node.vehicle("v1").fed == ref_fed(msgs[100:])


def ref_fed(msgs) -> dict[str, int]:
    out: dict[str, int] = {}
    for topic, _, _ in msgs:
        out[topic] = out.get(topic, 0) + 1
    return out


def test_held_inputs_beyond_the_bound_are_counted(archives):
    bus = InMemoryBus()
    client = InMemoryTransport(bus)
    node = FleetNode(InMemoryTransport(bus), inbox_key="radical-fleet/t/inbox/w",
                     queue_bytes=20_000)
    node.start()
    try:
        msgs = input_messages(archives["a60"])[:300]
        node.hold("v1", _sp("v1"))
        for topic, _, data in msgs:
            client.put(f"radical/v1/{topic}", data, block=True)
            node.wait_idle(5)  # the FIFO itself never overflows: only the held list
        node.serve_vehicle("v1")
        assert node.wait_idle(30)
        kept = sum(node.vehicle("v1").fed.values())
        assert 0 < kept < len(msgs)
        assert node.processor("v1").rejected["queue_overflow"] == len(msgs) - kept
    finally:
        node.stop(drain_s=0.0, final_checkpoint=False)


def test_periodic_checkpoints_are_one_vehicle_at_a_time(rig):
    node, _client, written, clock = rig
    names = [f"v{i}" for i in range(6)]
    for v in names:
        node.hold(v, _sp(v))
        node.serve_vehicle(v)
    for _ in range(40):  # two periods in steps of 0.5 s
        clock.now += 0.5
        node.checkpoint_step()
    assert written and all(len(w) == 1 for w in written)  # never all at once
    per = {v: sum(w == [v] for w in written) for v in names}
    assert all(n == 2 for n in per.values()), per  # each once per 10-s period
    assert len({w[0] for w in written[:6]}) == 6  # spread: every vehicle before any twice


def test_a_command_for_a_vehicle_cut_meanwhile_is_refused(rig):
    node, client, _written, _clock = rig
    node.hold("v1", _sp("v1"))
    node.serve_vehicle("v1")
    [r] = client.get("radical/v1/cmd", msgpack.packb({"cmd": "status"}), timeout=5)
    assert msgpack.unpackb(r, raw=False)["vehicle"] == "v1"
    with pytest.raises(RuntimeError, match="cut it first"):
        node.drop("v1")  # served: only after a cut
    v = node.vehicle("v1")
    node.cut("v1")
    assert client.get("radical/v1/cmd", msgpack.packb({"cmd": "status"}), timeout=1) == []
    # a command queued for it before the cut (its queryable answered) is refused by the loop
    q = CommandQueue()
    reply: dict = {}
    th = threading.Thread(target=lambda: reply.update(
        q.submit(v, commands.parse(msgpack.packb({"cmd": "status"})), 5.0, lambda: None)))
    th.start()
    wait_for(lambda: not q.empty(), 5, what="the command to queue")
    q.run(node.vehicles)
    th.join()
    assert reply["ok"] is False and "no longer served" in reply["error"]
