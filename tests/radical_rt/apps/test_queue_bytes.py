"""Issue 23, "a byte bound on the input queue", over real Zenoh on loopback (free ports, multicast
off): a slow node flooded with large payloads keeps its input FIFO under ``queue_bytes``, its RSS
bounded, and counts what it dropped (messages and bytes, per topic) in status and as
INPUT_REJECTED. Before (main at fbe5c42): the Zenoh FIFO was bounded in samples only (4096 ×
any size), RSS grew by the flood, nothing was counted."""

from __future__ import annotations

import threading
import time

import msgpack
import pytest

from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_setup import build_processors
from radical_rt.io import zconfig
from radical_rt.io.zenoh_transport import ZenohTransport
from tests.support.node import wait_for

pytestmark = pytest.mark.zenoh

PAYLOAD = 512 << 10  # each under the 1 MiB payload bound: only the byte budget can stop them
N_PUT = 800  # 400 MiB offered
BUDGET = 8 << 20  # 16 payloads
SLACK = 96 << 20  # allocator, Zenoh buffers of both sessions (the client is in this process)


def _rss() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096


def status(t: ZenohTransport, vehicle: str) -> dict:
    r = t.get(f"radical/{vehicle}/cmd", msgpack.packb({"cmd": "status"}), timeout=10)
    assert len(r) == 1, f"{len(r)} replies"
    return msgpack.unpackb(r[0], raw=False, strict_map_key=False)


def test_slow_consumer_flood_is_byte_bounded_and_counted():
    ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
    nt = ZenohTransport("peer", listen=[ep])
    node = FilterNode(nt, build_processors(["qb"]), queue_bytes=BUDGET, queue_wait_s=0.01)
    take = node.take_input

    def slow_take(key: str, data: bytes) -> None:  # a consumer far slower than the flood
        time.sleep(0.02)
        take(key, data)

    node.take_input = slow_take
    node.start()
    client = ZenohTransport("peer", connect=[ep])
    junk = b"\xc1" * PAYLOAD  # never-used msgpack byte: each one rejected as undecodable
    peak, stop = [0, 0], threading.Event()

    def watch() -> None:
        while not stop.is_set():
            peak[0] = max(peak[0], _rss())
            q = node.queue_bytes_used()
            peak[1] = max(peak[1], q or 0)
            time.sleep(0.005)

    w = threading.Thread(target=watch)
    try:
        assert status(client, "qb")["ok"]
        base = _rss()
        w.start()
        for _ in range(N_PUT):
            client.put("radical/qb/siru", junk, block=True)
        wait_for(lambda: node.queue_bytes_used() == 0 and node._idle, 60, 0.05, "the FIFO drained")
        stop.set()
        w.join()
        st = status(client, "qb")
    finally:
        stop.set()
        client.close()
        node.stop()
        nt.close()
    info = st["node"]
    dropped = info["queue_overflow"].get("siru", 0)
    assert dropped > 0 and info["queue_overflow_bytes"]["siru"] == dropped * PAYLOAD
    assert info["received"]["siru"] + dropped == N_PUT  # BLOCK puts: every one taken or counted
    assert st["rejected"]["queue_overflow"] == dropped
    assert info["queue_bytes"] == BUDGET and peak[1] <= BUDGET
    print(f"RSS growth {(peak[0] - base) / 2**20:.0f} MiB, {dropped} of {N_PUT} dropped")
    assert peak[0] - base < BUDGET + SLACK, f"RSS grew by {(peak[0] - base) / 2**20:.0f} MiB"


def test_queue_bytes_arguments():
    import argparse

    from radical_rt.apps.node_cli import _check, add_arguments
    p = argparse.ArgumentParser()
    add_arguments(p)

    def check(*a: str) -> str | None:
        return _check(p.parse_args(["--vehicle", "a", *a]))

    assert "--queue-bytes" in check("--queue-bytes", "-1")
    assert "--queue-bytes" in check("--queue-bytes", "1000")  # under the payload bound
    assert check("--queue-bytes", "0") is None and check() is None
