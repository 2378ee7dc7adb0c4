"""End of stream and visible losses (issue 23): the end-of-stream marker and the idle release
end a live stream bit-identical to batch; losses reported by the marker, gaps in the siru bus
times and gyro gaps are counted and published as flags. Each test failed before the fix."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import make_processor, make_summary, process
from radical_rt.stream.eos import make_eos
from tests.support.node import MemNode, input_messages, make_archive, wait_for

SI_KEYS = ("estimate", "sigma")


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    return make_archive(tmp_path_factory.mktemp("losses"), "a30", seed=3, duration=30)


@pytest.fixture(scope="module")
def msgs(archive):
    return input_messages(archive)


@pytest.fixture(scope="module")
def ref(archive):
    return process([str(archive)], None)


def same(a: dict, b: dict) -> bool:
    return all(np.array_equal(np.array(a[k][g]), np.array(b[k][g])) for k in SI_KEYS
               for g in a[k]) and a["t_end"] == b["t_end"] and a["counters"] == b["counters"]


def counts_of(msgs) -> dict[str, int]:
    c: dict[str, int] = {}
    for t, _ns, _d in msgs:
        c[t] = c.get(t, 0) + 1
    return c


def test_end_of_stream_marker_ends_bit_identical_to_batch(msgs, ref):
    """Before: the node ignored the marker and ended one packet short (the samples held for
    reordering were never released)."""
    mn = MemNode()
    try:
        for topic, _ns, data in msgs:
            mn.publish("v1", topic, data)
        mn.publish("v1", "eos", msgpack.packb(make_eos(counts_of(msgs))))
        mn.idle()
        s = mn.cmd(cmd="status")["summary"]
        info = mn.node.vehicles["v1"].node_info()
        last_t = max(m["t"] for k, m in mn.outputs if k.endswith("tlm/medium"))
    finally:
        mn.close()
    assert same(s, ref)
    assert info["eos"] == 1 and info["reported_lost"] == 0
    assert last_t == pytest.approx(ref["t_end"], abs=0.15)


def test_idle_release_ends_bit_identical_to_batch(msgs, ref):
    """No marker (an older publisher, a stopped replay): after idle_release_s without input the
    node releases what it holds."""
    mn = MemNode(idle_release_s=0.3)
    try:
        for topic, _ns, data in msgs:
            mn.publish("v1", topic, data)
        wait_for(lambda: mn.node.vehicles["v1"].idle_releases == 1, timeout=20,
                 what="the idle release")
        mn.idle()
        s = mn.cmd(cmd="status")["summary"]
    finally:
        mn.close()
    assert same(s, ref)


def test_loss_reported_by_the_marker_is_counted_and_flagged(msgs):
    """Seven siru messages lost on the way: the marker's counts say so (before: nothing)."""
    drop = {i for i, m in enumerate(msgs) if m[0] == "siru"}
    drop = set(sorted(drop)[100:107])
    mn = MemNode()
    try:
        for i, (topic, _ns, data) in enumerate(msgs):
            if i not in drop:
                mn.publish("v1", topic, data)
        mn.publish("v1", "eos", msgpack.packb(make_eos(counts_of(msgs))))
        mn.idle()
        info = mn.node.vehicles["v1"].node_info()
        st = mn.cmd(cmd="status")
        faults = [m for k, m in mn.outputs if k.endswith("/fault")]
    finally:
        mn.close()
    assert info["reported_lost"] == 7 and st["counters"]["input_reported_lost"] == 7
    assert any("INPUT_GAP" in f["set"] for f in faults)


def test_bad_marker_is_a_counted_rejection_and_changes_nothing(msgs):
    mn = MemNode()
    try:
        for topic, _ns, data in msgs[:300]:
            mn.publish("v1", topic, data)
        mn.idle()
        before = mn.state()
        for bad in (b"junk", msgpack.packb({"v": 1, "next": "sideways"}),
                    msgpack.packb({"v": 1, "counts": {"siru": -1}}), msgpack.packb([1])):
            mn.publish("v1", "eos", bad)
        after = mn.state()
        rej = dict(mn.sp().rejected)
    finally:
        mn.close()
    assert rej == {"bad_eos": 4}
    # the running state (engine, clock, queues, FDI) is unchanged by the refused markers; only
    # the time of the last rejection moves (it raises INPUT_REJECTED)
    run0, run1 = msgpack.unpackb(before)["running"], msgpack.unpackb(after)["running"]
    assert run0.pop("schedule")["packets"] == run1.pop("schedule")["packets"]
    assert run0 == run1


def _run(msgs, keep):
    sp, outs = make_processor(), []
    for i, (topic, _ns, data) in enumerate(msgs):
        if keep(i, topic):
            outs.extend(sp.feed(topic, data))
    outs.extend(sp.end_stream(None))
    return sp, [m for k, m in outs if k == "fault"]


def test_gyro_gap_is_published(msgs):
    """One second of siru messages lost: the engine raises GYRO_GAP and clears it at the next
    attitude initialisation, inside one window; before, no fault message ever carried it."""
    siru = [i for i, m in enumerate(msgs) if m[0] == "siru"]
    lost = set(siru[150:160])  # 10 batches of 10 samples: 1 s
    sp, faults = _run(msgs, lambda i, t: i not in lost)
    assert sp.engine.counters["gyro_gaps"] == 1
    assert any("GYRO_GAP" in f["set"] for f in faults)
    assert any("GYRO_GAP" in f["cleared"] for f in faults)  # and it clears again


def test_siru_bus_time_gap_is_counted_and_flagged(msgs):
    """A publisher that drops (here: every 7th siru batch): gaps in the bus times, counted."""
    siru = [i for i, m in enumerate(msgs) if m[0] == "siru"]
    lost = set(siru[50:250:7])
    sp, faults = _run(msgs, lambda i, t: i not in lost)
    c = sp.counters()
    assert c["input_gaps"] == len(lost)
    assert c["input_gap_s"] == pytest.approx(0.1 * len(lost), rel=0.2)
    assert any("INPUT_GAP" in f["set"] for f in faults)
    assert make_summary(sp)["counters"]["siru_missing"] >= 10 * len(lost) - 5


def test_input_queue_is_bounded_in_bytes():
    """Junk payloads into a stalled loop: the in-memory FIFO never holds more than its byte bound
    and counts what it drops (before: bounded in samples only)."""
    import threading

    from radical_rt.apps.node import FilterNode
    from radical_rt.apps.node_setup import build_processors
    from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport

    bus = InMemoryBus()
    node = FilterNode(InMemoryTransport(bus), build_processors(["v1"]), queue_size=4096,
                      queue_wait_s=0.0, queue_bytes=1 << 20)
    client = InMemoryTransport(bus)
    node.start()
    gate = threading.Event()
    sp = node.vehicles["v1"].sp
    real = sp.feed
    sp.feed = lambda t, d: (gate.wait(30), real(t, d))[1]
    peak = 0
    try:
        junk = bytes(range(256)) * 800  # 200 kB, not msgpack
        for _ in range(40):
            client.put("radical/v1/siru", junk)
            peak = max(peak, node._inbox.nbytes)
        gate.set()
        assert node.wait_idle(30)
        info = node.vehicles["v1"].node_info()
    finally:
        gate.set()
        node.stop()
    assert peak <= 1 << 20
    dropped = info["queue_overflow"]["siru"]
    assert dropped >= 40 - 6 and sp.rejected["queue_overflow"] == dropped
    assert sum(sp.rejected.values()) == 40
