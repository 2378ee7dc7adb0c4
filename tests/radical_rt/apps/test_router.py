"""`radical router`: a Zenoh router process (loopback, gossip off), plain, as the enforcement
point of a security profile, and in a chain of two routers."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import msgpack
import pytest

from radical_rt.apps.cli import main as radical_main
from radical_rt.apps.keys_cli import init_profile
from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_setup import build_processors
from radical_rt.apps.router_cli import ROUTER_ENDPOINT, router_endpoints
from radical_rt.io import zconfig
from radical_rt.io.transport import TransportError
from radical_rt.io.zenoh_transport import ZenohTransport

pytestmark = pytest.mark.zenoh


def _ep() -> str:
    return f"tcp/127.0.0.1:{zconfig.free_port()}"


def _router(*argv: str) -> subprocess.Popen:
    """A `radical router` process, returned once it said it is ready."""
    p = subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", "router", *argv],
                         stderr=subprocess.PIPE, text=True, env={**os.environ, "RUST_LOG": ""})
    assert p.stderr is not None
    line = p.stderr.readline()
    assert "ready" in line, line
    return p


def _stop(p: subprocess.Popen) -> int:
    p.terminate()
    return p.wait(20)


def _status(client: ZenohTransport, key: str = "radical/v1/cmd") -> list[dict]:
    replies = client.get(key, msgpack.packb({"cmd": "status"}), timeout=3)
    return [msgpack.unpackb(r, raw=False) for r in replies]


def test_endpoints_and_option_errors(tmp_path, capsys):
    assert router_endpoints([], [], None) == ([ROUTER_ENDPOINT], [])
    prof = init_profile(tmp_path / "p", port=17100)
    assert router_endpoints([], [], prof) == (["tls/127.0.0.1:17100"], [])
    assert router_endpoints([], ["tcp/127.0.0.1:9"], None) == ([], ["tcp/127.0.0.1:9"])
    assert radical_main(["router", "--listen", "tcp/0.0.0.0:7447"]) == 2
    assert "not a loopback locator" in capsys.readouterr().err
    assert radical_main(["router", "--auth", str(tmp_path)]) == 2
    assert "not a security profile" in capsys.readouterr().err


def test_a_chain_of_two_routers_carries_commands():
    ep_a, ep_b = _ep(), _ep()
    ra = _router("--listen", ep_a)
    rb = _router("--listen", ep_b, "--connect", ep_a)
    node_t = client = None
    try:
        node_t = ZenohTransport("client", connect=[ep_a])
        node = FilterNode(node_t, build_processors(["v1"]))
        node.start()
        client = ZenohTransport("client", connect=[ep_b])  # the other end of the chain
        deadline = time.monotonic() + 10
        replies = _status(client)
        while not replies and time.monotonic() < deadline:
            time.sleep(0.2)
            replies = _status(client)
        assert len(replies) == 1 and replies[0]["ok"] and replies[0]["vehicle"] == "v1"
        node.stop(final_checkpoint=False)
    finally:
        for t in (client, node_t):
            if t is not None:
                t.close()
        assert _stop(rb) == 0 and _stop(ra) == 0


def test_router_enforces_a_profile(tmp_path):
    prof = init_profile(tmp_path / "p", port=zconfig.free_port())
    r = _router("--auth", str(prof.directory))
    node_t = op = None
    try:
        node_t = ZenohTransport("client", connect=[prof.endpoint],
                                extra=prof.client_settings("node"))
        node = FilterNode(node_t, build_processors(["v1"]), auth=prof)
        node.start()
        op = ZenohTransport("client", connect=[prof.endpoint],
                            extra=prof.client_settings("operator"))
        replies = _status(op, "radical/v1/cmd/write/operator")
        assert len(replies) == 1 and replies[0]["ok"]
        assert _status(op, "radical/v1/cmd/write/monitor") == []  # another user's key
        with pytest.raises(TransportError, match="cannot open"):
            ZenohTransport("client", connect=[prof.endpoint])
        node.stop(final_checkpoint=False)
    finally:
        for t in (op, node_t):
            if t is not None:
                t.close()
        assert _stop(r) == 0
