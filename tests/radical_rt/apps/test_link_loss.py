"""Issue 23, "losses visible: … link loss": a vehicle whose stream stops for ``stale_after_s`` of
wall time raises LINK_LOSS (bit 19) at once, published in a fault message and counted
(``link_losses``, ``link_lost_s``); the next input clears it; an end-of-stream marker ends the
watch. In memory with an injected monotonic clock, and over real Zenoh on loopback across a
router restart. Before (main at fbe5c42): no such flag or counter (losses showed only later, as
INPUT_GAP in the bus times, once input resumed)."""

from __future__ import annotations

import threading
import time

import msgpack
import pytest

from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_setup import build_processors
from radical_rt.contract.flags import Flag
from radical_rt.io import zconfig
from radical_rt.io.zenoh_transport import ZenohTransport
from radical_rt.stream.eos import make_eos
from replayer.publish import replay
from tests.support.node import MemNode, input_messages, make_archive, wait_for

LINK = int(Flag.LINK_LOSS)


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    return make_archive(tmp_path_factory.mktemp("link"), "lk20", seed=7, duration=20)


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def _idle(mn: MemNode) -> None:
    """Everything fed (generous: the first feed may compile the Numba kernels on a cold cache)."""
    assert mn.node.wait_idle(300)


def _faults(mn: MemNode) -> list[int]:
    return [m["flags"] for k, m in mn.outputs if k.endswith("/fault")]


def test_link_loss_in_memory(archive):
    msgs = input_messages(archive)
    clock = FakeClock()
    mn = MemNode(("lk",), stale_after_s=3.0, monotonic=clock)
    try:
        half = len(msgs) // 2
        for topic, _, data in msgs[:half]:
            mn.publish("lk", topic, data)
        _idle(mn)
        sp = mn.sp("lk")
        assert not sp.flags & LINK
        clock.now += 2.9  # under the stale time: nothing
        time.sleep(3 * FilterNode.TICK_S)
        assert not sp.flags & LINK and sp.counters()["link_losses"] == 0
        clock.now += 0.2  # 3.1 s without input
        wait_for(lambda: sp.flags & LINK, 10, 0.02, "LINK_LOSS")
        wait_for(lambda: any(f & LINK for f in _faults(mn)), 10, 0.02, "a fault message with it")
        st = mn.cmd("lk", cmd="status")
        assert "LINK_LOSS" in st["flag_names"] and st["node"]["link_lost"]
        assert st["counters"]["link_losses"] == 1
        clock.now += 10.0  # still lost: counted once
        time.sleep(3 * FilterNode.TICK_S)
        assert sp.counters()["link_losses"] == 1
        for topic, _, data in msgs[half:]:
            mn.publish("lk", topic, data)
        _idle(mn)
        c = sp.counters()
        assert not sp.flags & LINK and not _faults(mn)[-1] & LINK  # cleared, and published so
        assert c["link_losses"] == 1 and c["link_lost_s"] == pytest.approx(13.1)
        mn.publish("lk", "eos", msgpack.packb(make_eos({}, "none")))
        _idle(mn)
        clock.now += 100.0  # after a marker, silence is expected
        time.sleep(3 * FilterNode.TICK_S)
        assert not sp.flags & LINK and sp.counters()["link_losses"] == 1
    finally:
        mn.close()


@pytest.mark.zenoh
def test_link_loss_across_router_restart(archive):
    """Node and replayer behind a router that is down for 1.5 s during a paced replay: LINK_LOSS
    raised (and published) while it is down, cleared when input resumes, counted once."""
    ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
    router = ZenohTransport("router", listen=[ep])
    nt = ZenohTransport("peer", connect=[ep])
    node = FilterNode(nt, build_processors(["lr"]), stale_after_s=0.5)
    faults: list[int] = []
    publish = node.publish

    def spy(v, outs):  # the fault messages the node publishes (the link to a listener is down)
        faults.extend(m["flags"] for t, m in outs if t == "fault")
        publish(v, outs)

    node.publish = spy
    node.start()
    import zenoh
    ps = zenoh.open(zconfig.make_config("client", connect=[ep]))
    out: dict = {}
    th = threading.Thread(target=lambda: out.update(
        res=replay([archive], "lr", ps, rate=4.0, wait_subscribers=20)))
    v = node.vehicles["lr"]
    try:
        th.start()
        wait_for(lambda: v.received.get("siru", 0) > 50, 30, 0.01, "input")
        router.close()
        wait_for(lambda: v.sp.flags & LINK, 10, 0.01, "LINK_LOSS while the router is down")
        time.sleep(1.0)
        router = ZenohTransport("router", listen=[ep])
        th.join(60)
        assert not th.is_alive()
        wait_for(lambda: v.eos_seen == 1, 30, 0.05, "the end-of-stream marker")
        node.wait_idle(10)
        c = v.sp.counters()
        flags = v.sp.flags
    finally:
        ps.close()
        node.stop()
        nt.close()
        router.close()
    assert any(f & LINK for f in faults) and not faults[-1] & LINK
    assert not flags & LINK
    assert c["link_losses"] >= 1 and c["link_lost_s"] > 0.5
