"""A fleet over a real router on loopback: two worker processes share three vehicles, one is
killed with SIGKILL mid-stream, the survivor takes its vehicles over from the replica (the loss
counted and flagged), every vehicle keeps being served, the final estimates lie within 3σ of the
truth, and no vehicle ever has two owners (issue #19)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import msgpack
import numpy as np
import pytest

from radical_rt.fleet.ownership import assign
from radical_rt.io import zconfig
from radical_rt.io.archive import ArchiveReader
from radical_rt.io.zenoh_transport import ZenohTransport
from tests.support.fleet import FleetWatch, spawn_cli, wait_line
from tests.support.node import input_messages, wait_for

pytestmark = pytest.mark.zenoh
VEHICLES = ["va", "vb", "vc"]
RATE = 6.0  # archive seconds per wall second


def _owner_of(client: ZenohTransport, v: str) -> str | None:
    replies = client.get(f"radical/{v}/cmd", msgpack.packb({"cmd": "status"}), timeout=2.0)
    if len(replies) != 1:
        return None
    st = msgpack.unpackb(replies[0], raw=False, strict_map_key=False)
    return (st["node"].get("fleet") or {}).get("worker")


def _fleet_status(ep: str) -> list[dict]:
    out = subprocess.run([sys.executable, "-m", "radical_rt.apps.cli", "fleet", "status",
                          "--fleet", "f1", "--connect", ep, "--json"], capture_output=True,
                         text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_fleet_option_errors(capsys):
    from radical_rt.apps.cli import main as radical_main

    assert radical_main(["node", "--fleet", "f1", "--vehicle", "v1"]) == 2
    assert "--connect" in capsys.readouterr().err
    assert radical_main(["node", "--vehicle", "v1", "--roster", "x.txt"]) == 2
    assert "--roster needs --fleet" in capsys.readouterr().err
    assert radical_main(["node", "--vehicle", "v1", "--discover"]) == 2
    assert "--discover needs --fleet" in capsys.readouterr().err
    assert radical_main(["node", "--fleet", "f1", "--connect", "tcp/127.0.0.1:9",
                         "--vehicle", "Bad!"]) == 2
    assert "must match [a-z0-9_-]+" in capsys.readouterr().err
    assert radical_main(["fleet", "add", "Bad!", "--fleet", "f1"]) == 2
    assert "must match [a-z0-9_-]+" in capsys.readouterr().err


def test_kill_one_worker_mid_stream(archives):
    ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
    router = spawn_cli("router", "--listen", ep)
    wait_line(router, "ready", 60)
    worker_args = ["node", "--fleet", "f1", "--connect", ep, "--workers", "1",
                   "--checkpoint-every", "2", "--log-level", "info",
                   *[a for v in VEHICLES for a in ("--vehicle", v)]]
    workers = [spawn_cli(*worker_args) for _ in range(2)]
    client = ZenohTransport("client", connect=[ep])
    try:
        for w in workers:
            wait_line(w, "ready", 180)
        watch = FleetWatch(client, "f1")
        def settled() -> bool:  # both workers up, each serving what rendezvous hashing gives it
            ws = [msgpack.unpackb(r, raw=False) for r in client.get(
                "radical-fleet/f1/status/*", b"", timeout=3.0, every=True)]
            want = assign(VEHICLES, [w["worker"] for w in ws])
            return len(ws) == 2 and all(w["serving"] == sorted(v for v in VEHICLES
                                                               if want[v] == w["worker"])
                                        for w in ws)
        wait_for(settled, 60, 0.5, "both workers to share the roster")
        owners = {v: _owner_of(client, v) for v in VEHICLES}
        assert all(owners.values()), owners

        msgs = input_messages(archives["a60"])
        t0, ns0 = time.monotonic(), msgs[0][1]
        victim_id = max(set(owners.values()), key=lambda w: sum(o == w for o in owners.values()))
        victim_pid = int(victim_id.split("-")[-2])
        killed_at = None
        for topic, ns, data in msgs:
            delay = t0 + (ns - ns0) / 1e9 / RATE - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if killed_at is None and (ns - ns0) / 1e9 > 24.0:
                os.kill(victim_pid, signal.SIGKILL)
                killed_at, killed_unix = time.monotonic(), time.time()
            for v in VEHICLES:
                client.put(f"radical/{v}/{topic}", data, block=True)
        assert killed_at is not None
        survivor = next(w["worker"] for w in _fleet_status(ep))  # the only one left
        wait_for(lambda: all(_owner_of(client, v) == survivor for v in VEHICLES), 15, 0.2,
                 "the survivor to serve every vehicle")

        moved = [v for v in VEHICLES if owners[v] == victim_id]
        [after] = _fleet_status(ep)
        assert after["worker"] == survivor and after["serving"] == VEHICLES
        assert {t["vehicle"] for t in after["takeovers"] if t["taken_unix"] > killed_unix} \
            == set(moved)
        with ArchiveReader(archives["a60"]) as r:
            truth = [m for _t, _ns, m in r.iter_messages("/truth/params")][-1]
        for v in VEHICLES:
            [raw] = client.get(f"radical/{v}/cmd", msgpack.packb({"cmd": "status"}), timeout=5)
            st = msgpack.unpackb(raw, raw=False, strict_map_key=False)
            fleet = st["node"]["fleet"]
            if v in moved:  # taken over: from the victim's replica, the loss counted and flagged
                assert fleet["source"] == "replica" and fleet["replica_worker"] == victim_id
                assert fleet["loss_flagged"] and 0 <= fleet["lost_s"] < 10
                assert st["counters"]["input_gaps"] >= 1
            for g in ("b", "lam", "mu", "du", "dv", "phi2"):
                err = np.abs(np.array(st["est"][g]) - np.array(truth[g]))
                assert np.all(err <= 3 * np.array(st["sigma"][g]) + 1e-12), (v, g)
        assert watch.most == 1, watch.owners  # never two owners of a vehicle at once
        runs = watch.runs()
        for v in VEHICLES:  # diag from one worker, then (after the kill) only from the survivor
            assert runs[v] == ([victim_id, survivor] if v in moved else [survivor]), runs[v]
    finally:
        client.close()
        for p in [*workers, router]:
            if p.poll() is None:
                p.terminate()
        for p in [*workers, router]:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()
