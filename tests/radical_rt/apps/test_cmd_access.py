"""Who may send which command, and the audit of every command (radical_rt.apps.cmd_access), on
an in-memory node: the gate the node applies on top of Zenoh's access control, the cmd_log
channel and the commands map of diag/status."""

from __future__ import annotations

import msgpack
import pytest

from radical_rt.apps import cmd_access
from radical_rt.apps.keys_cli import init_profile, parse_users
from radical_rt.io.zauth import Profile
from tests.support.node import MemNode


def _ask(mn: MemNode, key: str, **request) -> dict:
    replies = mn.client.get(key, msgpack.packb(request), timeout=10)
    assert len(replies) == 1
    return msgpack.unpackb(replies[0], raw=False, strict_map_key=False)


@pytest.fixture(scope="module")
def profile(tmp_path_factory) -> Profile:
    return init_profile(tmp_path_factory.mktemp("auth") / "p",
                        users=parse_users(["operator:alice", "monitor:bob"]))


@pytest.fixture()
def secured(profile):
    mn = MemNode(auth=profile)
    logs: list[dict] = []
    mn.client.subscribe("radical/v1/cmd_log",
                        lambda k, d: logs.append(msgpack.unpackb(d, raw=False)))
    yield mn, logs
    mn.close()


def test_command_access_of_keys():
    p = "radical/v1/"
    assert cmd_access.command_access(p, "radical/v1/cmd") == ("contract", None)
    assert cmd_access.command_access(p, "radical/v1/cmd/read/bob") == ("read", "bob")
    assert cmd_access.command_access(p, "radical/v1/cmd/write/alice") == ("write", "alice")
    assert cmd_access.command_access(p, "radical/v1/cmd/admin/alice")[0] == "invalid"
    assert cmd_access.command_access(p, "radical/v2/cmd")[0] == "invalid"


def test_authorize_matrix(profile):
    auth = cmd_access.authorize
    assert auth("contract", None, "cold_start", None) is None  # unauthenticated node: as before
    assert "changes state" in auth("read", "bob", "set_params", None)
    assert auth("read", "bob", "status", profile) is None
    assert auth("read", "alice", "get_params", profile) is None
    assert "changes state" in auth("read", "alice", "cold_start", profile)
    assert auth("write", "alice", "cold_start", profile) is None
    assert "may not send commands on the write key" in auth("write", "bob", "cold_start", profile)
    assert "may not" in auth("read", "sensor", "status", profile)
    assert "may not" in auth("write", "mallory", "status", profile)
    assert "requires authenticated commands" in auth("contract", None, "status", profile)


def test_monitor_reads_operator_writes_and_every_case_is_audited(secured):
    mn, logs = secured
    st = _ask(mn, "radical/v1/cmd/read/bob", cmd="status")
    assert st["ok"] and st["node"]["security"]["auth"] == "usrpwd+mtls"
    before = mn.state()
    r = _ask(mn, "radical/v1/cmd/read/bob", cmd="set_params", params={"st_min_stars": 5})
    assert not r["ok"] and "changes state" in r["error"]
    r = _ask(mn, "radical/v1/cmd/write/bob", cmd="cold_start")
    assert not r["ok"] and "role monitor" in r["error"]
    r = _ask(mn, "radical/v1/cmd", cmd="cold_start", id="x1")
    assert not r["ok"] and "requires authenticated commands" in r["error"] and r["id"] == "x1"
    assert mn.state() == before  # nothing refused changed anything
    r = _ask(mn, "radical/v1/cmd/write/alice", cmd="set_params", params={"st_min_stars": 5})
    assert r["ok"], r
    assert _ask(mn, "radical/v1/cmd/read/alice", cmd="get_params")["params"]["st_min_stars"] == 5
    mn.idle()
    got = [(e["user"], e["role"], e["key"], e["cmd"], e["ok"], e["authenticated"]) for e in logs]
    assert got == [("bob", "monitor", "read", "status", True, True),
                   ("bob", "monitor", "read", "set_params", False, True),
                   ("bob", "monitor", "write", "cold_start", False, True),
                   ("anonymous", None, "contract", "cold_start", False, False),
                   ("alice", "operator", "write", "set_params", True, True),
                   ("alice", "operator", "read", "get_params", True, True)]
    assert logs[1]["args"] == {"params": {"st_min_stars": 5}} and "changes state" in logs[1]["error"]
    assert all(isinstance(e["t_wall"], float) for e in logs)
    summary = _ask(mn, "radical/v1/cmd/read/bob", cmd="status")["node"]["commands"]
    assert (summary["applied"], summary["refused"]) == (3, 3)
    assert [e["cmd"] for e in summary["last"]][-2:] == ["set_params", "get_params"]


def test_unauthenticated_node_serves_the_contract_key_and_audits_claims():
    mn = MemNode()
    logs: list[dict] = []
    mn.client.subscribe("radical/v1/cmd_log", lambda k, d: logs.append(msgpack.unpackb(d, raw=False)))
    try:
        assert _ask(mn, "radical/v1/cmd", cmd="cold_start")["ok"]
        assert _ask(mn, "radical/v1/cmd/write/eve", cmd="status")["ok"]
        assert not _ask(mn, "radical/v1/cmd/read/eve", cmd="cold_start")["ok"]
        r = _ask(mn, "radical/v1/cmd", cmd="nope")
        assert not r["ok"] and "unknown command" in r["error"]
        mn.idle()
        assert [(e["user"], e["authenticated"], e["ok"]) for e in logs] == [
            ("anonymous", False, True), ("eve", False, True), ("eve", False, False),
            ("anonymous", False, False)]
        assert _ask(mn, "radical/v1/cmd", cmd="status")["node"]["security"] == {"auth": "none"}
    finally:
        mn.close()


def test_audit_keeps_large_arguments_short():
    sent = []
    log = cmd_access.AuditLog(None, lambda k, d: sent.append((k, d)))
    rec = log.record("v1", "radical/v1/", "contract", None,
                     {"cmd": "set_packets", "packets": {"x": "y" * 5000}}, {"ok": False, "error": "e"})
    assert rec["args"] == {"truncated": ["packets"]}
    assert sent[0][0] == "radical/v1/cmd_log" and len(sent[0][1]) < 1000
    rec = log.record("v1", "radical/v1/", "contract", None, b"\xff", {"ok": False, "error": "bad"})
    assert rec["cmd"] is None and rec["args"] is None
