"""The fleet's checkpoint replica (radical_rt.fleet.replica): every worker holds the newest
checkpoint of every vehicle, a late joiner fetches it, damaged envelopes are refused."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from radical_rt.apps.node_setup import build_processors
from radical_rt.fleet.replica import CheckpointReplica
from radical_rt.io import checkpoint as ckpt
from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport
from tests.support.node import input_messages


@pytest.fixture(scope="module")
def fed_state(archives):
    sp = build_processors(["v1"])["v1"]
    for topic, _, data in input_messages(archives["a60"])[:400]:
        sp.feed(topic, data)
    return sp, ckpt.capture(sp, "v1")


def test_every_worker_holds_the_newest_and_a_survivor_restores_it(fed_state):
    sp, state = fed_state
    bus = InMemoryBus()
    a, b = (CheckpointReplica(InMemoryTransport(bus), "f1", w) for w in ("w-a", "w-b"))
    first = a.publish("v1", state)
    second = a.publish("v1", state)
    assert second.seq == first.seq + 1
    held = b.latest("v1")
    assert held is not None and (held.worker, held.seq) == ("w-a", second.seq)
    fresh = build_processors(["v1"])["v1"]
    ckpt.restore(fresh, held.state())
    e, f = sp.engine, fresh.engine
    assert f.t == e.t and f.estimates() == e.estimates() and f.sigmas() == e.sigmas()
    assert np.array_equal(f.q, e.q) and f.mode == e.mode
    late = CheckpointReplica(InMemoryTransport(bus), "f1", "w-c")  # joins after the puts
    assert late.latest("v1") is None
    got = late.fetch("v1")
    assert got is not None and got.data == second.data
    assert late.fetch("nope") is None


def test_damaged_or_foreign_envelopes_are_refused(fed_state):
    _, state = fed_state
    bus = InMemoryBus()
    t = InMemoryTransport(bus)
    r = CheckpointReplica(InMemoryTransport(bus), "f1", "w-b")
    good = msgpack.unpackb(msgpack.packb({"v": 1, "fleet": "f1", "vehicle": "v1", "worker": "w-a",
                                          "seq": 1, "t_wall": 1.0,
                                          "ckpt": ckpt.dumps({"v1": state})}), raw=False)
    damaged = dict(good, ckpt=good["ckpt"][:-3] + b"xyz")
    for env in (damaged, dict(good, fleet="f2"), {"v": 1}, dict(good, vehicle="v2")):
        t.put("radical-fleet/f1/ckpt/v1", msgpack.packb(env, use_bin_type=True))
    t.put("radical-fleet/f1/ckpt/v1", b"\xc1")
    assert r.rejected == 5 and r.latest("v1") is None and r.latest("v2") is None
    t.put("radical-fleet/f1/ckpt/v1", msgpack.packb(good, use_bin_type=True))
    assert r.latest("v1") is not None and r.rejected == 5
