"""Shared helpers and fixtures of the node tests: the session archives and batch references
(fixtures, registered for every test by tests/conftest.py), an in-memory node, command and
wait helpers."""

from __future__ import annotations

import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import process
from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_setup import build_processors
from radical_rt.io.checkpoint import capture
from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport
from tests.support.streams import INPUTS, input_messages, make_archive  # noqa: F401 (re-exported)


@pytest.fixture(scope="session")
def archives(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("node_archives")
    return {"a60": make_archive(d, "a60", seed=1, duration=60),
            "b60": make_archive(d, "b60", seed=2, duration=60, base="2005300"),
            "a120": make_archive(d, "a120", seed=1, duration=120)}


@pytest.fixture(scope="session")
def batch_ref(archives) -> dict[str, dict]:
    """batch.process summaries of the archives (the reference for bit-identity)."""
    return {k: process([str(p)], None) for k, p in archives.items()}


def cmd(transport, vehicle: str, timeout: float = 10.0, **request) -> dict:
    """Send one command and return the decoded reply (exactly one reply expected)."""
    replies = transport.get(f"radical/{vehicle}/cmd", msgpack.packb(request), timeout=timeout)
    assert len(replies) == 1, f"expected one reply to {request}, got {len(replies)}"
    return msgpack.unpackb(replies[0], raw=False, strict_map_key=False)


class MemNode:
    """A FilterNode on an in-memory bus plus a client transport on the same bus."""

    def __init__(self, vehicles=("v1",), threaded: bool = False, **node_kw) -> None:
        self.bus = InMemoryBus(threaded=threaded)
        build_kw = {k: node_kw.pop(k) for k in ("config", "packets", "resume", "resume_bump",
                                                          "force_vehicle", "resume_new_stream")
                    if k in node_kw}
        self.node = FilterNode(InMemoryTransport(self.bus), build_processors(list(vehicles), **build_kw),
                               **node_kw)
        self.client = InMemoryTransport(self.bus)
        self.outputs: list[tuple[str, dict]] = []
        self.client.subscribe("radical/**", self._on_out)
        self.node.start()

    def _on_out(self, key: str, data: bytes) -> None:
        if key.split("/", 2)[2] not in ("tlm/small", "tlm/medium", "tlm/large", "fault", "diag"):
            return  # inputs (and junk) published by the tests themselves
        self.outputs.append((key, msgpack.unpackb(data, raw=False, strict_map_key=False)))

    def publish(self, vehicle: str, topic: str, data: bytes) -> None:
        self.client.put(f"radical/{vehicle}/{topic}", data, block=True)

    def idle(self) -> None:
        assert self.bus.sync() if self.bus.threaded else True
        assert self.node.wait_idle(30)

    def cmd(self, vehicle: str = "v1", **request) -> dict:
        return cmd(self.client, vehicle, **request)

    def sp(self, vehicle: str = "v1"):
        return self.node.vehicles[vehicle].sp

    def state(self, vehicle: str = "v1") -> bytes:
        """Everything a command could change, as bytes (compare before/after)."""
        self.idle()
        return msgpack.packb(capture(self.sp(vehicle)))

    def close(self) -> None:
        self.node.stop()


def feed_archive(mn: MemNode, vehicle: str, msgs, until_ns: int | None = None) -> int:
    n = 0
    for topic, ns, data in msgs:
        if until_ns is not None and ns >= until_ns:
            break
        mn.publish(vehicle, topic, data)
        n += 1
    mn.idle()
    return n


def wait_for(pred, timeout: float = 30.0, step: float = 0.02, what: str = "condition"):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = pred()
        if v:
            return v
        time.sleep(step)
    raise AssertionError(f"timed out waiting for {what}")


SI_KEYS = ("estimate", "sigma")


def final_summary(mn: MemNode, vehicle: str = "v1") -> dict:
    """End the vehicle's stream (no next stream) and return the summary of its reply."""
    r = mn.cmd(vehicle, cmd="end_stream", next="none")
    assert r["ok"], r
    return r["summary"]


def same_estimates(a: dict, b: dict) -> bool:
    """Bit-identical estimates and sigmas (msgpack float64 round-trips exactly)."""
    return all(np.array_equal(np.array(a[k][g]), np.array(b[k][g]))
               for k in SI_KEYS for g in a[k]) and a["t_end"] == b["t_end"]
