"""The shared roster over a real router on loopback: ``radical fleet add/remove`` against one
worker process (exit 0, confirmed by the live worker, the vehicle served then let go), exit 1
for a fleet without workers, and discovery of a vehicle from its input key (issue #19)."""

from __future__ import annotations

import subprocess
import sys

import msgpack
import pytest

from radical_rt.io import zconfig
from radical_rt.io.zenoh_transport import ZenohTransport
from tests.support.fleet import spawn_cli, wait_line
from tests.support.node import wait_for

pytestmark = pytest.mark.zenoh


def _cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "radical_rt.apps.cli", *argv],
                          capture_output=True, text=True, timeout=60)


def _status(client: ZenohTransport) -> list[dict]:
    """The workers' status answers (what `radical fleet status --json` prints)."""
    return [msgpack.unpackb(r, raw=False) for r in client.get("radical-fleet/f1/status/*", b"",
                                                               timeout=3.0, every=True)]


def test_fleet_add_remove_and_discovery_over_a_router():
    ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
    router = spawn_cli("router", "--listen", ep)
    procs = [router]
    client = None
    try:
        wait_line(router, "ready", 60)
        worker = spawn_cli("node", "--fleet", "f1", "--connect", ep, "--workers", "1",
                        "--vehicle", "v1", "--discover", "temp", "--log-level", "info")
        procs.append(worker)
        wait_line(worker, "ready", 180)
        client = ZenohTransport("client", connect=[ep])

        out = _cli("fleet", "add", "v9", "--fleet", "f1", "--connect", ep)
        assert out.returncode == 0, out.stderr
        assert "v9 added to the roster" in out.stdout and "confirmed by 1 of 1" in out.stdout
        wait_for(lambda: _status(client)[0]["serving"] == ["v1", "v9"], 20, 0.5, "v9 served")

        wait_for(lambda: (client.put("radical/dv/temp", msgpack.packb({"v": 1, "t_bus": 1.0}))
                          or "dv" in _status(client)[0]["roster"]["vehicles"]), 20, 0.5,
                 "dv discovered from its temp key")
        [w] = _status(client)
        assert w["roster"]["entries"]["dv"]["state"] == "discovered"
        assert w["roster"]["entries"]["v9"]["state"] == "added"
        assert w["discovery"]["active"] and w["discovery"]["samples"] >= 1

        out = _cli("fleet", "remove", "v9", "v1", "--fleet", "f1", "--connect", ep)
        assert out.returncode == 0, out.stderr
        wait_for(lambda: _status(client)[0]["serving"] == ["dv"], 20, 0.5, "v1 and v9 let go")
        out = _cli("fleet", "status", "--fleet", "f1", "--connect", ep)
        assert out.returncode == 0, out.stderr
        lines = {ln.split()[0]: ln.split()[1] for ln in out.stdout.splitlines()
                 if ln.startswith("    ")}  # the roster lines: name, state
        assert lines == {"dv": "discovered", "v1": "removed", "v9": "removed"}, out.stdout

        out = _cli("fleet", "add", "v2", "--fleet", "nobody", "--connect", ep, "--timeout", "1")
        assert out.returncode == 1 and "no worker of fleet nobody answered" in out.stderr
    finally:
        if client is not None:
            client.close()
        for p in procs:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(30)
            except subprocess.TimeoutExpired:
                p.kill()


def test_roster_edits_under_a_security_profile(tmp_path, capsys):
    """Through the profile's router: an operator's `fleet add` is confirmed, a monitor may read
    the roster (`fleet status`) but its edit is dropped by the ACL (exit 1, nothing changed)."""
    import zenoh

    from radical_rt.apps.cli import main as radical_main
    from radical_rt.apps.fleet_cli import serve_status
    from radical_rt.apps.fleet_worker import FleetWorker
    from radical_rt.apps.keys_cli import init_profile, parse_users
    from radical_rt.apps.node_setup import build_processors

    prof = init_profile(tmp_path / "auth", tls=False, port=zconfig.free_port(),
                        users=parse_users(["operator:alice"]))
    router = zenoh.open(zenoh.Config.from_file(str(prof.directory / "router.json5")))
    t = worker = None
    try:
        t = ZenohTransport("client", connect=[prof.endpoint], extra=prof.client_settings("node"))
        worker = FleetWorker(t, "f1", ["v1"], lambda v: build_processors([v])[v],
                             worker_id="w-sec")
        serve_status(t, worker)  # (as radical node --fleet does)
        worker.start()
        auth = ["--fleet", "f1", "--connect", prof.endpoint, "--auth", str(prof.directory)]
        assert radical_main(["fleet", "add", "v9", *auth, "--user", "alice"]) == 0
        assert "confirmed by 1 of 1" in capsys.readouterr().out
        assert worker.vehicles == ["v1", "v9"]
        assert radical_main(["fleet", "remove", "v1", *auth, "--role", "monitor",
                             "--timeout", "1"]) == 1
        assert "not confirmed within 1 s by: w-sec" in capsys.readouterr().err
        assert worker.vehicles == ["v1", "v9"]
        assert radical_main(["fleet", "status", *auth]) == 0  # a monitor reads the roster
        out = capsys.readouterr().out
        assert "roster: 2 vehicle(s)" in out and "v9               added" in out
    finally:
        if worker is not None:
            worker.stop()
        if t is not None:
            t.close()
        router.close()
