"""Security profiles on real Zenoh sessions (loopback, free ports, multicast off): who gets in,
who may read, publish and command, TLS certificates, a router deployment and the audit trail
(issue #24; docs/security.md)."""

from __future__ import annotations

import argparse
import json
import logging
import time

import msgpack
import pytest

from radical_rt.apps.cli import main as radical_main
from radical_rt.apps.keys_cli import init_profile, parse_users
from radical_rt.apps.node import FilterNode
from radical_rt.apps.node_cli import _open_session
from radical_rt.apps.node_setup import build_processors
from radical_rt.io import zconfig
from radical_rt.io.transport import TransportError
from radical_rt.io.zauth import cmd_key
from radical_rt.io.zenoh_transport import ZenohTransport
from tests.support.node import input_messages, wait_for

pytestmark = pytest.mark.zenoh
V = "v1"


def _node_args(profile_dir, **kw) -> argparse.Namespace:
    base = {"auth": str(profile_dir) if profile_dir else None, "role": None, "user": None,
            "listen": None, "connect": None, "mode": "peer", "zenoh_config": None}
    return argparse.Namespace(**{**base, **kw})


class Secured:
    """A node serving V with a security profile (listening: the enforcement point), or as a
    client of a router (``connect``)."""

    def __init__(self, profile, **node_args) -> None:
        self.profile = profile
        self.transport, self.sa, _, _ = _open_session(_node_args(profile.directory, **node_args))
        self.node = FilterNode(self.transport, build_processors([V]), block_outputs=True,
                               auth=self.sa.profile)
        self.node.start()
        self.sessions: list[ZenohTransport] = []

    def client(self, user: str) -> ZenohTransport:
        t = ZenohTransport("client", connect=[self.profile.endpoint],
                           extra=self.profile.client_settings(user))
        self.sessions.append(t)
        return t

    def received(self) -> dict:
        with self.node.vehicles[V].lock:
            return dict(self.node.vehicles[V].received)

    def close(self) -> None:
        for s in self.sessions:
            s.close()
        self.node.stop(final_checkpoint=False)
        self.transport.close()


def _cmd(capsys, *argv) -> tuple[int, dict | None, str]:
    rc = radical_main(["cmd", "--vehicle", V, *argv, "--json", "--timeout", "3"])
    out, err = capsys.readouterr()
    return rc, (json.loads(out) if out.strip() else None), err


@pytest.fixture()
def tcp_profile(tmp_path):
    return init_profile(tmp_path / "auth", tls=False, port=zconfig.free_port(),
                        users=parse_users(["operator:alice"]))


def test_roles_on_an_authenticated_node(tcp_profile, archives, capsys):
    sn = Secured(tcp_profile)
    try:
        msgs = input_messages(archives["a60"])[:40]
        audit: list[dict] = []
        op = sn.client("alice")
        op.subscribe(f"radical/{V}/cmd_log", lambda k, d: audit.append(msgpack.unpackb(d)))
        mon_inputs: list[str] = []
        mon = sn.client("monitor")
        mon.subscribe(f"radical/{V}/siru", lambda k, d: mon_inputs.append(k))
        time.sleep(0.3)

        # no credentials: the session cannot open; a peer without them opens but is isolated
        with pytest.raises(TransportError, match="cannot open"):
            ZenohTransport("client", connect=[tcp_profile.endpoint])
        anon = ZenohTransport("peer", connect=[tcp_profile.endpoint])
        sn.sessions.append(anon)
        assert anon.get(f"radical/{V}/cmd", msgpack.packb({"cmd": "status"}), timeout=1.0) == []
        for topic, _, data in msgs[:5]:
            anon.put(f"radical/{V}/{topic}", data, block=True)
            mon.put(f"radical/{V}/{topic}", data, block=True)  # a monitor cannot forge inputs

        # the sensor's inputs are taken
        sensor = sn.client("sensor")
        for topic, _, data in msgs:
            sensor.put(f"radical/{V}/{topic}", data, block=True)
        expect = {}
        for topic, _, _ in msgs:
            expect[topic] = expect.get(topic, 0) + 1
        wait_for(lambda: sn.received() == expect, 20, what="the sensor's inputs")
        time.sleep(0.3)
        assert sn.received() == expect  # nothing from the anonymous peer or the monitor
        assert mon_inputs == [f"radical/{V}/siru"] * sum(1 for t, _, _ in msgs[:5] if t == "siru")
        # (the monitor's own puts only: it never receives the sensor's inputs)

        rc, st, _ = _cmd(capsys, "status", "--auth", str(tcp_profile.directory))
        assert rc == 0 and st["ok"] and st["node"]["received"] == expect
        rc, r, _ = _cmd(capsys, "set_params", "--args", '{"params": {"st_min_stars": 5}}',
                        "--auth", str(tcp_profile.directory), "--role", "monitor")
        assert rc == 1 and not r["ok"] and "changes state" in r["error"]
        rc, r, _ = _cmd(capsys, "set_params", "--args", '{"params": {"st_min_stars": 5}}',
                        "--auth", str(tcp_profile.directory), "--user", "alice")
        assert rc == 0 and r["params"] == {"st_min_stars": 5}
        rc, r, err = _cmd(capsys, "status", "--auth", str(tcp_profile.directory), "--role", "sensor")
        assert rc == 1 and r is None and "access control refused" in err
        # a monitor's session cannot reach the write key, nor impersonate another user
        for key in (cmd_key(V, "write", "monitor"), cmd_key(V, "write", "alice"), f"radical/{V}/cmd"):
            assert mon.get(key, msgpack.packb({"cmd": "cold_start"}), timeout=1.0) == []
        rc, _, err = _cmd(capsys, "status", "--connect", tcp_profile.endpoint)
        assert rc == 1 and "cannot open" in err

        wait_for(lambda: len(audit) >= 3, 5, what="the audit records")
        time.sleep(0.3)
        assert [(e["user"], e["role"], e["cmd"], e["ok"]) for e in audit] == [
            ("monitor", "monitor", "status", True), ("monitor", "monitor", "set_params", False),
            ("alice", "operator", "set_params", True)]
        summary = sn.node.audit.summary(V)
        assert (summary["applied"], summary["refused"]) == (2, 1)
    finally:
        sn.close()


