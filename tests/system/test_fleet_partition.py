"""A network partition of a fleet worker (its only link cut by a proxy, then restored), on real
Zenoh sessions in one process: the cut-off worker stops serving, the other takes its vehicles
over from the replica (the loss flagged), and once the link is back the vehicles return to it by
handover; no vehicle ever has two owners (issue #19)."""

from __future__ import annotations

import threading
import time

import pytest

from radical_rt.apps.fleet_worker import FleetWorker
from radical_rt.apps.node_setup import build_processors
from radical_rt.fleet.ownership import assign
from radical_rt.io import zconfig
from radical_rt.io.zenoh_transport import ZenohTransport
from tests.support.fleet import FleetWatch
from tests.support.node import input_messages, wait_for
from tests.support.tcp_proxy import TcpProxy

pytestmark = pytest.mark.zenoh
VEHICLES = ["pa", "pb", "pc", "pd"]
PACE = 1.5  # input bus time per wall-clock second


def _make(name: str):
    return build_processors([name])[name]


def test_partition_and_heal(archives):
    p_router, p_proxy = zconfig.free_port(), zconfig.free_port()
    router = ZenohTransport("router", listen=[f"tcp/127.0.0.1:{p_router}"])
    proxy = TcpProxy(p_proxy, p_router)
    direct = f"tcp/127.0.0.1:{p_router}"
    ta = ZenohTransport("client", connect=[direct])
    tb = ZenohTransport("client", connect=[f"tcp/127.0.0.1:{p_proxy}"])  # through the proxy
    client = ZenohTransport("client", connect=[direct])
    a = FleetWorker(ta, "fp", VEHICLES, _make, worker_id="w-a", checkpoint_every_s=0.5)
    b = FleetWorker(tb, "fp", VEHICLES, _make, worker_id="w-b", checkpoint_every_s=0.5)
    stop = threading.Event()
    msgs = input_messages(archives["a120"])
    sent = [0]

    def publish() -> None:
        """The 120 s archive paced on the wall clock at PACE x its bus time (80 s: longer than
        the test's waits can add up to, 64.5 s, however slow the machine)."""
        t0, ns0 = time.monotonic(), msgs[0][1]
        for topic, ns, data in msgs:
            ahead = t0 + (ns - ns0) * 1e-9 / PACE - time.monotonic()
            if ahead > 0:
                stop.wait(ahead)
            if stop.is_set():
                return
            for v in VEHICLES:
                client.put(f"radical/{v}/{topic}", data, block=True)
            sent[0] += 1

    def served() -> dict[str, list[str]]:
        out: dict[str, list[str]] = {}
        for w in (a, b):
            for v in w.serving:
                out.setdefault(v, []).append(w.id)
        return out

    try:
        watch = FleetWatch(client, "fp")
        a.start()
        b.start()
        want = assign(VEHICLES, ["w-a", "w-b"])
        wait_for(lambda: served() == {v: [want[v]] for v in VEHICLES}, 30, 0.1, "the shares")
        of_b = sorted(v for v in VEHICLES if want[v] == "w-b")
        assert of_b, want  # (fixed worker ids: w-b owns some of the four)
        th = threading.Thread(target=publish, daemon=True)
        th.start()
        time.sleep(2.0)  # inputs flowing, replicas written

        proxy.cut()  # b loses its only link
        wait_for(lambda: b.fenced and not b.serving, 10, 0.05, "b to stop serving")
        wait_for(lambda: served() == {v: ["w-a"] for v in VEHICLES}, 20, 0.1, "a to take all")
        taken = {t["vehicle"]: t for t in a.takeovers if t["vehicle"] in of_b}
        assert set(taken) == set(of_b)
        assert all(t["source"] == "replica" and t["loss_flagged"] for t in taken.values())
        time.sleep(1.0)

        proxy.restore()  # the link is back: b's vehicles return to it by handover
        sent_at_restore = sent[0]
        wait_for(lambda: served() == {v: [want[v]] for v in VEHICLES}, 30, 0.1, "the shares again")
        back = [t for t in b.takeovers if t["vehicle"] in of_b and t["replica_worker"] == "w-a"]
        assert {t["vehicle"] for t in back} == set(of_b)
        assert all(t["source"] == "handover" for t in back)
        time.sleep(1.5)
        assert th.is_alive() and sent[0] > sent_at_restore  # inputs flowed through it all
        stop.set()
        th.join(10)
        assert watch.most == 1, watch.owners  # never two owners of a vehicle at once
        runs = watch.runs()
        for v in VEHICLES:
            assert runs[v] == (["w-b", "w-a", "w-b"] if v in of_b else ["w-a"]), (v, runs[v])
    finally:
        stop.set()
        for w in (b, a):
            w.stop()
        for t in (client, tb, ta, router):
            t.close()
        proxy.close()
