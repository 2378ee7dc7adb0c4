"""The node over the in-memory transport: bit-identical to batch, survives any payload (seeded
fuzz), serves several vehicles independently, checkpoints round-trip, overflow is counted."""

from __future__ import annotations

import math
import os

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import make_processor, process
from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_setup import build_processors, warm_up
from radical_rt.contract.flags import Flag
from radical_rt.io import checkpoint as ckpt
from radical_rt.io.archive import ArchiveReader
from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport
from tests.support.node import (
    MemNode,
    feed_archive,
    final_summary,
    input_messages,
    same_estimates,
)
from tests.support.node_fuzz import fuzz_stream

SEED = 20240607


# ------------------------------------------------------------------------------ bit-identity
@pytest.mark.parametrize("threaded", [False, True])
def test_node_equals_batch(archives, batch_ref, threaded, tmp_path):  # noqa: F811
    mn = MemNode(threaded=threaded, block_outputs=True)
    try:
        feed_archive(mn, "v1", input_messages(archives["a60"]))
        s = final_summary(mn)
        ref = batch_ref["a60"]
        assert same_estimates(s, ref)
        assert s["counters"] == ref["counters"] and s["mode"] == ref["mode"]
        if threaded:
            return
        # the published telemetry equals the batch shell's output archive, packet for packet
        out = tmp_path / "out.mcap"
        process([str(archives["a60"])], str(out))
        with ArchiveReader(out) as r:
            want = [(t, m) for t, _, m in r.iter_messages(["/tlm/small", "/tlm/medium", "/fault"])]
        got = [(k[len("radical/v1"):], m) for k, m in mn.outputs
               if k.endswith(("tlm/small", "tlm/medium", "fault"))]
        assert len(got) == len(want) > 600
        assert sorted(got, key=lambda x: (x[1]["t"], x[0])) == sorted(want, key=lambda x: (x[1]["t"], x[0]))
    finally:
        mn.close()


def test_end_stream_between_archives_equals_batch(archives):  # noqa: F811
    """Two disjoint streams with a warm start between them, as `radical process A B` does."""
    ref = process([str(archives["a60"]), str(archives["b60"])], None)
    mn = MemNode()
    try:
        feed_archive(mn, "v1", input_messages(archives["a60"]))
        assert mn.cmd(cmd="end_stream")["next"] == "warm"
        feed_archive(mn, "v1", input_messages(archives["b60"]))
        s = final_summary(mn)
    finally:
        mn.close()
    assert same_estimates(s, ref) and s["counters"] == ref["counters"]


def test_warm_up_compiles_everything():
    assert warm_up() < 60.0


# ------------------------------------------------------------------------------ fuzz
def test_fuzzed_payloads_leave_estimates_unchanged(archives, batch_ref):  # noqa: F811
    msgs = input_messages(archives["a60"])
    stream, n_bad = fuzz_stream(msgs, SEED)
    mn = MemNode()
    try:
        for topic, payload in stream:
            mn.publish("v1", topic, payload)
        mn.idle()
        sp = mn.sp()
        diag = [m for k, m in mn.outputs if k.endswith("/diag")]
        faults = [m for k, m in mn.outputs if k.endswith("/fault")]
        s = final_summary(mn)
    finally:
        mn.close()
    ref = batch_ref["a60"]
    assert n_bad > 500, "seed produced too few bad messages"
    assert same_estimates(s, ref), f"fuzz seed {SEED}: estimates differ from the clean run"
    assert s["counters"]["input_rejected"] == n_bad, f"seed {SEED}: {dict(sp.rejected)}"
    assert {k: v for k, v in s["counters"].items() if k != "input_rejected"} == \
        {k: v for k, v in ref["counters"].items() if k != "input_rejected"}
    reasons = set(sp.rejected)
    assert {"malformed", "not_a_map", "bad_version", "missing_field", "bad_type", "bad_shape",
            "nonfinite", "non_unit_quaternion", "time_backwards", "duplicate"} <= reasons, reasons
    assert diag and diag[-1]["rejected"] and sum(diag[-1]["rejected"].values()) > 0
    assert any("INPUT_REJECTED" in f["set"] for f in faults)
    assert not sp.engine.flags & Flag.NUMERIC


