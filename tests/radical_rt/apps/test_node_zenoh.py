"""The node over real Zenoh on loopback (free ports, multicast off): bit-identical to batch, commands
over the queryable, kill -9 + --resume, SIGTERM shutdown, CLI errors."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import make_processor, process
from radical_rt.apps.cli import main as radical_main
from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_setup import build_processors
from radical_rt.io import checkpoint as ckpt
from radical_rt.io.archive import ArchiveReader
from radical_rt.io.zenoh_transport import ZenohTransport
from tests.support.node import cmd, input_messages, wait_for
from tests.support.node_zenoh import NodeProc, free_endpoint, publish, wait_fed

pytestmark = pytest.mark.zenoh
ROOT = Path(__file__).resolve().parents[3]


# ------------------------------------------------------------------------------ in-thread node
def test_node_over_zenoh_equals_batch_and_commands(archives, batch_ref, tmp_path):  # noqa: F811
    ep = free_endpoint()
    node_t = ZenohTransport("peer", listen=[ep])
    node = FilterNode(node_t, build_processors(["zz"]), block_outputs=True)
    node.start()
    client = ZenohTransport("peer", connect=[ep])
    medium: list[dict] = []
    client.subscribe("radical/zz/tlm/medium", lambda k, d: medium.append(msgpack.unpackb(d)))
    try:
        wait_for(lambda: client.alive("radical/*/alive/filter", 1.0) == ["radical/zz/alive/filter"],
                 20, 0.05, "the node's liveliness token")
        msgs = input_messages(archives["a120"])
        counts = publish(client, "zz", msgs)
        wait_fed(client, "zz", counts)
        r = cmd(client, "zz", cmd="end_stream", next="none")
        ref = batch_ref["a120"]
        s = r["summary"]
        for k in ("estimate", "sigma"):
            for g in ref[k]:
                assert np.array_equal(np.array(s[k][g]), np.array(ref[k][g])), (k, g)
        assert s["counters"] == ref["counters"] and s["t_end"] == ref["t_end"]
        # the published medium packets equal the batch shell's output archive
        out = tmp_path / "out.mcap"
        process([str(archives["a120"])], str(out))
        with ArchiveReader(out) as rd:
            want = [m for _, _, m in rd.iter_messages("/tlm/medium")]
        wait_for(lambda: len(medium) >= len(want), 10, 0.05, "all tlm/medium packets")
        assert medium == want

        # commands round-trip over the queryable
        st = cmd(client, "zz", cmd="status")
        assert st["ok"] and st["t"] == s["t_end"] and st["node"]["received"] == counts
        p = cmd(client, "zz", cmd="get_params")["params"]
        assert p["gate_st_nis"] == 30.0
        r = cmd(client, "zz", cmd="set_params", params={"gate_st_nis": 25.0})
        assert r["ok"] and node.vehicles["zz"].sp.engine.si.gate_st_nis == 25.0
        r = cmd(client, "zz", cmd="set_params", params={"gate_st_nis": "x"})
        assert r == {"ok": False, "error": "set_params: gate_st_nis: expected a number, got 'x'",
                     "cmd": "set_params"}
        assert cmd(client, "zz", cmd="bump", sigma={"mu": [1e-6] * 4}, mode="scale")["ok"]
        assert cmd(client, "zz", cmd="exclude_gyro", gyro=0)["excluded"] == [0]
        assert cmd(client, "zz", cmd="include_gyro", gyro=0)["excluded"] == []
        assert cmd(client, "zz", cmd="nope")["ok"] is False
        assert client.get("radical/zz/cmd", b"\xc1", timeout=5)  # garbage: an error reply
    finally:
        client.close()
        node.stop()
        node_t.close()


def test_node_behind_a_router(archives):  # noqa: F811
    """--connect: node and client both reach each other through a (Python) Zenoh router."""
    ep = free_endpoint()
    router = ZenohTransport("router", listen=[ep])
    node_t = ZenohTransport("peer", connect=[ep])
    node = FilterNode(node_t, build_processors(["r1", "r2"]))
    node.start()
    client = ZenohTransport("client", connect=[ep])
    try:
        want = ["radical/r1/alive/filter", "radical/r2/alive/filter"]
        wait_for(lambda: client.alive("radical/*/alive/filter", 1.0) == want, 20, 0.05, "tokens")
        msgs = [m for m in input_messages(archives["a60"]) if m[1] < 1005e9]
        counts = publish(client, "r2", msgs)
        st = wait_fed(client, "r2", counts)
        assert st["vehicle"] == "r2" and st["counters"]["siru_samples"] > 0
        assert cmd(client, "r1", cmd="status")["node"]["fed"] == {}
    finally:
        client.close()
        node.stop()
        node_t.close()
        router.close()


def test_kill9_and_resume(archives, batch_ref, tmp_path):  # noqa: F811
    msgs = input_messages(archives["a120"])
    ck = tmp_path / "node.ckpt"
    every, rate = 1.0, 10.0
    n1 = NodeProc(tmp_path, "n1", "--vehicle", "k9", "--checkpoint", str(ck),
                  "--checkpoint-every", str(every))
    try:
        wait_for(lambda: n1.client.alive("radical/k9/alive/filter", 1.0), 20, 0.05, "token")
        publish(n1.client, "k9", [m for m in msgs if m[1] < 1030e9], rate=rate)
        t_kill = cmd(n1.client, "k9", cmd="status")["t"]
        os.kill(n1.p.pid, signal.SIGKILL)
        kill_wall = time.time()
        assert n1.p.wait(10) == -signal.SIGKILL
    finally:
        n1.close()
    doc = ckpt.read(ck)  # complete, readable: written atomically
    saved = doc["vehicles"]["k9"]
    slack = 0.75  # s of wall time: loop latency on a loaded machine
    assert kill_wall - doc["written_unix"] <= every + slack
    assert saved["t"] > 1010.0, "no progress was checkpointed while streaming"
    assert t_kill - saved["t"] <= rate * (every + slack), (t_kill, saved["t"])
    assert not [p for p in tmp_path.iterdir() if ".tmp-" in p.name]
    local = make_processor()
    ckpt.restore(local, saved)

    n2 = NodeProc(tmp_path, "n2", "--vehicle", "k9", "--resume", str(ck), "--checkpoint", str(ck))
    try:
        wait_for(lambda: n2.client.alive("radical/k9/alive/filter", 1.0), 20, 0.05, "token")
        st = cmd(n2.client, "k9", cmd="status")
        assert st["est"] == local.engine.estimates() and st["sigma"] == local.engine.sigmas()
        assert st["mode"] == saved["mode"] and st["t"] == saved["t"]  # the stream continues
        counts = publish(n2.client, "k9", [m for m in msgs if m[1] >= 1040e9])  # 10 s outage
        wait_fed(n2.client, "k9", counts)
        s = cmd(n2.client, "k9", cmd="end_stream", next="none")["summary"]
        ref = batch_ref["a120"]
        assert s["mode"] in ("converging", "converged") and s["t_end"] == pytest.approx(ref["t_end"], abs=1e-3)
        for g in ref["estimate"]:  # consistent with the uninterrupted run
            d = np.abs(np.array(s["estimate"][g]) - np.array(ref["estimate"][g]))
            assert np.all(d <= 3 * np.array(s["sigma"][g])), g
        n2.p.send_signal(signal.SIGTERM)
        assert n2.p.wait(20) == 0, n2.text()
        assert "final checkpoint written" in n2.text()
        assert ckpt.read(ck)["vehicles"]["k9"]["t"] == s["t_end"]
    finally:
        n2.close()


# ------------------------------------------------------------------------------ CLI errors
@pytest.mark.parametrize("args, match", [
    (["--vehicle", "v", "--listen", "tcp/0.0.0.0:7448"], "not a loopback locator"),
    (["--vehicle", "v", "--connect", "tcp/10.1.2.3:7448"], "not a loopback locator"),
    (["--vehicle", "Bad!"], "must match [a-z0-9_-]+"),
    (["--vehicle", "v", "--resume", "/nonexistent/ck"], "no such file"),
    (["--vehicle", "v", "--config", "/nonexistent/p.toml"], "no such file"),
    (["--vehicle", "v", "--checkpoint-every", "0"], "--checkpoint-every must be > 0"),
    (["--vehicle", "v", "--resume-bump"], "--resume-bump needs --resume"),
])
def test_cli_errors_are_one_line(args, match, capsys):
    assert radical_main(["node", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("radical node: ") and match in err[0], err


def test_cli_checkpoint_path_refused_while_parsing(tmp_path, capsys):
    """The one output-path policy (radical_rt.io.outpaths): a checkpoint path that cannot be created
    is a usage error before the node starts (missing parents would be created)."""
    (tmp_path / "f").write_text("")
    with pytest.raises(SystemExit) as exc:
        radical_main(["node", "--vehicle", "v", "--checkpoint", str(tmp_path / "f" / "c.ckpt")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "--checkpoint" in err[-1] and "in the way" in err[-1], err


def test_cli_duration_and_packets(tmp_path, capsys):
    pk = tmp_path / "packets.toml"
    pk.write_text('[packets.small]\nperiod_s = 0.5\nfields = ["seq", "t", "flags"]\n')
    ck = tmp_path / "c.ckpt"
    rc = radical_main(["node", "--vehicle", "a", "--vehicle", "b", "--listen", free_endpoint(),
                       "--packets", str(pk), "--checkpoint", str(ck), "--duration", "0.5"])
    assert rc == 0
    doc = ckpt.read(ck)
    assert set(doc["vehicles"]) == {"a", "b"}
    assert doc["vehicles"]["a"]["packets"]["small"]["fields"] == ["seq", "t", "flags"]
    assert "Numba kernels ready" in capsys.readouterr().err
