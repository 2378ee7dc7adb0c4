"""Security profiles (radical keys init, radical_rt.io.zauth, radical_rt.io.certs): files,
permissions, certificates, the access-control list and the --auth/--role/--user rules. The
profiles' effect on real Zenoh sessions is tested in tests/system/test_security.py."""

from __future__ import annotations

import json
import stat

import pytest

from radical_rt.apps.cli import main as radical_main
from radical_rt.apps.keys_cli import init_profile, parse_users
from radical_rt.io import certs, zauth, zconfig


def _mode(path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_init_writes_a_complete_profile_with_private_secrets(tmp_path):
    d = tmp_path / "prof"
    prof = init_profile(d, tls=True, port=17001, users=parse_users(["operator:alice"]))
    assert prof.endpoint == "tls/127.0.0.1:17001" and prof.tls
    assert prof.users == {"sensor": "sensor", "node": "node", "monitor": "monitor",
                          "operator": "operator", "alice": "operator"}
    assert _mode(d) == 0o700
    for name in ("users.txt", "ca.key", "server.key", "alice.key", "sensor.json5", "node.json5",
                 "monitor.json5", "operator.json5", "user-alice.json5"):
        assert _mode(d / name) == 0o600, name
    pw = prof.passwords
    assert len(set(pw.values())) == len(pw) and all(len(p) >= 24 for p in pw.values())
    assert certs.common_name(d / "alice.pem") == "alice"


def test_json5_files_are_zenoh_configs_of_the_role(tmp_path):
    import zenoh

    prof = init_profile(tmp_path / "p", port=17002)  # the default: TLS
    assert prof.endpoint == "tls/127.0.0.1:17002"
    for role in zauth.ROLES:
        zenoh.Config.from_file(str(tmp_path / "p" / f"{role}.json5"))  # zenoh parses it
        doc = json.loads((tmp_path / "p" / f"{role}.json5").read_text().split("\n", 1)[1])
        assert doc["mode"] == "client" and doc["connect"]["endpoints"] == [prof.endpoint]
        assert doc["scouting"]["multicast"]["enabled"] is False
        assert doc["transport"]["auth"]["usrpwd"]["user"] == role
        assert doc["transport"]["auth"]["usrpwd"]["password"] == prof.passwords[role]
    zenoh.Config.from_file(str(tmp_path / "p" / "router.json5"))
    router = json.loads((tmp_path / "p" / "router.json5").read_text().split("\n", 1)[1])
    assert router["listen"]["endpoints"] == [prof.endpoint]
    assert router["access_control"]["default_permission"] == "deny"
    assert router["transport"]["auth"]["usrpwd"]["dictionary_file"] == str(prof.directory / "users.txt")


def test_server_certificate_names_loopback_and_clients_are_signed_by_the_ca(tmp_path):
    from cryptography import x509

    init_profile(tmp_path / "p", tls=True, port=17003)
    ca = x509.load_pem_x509_certificate((tmp_path / "p" / "ca.pem").read_bytes())
    server = x509.load_pem_x509_certificate((tmp_path / "p" / "server.pem").read_bytes())
    san = server.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "127.0.0.1" in [str(ip) for ip in san.get_values_for_type(x509.IPAddress)]
    for user in ("sensor", "operator"):
        cert = x509.load_pem_x509_certificate((tmp_path / "p" / f"{user}.pem").read_bytes())
        cert.verify_directly_issued_by(ca)  # raises if not signed by the profile's CA
        assert certs.common_name(tmp_path / "p" / f"{user}.pem") == user


def test_acl_grants_each_user_only_its_own_command_keys():
    acl = zauth.access_control({"monitor": "monitor", "alice": "operator", "sensor": "sensor",
                                "node": "node"})
    rules = {r["id"]: r for r in acl["rules"]}
    by_user = {s["usernames"][0]: s["id"] for s in acl["subjects"]}
    policy = {p["subjects"][0]: p["rules"] for p in acl["policies"]}
    assert acl["default_permission"] == "deny"

    def keys(user: str, message: str, flow: str) -> set[str]:
        return {k for rid in policy[by_user[user]] for k in rules[rid]["key_exprs"]
                if message in rules[rid]["messages"] and flow in rules[rid]["flows"]}

    fleet_status = {"radical-fleet/*/status/*",  # radical fleet status
                    "radical-fleet/*/roster-state/*"}  # the roster (fleet add/remove confirm)
    assert keys("monitor", "query", "ingress") == {"radical/*/cmd/read/monitor", *fleet_status}
    assert keys("alice", "query", "ingress") == {"radical/*/cmd/read/alice",
                                                 "radical/*/cmd/write/alice", *fleet_status}
    assert keys("sensor", "query", "ingress") == set()
    assert keys("sensor", "put", "ingress") == {f"radical/*/{t}" for t in zauth.INPUT_TOPICS}
    assert keys("monitor", "put", "ingress") == set()
    assert keys("alice", "put", "ingress") == {"radical-fleet/*/roster/*"}  # fleet add/remove
    assert "radical/*/siru" not in keys("monitor", "put", "egress")  # monitors never see inputs
    assert "radical/*/siru" in keys("alice", "put", "egress")
    assert keys("node", "put", "ingress") == {"radical/**", "radical-fleet/**"}
    assert keys("sensor", "put", "ingress").isdisjoint({"radical-fleet/**"})
    roster_edit = "radical-fleet/*/roster/*"  # radical fleet add/remove: operators only
    assert roster_edit not in keys("monitor", "put", "ingress")
    assert roster_edit not in keys("sensor", "put", "ingress")
    assert "radical-fleet/*/worker/*" in keys("monitor", "liveliness_query", "ingress")
    assert all("radical/*/cmd" not in keys(u, "query", "ingress") for u in by_user if u != "node")


def test_parse_users_and_init_refusals(tmp_path):
    with pytest.raises(ValueError, match="ROLE:NAME"):
        parse_users(["admin:bob"])
    with pytest.raises(ValueError, match="a name is"):
        parse_users(["operator:Bob!"])
    with pytest.raises(ValueError, match="already has role"):
        parse_users(["operator:monitor"])
    init_profile(tmp_path / "p", port=17004)
    with pytest.raises(ValueError, match="already holds a profile"):
        init_profile(tmp_path / "p", port=17004)
    assert init_profile(tmp_path / "p", port=17005, force=True).endpoint.endswith(":17005")


def test_session_auth_rules(tmp_path):
    init_profile(tmp_path / "p", users=parse_users(["operator:alice"]))
    with pytest.raises(zauth.AuthError, match="need --auth"):
        zauth.session_auth(None, "operator", "monitor")
    assert zauth.session_auth(None, None, "monitor") is None
    sa = zauth.session_auth(str(tmp_path / "p"), None, "monitor")
    assert (sa.role, sa.user) == ("monitor", "monitor")
    sa = zauth.session_auth(str(tmp_path / "p"), None, "monitor", user="alice")
    assert (sa.role, sa.user) == ("operator", "alice")
    with pytest.raises(zauth.AuthError, match="has role 'operator', not 'sensor'"):
        zauth.session_auth(str(tmp_path / "p"), "sensor", "monitor", user="alice")
    with pytest.raises(zauth.AuthError, match="no user 'mallory'"):
        zauth.session_auth(str(tmp_path / "p"), None, "monitor", user="mallory")
    with pytest.raises(zauth.AuthError, match="not a security profile"):
        zauth.session_auth(str(tmp_path), None, "monitor")
    with pytest.raises(zauth.AuthError, match="only the node listens"):
        sa.settings(listening=True)
    assert "access_control" in zauth.session_auth(str(tmp_path / "p"), "node", "x").settings(True)


def test_tls_endpoints_are_loopback_locators():
    assert zconfig.check_endpoint("tls/127.0.0.1:7448") == "tls/127.0.0.1:7448"
    with pytest.raises(zconfig.ZenohConfigError, match="not a loopback locator"):
        zconfig.check_endpoint("tls/10.0.0.1:7448")


def test_keys_cli(tmp_path, capsys):
    assert radical_main(["keys", "init", str(tmp_path / "k"), "--port", "17006"]) == 0
    assert "profile written" in capsys.readouterr().out
    assert radical_main(["keys", "init", str(tmp_path / "k")]) == 2
    assert "already holds a profile" in capsys.readouterr().err
    assert radical_main(["keys", "init", str(tmp_path / "k2"), "--user", "boss:x"]) == 2


def test_a_users_kit_holds_only_its_own_secrets(tmp_path):
    from radical_rt.apps.keys_cli import make_kit

    prof = init_profile(tmp_path / "p", port=17007, users=parse_users(["operator:alice"]))
    kit = make_kit(prof.directory, "alice", tmp_path / "kit")
    names = sorted(f.name for f in kit.iterdir())
    assert names == ["alice.key", "alice.pem", "ca.pem", "profile.json", "user-alice.json5"]
    assert _mode(kit) == 0o700 and _mode(kit / "alice.key") == 0o600
    sa = zauth.session_auth(str(kit), None, "monitor", user="alice")
    settings = sa.settings(listening=False)
    assert settings["transport/auth/usrpwd/password"] == prof.passwords["alice"]
    assert settings["transport/link/tls/connect_certificate"] == str(kit.resolve() / "alice.pem")
    assert sa.profile.passwords == {"alice": prof.passwords["alice"]}  # nobody else's
    with pytest.raises(zauth.AuthError, match="holds no credentials of a user with role"):
        zauth.session_auth(str(kit), "monitor", "monitor")
    with pytest.raises(zauth.AuthError, match="user's kit"):
        sa.profile.listener_settings()
    with pytest.raises(ValueError, match="not empty"):
        make_kit(prof.directory, "alice", kit)
    with pytest.raises(ValueError, match="no user 'bob'"):
        make_kit(prof.directory, "bob", tmp_path / "kit2")