def test_fuzz_seeds_do_not_crash_the_node(archives):  # noqa: F811
    """More seeds on a short stretch: the node keeps running and keeps a sane state."""
    msgs = [m for m in input_messages(archives["a60"]) if m[1] < 1010e9]
    for seed in range(3):
        stream, n_bad = fuzz_stream(msgs, seed, rate=0.6)
        mn = MemNode()
        try:
            for topic, payload in stream:
                mn.publish("v1", topic, payload)
            mn.idle()
            st = mn.cmd(cmd="status")
            assert st["ok"] and st["counters"]["input_rejected"] == n_bad, f"seed {seed}"
            assert st["flags"] & Flag.INPUT_REJECTED or st["t"] - 1010 > 1.0
            assert np.all(np.isfinite(mn.sp().engine.xp)) and mn.node.loop_error is None
        finally:
            mn.close()


# ------------------------------------------------------------------------------ several vehicles
def test_two_vehicles_do_not_interfere(archives, batch_ref):  # noqa: F811
    a, b = input_messages(archives["a60"]), input_messages(archives["b60"])
    stream_b, n_bad = fuzz_stream(b, SEED + 1, rate=0.1)
    mn = MemNode(vehicles=("alpha", "bravo"))
    try:
        ia = ib = 0
        while ia < len(a) or ib < len(stream_b):  # interleave the two vehicles' streams
            if ia < len(a):
                mn.publish("alpha", a[ia][0], a[ia][2])
                ia += 1
            for _ in range(2):
                if ib < len(stream_b):
                    mn.publish("bravo", *stream_b[ib])
                    ib += 1
        mn.idle()
        assert mn.cmd("bravo", cmd="set_params", params={"gate_st_nis": 1.0})["ok"]
        assert mn.cmd("bravo", cmd="exclude_gyro", gyro=3)["ok"]
        assert mn.sp("alpha").engine.table.active.gate_st_nis == 30.0
        assert not mn.sp("alpha").engine.excluded.any()
        sa = final_summary(mn, "alpha")
        mn.cmd("bravo", cmd="include_gyro", gyro=3)
        mn.cmd("bravo", cmd="reset_params")
        sb = final_summary(mn, "bravo")
        outs = {k.split("/")[1] for k, _ in mn.outputs}
    finally:
        mn.close()
    assert same_estimates(sa, batch_ref["a60"]) and sa["counters"]["input_rejected"] == 0
    assert same_estimates(sb, batch_ref["b60"]) and sb["counters"]["input_rejected"] == n_bad
    assert outs == {"alpha", "bravo"}


def test_liveliness_tokens_and_keys():
    mn = MemNode(vehicles=("x1", "y-2"))
    try:
        assert mn.bus.alive("radical/*/alive/filter") == ["radical/x1/alive/filter",
                                                          "radical/y-2/alive/filter"]
    finally:
        mn.close()
    assert mn.bus.alive() == []


def test_bad_vehicle_names():
    for bad in (["Upper"], ["a/b"], ["ok", "ok"], []):
        with pytest.raises(ValueError):
            build_processors(bad)


# ------------------------------------------------------------------------------ overflow
def test_queue_overflow_is_counted(archives):  # noqa: F811
    msgs = input_messages(archives["a60"])[:400]
    bus = InMemoryBus()
    procs = build_processors(["v1"])
    # the overflow leaves gaps longer than the plausibility window, and the last step is far
    # ahead: this test is about the overflow count, so no time sanity check (test_time_sanity.py)
    procs["v1"].time_window_s = math.inf
    node = FilterNode(InMemoryTransport(bus), procs, queue_size=8, queue_wait_s=0.0)
    client = InMemoryTransport(bus)
    node.start()
    try:
        sp = node.vehicles["v1"].sp
        real = sp.feed
        sp.feed = lambda t, d: (__import__("time").sleep(0.002), real(t, d))[1]
        for topic, _ns, data in msgs:  # far faster than the stalled loop drains
            client.put(f"radical/v1/{topic}", data)
        assert node.wait_idle(30)
        sp.feed = real
        client.put("radical/v1/temp", msgpack.packb({"v": 1, "t_bus": 5000.0}))  # one more step
        assert node.wait_idle(10)
        info = node.vehicles["v1"].node_info()
        dropped = sum(info["queue_overflow"].values())
        assert dropped > 0 and sum(info["fed"].values()) == len(msgs) + 1 - dropped
        assert sp.rejected["queue_overflow"] == dropped
        assert sp.flags & Flag.INPUT_REJECTED
        assert "queue full" in sp.last_reject
    finally:
        node.stop()


