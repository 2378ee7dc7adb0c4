"""Transport seam: key expressions, the in-memory bus (sync and threaded) and Zenoh on loopback
behave the same for what the node uses."""

from __future__ import annotations

import threading
import time

import pytest

from radical_rt.io import zconfig
from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport
from radical_rt.io.transport import key_matches
from radical_rt.io.zenoh_transport import ZenohTransport


@pytest.mark.parametrize("expr, key, ok", [
    ("radical/v1/*", "radical/v1/siru", True),
    ("radical/v1/*", "radical/v1/tlm/small", False),
    ("radical/*/cmd", "radical/v2/cmd", True),
    ("radical/**", "radical/v1/tlm/small", True),
    ("radical/**", "radical", True),
    ("radical/**/small", "radical/v1/tlm/small", True),
    ("radical/v1/siru", "radical/v1/siru", True),
    ("radical/v1/siru", "radical/v1/st1", False),
    ("radical/*", "radical/v1/siru", False),
])
def test_key_matches(expr, key, ok):
    assert key_matches(expr, key) is ok


def _exercise(a, b, sync, wait_alive):
    """The same checks on any pair of connected transports (a serves, b is the client)."""
    got: list[tuple[str, bytes]] = []
    sub = a.subscribe("radical/v1/*", lambda k, d: got.append((k, d)))
    a.queryable("radical/v1/cmd", lambda payload: b"re:" + payload)
    tok = a.liveliness_token("radical/v1/alive/filter")
    wait_alive(b, "radical/*/alive/filter", ["radical/v1/alive/filter"])
    keys = ["radical/v1/siru", "radical/v1/st1", "radical/v1/st2", "radical/v1/temp"]
    sent = [(keys[i % 4], i.to_bytes(4, "big")) for i in range(2000)]
    for k, d in sent:
        b.put(k, d, block=True)
    b.put("radical/v1/tlm/small", b"x")  # not matched by the subscriber
    sync(lambda: len(got) >= len(sent))
    assert got == sent  # every message, in order across keys
    assert b.get("radical/v1/cmd", b"hello", timeout=5) == [b"re:hello"]
    assert b.get("radical/v9/cmd", b"x", timeout=1) == []  # no queryable: no reply
    sub.undeclare()
    tok.undeclare()
    wait_alive(b, "radical/**", [])
    b.put("radical/v1/siru", b"late", block=True)
    time.sleep(0.1)
    assert got[-1][1] != b"late"
    # remote_only: a transport's own samples are not delivered to such a subscriber
    mine, anyone = [], []
    a.subscribe("own/*", lambda k, d: mine.append(d), remote_only=True)
    a.subscribe("own/*", lambda k, d: anyone.append(d))
    a.liveliness_token("own/alive")
    wait_alive(b, "own/**", ["own/alive"])
    a.put("own/x", b"from-a", block=True)
    b.put("own/x", b"from-b", block=True)
    sync(lambda: len(anyone) == 2 and len(mine) == 1)
    assert mine == [b"from-b"] and sorted(anyone) == [b"from-a", b"from-b"]
    _exercise_inbox(a, b, sync)


def _exercise_inbox(a, b, sync):
    """Inbox: other transports' samples in order, pulled; recv waits and wake() ends it; a
    remote_only put of its own transport never comes back into it."""
    box = a.inbox("radical/*/*", capacity=4096)
    a.liveliness_token("radical/box/alive")  # (Zenoh: wait for the subscription to be known)
    time.sleep(0.3 if isinstance(a, ZenohTransport) else 0)
    sent = [(f"radical/v{i % 3}/siru", i.to_bytes(4, "big")) for i in range(500)]
    for k, d in sent:
        b.put(k, d, block=True)
    a.put("radical/v0/diag", b"own", remote_only=True)
    b.put("radical/v0/tlm/small", b"4 chunks: not matched", block=True)
    got: list = []
    sync(lambda: True)
    end = time.monotonic() + 10
    while len(got) < len(sent) and time.monotonic() < end:
        item = box.try_recv()
        if item is None:
            time.sleep(0.005)
        else:
            got.append(item)
    assert got == sent and box.try_recv() is None
    woke: list = []
    th = threading.Thread(target=lambda: woke.append(box.recv()))
    th.start()
    time.sleep(0.1)
    assert th.is_alive()  # recv waits for a sample
    box.wake()
    th.join(5)
    assert not th.is_alive() and woke == [None]
    b.put("radical/v7/st1", b"after", block=True)
    sync(lambda: True)
    assert box.recv() == ("radical/v7/st1", b"after")
    assert box.take_dropped() == {}
    box.undeclare()