def test_tls_client_certificates(tmp_path, capsys):
    prof = init_profile(tmp_path / "tls", tls=True, port=zconfig.free_port())
    other = init_profile(tmp_path / "other", tls=True, port=zconfig.free_port())
    sn = Secured(prof)
    try:
        rc, r, _ = _cmd(capsys, "get_params", "--auth", str(prof.directory), "--role", "operator")
        assert rc == 0 and r["ok"]
        from radical_rt.apps.keys_cli import make_kit

        kit = make_kit(prof.directory, "monitor", tmp_path / "kit")  # what a monitor is handed
        rc, r, _ = _cmd(capsys, "status", "--auth", str(kit))
        assert rc == 0 and r["ok"]
        wrong = prof.client_settings("operator")  # right password, certificate of another CA
        wrong.update({"transport/link/tls/connect_certificate": str(other.directory / "operator.pem"),
                      "transport/link/tls/connect_private_key": str(other.directory / "operator.key")})
        with pytest.raises(TransportError, match="cannot open"):
            ZenohTransport("client", connect=[prof.endpoint], extra=wrong)
        no_cert = {"transport/link/tls/root_ca_certificate": str(prof.directory / "ca.pem"),
                   "transport/auth/usrpwd/user": "operator",
                   "transport/auth/usrpwd/password": prof.passwords["operator"]}
        with pytest.raises(TransportError, match="cannot open"):
            ZenohTransport("client", connect=[prof.endpoint], extra=no_cert)
        wrong_ca = {**prof.client_settings("operator"),
                    "transport/link/tls/root_ca_certificate": str(other.directory / "ca.pem")}
        with pytest.raises(TransportError, match="cannot open"):
            ZenohTransport("client", connect=[prof.endpoint], extra=wrong_ca)
        rec = sn.node.audit.summary(V)
        assert rec["applied"] == 2 and [e["user"] for e in rec["last"]] == ["operator", "monitor"]
    finally:
        sn.close()


def test_router_deployment_with_the_profiles_router_config(tcp_profile, archives, capsys):
    import zenoh

    router = zenoh.open(zenoh.Config.from_file(str(tcp_profile.directory / "router.json5")))
    sn = None
    try:
        sn = Secured(tcp_profile, connect=tcp_profile.endpoint)  # the node: a client of the router
        time.sleep(0.3)
        sensor = sn.client("sensor")
        msgs = input_messages(archives["a60"])[:20]
        for topic, _, data in msgs:
            sensor.put(f"radical/{V}/{topic}", data, block=True)
        wait_for(lambda: sum(sn.received().values()) == len(msgs), 20, what="inputs via the router")
        rc, r, _ = _cmd(capsys, "cold_start", "--auth", str(tcp_profile.directory), "--user", "alice")
        assert rc == 0 and r["ok"]
        rc, r, _ = _cmd(capsys, "cold_start", "--auth", str(tcp_profile.directory))
        assert rc == 1 and "changes state" in r["error"]
        with pytest.raises(TransportError, match="cannot open"):
            ZenohTransport("client", connect=[tcp_profile.endpoint])
    finally:
        if sn is not None:
            sn.close()
        router.close()