# ------------------------------------------------------------------------------ checkpoints
def test_checkpoint_round_trip(archives, tmp_path):  # noqa: F811
    msgs = input_messages(archives["a60"])
    sp = make_processor()
    sp.engine.table.set({"gate_st_nis": 20.0})
    sp.engine.params_changed()
    for topic, _ns, data in msgs[: len(msgs) // 2]:
        sp.feed(topic, data)
    sp.feed("st1", b"garbage")
    path = tmp_path / "c.ckpt"
    state = ckpt.capture(sp, "v1")
    assert ckpt.write(path, {"v1": state}) == str(path)
    assert [p.name for p in tmp_path.iterdir()] == ["c.ckpt"]  # no temp file left
    doc = ckpt.read(path)
    assert doc["vehicles"]["v1"] == msgpack.unpackb(msgpack.packb(state), strict_map_key=False)

    sp2 = make_processor()
    ckpt.restore(sp2, doc["vehicles"]["v1"])
    e, e2 = sp.engine, sp2.engine
    assert e2.estimates() == e.estimates() and e2.sigmas() == e.sigmas()  # parameters exact
    assert np.array_equal(e2.U[3:, 3:], e.U[3:, 3:]) and np.array_equal(e2.d[3:], e.d[3:])
    assert e2.mode == e.mode and e2.att_valid  # the stream continues (no warm start)
    assert np.array_equal(e2.q, e.q) and np.array_equal(e2.U, e.U)
    assert e2.table.active.gate_st_nis == 20.0 and e2.si.gate_st_nis == 20.0
    assert dict(sp2.rejected) == dict(sp.rejected) == {"malformed": 1}
    assert {n: s.seq for n, s in sp2.packets.items()} == {n: s.seq for n, s in sp.packets.items()}
    assert sp2.clock.freq_offset_ppm() == sp.clock.freq_offset_ppm()
    for name in ("Minv", "Gp", "N"):  # derived geometry refreshed from the restored parameters
        assert np.array_equal(getattr(e2, name), getattr(e, name)), name
    # the restored processor continues and converges to the uninterrupted run's estimates
    for topic, _ns, data in msgs[len(msgs) // 2:]:
        sp.feed(topic, data)
        sp2.feed(topic, data)
    sp.end_stream(None)
    sp2.end_stream(None)
    assert e2.mode in ("converging", "converged")
    assert e2.estimates() == e.estimates() and e2.sigmas() == e.sigmas()  # continued exactly
    # a new stream instead (--resume-new-stream): warm start, attitude from the next tracker
    sp3 = make_processor()
    ckpt.restore(sp3, doc["vehicles"]["v1"], new_stream=True)
    assert sp3.engine.mode == "init" and not sp3.engine.att_valid


def test_checkpoint_errors_change_nothing(tmp_path):
    path = tmp_path / "bad.ckpt"
    path.write_bytes(b"\x00\x01garbage")
    with pytest.raises(ckpt.CheckpointError, match="not a msgpack checkpoint|schema"):
        ckpt.read(path)
    path.write_bytes(msgpack.packb({"schema": "other/1"}))
    with pytest.raises(ckpt.CheckpointError, match="schema 'other/1'"):
        ckpt.read(path)
    with pytest.raises(ckpt.CheckpointError, match="no such file"):
        ckpt.read(tmp_path / "missing.ckpt")
    sp = make_processor()
    good = ckpt.capture(sp)
    before = msgpack.packb(ckpt.capture(sp))
    for broken in ({k: v for k, v in good.items() if k != "running"},
                   {**good, "params": {"active": {"gate_st_nis": -1}}},
                   {**good, "running": {**good["running"], "clock": {"schema": "nope"}}}):
        with pytest.raises(ckpt.CheckpointError):
            ckpt.restore(sp, broken)
        assert msgpack.packb(ckpt.capture(sp)) == before
    with pytest.raises(ckpt.CheckpointError, match="cannot write"):
        ckpt.write(tmp_path / "no" / "dir" / "c.ckpt", {"v": good})


def test_periodic_final_and_resume(archives, tmp_path):  # noqa: F811
    msgs = input_messages(archives["a60"])
    now = [0.0]
    path = str(tmp_path / "node.ckpt")
    mn = MemNode(vehicles=("v1", "v2"), checkpoint_path=path, checkpoint_every_s=10.0,
                 monotonic=lambda: now[0])
    try:
        feed_archive(mn, "v1", msgs[:300])
        assert not os.path.exists(path)
        now[0] = 10.5  # ten seconds of (fake) wall time later
        feed_archive(mn, "v1", msgs[300:301])
        assert mn.node.checkpoints_written == 1 and os.path.exists(path)
        t1 = ckpt.read(path)["vehicles"]["v1"]["t"]
        feed_archive(mn, "v1", msgs[301:1500])
        assert ckpt.read(path)["vehicles"]["v1"]["t"] == t1  # not due yet
        est = mn.sp("v1").engine.estimates()
    finally:
        mn.close()  # final checkpoint
    doc = ckpt.read(path)
    assert doc["vehicles"]["v1"]["t"] > t1 and set(doc["vehicles"]) == {"v1", "v2"}
    with pytest.raises(ckpt.CheckpointError, match="not of 'v3'"):
        MemNode(vehicles=("v1", "v3"), resume=path)  # v3 is not in the checkpoint: refused
    mn2 = MemNode(vehicles=("v1", "v3"), resume=path, force_vehicle=True)
    try:
        st = mn2.cmd("v1", cmd="status")
        assert st["est"] == est and st["mode"] != "init"  # the stream continues
        assert mn2.cmd("v3", cmd="status")["t"] == -math.inf  # not in the checkpoint: cold
        feed_archive(mn2, "v1", msgs[1600:])
        assert mn2.sp("v1").engine.mode in ("converging", "converged")
    finally:
        mn2.close()


# ------------------------------------------------------------------------------ real-time loop
def _fifo_allowed() -> bool:
    """Whether this process may give a thread SCHED_FIFO (root or CAP_SYS_NICE)."""
    import threading

    ok = []

    def probe():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
            ok.append(True)
        except OSError:
            ok.append(False)

    t = threading.Thread(target=probe)
    t.start()
    t.join()
    return ok[0]


def test_rt_priority_runs_the_loop_sched_fifo_or_refuses_clearly(archives):  # noqa: F811
    from radical_rt.apps.node import NodeStartError

    with pytest.raises(ValueError, match="rt_priority"):
        FilterNode(InMemoryTransport(InMemoryBus()), build_processors(["v1"]), rt_priority=0)
    bus = InMemoryBus()
    node = FilterNode(InMemoryTransport(bus), build_processors(["v1"]), rt_priority=7)
    if not _fifo_allowed():
        with pytest.raises(NodeStartError, match="SCHED_FIFO priority 7.*CAP_SYS_NICE"):
            node.start()
        assert node._thread is None and node._inbox is None and not node.running
        return
    node.start()
    try:
        tid = node._thread.native_id
        assert os.sched_getscheduler(tid) == os.SCHED_FIFO
        assert os.sched_getparam(tid).sched_priority == 7
        client = InMemoryTransport(bus)
        msgs = input_messages(archives["a60"])[:300]
        for topic, _ns, data in msgs:
            client.put(f"radical/v1/{topic}", data)
        assert node.wait_idle(30)
        assert sum(node.vehicles["v1"].fed.values()) == len(msgs)
    finally:
        node.stop()
    assert os.sched_getscheduler(0) != os.SCHED_FIFO  # only the loop thread was changed


def test_rt_priority_refused_leaves_nothing_running(monkeypatch):
    from radical_rt.apps import node as node_mod
    from radical_rt.apps.node import NodeStartError

    def refuse(*_a):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(node_mod.os, "sched_setscheduler", refuse)
    node = FilterNode(InMemoryTransport(InMemoryBus()), build_processors(["v1"]), rt_priority=3)
    with pytest.raises(NodeStartError, match="priority 3: Operation not permitted"):
        node.start()
    assert node._thread is None and node._ticker is None and node._inbox is None
    assert not node.running
