"""`radical monitor foxglove`: a real node over Zenoh (loopback, free ports, multicast off), the
bridge as a subprocess, and an independent client (@foxglove/ws-protocol over `ws`, node,
tests/js/ws_client.mjs) offering the subprotocol foxglove.sdk.v1: channels advertised, live data
received, FrameTransform/Log validated against @foxglove/schemas.

Needs node and `npm ci --prefix tests/js` (make jsdeps); fails (never skips) without them."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_setup import build_processors, warm_up
from radical_rt.io import zconfig
from radical_rt.io.zenoh_transport import ZenohTransport
from tests.support.node import input_messages, make_archive, wait_for

pytestmark = pytest.mark.zenoh
ROOT = Path(__file__).resolve().parents[2]
JS = Path(__file__).parents[1] / "js"


def _read_line(proc: subprocess.Popen, needle: str, timeout: float) -> str:
    out: list[str] = []

    def reader():
        for line in proc.stdout:  # type: ignore[union-attr]
            out.append(line)
            if needle in line:
                return

    t = threading.Thread(target=reader, daemon=True)
    t.start()
    t.join(timeout)
    assert out and needle in out[-1], f"no {needle!r} from the bridge: {''.join(out)}"
    return out[-1]


def test_live_foxglove_bridge(tmp_path):
    node_exe = shutil.which("node")
    assert node_exe, "node is required: apt-get install nodejs (node >= 18)"
    assert (JS / "node_modules" / "@foxglove" / "ws-protocol").exists(), (
        "JS client missing: run `npm ci --prefix tests/js` (make jsdeps)")
    archive = make_archive(tmp_path, "live", seed=5, duration=60)
    msgs = input_messages(archive)
    ep, port = f"tcp/127.0.0.1:{zconfig.free_port()}", zconfig.free_port()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    warm_up()  # as `radical node` does: a cold kernel cache must not eat the test's waits
    node = FilterNode(ZenohTransport("peer", listen=[ep]), build_processors(["fx"]),
                      block_outputs=True)
    node.start()
    bridge = subprocess.Popen(
        [sys.executable, "-m", "radical_rt.apps.cli", "monitor", "foxglove", "--vehicle", "fx",
         "--port", str(port), "--connect", ep, "--duration", "90"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    client = js = None
    stopped = False
    try:
        line = _read_line(bridge, "ws://", 30)
        assert f"ws://127.0.0.1:{port}" in line
        client = ZenohTransport("peer", connect=[ep])
        wait_for(lambda: client.alive("radical/*/alive/filter", 1.0), 20, 0.05, "the node")

        def publish(part):  # 10x real time
            t0, ns0 = time.monotonic(), part[0][1]
            for topic, ns, data in part:
                delay = t0 + (ns - ns0) / 1e10 - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                client.put(f"radical/fx/{topic}", data, block=True)

        # the first 15 s of data: the node's channels exist before the Foxglove client connects,
        # as when a user opens the app on a running bridge
        k = next(i for i, m in enumerate(msgs) if m[1] - msgs[0][1] > 15e9)
        publish(msgs[:k])
        time.sleep(1.0)
        js = subprocess.Popen([node_exe, str(JS / "ws_client.mjs"), f"ws://127.0.0.1:{port}",
                               "60", "5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True)
        got: list[str] = []
        t = threading.Thread(target=lambda: got.append(js.stderr.readline()), daemon=True)
        t.start()
        t.join(30)
        assert got and got[0].strip() == "subscribed", f"the ws client did not subscribe: {got}"
        publish(msgs[k:])  # live data to the connected client
        time.sleep(1.0)
        node.stop()  # its liveliness token goes: the client gets "filter node fx gone"
        stopped = True
        stdout, stderr = js.communicate(timeout=70)
        assert js.returncode == 0, stderr[-2000:]
        rd = json.loads(stdout)
    finally:
        if js is not None and js.poll() is None:
            js.kill()
            js.wait()
        if client is not None:
            client.close()
        if not stopped:
            node.stop()
        bridge.terminate()
        try:
            rest, err = bridge.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            bridge.kill()
            rest, err = bridge.communicate()
    diag = (rd.get("counts"), rd.get("resubscribed", 0), rest, err[-2000:])
    assert bridge.returncode == 0, diag
    assert "0 dropped, 0 undecodable" in rest, diag
    assert rd["protocol"] == "foxglove.sdk.v1"
    assert rd["errors"] == [] and rd["officialErrors"] == []
    ch = rd["channels"]
    for topic in ("/tlm/small", "/tlm/medium", "/tlm/large", "/diag", "/paper/calibration"):
        assert topic in ch, (topic, "never advertised", diag)
        assert ch[topic]["encoding"] == "json" and ch[topic]["schemaEncoding"] == "jsonschema"
        assert ch[topic]["schemaType"] == "object"
        assert rd["counts"].get(topic, 0) >= 5, (topic, diag)
    for topic in ("/tf/body", "/tf/st1", "/tf/st2"):
        assert ch[topic]["schemaName"] == "foxglove.FrameTransform"
        assert rd["counts"].get(topic, 0) >= 5, (topic, diag)
    assert ch["/log/faults"]["schemaName"] == "foxglove.Log"
    assert any("filter node fx gone" in t for t in rd["logTexts"]), rd["logTexts"]
    # live data: the body transform is the inverse of the packet's attitude, at its bus time
    small, tf = rd["last"]["/tlm/small"]["msg"], rd["last"]["/tf/body"]["msg"]
    assert small["t"] > 1000.0  # bus time of the archive (starts at 1000 s)
    r = tf["rotation"]
    q = Rotation.from_quat([r["x"], r["y"], r["z"], r["w"]])
    stamp_s = tf["timestamp"]["sec"] + tf["timestamp"]["nsec"] * 1e-9
    assert abs(stamp_s - small["t"]) < 1.0
    angle = (q * Rotation.from_quat(small["q_body_from_inertial"])).magnitude()
    assert angle < np.radians(1.0)  # the same attitude, up to the packets in between
    assert rd["serverInfo"]["name"] == "radical-rt fx"


def test_foxglove_cli_errors(capsys):
    from radical_rt.apps.cli import main

    assert main(["monitor", "foxglove"]) == 2
    assert "--vehicle" in capsys.readouterr().err
    assert main(["monitor", "foxglove", "--vehicle", "Bad!"]) == 2
    assert main(["monitor", "foxglove", "--vehicle", "v", "--connect", "tcp/10.0.0.1:7448"]) == 2
    assert "loopback" in capsys.readouterr().err
