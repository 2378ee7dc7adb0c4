"""Helpers of the node tests over real Zenoh on loopback (free ports, multicast off): a free
endpoint, publishing input messages (optionally paced), waiting until the node fed them, and a
`radical node` subprocess with a client session."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from radical_rt.io import zconfig
from radical_rt.io.zenoh_transport import ZenohTransport
from tests.support.node import cmd, wait_for

ROOT = Path(__file__).resolve().parents[2]  # the repository


def free_endpoint() -> str:
    """tcp/127.0.0.1:PORT on a free port."""
    return f"tcp/127.0.0.1:{zconfig.free_port()}"


def publish(client: ZenohTransport, vehicle: str, msgs, rate: float | None = None) -> dict[str, int]:
    """Publish input messages in log_time order with BLOCK congestion control (paced if rate)."""
    counts: dict[str, int] = {}
    t0, ns0 = time.monotonic(), msgs[0][1] if msgs else 0
    for topic, ns, data in msgs:
        if rate:
            delay = t0 + (ns - ns0) / 1e9 / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        client.put(f"radical/{vehicle}/{topic}", data, block=True)
        counts[topic] = counts.get(topic, 0) + 1
    return counts


def wait_fed(client, vehicle, counts, timeout=60.0) -> dict:
    """The node's status once it has fed exactly ``counts`` per topic with an empty queue."""
    def done():
        st = cmd(client, vehicle, cmd="status")
        return st if st["node"]["fed"] == counts and st["node"]["queue_depth"] == 0 else None
    return wait_for(done, timeout, 0.05, "the node to feed every message")


class NodeProc:
    """`radical node` in a subprocess; stderr goes to a file (read to see 'ready')."""

    def __init__(self, tmp: Path, name: str, *args: str) -> None:
        self.ep = free_endpoint()
        self.log = tmp / f"{name}.log"
        self.f = open(self.log, "wb")
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.p = subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", "node", "--listen",
                                   self.ep, *args], stdout=self.f, stderr=subprocess.STDOUT,
                                  cwd=ROOT, env=env)
        wait_for(lambda: "ready" in self.text() or self.p.poll() is not None, 120, 0.05,
                 f"node {name} to start")
        assert self.p.poll() is None, self.text()
        self.client = ZenohTransport("peer", connect=[self.ep])

    def text(self) -> str:
        return self.log.read_text(errors="replace")

    def close(self) -> None:
        self.client.close()
        if self.p.poll() is None:
            self.p.kill()
            self.p.wait(10)
        self.f.close()