def _poll(pred, timeout=10.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return
        time.sleep(0.01)
    raise AssertionError("timeout")


@pytest.mark.parametrize("threaded", [False, True])
def test_in_memory(threaded):
    bus = InMemoryBus(threaded=threaded)
    a, b = InMemoryTransport(bus), InMemoryTransport(bus)

    def sync(pred):
        bus.sync()
        assert pred()

    def wait_alive(t, expr, want):
        assert bus.alive(expr) == want

    _exercise(a, b, sync, wait_alive)
    a.close()
    with pytest.raises(Exception, match="closed"):
        a.put("radical/v1/siru", b"")


def test_in_memory_threaded_delivery_thread_and_errors():
    bus = InMemoryBus(threaded=True)
    a, b = InMemoryTransport(bus), InMemoryTransport(bus)
    names, seen = [], []

    def cb(k, d):
        names.append(threading.current_thread().name)
        if d == b"boom":
            raise RuntimeError("callback failure must not stop delivery")
        seen.append(d)

    a.subscribe("k/**", cb)
    for d in (b"1", b"boom", b"2"):
        b.put("k/x", d)
    assert bus.sync()
    assert seen == [b"1", b"2"] and set(names) == {"inmem-sub-k/**"}


@pytest.mark.zenoh
def test_zenoh_loopback():
    port = zconfig.free_port()
    ep = f"tcp/127.0.0.1:{port}"
    a = ZenohTransport("peer", listen=[ep])
    b = ZenohTransport("peer", connect=[ep])
    try:
        def wait_alive(t, expr, want):
            _poll(lambda: t.alive(expr, timeout=1.0) == want)

        _exercise(a, b, _poll, wait_alive)
    finally:
        b.close()
        a.close()
    assert a.closed and b.closed


@pytest.mark.zenoh
def test_zenoh_refuses_non_loopback_and_reports_open_errors(tmp_path):
    with pytest.raises(zconfig.ZenohConfigError, match="not a loopback locator"):
        ZenohTransport("peer", listen=["tcp/0.0.0.0:7448"])
    bad = tmp_path / "z.json5"
    bad.write_text("{ this is not json5")
    with pytest.raises(Exception, match="Zenoh configuration|cannot open"):
        ZenohTransport("peer", listen=[f"tcp/127.0.0.1:{zconfig.free_port()}"], config_file=str(bad))
    port = zconfig.free_port()
    a = ZenohTransport("peer", listen=[f"tcp/127.0.0.1:{port}"])
    try:  # the same port twice: a clear error, not a hang
        with pytest.raises(Exception, match="cannot open Zenoh session"):
            ZenohTransport("peer", listen=[f"tcp/127.0.0.1:{port}"])
    finally:
        a.close()


def test_in_memory_inbox_full_waits_then_drops_and_counts():
    bus = InMemoryBus()
    a, b = InMemoryTransport(bus), InMemoryTransport(bus)
    box = a.inbox("k/*", capacity=2, wait_s=0.05)
    for i in range(5):
        b.put("k/x" if i % 2 else "k/y", bytes([i]))
    assert box.pending() == 2 and box.take_dropped() == {"k/y": 2, "k/x": 1}
    assert box.take_dropped() == {}  # counted once
    assert [box.try_recv(), box.try_recv(), box.try_recv()] == [("k/y", b"\x00"), ("k/x", b"\x01"), None]
    b.put("k/x", b"a")
    b.put("k/x", b"b")
    box.wait_s = 5.0
    t = threading.Thread(target=lambda: (time.sleep(0.1), box.try_recv()))
    t.start()
    b.put("k/x", b"c")  # full: waits until the reader makes room, then enters
    t.join()
    assert box.take_dropped() == {} and [box.try_recv(), box.try_recv()] == [("k/x", b"b"),
                                                                            ("k/x", b"c")]