def test_node_without_a_profile_says_it_is_unauthenticated(caplog):
    ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
    with caplog.at_level(logging.WARNING, logger="radical.node"):
        transport, sa, listen, _ = _open_session(_node_args(None, listen=ep))
    transport.close()
    assert sa is None and listen == [ep]
    assert any("UNAUTHENTICATED" in r.getMessage() and ep in r.getMessage() for r in caplog.records)


def test_the_audit_trail_is_recorded_as_a_cmd_log_channel(tcp_profile, tmp_path, capsys):
    import threading

    import zenoh

    from radical_rt.io import zauth
    from radical_rt.io.archive import ArchiveReader
    from replayer.recorder import record
    from replayer.sessions import tool_config

    sn = Secured(tcp_profile)
    try:
        sa = zauth.session_auth(str(tcp_profile.directory), "operator", "operator")
        cfg, _, _ = tool_config(None, None, "record", auth=sa)
        session = zenoh.open(cfg)
        stop, ready = threading.Event(), threading.Event()
        out = tmp_path / "rec.mcap"
        res: dict = {}
        th = threading.Thread(target=lambda: res.update(record(
            out, V, session, topics=",".join(zauth.readable_topics("operator")),
            stop_event=stop, ready_event=ready)))
        th.start()
        assert ready.wait(10)
        time.sleep(0.3)
        assert _cmd(capsys, "status", "--auth", str(tcp_profile.directory))[0] == 0
        assert _cmd(capsys, "warm_start", "--auth", str(tcp_profile.directory))[0] == 1
        wait_for(lambda: sn.node.audit.summary(V)["refused"] == 1, 5, what="the audit")
        time.sleep(0.5)
        stop.set()
        th.join(20)
        session.close()
        with ArchiveReader(out) as r:
            logs = [m for topic, _, m in r.iter_messages() if topic == "/cmd_log"]
            assert "/cmd_log" in r.schemas
        assert [(m["user"], m["cmd"], m["ok"]) for m in logs] == [
            ("monitor", "status", True), ("monitor", "warm_start", False)]
    finally:
        sn.close()


def test_replay_as_sensor_and_a_monitor_dashboard_under_a_profile(tcp_profile, archives, capsys):
    from monitors.live import LatestStore, ZenohSource
    from radical_rt.io import zauth

    sn = Secured(tcp_profile)
    store = LatestStore()
    source = ZenohSource(store, V, auth=zauth.session_auth(str(tcp_profile.directory), None,
                                                          "monitor")).start()
    try:
        rc = radical_main(["replay", str(archives["a60"]), "--vehicle", V, "--fast", "--auth",
                           str(tcp_profile.directory), "--wait-node", "10", "--linger", "0.5",
                           "--no-progress", "--end", "20"])
        capsys.readouterr()
        assert rc == 0
        n_sent = sum(1 for _, ns, _ in input_messages(archives["a60"])
                     if ns - input_messages(archives["a60"])[0][1] < 20e9)
        assert n_sent > 100
        wait_for(lambda: sum(sn.received().values()) >= n_sent - 5, 20, what="the replayed inputs")
        wait_for(lambda: store.latest(V, "diag").msg is not None, 20, what="diag at the monitor")
        assert store.latest(V, "diag").msg["node"]["security"]["auth"] == "usrpwd"
        seen: list[int] = []

        def settled() -> bool:  # no input arrived for 1 s
            seen.append(sum(sn.received().values()))
            return len(seen) > 10 and seen[-1] == seen[-11]
        wait_for(settled, 30, 0.1, "the replayed inputs to settle")
        before = seen[-1]
        # a replayer that names the monitor role is not let in to publish
        rc = radical_main(["replay", str(archives["a60"]), "--vehicle", V, "--fast", "--auth",
                           str(tcp_profile.directory), "--role", "monitor", "--no-wait-node",
                           "--linger", "0.5", "--no-progress", "--end", "5"])
        out = capsys.readouterr()
        assert "replayed" in out.out + out.err  # it did publish (to no one it may reach)
        time.sleep(0.5)
        assert sum(sn.received().values()) == before
    finally:
        source.close()
        sn.close()
